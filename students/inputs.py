"""What a policy reads (`make train-bc INPUTS=...`, recorded in its checkpoint's `MLPSpec.inputs`).

    full      the gymnasium observation (348 floats), as is
    proprio   what a robot senses: `observation.state` (48; humanoid.sensors)
    pending   the sensed features but the feet's forces, then what `humanoid.estimator` computes from the sensed
              features alone (the torso's height and linear velocity, the nominal model's body inertias), then
              the action sent but not yet executed under one step of action latency (zeros without latency)
              and that latency in steps (176 + 17 + 1): what a robot knows of itself and of its own actuation
              delay (docs/decisions/pending-inputs.md)
    full+command, pending+command  full or pending, then the operator's posture command (`observation.command`'s
              5 posture fields: task.command_fields.POSTURE_NAMES): a policy that follows posture commands;
              standing still is the zero command
              (docs/concepts/commands.md); full+command learns from keyboard demonstrations, which delay no episode
    pending+ramp  pending, then the command as the expert's setpoint moves toward it (`task.posture.PosturePath`
              run on the recorded command: 4 posture fields and the 6 arm angles on the way, 10): where along a
              move the teacher's labels are (docs/decisions/command-features.md)
    pending+walk  pending+ramp reading every command field: the velocities on their ramp too (3), whether the
              stepping teacher's planners have the body (`planning`, 1), then the velocities as the leg odometry
              estimates them (3): a policy that walks on velocity commands (docs/decisions/walking-student.md)
    pending+gait  pending+walk with the walker's gait clock in place of `planning`: whether a walk is on, its phase,
              which foot swings, how far the step has gone, where the foot lands (`task.gait.GaitClock.features`,
              9), run on the same leg odometry as the walker on what a robot senses (`walker-sensed`), the odometry's
              velocity and inertias in the heading's frame: its student (docs/decisions/walker-students.md)

Each is one `InputSet` subclass, registered by name in `INPUT_SETS` (`input_set_named` looks one up): its names,
the dataset columns it is computed from, and the one stateful per-frame computation that every user runs
the same way: the live controller (`students.learned.PolicyController`), the offline loader along each
recorded episode (`episode_inputs`, used by `bc.data`), and PPO's environments (`InputObservation`, whose
appended entries PPO's actor reads). Per episode:

    set_delay(steps)   the episode's action latency in steps (`make record LATENCY=`), told before `reset`
    reset()            the episode starts
    observe(obs, cmd)  a gymnasium observation and the command in force -> the frame: the entries `observed_names`
                       a recording holds
    __call__(frame)    the frame -> the policy's inputs
    sent(action)       the action sent from this frame (offline: the frame's recorded action label)

Live and in PPO the frames are the observations' (float64), offline the recorded ones (float32): the same code,
so a policy trains on what it reads when deployed, to the recording's float32 rounding. Every set implements
every call (no-ops where it has no use), so no caller asks what a set can do. The operator's command, which the
rollout passes in, joins a commanded set's frame as the entries of its recorded column (`observed_columns`), given
to `observe` live and decoded with the frame offline; a set without it ignores the command.
"""

from __future__ import annotations

import hashlib
from abc import ABC, abstractmethod
from typing import Any, ClassVar

import gymnasium as gym
import mujoco
import numpy as np

from common.cli import REMOVED_VALUES, Removed, UserError
from common.columns import ACTION, OBS_COMMAND, OBS_ENV_STATE, OBS_STATE
from common.digest import source_digest
from humanoid.conditions import LATENCY_PARAMETER, action_delay
from humanoid.env import actuator_names, nominal_model, observation_names
from humanoid.estimator import OdometryFeatures, odometry_names
from humanoid.sensors import Proprioception, proprioception_names
from task.command_fields import (
    ARM_JOINTS,
    COMMAND_SIZE,
    POSTURE_TASK,
    STAND,
    VELOCITY_NAMES,
    WALK,
    Readout,
    field_positions,
    task_fields,
)
from task.gait import GAIT_FILE, GaitClock, load_gait
from task.handover import STEPPING, HandOverFlag
from task.posture import POSED, Posture, PosturePath
from task.tracking import COMMAND_INFO


