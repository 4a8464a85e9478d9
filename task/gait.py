"""The walker's gait clock: when a walk starts, which foot swings, where it lands, when it has landed and when the walk
is over, computed alike by the walking teacher and by its students (docs/decisions/walking-teacher.md).

Humanoid-v5 is a point-footed biped (sphere feet, no ankle): where the swing foot lands sets the next step's
velocity. The clock is a deterministic function of a state (qpos, qvel; the leg odometry's estimate for a teacher or a
student on what a robot senses), the command filter's velocity and its own history, as `task.handover`'s rule is:

    state ──> centre of mass c, velocity ċ, capture point ξ = c + ċ/ω, the feet, the pelvis's yaw
    start ──> a walk commanded, or, once armed, ξ off the feet (a kick: `task.handover.STEPPING`); the first swing
              is the foot farther from ξ
    single support ─> `Gait.period` (the first step `Gait.first` of it), cut short when ξ would leave the legs' reach;
                      the landing: ξ predicted to the landing, scaled by gains, less the offset a steady gait at the
                      commanded velocity keeps (`GaitClock.placement`); under the zero command, once
                      ξ lands between the feet, the last step
    landing ────────> the swing foot down once its time is up; then double support (`Gait.double`), or after the last
                      step settling, until the body rests over its feet (`SETTLE_SECONDS`): the walk is over

`teachers.walker` turns the clock's phase and landing point into torques (whole-body control); a walking student reads
`GaitClock.features`. The gait's free parameters (`Gait`) were tuned by CMA-ES on selection seeds
(`make tune-walker`); the chosen values are in `GAIT_FILE`.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import mujoco
import numpy as np

from common.cli import UserError, write_json
from humanoid.capture import capture_offset
from humanoid.env import step_seconds
from humanoid.physics import FOOT_GEOMS, TORSO_BODY
from task.handover import STEPPING

G = 9.81
SIDES = ("right", "left")
"""The feet, in `humanoid.physics.FOOT_GEOMS` order."""
GAIT_FILE = Path(__file__).with_name("gait.json")
"""The tuned `Gait`, with the run that chose it (`make tune-walker` writes it)."""
GAIT_VERSION = 1
"""Bumped whenever `Gait`'s fields or their meaning change: a file of another version is refused."""

MAX_STEP = 0.40
"""m: the farthest a foot lands ahead of or behind the stance foot (the legs' reach)."""
MAX_SIDE = 0.32
"""m: the farthest a foot lands beside the stance foot: hip_x abducts 25°, and a swing of 0.2 s reached 0.31 m."""
SHORTEST_STEP = 0.15
"""s: the least single support a step is cut to (`GaitClock.cut`): the swing foot must lift and move."""
STOP_REACH = 0.035
"""m: the farthest ahead of or behind the stance foot the capture point may be at the landing for the walk's last
step: it lands twice as far, so that the capture point is between the feet, where the LQR takes over. The LQR stands
from rest in stances up to 0.074 m out of line (docs/decisions/walker-stopping.md); farther, the walker steps on in
place, which slows it."""
STOP_MARGIN = 0.15
"""m: how far inside the widest last step the capture point must be at the landing for the last step: at 0.15 (the
capture point at most halfway) a tuned gait walked 12 of 12 selection schedules, at 0.05 6 of 12, its settles
stepping on. The gait tuned since sways 0.20 m, past it, and steps on in place (docs/decisions/walker-stopping.md)."""
LAST_WIDTH = (0.18, 0.30)
"""m: the least and the most the feet are apart sideways after the last step: the LQR stands from rest in these
(its design's 0.18 to 0.33), and in narrower ones less often."""
SETTLE_SECONDS = (0.15, 1.0)
"""s: the least and the most a stop settles before the walk is over; past the most, the walk steps on."""
REST_SPEED = 0.05
"""m/s: the centre of mass's horizontal speed below which a settling body is at rest."""
FIRST_SWING_MARGIN = 0.02
"""m: how much nearer one foot must be to the capture point than the other to stand on it for the first step."""
MAX_LAG = 0.15
"""rad: the farthest the heading the walk turns to runs ahead of the pelvis's yaw: a body that cannot turn as fast as
commanded (one point contact holds no yaw) is not asked for an ever larger turn."""
TOUCH_HEIGHT = 0.005
"""m: the swing foot's sphere is down when its lowest point is this close to the floor."""


