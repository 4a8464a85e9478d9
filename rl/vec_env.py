"""Many environments in a few worker processes: the vectorised environment of `make finetune-rl`.

SB3's `SubprocVecEnv` runs one environment per process, so the learner pays its per-step cost
(tensor conversion, the policy's forward pass, the rollout buffer) once for every environment
step, and that cost, not the simulation, is what limits PPO here (docs/benchmarks.md, "PPO
fine-tuning"). Here each worker process holds a contiguous group of the environments and
steps them as SB3's in-process `DummyVecEnv` does (auto-reset, `terminal_observation`, consecutive
seeds), so N environments give the same observations and rewards whatever the number of workers
(a test compares them step by step). Besides SB3's `step`, a worker can sample a whole rollout of
its environments with its own copy of the policy (`install_samplers`, `sample`; `rl.rollouts`),
so that PPO's learner does not take part in every step.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import CloudpickleWrapper, VecEnvIndices, VecEnvObs, VecEnvStepReturn

from common.ray_backend import RaySession, RayWorker
from common.workers import Channel, Worker, close_all

# The info keys SB3's PPO reads (bootstrapping at time limits, episode statistics). Humanoid's
# info holds a dozen NumPy scalars and arrays besides, whose copying and pickling cost more than
# stepping the environments (about 350 µs per batch of 8), so workers send back only these.
SB3_INFO_KEYS = ("terminal_observation", "TimeLimit.truncated", "episode", "is_success")


def _random_wrappers(env: gym.Env) -> list[Any]:
    """The wrappers around `env` whose random streams an episode uses besides the environment's own
    (those with `random_state` / `set_random_state`, e.g. `humanoid.perturbations.TorsoPushes`)."""
    found = []
    while isinstance(env, gym.Wrapper):
        if hasattr(env, "random_state") and hasattr(env, "set_random_state"):
            found.append(env)
        env = env.env
    return found


class _Share:
    """A worker's environments, stepped as SB3's `DummyVecEnv` steps them (auto-reset, terminal observation).

    For a run to resume exactly (`rl.resume`), each environment's episode in progress is kept as how it
    started (the reset's seed, or the random streams' states before an auto-reset) and the actions since:
    replaying them rebuilds the simulation, its time limit and every wrapper's counters bit for bit, through
    the environments' public API only. That is at most one episode of actions (68 KB) per environment.
    """

    def __init__(self, envs: list[gym.Env]) -> None:
        self.envs = envs
        self.starts: list[dict[str, Any]] = [{} for _ in envs]
        self.actions: list[list[np.ndarray]] = [[] for _ in envs]
        # Where the environments are, for a sampler to act from (`rl.rollouts`): the last observations and
        # whether each is the first of its episode.
        self.observations: np.ndarray | None = None
        self.episode_starts = np.ones(len(envs), bool)
        self.sampler: Any = None

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict], dict[int, dict]]:
        observations, rewards, dones, infos, reset_infos = [], [], [], [], {}
        for i, (env, action) in enumerate(zip(self.envs, actions, strict=True)):
            self.actions[i].append(np.array(action))
            obs, reward, terminated, truncated, full_info = env.step(action)
            info = {key: full_info[key] for key in SB3_INFO_KEYS if key in full_info}
            info["TimeLimit.truncated"] = truncated and not terminated
            if terminated or truncated:
                info["terminal_observation"] = obs
                self.starts[i], self.actions[i] = self._streams(env), []
                obs, reset_infos[i] = env.reset()
            observations.append(obs)
            rewards.append(reward)
            dones.append(terminated or truncated)
            infos.append(info)
        self.observations, self.episode_starts = np.stack(observations), np.array(dones)
        return self.observations, np.array(rewards, np.float32), self.episode_starts, infos, reset_infos

    def reset(self, seeds: list[int | None], options: list[dict]) -> tuple[np.ndarray, list[dict]]:
        self.starts = [
            {"seed": seed, "options": opts, **self._streams(env)}
            for env, seed, opts in zip(self.envs, seeds, options, strict=True)
        ]
        self.actions = [[] for _ in self.envs]
        results = [
            env.reset(seed=seed, **({"options": opts} if opts else {}))
            for env, seed, opts in zip(self.envs, seeds, options, strict=True)
        ]
        self.observations, self.episode_starts = np.stack([obs for obs, _ in results]), np.ones(len(self.envs), bool)
        return self.observations, [info for _, info in results]

    @staticmethod
    def _streams(env: gym.Env) -> dict[str, Any]:
        """The random streams an unseeded reset and its episode draw from, as they are now."""
        return {
            "np_random": env.unwrapped.np_random.bit_generator.state,
            "wrappers": [wrapper.random_state() for wrapper in _random_wrappers(env)],
        }

    def get_state(self) -> dict[str, Any]:
        """What `set_state` needs to put fresh copies of these environments (and the sampler) where these are."""
        return {
            "starts": self.starts,
            "actions": [
                np.array(actions, np.float32).reshape(len(actions), *self.envs[0].action_space.shape)
                for actions in self.actions
            ],
            "observations": self.observations,
            "episode_starts": self.episode_starts,
            "sampler": None if self.sampler is None else self.sampler.random_state(),
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Replay each environment's episode in progress from its start; the result must equal the saved one."""
        observations = []
        for i, (env, start, actions) in enumerate(zip(self.envs, state["starts"], state["actions"], strict=True)):
            env.unwrapped.np_random.bit_generator.state = start["np_random"]
            for wrapper, wrapper_state in zip(_random_wrappers(env), start["wrappers"], strict=True):
                wrapper.set_random_state(wrapper_state)
            options = start.get("options")
            obs, _ = env.reset(seed=start.get("seed"), **({"options": options} if options else {}))
            for action in actions:
                obs, _, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    raise RuntimeError(f"environment {i} ended while replaying its episode in progress")
            observations.append(obs)
            self.starts[i], self.actions[i] = start, list(actions)
        self.observations, self.episode_starts = np.stack(observations), state["episode_starts"]
        if not np.array_equal(self.observations, state["observations"]):
            raise RuntimeError("the replayed environments are not where the saved ones were")
        if state["sampler"] is not None:
            self.sampler.set_random_state(state["sampler"])

    def handle(self, command: str, *data: Any) -> Any:
        """A worker's request: `spaces`, or the method `command` called with `data`."""
        if command == "spaces":
            return self.envs[0].observation_space, self.envs[0].action_space
        return getattr(self, command)(*data)

    def install_sampler(self, sampler: Any) -> None:
        self.sampler = sampler

    def sample(self, state: dict, n_steps: int) -> Any:
        """The sampler's rollout of these environments, from where they are, with the policy weights `state`."""
        if self.observations is None:
            raise RuntimeError("reset the environments before sampling")
        return self.sampler.collect(
            lambda actions: self.step(actions)[:4], self.observations, self.episode_starts, state, n_steps
        )

    def get_attr(self, indices: list[int], name: str) -> list[Any]:
        return [self.envs[i].get_wrapper_attr(name) for i in indices]

    def set_attr(self, indices: list[int], name: str, value: Any) -> list[None]:
        return [setattr(self.envs[i], name, value) for i in indices]

    def env_method(self, indices: list[int], name: str, args: tuple, kwargs: dict[str, Any]) -> list[Any]:
        return [self.envs[i].get_wrapper_attr(name)(*args, **kwargs) for i in indices]

    def env_is_wrapped(self, indices: list[int], wrapper_class: type[gym.Wrapper]) -> list[bool]:
        return [is_wrapped(self.envs[i], wrapper_class) for i in indices]

    def has_attr(self, indices: list[int], name: str) -> list[bool]:
        return [hasattr(self.envs[i], name) or name in dir(self.envs[i].unwrapped) for i in indices]

    def close(self) -> None:
        for env in self.envs:
            env.close()


