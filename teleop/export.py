"""`make export FORMAT=minari|lerobot-command DATASET=... OUT=...`: a recorded dataset in another library's format.

`minari`: Farama's Minari is the offline-RL format d3rlpy and others read. The export writes a new Minari
datasets root at OUT (the folder `MINARI_DATASETS_PATH` points at), holding one dataset,
`humanoid-bc/<DATASET's folder name>-v0`:

    DATASET (LeRobot frames + final observations) --read_transitions--> T+1 observations, T actions
        --minari.create_dataset_from_buffers--> OUT/humanoid-bc/<name>-v0 (Arrow storage)

so `minari.load_dataset(id)` serves (o_t, a_t, r_t, o_t+1) for every step, and
`recover_environment()` gives Humanoid-v5. The reference scores that normalise returns come from
the random and the expert controllers, rolled out here on the same held-out seeds (1000 on). Where an operator
commanded anything, each observation is a Dict of the gymnasium observation and the command in force. Why
Arrow, and what Minari does with fewer observations than it needs: docs/how-to/minari.md.

`lerobot-command`: a copy of DATASET as a LeRobot v3.0 dataset whose `observation.state` ends with the operator's
command (`command.<field>`, `task.command_fields`), in place of `observation.command`: LeRobot's own policies
read only `observation.state` and `observation.environment_state`, so this is how `lerobot-train` conditions one on
the command (docs/how-to/lerobot-train.md). Written by this project's LeRobot writer, statistics included.
"""

from __future__ import annotations

import os
import shutil
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

from common import columns, paths
from common.cli import DatasetError, UserError, check_positive, run_cli, setting
from common.files import PARTIAL_SUFFIX
from common.seed_ranges import EVAL_SEED
from humanoid.env import ENV_ID, make_env
from rollout.controllers import make_controller
from rollout.episode import EpisodeBuffer, run_episode
from task.command_fields import COMMAND_FIELDS, COMMAND_NAMES
from teleop.dataset_reader import (
    Transitions,
    read_commanded_frames,
    read_episodes,
    read_info,
    read_transitions,
    read_videos,
)
from teleop.lerobot_io.format import DEFAULT_FEATURES, INFO_PATH, TASKS_PATH, video_keys

MINARI = "minari"
LEROBOT_COMMAND = "lerobot-command"
FORMATS = (MINARI, LEROBOT_COMMAND)
NAMESPACE = "humanoid-bc"
COMMAND_STATE_NAMES = tuple(f"command.{name}" for name in COMMAND_NAMES)
"""The names of the command's entries at the end of `observation.state` in a `lerobot-command` copy."""
# The columns of an episode row LeRobot's writer fills itself (`teleop.lerobot_io.writer.LeRobotWriter.stage`).
_LEROBOT_EPISODE_COLUMNS = (
    "episode_index",
    "tasks",
    "length",
    "data/chunk_index",
    "data/file_index",
    "dataset_from_index",
    "dataset_to_index",
    "meta/episodes/chunk_index",
    "meta/episodes/file_index",
)


@dataclass
class ExportConfig:
    """Settings of one export."""

    dataset: Path = setting(paths.DATASET, "recorded dataset to export (left unchanged)")
    out: Path | None = setting(
        None,
        "new folder to write (must not exist): a Minari datasets root (minari) or a LeRobot dataset "
        "(lerobot-command); default: exports/FORMAT",
    )
    format: str = setting(
        MINARI,
        "the format to write: minari (offline RL), or lerobot-command (a copy whose observation.state ends with the "
        "operator's command, for lerobot-train)",
        choices=FORMATS,
    )
    reference_episodes: int = setting(10, "episodes of the random and expert controllers for the reference scores")


def dataset_id(dataset: Path) -> str:
    return f"{NAMESPACE}/{dataset.resolve().name}-v0"


def out_folder(cfg: ExportConfig) -> Path:
    """OUT, or exports/FORMAT."""
    return Path("exports") / cfg.format if cfg.out is None else cfg.out


def commanded(transitions: list[Transitions]) -> bool:
    """Whether an operator commanded anything (a command other than the zero one, standing, in some frame)."""
    return any(t.commands.any() for t in transitions)


def observation_space(with_command: bool) -> gym.spaces.Space:
    """Humanoid-v5's observation space; with the command, a Dict of it ("observation") and the command's
    ("command": `COMMAND_NAMES` within the fields' limits), as goal-conditioned Minari datasets nest theirs."""
    env = make_env()
    try:
        space = env.observation_space
    finally:
        env.close()
    if not with_command:
        return space
    low, high = (np.array([getattr(field, bound) for field in COMMAND_FIELDS], np.float32) for bound in ("low", "high"))
    return gym.spaces.Dict({"observation": space, "command": gym.spaces.Box(low, high, dtype=np.float32)})


