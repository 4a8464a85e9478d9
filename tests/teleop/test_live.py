"""`LIVE=1`: a WebSocket client speaking Foxglove's protocol watches a recording on loopback."""

from __future__ import annotations

import json
import os
import re
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from websockets.sync.client import connect

from common import columns
from evaluation.evaluate import cli as evaluate_cli
from humanoid.env import make_env
from rollout.episode import EpisodeBuffer
from support import MESSAGE_DATA, SUBPROTOCOLS, read_mcap_episode
from teachers.expert import LQRExpert
from teleop.dataset_reader import read_episodes, read_frames
from teleop.keyboard import TeleopSession
from teleop.mcap_io.schema import Step
from teleop.record import cli as record_cli
from teleop.store import DatasetSpec, EpisodeStore

pytestmark = pytest.mark.slow  # a recorder process and a client: seconds


@pytest.fixture(scope="module")
def watched(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict, list[dict], dict[int, list]]:
    """A recording with LIVE on (any free port, loopback) and what a client got: serverInfo, channels, messages.

    3 episodes of at most 400 steps, 864 in all (seed 1 falls at step 64): the client subscribes while the recorder
    still builds its controller, and the episodes after the first (one after a fall) check the live episode index."""
    root = tmp_path_factory.mktemp("live") / "dataset"
    command = [sys.executable, "-m", "teleop.record", "--dataset", str(root), "--episodes", "3", "--noise", "0"]
    command += ["--max-steps", "400"]
    command += ["--live", "true", "--live-port", "0", "--writer", "inline", "--progress", "false"]
    recorder = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, env={**os.environ, "HF_HUB_OFFLINE": "1"})
    try:
        port = None
        for line in recorder.stderr:
            found = re.search(r"live view: ws://127\.0\.0\.1:(\d+)", line)
            if found:
                port = int(found.group(1))
                break
        assert port, "the recorder did not say where the live view is"
        received: dict[int, list] = {1: [], 2: []}
        with connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS, open_timeout=10) as client:
            info = json.loads(client.recv(timeout=10))
            advertised: list[dict] = []
            while len(advertised) < 4:
                message = json.loads(client.recv(timeout=10))
                advertised += message.get("channels", []) if message["op"] == "advertise" else []
            ids = {channel["topic"]: channel["id"] for channel in advertised}
            subscriptions = [{"id": 1, "channelId": ids["/tf"]}, {"id": 2, "channelId": ids["/step"]}]
            client.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
            deadline = time.monotonic() + 120
            while recorder.poll() is None and time.monotonic() < deadline:
                try:
                    data = client.recv(timeout=0.5)
                except TimeoutError:
                    continue
                except Exception:  # the server stopped with the recorder
                    break
                if isinstance(data, bytes) and data[0] == MESSAGE_DATA:
                    subscription, log_time = struct.unpack_from("<IQ", data, 1)
                    received[subscription].append((log_time, data[13:]))
        assert recorder.wait(timeout=120) == 0, recorder.stderr.read()
    finally:
        if recorder.poll() is None:
            recorder.kill()
    return root, info, advertised, received


def test_the_server_speaks_foxglove_and_advertises_the_mcap_topics(watched: tuple) -> None:
    _, info, advertised, _ = watched
    assert info["op"] == "serverInfo" and info["name"] == "humanoid-bc"
    topics = {channel["topic"]: channel for channel in advertised}
    assert set(topics) == {"/scene", "/step", "/tf", "/command"}
    assert topics["/tf"]["schemaName"] == "foxglove.FrameTransforms" and topics["/tf"]["encoding"] == "protobuf"
    assert topics["/step"]["schemaName"] == "humanoid_bc.Step"


def test_live_poses_equal_the_simulations_at_those_steps(watched: tuple) -> None:
    """Each /tf message a client got holds the body poses of its step (named by the /step at the same time),
    bit for bit the poses the episode's MCAP file stores for that step."""
    root, _, _, received = watched
    steps = {log_time: Step.FromString(payload) for log_time, payload in received[2]}
    recorded = [read_mcap_episode(root / row[columns.EPISODE_MCAP]) for row in read_episodes(root).to_pylist()]
    compared = 0
    for log_time, payload in received[1]:
        if log_time not in steps:
            continue
        step = steps[log_time]
        transforms = FrameTransforms.FromString(payload).transforms
        episode = recorded[step.episode_index]
        position = [(t.translation.x, t.translation.y, t.translation.z) for t in transforms]
        orientation = [(t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z) for t in transforms]
        np.testing.assert_array_equal(position, episode.body_position[step.frame_index])
        np.testing.assert_array_equal(orientation, episode.body_orientation[step.frame_index])
        assert [t.child_frame_id for t in transforms] == episode.body_frames
        compared += 1
    assert compared >= 100, f"only {compared} steps seen live"


def test_a_port_out_of_range_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    code = evaluate_cli(["--policy", "expert", "--episodes", "1", "--live", "true", "--live-port", "70000"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "--live-port" in err[0]


def test_a_port_in_use_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Another server on the port: the evaluation stops before its first episode, and the recorder before it opens
    the dataset, saying why in one line."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        live = ["--live", "true", "--live-port", str(port)]
        codes = [
            evaluate_cli(["--policy", "expert", "--episodes", "1", *live]),
            record_cli(["--dataset", str(tmp_path / "dataset"), "--writer", "inline", "--progress", "false", *live]),
        ]
    err = capsys.readouterr().err.strip().splitlines()
    assert codes == [1, 1] and len(err) == 2 and not (tmp_path / "dataset").exists()
    assert all(f"cannot serve the live view on 127.0.0.1:{port}" in line for line in err)


class Seen:
    """A StepObserver that keeps what it was shown (rows of the rollout's buffer)."""

    def __init__(self) -> None:
        self.seeds: list[int] = []
        self.heights: list[float] = []

    def episode_started(self, seed: int) -> None:
        self.seeds.append(seed)

    def step(self, buffer: EpisodeBuffer, t: int) -> None:
        self.heights.append(float(buffer.observation[t, 0]))


def test_keyboard_sessions_show_every_step_they_record(tmp_path: Path) -> None:
    """The keyboard's session passes each recorded step to its observer, the one LIVE=1 gives it."""
    env = make_env(40)
    store = EpisodeStore(tmp_path / "dataset", DatasetSpec.from_env(env))
    seen = Seen()
    session = TeleopSession(env, LQRExpert(env.unwrapped.model), store, 7, 1, 0.0, lambda committed: None, seen)
    session.press("enter")
    while session.recording:
        session.tick()
    store.close()
    frames = read_frames(tmp_path / "dataset", [columns.OBS_ENV_STATE])
    assert seen.seeds == [7] and len(seen.heights) == 40
    assert seen.heights == frames[columns.OBS_ENV_STATE][:, 0].tolist()  # root z, the first privileged entry
