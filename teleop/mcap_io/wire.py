"""Protobuf wire encoding of the per-step MCAP messages, from NumPy arrays, a whole episode at once.

Building `foxglove.FrameTransforms`, `humanoid_bc.Step` and `humanoid_bc.Command` through the
protobuf API converts 13 nested transforms and 348 doubles one by one, a large share of the time
it takes to simulate the step (docs/decisions/mcap-writing.md).
The messages are mostly numbers in fixed
places, so their bytes are built here directly, following the wire format
(https://protobuf.dev/programming-guides/encoding/): each message is a row of bytes, filled by
NumPy for every step at once, plus the few fields whose size varies (timestamp, frame index, task).

Concatenated fields are a valid encoding, in any order, and every number is written explicitly
(zeros too), which parsers accept. Field numbers come from the message descriptors, never typed in
by hand. The tests decode the bytes with the generated classes and compare them with the arrays
they came from.
"""

from __future__ import annotations

import functools
import struct

import numpy as np
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.message import Message
from google.protobuf.timestamp_pb2 import Timestamp

from teleop.mcap_io.schema import COMMAND_VALUES, Command, Step

_VARINT = 0
_FIXED64 = 1
_LENGTH_DELIMITED = 2
_DOUBLE_SIZE = 8
_NANOS_PER_SECOND = 1_000_000_000


def varint(value: int) -> bytes:
    """Base-128 varint of a non-negative integer."""
    out = bytearray()
    while value >= 0x80:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def tag(message: type[Message], field: str, wire_type: int) -> bytes:
    """The key that precedes `field` of `message` on the wire."""
    return varint(message.DESCRIPTOR.fields_by_name[field].number << 3 | wire_type)


def length_delimited(key: bytes, payload: bytes) -> bytes:
    """A length-delimited field: sub-message, string, bytes or packed repeated numbers."""
    return key + varint(len(payload)) + payload


def packed_key(message: type[Message], field: str) -> bytes:
    """The key of a packed repeated numeric field."""
    return tag(message, field, _LENGTH_DELIMITED)


_SECONDS_KEY = tag(Timestamp, "seconds", _VARINT)
_NANOS_KEY = tag(Timestamp, "nanos", _VARINT)


def _byte_rows(steps: int, parts: list[bytes | np.ndarray]) -> np.ndarray:
    """(steps, size) bytes: each row the concatenation of `parts`, constant strings or (steps, n) byte arrays."""
    return np.concatenate(
        [
            np.broadcast_to(np.frombuffer(part, np.uint8), (steps, len(part))) if isinstance(part, bytes) else part
            for part in parts
        ],
        axis=1,
    )


def _number_bytes(values: np.ndarray, dtype: str) -> np.ndarray:
    """(steps, ...) numbers as (steps, n) bytes of little-endian `dtype`."""
    values = np.ascontiguousarray(values, dtype=dtype)
    return values.view(np.uint8).reshape(len(values), -1)


def timestamp_fields(key: bytes, times_ns: np.ndarray) -> list[bytes]:
    """The field `key` = google.protobuf.Timestamp(times_ns[t]) for each step, as Timestamp serialises it."""
    if len(times_ns) and times_ns.min() < 0:
        raise ValueError(f"times must be >= 0 ns, got {times_ns.min()}")
    return [_timestamp_field(key, time_ns) for time_ns in times_ns.tolist()]


@functools.cache
def _timestamp_field(key: bytes, time_ns: int) -> bytes:
    # Cached: every episode has the same time grid, and a timestamp's varints cost more than a lookup.
    return timestamp_field(key, time_ns)


def timestamp_field(key: bytes, time_ns: int) -> bytes:
    """The field `key` = google.protobuf.Timestamp(time_ns), uncached (a live stream's times never repeat)."""
    seconds, nanos = divmod(time_ns, _NANOS_PER_SECOND)
    stamp = (_SECONDS_KEY + varint(seconds) if seconds else b"") + (_NANOS_KEY + varint(nanos) if nanos else b"")
    return length_delimited(key, stamp)


