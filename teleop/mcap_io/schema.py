"""The protobuf messages of this project's MCAP channels, built at import time (no generated code).

- `humanoid_bc.Step` (`/step`): one step's observation (the gymnasium one, and the sensed part of it as
  `state`, named by the metadata record's `state_names`), actions, reward and outcome.
- `humanoid_bc.Command` (`/command`): the command in force at that step, one field per entry of
  the dataset's `observation.command` (so Foxglove plots each by name), the push, the task that names it,
  the expert's setpoint toward it (`setpoint_*`) and the posture achieved (`achieved_*`: the fields read from one
  coordinate). Every number field's protobuf number is its command field's row's (`CommandField.mcap`), never
  derived from an order: a file written before a field was added decodes the same with today's message.

Defining the schema from a `FileDescriptorProto` keeps it independent of the protoc version the
installed protobuf runtime expects; MCAP files embed the schema, so readers need nothing from here.
"""

from __future__ import annotations

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory, timestamp_pb2

from common.columns import PUSH_NAMES
from task.command_fields import COMMAND_FIELDS
from task.tracking import PLOTTED

PACKAGE = "humanoid_bc"
STEP_TYPE = f"{PACKAGE}.Step"
COMMAND_TYPE = f"{PACKAGE}.Command"

_F = descriptor_pb2.FieldDescriptorProto
# (name, number, type, label, type_name): one row per field of `Step`.
_STEP_FIELDS = (
    ("timestamp", 1, _F.TYPE_MESSAGE, _F.LABEL_OPTIONAL, ".google.protobuf.Timestamp"),
    ("episode_index", 2, _F.TYPE_UINT64, _F.LABEL_OPTIONAL, None),
    ("frame_index", 3, _F.TYPE_UINT64, _F.LABEL_OPTIONAL, None),
    ("observation", 4, _F.TYPE_DOUBLE, _F.LABEL_REPEATED, None),
    ("action", 5, _F.TYPE_FLOAT, _F.LABEL_REPEATED, None),
    ("executed_action", 6, _F.TYPE_FLOAT, _F.LABEL_REPEATED, None),
    ("reward", 7, _F.TYPE_DOUBLE, _F.LABEL_OPTIONAL, None),
    ("terminated", 8, _F.TYPE_BOOL, _F.LABEL_OPTIONAL, None),
    ("truncated", 9, _F.TYPE_BOOL, _F.LABEL_OPTIONAL, None),
    ("task", 10, _F.TYPE_STRING, _F.LABEL_OPTIONAL, None),
    ("state", 11, _F.TYPE_DOUBLE, _F.LABEL_REPEATED, None),  # observation.state: what a robot senses
)
PUSH_NUMBERS = (7, 8)
"""The push's numbers (`PUSH_NAMES`), and the task's: fixed since the first version."""
TASK_NUMBER = 9
_NUMBERED = (
    *((field.name, field.mcap[0]) for field in COMMAND_FIELDS),
    *zip(PUSH_NAMES, PUSH_NUMBERS, strict=True),
    *((f"setpoint_{field.name}", field.mcap[1]) for field in COMMAND_FIELDS),
    *((f"achieved_{field.name}", field.mcap[2]) for field in PLOTTED),
)
COMMAND_VALUES = tuple(name for name, _ in _NUMBERED)
"""The number fields of `Command`, in the order `command_values` gives them."""
_COMMAND_FIELDS = (
    ("timestamp", 1, _F.TYPE_MESSAGE, _F.LABEL_OPTIONAL, ".google.protobuf.Timestamp"),
    *((name, number, _F.TYPE_DOUBLE, _F.LABEL_OPTIONAL, None) for name, number in _NUMBERED),
    ("task", TASK_NUMBER, _F.TYPE_STRING, _F.LABEL_OPTIONAL, None),
)
_MESSAGES = {"Step": _STEP_FIELDS, "Command": _COMMAND_FIELDS}


def _build_classes() -> tuple[type, type]:
    pool = descriptor_pool.Default()
    try:
        pool.FindMessageTypeByName(STEP_TYPE)
    except KeyError:
        # One file per message: each MCAP schema then embeds only its own message.
        for message_name, fields in _MESSAGES.items():
            file_proto = descriptor_pb2.FileDescriptorProto(
                name=f"humanoid_bc/{message_name.lower()}.proto",
                package=PACKAGE,
                syntax="proto3",
                dependency=[timestamp_pb2.DESCRIPTOR.name],
            )
            message = file_proto.message_type.add(name=message_name)
            for name, number, field_type, label, type_name in fields:
                field = message.field.add(name=name, number=number, type=field_type, label=label)
                if type_name:
                    field.type_name = type_name
            pool.Add(file_proto)
    return tuple(
        message_factory.GetMessageClass(pool.FindMessageTypeByName(name)) for name in (STEP_TYPE, COMMAND_TYPE)
    )


Step, Command = _build_classes()


def command_values(command: np.ndarray, push: np.ndarray, setpoint: np.ndarray, achieved: np.ndarray) -> np.ndarray:
    """(T, len(COMMAND_VALUES)) the numbers of `Command` messages, from an episode's (T, ...) columns."""
    return np.concatenate([command, push, setpoint, achieved], axis=-1)