@dataclass(frozen=True)
class Gait:
    """The walker's free parameters, each with its unit: what `make tune-walker` tunes."""

    period: float
    """s: single support of a step."""
    double: float
    """s: double support after each landing, where the two feet turn the body (a point foot holds no yaw)."""
    first: float
    """The first step's single support, a share of `period`: a kick or a start is caught sooner."""
    height: float
    """m: the centre of mass's height while stepping."""
    clearance: float
    """m: how high the swing foot lifts."""
    width: float
    """m: the sideways distance between the feet of a steady walk in place."""
    min_side: float
    """m: the least sideways distance a foot lands from the stance foot (the legs cannot cross)."""
    k_x: float
    """Feedback on the capture point's predicted error, fore and aft (1: deadbeat in one step)."""
    k_y: float
    """The same, sideways."""
    pitch: float
    """rad: the pelvis's pitch while stepping, + forward."""
    waist_roll: float
    """rad: the torso leant through the waist toward the swing side (+) or the stance side (-)."""
    w_attitude: float
    """1/s: the pelvis attitude's natural frequency (critically damped)."""
    w_height: float
    """1/s: the centre of mass's height's."""
    w_foot: float
    """1/s: the swing foot's path's."""
    w_joint: float
    """1/s: the waist's, the arms' and the hips' yaw's."""
    yaw_single: float
    """The pelvis's yaw's weight in single support, a share of the attitude's: one point contact holds no yaw."""

    @property
    def omega(self) -> float:
        """1/s: the capture point's time constant at `height`."""
        return math.sqrt(G / self.height)


def read_gait(path: Path) -> tuple[Gait, dict | None]:
    """The gait at `path` and the run that tuned it; ValueError saying why not (missing, unreadable, another
    version)."""
    try:
        saved = json.loads(path.read_text())
        if saved.get("version") != GAIT_VERSION:
            raise ValueError(f"version {saved.get('version')}, not {GAIT_VERSION}")
        return Gait(**{f.name: float(saved["gait"][f.name]) for f in fields(Gait)}), saved.get("tuning")
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as error:
        raise ValueError(f"{path} holds no walker gait of version {GAIT_VERSION} ({error})") from None


def is_gait_file(path: Path) -> bool:
    """Whether `path` holds a walker gait of any version: a file `make tune-walker` may replace."""
    try:
        saved = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(saved, dict) and {"version", "gait"} <= saved.keys()


def load_gait(path: Path = GAIT_FILE) -> Gait:
    """The tuned gait at `path`; UserError in one line naming `make tune-walker` if it is missing, unreadable or of
    another version (and, for the committed file, how to restore it)."""
    try:
        return read_gait(path)[0]
    except ValueError as error:
        restore = f", or `git checkout task/{path.name}` for the committed one" if path == GAIT_FILE else ""
        raise UserError(f"{error}: run `make tune-walker`{restore}") from None


def save_gait(gait: Gait, path: Path, tuning: dict) -> None:
    """Write `gait` to `path` with its version and how it was tuned, whole or not at all (a kill mid-write leaves the
    file that was there)."""
    write_json(path, {"version": GAIT_VERSION, "gait": asdict(gait), "tuning": tuning})


def rotation(axis: int, angle: float) -> np.ndarray:
    """The 3×3 rotation by `angle` (rad) about axis `axis` (0 x, 1 y, 2 z)."""
    c, s = math.cos(angle), math.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def other(side: str) -> str:
    """The other foot."""
    return SIDES[1 - SIDES.index(side)]


@dataclass
class Points:
    """What the clock reads of a state: the centre of mass and its velocity, the feet's centres (by side), the
    pelvis's yaw (rad)."""

    com: np.ndarray
    velocity: np.ndarray
    feet: dict[str, np.ndarray]
    yaw: float