def _doubles_records(
    message: type[Message], field: str, sub_message: type[Message], components: list[str], values: np.ndarray
) -> np.ndarray:
    """`field` = sub_message(components...) for each row of `values` (rows, len(components)), as byte rows."""
    parts: list[bytes | np.ndarray] = [
        tag(message, field, _LENGTH_DELIMITED) + varint(len(components) * (1 + _DOUBLE_SIZE))
    ]
    for column, component in enumerate(components):
        parts += [tag(sub_message, component, _FIXED64), _number_bytes(values[:, column], "<f8")]
    return _byte_rows(len(values), parts)


class FrameTransformsEncoder:
    """Serialised `foxglove.FrameTransforms` for every step of an episode, one `bytes` per step."""

    def __init__(self, parent_frame: str, child_frames: list[str]) -> None:
        parent = length_delimited(tag(FrameTransform, "parent_frame_id", _LENGTH_DELIMITED), parent_frame.encode())
        self._frame_fields = [
            parent + length_delimited(tag(FrameTransform, "child_frame_id", _LENGTH_DELIMITED), child.encode())
            for child in child_frames
        ]
        self._timestamp_key = tag(FrameTransform, "timestamp", _LENGTH_DELIMITED)
        self._transform_key = tag(FrameTransforms, "transforms", _LENGTH_DELIMITED)
        # One body's pose as `encode` writes it, for `encode_one`: translation (x, y, z), rotation (x, y, z, w),
        # each a length-delimited sub-message of tagged doubles; every tag and length is one byte.
        layout = [tag(FrameTransform, "translation", _LENGTH_DELIMITED), varint(3 * (1 + _DOUBLE_SIZE))]
        layout += [tag(Vector3, axis, _FIXED64) for axis in "xyz"]
        layout += [tag(FrameTransform, "rotation", _LENGTH_DELIMITED), varint(4 * (1 + _DOUBLE_SIZE))]
        layout += [tag(Quaternion, axis, _FIXED64) for axis in "xyzw"]
        assert all(len(part) == 1 for part in layout)
        self._pose = struct.Struct("<BB" + "Bd" * 3 + "BB" + "Bd" * 4)
        self._pose_tags = [part[0] for part in layout]

    def encode_one(self, time_ns: int, positions: np.ndarray, orientations_wxyz: np.ndarray) -> bytes:
        """The message `encode` gives for one step, built without NumPy's per-call overhead (a live stream)."""
        stamp = timestamp_field(self._timestamp_key, time_ns)
        tr, tr_len, tx, ty, tz, ro, ro_len, qx, qy, qz, qw = self._pose_tags
        parts = []
        for frame, (x, y, z), (w, i, j, k) in zip(
            self._frame_fields, positions.tolist(), orientations_wxyz.tolist(), strict=True
        ):
            pose = self._pose.pack(tr, tr_len, tx, x, ty, y, tz, z, ro, ro_len, qx, i, qy, j, qz, k, qw, w)
            parts += [self._transform_key, varint(len(stamp) + len(frame) + len(pose)), stamp, frame, pose]
        return b"".join(parts)

    def encode(self, times_ns: np.ndarray, positions: np.ndarray, orientations_wxyz: np.ndarray) -> list[bytes]:
        """Messages for (T,) times, (T, bodies, 3) positions and (T, bodies, 4) w-x-y-z quaternions."""
        steps, bodies = positions.shape[:2]
        xyzw = orientations_wxyz[..., [1, 2, 3, 0]]  # Foxglove orders quaternions x, y, z, w
        poses = np.concatenate(
            [
                _doubles_records(FrameTransform, "translation", Vector3, ["x", "y", "z"], positions.reshape(-1, 3)),
                _doubles_records(FrameTransform, "rotation", Quaternion, ["x", "y", "z", "w"], xyzw.reshape(-1, 4)),
            ],
            axis=1,
        ).reshape(steps, bodies, -1)
        stamps = timestamp_fields(self._timestamp_key, times_ns)
        messages: list[bytes] = [b""] * steps
        # Every step's message has the same layout but for its timestamp's size, which takes a few
        # values only: fill each group of same-size steps as rows of one byte array.
        for stamp_size in set(map(len, stamps)):
            rows = [t for t, stamp in enumerate(stamps) if len(stamp) == stamp_size]
            stamp_bytes = np.frombuffer(b"".join(stamps[t] for t in rows), np.uint8).reshape(len(rows), stamp_size)
            parts: list[bytes | np.ndarray] = []
            for frame, pose in zip(self._frame_fields, poses[rows].transpose(1, 0, 2), strict=True):
                parts += [
                    self._transform_key + varint(stamp_size + len(frame) + pose.shape[1]),
                    stamp_bytes,
                    frame,
                    pose,
                ]
            filled = _byte_rows(len(rows), parts)
            for t, row in zip(rows, filled, strict=True):
                messages[t] = row.tobytes()
        return messages