def _share_of(factories: list[Callable[[], gym.Env]]) -> _Share:
    """A Ray worker's environments (`common.ray_backend`: the actor holds what this returns)."""
    return _Share([factory() for factory in factories])


def _serve(channel: Channel, factories: CloudpickleWrapper) -> None:
    """A worker (`common.workers`): runs its share of the environments, one command per message, until closed.

    A command's exception is its answer: the learner raises it as itself (SB3 catches AttributeError).
    """
    share = _Share([factory() for factory in factories.var])
    try:
        channel.serve(lambda message: share.handle(message[0], *message[1]))
    finally:
        share.close()


class _InProcess:
    """The single worker of WORKERS=1: the learner's own process behind a worker's send/recv (it runs on `recv`)."""

    def __init__(self, factories: list[Callable[[], gym.Env]]) -> None:
        self.share = _Share([factory() for factory in factories])
        self.pending: tuple[str, tuple] | None = None

    def send(self, message: tuple[str, tuple]) -> None:
        self.pending = message

    def recv(self) -> Any:
        assert self.pending is not None, "recv without send"
        (command, data), self.pending = self.pending, None
        return self.share.handle(command, *data)

    def close(self) -> None:
        self.share.close()


def split(count: int, parts: int) -> list[range]:
    """`count` consecutive indices in `parts` contiguous groups whose sizes differ by at most one."""
    bounds = [round(i * count / parts) for i in range(parts + 1)]
    return [range(bounds[i], bounds[i + 1]) for i in range(parts)]


