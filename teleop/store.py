"""A dataset folder as the recorder writes it: a LeRobot v3.0 dataset and one MCAP file per episode.

    DATASET/
      meta/, data/            LeRobot v3.0 (see teleop.lerobot_io.writer)
      mcap/episode_000000.mcap

An episode is written in the order parquet -> MCAP -> info.json; the last step commits it, so a
kill at any moment leaves the committed episodes readable in both formats, and the next `open`
removes the rest. Episodes a parallel recording finished but had not committed yet wait in the
spool (`teleop.spool`); the next `open` commits them. A recorder holds an exclusive lock on the
folder while it appends; a second one refuses. Episodes recorded with domain randomisation carry
their draw as episode columns (`columns.RANDOMIZATION_PREFIX`); a dataset holds either none or the
same ones in every episode (LeRobot loads episode rows of one schema only), so a store for other
parameters than the dataset's refuses to open. `WriterProcess` runs a store in a child process,
so that writing overlaps with simulation instead of stalling it.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Protocol

import gymnasium as gym
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

from common import columns
from common.cli import DatasetError
from humanoid.cameras import Camera, intrinsics
from humanoid.conditions import SCALE_SUFFIX, Randomization
from humanoid.env import (
    ENV_ID,
    LEROBOT_FPS,
    ROBOT_TYPE,
    actuator_names,
    body_names,
    mjcf_path,
    model_and_data,
    step_duration_ns,
)
from humanoid.sensors import ObservationSplit, privileged_names, proprioception_names
from rollout.episode import Episode
from task.command_fields import COMMAND_NAMES
from teleop.lerobot_io.format import cameras_spec, check_destination, video_feature
from teleop.lerobot_io.writer import LeRobotWriter
from teleop.mcap_io.writer import calibration, scene_update, write_episode_mcap
from teleop.seeds import next_free
from teleop.spool import Spool

log = logging.getLogger(__name__)

MCAP_DIR = "mcap"
STATE_NAMES_METADATA = "state_names"  # the MCAP metadata entry naming each entry of /step's `state` (JSON list)


def mcap_name(episode_index: int) -> str:
    return f"episode_{episode_index:06d}.mcap"


@dataclass(frozen=True)
class DatasetSpec:
    """What the environment fixes about a dataset: features, rates, bodies and the model."""

    features: dict
    body_frames: list[str]
    scene: SceneUpdate
    step_ns: int
    mjcf: bytes
    split: ObservationSplit
    parameters: tuple[str, ...] = ()
    """The physical parameters every episode's draw holds (`Randomization.parameters`); () for none."""
    cameras: tuple[Camera, ...] = ()
    """The cameras every episode records (`humanoid.cameras`); () for none."""
    calibrations: tuple[CameraCalibration, ...] = ()
    """Each camera's calibration for the MCAP (`teleop.mcap_io.writer.calibration`)."""

    @classmethod
    def from_env(cls, env: gym.Env, parameters: tuple[str, ...] = (), cameras: tuple[Camera, ...] = ()) -> DatasetSpec:
        """The spec of datasets recorded in `env`, whose episodes draw `parameters` (domain randomisation) and record
        `cameras`."""
        model, _ = model_and_data(env)
        sensed, privileged = proprioception_names(model), privileged_names(model)
        actions = actuator_names(model)
        commands = list(COMMAND_NAMES)
        flag = {"dtype": "bool", "shape": (1,), "names": None}
        features = {
            columns.OBS_STATE: {"dtype": "float64", "shape": (len(sensed),), "names": sensed},
            columns.OBS_ENV_STATE: {"dtype": "float64", "shape": (len(privileged),), "names": privileged},
            columns.ACTION: {"dtype": "float32", "shape": (len(actions),), "names": actions},
            columns.EXECUTED_ACTION: {"dtype": "float32", "shape": (len(actions),), "names": actions},
            columns.OBS_COMMAND: {"dtype": "float32", "shape": (len(commands),), "names": commands},
            columns.SETPOINT: {"dtype": "float32", "shape": (len(commands),), "names": commands},
            columns.PUSH: {"dtype": "float32", "shape": (len(columns.PUSH_NAMES),), "names": list(columns.PUSH_NAMES)},
            columns.REWARD: {"dtype": "float64", "shape": (1,), "names": None},
            columns.DONE: flag,
            columns.TERMINATED: flag,
            columns.TRUNCATED: flag,
            **{columns.image_key(camera.name): video_feature(*camera.size, LEROBOT_FPS) for camera in cameras},
        }
        frames = body_names(model)
        scene = scene_update(model, frames)
        mjcf = mjcf_path(env).read_bytes()
        return cls(
            features,
            frames,
            scene,
            step_duration_ns(env),
            mjcf,
            ObservationSplit(model),
            parameters,
            cameras,
            tuple(calibration(camera.name, intrinsics(model, camera), *camera.size) for camera in cameras),
        )


