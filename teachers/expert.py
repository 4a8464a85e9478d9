"""Scripted LQR standing controller ("the expert") for gymnasium's Humanoid-v5: the teachers `expert` and
`expert-sensed` (`teachers.registry`).

The gains come from `teachers.lqr`; the landing after each reset from `teachers.landing`;
commanded postures (`hold`) from `teachers.postures`. At run time the action is
``ctrl_ff - gain @ state``, clipped to the motors' range; for the first steps after a reset
the landing plan's time-varying version of it.
"""

from __future__ import annotations

import copy
from collections import deque
from typing import ClassVar

import mujoco
import numpy as np

from humanoid.env import FRAME_SKIP, QPOS_OBS, QVEL_OBS, nominal_model
from humanoid.estimator import LegOdometry
from humanoid.physics import turned
from humanoid.sensors import Proprioception
from task.posture import NEUTRAL, Posture
from task.schedules import command_posture, command_vector
from teachers.base import Teacher
from teachers.landing import Landing, load_or_design_landing
from teachers.lqr import (
    ROOT_XY,
    LQRDesign,
    LQRGains,
    cache_key,
    load_or_design,
    steady_action,
)
from teachers.postures import PostureRamp, body_gains


class LQRExpert(Teacher):
    """Standing controller acting from the Humanoid-v5 observation alone.

    ``qpos_ref``, ``ctrl_ff`` and ``gain`` are the setpoint, its feed-forward and the feedback
    gain: the design's until ``hold`` commands a posture (lean, crouch, twist, arms;
    ``task.posture``), toward whose own (balanced pose, feed-forward, gain) they then move
    gradually. The neutral gain alone does not hold most postures: it lets them oscillate or fall.
    """

    name = "expert"

    def __init__(
        self,
        model: mujoco.MjModel | None = None,
        design: LQRDesign = LQRDesign(),
        delay: int = 0,
        landing: bool = True,
    ) -> None:
        """Design (or load from the cache) the gains for ``model``, by default Humanoid-v5's.

        With ``landing`` (and ``design.landing_steps`` > 0) the first steps after each `reset` track the
        planned landing (`teachers.landing`) on the design's body without delay and until a posture is
        commanded; the plan is the nominal body's and assumes each action executes at once. Without it
        the steady gain acts from the first step, as before the landing was planned.

        ``delay`` is the system's known action latency in env steps: the environment executes each
        action that many steps late (``humanoid.conditions.ActionLatency``). The expert then acts
        on the state its pending actions will have led to, predicted by stepping its own copy of
        the model (the nominal one: it knows no randomised parameter) from the observed state.
        Without it one step of latency topples the expert at once (docs/decisions/expert-delay.md).
        """
        self.model = nominal_model() if model is None else model
        self.design = design
        self._key = cache_key(self.model, design)  # the body the gains are designed on, as it is now
        self._body: tuple[mujoco.MjModel, LQRGains] | None = None  # a told body other than that one
        self._predictor: Predictor | None = None
        self.set_delay(delay)
        self._pending: deque[np.ndarray] = deque()
        self.gains = load_or_design(self.model, design)
        self.landing: Landing | None = None
        if landing and design.landing_steps > 0:
            self.landing = load_or_design_landing(self.model, design)
        self._landing_step = self._landing_end = 0  # armed by `reset`
        self.qpos_ref = self.gains.qpos_ref.copy()
        self.ctrl_ff = self.gains.ctrl_ff.copy()
        self.gain = self.gains.gain  # replaced by a copy that PostureRamp writes into on the first hold
        self._qpos = self.qpos_ref.copy()
        self._ramp: PostureRamp | None = None  # built on the first hold: a never-commanded expert pays nothing
        self._moving = False  # one attribute test per act while the setpoint is still
        self.heading = 0.0
        """The yaw (rad) the setpoint faces: 0, as designed, until a walker hands the body back facing elsewhere."""

    def set_delay(self, steps: int) -> None:
        """The action latency from the next `reset` on, told for each episode (`rollout.episode.tell_delay`)."""
        if steps < 0:
            raise ValueError(f"delay must be >= 0 steps, got {steps}")
        self.delay = steps
        if steps and self._predictor is None:
            self._predictor = Predictor(self._body_model(), FRAME_SKIP)

    def set_body(self, model: mujoco.MjModel) -> None:
        """The body of the episodes from the next `reset` on, told by the rollout (`rollout.episode.tell_body`).

        A body other than the design's (drawn masses, friction or motors: `humanoid.conditions.DomainRandomization`)
        gets its own balanced stance and gain (`teachers.postures.body_gains`, about 0.1 s), and the predictor
        steps it; the design's body gets the design's gains. The expert reads the simulator's observation,
        whose `cinert` holds the masses anyway: a privileged teacher. Without this the nominal stance tips
        a drawn body (docs/decisions/expert-body.md). Commanded postures stay the design's.
        """
        previous = self._body
        if cache_key(model, self.design) == self._key:
            self._body = None
        else:
            body = copy.copy(model)  # the env draws its next body into `model` in place
            self._body = body, body_gains(body, self.design, self.gains.qpos_ref)
        if self._predictor is not None and (previous is not None or self._body is not None):
            self._predictor = Predictor(self._body_model(), FRAME_SKIP)

    def _body_model(self) -> mujoco.MjModel:
        """A model of the body acted on, for the predictor to step."""
        return copy.copy(self.model) if self._body is None else self._body[0]

    def reset(self, seed: int | None = None) -> None:
        """Back to the neutral posture at once (setpoint and target), facing +x (`heading`); no action pending;
        otherwise deterministic."""
        gains = self.gains if self._body is None else self._body[1]
        if self._ramp is None:
            self.gain = gains.gain  # only read until a posture is held
        else:
            self._ramp.reset()  # writes the design's neutral setpoint and gain in place
            self.gain[:] = gains.gain
        self.qpos_ref[:] = gains.qpos_ref
        self.ctrl_ff[:] = gains.ctrl_ff
        self._moving = False
        self.heading = 0.0
        self._landing_step = 0
        planned = self.landing is not None and self._body is None and self.delay == 0
        self._landing_end = len(self.landing) if planned else 0
        # As ActionLatency does: the first `delay` steps execute zeros.
        self._pending = deque([np.zeros(self.model.nu)] * self.delay)

    def ran(self, action: np.ndarray) -> None:
        """Under latency its prediction steps the actions in flight: as a DAgger labeller those are what the policy
        rolled out sent, not its own labels."""
        if self._pending:  # empty without a delay
            self._pending[-1] = np.asarray(action, np.float64)

    def hold(self, posture: Posture, clip: bool = True) -> None:
        """Hold ``posture`` (clipped to its limits unless ``clip`` is False) from now on, moving there gradually.

        Plans the move at once: balanced waypoints (about 3 ms each, one per 0.1 s of move) and,
        the first time a posture is commanded, its LQR gain (0.05 to 0.2 s; cached after). Later
        calls retarget from wherever the setpoint has got to; ``Posture()`` returns to neutral.
        """
        self._landing_end = 0  # the plan lands in the neutral stance; the posture's setpoint takes over now
        if self._ramp is None:
            self.gain = self.gain.copy()  # the design's or the told body's
            self._ramp = PostureRamp(self.model, self.design, self.qpos_ref, self.ctrl_ff, self.gain)
        self._ramp.hold(posture, clip)
        self._moving = self._ramp.moving

    def set_command(self, command: np.ndarray) -> None:
        """Hold the commanded posture (`hold`), unless it is the one held already: the zero command of a fresh
        episode keeps the planned landing."""
        posture = command_posture(command)
        if posture.clipped() != self.target:
            self.hold(posture)

    def setpoint(self) -> np.ndarray:
        """The posture the setpoint is at now, as a command vector."""
        return command_vector(self.posture)

    @property
    def moving(self) -> bool:
        """True while the setpoint is still on its way to the commanded posture."""
        return self._moving

    @property
    def posture(self) -> Posture:
        """The posture the setpoint is at now (between the previous and the target while moving)."""
        return self._ramp.posture if self._ramp is not None else NEUTRAL

    @property
    def target(self) -> Posture:
        """The posture last commanded by ``hold`` (clipped), or the neutral one."""
        return self._ramp.target if self._ramp is not None else NEUTRAL

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Action (float32, shape (nu,), within +-CTRL_LIMIT) for a 348-dim Humanoid-v5 observation.

        While a commanded posture is being approached, each call also moves the setpoint one env step.
        """
        # Root x, y are not observed: _qpos keeps the reference's (they drop out of the LQR state anyway).
        self._qpos[ROOT_XY:] = obs[QPOS_OBS]
        return self.act_on_state(self._qpos, obs[QVEL_OBS])

    def follow(self) -> None:
        """One env step of the setpoint while another law acts (a walker's stepper): the planned landing and the
        command filter move on as `act` moves them, and under latency the step's action joins those in flight, as
        `ran` then tells it; nothing is computed."""
        if self._landing_step < self._landing_end:
            self._landing_step += 1
        if self._moving:
            self._moving = self._ramp.step()
        if self._predictor is not None:
            self._pending.append(np.zeros(self.model.nu))
            self._pending.popleft()

    def predicted(self, qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The state (qpos, qvel) the actions in flight lead to from (qpos, qvel): the one this step's action acts on
        (itself without a delay). Read before `follow`, which moves the actions in flight on."""
        if self._predictor is None:
            return qpos, qvel
        return self._predictor.predict(qpos, qvel, self._pending)

    def act_on_state(self, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """`act` for a state given as (qpos, qvel); root x and y are not read (translation-invariant)."""
        if self._landing_step < self._landing_end:  # no delay then, so nothing is pending
            self._landing_step += 1
            return self.landing.action(self.model, self._landing_step - 1, qpos, qvel)
        if self._moving:
            self._moving = self._ramp.step()
        qpos, qvel = self.predicted(qpos, qvel)
        if self.heading:  # a walker handed the body back facing elsewhere: the setpoint faces there too
            qpos, qvel = turned(qpos, qvel, -self.heading)
        action = steady_action(self.model, self.design, (self.qpos_ref, self.ctrl_ff, self.gain), qpos, qvel)
        if self._predictor is not None:
            self._pending.append(action.astype(np.float64))
            self._pending.popleft()
        return action


class Predictor:
    """Where pending actions take the humanoid: MuJoCo steps of a model from a given state (a Smith predictor)."""

    def __init__(self, model: mujoco.MjModel, frame_skip: int) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self.frame_skip = frame_skip

    def predict(self, qpos: np.ndarray, qvel: np.ndarray, actions: deque[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """(qpos, qvel) after applying `actions` in turn for one env step each from (qpos, qvel); copies."""
        data = self.data
        data.qpos[:], data.qvel[:] = qpos, qvel
        data.act[:] = 0.0
        for action in actions:
            data.ctrl[:] = action
            mujoco.mj_step(self.model, data, nstep=self.frame_skip)
        return data.qpos.copy(), data.qvel.copy()


class ExpertAround(Teacher):
    """A controller built around an `LQRExpert` (`self.expert`): the command, the delay, its setpoint and the actions
    that ran are the expert's; what it reads and how it acts are the subclass's."""

    expert: LQRExpert

    def set_delay(self, steps: int) -> None:
        self.expert.set_delay(steps)

    def set_command(self, command: np.ndarray) -> None:
        self.expert.set_command(command)

    def setpoint(self) -> np.ndarray:
        return self.expert.setpoint()

    def ran(self, action: np.ndarray) -> None:
        self.expert.ran(action)


class SensedExpert(ExpertAround):
    """The LQR expert acting on what a robot senses: the state `LegOdometry` estimates from the sensed features.

    The expert's gain reads the torso's height and linear velocity, which no sensor measures; fed the
    estimate instead, the expert is a controller of the sensed features (and the estimator's memory,
    which matters only while a foot is off the ground): a policy on the sensed features reads all it
    acts on (docs/decisions/leg-odometry.md measures both).
    """

    name = "expert-sensed"

    def __init__(self, model: mujoco.MjModel | None = None, delay: int = 0) -> None:
        """The expert designed on `model` (like `LQRExpert`), without the planned landing: on the estimate it
        stood no more often, and the odometry students of its demonstrations stood less often
        (docs/decisions/landing-plan.md); the estimator runs on `model` too.
        """
        self.expert = LQRExpert(model, delay=delay, landing=False)
        self.sensed = Proprioception(self.expert.model)
        self.estimator = LegOdometry(self.expert.model)
        self.estimate: tuple[np.ndarray, np.ndarray] = (np.zeros(self.expert.model.nq), np.zeros(self.expert.model.nv))
        """The (qpos, qvel) the last `act` acted on."""
        self.still: np.ndarray | None = None
        """The feet a contact schedule holds still (`LegOdometry`'s `still`); None, the expert's own: every foot down.
        A walker on it sets its gait's every step (`task.gait.GaitClock.schedule`)."""

    def set_body(self, model: mujoco.MjModel) -> None:
        """Never told the body: it acts on what a robot senses (its estimator included), on the nominal model."""

    def reset(self, seed: int | None = None) -> None:
        self.expert.reset(seed)
        self.estimator.reset()

    def observe(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The leg odometry moved on by this step's sensed features, under the `still` schedule: the estimate."""
        self.estimate = self.estimator(self.sensed(obs), self.still)
        return self.estimate

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.expert.act_on_state(*self.observe(obs))


class Balanced(ExpertAround):
    """A teacher that balances with the LQR expert and hands the body to another law on the way (the stepping
    teachers, the walker): `balance` is the expert told the simulator's state, or with `on_estimate` the expert on
    leg odometry (`SensedExpert`), the teacher of students on what a robot senses; `expert` is the LQR expert inside
    it, whose setpoint, command and delay the teacher shares."""

    on_estimate: ClassVar[bool] = False
    """Whether its balance acts on the leg odometry's estimate rather than the simulator's state."""

    def __init__(self, delay: int = 0) -> None:
        self.balance: LQRExpert | SensedExpert = (
            SensedExpert(delay=delay) if self.on_estimate else LQRExpert(delay=delay)
        )
        """Who balances until another law takes over."""
        self.expert = self.balance.expert if isinstance(self.balance, SensedExpert) else self.balance

    def set_body(self, model: mujoco.MjModel) -> None:
        self.balance.set_body(model)
