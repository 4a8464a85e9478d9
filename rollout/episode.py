"""One episode in memory, and the rollout loop that fills it.

The rollout is shared by the recorder, the benchmarks and evaluation, so that "recording" and
"running the controller" differ only in what happens to the finished `Episode`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import gymnasium as gym
import mujoco
import numpy as np

from common.cli import UserError
from common.columns import PUSH_NAMES
from humanoid.cameras import Camera, CameraRecorder, CameraRig, CameraTrack
from humanoid.conditions import action_delay
from humanoid.env import LEROBOT_FPS, body_poses, model_and_data
from humanoid.perturbations import perturbation
from rollout.controllers import Controller
from task.command_fields import COMMAND_NAMES, STAND
from task.schedules import command_posture, task_commands, task_for


@dataclass
class Episode:
    """Per-step arrays of one episode (T rows each) and the facts needed to reproduce it.

    Row t holds the observation o_t, the label action a_t chosen from it, the executed action
    (a_t plus injected noise, clipped), and the outcome of that step (r_t, terminated, truncated).
    Body poses are those of o_t; they feed the MCAP 3D view only. `final_observation` is o_T, the
    observation the last action led to (the fallen state of a terminated episode), so that every
    transition (o_t, a_t, r_t, o_t+1) is complete.
    """

    seed: int
    controller: str  # who acted
    labeller: str  # who chose the `action` labels: the controller itself, or the expert in DAgger
    noise_std: float
    observation: np.ndarray  # (T, 348) float64
    action: np.ndarray  # (T, 17) float32
    executed_action: np.ndarray  # (T, 17) float32
    reward: np.ndarray  # (T,) float64
    terminated: np.ndarray  # (T,) bool
    truncated: np.ndarray  # (T,) bool
    body_position: np.ndarray  # (T, 13, 3) float64, world frame
    body_orientation: np.ndarray  # (T, 13, 4) float64, w-x-y-z
    command: np.ndarray  # (T, len(COMMAND_NAMES)) float32: the operator's command in force (columns.OBS_COMMAND)
    setpoint: np.ndarray  # (T, len(COMMAND_NAMES)) float32: the expert's setpoint toward it (columns.SETPOINT)
    push: np.ndarray  # (T, len(PUSH_NAMES)) float32: the push applied to the torso (columns.PUSH)
    tasks: np.ndarray  # (T,) str: the task string in force, which names the command
    final_observation: np.ndarray  # (348,) float64: o_T, after the last step
    dagger_round: int = 0  # 0 for demonstrations, k for the k-th round of DAgger
    # The physical parameters drawn for the episode (humanoid.conditions.DomainRandomization, e.g.
    # {"friction_scale": 1.2}: JSON-ready scale factors); empty when nothing is randomised.
    parameters: dict[str, Any] = field(default_factory=dict)
    # Each camera's frames, by name (`humanoid.cameras`; `make record CAMERAS=...`); empty when none records.
    cameras: dict[str, CameraTrack] = field(default_factory=dict)

    @property
    def length(self) -> int:
        return len(self.reward)

    @property
    def episode_return(self) -> float:
        return float(self.reward.sum())

    @property
    def fell(self) -> bool:
        """The episode ended because the torso left the healthy height range."""
        return bool(self.terminated[-1])


class StepObserver(Protocol):
    """Sees each step as it happens (a live view, `teleop.live`): the rollout calls it, it never changes the rollout."""

    def episode_started(self, seed: int) -> None:
        """An episode was reset with `seed`."""

    def step(self, buffer: EpisodeBuffer, t: int) -> None:
        """Row t of `buffer` is complete: observation, poses, actions, command and outcome."""


class NonFiniteActionError(UserError):
    """A controller returned NaN or infinity: MuJoCo would integrate it into garbage, so the rollout stops."""


class ControllerFailure(UserError):
    """A controller raised an error in an episode: that episode ends unrecorded (one line naming its seed, step and
    command), and a recording goes on with the next seed (`EpisodeFailure`)."""


@dataclass(frozen=True)
class EpisodeFailure:
    """A seed whose episode a controller failed in (`ControllerFailure`): what a recording worker hands back instead
    of the episode."""

    seed: int
    message: str


def controlled(call: Callable[..., Any], controller: Controller, seed: int, t: int, task: str, *args: Any) -> Any:
    """`call(*args)`, one of `controller`'s methods at step `t` of the episode with `seed` under the command the task
    string `task` names; a `ControllerFailure` in one line if it raises (a `UserError` passes as it is)."""
    try:
        return call(*args)
    except UserError:
        raise
    except Exception as error:
        raise ControllerFailure(
            f"controller {controller.name!r} failed at step {t} of the episode with seed {seed}, commanded "
            f"{task[:-1].lower()!r}: {type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}"
        ) from error


def injected_noise(seed: int, steps: int, noise_std: float, action_dim: int) -> np.ndarray:
    """The Gaussian noise added to the label actions of the episode with this seed.

    Drawn from its own stream so that controllers using `seed` are not correlated with it.
    """
    rng = np.random.default_rng((seed, 1))
    return noise_std * rng.standard_normal((steps, action_dim))


class EpisodeBuffer:
    """Preallocated storage for the longest episode, reused from one episode to the next; with `cameras`, each row's
    frames too (rendered at the row's state, encoded as the episode goes)."""

    def __init__(self, env: gym.Env, max_steps: int, cameras: tuple[Camera, ...] = ()) -> None:
        model, _ = model_and_data(env)
        obs_dim = env.observation_space.shape[0]
        act_dim = env.action_space.shape[0]
        bodies = model.nbody - 1
        self.observation = np.empty((max_steps, obs_dim), np.float64)
        self.action = np.empty((max_steps, act_dim), np.float32)
        self.executed_action = np.empty((max_steps, act_dim), np.float32)
        self.reward = np.empty(max_steps, np.float64)
        self.terminated = np.zeros(max_steps, bool)
        self.truncated = np.zeros(max_steps, bool)
        self.body_position = np.empty((max_steps, bodies, 3), np.float64)
        self.body_orientation = np.empty((max_steps, bodies, 4), np.float64)
        self.command = np.zeros((max_steps, len(COMMAND_NAMES)), np.float32)
        self.setpoint = np.zeros((max_steps, len(COMMAND_NAMES)), np.float32)
        self.push = np.zeros((max_steps, len(PUSH_NAMES)), np.float32)
        self.tasks = np.empty(max_steps, object)
        self.cameras = CameraRecorder(CameraRig(model, cameras), LEROBOT_FPS) if cameras else None

    def record(
        self,
        t: int,
        obs: np.ndarray,
        data: mujoco.MjData,
        action: np.ndarray,
        executed: np.ndarray,
        command: np.ndarray,
        task: str,
        setpoint: np.ndarray | None = None,
        push: np.ndarray | None = None,
    ) -> None:
        """Row t before the step: observation o_t, body poses, label and executed action, the command in force and
        the task naming it, the setpoint toward it (the command itself where None) and the push (None: none)."""
        self.observation[t] = obs
        self.body_position[t], self.body_orientation[t] = body_poses(data)
        self.action[t] = action
        self.executed_action[t] = executed
        self.command[t] = command
        self.setpoint[t] = command if setpoint is None else setpoint
        self.push[t] = 0.0 if push is None else push
        self.tasks[t] = task
        if self.cameras is not None:
            if t == 0:
                self.cameras.restart()
            self.cameras.add(data)

    def outcome(self, t: int, reward: float, terminated: bool, truncated: bool) -> None:
        """Row t after the step: its reward and how it ended."""
        self.reward[t] = reward
        self.terminated[t] = terminated
        self.truncated[t] = truncated

    def episode(self, steps: int, final_observation: np.ndarray, **facts: object) -> Episode:
        """Copies of the first `steps` rows, so the buffer can be reused while they are written, and of
        the observation the last step returned."""
        arrays = {name: getattr(self, name)[:steps].copy() for name in ARRAY_FIELDS}
        cameras = {} if self.cameras is None else self.cameras.finish(steps)
        return Episode(**facts, **arrays, final_observation=np.array(final_observation, np.float64), cameras=cameras)


# The array fields of `Episode` besides the per-step ones (what the spool stores as arrays too).
FINAL_FIELDS = ("final_observation",)

# The per-step fields of `Episode`, the ones `EpisodeBuffer` preallocates.
ARRAY_FIELDS = (
    "observation",
    "action",
    "executed_action",
    "reward",
    "terminated",
    "truncated",
    "body_position",
    "body_orientation",
    "command",
    "setpoint",
    "push",
    "tasks",
)


def executed_action(action: np.ndarray, noise: np.ndarray | None, t: int, space: gym.spaces.Box) -> np.ndarray:
    """What the env receives at step t: `action` plus the episode's injected noise (if any), clipped to `space`."""
    return action if noise is None else np.clip(action + noise[t], space.low, space.high).astype(np.float32)


def run_episode(
    env: gym.Env,
    controller: Controller,
    seed: int,
    noise_std: float = 0.0,
    buffer: EpisodeBuffer | None = None,
    labeller: Controller | None = None,
    observer: StepObserver | None = None,
    task: str = STAND,
    commands: np.ndarray | None = None,
) -> Episode:
    """Roll `controller` out from `env.reset(seed=seed)` until termination or the time limit.

    The stored label of each step is the controller's action, or, with a `labeller` (DAgger), the
    labeller's action in the state the controller led to. Perturbations, domain randomisation and
    rendering come with `env` as wrappers (`humanoid.perturbations`, `humanoid.conditions`,
    `humanoid.video`); the randomisation's draw (the reset info's "parameters") goes into the episode.
    An `observer` sees every step as it completes. The operator's command is `task`'s (`task.schedules.task_commands`:
    zero to stand, else the schedule drawn from `seed`), or `commands`, a row a step, where given (`make eval HOLD=`);
    told to the controller and the labeller at each change; the task string names the command in force
    (`task.schedules.task_for`). A controller that raises ends the episode with a `ControllerFailure`.
    """
    max_steps = env.spec.max_episode_steps
    buffer = buffer or EpisodeBuffer(env, max_steps)
    _, data = model_and_data(env)
    noise = injected_noise(seed, max_steps, noise_std, env.action_space.shape[0]) if noise_std > 0 else None
    if commands is None:
        commands = task_commands(task, seed, max_steps, env.unwrapped.dt)
    acting = [controller] if labeller is None else [controller, labeller]
    perturbed = perturbation(env)

    obs, info = env.reset(seed=seed)
    for each in acting:
        tell_delay(each, env)
        tell_body(each, env)
        each.reset(seed)
    if observer is not None:
        observer.episode_started(seed)
    t = 0
    while True:
        if t == 0 or (commands[t] != commands[t - 1]).any():
            named = task_for(command_posture(commands[t]))
            for each in acting:
                controlled(each.set_command, each, seed, t, named, commands[t])
        push = None if perturbed is None else perturbed.recorded_push(t)
        obs, _, terminated, truncated = rollout_step(
            env,
            data,
            controller,
            obs,
            t,
            seed,
            noise,
            buffer,
            commands[t],
            named,
            labeller=labeller,
            push=push,
            observer=observer,
        )
        t += 1
        if terminated or truncated:
            break
    return buffer.episode(
        t,
        obs,
        seed=seed,
        controller=controller.name,
        noise_std=noise_std,
        labeller=controller.name if labeller is None else labeller.name,
        parameters=info.get("parameters", {}),
    )


def rollout_step(
    env: gym.Env,
    data: mujoco.MjData,
    controller: Controller,
    obs: np.ndarray,
    t: int,
    seed: int,
    noise: np.ndarray | None,
    buffer: EpisodeBuffer,
    command: np.ndarray,
    task: str,
    *,
    labeller: Controller | None = None,
    push: np.ndarray | None = None,
    observer: StepObserver | None = None,
) -> tuple[np.ndarray, float, bool, bool]:
    """Step t of an episode, as every rollout takes it (`run_episode`, the keyboard's session): `controller` acts on
    `obs` (checked; a failure is `controlled`'s), the episode's `noise` is added (`executed_action`), `labeller`
    (DAgger) labels the state, row t is recorded with the teacher's setpoint (the labeller's, else the controller's)
    and the `push` in force, the env steps, and `observer` sees the row. Returns (o_t+1, r_t, terminated,
    truncated)."""
    action = controlled(controller.act, controller, seed, t, task, obs)
    check_action(action, controller, t, seed)
    executed = executed_action(action, noise, t, env.action_space)
    label = action if labeller is None else controlled(labeller.act, labeller, seed, t, task, obs)
    if labeller is not None:
        labeller.ran(executed)  # what is in flight is what ran, not its label
    teacher = controller if labeller is None else labeller  # whose actions are the labels
    buffer.record(t, obs, data, label, executed, command, task, teacher.setpoint(), push)
    obs, reward, terminated, truncated, _ = env.step(executed)
    buffer.outcome(t, reward, terminated, truncated)
    if observer is not None:
        observer.step(buffer, t)
    return obs, float(reward), terminated, truncated


def tell_delay(controller: Controller, env: gym.Env) -> None:
    """Tell a controller the action latency of the episode `env` was just reset to, as a robot knows its actuation
    delay (the experts and a policy on the "pending" inputs use it)."""
    controller.set_delay(action_delay(env))


def tell_body(controller: Controller, env: gym.Env) -> None:
    """Tell a controller the body the episode `env` was just reset to: its masses, friction and motors as drawn
    (`humanoid.conditions`; the privileged expert uses it)."""
    controller.set_body(model_and_data(env)[0])


def check_action(action: np.ndarray, controller: Controller, t: int, seed: int) -> None:
    """NonFiniteActionError unless every entry of `action` is finite."""
    if not np.isfinite(action).all():
        raise NonFiniteActionError(
            f"controller {controller.name!r} returned a non-finite action at step {t} of the episode with seed {seed}"
        )
