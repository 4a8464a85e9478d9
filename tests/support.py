"""Helpers the tests share: small constants, file snapshots, a decoder of every MCAP topic, TensorBoard text.

Importable as `support` because pytest puts `tests/` on the path (its conftest lives there).
"""

from __future__ import annotations

import contextlib
import json
import os
import pty
import re
import select
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from common import columns
from common.cli import flag
from common.columns import PUSH_NAMES
from humanoid.conditions import ActionLatency
from humanoid.env import humanoid_model, make_env
from humanoid.sensors import ObservationSplit
from policies import checkpoint
from policies.mlp import MLPPolicy, MLPSpec
from task.command_fields import COMMAND_NAMES
from teachers.base import Teacher
from teachers.expert import LQRExpert
from teachers.registry import TEACHERS
from teleop.dataset_reader import STEP_FIELDS, read_episodes, read_frames
from teleop.mcap_io.writer import COMMAND_TOPIC, METADATA_NAME, SCENE_TOPIC, STEP_TOPIC, TF_TOPIC
from teleop.record import STANDING, RecordConfig, main

SHORT_EPISODE = 80  # steps: long enough for noise to matter, short enough to keep the suite fast

STANDING_FLAGS = [word for name, value in STANDING.items() for word in (flag(name), str(value))]
"""The same as `make record`'s flags."""

SMALL_BC = {"inputs": "full", "hidden": 32, "epochs": 5, "min_updates": 0, "eval_episodes": 0, "progress": False}
"""A small BC training on the 3-episode standing recording, on the full observation: 5 passes exactly."""

TINY_PPO = {
    "curriculum": "",
    "randomize": "none",
    "latency_share": 0.0,
    "obs_noise_share": 0.0,
    "envs": 4,
    "workers": 2,
    "rollout_steps": 256,
    "batch_size": 64,
    "epochs": 2,
    "eval_freq": 256,
    "eval_episodes": 1,
    "floor_episodes": 1,
    "final_eval_episodes": 1,
    "progress": False,
}
"""`FinetuneConfig` settings of the PPO tests' runs: 256-step rollouts over 2 worker processes, unpushed on the nominal
task (the curriculum and the randomisation have tests of their own), an evaluation of one episode after each."""


@contextlib.contextmanager
def one_core() -> Iterator[None]:
    """This process on one core for the block (its affinity narrowed, as `taskset` would): a training's torch threads,
    one per core, beside the other test process on two cores ran several times slower."""
    cores = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(cores)})
    try:
        yield
    finally:
        os.sched_setaffinity(0, cores)


# Foxglove's WebSocket protocol (serverInfo, advertise, subscribe, binary message data) under both of its
# names, as the Foxglove app offers it: foxglove-sdk 0.30.3 accepts only the newer name, foxglove.sdk.v1,
# and answers a client offering foxglove.websocket.v1 alone with HTTP 400.
SUBPROTOCOLS = ["foxglove.websocket.v1", "foxglove.sdk.v1"]
MESSAGE_DATA = 0x01  # binary opcode: subscription id (uint32), log time (uint64), payload


def untrained_checkpoint(folder: Path, poison: bool = False) -> Path:
    """A freshly initialised policy saved as a checkpoint; `poison` makes its output NaN."""
    policy = MLPPolicy(
        MLPSpec(("observation.state", "observation.environment_state"), 348, 17, hidden=(8,)),
        -0.4 * np.ones(17),
        0.4 * np.ones(17),
    )
    if poison:
        with torch.no_grad():
            policy.net[-1].bias.fill_(float("nan"))
    checkpoint.save(policy, folder, {}, {})
    return folder


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under `root` with its content: equal snapshots mean nothing on disk changed."""
    if root.is_file():
        return {str(root): root.read_bytes()}
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def join_observation(state: np.ndarray, environment_state: np.ndarray) -> np.ndarray:
    """The gymnasium observation from its two stored parts: the entries placed by their recorded names."""
    return ObservationSplit(humanoid_model()).join(state, environment_state)


@dataclass
class McapEpisode:
    """The decoded content of one episode's MCAP file."""

    metadata: dict[str, str]
    attachments: dict[str, bytes]
    step_times_ns: np.ndarray  # (T,) log times of the /step messages
    steps: dict[str, np.ndarray]  # Step fields, one row per step
    tf_times_ns: np.ndarray  # (T,)
    body_position: np.ndarray  # (T, bodies, 3)
    body_orientation: np.ndarray  # (T, bodies, 4), w-x-y-z like MuJoCo
    body_frames: list[str]
    scene_entities: list[str]  # frame ids of the /scene entities
    tasks: list[str]  # the /step messages' task strings
    command_times_ns: np.ndarray  # (T,) log times of the /command messages
    command: np.ndarray  # (T, len(COMMAND_NAMES)) float64
    push: np.ndarray  # (T, len(PUSH_NAMES)) float64
    command_tasks: list[str]  # the /command messages' task strings


