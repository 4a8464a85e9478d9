"""The stepping expert: today's LQR balance while the capture point stays over the feet, a sampling planner that steps
once it leaves (docs/decisions/stepping-teacher.md).

Humanoid-v5's feet are spheres with no ankle: without a step the hips absorb about 0.16 m/s of the body's velocity,
and every standing controller falls to a 0.2 m/s kick. `SteppingExpert` runs the LQR expert (`teachers.expert`)
until the capture point (centre of mass + its velocity / ω) leaves the segment between the feet, or the centre of
mass moves faster than a standing body does (the hand-over rule its students compute too: `task.handover`), and from
then on plans every env step by predictive sampling, MuJoCo
MPC's way: spline controls around the previous plan, rolled out on a planning copy of the model (`mujoco.rollout`),
the cheapest kept. Its cost is MuJoCo MPC's humanoid balance: the capture point over the feet, head high, torso
upright, feet back at the stance's width, small velocity and effort. Under the zero command and no push the trigger
never fires, so it stands exactly as the LQR expert does; after a kick it plans to the episode's end (handing back to
the LQR in a stance other than its design toppled more bodies than it saved: the decision record's table). A velocity
command hands the body to a second planner (`WALKING`) that tracks it, to the episode's end: it walks, but not yet
well (docs/decisions/walking-teacher.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np
from mujoco import rollout

from humanoid.capture import Support, capture_offset, off_segment
from humanoid.env import QPOS_OBS, QVEL_OBS, humanoid_xml
from humanoid.sensors import yaw_rate
from task.command_fields import VELOCITY_NAMES, field_positions
from task.handover import STEPPING
from teachers.expert import Balanced
from teachers.lqr import CTRL_LIMIT

STEPPING_STREAM = 8  # random stream of the planner's samples: (seed, 8); humanoid.conditions lists the others
STANCE_WIDTH = 0.18
"""Sideways distance between the feet in the LQR's stance, m."""
_VELOCITIES = field_positions(VELOCITY_NAMES)  # where the walk sits in the expert's setpoint
HEAD_HEIGHT = 1.40
"""The head's height above the lower foot's centre in the LQR's stance, m: the cost asks for at least this (less
the commanded crouch)."""


@dataclass(frozen=True)
class SteppingDesign:
    """The planner's settings (docs/decisions/stepping-teacher.md)."""

    samples: int = 64
    """Control sequences rolled out per env step (the previous plan among them): 32 survived 0.4 m/s kicks about
    half as often."""
    horizon: int = 30
    """Planning steps of `dt` each: 0.45 s, MuJoCo MPC's humanoid horizon."""
    knots: int = 4
    """Spline knots over the horizon, linearly interpolated."""
    sigma: float = 0.15
    """Std of the knots' Gaussian perturbation (the motors accept ±0.4)."""
    dt: float = 0.015
    """The planning model's step, one env step, with the implicitfast integrator (the env's is RK4 at 0.003 x 5)."""
    weights: dict[str, float] = field(
        default_factory=lambda: {
            "height": 30.0,
            "capture": 50.0,
            "centre": 20.0,
            "upright": 10.0,
            "velocity": 10.0,
            "posture": 0.3,
            "effort": 0.1,
            "stance": 50.0,
            "fall": 1000.0,
        }
    )
    """The cost's terms per planning step (`StepPlanner.cost`); the horizon's last step counts 5 times."""
    walk: dict[str, float] = field(default_factory=dict)
    """The walking cost's terms (`WALKING`'s; empty: the kick planner's design, which walks nothing)."""


WALKING = SteppingDesign(
    horizon=45,
    weights={**SteppingDesign().weights, "upright": 30.0},
    walk={
        "yaw": 20.0,  # the horizon's mean yaw rate against the commanded turn
        "rest_yaw": 5.0,  # each step's yaw rate, while the command is zero again
        "fore": 0.0,  # the stance's fore-aft term, scaled by this while walking: a walk puts one foot ahead
        "full_speed": 0.2,  # m/s (and `full_turn` rad/s) of command at which walking's changes are complete
        "full_turn": 0.3,
    },
)
"""The planner that walks: on velocity commands it tracks the horizon's mean velocity in the heading's frame (a gait
sways within a stride, so each step's would fight the stride) over 0.675 s, with the torso kept more upright; its
changes to the balance cost blend in with the command (docs/decisions/walking-teacher.md)."""


