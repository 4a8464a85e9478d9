"""The protobuf message carrying one step in MCAP, built at import time (no generated code).

Defining the schema from a `FileDescriptorProto` keeps it independent of the protoc version the
installed protobuf runtime expects; MCAP files embed the schema, so readers need nothing from here.
"""

from __future__ import annotations

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory, timestamp_pb2

PACKAGE = "humanoid_bc"
STEP_TYPE = f"{PACKAGE}.Step"

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
)


def _build_step_class() -> type:
    pool = descriptor_pool.Default()
    try:
        return message_factory.GetMessageClass(pool.FindMessageTypeByName(STEP_TYPE))
    except KeyError:
        pass
    file_proto = descriptor_pb2.FileDescriptorProto(
        name="humanoid_bc/step.proto",
        package=PACKAGE,
        syntax="proto3",
        dependency=[timestamp_pb2.DESCRIPTOR.name],
    )
    step = file_proto.message_type.add(name="Step")
    for name, number, field_type, label, type_name in _STEP_FIELDS:
        field = step.field.add(name=name, number=number, type=field_type, label=label)
        if type_name:
            field.type_name = type_name
    pool.Add(file_proto)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(STEP_TYPE))


Step = _build_step_class()
