"""What cameras cost a recording: frames per second with 0, 1 and 2 cameras, at the default size and a large one, with
1 and 2 simulation workers, side by side in one run (docs/how-to/cameras.md, "What cameras cost"); then what each way
of storing a frame costs (docs/decisions/cameras.md).

    .venv/bin/python -m bench.camera_cost [--episodes 4] [--steps 300] [--frames 200]

Each row is `make record` of the standing recipe (`teleop.record.STANDING`) into a new folder, end to end (start-up
included), for `--episodes` episodes of `--steps` steps; the ratios are to the row without cameras with as many
workers, measured in the same run (these machines are shared and noisy). The speed-up of 2 workers over 1 says whether
rendering and encoding, which the workers do, keep parallel recording's scaling. The second table encodes `--frames`
frames of the tracking camera of the standing expert as AV1 (the dataset's settings), as H.264, as JPEG and as PNG,
and decodes the videos: milliseconds and kilobytes per frame and the mean error to the rendered frame. Prints markdown
tables.
"""

from __future__ import annotations

import argparse
import io
import tempfile
import time
from pathlib import Path

import av
import numpy as np
from PIL import Image

from humanoid.cameras import DEFAULT_SIZE, CameraRig, parse_cameras
from humanoid.encoding import Av1Stream
from humanoid.env import make_env, model_and_data
from rollout.controllers import make_controller
from teleop.record import STANDING, STANDING_NOISE, RecordConfig, main

H264 = {"g": "2", "crf": "30", "preset": "ultrafast", "threads": "1"}
"""x264's settings in the comparison: its fastest preset at the same quality number and key-frame interval."""

LARGE = (480, 640)
"""(height, width): LeRobot's usual camera size (its ALOHA and SO-100 datasets)."""


def cameras_flag(count: int, size: tuple[int, int]) -> str:
    """`--cameras` for the first `count` cameras at `size`."""
    return ",".join(f"{name}:{size[0]}x{size[1]}" for name in ("head", "tracking")[:count])


def frames_per_second(cameras: str, workers: int, episodes: int, steps: int) -> float:
    """Frames/s of one recording into a new folder, start-up included."""
    with tempfile.TemporaryDirectory() as folder:
        cfg = RecordConfig(
            dataset=Path(folder) / "dataset",
            episodes=episodes,
            max_steps=steps,
            noise=STANDING_NOISE,
            cameras=cameras,
            workers=workers,
            progress=False,
            **STANDING,
        )
        start = time.perf_counter()
        summary = main(cfg)
        return summary.frames / (time.perf_counter() - start)


def rendered(size: tuple[int, int], frames: int) -> tuple[list[np.ndarray], float]:
    """`frames` frames of the tracking camera at `size` while the expert stands (seed 0), and the seconds per frame
    that rendering took with its env step."""
    env = make_env()
    model, data = model_and_data(env)
    controller = make_controller("expert", env)
    rig = CameraRig(model, parse_cameras(f"tracking:{size[0]}x{size[1]}"))
    obs, _ = env.reset(seed=0)
    controller.reset(0)
    shots = []
    start = time.perf_counter()
    for _ in range(frames):
        shots.append(rig.frames(data)[0][0])
        obs, *_ = env.step(controller.act(obs))
    seconds = (time.perf_counter() - start) / frames
    rig.close()
    env.close()
    return shots, seconds


def video_cost(frames: list[np.ndarray], codec: str) -> tuple[float, float, float, float]:
    """(encode s/frame, decode s/frame, bytes/frame, mean abs error /255) of `frames` as `codec` ("av1": the
    dataset's `Av1Stream`; "h264": `H264`) in an MP4."""
    height, width = frames[0].shape[:2]
    start = time.perf_counter()
    if codec == "av1":
        stream = Av1Stream(height, width, 67)
        for frame in frames:
            stream.add(frame)
        video = stream.finish()
    else:
        buffer = io.BytesIO()
        with av.open(buffer, "w", format="mp4") as container:
            encoder = container.add_stream("libx264", 67, options=H264)
            encoder.pix_fmt, encoder.width, encoder.height = "yuv420p", width, height
            for frame in frames:
                container.mux(encoder.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")))
            container.mux(encoder.encode())
        video = buffer.getvalue()
    encode = (time.perf_counter() - start) / len(frames)
    start = time.perf_counter()
    with av.open(io.BytesIO(video)) as container:
        decoded = [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]
    decode = (time.perf_counter() - start) / len(frames)
    error = float(np.mean([np.abs(a.astype(int) - b).mean() for a, b in zip(decoded, frames, strict=True)]))
    return encode, decode, len(video) / len(frames), error


def image_cost(frames: list[np.ndarray], kind: str) -> tuple[float, float]:
    """(encode s/frame, bytes/frame) of `frames` as PIL's `kind` images ("JPEG" at the MCAP's quality, "PNG")."""
    options = {"quality": 90} if kind == "JPEG" else {}
    start, size = time.perf_counter(), 0
    for frame in frames:
        buffer = io.BytesIO()
        Image.fromarray(frame).save(buffer, format=kind, **options)
        size += len(buffer.getvalue())
    return (time.perf_counter() - start) / len(frames), size / len(frames)


def codec_table(frames: int) -> list[str]:
    """The second table's rows (markdown)."""
    rows = []
    for size in (DEFAULT_SIZE, LARGE):
        shots, render = rendered(size, frames)
        shown = f"{size[0]}x{size[1]}"
        rows.append(f"| rendering and the env step, {shown} | {1e3 * render:.1f} | | | |")
        for codec, name in (("av1", "AV1 (the dataset's settings)"), ("h264", "H.264 (x264 ultrafast, CRF 30)")):
            encode, decode, size_bytes, error = video_cost(shots, codec)
            rows.append(
                f"| {name}, {shown} | {1e3 * encode:.2f} | {1e3 * decode:.2f} | {size_bytes / 1e3:.1f} | {error:.2f} |"
            )
        for kind in ("JPEG", "PNG"):
            encode, size_bytes = image_cost(shots, kind)
            rows.append(f"| {kind}, {shown} | {1e3 * encode:.2f} | | {size_bytes / 1e3:.1f} | |")
    return rows


def main_bench() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--frames", type=int, default=200)
    args = parser.parse_args()
    rows = [(0, DEFAULT_SIZE), (1, DEFAULT_SIZE), (2, DEFAULT_SIZE), (1, LARGE), (2, LARGE)]
    rates = {
        (count, size, workers): frames_per_second(cameras_flag(count, size), workers, args.episodes, args.steps)
        for count, size in rows
        for workers in (1, 2)
    }
    print("| cameras | size | frames/s, 1 worker | x without | frames/s, 2 workers | x without | 2 workers / 1 |")
    print("|---|---|---|---|---|---|---|")
    for count, size in rows:
        one, two = rates[(count, size, 1)], rates[(count, size, 2)]
        shown = f"{size[0]}x{size[1]}" if count else "-"
        print(
            f"| {count} | {shown} | {one:.0f} | {one / rates[(0, DEFAULT_SIZE, 1)]:.2f} | {two:.0f} | "
            f"{two / rates[(0, DEFAULT_SIZE, 2)]:.2f} | {two / one:.2f} |"
        )

    print("\n| storing a frame | encode, ms/frame | decode, ms/frame | kB/frame | mean abs error (/255) |")
    print("|---|---|---|---|---|")
    print("\n".join(codec_table(args.frames)))


if __name__ == "__main__":
    main_bench()
