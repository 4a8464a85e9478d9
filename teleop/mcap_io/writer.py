"""One MCAP file per episode: protobuf messages in zstd chunks, viewable in Foxglove's 3D panel.

The file is written by `teleop.mcap_io.bulk`, which takes the whole episode's messages at once.

Topics (log and publish times are integer nanoseconds of simulated time, frame_index x step):
- `/step`  humanoid_bc.Step: observation, sensed state, label and executed action, reward, terminated, truncated.
- `/final_observation`  humanoid_bc.Step, once, at time T: the observation and state the last action led
  to (o_T; frame index T, no action or reward), with the episode's terminated / truncated flags.
- `/tf`    foxglove.FrameTransforms: the world pose of each of the 13 bodies, every step.
- `/command` humanoid_bc.Command: the command in force, the push, the task naming the command, the expert's
  setpoint and the posture achieved.
- `/scene` foxglove.SceneUpdate, once: the geoms (capsules as a cylinder and two spheres), each
  attached to its body's frame, and the floor.
- `/camera/<name>/image` foxglove.CompressedImage (JPEG) and `/camera/<name>/calibration`
  foxglove.CameraCalibration, every step, for each camera the dataset records (`make record CAMERAS=...`): the frame
  of row t, in the optical frame `<name>_camera` that `/tf` also carries (x right, y down, z along the view), so that
  Foxglove's image panel shows it and its 3D panel places it.
Plus an `episode` metadata record and the MJCF model as an attachment.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.CylinderPrimitive_pb2 import CylinderPrimitive
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.SpherePrimitive_pb2 import SpherePrimitive
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from mcap.well_known import MessageEncoding
from mcap_protobuf.schema import register_schema

from common.files import write_atomically
from humanoid.cameras import CameraTrack
from humanoid.env import nominal_model
from rollout.episode import Episode
from task.tracking import Tracking
from teleop.mcap_io.bulk import BulkMcapWriter
from teleop.mcap_io.schema import Command, Step, command_values
from teleop.mcap_io.wire import CommandEncoder, FrameTransformsEncoder, StepEncoder

STEP_TOPIC = "/step"
FINAL_TOPIC = "/final_observation"
TF_TOPIC = "/tf"
COMMAND_TOPIC = "/command"
SCENE_TOPIC = "/scene"
WORLD_FRAME = "world"
IMAGE_TOPIC = "/camera/{name}/image"
CALIBRATION_TOPIC = "/camera/{name}/calibration"
METADATA_NAME = "episode"
MJCF_ATTACHMENT = "model.xml"
_DEFAULT_RGBA = (0.5, 0.5, 0.5, 1.0)


def _pose(position: np.ndarray, wxyz: np.ndarray) -> Pose:
    w, x, y, z = wxyz
    return Pose(
        position=Vector3(x=position[0], y=position[1], z=position[2]), orientation=Quaternion(x=x, y=y, z=z, w=w)
    )


def _geom_color(model: mujoco.MjModel, geom: int) -> Color:
    # MuJoCo's rule: a geom's own rgba wins over its material's unless it was left at the default.
    material = model.geom_matid[geom]
    own = model.geom_rgba[geom]
    r, g, b, a = model.mat_rgba[material] if material >= 0 and np.allclose(own, _DEFAULT_RGBA) else own
    return Color(r=r, g=g, b=b, a=a)


def scene_update(model: mujoco.MjModel, body_frames: list[str]) -> SceneUpdate:
    """Foxglove primitives for every geom, in its body's frame, so `/tf` alone animates the scene."""
    entities: dict[int, SceneEntity] = {}
    for geom in range(model.ngeom):
        body = int(model.geom_bodyid[geom])
        frame = WORLD_FRAME if body == 0 else body_frames[body - 1]
        entity = entities.setdefault(body, SceneEntity(frame_id=frame, id=frame, frame_locked=True))
        pose, size, color = model.geom_pos[geom], model.geom_size[geom], _geom_color(model, geom)
        orientation = model.geom_quat[geom]
        kind = model.geom_type[geom]
        if kind == mujoco.mjtGeom.mjGEOM_PLANE:
            entity.cubes.append(
                CubePrimitive(
                    pose=_pose(pose - [0, 0, 0.005], orientation),
                    size=Vector3(x=2 * size[0], y=2 * size[1], z=0.01),
                    color=color,
                )
            )
        elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
            d = 2 * size[0]
            entity.spheres.append(
                SpherePrimitive(pose=_pose(pose, orientation), size=Vector3(x=d, y=d, z=d), color=color)
            )
        elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
            radius, half_length = size[0], size[1]
            d = 2 * radius
            entity.cylinders.append(
                CylinderPrimitive(pose=_pose(pose, orientation), size=Vector3(x=d, y=d, z=2 * half_length), color=color)
            )
            axis = np.empty(9)
            mujoco.mju_quat2Mat(axis, orientation)
            along = axis.reshape(3, 3)[:, 2] * half_length  # capsule axis is the geom's local z
            for end in (pose + along, pose - along):
                entity.spheres.append(
                    SpherePrimitive(pose=_pose(end, orientation), size=Vector3(x=d, y=d, z=d), color=color)
                )
        else:
            raise ValueError(f"geom {geom} has type {kind}, which the Foxglove scene does not draw")
    return SceneUpdate(entities=list(entities.values()))


