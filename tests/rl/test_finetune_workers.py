"""`make finetune-rl` ends with the same weights however it runs: over 1 or 2 worker processes or Ray actors on two
nodes; on 1 or 2 update threads, to float rounding.

Apart from `test_finetune.py` and `test_finetune_resume.py` so that the two test processes of `make test` share PPO's
tests (each takes whole files).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from policies import checkpoint
from rl.finetune import FinetuneConfig, main
from support import TINY_PPO, RayCluster

pytestmark = pytest.mark.slow  # `make test-fast` leaves this module out (seconds per test)


def final_actors(bc_policy: Path, tmp_path: Path, settings: list[dict]) -> list[dict[str, torch.Tensor]]:
    """The last actors of 512-step TINY_PPO runs (their last periodic checkpoints), one per entry of `settings`.

    Not the actor kept: that may be step 0's, the BC policy itself, which would prove nothing.
    """
    actors = []
    for index, overrides in enumerate(settings):
        main(
            FinetuneConfig(
                bc_policy=bc_policy,
                policy=tmp_path / f"ppo_{index}",
                timesteps=512,
                **{**TINY_PPO, **overrides},
            )
        )
        actors.append(checkpoint.load(tmp_path / f"ppo_{index}" / "checkpoints" / "step_00000512").state_dict())
    return actors


def assert_same_trained_actor(actors: list[dict[str, torch.Tensor]], bc_policy: Path) -> None:
    """Bit-identical actors, which PPO did change (so their equality is not the BC policy's)."""
    assert actors[0].keys() == actors[1].keys()
    for name, value in actors[0].items():
        assert torch.equal(value, actors[1][name]), name
    assert not torch.equal(actors[0]["net.0.weight"], checkpoint.load(bc_policy).state_dict()["net.0.weight"])


TWO_WORKERS = {"envs": 8, "workers": 2, "critic_warmup": 256}
"""8 environments over 2 local worker processes of 4: the run the other ways of running it must equal."""


@pytest.fixture(scope="module")
def two_workers_actor(bc_policy: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, torch.Tensor]:
    """The last actor of the TWO_WORKERS run (one run for the two tests that compare with it)."""
    (actor,) = final_actors(bc_policy, tmp_path_factory.mktemp("two_workers"), [TWO_WORKERS])
    return actor


def test_worker_count_changes_nothing_but_speed(
    bc_policy: Path, tmp_path: Path, two_workers_actor: dict[str, torch.Tensor]
) -> None:
    """8 environments in 1 process or in 2 workers of 4 end the same run with the same weights, bit for bit."""
    (one_process,) = final_actors(bc_policy, tmp_path, [{**TWO_WORKERS, "workers": 1}])
    assert_same_trained_actor([one_process, two_workers_actor], bc_policy)


def test_ray_workers_give_the_local_weights(
    bc_policy: Path, tmp_path: Path, ray_cluster: RayCluster, two_workers_actor: dict[str, torch.Tensor]
) -> None:
    """BACKEND=ray: 2 actors on 2 nodes of 4 environments each end the run with the local workers' weights."""
    ray = {**TWO_WORKERS, "backend": "ray", "ray_address": ray_cluster.address}
    (on_ray,) = final_actors(bc_policy, tmp_path, [ray])
    assert_same_trained_actor([on_ray, two_workers_actor], bc_policy)


def test_update_threads_change_nothing_but_float_rounding(bc_policy: Path, tmp_path: Path) -> None:
    """PPO's updates on 1 or 2 torch threads end with the same weights to float rounding: how torch splits a
    product over threads may change its summation order on some processors (bit for bit on others)."""
    settings = [{"batch_size": 256, "update_threads": threads, "critic_warmup": 0} for threads in (1, 2)]
    one, two = final_actors(bc_policy, tmp_path, settings)
    assert one.keys() == two.keys()
    for name, value in one.items():
        torch.testing.assert_close(two[name], value, rtol=1e-4, atol=1e-6, msg=name)
    assert not torch.equal(one["net.0.weight"], checkpoint.load(bc_policy).state_dict()["net.0.weight"])
