"""Cameras on the body, declared as data: what `make record CAMERAS=...` renders at every step and stores as video.

Each row of `CAMERAS` is one camera: the body it rides on or follows, where it looks, and its default size. A user adds
a camera by adding a row (docs/how-to/cameras.md). A session's cameras are named in one flag,
`--cameras head,tracking:240x320` (a name, optionally `:HEIGHTxWIDTH`, positive even numbers: the video's 4:2:0
chroma halves both).

A camera renders the state a row's observation was read from (before the step), offscreen through MUJOCO_GL (EGL on
llvmpipe without a GPU, or OSMesa), without shadows or reflections, which cost most of a software frame
(docs/decisions/video-rendering.md). Each episode's frames are encoded while it runs (`CameraRecorder`): an MP4 of
AV1 with LeRobot's default encoder settings for the dataset (`observation.images.<name>`), a JPEG per frame for the
MCAP's `foxglove.CompressedImage` channel, the camera's pose per frame for `/tf`, and the frames LeRobot samples for
its image statistics. The simulation workers encode, so cameras keep parallel recording's scaling.
"""

from __future__ import annotations

import io
import math
import os
from dataclasses import dataclass, field

import mujoco
import numpy as np

from common.cli import UserError
from common.lerobot_stats import image_stats
from humanoid.physics import TORSO_BODY, heading

DEFAULT_SIZE = (96, 128)
"""(height, width) in pixels of a camera whose size is not given: 4:3 like LeRobot's 480x640 and 240x320, small
enough that a frame renders in about 12 ms on llvmpipe (docs/decisions/cameras.md)."""


@dataclass(frozen=True)
class Camera:
    """One camera: a MuJoCo viewer camera (`mujoco.MjvCamera`) placed from the body's state at every frame."""

    name: str
    """The camera's name: its dataset key is `observation.images.<name>`, its MCAP topic `/camera/<name>/image`."""
    description: str
    """What it shows, for `--help` and the docs."""
    mode: str
    """"head": rides on `body`, at `offset` in its heading frame, looking along the heading (no roll, a gimbal's
    view); "tracking": follows `body` from `distance` at a fixed world `azimuth` (MuJoCo's tracking camera)."""
    distance: float
    """m: from the camera to the point it looks at."""
    azimuth: float
    """deg: the direction it looks in, about the vertical: from the heading for "head", in the world for "tracking"."""
    elevation: float
    """deg: up (+) or down (-) from the horizontal."""
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """m: where a "head" camera sits from `body`'s origin, in its heading frame (forward, left, up)."""
    body: str = TORSO_BODY
    """The body it rides on or follows."""
    size: tuple[int, int] = DEFAULT_SIZE
    """(height, width) in pixels unless the session gives one."""


CAMERAS = {
    camera.name: camera
    for camera in (
        Camera(
            "head",
            "on the torso, at the head, looking ahead and a little down",
            mode="head",
            distance=1.0,
            azimuth=0.0,
            elevation=-20.0,
            offset=(0.1, 0.0, 0.19),
        ),
        # A three-quarter view with the whole body in frame (gymnasium's default camera for Humanoid looks from the
        # side and cuts the feet off): also the eval videos' camera (`humanoid.video`).
        Camera("tracking", "follows the body from 3.5 m, three-quarter view", "tracking", 3.5, 135.0, -10.0),
    )
}
"""The cameras a session may name, by name."""
EXPENSIVE_EFFECTS = (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION)
"""What a software renderer spends most of a frame on: switched off (docs/decisions/video-rendering.md)."""


def parse_cameras(spec: str) -> tuple[Camera, ...]:
    """The cameras `spec` names ("" for none; "head,tracking:240x320"), each with its size; UserError in one line for
    an unknown name, a repeated one, or a size that is not HEIGHTxWIDTH of positive even numbers."""
    cameras: list[Camera] = []
    for item in filter(None, (part.strip() for part in spec.split(","))):
        name, _, size = item.partition(":")
        if name not in CAMERAS:
            raise UserError(f"--cameras: unknown camera {name!r}; known: {', '.join(CAMERAS)}")
        if any(camera.name == name for camera in cameras):
            raise UserError(f"--cameras: {name} is named twice")
        camera = CAMERAS[name]
        if size:
            height, _, width = size.partition("x")
            try:
                dims = int(height), int(width)
            except ValueError:
                dims = (0, 0)
            if min(dims) <= 0 or any(d % 2 for d in dims):
                raise UserError(
                    f"--cameras: size {size!r} of {name} is not HEIGHTxWIDTH of positive even numbers (e.g. 96x128)"
                )
            camera = Camera(**{**camera.__dict__, "size": dims})
        cameras.append(camera)
    return tuple(cameras)