def camera_frame(name: str) -> str:
    """The `/tf` frame of camera `name`'s optical frame."""
    return f"{name}_camera"


def calibration(name: str, k: np.ndarray, height: int, width: int) -> CameraCalibration:
    """Camera `name`'s `foxglove.CameraCalibration` (no timestamp): pinhole `k`, no distortion, the image's size."""
    projection = np.hstack([k, np.zeros((3, 1))])
    return CameraCalibration(
        frame_id=camera_frame(name),
        width=width,
        height=height,
        distortion_model="plumb_bob",
        D=[0.0] * 5,
        K=k.reshape(-1).tolist(),
        R=np.eye(3).reshape(-1).tolist(),
        P=projection.reshape(-1).tolist(),
    )


def image_message(name: str, jpeg: bytes, time_ns: int) -> bytes:
    """Camera `name`'s `foxglove.CompressedImage` of one JPEG frame at `time_ns`, serialised (the file's and the live
    view's)."""
    image = CompressedImage(frame_id=camera_frame(name), data=jpeg, format="jpeg")
    image.timestamp.FromNanoseconds(time_ns)
    return image.SerializeToString()


def calibration_message(calibrated: CameraCalibration, time_ns: int) -> bytes:
    """`calibrated` (`calibration`) stamped `time_ns`, serialised; the stamp is written into it."""
    calibrated.timestamp.FromNanoseconds(time_ns)
    return calibrated.SerializeToString()


def camera_messages(
    name: str, track: CameraTrack, calibrated: CameraCalibration, times_ns: np.ndarray
) -> tuple[list[bytes], list[bytes]]:
    """Camera `name`'s image and calibration (`calibrated`) messages, one each per frame of `track`, at `times_ns`."""
    calibrated = CameraCalibration.FromString(calibrated.SerializeToString())  # stamped here, not the caller's
    times = times_ns.tolist()
    images = [image_message(name, jpeg, time_ns) for time_ns, jpeg in zip(times, track.images, strict=True)]
    return images, [calibration_message(calibrated, time_ns) for time_ns in times]


