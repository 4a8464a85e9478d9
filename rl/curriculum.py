"""A curriculum of push sizes for PPO: the torso pushes of the training environments grow as the policy copes.

Trained straight at the size it should withstand, the policy spends most of its episodes falling early
and learns slowly (docs/decisions/curriculum.md). Here the training environments start at
the first stage's force and move to the next stage after a rollout in which at least `min_episodes`
training episodes ended and at least `advance` of those reached the time limit instead of falling.
The domain randomisation widens with the stages: stage k of K draws the physical parameters from
their ranges narrowed to k/(K-1) of their size about 1 (`Randomization.widened`), so the first stage
is the nominal body the demonstrations showed and the last the whole distribution; the shares of the
episodes run with the suite's action latency and sensor noise grow alike, from none. Trained on the
whole distribution from the start, the BC actor (with PPO's exploration noise) survived few of
its training episodes and no stage was ever passed (docs/decisions/curriculum.md).
A new stage applies to each
environment from its next episode (`TorsoPushes.set_force`, `DomainRandomization.set_width`,
`ActionLatency.set_latency_share`, `ObservationNoise.set_noise_share`), so every episode runs under one
stage and a resumed run replays it exactly. The stage never goes back.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv


def parse_stages(text: str) -> list[float]:
    """`text` ("10,20,40") as non-decreasing push forces in newtons, [] for 'none' or ''; ValueError naming
    --curriculum."""
    if text.strip() in ("", "none"):
        return []
    try:
        stages = [float(part) for part in text.split(",")]
    except ValueError:
        raise ValueError(
            f"--curriculum {text!r}: give push forces in newtons separated by commas, e.g. 10,20,40"
        ) from None
    if not all(0 <= force < float("inf") for force in stages):
        raise ValueError(f"--curriculum {text!r}: forces must be finite and >= 0")
    if any(later < earlier for earlier, later in zip(stages, stages[1:], strict=False)):
        raise ValueError(f"--curriculum {text!r}: forces must not decrease")
    return stages


def rollout_survival(dones: Any, infos: Sequence[Sequence[dict]]) -> tuple[int, int]:
    """(episodes ended, of which reached the time limit) in a rollout's `dones` (steps x envs) and SB3 infos."""
    ended = survived = 0
    for step_dones, step_infos in zip(dones, infos, strict=True):
        for done, info in zip(step_dones, step_infos, strict=True):
            if done:
                ended += 1
                survived += bool(info.get("TimeLimit.truncated", False))
    return ended, survived


def stage_width(stage: int, stages: int) -> float:
    """The randomisation's width at `stage` of `stages`: 0 at the first, 1 at the last (1 for a single stage)."""
    return stage / (stages - 1) if stages > 1 else 1.0


class PushCurriculum(BaseCallback):
    """Moves the training environments' push force through `stages` (see the module)."""

    def __init__(
        self, stages: Sequence[float], advance: float, min_episodes: int, widened: Mapping[str, float] | None = None
    ) -> None:
        """`widened`: the environments' methods the stage's width goes to, each times its value at the last stage,
        e.g. {"set_width": 1.0} (`DomainRandomization`), {"set_latency_share": 0.5} (`ActionLatency`)."""
        super().__init__()
        if not stages:
            raise ValueError("a curriculum needs at least one stage")
        # min_episodes: with 64 environments x 256 steps per rollout, about 16 episodes end in a rollout
        # where each lasts its 1,000 steps.
        self.stages, self.advance, self.min_episodes = list(stages), advance, min_episodes
        self.widened = dict(widened or {})
        self.stage = 0
        self.history: list[dict[str, float]] = []  # when each stage began: {"timesteps", "stage", "push"}

    @property
    def force(self) -> float:
        return self.stages[self.stage]

    @property
    def width(self) -> float:
        return stage_width(self.stage, len(self.stages))

    def apply(self, env: VecEnv) -> None:
        """Put `env`'s environments at this stage from their next episodes on."""
        env.env_method("set_force", self.force)
        for method, last in self.widened.items():
            env.env_method(method, self.width * last)

    def get_state(self) -> dict[str, Any]:
        return {"stage": self.stage, "history": list(self.history)}

    def set_state(self, state: dict[str, Any]) -> None:
        self.stage, self.history = state["stage"], list(state["history"])

    def _on_training_start(self) -> None:
        if not self.history:
            self.history.append(self._entry())
        # A resumed run's environments replayed their episodes under the stage they began in; new ones get this.
        self.apply(self.training_env)

    def _on_rollout_end(self) -> None:
        segment = self.locals["segment"]
        ended, survived = rollout_survival(segment.dones, segment.infos)
        self.logger.record("curriculum/stage", self.stage)
        self.logger.record("curriculum/push", self.force)
        if self.widened:
            self.logger.record("curriculum/randomization_width", self.width)
        if ended:
            self.logger.record("curriculum/rollout_survival", survived / ended)
        if self.ready(ended, survived):
            self.stage += 1
            self.history.append(self._entry())
            self.apply(self.training_env)

    def _entry(self) -> dict[str, float]:
        entry = {"timesteps": self.num_timesteps, "stage": self.stage, "push": self.force}
        return {**entry, "randomization_width": self.width} if self.widened else entry

    def ready(self, ended: int, survived: int) -> bool:
        """Whether a rollout that ended `ended` training episodes, `survived` at the time limit, moves the stage on."""
        last = self.stage == len(self.stages) - 1
        return not last and ended >= self.min_episodes and survived >= self.advance * ended

    def _on_step(self) -> bool:
        return True
