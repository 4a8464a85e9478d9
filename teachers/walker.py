"""The walker: a teacher that walks by foot placement, a deterministic function of the state, its gait clock and the
command (docs/decisions/walking-teacher.md).

Humanoid-v5 is a point-footed biped (sphere feet, no ankle): where the swing foot lands sets the next step's velocity.
The walker runs today's LQR expert while the body stands (`teachers.expert`: the posture task to the bit) and steps
when a walk is commanded or, once armed, when the capture point leaves the feet (a kick). When, which foot and where
are the gait clock's (`task.gait.GaitClock`), which its students compute too; how is the whole-body control's here:

    the clock's phase ──> single support, double support, or settling after the last step
    whole-body control ─> the torques whose accelerations best meet, by weight, the pelvis's attitude (its yaw only
                          where two feet hold it), the centre of mass's height, the swing foot's smooth path to the
                          clock's landing point, and the setpoint's waist, arms and hips' yaw, under the body's
                          dynamics with the stance foot (both feet in double support) held still, the motors' limits
                          and a floor that only pushes (`WholeBody.solve`)

Once a walk is over (the command zero and the body at rest over its feet), the LQR takes over again, facing the way
the walk left it (`LQRExpert.heading`). The whole-body control's gains are the gait's (`task.gait.Gait`), tuned with
the clock's by CMA-ES (`make tune-walker`).
"""

from __future__ import annotations

import copy
import math

import mujoco
import numpy as np

from humanoid.env import QPOS_OBS, QVEL_OBS
from humanoid.physics import FOOT_GEOMS
from task.command_fields import ARM_JOINTS, VELOCITY_NAMES
from task.gait import SIDES, Gait, GaitClock, load_gait, other, rotation
from task.handover import STEPPING
from teachers.expert import Balanced
from teachers.lqr import CTRL_LIMIT

WAIST = ("abdomen_z", "abdomen_y", "abdomen_x")

# What the whole-body control weighs (task weights), fixed: the tuning scales the gains, not these.
ATTITUDE_WEIGHT = 100.0
"""The pelvis's attitude: the first thing kept."""
HEIGHT_WEIGHT = 10.0
"""The centre of mass's height (its horizontal place while settling)."""
FOOT_WEIGHT = 5.0
"""The swing foot's path."""
JOINT_WEIGHT = 1.0
"""The waist, the arms and, while stepping, both hips' yaw."""
REGULARISATION = 1e-4
"""On the torques and the contact forces (N·m, N): among the solutions that meet the tasks, the gentlest."""
LAND_DEPTH = 0.01
"""m: how far below the floor the swing foot's path ends, so that it lands on time."""


def attitude_error(desired: np.ndarray, actual: np.ndarray) -> np.ndarray:
    """The rotation vector (world, small-angle) from `actual` to `desired` (3×3 rotations)."""
    e = desired @ actual.T
    return 0.5 * np.array([e[2, 1] - e[1, 2], e[0, 2] - e[2, 0], e[1, 0] - e[0, 1]])


def attitude_task(
    frequency: float, desired: np.ndarray, actual: np.ndarray, spin: np.ndarray, turn_rate: float
) -> np.ndarray:
    """The angular acceleration (world, rad/s²) a critically damped spring of natural `frequency` (1/s) asks of a
    body whose attitude is `actual` (3×3) spinning at `spin` (rad/s, world) toward `desired`, which turns about the
    vertical at `turn_rate` (rad/s): the heading's rate is fed forward, not damped away. With the yaw rate damped to
    zero the body stopped turning 1.5 s into a turn, and turned left when asked right; fed forward, the turn rate's
    error on selection walks fell from 0.30 to 0.26 rad/s (docs/decisions/walker-turning.md)."""
    return _pd(frequency, attitude_error(desired, actual), spin - np.array([0.0, 0.0, turn_rate]))


def _pd(frequency: float, error: np.ndarray | float, velocity: np.ndarray | float) -> np.ndarray:
    """The acceleration a critically damped spring of natural `frequency` (1/s) asks for."""
    return np.asarray(frequency**2 * error - 2.0 * frequency * velocity)