class InputSet(ABC):
    """One input set: its names, its columns, and its computation along one episode (see the module's sketch)."""

    name: ClassVar[str]
    columns: ClassVar[tuple[str, ...]]
    """The dataset columns the inputs are computed from (`MLPSpec.input_keys`)."""
    observed_columns: ClassVar[tuple[str, ...]]
    """Those whose entries make up a frame (`observed_names`); the others are told (`sent`)."""
    takes_command: ClassVar[bool] = False
    """Whether the operator's command is among the inputs (a `commanded_set`)."""
    reads_latency: ClassVar[bool] = False
    """Whether the inputs carry the action latency, which only delayed episodes teach."""
    walks: ClassVar[bool] = False
    """Whether the velocity command is among the inputs (a walking set): a policy that can be told to walk."""
    recording: ClassVar[str] = "make record"
    """The recording whose demonstrations teach it, which a refusal names."""
    task: ClassVar[str] = STAND
    """The task (`task.command_fields.TASKS`) its policy is trained and evaluated on: what its command asks."""
    version: ClassVar[int] = 1
    """Which computation of these inputs, recorded in a checkpoint (`MLPSpec.inputs_version`): raised where a change
    computes the same names otherwise, so that `students.learned.check_fits` refuses a policy trained on the old one."""

    def __init__(self, model: mujoco.MjModel) -> None:
        """For `model`'s environment (its observation layout; a stateful set computes on this nominal body)."""
        self.size = len(self.input_names(model))

    @staticmethod
    @abstractmethod
    def input_names(model: mujoco.MjModel) -> list[str]:
        """The names of the policy's input entries, in order."""

    @staticmethod
    @abstractmethod
    def observed_names(model: mujoco.MjModel) -> list[str]:
        """The names of a frame's entries, in order: where they sit among `observed_columns`' recorded names."""

    @abstractmethod
    def observe(self, obs: np.ndarray, command: np.ndarray) -> np.ndarray:
        """The frames (..., len(observed_names)) of gymnasium observations (..., 348) under the commands (..., 5) in
        force: the entries the recorder stores."""

    @abstractmethod
    def __call__(self, frame: np.ndarray) -> np.ndarray:
        """This frame's inputs."""

    def set_delay(self, steps: int) -> None:  # noqa: B027 - a no-op where a set does not read the delay
        """The action latency, in steps, of the episodes from the next `reset` on."""

    def reset(self) -> None:  # noqa: B027 - a no-op where a set has no memory
        """An episode starts."""

    def sent(self, action: np.ndarray) -> None:  # noqa: B027 - a no-op where a set does not read its actions
        """The action sent from this frame."""


class FullInputs(InputSet):
    """The gymnasium observation as it is: the privileged state, which no robot measures."""

    name = "full"
    columns = observed_columns = (OBS_STATE, OBS_ENV_STATE)
    input_names = observed_names = staticmethod(observation_names)

    def observe(self, obs: np.ndarray, command: np.ndarray) -> np.ndarray:
        return obs

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        return frame


class ProprioInputs(InputSet):
    """What a robot senses (`humanoid.sensors`), read as it is."""

    name = "proprio"
    columns = observed_columns = (OBS_STATE,)
    input_names = observed_names = staticmethod(proprioception_names)

    def __init__(self, model: mujoco.MjModel) -> None:
        super().__init__(model)
        self.sensed = Proprioception(model)

    def observe(self, obs: np.ndarray, command: np.ndarray) -> np.ndarray:
        return self.sensed(obs)

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        return frame


class PendingInputs(InputSet):
    """`OdometryFeatures` of the sensed features, the action still in flight, the delay.

    Why: a student on the sensed features alone does not stand, one that also reads the estimator's does
    (docs/decisions/deployable-inputs.md); and one step of action latency topples a policy that
    acts as if its action ran at once, while told the delay and what it sent, a student learns to act
    through it (docs/decisions/pending-inputs.md).
    """

    name = "pending"
    columns = (OBS_STATE, ACTION)
    observed_columns = (OBS_STATE,)
    observed_names = staticmethod(proprioception_names)
    reads_latency = True
    MAX_DELAY = 1  # the action in flight is one: one step of latency
    heading_frame: ClassVar[bool] = False
    """Whether the odometry's velocity and inertias are read in the heading's frame (`OdometryFeatures`)."""

    @staticmethod
    def input_names(model: mujoco.MjModel) -> list[str]:
        return [*odometry_names(model), *(f"pending.{name}" for name in actuator_names(model)), LATENCY_PARAMETER]

    def __init__(self, model: mujoco.MjModel) -> None:
        super().__init__(model)
        self.sensed = Proprioception(model)
        self.odometry = OdometryFeatures(model, self.heading_frame)
        self.delay = 0
        self.pending = np.zeros(model.nu)

    def set_delay(self, steps: int) -> None:
        if not 0 <= steps <= self.MAX_DELAY:
            raise UserError(
                f"a policy on the 'pending' inputs acts through at most {self.MAX_DELAY} step of action latency; "
                f"this episode delays its actions by {steps}"
            )
        self.delay = steps

    def reset(self) -> None:
        self.odometry.reset()
        self.pending[:] = 0.0  # as ActionLatency does: the first step executes zeros

    def sent(self, action: np.ndarray) -> None:
        """In flight until the next frame's action, if the episode is delayed."""
        if self.delay:
            self.pending[:] = action

    def observe(self, obs: np.ndarray, command: np.ndarray) -> np.ndarray:
        return self.sensed(obs)

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        # float64 whatever the frame's type: the estimator's trigonometry in float32 would not be the live one's.
        odometry = self.odometry.from_sensed(np.asarray(frame, np.float64))
        return np.concatenate([odometry, self.pending, [float(self.delay)]])


