"""`LIVE=1`: every step published as it happens to a Foxglove WebSocket server, for a 3D view with no display.

The Foxglove app opens `ws://127.0.0.1:8765` ("Open connection") and gets the topics an episode's
MCAP file holds, the same messages encoded the same way (`teleop.mcap_io`):

    rollout step t (rollout.episode.StepObserver) --> /step, /tf, /command  (one message each, same schemas)
                                                      and each camera's image and calibration (`CAMERAS=...`)
    episode start                                  --> /scene (again every SCENE_EVERY steps, for late joiners)
                                                        \\--> foxglove-sdk server (a Rust thread) --> clients

Messages are only encoded while a client is subscribed, so with nobody watching a step costs a
check per channel. Times are wall-clock nanoseconds: the episode's start plus t steps of simulated
time, so a live view runs forward through episode after episode. Cost per step with and without a
client: docs/benchmarks.md, "Live view".
"""

from __future__ import annotations

import sys
import time

import foxglove
import gymnasium as gym
import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf.message import Message
from mcap_protobuf.schema import build_file_descriptor_set

from common.cli import UserError
from humanoid.cameras import Camera, intrinsics
from humanoid.env import body_names, model_and_data, nominal_model, step_duration_ns
from humanoid.sensors import Proprioception
from rollout.episode import EpisodeBuffer
from task.tracking import Tracking
from teleop.mcap_io.schema import COMMAND_VALUES, Command, Step, command_values
from teleop.mcap_io.wire import FrameTransformsEncoder
from teleop.mcap_io.writer import (
    CALIBRATION_TOPIC,
    COMMAND_TOPIC,
    IMAGE_TOPIC,
    SCENE_TOPIC,
    STEP_TOPIC,
    TF_TOPIC,
    WORLD_FRAME,
    calibration,
    calibration_message,
    camera_frame,
    image_message,
    scene_update,
)

DEFAULT_HOST = "127.0.0.1"  # loopback unless the user asks otherwise: the stream has no authentication
DEFAULT_PORT = 8765  # Foxglove's default
SCENE_EVERY = 200  # steps (3 s of simulated time) between repeats of /scene


def _schema(message: type[Message]) -> foxglove.Schema:
    descriptor = message.DESCRIPTOR
    data = build_file_descriptor_set(message).SerializeToString()
    return foxglove.Schema(name=descriptor.full_name, encoding="protobuf", data=data)