class StepEncoder:
    """Serialised `humanoid_bc.Step` messages for every step of an episode, one `bytes` per step."""

    def __init__(self) -> None:
        self._timestamp_key = tag(Step, "timestamp", _LENGTH_DELIMITED)
        self._episode_key = tag(Step, "episode_index", _VARINT)
        self._frame_key = tag(Step, "frame_index", _VARINT)
        self._task_key = tag(Step, "task", _LENGTH_DELIMITED)

    def encode(
        self,
        times_ns: np.ndarray,
        episode_index: int,
        observation: np.ndarray,
        state: np.ndarray,
        action: np.ndarray,
        executed_action: np.ndarray,
        reward: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
        tasks: np.ndarray,
    ) -> list[bytes]:
        """Messages for an episode's T steps: (T,) times, (T, n) observation, state and actions, (T,) reward, flags
        and tasks; frame indices from 0."""
        steps = len(times_ns)
        parts: list[bytes | np.ndarray] = []
        for name, values, dtype in (
            ("observation", observation, "<f8"),
            ("state", state, "<f8"),
            ("action", action, "<f4"),
            ("executed_action", executed_action, "<f4"),
        ):
            numbers = _number_bytes(values, dtype)
            parts += [packed_key(Step, name) + varint(numbers.shape[1]), numbers]
        parts += [tag(Step, "reward", _FIXED64), _number_bytes(reward, "<f8")]
        for name, flags in (("terminated", terminated), ("truncated", truncated)):
            parts += [tag(Step, name, _VARINT), _number_bytes(flags, "u1")]  # varints 0 and 1 are one byte
        rows = _byte_rows(steps, parts)
        head = self._episode_key + varint(episode_index)
        task_fields = {task: length_delimited(self._task_key, task.encode()) for task in set(tasks.tolist())}
        return [
            stamp + head + self._frame_key + varint(t) + row.tobytes() + task_fields[task]
            for t, (stamp, row, task) in enumerate(
                zip(timestamp_fields(self._timestamp_key, times_ns), rows, tasks.tolist(), strict=True)
            )
        ]


class CommandEncoder:
    """Serialised `humanoid_bc.Command` messages for every step of an episode, one `bytes` per step."""

    def __init__(self) -> None:
        self._task_key = tag(Command, "task", _LENGTH_DELIMITED)
        self._timestamp_key = tag(Command, "timestamp", _LENGTH_DELIMITED)

    def encode(self, times_ns: np.ndarray, values: np.ndarray, tasks: np.ndarray) -> list[bytes]:
        """Messages for (T,) times, (T, len(COMMAND_VALUES)) numbers (`schema.command_values`) and (T,) task
        strings."""
        parts: list[bytes | np.ndarray] = []
        for column, name in enumerate(COMMAND_VALUES):
            parts += [tag(Command, name, _FIXED64), _number_bytes(values[:, column], "<f8")]
        rows = _byte_rows(len(values), parts)
        task_fields = {task: length_delimited(self._task_key, task.encode()) for task in set(tasks.tolist())}
        return [
            stamp + row.tobytes() + task_fields[task]
            for stamp, row, task in zip(
                timestamp_fields(self._timestamp_key, times_ns), rows, tasks.tolist(), strict=True
            )
        ]