class GaitClock:
    """The gait clock on a copy of the nominal model: one `tick` per env step before the controls, one `advance`
    after. While it is `active` its `phase`, `stance`, `t`, `period`, `lift`, `target` and `heading` say what the
    walker's whole-body control does this step; `done` once a walk has come to rest."""

    SINGLE, DOUBLE, SETTLE = "single", "double", "settle"
    PHASES = (SINGLE, DOUBLE, SETTLE)

    def __init__(self, model: mujoco.MjModel, gait: Gait) -> None:
        self.gait = gait
        self.model = model
        self.data = mujoco.MjData(model)
        self.dt = step_seconds(model)
        self._feet = {side: model.geom(geom).id for side, geom in zip(SIDES, FOOT_GEOMS, strict=True)}
        self.radius = float(model.geom_size[self._feet[SIDES[0]]][0])
        self._torso = model.body(TORSO_BODY).id
        self._pelvis = model.body("pelvis").id
        self.reset()

    def reset(self) -> None:
        """Standing, facing +x, the hand-over rule not yet armed: where an episode starts."""
        self.active = self.done = False
        self.ticks = 0
        self.heading = 0.0
        """rad: the yaw the walk faces, which turns with the command; kept when a walk ends."""
        self.turn_rate = 0.0
        """rad/s: how fast the heading turns, the command filter's turn rate (the whole-body control's yaw rate)."""
        self.phase, self.stance, self.steps = self.SINGLE, SIDES[0], 0
        self._single()

    def _single(self) -> None:
        """A step begins: single support on `stance`."""
        self.phase = self.SINGLE
        self.t = 0.0
        self.period = self.gait.period * (self.gait.first if self.steps == 0 else 1.0)
        """s: this step's single support, which a capture point out of reach cuts short (`cut`)."""
        self.lift: np.ndarray | None = None
        """The swing foot's lift-off point, relative to the stance foot (m, world axes), read at the first tick."""
        self.target = np.zeros(2)
        """Where the swing foot lands, relative to the stance foot (m, world axes)."""
        self.stopping = False
        """Whether that is the walk's last step."""

    def points(self, qpos: np.ndarray, qvel: np.ndarray) -> Points:
        """What the clock reads of the state (qpos, qvel) (root x and y may be 0: only differences are read)."""
        model, data = self.model, self.data
        data.qpos[:], data.qvel[:] = qpos, qvel
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        mujoco.mj_comVel(model, data)
        mujoco.mj_subtreeVel(model, data)
        frame = data.xmat[self._pelvis]
        return Points(
            data.subtree_com[self._torso].copy(),
            data.subtree_linvel[self._torso].copy(),
            {side: data.geom_xpos[geom].copy() for side, geom in self._feet.items()},
            math.atan2(frame[3], frame[0]),
        )

    def tick(self, qpos: np.ndarray, qvel: np.ndarray, velocity: np.ndarray) -> bool:
        """This env step, before the controls, at state (qpos, qvel) under the command filter's `velocity` (forward
        m/s, sideways m/s, turn rad/s): start a walk if one is commanded or, once armed, the capture point has left
        the feet; while walking, turn the heading, run the phase's time on, and place the swing foot. True while
        walking (the walker's stepping law acts), False while standing (the LQR's)."""
        self.ticks += 1
        self._now = now = self.points(qpos, qvel)
        if not self.active:
            kicked = STEPPING.armed(self.ticks) and STEPPING.leaves(*self._offset(now))
            if not (velocity.any() or kicked):
                return False
            self.start(self.first_swing(now, velocity))
        self.turn_rate = float(velocity[2])
        lag = math.remainder(self.heading + self.turn_rate * self.dt - now.yaw, math.tau)
        self.heading = now.yaw + min(max(lag, -MAX_LAG), MAX_LAG)  # turns no faster than the feet turn the body
        self.t += self.dt
        if self.phase == self.SINGLE:
            turn = rotation(2, self.heading)[:2, :2]
            stance, swing = now.feet[self.stance], now.feet[other(self.stance)]
            if self.lift is None:
                self.lift = swing[:2] - stance[:2]
            self.cut(now, turn, velocity)
            self.target, self.stopping = self.placement(now, turn, velocity, max(self.period - self.t, 0.0))
        return True

    def start(self, swing: str) -> None:
        """Begin walking: `swing` ("right", "left") lifts first, the body facing `heading`."""
        self.active, self.done = True, False
        self.stance = other(swing)
        self.steps = 0
        self._single()

    def first_swing(self, now: Points, velocity: np.ndarray) -> str:
        """The foot a walk starts with: the one farther from the capture point, so that the stance foot is the one
        nearer it, where it grows the least (a kick sideways is caught by a step of the inner foot and then one of
        the outer: the legs cannot cross); with the capture point between the feet, the one on the side walked to,
        else the left."""
        capture = now.com[:2] + now.velocity[:2] / self.gait.omega
        right, left = (float(np.linalg.norm(now.feet[side][:2] - capture)) for side in SIDES)
        if abs(right - left) > FIRST_SWING_MARGIN:
            return "left" if right < left else "right"
        return "left" if velocity[1] >= 0 else "right"

    def cut(self, now: Points, turn: np.ndarray, velocity: np.ndarray) -> None:
        """Cut this step short where the capture point, growing as e^{ωt} until the landing, would leave the legs'
        reach: land while the step the law asks for is still within it (at the earliest `SHORTEST_STEP` after the
        lift-off). A kick of 0.5 m/s moves ξ about 0.15 m, which triples over a 0.35 s step."""
        g = self.gait
        stance = now.feet[self.stance]
        pull = np.abs(np.array([g.k_x, g.k_y]) * (turn.T @ (now.com[:2] + now.velocity[:2] / g.omega - stance[:2])))
        growth = math.exp(g.omega * (g.period + g.double))
        steady = np.abs(velocity[:2]) * (g.period + g.double) / (growth - 1.0) + [0.0, g.width / (growth + 1.0)]
        allowed = float(((np.array([MAX_STEP, MAX_SIDE]) + steady) / np.maximum(pull, 1e-9)).min())
        remaining = math.log(allowed) / g.omega if allowed > 1.0 else 0.0
        self.period = max(min(self.period, self.t + remaining), min(SHORTEST_STEP, self.period))

    def placement(
        self, now: Points, turn: np.ndarray, velocity: np.ndarray, remaining: float
    ) -> tuple[np.ndarray, bool]:
        """Where the swing foot lands, relative to the stance foot (m, world axes), and whether it is the last step.

        The divergent-component step law: the capture point ξ = c + ċ/ω, predicted to the landing (`remaining` s of
        single support on a point foot: ξ - p grows as e^{ωt}), scaled by the gains (`Gait.k_x`, `Gait.k_y`), less
        the offset a steady gait at the commanded `velocity` keeps between ξ and the next foot, in the heading's frame
        (`turn`), within the legs' reach. The offset is a deadbeat gait's (gain 1) whatever the gains: the tuned gait
        walks at about 57 % of the command, and the exact offset for the gains (H-LIP's form) tracked the command but
        fell, tuned or not; that margin keeps the gait up (docs/decisions/walker-speed.md). Under the zero command,
        once ξ lands within `STOP_REACH` of the stance foot's line and at least `STOP_MARGIN` short of the widest last
        step, the foot lands twice as far (within `LAST_WIDTH`): the last step, ξ between the feet."""
        g = self.gait
        sign = self.sign
        stance = now.feet[self.stance]
        capture = now.com[:2] + now.velocity[:2] / g.omega
        ahead = turn.T @ ((capture - stance[:2]) * math.exp(g.omega * remaining))  # ξ at the landing, heading frame
        if not velocity.any() and abs(ahead[0]) <= STOP_REACH and 0.0 < sign * ahead[1] <= LAST_WIDTH[1] - STOP_MARGIN:
            side = min(max(2.0 * sign * ahead[1], LAST_WIDTH[0]), LAST_WIDTH[1])
            return turn @ np.array([2.0 * ahead[0], sign * side]), True
        growth = math.exp(g.omega * (g.period + g.double))
        steady = velocity[:2] * (g.period + g.double) / (growth - 1.0)
        steady[1] -= sign * g.width / (growth + 1.0)
        step = np.array([g.k_x, g.k_y]) * ahead - steady
        step[0] = min(max(step[0], -MAX_STEP), MAX_STEP)
        step[1] = sign * min(max(sign * step[1], g.min_side), MAX_SIDE)
        return turn @ step, False

    @property
    def sign(self) -> float:
        """+1 while the left foot swings (it lands left of the stance foot), -1 while the right does."""
        return 1.0 if self.stance == SIDES[0] else -1.0

    def advance(self, velocity: np.ndarray) -> None:
        """This env step, after the controls, on what `tick` read: a landing (the swing foot down once its time is up,
        or half a period late), the next step after double support, the end of a settle (at rest: the walk is over;
        walked on, kicked or not at rest in time: it steps on)."""
        if not self.active:
            return
        now = self._now
        if self.phase == self.SINGLE:
            down = now.feet[other(self.stance)][2] < self.radius + TOUCH_HEIGHT
            if (down and self.t >= self.period - 1e-9) or self.t >= 1.5 * self.period:
                self.phase, self.t = (self.SETTLE if self.stopping else self.DOUBLE), 0.0
        elif self.phase == self.DOUBLE:
            if self.t >= self.gait.double - 1e-9:
                self._next()
        else:
            offset, speed = self._offset(now)
            if velocity.any() or offset > STEPPING.trigger_offset or self.t >= SETTLE_SECONDS[1]:
                self._next()
            elif self.t >= SETTLE_SECONDS[0] and speed < REST_SPEED:
                self.active, self.done = False, True

    def _next(self) -> None:
        """The landed foot takes the weight: the next step swings the other."""
        self.stance = other(self.stance)
        self.steps += 1
        self._single()

    @staticmethod
    def _offset(now: Points) -> tuple[float, float]:
        return capture_offset(now.com, now.velocity, now.feet["left"], now.feet["right"])

    def still(self) -> np.ndarray:
        """Which feet (`FOOT_GEOMS` order) the gait holds still now: the stance foot, or both (standing too)."""
        if self.active and self.phase == self.SINGLE:
            return np.array([side == self.stance for side in SIDES])
        return np.ones(len(SIDES), bool)

    def schedule(self) -> np.ndarray | None:
        """The feet the leg odometry may take as held still now (`humanoid.estimator.LegOdometry`'s `still`): while
        walking `still`'s; standing, both once the hand-over rule is armed, so that a kick is taken in at once; before,
        none: the landing after a reset is the LQR's, and closing its gaps at once fell more
        (docs/decisions/leg-odometry.md)."""
        return self.still() if self.active or STEPPING.armed(self.ticks) else None

    FEATURES = (
        "walking",
        "single",
        "double",
        "settle",
        "left_swings",
        "progress_sin",
        "progress_cos",
        "target_fore",
        "target_side",
    )
    """The names of `features`' entries."""

    def features(self) -> np.ndarray:
        """What a walking student reads of the clock (`FEATURES`): whether a walk is on, its phase (one-hot), which
        foot swings, how far the single support has gone (sin and cos of π·t/period), and where the swing foot lands
        relative to the stance foot in the heading's frame (m); zeros while standing."""
        if not self.active:
            return np.zeros(len(self.FEATURES))
        progress = math.pi * min(self.t / self.period, 1.0) if self.phase == self.SINGLE else math.pi
        target = rotation(2, self.heading)[:2, :2].T @ self.target
        return np.array(
            [
                1.0,
                *(float(self.phase == phase) for phase in self.PHASES),
                float(self.stance == SIDES[0]),
                math.sin(progress),
                math.cos(progress),
                *target,
            ]
        )
