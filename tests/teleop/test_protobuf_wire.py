"""The hand-built protobuf encodings decode, with the generated classes, to the values they came from."""

from __future__ import annotations

import numpy as np
import pytest
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp

from teleop.mcap_io.schema import Step
from teleop.mcap_io.wire import FrameTransformsEncoder, StepEncoder, length_delimited, timestamp_fields, varint


def test_varint_known_answers() -> None:
    """Varints of the protobuf documentation's examples."""
    assert varint(0) == b"\x00"
    assert varint(1) == b"\x01"
    assert varint(150) == b"\x96\x01"
    assert varint(300) == b"\xac\x02"


def test_frame_transforms_decode_to_the_api_built_message() -> None:
    """Encoded transforms parse into the message the protobuf API builds from the same numbers."""
    rng = np.random.default_rng(0)
    frames = ["torso", "left_foot"]
    times = np.array([0, 15_000_000, 3_000_000_000])
    positions, orientations = rng.normal(size=(3, 2, 3)), rng.normal(size=(3, 2, 4))
    positions[1, 0] = 0.0  # zeros are written explicitly; they must still decode as zeros
    encoded = FrameTransformsEncoder("world", frames).encode(times, positions, orientations)
    assert len(encoded) == len(times)
    for t, data in enumerate(encoded):
        expected = FrameTransforms()
        for frame, p, q in zip(frames, positions[t], orientations[t], strict=True):
            transform = FrameTransform(
                parent_frame_id="world",
                child_frame_id=frame,
                translation=Vector3(x=p[0], y=p[1], z=p[2]),
                rotation=Quaternion(x=q[1], y=q[2], z=q[3], w=q[0]),
            )
            transform.timestamp.FromNanoseconds(int(times[t]))
            expected.transforms.append(transform)
        assert FrameTransforms.FromString(data) == expected


def test_steps_decode_to_their_fields() -> None:
    """Encoded Steps carry the scalars and the four arrays exactly, float32 arrays and zeros included."""
    rng = np.random.default_rng(1)
    times = np.array([0, 15_000_000, 3_000_000_000])
    observation, action = rng.normal(size=(3, 348)), rng.normal(size=(3, 17)).astype(np.float32)
    state = rng.normal(size=(3, 42))
    executed = np.zeros((3, 17), np.float32)
    reward, terminated, truncated = (
        np.array([4.5, 0.0, -1.25]),
        np.array([False, False, True]),
        np.array([False, True, False]),
    )
    tasks = np.array(["stand", "crouch", "stand"], dtype=object)
    encoded = StepEncoder().encode(times, 2, observation, state, action, executed, reward, terminated, truncated, tasks)
    assert len(encoded) == len(times)
    for t, data in enumerate(encoded):
        step = Step.FromString(data)
        assert (step.episode_index, step.frame_index, step.reward, step.terminated, step.truncated, step.task) == (
            2,
            t,
            reward[t],
            terminated[t],
            truncated[t],
            tasks[t],
        )
        assert step.timestamp.ToNanoseconds() == times[t]
        np.testing.assert_array_equal(np.array(step.observation), observation[t])
        np.testing.assert_array_equal(np.array(step.state), state[t])
        np.testing.assert_array_equal(np.array(step.action, np.float32), action[t])
        np.testing.assert_array_equal(np.array(step.executed_action, np.float32), executed[t])


def test_timestamp_fields_equal_protobuf_serialisation() -> None:
    """Timestamps are the bytes protobuf's Timestamp writes, zero parts omitted, for every kind of time."""
    times = np.array([0, 1, 15_000_000, 1_000_000_000, 3_015_000_000, 10**15])
    key = b"\x0a"
    for time_ns, field in zip(times, timestamp_fields(key, times), strict=True):
        stamp = Timestamp()
        stamp.FromNanoseconds(int(time_ns))
        assert field == length_delimited(key, stamp.SerializeToString())


def test_negative_time_is_refused() -> None:
    """A time before the episode's start has no place in the file: ValueError."""
    with pytest.raises(ValueError, match="times must be >= 0"):
        timestamp_fields(b"\x0a", np.array([0, -1]))


def test_one_step_transforms_equal_the_batch_encoders() -> None:
    """The live stream's one-step /tf encoding gives the bytes the episode encoder gives, for any time."""
    encoder = FrameTransformsEncoder("world", [f"body{i}" for i in range(13)])
    rng = np.random.default_rng(2)
    for time_ns in (0, 15_000_000, 1_000_000_000, 1_763_900_000_123_456_789):
        positions, orientations = rng.normal(size=(13, 3)), rng.normal(size=(13, 4))
        batch = encoder.encode(np.array([time_ns]), positions[None], orientations[None])[0]
        assert encoder.encode_one(time_ns, positions, orientations) == batch
