"""Offscreen MP4 recording of an environment, on the CPU, without a display.

MuJoCo renders through EGL (Mesa's llvmpipe when there is no GPU) or OSMesa, chosen by
MUJOCO_GL, which gymnasium reads when it creates its first viewer: `VideoRecorder` sets it to
`egl` unless the user chose. Shadows and reflections are switched off: in software they cost most
of a frame's time (docs/decisions/video-rendering.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from common.cli import UserError
from humanoid.cameras import CAMERAS, EXPENSIVE_EFFECTS, backend

_TRACKING = CAMERAS["tracking"]
CAMERA = {
    "trackbodyid": 1,
    "distance": _TRACKING.distance,
    "lookat": np.array([0.0, 0.0, 1.0]),
    "elevation": _TRACKING.elevation,
    "azimuth": _TRACKING.azimuth,
}
"""gymnasium's `default_camera_config` for the eval videos: the dataset's tracking camera (`humanoid.cameras`)."""


class VideoError(UserError):
    """Offscreen rendering or video encoding is not available, or the file cannot be written."""


class VideoRecorder(gym.Wrapper):
    """Appends a frame to an MP4 file after every reset and step; `close` finishes the file.

    `env` must be made with `render_mode="rgb_array"`, best with `default_camera_config=CAMERA`.
    """

    def __init__(self, env: gym.Env, path: Path) -> None:
        super().__init__(env)
        if env.render_mode != "rgb_array":
            raise ValueError(f"VideoRecorder needs render_mode='rgb_array', got {env.render_mode!r}")
        self.backend = backend()
        try:
            import imageio.v3 as iio  # noqa: PLC0415 - only runs with a video pay for the encoder
        except ImportError as error:
            raise VideoError(f"videos need imageio and PyAV ({error}); pip install 'imageio[pyav]'") from None
        self.path = path
        self._file = None
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._file = iio.imopen(path, "w", plugin="pyav")
            self._file.init_video_stream("libx264", fps=env.metadata.get("render_fps", 30))
        except (OSError, ValueError) as error:  # unwritable folder, or a PyAV without libx264
            raise VideoError(f"cannot write a video to {path}: {error}") from None
        self._scene_configured = False
        self.frames = 0

    def _capture(self) -> None:
        try:
            frame = self.env.render()
        except Exception as error:
            raise VideoError(
                f"offscreen rendering failed with MUJOCO_GL={self.backend} ({error}); "
                f"try MUJOCO_GL=osmesa or MUJOCO_GL=egl"
            ) from None
        if not self._scene_configured:
            # The viewer exists only after the first render: from the second frame on, no shadows.
            viewer = self.env.unwrapped.mujoco_renderer.viewer
            for flag in EXPENSIVE_EFFECTS:
                viewer.scn.flags[flag] = 0
            self._scene_configured = True
            frame = self.env.render()
        self._file.write_frame(np.ascontiguousarray(frame))
        self.frames += 1

    def reset(self, **kwargs: Any) -> tuple[Any, dict]:
        result = self.env.reset(**kwargs)
        self._capture()
        return result

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict]:
        result = self.env.step(action)
        self._capture()
        return result

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
        super().close()
