"""Resuming a PPO run where it stopped, kill -9 included, to the same final weights as an unbroken run.

A run writes into a fixed hidden folder beside its checkpoint (`policies.checkpoint.running`), and at
the start of every rollout (after the previous update) `Snapshots` replaces `resume.pt` there,
atomically, with everything the rest of the run depends on:

    learner:   policy and optimiser state dicts, step and update counters, the last observations,
               NumPy's, torch's and Python's global random states (minibatch order, ...)
    workers:   each environment's episode in progress, as its start and its actions since
               (`rl.vec_env`), and each sampler's noise streams
    callbacks: the validator's curve and best actor, the push curriculum's stage

Started again with the same settings, `rl.finetune` rebuilds the learner and the environments as
before and `restore`s the snapshot: the workers replay their episodes (and check that they arrive
where the saved ones were), and SB3 continues with `reset_num_timesteps=False`. What was computed
after the snapshot (part of a rollout, part of an update) is computed again, identically.
"""

from __future__ import annotations

import os
import random
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback

from common.files import write_atomically
from rl.curriculum import PushCurriculum
from rl.rollouts import WorkerRolloutPPO
from rl.validation import Validator
from rl.vec_env import WorkerGroupVecEnv

RESUME_FILE = "resume.pt"
# Settings that change how a run is shown or where its workers run, not what it computes: a resume may differ in
# them (a run stopped by a lost Ray worker can go on in local processes: the same worker split gives the same result).
PRESENTATION = ("progress", "overwrite", "backend", "ray_address")


def comparable(settings: dict[str, Any]) -> dict[str, Any]:
    """The settings two runs must share for one to continue the other."""
    return {name: value for name, value in settings.items() if name not in PRESENTATION}


def snapshot(
    model: WorkerRolloutPPO,
    env: WorkerGroupVecEnv,
    validator: Validator,
    settings: dict[str, Any],
    curriculum: PushCurriculum | None = None,
) -> dict[str, Any]:
    """Everything the rest of the run depends on, at a rollout's start (see the module)."""
    return {
        "settings": comparable(settings),
        "num_timesteps": model.num_timesteps,
        "n_updates": model._n_updates,
        "last_obs": model._last_obs,
        "last_episode_starts": model._last_episode_starts,
        "ep_info_buffer": list(model.ep_info_buffer or []),
        "ep_success_buffer": list(model.ep_success_buffer or []),
        "policy": model.policy.state_dict(),
        "optimizer": model.policy.optimizer.state_dict(),
        "rng": {"numpy": np.random.get_state(), "torch": torch.get_rng_state(), "python": random.getstate()},
        "workers": env.get_state(),
        "validator": {
            "curve": validator.curve,
            "best": validator.best,
            "best_state": validator.best_state,
            "next_at": validator.next_at,
        },
        "curriculum": None if curriculum is None else curriculum.get_state(),
    }


def save(folder: Path, state: dict[str, Any]) -> None:
    """Replace `folder/resume.pt` with `state`: a kill leaves the old file or the new one, never a part."""

    def write(partial: Path) -> None:
        with partial.open("wb") as stream:
            torch.save(state, stream)
            stream.flush()
            os.fsync(stream.fileno())  # the newest snapshot outlives a power cut, not only a kill

    write_atomically(folder / RESUME_FILE, write)


def load(folder: Path) -> dict[str, Any] | None:
    """The snapshot in `folder`, or None if there is none."""
    path = folder / RESUME_FILE
    if not path.is_file():
        return None
    # Our own file (NumPy arrays and random states beside tensors): not weights_only.
    return torch.load(path, weights_only=False)


def restore(
    state: dict[str, Any],
    model: WorkerRolloutPPO,
    env: WorkerGroupVecEnv,
    validator: Validator,
    curriculum: PushCurriculum | None = None,
) -> None:
    """Put a freshly built run where `state` was taken; `model.learn` then continues it (with `Snapshots`
    given the same `state`, which refills the episode statistics SB3 resets when learning starts)."""
    model.policy.load_state_dict(state["policy"])
    model.policy.optimizer.load_state_dict(state["optimizer"])
    model.num_timesteps, model._n_updates = state["num_timesteps"], state["n_updates"]
    model._last_obs, model._last_episode_starts = state["last_obs"], state["last_episode_starts"]
    model.ensure_samplers(env)  # before their noise streams are set
    env.set_state(state["workers"])
    validator.curve, validator.best = state["validator"]["curve"], state["validator"]["best"]
    validator.best_state, validator.next_at = state["validator"]["best_state"], state["validator"]["next_at"]
    if curriculum is not None:  # same settings, so the snapshot has its state
        curriculum.set_state(state["curriculum"])
    np.random.set_state(state["rng"]["numpy"])
    torch.set_rng_state(state["rng"]["torch"])
    random.setstate(state["rng"]["python"])


class Snapshots(BaseCallback):
    """Saves a snapshot at the start of every rollout (after the validator's turn: its evaluation is kept)."""

    def __init__(
        self,
        folder: Path,
        validator: Validator,
        settings: dict[str, Any],
        restored: dict[str, Any] | None = None,
        curriculum: PushCurriculum | None = None,
    ) -> None:
        super().__init__()
        self.folder, self.validator, self.settings = folder, validator, settings
        self.restored, self.curriculum = restored, curriculum

    def _on_training_start(self) -> None:
        if self.restored is not None:  # SB3's _setup_learn has just made fresh episode-statistics buffers
            self.model.ep_info_buffer.extend(self.restored["ep_info_buffer"])
            self.model.ep_success_buffer.extend(self.restored["ep_success_buffer"])

    def _on_rollout_start(self) -> None:
        save(
            self.folder,
            snapshot(self.model, self.training_env, self.validator, self.settings, self.curriculum),
        )

    def _on_step(self) -> bool:
        return True