def planning_model(design: SteppingDesign) -> mujoco.MjModel:
    """Humanoid-v5's model with the sensors the cost reads (centre of mass and its velocity, feet, head, torso axes),
    stepped at `design.dt` with implicitfast and the Newton solver: a few times faster per second planned than the
    env's, and stable at that step."""
    spec = mujoco.MjSpec.from_file(str(humanoid_xml()))
    body, geom, sensor = mujoco.mjtObj.mjOBJ_BODY, mujoco.mjtObj.mjOBJ_GEOM, mujoco.mjtSensor
    for kind, objtype, name in (
        (sensor.mjSENS_SUBTREECOM, body, "torso"),
        (sensor.mjSENS_SUBTREELINVEL, body, "torso"),
        (sensor.mjSENS_FRAMEPOS, geom, "left_foot"),
        (sensor.mjSENS_FRAMEPOS, geom, "right_foot"),
        (sensor.mjSENS_FRAMEPOS, geom, "head"),
        (sensor.mjSENS_FRAMEZAXIS, body, "torso"),
        (sensor.mjSENS_FRAMEXAXIS, body, "torso"),
    ):
        spec.add_sensor(type=kind, objtype=objtype, objname=name)
    model = spec.compile()
    model.opt.timestep = design.dt
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    model.opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
    model.opt.iterations, model.opt.ls_iterations = 20, 10
    return model


# Where each quantity sits in the planning model's sensordata.
COM, COM_VEL, LEFT_FOOT, RIGHT_FOOT, HEAD, TORSO_Z, TORSO_X = (slice(3 * i, 3 * i + 3) for i in range(7))