def write_episode_mcap(
    path: Path,
    episode: Episode,
    state: np.ndarray,
    final_state: np.ndarray,
    episode_index: int,
    scene: SceneUpdate,
    body_frames: list[str],
    step_ns: int,
    metadata: dict[str, str],
    mjcf: bytes,
    calibrations: tuple[CameraCalibration, ...] = (),
) -> None:
    """Write `episode` to `path` atomically: a finished file appears under its name, or nothing does.
    `calibrations`: each of `episode.cameras`' (`calibration`), in order."""
    times_ns = np.arange(episode.length, dtype=np.int64) * step_ns
    cameras = list(episode.cameras.items())
    frames = [*body_frames, *(camera_frame(name) for name, _ in cameras)]
    positions = np.concatenate([episode.body_position, *(track.position[:, None] for _, track in cameras)], axis=1)
    orientations = np.concatenate(
        [episode.body_orientation, *(track.orientation[:, None] for _, track in cameras)], axis=1
    )
    transforms = FrameTransformsEncoder(WORLD_FRAME, frames).encode(times_ns, positions, orientations)
    achieved = Tracking(nominal_model()).achieved(episode.observation)
    values = command_values(episode.command, episode.push, episode.setpoint, achieved)
    commands = CommandEncoder().encode(times_ns, values, episode.tasks)
    steps = StepEncoder().encode(
        times_ns,
        episode_index,
        episode.observation,
        state,
        episode.action,
        episode.executed_action,
        episode.reward,
        episode.terminated,
        episode.truncated,
        episode.tasks,
    )
    final = Step(
        episode_index=episode_index,
        frame_index=episode.length,
        observation=episode.final_observation.tolist(),
        state=final_state.tolist(),
        terminated=bool(episode.terminated[-1]),
        truncated=bool(episode.truncated[-1]),
        task=str(episode.tasks[-1]),
    )
    final.timestamp.FromNanoseconds(episode.length * step_ns)

    def save(partial: Path) -> None:
        with partial.open("wb") as stream:
            writer = BulkMcapWriter(stream)
            writer.start(profile="", library="humanoid-bc")
            kinds = (
                SceneUpdate,
                Step,
                FrameTransforms,
                Command,
                *((CompressedImage, CameraCalibration) if cameras else ()),
            )
            schemas = {kind: register_schema(writer, kind) for kind in kinds}
            topics = [
                (SCENE_TOPIC, SceneUpdate),
                (STEP_TOPIC, Step),
                (TF_TOPIC, FrameTransforms),
                (COMMAND_TOPIC, Command),
                (FINAL_TOPIC, Step),
            ]
            for name, _ in cameras:
                topics += [
                    (IMAGE_TOPIC.format(name=name), CompressedImage),
                    (CALIBRATION_TOPIC.format(name=name), CameraCalibration),
                ]
            channels = {
                topic: writer.register_channel(topic, MessageEncoding.Protobuf, schemas[message_type])
                for topic, message_type in topics
            }
            writer.add_attachment(
                create_time=0, log_time=0, name=MJCF_ATTACHMENT, media_type="application/xml", data=mjcf
            )
            writer.add_metadata(METADATA_NAME, metadata)
            no_time = np.zeros(1, np.int64)
            writer.add_messages(
                np.array([channels[SCENE_TOPIC]]), no_time, no_time, no_time, [scene.SerializeToString()]
            )
            per_step = [STEP_TOPIC, TF_TOPIC, COMMAND_TOPIC]  # each step's messages, in this order
            streams = [steps, transforms, commands]
            for (name, track), calibrated in zip(cameras, calibrations, strict=True):
                per_step += [IMAGE_TOPIC.format(name=name), CALIBRATION_TOPIC.format(name=name)]
                streams += camera_messages(name, track, calibrated, times_ns)
            data: list[bytes] = [b""] * (len(per_step) * episode.length)
            for offset, messages in enumerate(streams):
                data[offset :: len(per_step)] = messages
            step_times = np.repeat(times_ns, len(per_step))
            writer.add_messages(
                np.tile([channels[topic] for topic in per_step], episode.length),
                step_times,
                step_times,
                np.repeat(np.arange(episode.length), len(per_step)),
                data,
            )
            end = np.array([episode.length * step_ns], np.int64)
            length = np.array([episode.length])
            writer.add_messages(np.array([channels[FINAL_TOPIC]]), end, end, length, [final.SerializeToString()])
            writer.finish()

    write_atomically(path, save)