def read_mcap_episode(path: Path) -> McapEpisode:
    """Decode every message of `path` (which must be a finished MCAP file, with its summary)."""
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        metadata = {record.name: dict(record.metadata) for record in reader.iter_metadata()}
        attachments = {record.name: bytes(record.data) for record in reader.iter_attachments()}
        step_times, tf_times, steps, positions, orientations, frames, entities = [], [], [], [], [], [], []
        tasks, command_times, commands, pushes, command_tasks = [], [], [], [], []
        topics = [STEP_TOPIC, TF_TOPIC, SCENE_TOPIC, COMMAND_TOPIC]
        for _, channel, message, decoded in reader.iter_decoded_messages(topics=topics):
            if channel.topic == STEP_TOPIC:
                step_times.append(message.log_time)
                steps.append({name: getattr(decoded, name) for name in STEP_FIELDS})
                tasks.append(decoded.task)
            elif channel.topic == COMMAND_TOPIC:
                command_times.append(message.log_time)
                commands.append([getattr(decoded, name) for name in COMMAND_NAMES])
                pushes.append([getattr(decoded, name) for name in PUSH_NAMES])
                command_tasks.append(decoded.task)
            elif channel.topic == TF_TOPIC:
                tf_times.append(message.log_time)
                frames = [t.child_frame_id for t in decoded.transforms]
                positions.append([(t.translation.x, t.translation.y, t.translation.z) for t in decoded.transforms])
                orientations.append(
                    [(t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z) for t in decoded.transforms]
                )
            else:
                entities += [entity.frame_id for entity in decoded.entities]
    return McapEpisode(
        metadata=metadata.get(METADATA_NAME, {}),
        attachments=attachments,
        step_times_ns=np.array(step_times, np.int64),
        steps={name: np.array([step[name] for step in steps], dtype) for name, dtype in STEP_FIELDS.items()},
        tf_times_ns=np.array(tf_times, np.int64),
        body_position=np.array(positions, np.float64),
        body_orientation=np.array(orientations, np.float64),
        body_frames=frames,
        scene_entities=entities,
        tasks=tasks,
        command_times_ns=np.array(command_times, np.int64),
        command=np.array(commands, np.float64).reshape(-1, len(COMMAND_NAMES)),
        push=np.array(pushes, np.float64).reshape(-1, len(PUSH_NAMES)),
        command_tasks=command_tasks,
    )


def mcap_parameters(path: Path) -> dict[str, object]:
    """The drawn physical parameters in the MCAP metadata record of episode file `path` (JSON text, decoded)."""
    return {name: json.loads(text) for name, text in columns.drawn_parameters(read_mcap_episode(path).metadata).items()}


STATUS_LINE = re.compile(rb"REC seed \d+ t +([0-9.]+) s([^\r\n]*)")
"""The recorder's status line: its simulated time, and the rest (the command in force)."""


def status_lines(output: bytes) -> list[tuple[float, bytes]]:
    """Every recorder status line in a session's `output`: (its simulated time, the rest of it)."""
    return [(float(at), shown) for at, shown in STATUS_LINE.findall(output)]


SESSION_PACE = 3.0
"""The tests' keyboard sessions run at 3 simulated seconds a second (`--pace`): their keys land at simulated times
(`Terminal.wait_until_simulated`), so the pace changes only how long a session takes."""