def quintic_step(phase: float) -> tuple[float, float]:
    """The quintic 0 → 1 with zero velocity and acceleration at both ends, and its derivative, at `phase` in [0, 1].
    The swing foot follows it by PD with its velocity fed forward, not its acceleration: fed forward, the tuned gait
    fell on five of six walking probes (docs/decisions/walking-teacher.md)."""
    return phase**3 * (10.0 - 15.0 * phase + 6.0 * phase**2), 30.0 * phase**2 * (1.0 - phase) ** 2


def _matrix(quaternion: np.ndarray) -> np.ndarray:
    matrix = np.zeros(9)
    mujoco.mju_quat2Mat(matrix, quaternion)
    return matrix.reshape(3, 3)


class WholeBody:
    """The walker's whole-body control on a copy of the nominal model: the torques of one env step for the clock's
    phase (weighted least squares over the accelerations, the dynamics and the contacts: `solve`)."""

    def __init__(self, model: mujoco.MjModel, gait: Gait) -> None:
        self.gait = gait
        self.model = m = model
        self.data = mujoco.MjData(m)
        self.nv = m.nv
        joints = range(1, m.njnt)
        self.qadr = {m.joint(j).name: int(m.jnt_qposadr[j]) for j in joints}
        self.vadr = {m.joint(j).name: int(m.jnt_dofadr[j]) for j in joints}
        self.actdof = np.array([m.jnt_dofadr[m.actuator_trnid[a, 0]] for a in range(m.nu)])
        self.gear = m.actuator_gear[:, 0].copy()
        self.limit = CTRL_LIMIT * self.gear
        self.foot = {side: m.geom(geom).id for side, geom in zip(SIDES, FOOT_GEOMS, strict=True)}
        self.foot_body = {side: int(m.geom_bodyid[geom]) for side, geom in self.foot.items()}
        self.radius = float(m.geom_size[self.foot[SIDES[0]]][0])
        self.pelvis = m.body("pelvis").id
        self.mass = np.zeros((m.nv, m.nv))
        upper = WAIST + ARM_JOINTS
        self._upper = self._addresses(upper)
        self._with_hips = self._addresses((*upper, *(f"{side}_hip_z" for side in SIDES)))
        self._lean = upper.index("abdomen_x")
        self.forces = np.zeros(0)
        """The contact forces of the last solve (N, world axes, 3 per foot that carries)."""

    def _addresses(self, joints: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        """The joints' (qpos addresses, dof addresses)."""
        return np.array([self.qadr[j] for j in joints]), np.array([self.vadr[j] for j in joints])

    def act(self, clock: GaitClock, qpos: np.ndarray, qvel: np.ndarray, reference: np.ndarray) -> np.ndarray:
        """The controls for state (qpos, qvel) in the clock's phase this step, with the LQR's setpoint pose
        `reference` (qpos: what the waist and the arms hold, and the pose a stop settles to)."""
        g, d = self.gait, self.data
        self._kinematics(qpos, qvel)
        com, vcom = d.subtree_com[1], d.subtree_linvel[1]
        feet = {side: d.geom_xpos[geom].copy() for side, geom in self.foot.items()}
        single, settling = clock.phase == clock.SINGLE, clock.phase == clock.SETTLE
        tasks: list[tuple[np.ndarray, np.ndarray, float]] = []  # (A, b, weight): A q̈ = b, weighed

        # The pelvis's attitude: the heading and the gait's pitch, or the setpoint's while settling; its yaw rate the
        # heading's (`attitude_task`).
        facing = rotation(2, clock.heading)
        attitude = facing @ (_matrix(reference[3:7]) if settling else rotation(1, g.pitch))
        jr, jrd = np.zeros((3, self.nv)), np.zeros((3, self.nv))
        mujoco.mj_jacBody(self.model, d, None, jr, self.pelvis)
        mujoco.mj_jacDot(self.model, d, None, jrd, d.xpos[self.pelvis], self.pelvis)
        wanted = attitude_task(g.w_attitude, attitude, d.xmat[self.pelvis].reshape(3, 3), jr @ qvel, clock.turn_rate)
        wanted -= jrd @ qvel
        if single:  # one point contact holds no yaw: the pelvis's yaw waits for two feet
            tasks += [(jr[:2], wanted[:2], ATTITUDE_WEIGHT), (jr[2:], wanted[2:], ATTITUDE_WEIGHT * g.yaw_single)]
        else:
            tasks.append((jr, wanted, ATTITUDE_WEIGHT))

        # The centre of mass: at the gait's height, or over the middle of the feet while settling.
        jc = np.zeros((3, self.nv))
        mujoco.mj_jacSubtreeCom(self.model, d, jc, 1)
        if settling:
            middle = 0.5 * (feet[SIDES[0]] + feet[SIDES[1]])
            tasks.append((jc[:2], _pd(g.w_height, middle[:2] - com[:2], vcom[:2]), HEIGHT_WEIGHT))
        else:
            tasks.append((jc[2:], _pd(g.w_height, g.height - com[2], vcom[2])[None], HEIGHT_WEIGHT))

        # The swing foot, on its way to the clock's landing point.
        if single:
            tasks.append(self._swing_task(clock, feet))

        # The joints: the waist and arms at the setpoint (the waist leant by `waist_roll`), and while stepping both
        # hips' yaw at the setpoint's, so that the legs turn with the pelvis. A point foot has no torsional friction:
        # with only the swing hip's yaw held, the stance leg spun about its foot while the waist turned the pelvis, its
        # hip's yaw ran to its limit and the walk ran away off its heading (docs/decisions/walker-turning.md).
        held = self._upper if settling else self._with_hips
        goal = reference[held[0]].copy()
        if not settling:
            goal[self._lean] += clock.sign * g.waist_roll
        joints = held[1], _pd(g.w_joint, goal - qpos[held[0]], qvel[held[1]])

        down = [clock.stance] if single else list(SIDES)
        contacts = [self._point(feet[side] - np.array([0.0, 0.0, self.radius]), self.foot_body[side]) for side in down]
        torque = self.solve(tasks, joints, contacts, d.qfrc_bias - d.qfrc_passive)
        return np.clip(torque / self.gear, -CTRL_LIMIT, CTRL_LIMIT)

    def _swing_task(self, clock: GaitClock, feet: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, float]:
        """The swing foot's acceleration toward its path: a quintic blend from the lift-off point to the landing,
        lifted by `Gait.clearance` in a half sine, to `LAND_DEPTH` below the floor at the step's end (it lands)."""
        g = self.gait
        side = other(clock.stance)
        swing, stance = feet[side], feet[clock.stance]
        phase = min(clock.t / clock.period, 1.0)
        blend, rate = quintic_step(phase)
        move = clock.target - clock.lift
        want, speed = np.empty(3), np.zeros(3)
        want[:2] = stance[:2] + clock.lift + blend * move
        want[2] = self.radius + g.clearance * math.sin(math.pi * phase) - LAND_DEPTH * phase
        if phase < 1.0:
            speed[:2] = rate / clock.period * move
            speed[2] = g.clearance * math.pi / clock.period * math.cos(math.pi * phase) - LAND_DEPTH / clock.period
        jacobian, bias = self._point(swing, self.foot_body[side])
        wanted = _pd(g.w_foot, want - swing, jacobian @ self.data.qvel - speed) - bias
        return jacobian, wanted, FOOT_WEIGHT

    def solve(
        self,
        tasks: list[tuple[np.ndarray, np.ndarray, float]],
        joints: tuple[np.ndarray, np.ndarray],
        contacts: list[tuple[np.ndarray, np.ndarray]],
        bias: np.ndarray,
    ) -> np.ndarray:
        """The motor torques (N·m) whose accelerations q̈ meet the tasks best by weight: weighted least squares,
        regularised on the torques and the contact forces, under the dynamics M q̈ + bias = S τ + Jcᵀ λ with every
        contact point still (Jc q̈ = -J̇c q̇). Every joint has its motor, so τ = (M q̈ + bias - Jcᵀ λ) on the joints'
        rows: the unknowns are q̈ and λ, and the root's six rows (no motor) are the dynamics' constraint, one linear
        (KKT) system. The motors' limits and a floor that only pushes by active sets: a motor over its limit is fixed
        at it (one more constraint), a contact that would pull is dropped (while another holds), and it is solved
        again. `tasks`: (A, b, weight) asking A q̈ = b; `joints`: (dofs, accelerations) asked of single joints, at
        `JOINT_WEIGHT`; `contacts`: (Jacobian, J̇ q̇) of each point held still."""
        hessian, gradient = np.zeros((self.nv, self.nv)), np.zeros(self.nv)
        for A, b, weight in tasks:
            hessian += weight * (A.T @ A)
            gradient += weight * (A.T @ b)
        dofs, accelerations = joints
        hessian[dofs, dofs] += JOINT_WEIGHT
        gradient[dofs] += JOINT_WEIGHT * accelerations
        fixed = np.full(len(self.actdof), np.nan)
        keep = list(range(len(contacts)))
        for _ in range(4):
            jc = np.vstack([contacts[i][0] for i in keep])
            jcd = np.concatenate([contacts[i][1] for i in keep])
            torque, force = self._kkt(hessian, gradient, bias, jc, jcd, fixed)
            pulling = [i for k, i in enumerate(keep) if force[3 * k + 2] < 0.0]
            if len(keep) > 1 and pulling:
                keep.remove(pulling[0])
                continue
            over = np.isnan(fixed) & (np.abs(torque) > self.limit)
            if not over.any():
                break
            fixed[over] = np.clip(torque[over], -self.limit[over], self.limit[over])
        self.forces = force
        return torque

    def _kkt(
        self,
        tasks: np.ndarray,
        gradient: np.ndarray,
        bias: np.ndarray,
        jc: np.ndarray,
        jcd: np.ndarray,
        fixed: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """One solve of `solve`'s system, the torques of `fixed` (not NaN) given: (τ, λ)."""
        nv, nl = self.nv, len(jcd)
        n = nv + nl
        free = np.isnan(fixed)
        rows = np.hstack([self.mass[self.actdof], -jc.T[self.actdof]])  # each joint's torque, less its bias
        torque_bias = bias[self.actdof]
        hessian = np.zeros((n, n))
        hessian[:nv, :nv] = tasks + 1e-6 * np.eye(nv)
        hessian[nv:, nv:] += REGULARISATION * np.eye(nl)
        regularised = rows[free]
        hessian += REGULARISATION * regularised.T @ regularised
        linear = np.zeros(n)
        linear[:nv] = gradient
        linear -= REGULARISATION * regularised.T @ torque_bias[free]
        root = np.hstack([self.mass[:6], -jc.T[:6]])
        contact = np.hstack([jc, np.zeros((nl, nl))])
        equality = np.vstack([root, rows[~free], contact])
        known = np.concatenate([-bias[:6], fixed[~free] - torque_bias[~free], -jcd])
        m = len(known)
        system = np.zeros((n + m, n + m))
        system[:n, :n] = hessian
        system[:n, n:] = equality.T
        system[n:, :n] = equality
        solution = np.linalg.solve(system, np.concatenate([linear, known]))
        torque = fixed.copy()
        torque[free] = rows[free] @ solution[:n] + torque_bias[free]
        return torque, solution[nv:n]

    def _kinematics(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        """Positions, velocities, the mass matrix and the bias forces at (qpos, qvel)."""
        m, d = self.model, self.data
        d.qpos[:], d.qvel[:] = qpos, qvel
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_crb(m, d)
        mujoco.mj_comVel(m, d)
        mujoco.mj_subtreeVel(m, d)
        mujoco.mj_passive(m, d)
        mujoco.mj_rne(m, d, 0, d.qfrc_bias)
        mujoco.mj_fullM(m, d, self.mass)

    def _point(self, point: np.ndarray, body: int) -> tuple[np.ndarray, np.ndarray]:
        """The Jacobian of a point fixed on `body`, and its time derivative times q̇."""
        jp, jd = np.zeros((3, self.nv)), np.zeros((3, self.nv))
        mujoco.mj_jac(self.model, self.data, jp, None, point, body)
        mujoco.mj_jacDot(self.model, self.data, jd, None, point, body)
        return jp, jd @ self.data.qvel


class Walker(Balanced):
    """Today's LQR expert while the body stands; from a walk command or a kick until it rests again, the gait clock
    (`task.gait.GaitClock`) and the whole-body control (`WholeBody`).

    Told what the LQR expert is told (the observation, the body, the delay, the command); deterministic: the same
    state, gait clock and command give the same action. The walk follows the expert's setpoint, whose velocities ramp
    toward the command (each field's `rate`: `task.posture.PosturePath`)."""

    name = "walker"
    walks = True
    handover = STEPPING

    def __init__(self, delay: int = 0, gait: Gait | None = None) -> None:
        super().__init__(delay)  # the balance stands the body and moves the setpoint every step
        gait = load_gait() if gait is None else gait
        self.clock = GaitClock(copy.copy(self.expert.model), gait)
        self.body = WholeBody(copy.copy(self.expert.model), gait)
        self._qpos = np.zeros(self.expert.model.nq)
        self.stepped = 0
        """Env steps of this episode the whole-body control acted on."""

    def reset(self, seed: int | None = None) -> None:
        self.balance.reset(seed)
        self.clock.reset()
        self.stepped = 0

    def state(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The state (qpos with root x = y = 0, qvel) it acts on, after this step's balance: the simulator's."""
        self._qpos[2:] = obs[QPOS_OBS]
        return self._qpos, obs[QVEL_OBS]

    def _balance(self, obs: np.ndarray) -> np.ndarray:
        """The balance's action on this step's observation."""
        return self.balance.act(obs)

    def _estimate(self, obs: np.ndarray) -> None:
        """While the walk acts, what moves its state estimate on (the simulator's state: nothing)."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        clock = self.clock
        if clock.active:
            self._estimate(obs)
            qpos, qvel = self.state(obs)
            acted_on = self.expert.predicted(qpos, qvel)  # under latency: where the actions in flight take it
            self.expert.follow()  # the setpoint moves on, and this step's action joins those in flight
        else:
            action = self._balance(obs)  # the setpoint (and the estimate) move on with it
            qpos, qvel = self.state(obs)
            acted_on = (qpos, qvel)  # a walk's first step, under latency one step late
        posture = self.expert.posture  # the command filter's, as a walking student's ramp has it
        velocity = np.array([getattr(posture, name) for name in VELOCITY_NAMES])
        if not clock.tick(qpos, qvel, velocity):  # the clock on the estimate, as the student's runs
            return action
        self.stepped += 1
        controls = self.body.act(clock, *acted_on, self.expert.qpos_ref).astype(np.float32)
        clock.advance(velocity)
        self.expert.ran(controls)  # what its predictor steps once it balances again under latency
        if clock.done:  # at rest over its feet: the LQR balances from the next step, facing where the walk left it
            self.expert.heading = clock.heading
        return controls


class SensedWalker(Walker):
    """`Walker` on what a robot senses: its balance is the expert on leg odometry (`SensedExpert`), and the clock and
    the whole-body control act on that estimate, whose velocity only the feet the gait holds still correct
    (`GaitClock.still`: `humanoid.estimator.LegOdometry`), so its students can compute what it does."""

    name = "walker-sensed"
    on_estimate = True

    def _balance(self, obs: np.ndarray) -> np.ndarray:
        """Standing, once a kick would start a walk (`task.handover.STEPPING` armed), its odometry runs on the gait's
        schedule, both feet held: a kick is taken in at once (docs/decisions/leg-odometry.md)."""
        self.balance.still = self.clock.schedule()
        return super()._balance(obs)

    def state(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The leg odometry's estimate of this step."""
        return self.balance.estimate

    def _estimate(self, obs: np.ndarray) -> None:
        """The estimate moves on, its velocity corrected by the feet the gait holds still."""
        self.balance.still = self.clock.schedule()
        self.balance.observe(obs)