def to_minari(transitions: list[Transitions], with_command: bool = False) -> list:
    """Minari's episode buffers: T+1 observations (with the command in force, if `with_command`), T actions,
    rewards, terminations and truncations each."""
    from minari.data_collector import EpisodeBuffer as MinariEpisode  # noqa: PLC0415 - minari loads h5py/arrow; only export needs it

    return [
        MinariEpisode(
            id=index,
            observations={"observation": t.observations, "command": t.commands} if with_command else t.observations,
            actions=t.actions,
            rewards=t.rewards.tolist(),
            terminations=t.terminated.tolist(),
            truncations=t.truncated.tolist(),
        )
        for index, t in enumerate(transitions)
    ]


def validate(cfg: ExportConfig) -> None:
    check_positive(cfg, "reference_episodes")
    if not (cfg.dataset / INFO_PATH).is_file():
        raise DatasetError(f"no recorded dataset at {cfg.dataset} (no {INFO_PATH})")
    what = "a Minari datasets root" if cfg.format == MINARI else "a LeRobot dataset"
    if out_folder(cfg).exists():
        raise UserError(f"{out_folder(cfg)} exists; OUT must be a new folder ({what})")
    if out_folder(cfg).resolve().is_relative_to(cfg.dataset.resolve()):
        raise UserError(f"OUT {out_folder(cfg)} lies inside DATASET {cfg.dataset}, left unchanged: give another")
    read_info(cfg.dataset)  # readable, before any work


def main(cfg: ExportConfig) -> str:
    """Export as configured; returns the Minari dataset id, or the folder of the LeRobot copy."""
    validate(cfg)
    if cfg.format == LEROBOT_COMMAND:
        to_lerobot_command(cfg.dataset, out_folder(cfg))
        return str(out_folder(cfg))
    return export_minari(cfg)


def mean_return(controller: str, episodes: int, seed: int) -> float:
    """The mean return of the registered `controller` over `episodes` episodes from `seed` on: a reference score."""
    env = make_env()
    try:
        acting, buffer = make_controller(controller, env), EpisodeBuffer(env, env.spec.max_episode_steps)
        returns = [
            run_episode(env, acting, each, buffer=buffer).episode_return for each in range(seed, seed + episodes)
        ]
    finally:
        env.close()
    return float(np.mean(returns))


def export_minari(cfg: ExportConfig) -> str:
    """The Minari export (module docstring); returns the dataset id."""
    transitions = read_transitions(cfg.dataset)
    if not transitions:
        raise DatasetError(f"{cfg.dataset} holds no episodes")
    with_command = commanded(transitions)
    buffers = to_minari(transitions, with_command)
    scores = {
        "ref_min_score": mean_return("random", cfg.reference_episodes, EVAL_SEED),
        "ref_max_score": mean_return("expert", cfg.reference_episodes, EVAL_SEED),
    }
    import minari  # noqa: PLC0415 - minari loads h5py/arrow; only export needs it

    name = dataset_id(cfg.dataset)
    # Minari writes into a hidden staging root beside OUT, renamed at the end: OUT appears complete or not at all.
    out = out_folder(cfg)
    staging = out.with_name(f".{out.name}{PARTIAL_SUFFIX}")
    shutil.rmtree(staging, ignore_errors=True)  # what a killed export of the same OUT left
    previous = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(staging.resolve())  # where Minari writes
    try:
        with warnings.catch_warnings():
            # Minari warns that no author e-mail and no separate evaluation env are given: neither exists here.
            warnings.filterwarnings("ignore", category=UserWarning, module="minari")
            minari.create_dataset_from_buffers(
                dataset_id=name,
                buffer=buffers,
                env=ENV_ID,
                observation_space=observation_space(with_command),
                algorithm_name="humanoid-bc recorder",
                author="humanoid-bc",
                description=f"{ENV_ID} episodes recorded by humanoid-bc into {cfg.dataset.resolve()}",
                data_format="arrow",
                **scores,
            )
        staging.rename(out)
    finally:
        if previous is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = previous
        shutil.rmtree(staging, ignore_errors=True)
    return name


