"""`make record CAMERAS=...`: camera streams in the LeRobot dataset (video) and the MCAP (images, calibration, /tf)."""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import av
import mujoco
import numpy as np
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from lerobot.configs.video import VideoEncoderConfig
from lerobot.datasets import compute_stats
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.datasets.video_utils import get_video_info
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from PIL import Image
from websockets.sync.client import connect

from common import columns
from common.cli import DatasetError, UserError
from common.lerobot_stats import image_stats
from humanoid.cameras import CAMERAS, DEFAULT_SIZE, CameraRig, intrinsics, parse_cameras, stats_indices, stats_view
from humanoid.encoding import ENCODER, Av1Stream
from humanoid.env import make_env, model_and_data
from rollout.controllers import make_controller
from rollout.episode import EpisodeBuffer, run_episode
from support import (
    MESSAGE_DATA,
    SUBPROTOCOLS,
    assert_consistent,
    committed_episodes,
    humanoid_model,
    record_short,
    run_lerobot_train,
    snapshot,
    start_recording,
    wait_for_episodes,
)
from teleop.dataset_reader import read_episodes
from teleop.export import cli as export_cli
from teleop.inspect_dataset import InspectConfig
from teleop.inspect_dataset import main as inspect
from teleop.lerobot_io.format import INFO_PATH, VIDEO_PATH
from teleop.live import LivePublisher
from teleop.mcap_io.writer import CALIBRATION_TOPIC, IMAGE_TOPIC, TF_TOPIC, camera_frame
from teleop.merge import cli as merge_cli
from teleop.record import cli as record_cli

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)

CAMERAS_FLAG = "head,tracking:48x64"
STEPS = 210  # the posture schedules' first command comes at step 200: `make export` needs one


@pytest.fixture(scope="module")
def filmed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A posture episode of the expert with a head camera (default size) and a small tracking camera."""
    root = tmp_path_factory.mktemp("cameras") / "dataset"
    record_short(root, episodes=1, max_steps=STEPS, task="posture", cameras=CAMERAS_FLAG)
    return root


def video_path(root: Path, camera: str, episode: int) -> Path:
    key = columns.image_key(camera)
    return root / VIDEO_PATH.format(video_key=key, chunk_index=0, file_index=episode)


def test_cameras_are_named_in_one_flag() -> None:
    """Names from the table, each with its size or the default; the value a dataset's cameras round-trip through."""
    head, tracking = parse_cameras("head, tracking:240x320")
    assert (head.name, head.size, tracking.name, tracking.size) == ("head", DEFAULT_SIZE, "tracking", (240, 320))
    assert parse_cameras("") == ()
    assert tracking.mode == CAMERAS["tracking"].mode and tracking.distance == CAMERAS["tracking"].distance


