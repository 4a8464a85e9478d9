"""Video encoding in memory, frame by frame: the dataset's camera streams (`humanoid.cameras`).

PyAV (from the lock) brings its own FFmpeg with SVT-AV1 and x264: no system FFmpeg is needed.
"""

from __future__ import annotations

import io
import os
from fractions import Fraction

import numpy as np

ENCODER = {"vcodec": "libsvtav1", "pix_fmt": "yuv420p", "g": 2, "crf": 30, "preset": 12, "fast_decode": 0}
"""The dataset videos' encoder settings: LeRobot 0.6.1's defaults (`lerobot.configs.video.VideoEncoderConfig()`, held
to it by a test): AV1, a key frame every 2 frames (random access for training), quality 30, SVT-AV1's fastest preset."""
CODEC = "av1"
"""The codec's name as a decoder reports it (info.json's `video.codec`)."""


class Av1Stream:
    """Encodes RGB frames one at a time into an MP4 held in memory (`ENCODER`'s settings); `finish` returns the file.
    Frame i has the presentation time i / fps exactly, so that LeRobot finds frame i at timestamp i / fps."""

    def __init__(self, height: int, width: int, fps: int) -> None:
        import av  # noqa: PLC0415 - only where cameras record

        os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its configuration at every stream otherwise
        self._file = io.BytesIO()
        self._container = av.open(self._file, "w", format="mp4")
        options = {"g": str(ENCODER["g"]), "crf": str(ENCODER["crf"]), "preset": str(ENCODER["preset"])}
        # One thread: the simulation workers are the parallelism (as many as cores).
        options["svtav1-params"] = f"fast-decode={ENCODER['fast_decode']}:lp=1"
        self._stream = self._container.add_stream(ENCODER["vcodec"], fps, options=options)
        self._stream.pix_fmt, self._stream.height, self._stream.width = ENCODER["pix_fmt"], height, width
        self._time_base = Fraction(1, fps)
        self._frames = 0
        self._av = av

    def add(self, frame: np.ndarray) -> None:
        """Encode the next frame, (H, W, 3) uint8 RGB."""
        picture = self._av.VideoFrame.from_ndarray(frame, format="rgb24")
        picture.pts, picture.time_base = self._frames, self._time_base
        self._container.mux(self._stream.encode(picture))
        self._frames += 1

    def finish(self) -> bytes:
        """The finished MP4 file's bytes."""
        self._container.mux(self._stream.encode())
        self._container.close()
        return self._file.getvalue()