def command_names(walking: bool) -> tuple[str, ...]:
    """The command fields a commanded set reads by name (`task_fields`): the posture's, and with `walking` the
    velocities too; so a dataset that records more (or, recorded before them, fewer) fields gives the same frames."""
    return tuple(field.name for field in task_fields(WALK if walking else POSTURE_TASK))


def commanded_set(base: type[InputSet], walking: bool = False) -> type[InputSet]:
    """`base`'s inputs, then the operator's command as it is (`observation.command`'s `command_names(walking)`): the
    set named "BASE+command"."""
    names = command_names(walking)
    read = field_positions(names)

    class CommandedInputs(base):
        name = f"{base.name}+command"
        columns = (*base.columns, OBS_COMMAND)
        observed_columns = (*base.observed_columns, OBS_COMMAND)
        takes_command = True
        walks = walking
        task = WALK if walking else POSTURE_TASK
        __doc__ = f"{base.__name__}'s inputs, then the operator's command."

        @staticmethod
        def input_names(model: mujoco.MjModel) -> list[str]:
            return [*base.input_names(model), *(f"command.{name}" for name in names)]

        @staticmethod
        def observed_names(model: mujoco.MjModel) -> list[str]:
            return [*base.observed_names(model), *names]

        def observe(self, obs: np.ndarray, command: np.ndarray) -> np.ndarray:
            frame = base.observe(self, obs, command)
            given = np.asarray(command)[..., read]
            return np.concatenate([frame, np.broadcast_to(given, (*frame.shape[:-1], len(read)))], axis=-1)

        def __call__(self, frame: np.ndarray) -> np.ndarray:
            size = len(read)
            return np.concatenate([base.__call__(self, frame[..., :-size]), frame[..., -size:]], -1)

    CommandedInputs.__name__ = CommandedInputs.__qualname__ = f"Commanded{base.__name__}"
    return CommandedInputs


_RAMP_FIELDS = tuple(field.name for field in POSED)
RAMP_NAMES = (*(f"ramp.{name}" for name in _RAMP_FIELDS), *(f"ramp.{joint}" for joint in ARM_JOINTS))
"""A ramped set's posture inputs: the posture fields but the arm preset, then the six arm angles (`ARM_JOINTS`)."""
WALK_NAMES = (
    *(f"ramp.{name}" for name in VELOCITY_NAMES),
    "planning",
    *(f"estimate.{name}" for name in VELOCITY_NAMES),
)
"""A walking set's last inputs: the velocity fields on their ramp; whether the stepping teacher's planners have had
the body since the episode began (1) or not (0): the ramp has left the zero walk, or, once armed, the capture point of
the leg odometry's estimate has left the feet (their rule: `task.handover.STEPPING`); then the velocities as the leg
odometry estimates them (`Readout` of the estimated state)."""


GAIT_NAMES = (
    *(f"ramp.{name}" for name in VELOCITY_NAMES),
    *(f"gait.{name}" for name in GaitClock.FEATURES),
    *(f"estimate.{name}" for name in VELOCITY_NAMES),
)
"""The walker's students' last inputs: the velocity fields on their ramp, the gait clock's features
(`task.gait.GaitClock.features`), then the velocities as the leg odometry estimates them."""