class LivePublisher:
    """A Foxglove WebSocket server publishing one rollout's steps (a `rollout.episode.StepObserver`)."""

    def __init__(
        self, env: gym.Env, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, cameras: tuple[Camera, ...] = ()
    ) -> None:
        model, _ = model_and_data(env)
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(name="humanoid-bc", host=host, port=port, context=self.context)
        except Exception as error:  # the SDK raises its own error types: a port in use, an address not ours
            raise UserError(f"cannot serve the live view on {host}:{port}: {error}") from None
        self.channels = {
            topic: foxglove.Channel(topic, schema=_schema(kind), message_encoding="protobuf", context=self.context)
            for topic, kind in (
                (SCENE_TOPIC, SceneUpdate),
                (STEP_TOPIC, Step),
                (TF_TOPIC, FrameTransforms),
                (COMMAND_TOPIC, Command),
                *((IMAGE_TOPIC.format(name=camera.name), CompressedImage) for camera in cameras),
                *((CALIBRATION_TOPIC.format(name=camera.name), CameraCalibration) for camera in cameras),
            )
        }
        self._calibrations = {
            camera.name: calibration(camera.name, intrinsics(model, camera), *camera.size) for camera in cameras
        }
        frames = body_names(model)
        self._scene = scene_update(model, frames).SerializeToString()
        self._proprioception = Proprioception(model)
        self._tracking = Tracking(nominal_model())
        self._step_ns = step_duration_ns(env)
        self._transforms = FrameTransformsEncoder(WORLD_FRAME, [*frames, *(camera_frame(c.name) for c in cameras)])
        self.episode = -1
        self._start_ns = time.time_ns()

    @property
    def port(self) -> int:
        """The port the server listens on (the one asked for, or the system's choice for 0)."""
        return self.server.port

    def episode_started(self, seed: int) -> None:
        self.episode += 1
        self._start_ns = time.time_ns()
        self.channels[SCENE_TOPIC].log(self._scene, log_time=self._start_ns)

    def step(self, buffer: EpisodeBuffer, t: int) -> None:
        """Publish row t of `buffer` (complete: observation, actions and outcome)."""
        log_time = self._start_ns + t * self._step_ns
        if t and t % SCENE_EVERY == 0:
            self.channels[SCENE_TOPIC].log(self._scene, log_time=log_time)
        # One message at a time: the protobuf runtime (upb, in C) and a struct-packed /tf cost less than the
        # batch encoders' NumPy set-up for one row (docs/benchmarks.md, "Live view").
        if self.channels[STEP_TOPIC].has_sinks():
            step = Step(
                episode_index=self.episode,
                frame_index=t,
                observation=buffer.observation[t].tolist(),
                state=self._proprioception(buffer.observation[t]).tolist(),
                action=buffer.action[t].tolist(),
                executed_action=buffer.executed_action[t].tolist(),
                reward=float(buffer.reward[t]),
                terminated=bool(buffer.terminated[t]),
                truncated=bool(buffer.truncated[t]),
                task=str(buffer.tasks[t]),
            )
            step.timestamp.FromNanoseconds(log_time)
            self.channels[STEP_TOPIC].log(step.SerializeToString(), log_time=log_time)
        shots = buffer.cameras.latest() if buffer.cameras is not None else []
        if self.channels[TF_TOPIC].has_sinks():
            positions, orientations = buffer.body_position[t], buffer.body_orientation[t]
            if shots:  # the cameras' optical frames after the bodies'
                positions = np.vstack([positions, *(shot[2] for shot in shots)])
                orientations = np.vstack([orientations, *(shot[3] for shot in shots)])
            message = self._transforms.encode_one(log_time, positions, orientations)
            self.channels[TF_TOPIC].log(message, log_time=log_time)
        for name, jpeg, _, _ in shots:
            if self.channels[IMAGE_TOPIC.format(name=name)].has_sinks():
                self.channels[IMAGE_TOPIC.format(name=name)].log(image_message(name, jpeg, log_time), log_time=log_time)
            if self.channels[CALIBRATION_TOPIC.format(name=name)].has_sinks():
                message = calibration_message(self._calibrations[name], log_time)
                self.channels[CALIBRATION_TOPIC.format(name=name)].log(message, log_time=log_time)
        if self.channels[COMMAND_TOPIC].has_sinks():
            achieved = self._tracking.achieved(buffer.observation[t : t + 1])[0]
            values = command_values(buffer.command[t], buffer.push[t], buffer.setpoint[t], achieved)
            command = Command(task=str(buffer.tasks[t]), **dict(zip(COMMAND_VALUES, values.tolist(), strict=True)))
            command.timestamp.FromNanoseconds(log_time)
            self.channels[COMMAND_TOPIC].log(command.SerializeToString(), log_time=log_time)

    def close(self) -> None:
        self.server.stop()


def check_port(port: int) -> None:
    """UserError unless `port` is a TCP port number (0 lets the system choose)."""
    if not 0 <= port <= 65535:
        raise UserError(f"--live-port must be a TCP port, 0..65535, got {port}")


def start_live(env: gym.Env, host: str, port: int, cameras: tuple[Camera, ...] = ()) -> LivePublisher:
    """A `LivePublisher` for `env` (and `cameras`), its address said on stderr for the person who will open it."""
    live = LivePublisher(env, host, port, cameras)
    print(f"live view: ws://{host}:{live.port} (Foxglove: Open connection)", file=sys.stderr, flush=True)
    return live