@dataclass(frozen=True)
class CommittedEpisode:
    """What the progress bar and the summary report about an episode once it is on disk."""

    index: int
    seed: int
    length: int
    episode_return: float
    fell: bool


class EpisodeSink(Protocol):
    """Where the recorder sends finished episodes: an `EpisodeStore` here, or a `WriterProcess`."""

    num_episodes: int

    def wait_ready(self) -> None: ...
    def seeds(self) -> list[int]: ...
    def submit(self, episode: Episode) -> list[CommittedEpisode]: ...
    def close(self) -> list[CommittedEpisode]: ...


def _lock(root: Path) -> int:
    """An exclusive lock on the dataset folder itself (no lock file to leave behind), or DatasetError."""
    handle = os.open(root, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(handle)
        raise DatasetError(f"another recorder is writing to {root}; wait for it to finish") from None
    return handle


class EpisodeStore:
    """Appends episodes to one dataset folder, holding its lock until `close`."""

    def __init__(self, root: Path, spec: DatasetSpec) -> None:
        check_destination(root)
        try:
            root.mkdir(parents=True, exist_ok=True)
            self._lock = _lock(root)
        except OSError as error:
            raise DatasetError(f"cannot write to {root}: {error.strerror or error}") from None
        try:
            self.lerobot = LeRobotWriter.open(root, spec.features, LEROBOT_FPS, ROBOT_TYPE)
            (root / MCAP_DIR).mkdir(exist_ok=True)
        except OSError as error:
            self.close()
            raise DatasetError(f"cannot write to {root}: {error.strerror or error}") from None
        except BaseException:
            self.close()
            raise
        self.root = root
        self.spec = spec
        if len(self.lerobot.episode_column(columns.EPISODE_FINAL_STATE)) != self.num_episodes:
            self.close()
            # Its episode rows lack the final observation's columns; LeRobot loads rows of one set of columns only.
            raise DatasetError(
                f"{root} was recorded before episodes kept their final observation; record into a new dataset"
            )
        self._remove_uncommitted_mcap()
        # The parameters the dataset's episodes draw; None while it has none (the first episode decides).
        self._parameters: frozenset[str] | None = self._drawn_parameters() if self.num_episodes else None
        self.spool = Spool(root)
        self.spool.recover(self.num_episodes)
        recovered = self.commit_spool()
        if recovered:
            log.warning(
                "%s: committed %d episodes an interrupted parallel recording had finished (seeds %s)",
                root,
                len(recovered),
                ", ".join(str(e.seed) for e in recovered),
            )
        try:
            self._check_parameters(frozenset(spec.parameters))
        except DatasetError:
            self.close()
            raise

    @property
    def num_episodes(self) -> int:
        return self.lerobot.total_episodes

    def seeds(self) -> list[int]:
        """The seeds of the committed episodes, in episode order."""
        return list(self.lerobot.episode_column(columns.EPISODE_SEED))

    def next_seed(self) -> int:
        """One past the largest seed recorded so far (0 for a new dataset): appending never repeats one."""
        return next_free(self.seeds())

    def prepare(self) -> None:
        """Do the first episode's one-time set-up now, while the recorder waits for that episode."""
        self.lerobot.prepare()

    def append(self, episode: Episode, spooled: Path | None = None) -> CommittedEpisode:
        """Write `episode` to both formats and commit it; `spooled` is its spool file, removed exactly once."""
        state, environment_state = self.spec.split(episode.observation)
        final_state, final_environment_state = self.spec.split(episode.final_observation)
        frame_columns = {
            columns.OBS_STATE: state,
            columns.OBS_ENV_STATE: environment_state,
            columns.ACTION: episode.action,
            columns.EXECUTED_ACTION: episode.executed_action,
            columns.OBS_COMMAND: episode.command,
            columns.SETPOINT: episode.setpoint,
            columns.PUSH: episode.push,
            columns.REWARD: episode.reward,
            columns.DONE: episode.terminated | episode.truncated,
            columns.TERMINATED: episode.terminated,
            columns.TRUNCATED: episode.truncated,
        }
        drawn = {columns.RANDOMIZATION_PREFIX + name: value for name, value in episode.parameters.items()}
        self._check_parameters(frozenset(episode.parameters))
        if list(episode.cameras) != [camera.name for camera in self.spec.cameras]:
            raise DatasetError(
                f"{self.root} records cameras {cameras_spec(self.spec.features) or 'none'}, this episode has "
                f"{', '.join(episode.cameras) or 'none'}"
            )
        videos = {columns.image_key(name): (track.video, track.stats) for name, track in episode.cameras.items()}
        index = self.num_episodes
        mcap_path = Path(MCAP_DIR) / mcap_name(index)
        facts = {
            columns.EPISODE_SEED: episode.seed,
            columns.EPISODE_CONTROLLER: episode.controller,
            columns.EPISODE_LABELLER: episode.labeller,
            columns.EPISODE_DAGGER_ROUND: episode.dagger_round,
            columns.EPISODE_NOISE_STD: float(episode.noise_std),
            columns.EPISODE_RETURN: episode.episode_return,
            columns.EPISODE_TERMINATED: bool(episode.terminated[-1]),
            columns.EPISODE_TRUNCATED: bool(episode.truncated[-1]),
            columns.EPISODE_MCAP: str(mcap_path),
        }
        final = {
            columns.EPISODE_FINAL_STATE: final_state.tolist(),
            columns.EPISODE_FINAL_ENV_STATE: final_environment_state.tolist(),
        }
        metadata = {
            "episode_index": str(index),
            "env_id": ENV_ID,
            "step_duration_ns": str(self.spec.step_ns),
            STATE_NAMES_METADATA: json.dumps(self.spec.features[columns.OBS_STATE]["names"]),
            **{key: str(value) for key, value in facts.items() if key != columns.EPISODE_MCAP},
            **{key: json.dumps(value) for key, value in drawn.items()},
        }
        try:
            staged = self.lerobot.stage(frame_columns, episode.tasks, {**facts, **final, **drawn}, videos)
            write_episode_mcap(
                self.root / mcap_path,
                episode,
                state,
                final_state,
                index,
                self.spec.scene,
                self.spec.body_frames,
                self.spec.step_ns,
                metadata,
                self.spec.mjcf,
                self.spec.calibrations,
            )
            committing = self.spool.begin_commit(spooled, index) if spooled else None
            self.lerobot.commit(staged)
            if committing:
                committing.unlink()
        except OSError as error:  # disk full, folder removed...: the episode stays uncommitted
            raise DatasetError(f"writing episode {index} to {self.root} failed: {error.strerror or error}") from None
        return CommittedEpisode(index, episode.seed, episode.length, episode.episode_return, episode.fell)

    def commit_spool(self) -> list[CommittedEpisode]:
        """Commit every episode waiting in the spool, in seed order."""
        committed = [self.append(Spool.load(path), spooled=path) for path in self.spool.ready()]
        self.spool.remove_if_empty()
        return committed

    def wait_ready(self) -> None:
        """Nothing to wait for: the store is open once constructed (see `WriterProcess`)."""

    def submit(self, episode: Episode) -> list[CommittedEpisode]:
        """Append `episode` now; the `EpisodeSink` interface."""
        return [self.append(episode)]

    def close(self) -> list[CommittedEpisode]:
        """Release the lock (idempotent); committed episodes are complete on disk at any time."""
        if self._lock >= 0:
            os.close(self._lock)
            self._lock = -1
        return []

    def _drawn_parameters(self) -> frozenset[str]:
        """The drawn parameters of the last committed episode, from its metadata row's columns."""
        return frozenset(columns.drawn_parameters(dict.fromkeys(self.lerobot.last_episode_columns())))

    def _check_parameters(self, parameters: frozenset[str]) -> None:
        """DatasetError unless episodes drawing `parameters` fit the dataset's (any do while it is empty)."""
        if self._parameters is None:
            self._parameters = parameters
        elif parameters != self._parameters:
            raise DatasetError(
                f"{self.root} holds episodes {_randomised(self._parameters)}, these would be "
                f"{_randomised(parameters)}: a dataset does not mix them (LeRobot loads episode rows "
                "with one set of columns only); use another dataset folder"
            )

    def _remove_uncommitted_mcap(self) -> None:
        for path in (self.root / MCAP_DIR).glob("episode_*.mcap"):
            if int(path.stem.removeprefix("episode_")) >= self.num_episodes:
                path.unlink()


def _randomised(parameters: frozenset[str]) -> str:
    """How episodes drawing `parameters` were recorded, for a message: "with mass, friction randomised"."""
    if not parameters:
        return "without domain randomisation"
    order = [spec.name + SCALE_SUFFIX for spec in fields(Randomization)]
    names = sorted(parameters, key=lambda name: (order.index(name) if name in order else len(order), name))
    return f"with {', '.join(name.removesuffix(SCALE_SUFFIX) for name in names)} randomised"