def ramped_set(base: type[PendingInputs], walking: bool = False, gait: bool = False) -> type[InputSet]:
    """`base`'s inputs, then the operator's command as the expert's setpoint moves toward it (`PosturePath`, run on
    the command the frame records): the set named "BASE+ramp"; with `walking`, "BASE+walk": the velocity fields on
    their ramp too, whether the stepping teacher's planners have the body, then the velocities as `base`'s leg odometry
    estimates them (`WALK_NAMES`).

    Why: the expert's labels follow its setpoint, which reaches a new command over seconds; a policy that reads only
    the command cannot tell how far along that move it is, a policy reading the ramp can, and it is computed from the
    command alone, as a robot's command filter would (docs/decisions/command-features.md). The arm preset is read as
    the six angles the setpoint's arms have on the way: a preset's number halfway between two presets names a third.
    A walking student is told how fast it goes in the terms it is commanded in, and when its teacher's planners have
    taken over (a walk, or a kick), which they keep to the episode's end (docs/decisions/walking-student.md).
    Stateful: the ramp runs along the episode's frames, one env step per frame.
    """
    walking = walking or gait
    commanded = commanded_set(base, walking)
    names = command_names(walking)
    size = len(names)
    velocities = VELOCITY_NAMES if walking else ()

    class RampedInputs(commanded):
        name = f"{base.name}+gait" if gait else f"{base.name}+walk" if walking else f"{base.name}+ramp"
        # The walker's students read the odometry in the heading's frame: in the world's, a held turn took them to
        # headings their demonstrations never faced, and they fell (docs/decisions/turned-headings.md).
        heading_frame = gait
        # The walker's clock is in a gait set: its demonstrations are the walker's (a walking task's default teacher);
        # the walking set's `planning` flag is the stepping teacher's hand-over.
        recording = (
            f"make record{'' if gait else ' CONTROLLER=expert-sensed-stepping'} TASK=walk"
            if walking
            else base.recording
        )
        version = 2 if gait else base.version  # 2: the heading's frame (1 read the world's)
        __doc__ = f"{base.__name__}'s inputs, then the operator's command as the expert's setpoint moves toward it."

        @staticmethod
        def input_names(model: mujoco.MjModel) -> list[str]:
            return [*base.input_names(model), *RAMP_NAMES, *(GAIT_NAMES if gait else WALK_NAMES if walking else ())]

        def __init__(self, model: mujoco.MjModel) -> None:
            super().__init__(model)
            self.path = PosturePath(model)  # the env step, as the teacher's
            self.command = np.zeros(size, np.float32)
            self.readout = Readout(model) if walking else None
            self.planning = HandOverFlag(model, HANDOVER) if walking and not gait else None
            self.clock = GaitClock(model, load_gait()) if gait else None

        def reset(self) -> None:
            base.reset(self)
            self.path.reset()
            self.command[:] = 0.0
            if self.planning is not None:
                self.planning.reset()
            if self.clock is not None:
                self.clock.reset()

        def __call__(self, frame: np.ndarray) -> np.ndarray:
            command = frame[-size:]
            if (command != self.command).any():  # as the expert's `set_command`: a new target starts a move
                self.command[:] = command
                target = Posture(**dict(zip(names, map(float, command), strict=True))).clipped()
                if target != self.path.target:
                    self.path.hold(target)
            self.path.step()  # as the expert's `act`: one env step along the move, if there is one
            posture = self.path.posture
            ramp = [*(getattr(posture, name) for name in _RAMP_FIELDS), *self.path.arms()]
            if gait:  # the walker's odometry trusts only the feet its gait holds still
                self.odometry.still = self.clock.schedule()
            inputs = base.__call__(self, frame[:-size])  # runs the leg odometry on this frame
            if walking:
                speeds = [getattr(posture, name) for name in velocities]
                qpos, qvel = self.odometry.estimate
                if gait:  # as the walker's clock runs: a tick before its controls, the advance after
                    velocity = np.array(speeds)
                    self.clock.tick(qpos, qvel, velocity)
                    self.clock.advance(velocity)
                    ramp += [*speeds, *self.clock.features()]
                else:
                    ramp += [*speeds, float(self.planning(any(speeds), qpos, qvel))]  # as the teacher hands over
                achieved = self.readout(qpos[2:], qvel)
                ramp += [float(achieved[name][0]) for name in velocities]
            return np.concatenate([inputs, np.array(ramp, frame.dtype)])

    RampedInputs.__name__ = RampedInputs.__qualname__ = f"{'Walking' if walking else 'Ramped'}{base.__name__}"
    return RampedInputs


HANDOVER = STEPPING
"""The hand-over rule the walking sets' `planning` computes: their teachers' (`teachers.registry` declares each
teacher's; tests/teachers/test_registry.py holds every teacher a walking student learns from to it)."""