def intrinsics(model: mujoco.MjModel, camera: Camera) -> np.ndarray:
    """The 3x3 pinhole matrix K of `camera`'s images: MuJoCo's viewer cameras have the model's vertical field of
    view (`vis.global_.fovy`) and square pixels, the principal point at the image's centre."""
    height, width = camera.size
    focal = 0.5 * height / math.tan(math.radians(model.vis.global_.fovy) / 2)
    return np.array([[focal, 0.0, width / 2], [0.0, focal, height / 2], [0.0, 0.0, 1.0]])


def backend() -> str:
    """The MUJOCO_GL backend named in the environment, set to EGL where none is (MuJoCo reads it when it first renders
    in a process: `make` and the tests set it before)."""
    return os.environ.setdefault("MUJOCO_GL", "egl")


class RenderError(UserError):
    """Offscreen rendering is not available with this MUJOCO_GL backend."""


def render_error(error: Exception) -> RenderError:
    """What a failed offscreen context or render says, in one line."""
    cause = str(error).splitlines()[0] if str(error) else type(error).__name__
    return RenderError(
        f"offscreen rendering failed with MUJOCO_GL={backend()} ({cause}); try MUJOCO_GL=egl or MUJOCO_GL=osmesa"
    )


class CameraRig:
    """Renders `cameras` of `model`'s state: `frames(data)` is one RGB frame and one pose per camera."""

    def __init__(self, model: mujoco.MjModel, cameras: tuple[Camera, ...]) -> None:
        self.cameras = cameras
        self._body = {camera.name: model.body(camera.body).id for camera in cameras}
        # The offscreen buffer must hold the largest frame: the model's default is 640x480.
        model.vis.global_.offwidth = max([model.vis.global_.offwidth, *(c.size[1] for c in cameras)])
        model.vis.global_.offheight = max([model.vis.global_.offheight, *(c.size[0] for c in cameras)])
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}
        try:
            for size in {camera.size for camera in cameras}:
                self._renderers[size] = mujoco.Renderer(model, *size)
        except Exception as error:  # no EGL device, no OSMesa library, ...
            self.close()
            raise render_error(error) from None
        self._views = {camera.name: mujoco.MjvCamera() for camera in cameras}
        for camera in cameras:
            view = self._views[camera.name]
            view.distance, view.elevation = camera.distance, camera.elevation
            view.type = mujoco.mjtCamera.mjCAMERA_FREE
            if camera.mode == "tracking":
                view.type, view.trackbodyid = mujoco.mjtCamera.mjCAMERA_TRACKING, self._body[camera.name]
                view.azimuth = camera.azimuth

    def frames(self, data: mujoco.MjData) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Each camera's (frame (H, W, 3) uint8, position (3,), orientation (4,) w-x-y-z of its optical frame: x
        right, y down, z along the view) at `data`'s state (its kinematics computed, as after a step or a reset)."""
        shots = []
        for camera in self.cameras:
            view, body = self._views[camera.name], self._body[camera.name]
            if camera.mode == "head":
                yaw = heading(data, camera.body)
                turn = np.array([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0], [0, 0, 1]])
                eye = data.xpos[body] + turn @ np.array(camera.offset)
                view.azimuth = math.degrees(yaw) + camera.azimuth
                az, el = math.radians(view.azimuth), math.radians(camera.elevation)
                view.lookat[:] = eye + camera.distance * np.array(
                    [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]
                )
            renderer = self._renderers[camera.size]
            renderer.update_scene(data, camera=view)
            for flag in EXPENSIVE_EFFECTS:
                renderer.scene.flags[flag] = 0
            try:
                frame = renderer.render()
            except Exception as error:
                raise render_error(error) from None
            # The scene holds a camera per eye, apart by the model's interpupillary distance: a mono view is their mean.
            glcam = mujoco.mjv_averageCamera(renderer.scene.camera[0], renderer.scene.camera[1])
            forward, up = np.array(glcam.forward), np.array(glcam.up)
            right = np.cross(forward, up)
            rotation = np.column_stack([right, -up, forward])
            quaternion = np.empty(4)
            mujoco.mju_mat2Quat(quaternion, rotation.reshape(-1))
            shots.append((frame, np.array(glcam.pos), quaternion))
        return shots

    def close(self) -> None:
        for renderer in self._renderers.values():
            renderer.close()
        self._renderers = {}