def stance(sensors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(fore-aft, sideways) offset of the left foot from the right, in the torso's heading, of sensordata (..., n)."""
    heading = sensors[..., TORSO_X][..., :2]
    heading = heading / np.maximum(np.linalg.norm(heading, axis=-1, keepdims=True), 1e-6)
    apart = sensors[..., LEFT_FOOT][..., :2] - sensors[..., RIGHT_FOOT][..., :2]
    fore = (apart * heading).sum(-1)
    side = apart[..., 1] * heading[..., 0] - apart[..., 0] * heading[..., 1]
    return fore, side


def capture_of(sensors: np.ndarray) -> tuple[float, float]:
    """`humanoid.capture.capture_offset` of a planning model's sensordata."""
    return capture_offset(sensors[COM], sensors[COM_VEL], sensors[LEFT_FOOT], sensors[RIGHT_FOOT])


class StepPlanner:
    """Predictive sampling over linear-spline controls, one replan per env step."""

    def __init__(self, design: SteppingDesign, reference: np.ndarray, velocity: np.ndarray | None = None) -> None:
        """`reference`: the pose (qpos) whose joint angles the posture term keeps near and whose height the head's
        term asks for, read at each plan: the LQR expert's setpoint, so the commanded posture holds while stepping.
        `velocity`: the commanded (forward, sideways, turn) the walking cost reads, in place (a design with `walk`)."""
        self.design = design
        self.velocity = np.zeros(3) if velocity is None else velocity
        self.model = planning_model(design)
        self.data = mujoco.MjData(self.model)
        self._rollout_data = [mujoco.MjData(self.model)]  # one thread: the same plan whatever the machine
        self.reference = reference
        self.standing_height = float(reference[2])
        self.knot_steps = np.linspace(0.0, design.horizon - 1, design.knots)
        steps = np.arange(design.horizon)
        self._at = np.clip(np.searchsorted(self.knot_steps, steps, side="right") - 1, 0, design.knots - 2)
        self._share = (steps - self.knot_steps[self._at]) / np.diff(self.knot_steps)[self._at]
        self._state = np.empty(mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_FULLPHYSICS))
        self.plan: np.ndarray | None = None
        self.rng = np.random.default_rng()

    def reset(self, seed: int | None) -> None:
        self.plan = None
        self.rng = np.random.default_rng(None if seed is None else (seed, STEPPING_STREAM))

    def observe(self, obs: np.ndarray) -> np.ndarray:
        """The planning model at the observed state (root x and y at 0: the cost is translation-invariant); its
        sensordata."""
        data = self.data
        data.qpos[:2] = 0.0
        data.qpos[2:] = obs[QPOS_OBS]
        data.qvel[:] = obs[QVEL_OBS]
        mujoco.mj_forward(self.model, data)
        return data.sensordata

    def controls(self, knots: np.ndarray) -> np.ndarray:
        """Knots (..., knots, nu) as controls (..., horizon, nu)."""
        share = self._share[:, None]
        return knots[..., self._at, :] * (1.0 - share) + knots[..., self._at + 1, :] * share

    def cost(self, sensors: np.ndarray, controls: np.ndarray, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """Each rollout's cost (samples,) from its sensordata (samples, horizon, n), controls, qpos and qvel.

        A walking design (`WALKING`) changes the balance in proportion to how much walking is commanded: the capture
        point's target moves by the commanded velocity, the stance's fore-aft term is dropped, and every step's
        velocity term gives way to the horizon's mean velocity and yaw rate; at the zero command each step's yaw rate
        is held still too. The kick planner's design commands no velocity: its terms are the balance's alone."""
        w, walk, command = self.design.weights, self.design.walk, self.velocity
        walking = 0.0
        if walk:
            speeds = (abs(command[0]) / walk["full_speed"], abs(command[1]) / walk["full_speed"])
            walking = min(1.0, max(*speeds, abs(command[2]) / walk["full_turn"]))
        com, velocity = sensors[..., COM], sensors[..., COM_VEL]
        left, right = sensors[..., LEFT_FOOT], sensors[..., RIGHT_FOOT]
        heading = sensors[..., TORSO_X][..., :2]
        heading = heading / np.maximum(np.linalg.norm(heading, axis=-1, keepdims=True), 1e-6)
        cos, sin = heading[..., 0], heading[..., 1]
        asked = np.stack([cos * command[0] - sin * command[1], sin * command[0] + cos * command[1]], -1)  # world
        height = sensors[..., HEAD][..., 2] - np.minimum(left[..., 2], right[..., 2])
        capture = com[..., :2] + 0.3 * (velocity[..., :2] - asked)  # MuJoCo MPC's capture point, moved by a walk
        centre = 0.5 * (left[..., :2] + right[..., :2])
        fore, side = stance(sensors)
        yaw = yaw_rate(qpos[..., 3:7], qvel[..., 3:6]) if walk else None
        still = 1.0 - walking
        cost = (
            w["height"] * np.square(np.minimum(height - HEAD_HEIGHT - (self.reference[2] - self.standing_height), 0.0))
            + w["capture"] * off_segment(capture, left[..., :2], right[..., :2])
            + w["centre"] * np.linalg.norm(capture - centre, axis=-1)
            + w["upright"] * np.square(sensors[..., TORSO_Z][..., :2]).sum(-1)
            + still * w["velocity"] * np.square(velocity[..., :2] - asked).sum(-1)
            + (still * walk["rest_yaw"] * np.square(yaw - command[2]) if walk else 0.0)
            + w["posture"] * np.square(qpos[..., 7:] - self.reference[7:]).sum(-1)
            + w["effort"] * np.square(controls).sum(-1)
            + w["stance"]
            * ((1.0 + walking * (walk.get("fore", 1.0) - 1.0)) * np.square(fore) + np.square(side - STANCE_WIDTH))
            + w["fall"] * (com[..., 2] < 0.6)
        )
        cost[..., -1] *= 5.0
        total = cost.sum(-1)
        if walking > 0:
            steps = cost.shape[-1]
            mean = velocity[..., :2].mean(-2)
            c, s = cos.mean(-1), sin.mean(-1)
            forward, sideways = c * mean[..., 0] + s * mean[..., 1], c * mean[..., 1] - s * mean[..., 0]
            total += (
                walking * steps * w["velocity"] * (np.square(forward - command[0]) + np.square(sideways - command[1]))
            )
            total += walking * steps * walk["yaw"] * np.square(yaw.mean(-1) - command[2])
        return total

    def act(self, start: np.ndarray) -> np.ndarray:
        """The first control of the best plan from the state `observe` set, `start` the first plan's every knot."""
        design, nu = self.design, self.model.nu
        if self.plan is None:
            self.plan = np.tile(start, (design.knots, 1))
        else:  # the previous plan, one step on
            shifted = np.clip(np.round(self.knot_steps + 1).astype(int), 0, design.horizon - 1)
            self.plan = self.controls(self.plan)[shifted]
        noise = self.rng.standard_normal((design.samples, design.knots, nu)) * design.sigma
        noise[0] = 0.0
        knots = np.clip(self.plan[None] + noise, -CTRL_LIMIT, CTRL_LIMIT)
        controls = self.controls(knots)
        mujoco.mj_getState(self.model, self.data, self._state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        states, sensors = rollout.rollout(self.model, self._rollout_data, self._state[None], controls)
        nq, nv = self.model.nq, self.model.nv
        cost = self.cost(sensors, controls, states[..., 1 : 1 + nq], states[..., 1 + nq : 1 + nq + nv])
        self.plan = knots[int(np.argmin(cost))]
        return self.controls(self.plan)[0]


class SteppingExpert(Balanced):
    """The LQR expert until the capture point leaves the feet, then `StepPlanner` to the episode's end; on a velocity
    command, the `WALKING` planner to the episode's end.

    Told what the LQR expert is told (the 348-dim observation, the body, the delay, the command); deterministic given
    the reset's seed. The walk follows the expert's setpoint, whose velocities ramp toward the command
    (each field's `rate`: `task.posture.PosturePath`). `planned` counts the episode's planned steps.
    """

    name = "expert-stepping"
    walks = True
    handover = STEPPING

    def __init__(
        self, design: SteppingDesign = SteppingDesign(), delay: int = 0, walking: SteppingDesign = WALKING
    ) -> None:
        super().__init__(delay)  # the balance gives the planners their first plan
        self.design = design
        self.planner = StepPlanner(design, self.expert.qpos_ref)  # the setpoint, which the expert moves in place
        self.velocity = np.zeros(3)
        self.walker = StepPlanner(walking, self.expert.qpos_ref, self.velocity)
        self.planned = self.steps = 0
        self.walked = False

    def reset(self, seed: int | None = None) -> None:
        self.balance.reset(seed)
        self.planner.reset(seed)
        self.walker.reset(seed)
        self.planned = self.steps = 0
        self.walked = False

    def triggered(self, sensors: np.ndarray) -> bool:
        """Whether the kick planner takes over: its `handover` rule on the simulator's state (the planner's
        `sensors`)."""
        return self.handover.leaves(*capture_of(sensors))

    def act(self, obs: np.ndarray) -> np.ndarray:
        action = self.balance.act(obs)  # every step: its setpoint and pending actions stay current
        self.steps += 1
        self.velocity[:] = self.expert.setpoint()[_VELOCITIES]
        if self.walked or self.velocity.any():
            self.walked = True
            self.walker.observe(obs)
            self.planned += 1
            return self.walker.act(action).astype(np.float32)
        if self.planned or self.handover.armed(self.steps):
            sensors = self.planner.observe(obs)
            if self.planned or self.triggered(sensors):
                self.planned += 1
                return self.planner.act(action).astype(np.float32)
        return action


class SensedSteppingExpert(SteppingExpert):
    """`SteppingExpert` whose balance is the expert on leg odometry (`SensedExpert`): the teacher of students on what a
    robot senses, which read what its balance acts on, as the pipeline's students read `expert-sensed`'s
    (docs/decisions/deployable-inputs.md). Its kick planner takes over on that same estimate, so its students can
    compute the hand-over (their `planning` input, `task.handover.HandOverFlag`); the planners still plan on the
    simulator's state, as a teacher may (docs/decisions/walking-student.md)."""

    name = "expert-sensed-stepping"
    on_estimate = True

    def __init__(
        self, design: SteppingDesign = SteppingDesign(), delay: int = 0, walking: SteppingDesign = WALKING
    ) -> None:
        super().__init__(design, delay, walking)
        self.support = Support(self.expert.model)

    def triggered(self, sensors: np.ndarray) -> bool:
        """Its `handover` rule on the state its balance acts on, the leg odometry's estimate: what its students
        compute."""
        return self.handover.leaves(*self.support(*self.balance.estimate))
