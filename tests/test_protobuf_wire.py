"""The hand-built protobuf encodings decode, with the generated classes, to the values they came from."""

from __future__ import annotations

import numpy as np
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3

from teleop.mcap_schema import Step
from teleop.protobuf_wire import FrameTransformsEncoder, StepEncoder, varint


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
    for t, data in enumerate(encoded):
        expected = FrameTransforms()
        for frame, p, q in zip(frames, positions[t], orientations[t], strict=True):
            transform = FrameTransform(parent_frame_id="world", child_frame_id=frame,
                                       translation=Vector3(x=p[0], y=p[1], z=p[2]),
                                       rotation=Quaternion(x=q[1], y=q[2], z=q[3], w=q[0]))
            transform.timestamp.FromNanoseconds(int(times[t]))
            expected.transforms.append(transform)
        assert FrameTransforms.FromString(data) == expected


def test_step_decodes_to_its_fields() -> None:
    """An encoded Step carries the scalars and the three arrays exactly, float32 arrays included."""
    rng = np.random.default_rng(1)
    observation, action, executed = rng.normal(size=348), rng.normal(size=17).astype(np.float32), np.zeros(17, np.float32)
    data = StepEncoder().encode(45_000_000, {"episode_index": 2, "frame_index": 3, "reward": 4.5, "terminated": True,
                                             "truncated": False, "task": "stand"}, observation, action, executed)
    step = Step.FromString(data)
    assert (step.episode_index, step.frame_index, step.reward, step.terminated, step.task) == (2, 3, 4.5, True, "stand")
    assert step.timestamp.ToNanoseconds() == 45_000_000
    np.testing.assert_array_equal(np.array(step.observation), observation)
    np.testing.assert_array_equal(np.array(step.action, np.float32), action)
    np.testing.assert_array_equal(np.array(step.executed_action, np.float32), executed)
