"""Where a worker's CPU time goes beyond the simulation: a recording worker and a PPO sampling worker, stage by stage.

    .venv/bin/python -m bench.worker_overhead [--episodes 3] [--envs 32] [--steps 64] [--json FILE]

Why: on a 16-core machine recording reached 3.9x one worker and PPO's sampling 5.1x with 14 workers; what
a worker spends besides `mujoco.mj_step` is what more workers cannot hide. Everything runs in this process,
one thread, timed in CPU time (`time.process_time`), so a busy machine stretches the figures less than wall
time. Each stage is measured by running it alone on the same inputs (a replay of the same actions from
the same reset), never by a second copy of the workers' code:

- recording (`teleop.parallel.Simulator.run` + `teleop.spool.Spool.put`, what `_work` does per seed):
  the whole, then `env.step` replayed on the executed actions, `mj_step` alone on them, the controller
  replayed on the recorded observations, the spool write; the rest is the episode buffer and the loop.
- PPO (`_Share.sample`, what a worker runs per rollout): the whole, then `_Share.step` and a plain
  `env.step` loop replayed on the sampled actions, `mj_step` alone; the rest is the policy's forward
  pass, its noise and the records. The rollout's trip to the learner (pickling, as the pipe does) and
  the weights' trip out are timed on their own and spread over the rollout's steps.

Results: docs/decisions/worker-overhead.md.
"""

from __future__ import annotations

import argparse
import pickle
import time
from collections.abc import Callable
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any

import mujoco
import numpy as np
import torch

from common.cli import write_json
from humanoid.env import humanoid_model, model_and_data
from policies.mlp import MLPPolicy, MLPSpec
from rl.finetune import FinetuneConfig
from rl.learner import build_model, make_vec_env
from students.inputs import FullInputs
from teleop.parallel import RolloutSettings, Simulator
from teleop.record import STANDING_NOISE
from teleop.spool import Spool


def cpu(work: Callable[[], Any]) -> tuple[float, Any]:
    """(CPU seconds, result) of `work()`."""
    start = time.process_time()
    result = work()
    return time.process_time() - start, result


class Physics:
    """The simulation states met before each `env.step` of a replay, to time `mj_step` alone on them afterwards."""

    SPEC = mujoco.mjtState.mjSTATE_INTEGRATION  # everything mj_step reads, its warm start included

    def __init__(self) -> None:
        self.steps: list[tuple[Any, Any, np.ndarray, np.ndarray, int]] = []

    def before(self, env: Any, action: np.ndarray) -> None:
        model, data = model_and_data(env)
        state = np.empty(mujoco.mj_stateSize(model, self.SPEC))
        mujoco.mj_getState(model, data, state, self.SPEC)
        self.steps.append((model, data, state, np.asarray(action), env.unwrapped.frame_skip))

    def cpu(self) -> float:
        """CPU seconds of `mj_step` (the env step's frame_skip substeps) from every state met."""

        def run(step: bool) -> None:
            for model, data, state, action, skip in self.steps:
                mujoco.mj_setState(model, data, state, self.SPEC)
                data.ctrl[:] = action
                if step:
                    mujoco.mj_step(model, data, nstep=skip)

        return cpu(lambda: run(True))[0] - cpu(lambda: run(False))[0]


def recording(episodes: int) -> dict[str, float]:
    """Microseconds per recorded step of each stage of a recording worker, expert at the default noise."""
    simulator = Simulator(RolloutSettings("expert", STANDING_NOISE, 1000))
    env, controller = simulator.env, simulator.controller
    totals = dict.fromkeys(("worker", "env.step", "mj_step", "controller", "spool write"), 0.0)
    steps = 0
    simulator.run(episodes)  # a seed not timed: the controller's and the noise's first-use set-up
    with TemporaryDirectory() as folder:
        spool = Spool(Path(folder))
        for seed in range(episodes):
            seconds, episode = cpu(lambda seed=seed: simulator.run(seed))
            totals["spool write"] += cpu(lambda episode=episode: spool.put(episode))[0]
            totals["worker"] += seconds
            steps += episode.length

            env.reset(seed=seed)
            totals["env.step"] += cpu(lambda episode=episode: [env.step(a) for a in episode.executed_action])[0]
            env.reset(seed=seed)
            physics = Physics()
            for action in episode.executed_action:
                physics.before(env, action)
                env.step(action)
            totals["mj_step"] += physics.cpu()
            env.reset(seed=seed)
            controller.reset(seed)
            totals["controller"] += cpu(lambda episode=episode: [controller.act(o) for o in episode.observation])[0]
    totals["worker"] += totals["spool write"]
    per_step = {name: 1e6 * seconds / steps for name, seconds in totals.items()}
    return {
        "whole worker": per_step["worker"],
        "mj_step (the simulation)": per_step["mj_step"],
        "rest of env.step (observation, reward, wrappers)": per_step["env.step"] - per_step["mj_step"],
        "controller (LQR expert)": per_step["controller"],
        "spool write (the trip to the recorder)": per_step["spool write"],
        "episode buffer, noise, loop": per_step["worker"]
        - per_step["env.step"]
        - per_step["controller"]
        - per_step["spool write"],
    }