class Terminal:
    """A command behind a pseudo-terminal, as a person at a TTY would run it (the recorder in keyboard mode)."""

    def __init__(self, command: list[str]) -> None:
        self.master, slave = pty.openpty()
        self.process = subprocess.Popen(command, stdin=slave, stdout=slave, stderr=slave, close_fds=True)
        os.close(slave)
        self.output = b""

    def read_for(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            if select.select([self.master], [], [], 0.05)[0]:
                try:
                    self.output += os.read(self.master, 1 << 16)
                except OSError:  # the command exited and closed the terminal
                    return

    def wait_for(self, text: bytes, timeout: float = 60) -> None:
        deadline = time.monotonic() + timeout
        while text not in self.output:
            assert time.monotonic() < deadline, self.output.decode(errors="replace")[-2000:]
            self.read_for(0.1)

    def press(self, keys_: str, then_wait: float) -> None:
        os.write(self.master, keys_.encode())
        self.read_for(then_wait)

    def simulated(self) -> float:
        """The simulated time the status line shows last (s; 0 before it shows one)."""
        lines = status_lines(self.output)
        return lines[-1][0] if lines else 0.0

    def shown_at(self, text: bytes, timeout: float = 60) -> float:
        """The simulated time of the first status line that shows `text` (a key's command landed by then), waiting
        for one."""
        deadline = time.monotonic() + timeout
        while not (times := [at for at, shown in status_lines(self.output) if text in shown]):
            assert self.process.poll() is None, self.output.decode(errors="replace")[-2000:]
            assert time.monotonic() < deadline, self.output.decode(errors="replace")[-2000:]
            self.read_for(0.05)
        return times[0]

    def wait_until_simulated(self, seconds: float) -> None:
        """Until the recorder's status line shows the episode `seconds` in (simulated time: on a busy machine the
        session runs slower than the clock, never faster, so keys pressed after it land no earlier than that; the line
        read lags the session, by a few tenths of a simulated second at 3x pace, so they may land that much later:
        `shown_at` says where they did)."""
        deadline = time.monotonic() + 120.0 + 10.0 * seconds  # a session that stalls fails, it does not hang
        while not (times := [at for at, _ in status_lines(self.output)]) or times[-1] < seconds:
            assert self.process.poll() is None, self.output.decode(errors="replace")[-2000:]
            assert len(times) < 2 or times[-1] >= times[-2], "the episode ended (a fall): time went back"
            assert time.monotonic() < deadline, self.output.decode(errors="replace")[-2000:]
            self.read_for(0.05)


def lerobot_train_command(dataset: Path, output_dir: Path, repo_id: str, steps: int, *flags: str) -> list[str]:
    """A CPU run of a small ACT for `steps` steps; nothing from the Hub, no wandb, a checkpoint at the last step;
    `flags` added."""
    return [
        str(Path(sys.executable).parent / "lerobot-train"),
        f"--dataset.repo_id={repo_id}",
        f"--dataset.root={dataset}",
        "--policy.type=act",
        "--policy.device=cpu",
        "--policy.push_to_hub=false",
        "--wandb.enable=false",
        f"--output_dir={output_dir}",
        f"--steps={steps}",
        f"--save_freq={steps}",
        "--log_freq=1",
        "--batch_size=2",
        "--num_workers=0",
        # Small enough to train in a fraction of a second; ACT with no camera builds no ResNet.
        "--policy.chunk_size=10",
        "--policy.n_action_steps=10",
        "--policy.dim_model=64",
        "--policy.n_heads=2",
        "--policy.dim_feedforward=128",
        "--policy.n_encoder_layers=1",
        "--policy.n_vae_encoder_layers=1",
        *flags,
    ]


def run_lerobot_train(dataset: Path, work: Path, repo_id: str, steps: int, *flags: str) -> subprocess.CompletedProcess:
    """`lerobot-train` (`lerobot_train_command`) in a subprocess in `work`, every cache under it, the checkpoint in
    `work`/outputs (which must not exist yet: lerobot-train refuses an existing one unless resuming)."""
    env = {
        **os.environ,
        "HF_HUB_OFFLINE": "1",
        "HF_DATASETS_OFFLINE": "1",
        "HF_HOME": str(work / "hf"),
        "HF_DATASETS_CACHE": str(work / "hf-datasets"),
        "HF_LEROBOT_HOME": str(work / "lerobot"),
        "WANDB_MODE": "disabled",
    }
    command = lerobot_train_command(dataset, work / "outputs", repo_id, steps, *flags)
    return subprocess.run(command, cwd=work, env=env, capture_output=True, text=True, timeout=300)


def record_short(root: Path, **settings: object) -> None:
    """`make record`'s recording (no recordings.jsonl line) into `root` in this process: the standing recipe
    (`STANDING`), the writer inline and no progress bar, unless `settings` say otherwise."""
    main(RecordConfig(**{"dataset": root, "writer": "inline", "progress": False, **STANDING, **settings}))


def drawn_delay(seed: int, share: float = 0.5) -> int:
    """The delay `ActionLatency` at `share` draws for `seed`, outside any recording."""
    env = ActionLatency(make_env(), 1, share)
    try:
        env.reset(seed=seed)
        return env.delay
    finally:
        env.close()


def committed_episodes(root: Path) -> int:
    return json.loads((root / "meta/info.json").read_text())["total_episodes"]


def assert_consistent(root: Path, episodes: int) -> None:
    """LeRobot loads `episodes` episodes, every frame counted once, every MCAP file readable and matching."""
    dataset = LeRobotDataset("local/crashed", root=root)
    frames = read_frames(root, ["episode_index", "index", columns.ACTION])
    assert dataset.meta.total_episodes == episodes
    assert len(dataset) == len(frames["index"])
    np.testing.assert_array_equal(frames["index"], np.arange(len(frames["index"])))
    np.testing.assert_array_equal(np.unique(frames["episode_index"]), np.arange(episodes))
    for row in read_episodes(root).to_pylist():
        mcap = read_mcap_episode(root / row[columns.EPISODE_MCAP])
        np.testing.assert_array_equal(
            mcap.steps["action"], frames[columns.ACTION][frames["episode_index"] == row["episode_index"]]
        )


def assert_no_leftovers(root: Path, episodes: int) -> None:
    """After a recovery: one data, episode row and MCAP file per episode, and statistics over exactly those.

    (Before it, stats.json may still count the episode a kill interrupted: it is written just before
    info.json, and the next recording rebuilds it.)
    """
    stats = json.loads((root / "meta/stats.json").read_text())
    assert stats["index"]["count"] == [json.loads((root / "meta/info.json").read_text())["total_frames"]]
    for folder in ("data", "meta/episodes", "mcap"):
        assert len([p for p in (root / folder).rglob("*") if p.is_file()]) == episodes, folder


def tensorboard_text(folder: Path, tag: str) -> str:
    """The text written under `tag` (the first, if several) in the TensorBoard event files in `folder`."""
    events = EventAccumulator(str(folder), size_guidance={"tensors": 0})
    events.Reload()
    return events.Tensors(f"{tag}/text_summary")[0].tensor_proto.string_val[0].decode()


def scalars(folder: Path, tag: str) -> list[tuple[int, float]]:
    """(step, value) of every scalar written under `tag` in the TensorBoard event files in `folder`; [] if none."""
    events = EventAccumulator(str(folder), size_guidance={"scalars": 0})
    events.Reload()
    if tag not in events.Tags()["scalars"]:
        return []
    return [(event.step, event.value) for event in events.Scalars(tag)]


def start_recording(root: Path, episodes: int, *flags: str) -> subprocess.Popen:
    """`python -m teleop.record` (one worker and the writer process, unless `flags` say otherwise) of 150-step
    episodes in a process group of its own."""
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "teleop.record",
            "--dataset",
            str(root),
            "--episodes",
            str(episodes),
            "--max-steps",
            "150",
            "--progress",
            "false",
            "--workers",
            "1",
            *STANDING_FLAGS,
            *flags,
        ],
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )


def wait_for_episodes(root: Path, count: int, process: subprocess.Popen, timeout: float = 60) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if (root / "meta/info.json").exists() and committed_episodes(root) >= count:
            return
        assert process.poll() is None, process.stderr.read().decode()
        time.sleep(0.01)
    raise TimeoutError(f"fewer than {count} episodes after {timeout} s")


class RayCluster:
    """A Ray cluster on 127.0.0.1 of a 1-CPU head and `worker_nodes` 1-CPU worker nodes (`tests/ray_cluster.py`).

    With one CPU per node and none held by the driver, each of N workers lands on a node of its own.
    """

    def __init__(self, worker_nodes: int = 1) -> None:
        script = Path(__file__).with_name("ray_cluster.py")
        self.process = subprocess.Popen(
            [sys.executable, str(script), str(worker_nodes)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
        self.address = self._answer("address ")

    def _answer(self, prefix: str) -> str:
        """The rest of the script's next line that starts with `prefix` (Ray may print lines of its own)."""
        for line in self.process.stdout:
            if line.startswith(prefix):
                return line.removeprefix(prefix).strip()
        raise RuntimeError(f"the Ray cluster process ended (exit code {self.process.wait()})")

    def remove_worker_node(self) -> None:
        """Kill every process of the last worker node at once, as a lost machine."""
        self.process.stdin.write("remove\n")
        self.process.stdin.flush()
        self._answer("removed")

    def shutdown(self) -> None:
        self.process.stdin.close()
        self.process.wait(timeout=60)


class StandingWalker(LQRExpert):
    """A toy teacher: the LQR expert, declared to walk. It stands through a walk, so walking schedules record cheaply
    (a registered walker plans 55 ms an action). A class of its own module, so that worker processes, which are sent
    the class (`rollout.controllers.built`), import it."""

    name = "toy-walker"
    walks = True


@contextlib.contextmanager
def registered(teacher: type[Teacher]) -> Iterator[type[Teacher]]:
    """`teacher` in `teachers.registry.TEACHERS` for the block, as one line of the registry would put it."""
    assert teacher.name not in TEACHERS
    TEACHERS[teacher.name] = teacher
    try:
        yield teacher
    finally:
        del TEACHERS[teacher.name]


class FailingTeacher(LQRExpert):
    """A toy teacher that fails: on the episode of seed `FAILING_SEED` its action raises at step `FAILING_STEP`."""

    name = "toy-failing"
    FAILING_SEED = 1
    FAILING_STEP = 5

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self.failing, self.steps = seed == self.FAILING_SEED, 0

    def act(self, obs: np.ndarray) -> np.ndarray:
        self.steps += 1
        if self.failing and self.steps > self.FAILING_STEP:
            raise RuntimeError("no balanced pose: the iteration is not making good progress")
        return super().act(obs)