def to_lerobot_command(dataset: Path, out: Path) -> None:
    """Write the `lerobot-command` copy of `dataset` (module docstring) to the new folder `out`, through a hidden
    staging folder beside it: `out` appears complete or not at all. The episode rows keep this project's columns (the
    final observation's state extended by the last frame's command) but the MCAP path: the MCAP files stay with
    `dataset`. DatasetError if no frame holds a command other than zero: there would be nothing to condition on."""
    from teleop.lerobot_io.writer import LeRobotWriter  # noqa: PLC0415 - pandas and datasets: only this format

    info = read_info(dataset)
    if columns.OBS_COMMAND not in info["features"]:
        raise DatasetError(f"{dataset} has no {columns.OBS_COMMAND} (a lerobot-command copy already?)")
    frames = read_commanded_frames(dataset)
    if not frames[columns.OBS_COMMAND].any():
        raise DatasetError(
            f"{dataset}'s command is zero in every frame (nothing was commanded): nothing to condition a policy on; "
            "lerobot-train reads the dataset as it is"
        )
    features = {key: ft for key, ft in info["features"].items() if key not in {*DEFAULT_FEATURES, columns.OBS_COMMAND}}
    cameras = video_keys(features)
    stored = read_videos(dataset)  # each episode's videos and their statistics, by key
    if columns.SETPOINT in features:  # laid out as today's command, as `command_columns` reads it
        setpoint = features[columns.SETPOINT]
        features[columns.SETPOINT] = {**setpoint, "shape": [len(COMMAND_NAMES)], "names": [*COMMAND_NAMES]}
    state = features[columns.OBS_STATE]
    features[columns.OBS_STATE] = {
        **state,
        "shape": [state["shape"][0] + len(COMMAND_NAMES)],
        "names": [*state["names"], *COMMAND_STATE_NAMES],
    }
    import pandas as pd  # noqa: PLC0415 - as above

    task_names = pd.read_parquet(dataset / TASKS_PATH).sort_values("task_index").index.to_numpy()
    staging = out.with_name(f".{out.name}{PARTIAL_SUFFIX}")
    shutil.rmtree(staging, ignore_errors=True)  # what a killed export of the same OUT left
    staging.parent.mkdir(parents=True, exist_ok=True)
    try:
        writer = LeRobotWriter.open(staging, features, info["fps"], info["robot_type"])
        for episode in read_episodes(dataset).to_pylist():
            rows = frames["episode_index"] == episode["episode_index"]
            command = frames[columns.OBS_COMMAND][rows]
            arrays = {key: frames[key][rows] for key in features if key not in cameras}
            arrays[columns.OBS_STATE] = np.hstack([arrays[columns.OBS_STATE], command])
            extra = {
                name: value
                for name, value in episode.items()
                if name not in _LEROBOT_EPISODE_COLUMNS and name != columns.EPISODE_MCAP
            }
            if columns.EPISODE_FINAL_STATE in extra:  # (datasets recorded before episodes kept it have none)
                extra[columns.EPISODE_FINAL_STATE] = [*extra[columns.EPISODE_FINAL_STATE], *command[-1].tolist()]
            tasks = task_names[frames["task_index"][rows].reshape(-1)]
            videos = {
                key: (path.read_bytes(), stats) for key, (path, stats) in stored[episode["episode_index"]].items()
            }
            extra = {name: value for name, value in extra.items() if not name.startswith("videos/")}
            writer.commit(writer.stage(arrays, tasks, extra, videos))
        staging.rename(out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def constant_fields(root: Path) -> list[str]:
    """The command's fields that hold one value in every frame of the dataset at `root`."""
    command = read_commanded_frames(root, [columns.OBS_COMMAND])[columns.OBS_COMMAND]
    return [name for name, column in zip(COMMAND_NAMES, command.T, strict=True) if (column == column[0]).all()]


def _main_and_print(cfg: ExportConfig) -> None:
    name = main(cfg)
    out = out_folder(cfg)
    if cfg.format == LEROBOT_COMMAND:
        never = constant_fields(cfg.dataset)
        note = (
            f"; {', '.join(never)} never change there (a LeRobot policy normalises them by a zero spread: keep them at "
            "their recorded value)"
            if never
            else ""
        )
        print(
            f"{out}: LeRobot dataset whose {columns.OBS_STATE} ends with the command ({', '.join(COMMAND_STATE_NAMES)})"
            f"{note}; train with lerobot-train --dataset.root={out} (docs/how-to/lerobot-train.md)"
        )
        return
    print(f"{out}: Minari dataset {name}; load it with MINARI_DATASETS_PATH={out} and minari.load_dataset({name!r})")


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, ExportConfig, argv, description=__doc__, prog="python -m teleop.export")


if __name__ == "__main__":
    sys.exit(cli())
