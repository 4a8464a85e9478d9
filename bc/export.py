"""`make export FORMAT=minari DATASET=... OUT=...`: a recorded dataset in another library's format.

Farama's Minari is the offline-RL format d3rlpy and others read. The export writes a new Minari
datasets root at OUT (the folder `MINARI_DATASETS_PATH` points at), holding one dataset,
`humanoid-bc/<DATASET's folder name>-v0`:

    DATASET (LeRobot frames + final observations) --read_transitions--> T+1 observations, T actions
        --minari.create_dataset_from_buffers--> OUT/humanoid-bc/<name>-v0 (Arrow storage)

so `minari.load_dataset(id)` serves (o_t, a_t, r_t, o_t+1) for every step, and
`recover_environment()` gives Humanoid-v5. The reference scores that normalise returns come from
the random and the expert controllers, rolled out here on the same seeds (`--seed` on). Why Arrow,
and what Minari does with fewer observations than it needs: docs/how-to/minari.md.
"""

from __future__ import annotations

import os
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from bc.evaluate import EVAL_SEED, evaluate
from common import paths
from common.cli import DatasetError, UserError, run_cli, setting
from humanoid.env import ENV_ID
from teleop.dataset_reader import Transitions, read_transitions
from teleop.lerobot_io.format import INFO_PATH

FORMATS = ("minari",)
NAMESPACE = "humanoid-bc"


@dataclass
class ExportConfig:
    """Settings of one export."""

    dataset: Path = setting(paths.DATASET, "recorded dataset to export (left unchanged)")
    out: Path = setting(Path("exports/minari"), "new folder to write: a Minari datasets root (must not exist)")
    format: str = setting("minari", "the format to write", choices=FORMATS)
    reference_episodes: int = setting(10, "episodes of the random and expert controllers for the reference scores")
    seed: int = setting(EVAL_SEED, "first seed of the reference episodes")


def dataset_id(dataset: Path) -> str:
    return f"{NAMESPACE}/{dataset.resolve().name}-v0"


def to_minari(transitions: list[Transitions]) -> list:
    """Minari's episode buffers: T+1 observations, T actions, rewards, terminations and truncations each."""
    from minari.data_collector import EpisodeBuffer as MinariEpisode  # noqa: PLC0415 - minari loads h5py/arrow; only export needs it

    return [
        MinariEpisode(
            id=index,
            observations=t.observations,
            actions=t.actions,
            rewards=t.rewards.tolist(),
            terminations=t.terminated.tolist(),
            truncations=t.truncated.tolist(),
        )
        for index, t in enumerate(transitions)
    ]


def validate(cfg: ExportConfig) -> None:
    if cfg.reference_episodes <= 0:
        raise UserError(f"--reference-episodes must be positive, got {cfg.reference_episodes}")
    if not (cfg.dataset / INFO_PATH).is_file():
        raise DatasetError(f"no recorded dataset at {cfg.dataset} (no {INFO_PATH})")
    if cfg.out.exists():
        raise UserError(f"{cfg.out} exists; OUT must be a new folder (a Minari datasets root)")


def main(cfg: ExportConfig) -> str:
    """Export as configured; returns the Minari dataset id."""
    validate(cfg)
    transitions = read_transitions(cfg.dataset)
    if not transitions:
        raise DatasetError(f"{cfg.dataset} holds no episodes")
    buffers = to_minari(transitions)
    scores = {
        "ref_min_score": evaluate("random", cfg.reference_episodes, cfg.seed)["mean_return"],
        "ref_max_score": evaluate("expert", cfg.reference_episodes, cfg.seed)["mean_return"],
    }
    import minari  # noqa: PLC0415 - minari loads h5py/arrow; only export needs it

    name = dataset_id(cfg.dataset)
    previous = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(cfg.out.resolve())  # where Minari writes: the new root
    try:
        with warnings.catch_warnings():
            # Minari warns that no author e-mail and no separate evaluation env are given: neither exists here.
            warnings.filterwarnings("ignore", category=UserWarning, module="minari")
            minari.create_dataset_from_buffers(
                dataset_id=name,
                buffer=buffers,
                env=ENV_ID,
                algorithm_name="humanoid-bc recorder",
                author="humanoid-bc",
                description=f"{ENV_ID} episodes recorded by humanoid-bc into {cfg.dataset.resolve()}",
                data_format="arrow",
                **scores,
            )
    finally:
        if previous is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = previous
    return name


def _main_and_print(cfg: ExportConfig) -> None:
    name = main(cfg)
    print(
        f"{cfg.out}: Minari dataset {name}; load it with MINARI_DATASETS_PATH={cfg.out} and "
        f"minari.load_dataset({name!r})"
    )


def cli(argv: Sequence[str] | None = None) -> int:
    return run_cli(_main_and_print, ExportConfig, argv, description=__doc__, prog="python -m bc.export")


if __name__ == "__main__":
    sys.exit(cli())