STATS_SAMPLES = (100, 10_000, 0.75)
"""LeRobot's image statistics read min(T, max(100, min(T**0.75, 10000))) frames of an episode of T, evenly spaced
(`lerobot.datasets.compute_stats.sample_indices`, held to it by a test)."""
STATS_SIDE = (150, 300)
"""LeRobot's statistics read a frame whose longer side is 300 pixels or more at every k-th pixel, k the longer side
over 150, rounded down (`auto_downsample_height_width`)."""


def stats_indices(length: int) -> np.ndarray:
    """The frames of an episode of `length` that LeRobot's image statistics read (`STATS_SAMPLES`)."""
    least, most, power = STATS_SAMPLES
    count = max(min(least, length), min(int(length**power), most))
    return np.round(np.linspace(0, length - 1, count)).astype(int)


def stats_view(frame: np.ndarray) -> np.ndarray:
    """`frame` (H, W, 3) as LeRobot's statistics read it: channels first, downsampled where large (`STATS_SIDE`)."""
    target, threshold = STATS_SIDE
    height, width = frame.shape[:2]
    channels_first = frame.transpose(2, 0, 1)
    if max(height, width) < threshold:
        return channels_first
    step = int(max(height, width) / target)
    return channels_first[:, ::step, ::step]


@dataclass
class CameraTrack:
    """One camera's record of an episode (T frames, one per row)."""

    video: bytes
    """The MP4 (AV1) of the T frames, frame i at i / fps: the dataset's `observation.images.<name>` file."""
    images: list[bytes]
    """Each frame as a JPEG: the MCAP's `foxglove.CompressedImage` messages."""
    position: np.ndarray
    """(T, 3) m: where the camera was, world frame."""
    orientation: np.ndarray
    """(T, 4) w-x-y-z: its optical frame (x right, y down, z along the view)."""
    stats: dict[str, np.ndarray] = field(repr=False)
    """LeRobot's statistics of the frames (`common.lerobot_stats.image_stats` of those `stats_indices` picks)."""


JPEG_QUALITY = 90
"""The MCAP images' JPEG quality (PIL's scale, 1-95): about 5 kB a frame at the default size."""


class CameraRecorder:
    """Renders `rig`'s cameras at every row of an episode and encodes them as it goes; `finish` hands the tracks
    over and readies it for the next episode."""

    def __init__(self, rig: CameraRig, fps: int) -> None:
        self.rig, self.fps = rig, fps
        self._begin()

    def _begin(self) -> None:
        from humanoid.encoding import Av1Stream  # noqa: PLC0415 - PyAV, only where cameras record

        self._streams = [Av1Stream(*camera.size, self.fps) for camera in self.rig.cameras]
        self._images: list[list[bytes]] = [[] for _ in self.rig.cameras]
        self._poses: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in self.rig.cameras]
        self._views: list[list[np.ndarray]] = [[] for _ in self.rig.cameras]

    def add(self, data: mujoco.MjData) -> None:
        """The next row's frames, rendered at `data`'s state."""
        from PIL import Image  # noqa: PLC0415 - only where cameras record

        for i, (frame, position, orientation) in enumerate(self.rig.frames(data)):
            self._streams[i].add(frame)
            jpeg = io.BytesIO()
            Image.fromarray(frame).save(jpeg, format="JPEG", quality=JPEG_QUALITY)
            self._images[i].append(jpeg.getvalue())
            self._poses[i].append((position, orientation))
            self._views[i].append(stats_view(frame).copy())

    def latest(self) -> list[tuple[str, bytes, np.ndarray, np.ndarray]]:
        """Each camera's (name, JPEG, position, orientation) of the last row added (a live view's)."""
        return [(camera.name, self._images[i][-1], *self._poses[i][-1]) for i, camera in enumerate(self.rig.cameras)]

    def restart(self) -> None:
        """Drop what was recorded: the episode starts again (an episode's row 0)."""
        if any(self._images):
            self._begin()

    def finish(self, length: int) -> dict[str, CameraTrack]:
        """The tracks of the first `length` rows, by camera name (`length` frames were added)."""
        tracks = {}
        for i, camera in enumerate(self.rig.cameras):
            if len(self._images[i]) != length:
                raise RuntimeError(f"camera {camera.name} has {len(self._images[i])} frames for {length} rows")
            tracks[camera.name] = CameraTrack(
                video=self._streams[i].finish(),
                images=self._images[i],
                position=np.array([pose[0] for pose in self._poses[i]]).reshape(-1, 3),
                orientation=np.array([pose[1] for pose in self._poses[i]]).reshape(-1, 4),
                stats=image_stats(np.stack([self._views[i][k] for k in stats_indices(length)])),
            )
        self._begin()
        return tracks
