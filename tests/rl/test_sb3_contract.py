"""stable-baselines3 is pinned to the minor version whose PPO loop `rl.rollouts` follows.

`WorkerRolloutPPO.collect_rollouts` re-implements SB3's `OnPolicyAlgorithm.collect_rollouts` with the
sampling moved into the workers, and the PPO pieces use a few of SB3's protected members. A new SB3
may change any of them silently; these tests fail loudly instead, naming what to re-check.
"""

from __future__ import annotations

import ast
import hashlib
import inspect
import textwrap
import tomllib
from collections.abc import Callable
from pathlib import Path

import pytest
import stable_baselines3
from packaging.requirements import Requirement
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecEnv

PYPROJECT = Path(__file__).resolve().parents[2] / "pyproject.toml"

# Code fingerprints (AST, so comments and formatting do not count) of stable-baselines3 2.9.
FOLLOWED = {
    # mirrored step by step by WorkerRolloutPPO.collect_rollouts
    OnPolicyAlgorithm.collect_rollouts: "a36c095c92776d63",
    # overridden by BCActorCriticPolicy._build (it rebuilds the optimiser over the real parameters)
    ActorCriticPolicy._build: "935be32e94c74d41",
    # protected members the rollouts and the vectorised environment call
    BaseAlgorithm._update_info_buffer: "68fab443ce03ade2",
    BaseAlgorithm._update_learning_rate: "7423094eca3ca1f1",
    VecEnv._reset_seeds: "31b9220e8c578427",
    VecEnv._reset_options: "043de0d3106453c3",
    VecEnv._get_indices: "7a04444b1c9a25a0",
    VecEnv.seed: "6b050dc4ebaa103d",
    # what a resumed run relies on (rl.resume): learn(reset_num_timesteps=False) keeps the step counter
    # and the last observations it is given, and only then makes fresh episode-statistics buffers
    BaseAlgorithm._setup_learn: "3a571e660e230d68",
    OnPolicyAlgorithm.learn: "8fc8d0b1fa9d316a",
}


def fingerprint_source(source: str) -> str:
    return hashlib.sha256(ast.dump(ast.parse(textwrap.dedent(source))).encode()).hexdigest()[:16]


def fingerprint(function: Callable) -> str:
    return fingerprint_source(inspect.getsource(function))


def test_fingerprint_ignores_layout_and_comments_but_not_code() -> None:
    plain = "def f(x):\n    return x + 1\n"
    laid_out = "def f(x):  # a comment\n    return (\n        x + 1\n    )\n"
    changed = "def f(x):\n    return x - 1\n"
    assert fingerprint_source(plain) == fingerprint_source(laid_out)
    assert fingerprint_source(plain) != fingerprint_source(changed)


def test_installed_version_is_the_pinned_minor() -> None:
    """pyproject.toml admits exactly one SB3 minor version, and it is the installed one."""
    dependencies = tomllib.loads(PYPROJECT.read_text())["project"]["dependencies"]
    (requirement,) = [Requirement(d) for d in dependencies if Requirement(d).name == "stable-baselines3"]
    major, minor = (int(part) for part in stable_baselines3.__version__.split(".")[:2])
    assert requirement.specifier.contains(stable_baselines3.__version__)
    assert not requirement.specifier.contains(f"{major}.{minor + 1}.0")
    assert not requirement.specifier.contains(f"{major}.{minor - 1}.99")


@pytest.mark.parametrize("function", list(FOLLOWED), ids=lambda f: f.__qualname__)
def test_followed_sb3_code_is_unchanged(function: Callable) -> None:
    assert fingerprint(function) == FOLLOWED[function], (
        f"stable-baselines3's {function.__qualname__} changed: re-check rl/rollouts.py, rl/vec_env.py and "
        "policies/actor_critic.py against it, then update its fingerprint here and the pin in pyproject.toml"
    )