class WorkerGroupVecEnv(VecEnv):
    """`len(factories)` environments over `workers` processes, in contiguous groups, in order.

    `backend` "ray": the workers are Ray actors anywhere in the cluster at `ray_address` (or in a local
    Ray), one CPU and one core each (`common.ray_backend`); the groups, and so the results, are the same.
    `preload`: the modules the factories' environments import, which the forkserver then imports once
    (`common.workers`): without them each worker process imports them anew, seconds on these machines.

    One worker is the learner's own process (SB3's `DummyVecEnv`, minus its copies of the infos);
    more are that many processes, each pinned to a core of its own (unpinned, Linux woke a worker
    on the core of the learner that woke it, and two workers queued on one core). The learner
    simulates nothing then: with a share of its own, it was the bottleneck (its share plus PPO's
    per-step work). Both measured: docs/decisions/ppo-sampling.md.
    """

    def __init__(
        self,
        factories: Sequence[Callable[[], gym.Env]],
        workers: int,
        backend: str = "local",
        ray_address: str | None = None,
        preload: Iterable[str] = (),
    ):
        if not 1 <= workers <= len(factories):
            raise ValueError(f"need 1 <= workers <= environments, got {workers} workers for {len(factories)}")
        self.groups = split(len(factories), workers)
        cpus = sorted(os.sched_getaffinity(0))
        self.workers: list[Worker | _InProcess | RayWorker] = []
        self.closed = False
        self._ray: RaySession | None = None
        if backend == "ray":
            self._ray = RaySession(ray_address, workers)
            try:
                self.workers += self._ray.spawn(
                    [functools.partial(_share_of, [factories[i] for i in group]) for group in self.groups],
                    name="environment worker",
                )
            except BaseException:
                self.close()
                raise
        elif workers == 1:
            self.workers.append(_InProcess(list(factories)))
        else:
            try:
                for index, group in enumerate(self.groups):
                    self.workers.append(
                        Worker(
                            _serve,
                            CloudpickleWrapper([factories[i] for i in group]),
                            name=f"environment worker {index}",
                            preload=(__name__, *preload),
                            cpu=cpus[index % len(cpus)],
                            ignore_interrupt=False,  # Ctrl-C stops a worker mid-rollout, as it stops the learner
                        )
                    )
            except BaseException:
                self.close()
                raise
        self.workers[0].send(("spaces", ()))
        observation_space, action_space = self.workers[0].recv()
        super().__init__(len(factories), observation_space, action_space)

    def _all(self, command: str, data_per_group: Callable[[range], tuple]) -> list[Any]:
        """Send each worker its command, then collect the answers: the workers run theirs at the same time."""
        for worker, group in zip(self.workers, self.groups, strict=True):
            worker.send((command, data_per_group(group)))
        return [worker.recv() for worker in self.workers]

    def step_async(self, actions: np.ndarray) -> None:
        self.actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        results = self._all("step", lambda group: (self.actions[group.start : group.stop],))
        obs, rewards, dones, infos, reset_infos = zip(*results, strict=True)
        for group, resets in zip(self.groups, reset_infos, strict=True):
            for i, info in resets.items():
                self.reset_infos[group.start + i] = info
        return np.concatenate(obs), np.concatenate(rewards), np.concatenate(dones), [i for part in infos for i in part]

    def reset(self) -> VecEnvObs:
        results = self._all(
            "reset", lambda group: (self._seeds[group.start : group.stop], self._options[group.start : group.stop])
        )
        obs, reset_infos = zip(*results, strict=True)
        self.reset_infos = [info for part in reset_infos for info in part]
        self._reset_seeds()
        self._reset_options()
        return np.concatenate(obs)

    def install_samplers(self, make_sampler: Callable[[range], Any]) -> None:
        """Gives each worker `make_sampler(the global indices of its environments)` (a `rl.rollouts.Sampler`)."""
        self._all("install_sampler", lambda group: (make_sampler(group),))

    def get_state(self) -> list[dict[str, Any]]:
        """Each worker's `_Share.get_state`: where every environment is and how it got there (for resuming)."""
        return self._all("get_state", lambda _: ())

    def set_state(self, states: list[dict[str, Any]]) -> None:
        """Put the environments (and samplers) where `get_state` found them; the worker split must be the same."""
        if len(states) != len(self.groups):
            raise ValueError(f"saved for {len(states)} workers, not {len(self.groups)}")
        self._all("set_state", lambda group: (states[self.groups.index(group)],))

    def sample(self, state: dict, n_steps: int) -> list[Any]:
        """Each worker's rollout of its environments (`n_steps` steps, policy weights `state`), in order."""
        shared = state if self._ray is None else self._ray.put(state)  # sent once, not once per worker
        return self._all("sample", lambda group: (shared, n_steps))

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            close_all(worker for worker in self.workers if isinstance(worker, Worker))
            for worker in self.workers:
                if isinstance(worker, _InProcess):
                    worker.close()
            if self._ray is not None:
                self._ray.close()

    def _call(self, method: str, indices: VecEnvIndices, *args: Any) -> list[Any]:
        """`_Share.<method>(local indices, *args)` in each worker holding some of `indices`; results in their order."""
        wanted = list(self._get_indices(indices))
        asked = []
        for worker, group in zip(self.workers, self.groups, strict=True):
            local = [i - group.start for i in wanted if i in group]
            if local:
                worker.send((method, (local, *args)))
                asked.append((worker, [group.start + i for i in local]))
        by_index = {}
        for worker, global_indices in asked:
            by_index.update(zip(global_indices, worker.recv(), strict=True))
        return [by_index[i] for i in wanted]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return self._call("get_attr", indices, attr_name)

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        self._call("set_attr", indices, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        return self._call("env_method", indices, method_name, method_args, method_kwargs)

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return self._call("env_is_wrapped", indices, wrapper_class)

    def has_attr(self, attr_name: str) -> bool:
        return all(self._call("has_attr", None, attr_name))