def sampling(envs: int, steps: int) -> dict[str, float]:
    """Microseconds per environment step of each stage of a PPO worker holding `envs` environments, sampling
    rollouts of `steps` steps with an actor of `make train-bc`'s shape (random weights: the cost is the same)."""
    cfg = FinetuneConfig()
    torch.manual_seed(0)
    observation_size = len(FullInputs.input_names(humanoid_model()))
    actor = MLPPolicy(MLPSpec(FullInputs.columns, observation_size, 17, (256, 256), activation="elu"))
    env = make_vec_env(envs, 1, None, cfg.seed)  # the observation, then the full actor's inputs: the same again
    model = build_model(
        actor,
        env,
        critic_normalisation=(torch.zeros(2 * observation_size), torch.ones(2 * observation_size)),
        learning_rate=cfg.learning_rate,
        critic_learning_rate=cfg.critic_learning_rate,
        reward_scale=cfg.reward_scale,
        log_std_init=cfg.log_std_init,
        n_steps=steps,
        batch_size=cfg.batch_size,
        n_epochs=1,
        gamma=cfg.gamma,
        gae_lambda=cfg.gae_lambda,
        clip_range=cfg.clip_range,
        target_kl=None,
        seed=cfg.seed,
        update_threads=1,
    )
    model.ensure_samplers(env)
    env.reset()
    torch.set_num_threads(1)
    state = model.policy.state_dict()
    share = env.workers[0].share
    whole, segment = cpu(lambda: share.sample(state, steps))
    weights_out = cpu(lambda: pickle.loads(pickle.dumps(state, pickle.HIGHEST_PROTOCOL)))[0]
    rollout_back = cpu(lambda: pickle.loads(pickle.dumps(segment, pickle.HIGHEST_PROTOCOL)))[0]
    actions = np.clip(segment.actions, env.action_space.low, env.action_space.high)

    # The same environments again, from the same reset, stepped by `_Share.step` and by a plain loop.
    again = make_vec_env(envs, 1, None, cfg.seed)
    again.reset()
    replayed = again.workers[0].share
    share_step = cpu(lambda: [replayed.step(a) for a in actions])[0]

    def plain_steps(plain: Any, physics: Physics | None = None) -> None:
        """`plain`'s environments, reset as the others, stepped by a plain loop (`physics`: noting each state)."""
        for step_actions in actions:
            for single, action in zip(plain.workers[0].share.envs, step_actions, strict=True):
                if physics is not None:
                    physics.before(single, action)
                _, _, terminated, truncated, _ = single.step(action)
                if terminated or truncated:
                    single.reset()

    plain, noted = make_vec_env(envs, 1, None, cfg.seed), make_vec_env(envs, 1, None, cfg.seed)
    plain.reset()
    noted.reset()
    env_step = cpu(lambda: plain_steps(plain))[0]
    physics = Physics()
    plain_steps(noted, physics)
    simulation = physics.cpu()
    env_steps = envs * steps
    per_step = {
        "whole": whole,
        "share.step": share_step,
        "env.step": env_step,
        "mj_step": simulation,
        "weights out": weights_out,
        "rollout back": rollout_back,
    }
    per_step = {name: 1e6 * seconds / env_steps for name, seconds in per_step.items()}
    for vec_env in (env, again, plain, noted):
        vec_env.close()
    return {
        "whole worker (sampling, with the trips to and from the learner)": per_step["whole"]
        + per_step["weights out"]
        + per_step["rollout back"],
        "mj_step (the simulation)": per_step["mj_step"],
        "rest of env.step (observation, reward, wrappers, resets)": per_step["env.step"] - per_step["mj_step"],
        "_Share.step's bookkeeping (infos, actions kept for a resume)": per_step["share.step"] - per_step["env.step"],
        "policy forward pass, noise, records": per_step["whole"] - per_step["share.step"],
        "rollout to the learner (pickle, as the pipe does)": per_step["rollout back"],
        "weights from the learner (pickle)": per_step["weights out"],
    }


def table(title: str, stages: dict[str, float]) -> str:
    whole = next(iter(stages.values()))
    lines = [f"| {title} | µs per step | share |", "|---|---|---|"]
    lines += [f"| {name} | {value:.1f} | {value / whole:.0%} |" for name, value in stages.items()]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=3, help="recorded episodes (seeds 0..)")
    parser.add_argument("--envs", type=int, default=32, help="environments of the PPO worker (64 over 2 workers)")
    parser.add_argument("--steps", type=int, default=256, help="steps of each environment per rollout (16,384 over 64)")
    parser.add_argument("--json", type=Path, default=None, help="write both tables' figures here too")
    args = parser.parse_args()
    torch.set_num_threads(1)
    results = {"recording": recording(args.episodes), "ppo": sampling(args.envs, args.steps)}
    print(table("recording worker, per recorded step", results["recording"]))
    print()
    print(table(f"PPO worker ({args.envs} environments), per environment step", results["ppo"]))
    if args.json is not None:
        write_json(args.json, results)


if __name__ == "__main__":
    main()