@pytest.mark.parametrize(
    ("spec", "said"),
    [
        ("eye", "unknown camera 'eye'"),
        ("head:95x128", "positive even"),
        ("head:0x2", "positive even"),
        ("head:ax4", "positive even"),
        ("head,head", "named twice"),
    ],
)
def test_bad_cameras_are_refused_in_one_line_and_nothing_is_written(
    spec: str, said: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = tmp_path / "dataset"
    with pytest.raises(UserError, match=said):
        parse_cameras(spec)
    assert record_cli(["--dataset", str(root), "--episodes", "1", "--cameras", spec]) != 0
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert not root.exists()


def test_a_backend_that_cannot_render_is_refused_in_one_line(tmp_path: Path) -> None:
    """MUJOCO_GL=osmesa where OSMesa is missing (these machines): one line naming MUJOCO_GL's choices, nothing
    written."""
    root = tmp_path / "dataset"
    command = [sys.executable, "-m", "teleop.record", "--dataset", str(root), "--episodes", "1", "--cameras", "head"]
    result = subprocess.run(
        command, env={**os.environ, "MUJOCO_GL": "osmesa"}, capture_output=True, text=True, timeout=120
    )
    if result.returncode == 0:
        pytest.skip("OSMesa renders on this machine")
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "MUJOCO_GL=osmesa" in lines[0] and "MUJOCO_GL=egl" in lines[0], result.stderr
    assert not root.exists()


def test_the_video_features_are_what_lerobot_reads_off_the_files(filmed: Path) -> None:
    """info.json declares each camera as LeRobot's writer would after probing the first episode's file with its own
    encoder settings (LeRobot's defaults: `humanoid.encoding.ENCODER`)."""
    default = VideoEncoderConfig()
    assert {key: getattr(default, key) for key in ENCODER} == ENCODER
    info = json.loads((filmed / INFO_PATH).read_text())
    assert info["video_path"] == VIDEO_PATH
    for camera, size in (("head", DEFAULT_SIZE), ("tracking", (48, 64))):
        feature = info["features"][columns.image_key(camera)]
        assert feature["dtype"] == "video" and feature["shape"] == [*size, 3]
        assert feature["info"] == get_video_info(video_path(filmed, camera, 0), default)


def test_lerobot_loads_every_frame_at_its_timestamp(filmed: Path) -> None:
    """One video frame per data frame, frame i at i / fps, and LeRobot decodes each camera at the first and the last
    frame of every episode (its timestamp tolerance is 0.1 ms) as the MCAP's image of that row."""
    dataset = LeRobotDataset("local/filmed", root=filmed, video_backend="pyav")
    assert dataset.meta.video_keys == [columns.image_key("head"), columns.image_key("tracking")]
    lengths = read_episodes(filmed)["length"].to_pylist()
    start = 0
    for episode, length in enumerate(lengths):
        for camera in ("head", "tracking"):
            with av.open(str(video_path(filmed, camera, episode))) as container:
                stream = container.streams.video[0]
                times = [float(frame.pts * stream.time_base) for frame in container.decode(stream)]
            np.testing.assert_allclose(times, np.arange(length) / dataset.fps, atol=1e-9)
            images = mcap_images(filmed / f"mcap/episode_{episode:06d}.mcap", camera)
            for row in (0, length - 1):
                frame = dataset[start + row][columns.image_key(camera)].permute(1, 2, 0).numpy()
                assert np.abs(frame - images[row] / 255.0).mean() < 0.03
        start += length


def mcap_images(path: Path, camera: str) -> list[np.ndarray]:
    """Every image of `camera` in the MCAP file at `path`, decoded (an independent reader: mcap, protobuf, PIL)."""
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        topic = IMAGE_TOPIC.format(name=camera)
        return [np.asarray(Image.open(io.BytesIO(m.data))) for *_, m in reader.iter_decoded_messages(topics=[topic])]


def test_the_mcap_carries_each_camera_with_its_calibration_and_frame(filmed: Path) -> None:
    """Per row: one JPEG per camera that decodes to its size, its calibration (the pinhole of MuJoCo's field of view),
    and its optical frame in /tf."""
    model = humanoid_model()
    length = read_episodes(filmed)["length"].to_pylist()[0]
    counts: Counter[str] = Counter()
    with (filmed / "mcap/episode_000000.mcap").open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, message in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            if channel.topic == TF_TOPIC:
                assert {camera_frame("head"), camera_frame("tracking")} <= {
                    t.child_frame_id for t in message.transforms
                }
            for camera in parse_cameras(CAMERAS_FLAG):
                if channel.topic == CALIBRATION_TOPIC.format(name=camera.name):
                    np.testing.assert_allclose(message.K, intrinsics(model, camera).reshape(-1))
                    assert (message.height, message.width, message.frame_id) == (
                        *camera.size,
                        camera_frame(camera.name),
                    )
    for camera in parse_cameras(CAMERAS_FLAG):
        images = mcap_images(filmed / "mcap/episode_000000.mcap", camera.name)
        assert len(images) == length and images[0].shape == (*camera.size, 3)
        assert counts[CALIBRATION_TOPIC.format(name=camera.name)] == length
    assert counts[TF_TOPIC] == length


def test_image_statistics_are_lerobots() -> None:
    """The frames LeRobot samples (which, how downsampled) and its per-channel statistics in [0, 1], (3, 1, 1)."""
    for length in (1, 50, 120, 1000, 20_000):
        assert stats_indices(length).tolist() == compute_stats.sample_indices(length)
    large = np.random.default_rng(0).integers(0, 256, (480, 640, 3), np.uint8)
    np.testing.assert_array_equal(
        stats_view(large), compute_stats.auto_downsample_height_width(large.transpose(2, 0, 1))
    )
    samples = np.random.default_rng(1).integers(0, 256, (7, 3, 12, 16), np.uint8)
    ours = image_stats(samples)
    theirs = compute_stats.get_feature_stats(samples / 255.0, axis=(0, 2, 3), keepdims=True)
    for name in ("min", "max", "mean", "std", "count"):
        np.testing.assert_allclose(ours[name], theirs[name].reshape(ours[name].shape), rtol=1e-12)
    for name in ("q01", "q50", "q99"):
        np.testing.assert_allclose(ours[name], theirs[name].reshape(ours[name].shape), atol=0.01)


def test_the_dataset_statistics_hold_each_camera(filmed: Path) -> None:
    """stats.json holds each camera's statistics, per channel in [0, 1], over the frames LeRobot samples."""
    stats = json.loads((filmed / "meta/stats.json").read_text())
    for camera in ("head", "tracking"):
        camera_stats = stats[columns.image_key(camera)]
        assert np.array(camera_stats["mean"]).shape == (3, 1, 1)
        assert 0.0 <= np.min(camera_stats["min"]) < np.max(camera_stats["max"]) <= 1.0
        assert camera_stats["count"] == [len(stats_indices(STEPS))]


def test_a_dataset_keeps_one_set_of_cameras(filmed: Path, tmp_path: Path) -> None:
    """Appending with other cameras (none, or another size) is refused in one line and nothing on disk changes."""
    root = tmp_path / "dataset"
    shutil.copytree(filmed, root)
    before = snapshot(root)
    for cameras in ("", "head", "head:48x64,tracking:48x64"):
        with pytest.raises(DatasetError, match="recorded with cameras head:96x128,tracking:48x64") as refused:
            record_short(root, episodes=1, max_steps=20, cameras=cameras)
        assert "\n" not in str(refused.value)
    assert snapshot(root) == before


def test_merge_carries_the_cameras(filmed: Path, tmp_path: Path) -> None:
    """A dataset merged alone is the recorder's own, file for file, videos and MCAP images included."""
    merged = tmp_path / "merged"
    assert merge_cli(["--shards", str(filmed), "--dataset", str(merged), "--progress", "false"]) == 0
    ours, theirs = snapshot(merged), snapshot(filmed)
    files = [name for name in theirs if not name.startswith("recordings")]
    assert [name for name in files if name.startswith("videos/")]
    assert {name: ours[name] for name in files} == {name: theirs[name] for name in files}


def test_export_carries_the_cameras(filmed: Path, tmp_path: Path) -> None:
    """`make export FORMAT=lerobot-command`'s copy holds the same videos and LeRobot loads their frames."""
    out = tmp_path / "exported"
    assert export_cli(["--format", "lerobot-command", "--dataset", str(filmed), "--out", str(out)]) == 0
    for episode in (0,):
        assert video_path(out, "head", episode).read_bytes() == video_path(filmed, "head", episode).read_bytes()
    dataset = LeRobotDataset("local/exported", root=out, video_backend="pyav")
    assert dataset[len(dataset) - 1][columns.image_key("tracking")].shape == (3, 48, 64)


def test_kill_9_mid_episode_with_cameras_loses_at_most_that_episode(tmp_path: Path) -> None:
    """SIGKILL to the recorder and its writer while cameras record: the committed episodes load with their videos,
    no video of an uncommitted one stays, and the next recording continues."""
    root = tmp_path / "dataset"
    recorder = start_recording(root, 100, "--cameras", "head:32x48")
    wait_for_episodes(root, 2, recorder, timeout=120)
    os.killpg(recorder.pid, signal.SIGKILL)
    recorder.wait()
    survived = committed_episodes(root)
    assert_consistent(root, survived)
    record_short(root, episodes=1, max_steps=30, cameras="head:32x48")
    assert_consistent(root, survived + 1)
    videos = sorted((root / "videos").rglob("*.mp4"))
    assert len(videos) == survived + 1
    LeRobotDataset("local/resumed", root=root, video_backend="pyav")[len(read_episodes(root)) - 1]


def test_lerobot_train_trains_act_on_the_cameras(filmed: Path, tmp_path: Path) -> None:
    """`lerobot-train --policy.type=act` reads the cameras (a ResNet-18 backbone, no pretrained weights offline)."""
    result = run_lerobot_train(filmed, tmp_path, "local/filmed", 2, "--policy.pretrained_backbone_weights=null")
    assert result.returncode == 0, (result.stdout + result.stderr)[-4000:]
    config = json.loads(next((tmp_path / "outputs").rglob("train_config.json")).read_text())
    assert columns.image_key("head") in config["policy"]["input_features"]


def test_the_live_view_streams_each_camera() -> None:
    """`LIVE=1 CAMERAS=...`: a Foxglove client subscribed to a camera gets its image of every step, the JPEG the
    episode records, and the camera's optical frame in /tf."""
    cameras = parse_cameras("head:32x48")
    env = make_env(40)
    live = LivePublisher(env, port=0, cameras=cameras)
    try:
        with connect(f"ws://127.0.0.1:{live.port}", subprotocols=SUBPROTOCOLS, open_timeout=10) as client:
            json.loads(client.recv(timeout=10))  # serverInfo
            advertised: list[dict] = []
            while len(advertised) < 6:
                message = json.loads(client.recv(timeout=10))
                advertised += message.get("channels", []) if message["op"] == "advertise" else []
            ids = {channel["topic"]: channel["id"] for channel in advertised}
            topics = [IMAGE_TOPIC.format(name="head"), CALIBRATION_TOPIC.format(name="head"), TF_TOPIC]
            subscriptions = [{"id": i, "channelId": ids[topic]} for i, topic in enumerate(topics)]
            client.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
            time.sleep(0.5)  # the server has the subscription before the first step
            buffer = EpisodeBuffer(env, 40, cameras)
            episode = run_episode(env, make_controller("expert", env), 0, buffer=buffer, observer=live)
            received: dict[int, list[bytes]] = {i: [] for i in range(len(topics))}
            while True:
                try:
                    data = client.recv(timeout=2)
                except TimeoutError:
                    break
                if isinstance(data, bytes) and data[0] == MESSAGE_DATA:
                    received[struct.unpack_from("<I", data, 1)[0]].append(data[13:])
    finally:
        live.close()
        env.close()
    images = [CompressedImage.FromString(payload) for payload in received[0]]
    assert [image.data for image in images] == episode.cameras["head"].images
    assert len(received[1]) == episode.length
    frames = {t.child_frame_id for t in FrameTransforms.FromString(received[2][0]).transforms}
    assert camera_frame("head") in frames


def test_inspect_checks_each_camera_and_draws_a_contact_sheet(filmed: Path, tmp_path: Path) -> None:
    """`make inspect` verifies every episode's frames per camera and draws a contact sheet; a video a frame short is
    found and named."""
    root = tmp_path / "dataset"
    shutil.copytree(filmed, root)
    report = inspect(InspectConfig(dataset=root, plot=True, plot_path=tmp_path / "inspect.png", lerobot=False))
    assert any(line.startswith("cameras: head, tracking") for line in report.verified)
    assert report.contact_sheet is not None and Image.open(report.contact_sheet).size[0] > 500
    short = Av1Stream(*DEFAULT_SIZE, 67)
    for _ in range(STEPS - 1):
        short.add(np.zeros((*DEFAULT_SIZE, 3), np.uint8))
    video_path(root, "head", 0).write_bytes(short.finish())
    with pytest.raises(DatasetError, match=f"holds {STEPS - 1} frames of observation.images.head for {STEPS}"):
        inspect(InspectConfig(dataset=root, lerobot=False))


def test_the_head_camera_sits_at_the_head_and_looks_ahead_and_down() -> None:
    """At the start: the head camera's optical frame is at the torso's origin plus its offset, its z axis along the
    heading 20 degrees down; the tracking camera's z axis points at the body."""
    env = make_env()
    env.reset(seed=0)
    model, data = model_and_data(env)
    rig = CameraRig(model, parse_cameras("head:32x48,tracking:32x48"))
    try:
        (frame, position, orientation), (_, tracked, tracking) = rig.frames(data)
    finally:
        rig.close()
        env.close()
    torso = data.body(CAMERAS["head"].body)
    yaw = np.arctan2(torso.xmat[3], torso.xmat[0])
    offset = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]) @ [0.1, 0, 0.19]
    np.testing.assert_allclose(position, torso.xpos + offset, atol=1e-6)
    axes = np.empty(9)
    mujoco.mju_quat2Mat(axes, orientation)
    view = axes.reshape(3, 3)[:, 2]
    pitch = np.radians(CAMERAS["head"].elevation)
    np.testing.assert_allclose(
        view, [np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], atol=1e-6
    )
    assert frame.shape == (32, 48, 3) and frame.std() > 0
    mujoco.mju_quat2Mat(axes, tracking)
    toward = torso.xpos - tracked
    assert np.dot(axes.reshape(3, 3)[:, 2], toward / np.linalg.norm(toward)) > 0.95


def test_two_workers_record_the_cameras_one_process_records(tmp_path: Path) -> None:
    """Rendered and encoded in the simulation workers, the cameras of a parallel recording are the one process's,
    file for file; the dataset's statistics aggregate the episodes' per channel."""
    for name, workers in (("one", 1), ("two", 2)):
        record_short(tmp_path / name, episodes=2, max_steps=40, cameras="head:32x48", workers=workers, writer="process")
    ours, theirs = snapshot(tmp_path / "two"), snapshot(tmp_path / "one")
    assert len([name for name in ours if name.startswith("videos/")]) == 2
    assert {k: v for k, v in ours.items() if "recordings" not in k} == {
        k: v for k, v in theirs.items() if "recordings" not in k
    }
    stats = json.loads((tmp_path / "two/meta/stats.json").read_text())[columns.image_key("head")]
    assert stats["count"] == [2 * len(stats_indices(40))] and np.array(stats["std"]).shape == (3, 1, 1)