INPUT_SETS: dict[str, type[InputSet]] = {
    input_set.name: input_set
    for input_set in (
        FullInputs,
        ProprioInputs,
        PendingInputs,
        commanded_set(FullInputs),  # the student of keyboard demonstrations, which delay no episode (make play)
        commanded_set(PendingInputs),
        ramped_set(PendingInputs),
        ramped_set(PendingInputs, walking=True),
        ramped_set(PendingInputs, gait=True),
    )
}
INPUTS = tuple(INPUT_SETS)
STUDENT_INPUTS = "pending+ramp"
"""What the deployable student reads (`make train-bc`, `make dagger`, and PPO's actor from them): what a robot senses,
the leg odometry computed from it, its command in flight and the delay, and the command through the teacher's ramp:
with it DAgger follows every held-out schedule, with the bare command it does not
(docs/decisions/pipeline-student.md)."""
BLIND_INPUTS = "pending"
"""The same without the operator's command: the pipeline's blind student, which shows what the command buys."""


def removed_inputs(inputs: str) -> Removed | None:
    """What replaced input set `inputs` if this version no longer computes it (`common.cli.REMOVED_VALUES`, which
    refuses `--inputs` of that name on every command line), else None."""
    return REMOVED_VALUES.get(("inputs", inputs))


def input_set_named(inputs: str) -> type[InputSet]:
    """The input set named `inputs`; UserError in one line for a name it is not (saying what replaced a removed one)."""
    removed = removed_inputs(inputs)
    if removed is not None:
        raise UserError(removed.message())
    if inputs not in INPUT_SETS:
        raise UserError(f"unknown inputs {inputs!r}; known: {', '.join(INPUTS)}")
    return INPUT_SETS[inputs]


def computation_digest() -> str:
    """A digest of the code that computes every input set from recorded frames, every project module this one imports
    at any depth (`common.digest.source_digest`), so that inputs an earlier version computed and cached are not
    reused; and of the gait file the walker's students' clock reads (`task.gait.GAIT_FILE`)."""
    return hashlib.sha256((source_digest(__name__) + GAIT_FILE.read_text()).encode()).hexdigest()


def episode_inputs(
    inputs: str,
    frames: np.ndarray,
    actions: np.ndarray,
    episode_index: np.ndarray,
    delays: np.ndarray,
    model: mujoco.MjModel,
) -> np.ndarray:
    """A policy's inputs for recorded frames (rows of `observed_names` entries in frame order), of `frames`' type:
    the set's computation run along each episode as a rollout runs it, told each episode's delay (`delays`, per
    frame) and each frame's action sent (`actions`: the recorded labels, or what ran where another controller
    labelled, as in DAgger's rounds)."""
    input_set = INPUT_SETS[inputs](model)
    out = np.empty((len(frames), input_set.size), frames.dtype)
    for row, frame in enumerate(frames):
        if row == 0 or episode_index[row] != episode_index[row - 1]:
            input_set.set_delay(int(delays[row]))
            input_set.reset()
        out[row] = input_set(frame)
        input_set.sent(actions[row])
    return out


class InputObservation(gym.Wrapper):
    """The env's observation with the inputs of a policy on `inputs` appended: what PPO's actor reads.

    PPO's policy is stateless and an input set may have memory (the estimator, the action in flight): run in
    the env, where each episode's steps arrive in order, a reset starts it afresh and each action stepped is the
    command sent, the inputs become part of the observation, computed by the code the live controller runs
    (train = deploy). The critic reads the observation too (`policies.actor_critic`). The set computes on the
    nominal model, whatever body the env has drawn (its inner wrappers may randomise it), and is told the delay
    the inner `ActionLatency` drew at each reset.
    """

    def __init__(self, env: gym.Env, inputs: str) -> None:
        super().__init__(env)
        self.input_set = INPUT_SETS[inputs](nominal_model())
        self.command = np.zeros(COMMAND_SIZE, np.float32)
        """The operator's command the inputs carry (a commanded set's): an inner `task.tracking.CommandedTask`'s,
        which it gives in the info at the reset and after every step; without one, zero (standing still) unless set."""
        space = env.observation_space
        extra = np.full(self.input_set.size, np.inf)
        self.observation_space = gym.spaces.Box(
            np.concatenate([space.low, -extra]), np.concatenate([space.high, extra]), dtype=space.dtype
        )

    def _with_inputs(self, obs: np.ndarray) -> np.ndarray:
        return np.concatenate([obs, self.input_set(self.input_set.observe(obs, self.command))]).astype(obs.dtype)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._told(info)
        self.input_set.set_delay(action_delay(self.env))
        self.input_set.reset()
        return self._with_inputs(obs), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self.input_set.sent(action)
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._told(info)
        return self._with_inputs(obs), reward, terminated, truncated, info

    def _told(self, info: dict[str, Any]) -> None:
        """Take the command in force from an inner `CommandedTask`'s info; without one it stays as set."""
        if COMMAND_INFO in info:
            self.command[:] = info[COMMAND_INFO]
