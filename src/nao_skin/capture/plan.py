"""Where to press next and how to get there: the target chooser, the fingertip's inverse kinematics and the approach.

Everything here is planned under the calibration the robot believes (nominal or the live one), never a ground
truth: the approach runs ``approach_margin`` beyond the believed surface so a skin a few millimetres off still
gets touched, and the safety gate (:mod:`nao_skin.capture.safety`) stops anything beyond that.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from nao_skin import se3
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.sim.poses import _chain_joint_columns, _spot_kinematics, outside_body

# IK: metres of fingertip error one radian away from the preferred posture costs; small, so it only picks
# among the arm's many poses for one fingertip point (the chain has five joints for three coordinates)
POSTURE_WEIGHT = 0.002
IK_STARTS, IK_STARTS_SEED = 8, 0
FOLLOW_STEPS, FOLLOW_DAMPING = 6, 1e-6    # Gauss-Newton steps per approach waypoint, damping (m^2)
IK_TOLERANCE = 0.0005        # m: a pose whose fingertip misses its goal by more is no solution
MAX_JOINT_STEP = 0.08        # rad between two approach waypoints: more is a jump of the arm, not a straight line
FOREARM_PROBES = np.linspace(0.0, 1.0, 5)     # points from the elbow (0) to the hand's far end (1)
OVER_SKIN = 0.02             # m sideways from the nearest taxel within which a point is over the skin
WAYPOINT_SPACING = 0.005     # m between two solved approach waypoints; the steps between are interpolated
TRANSIT_SAMPLES = 8          # poses checked along a joint-space move between two standoffs


@dataclass(frozen=True)
class CaptureOptions:
    """What a capture session may do; the node's parameters (``session.params.FINGERTIP_CAPTURE``) set them."""

    limit_margin: float = 0.02      # rad kept from every joint limit, in every command
    standoff: float = 0.02          # m: the fingertip's surface this far off the skin before the approach
    approach_margin: float = 0.005  # m: the approach goes at most this far beyond the believed surface
    step: float = 0.001             # m of fingertip travel between two contact checks of the approach
    # after the first contact, press on (in half steps) while the highest pressure still rises (the fabric gives:
    # the fingertip is not on the skin yet), at most this far (m) beyond the first contact (the simulator's
    # fabric fires 2-5 mm before the fingertip is on it: the press ends about on it)
    press_max: float = 0.0019
    contact_wait: float = 0.05      # s the skin is read after each step (skinManager's 50 Hz and the transport)
    hold: float = 0.3               # s the press is held
    move_speed: float = 0.2         # fraction of the joints' maximum speed: moves between standoffs
    approach_speed: float = 0.05    # ... the approach and the press
    retract_speed: float = 0.1      # ... the retract
    stiffness: float = 0.8          # the arm's stiffness while it moves (0-1)
    clearance: float = 0.015        # m the elbow, forearm and hand keep off the target's surface
    stale_after: float = 0.5        # s: joint states or skin readings older hold the arm (STALE_HOLD), then stop


@dataclass(frozen=True)
class Arm:
    """The fingertip's chain: its NAOqi joint names, their columns in the robot's ``q`` and the limits less the
    margin, the only range any command may take."""

    chain: str
    names: tuple
    cols: np.ndarray
    lo: np.ndarray
    hi: np.ndarray

    def within(self, q_arm: np.ndarray) -> np.ndarray:
        """(N,) True where every joint of ``q_arm`` (N, V) lies within the limits less the margin."""
        q_arm = np.atleast_2d(q_arm)
        return np.all((q_arm >= self.lo - 1e-12) & (q_arm <= self.hi + 1e-12), axis=1)


def arm_of(skin: SkinModel, fingertip: str, margin: float) -> Arm:
    robot = skin.robot
    chain = robot.fingertip(fingertip).chain
    cols = np.array([c for _, c in _chain_joint_columns(skin, chain)], int)
    lo, hi = robot.limits[cols, 0] + margin, robot.limits[cols, 1] - margin
    if np.any(lo >= hi):
        from nao_skin.errors import ConfigError
        raise ConfigError(f"limit_margin {margin:g} rad leaves no range to a joint of {chain}")
    return Arm(chain, tuple(robot.joint_names[c] for c in cols), cols, lo, hi)


@dataclass
class Approach:
    """One planned touch: ``path[0]`` the standoff pose, then the waypoints of the straight approach along the
    normal, ``travel[k]`` (m) the fingertip's way from the standoff to waypoint k (the last: standoff plus
    margin beyond the surface)."""

    slot: int
    point: np.ndarray            # (3,) believed taxel position, base frame
    normal: np.ndarray           # (3,) its outward normal
    path: np.ndarray             # (K, V) arm joint angles
    travel: np.ndarray           # (K,) m

    @property
    def budget(self) -> float:
        """m of approach the gate allows before it calls it "no contact"."""
        return float(self.travel[-1])


class Planner:
    """Poses of ``fingertip`` over taxels of ``part`` under ``calibration`` (the robot's belief)."""

    def __init__(self, skin: SkinModel, calibration: SkinCalibration, fingertip: str, part: str,
                 options: CaptureOptions):
        self.skin, self.options, self.part = skin, options, part
        self.arm = arm_of(skin, fingertip, options.limit_margin)
        robot = skin.robot
        self.centre, self.radius = calibration.fingertip_sphere(robot, fingertip)
        self.fabric = calibration.fabric_thickness or 0.0
        sp = skin.parts[part]
        if sp.chain is not None:
            from nao_skin.errors import ConfigError
            raise ConfigError(f"part {part}: the capture presses parts fixed to the base (the torso) only")
        pos, nor = sp.taxel_positions(calibration.parts.get(part))
        self.slots = sp.slots
        self.points, self.normals = pos[self.slots], nor[self.slots]
        self._cols = _chain_joint_columns(skin, self.arm.chain)
        self._plans: dict = {}
        self._aim: dict = {}          # row -> (3,) m added to where a taxel's touch aims (aim_again)
        self.rest = np.array([robot.body.rest_posture.get(n, (0.0, 0.0))[0] for n in robot.joint_names])
        self.rest[self.arm.cols] = np.clip(self.rest[self.arm.cols], self.arm.lo, self.arm.hi)
        # where the IK starts after the arm's own posture: the rest, then a fixed spread over the limits (one
        # start alone ends in the local minimum of an arm folded the wrong way)
        spread = np.random.default_rng(IK_STARTS_SEED).uniform(size=(IK_STARTS, len(self.arm.cols)))
        self.starts = np.concatenate([self.rest[None, self.arm.cols], self.arm.lo + spread * (self.arm.hi - self.arm.lo)])

    # ------------------------------------------------------------------ kinematics
    def full(self, q_arm: np.ndarray) -> np.ndarray:
        """(N, J) robot joint angles: the rest posture with the arm's joints set."""
        q_arm = np.atleast_2d(q_arm)
        q = np.repeat(self.rest[None], len(q_arm), axis=0)
        q[:, self.arm.cols] = q_arm
        return q

    def fingertip(self, q_arm: np.ndarray) -> np.ndarray:
        """(N, 3) the sphere's centre, base frame."""
        return se3.transform_points(self.skin.robot.fk(self.arm.chain, self.full(q_arm)), self.centre)

    def solve(self, goal: np.ndarray, starts: np.ndarray) -> np.ndarray | None:
        """Arm angles putting the sphere's centre at ``goal`` (3,), within the limits less the margin: scipy's
        least squares from each of ``starts`` (M, V) in turn, near that start's posture; None if none gets
        within :data:`IK_TOLERANCE`."""
        def residual(x, ref):
            return np.r_[self.fingertip(x)[0] - goal, POSTURE_WEIGHT * (x - ref)]

        def jacobian(x, ref):
            _, _, dp, _ = _spot_kinematics(self.skin, self.arm.chain, self.full(x), self.centre[None],
                                           np.zeros((1, 3)), self._cols)
            return np.r_[dp[0], POSTURE_WEIGHT * np.eye(len(x))]

        for start in np.atleast_2d(starts):
            x0 = np.clip(start, self.arm.lo, self.arm.hi)
            fit = least_squares(residual, x0, jac=jacobian, bounds=(self.arm.lo, self.arm.hi), args=(x0,),
                                xtol=1e-8, ftol=1e-10, max_nfev=60)
            if np.linalg.norm(self.fingertip(fit.x)[0] - goal) <= IK_TOLERANCE:
                return fit.x
        return None

    def follow(self, q0: np.ndarray, goals: np.ndarray) -> np.ndarray | None:
        """(K + 1, V) arm angles from ``q0`` through each of ``goals`` (K, 3) in turn, each from the last by
        damped Gauss-Newton steps kept within the limits less the margin (the goals a few millimetres apart: a
        handful of steps, where a fresh least-squares solve per waypoint took ten times as long); None when a
        goal is missed by more than :data:`IK_TOLERANCE`."""
        path = [q0]
        for goal in goals:
            q = path[-1].copy()
            for _ in range(FOLLOW_STEPS):
                pos, _, dp, _ = _spot_kinematics(self.skin, self.arm.chain, self.full(q), self.centre[None],
                                                 np.zeros((1, 3)), self._cols)
                err = goal - pos[0]
                if np.linalg.norm(err) <= 0.1 * IK_TOLERANCE:
                    break
                jac = dp[0]
                q = np.clip(q + jac.T @ np.linalg.solve(jac @ jac.T + FOLLOW_DAMPING * np.eye(3), err),
                            self.arm.lo, self.arm.hi)
            if np.linalg.norm(self.fingertip(q)[0] - goal) > IK_TOLERANCE:
                # a joint at its limit stalls the clipped steps: the bounded solver finds the way along it
                q = self.solve(goal, path[-1][None])
                if q is None:
                    return None
            path.append(q)
        return np.array(path)

    # ------------------------------------------------------------------ clearance
    def surface_height(self, points: np.ndarray) -> np.ndarray:
        """(N,) height of ``points`` (N, 3) over the part's believed skin (fabric included): along the normal of
        the nearest taxel, from its tangent plane; +inf where a point is not over the skin (farther than
        :data:`OVER_SKIN` from the nearest taxel sideways: beside the part, which the torso box covers)."""
        d = np.linalg.norm(points[:, None] - self.points[None], axis=2)
        near = np.argmin(d, axis=1)
        rel = points - self.points[near]
        height = np.einsum("nk,nk->n", rel, self.normals[near])
        lateral = np.linalg.norm(rel - height[:, None] * self.normals[near], axis=1)
        return np.where(lateral <= OVER_SKIN, height - self.fabric, np.inf)

    def clear(self, q_arm: np.ndarray, fingertip_min: float | None = None) -> np.ndarray:
        """(N,) True where the arm is clear of the body: the elbow and the hand's far end out of the torso box,
        the forearm (elbow to hand end) at least ``clearance`` over the part's skin, and (``fingertip_min``)
        the fingertip's surface at least that over it."""
        q = self.full(q_arm)
        robot = self.skin.robot
        end = robot.fk(self.arm.chain, q)
        hand_end = robot.body.hand_end if robot.body.hand_end is not None else np.zeros(3)
        probes = se3.transform_points(end[:, None], FOREARM_PROBES[:, None] * hand_end[None])    # (N, P, 3)
        n, m = probes.shape[:2]
        high = self.surface_height(probes.reshape(-1, 3)).reshape(n, m).min(axis=1) >= self.options.clearance
        ok = outside_body(self.skin, self.arm.chain, q) & high
        if fingertip_min is not None:
            ok &= self.surface_height(self.fingertip(q_arm)) - self.radius >= fingertip_min
        return ok

    def transit_clear(self, a: np.ndarray, b: np.ndarray) -> bool:
        """A joint-space move from ``a`` to ``b`` keeps the arm clear and the fingertip at half the standoff."""
        s = np.linspace(0.0, 1.0, TRANSIT_SAMPLES)[:, None]
        return bool(self.clear(a + s * (b - a), 0.5 * self.options.standoff).all())

    # ------------------------------------------------------------------ a touch
    def plan(self, row: int, q_now: np.ndarray) -> Approach | str:
        """The approach to taxel row ``row`` (of :attr:`slots`) from the arm at ``q_now``, or why none: from each
        IK start in turn (the arm's own posture first), the standoff pose, then the line down the normal. A
        taxel's answer is kept: a second touch there takes the same approach (the move to its standoff is
        checked on its own), where solving again cost a few tenths of a second a touch."""
        if row not in self._plans:
            self._plans[row] = self._plan(row, q_now)
        return self._plans[row]

    def aim_again(self, row: int, fired_slots) -> None:
        """A touch aimed at ``row`` fired ``fired_slots`` but not the taxel itself (the skin lies a few millimetres
        off the belief): the next touch there aims as far the other way in the skin's plane, where the
        fingertip then lands on the taxel. The taxel's plan is made again."""
        rows = np.flatnonzero(np.isin(self.slots, fired_slots))
        if not len(rows) or np.isin(self.slots[row], fired_slots):
            return
        miss = self.points[rows].mean(axis=0) - (self.points[row] + self._aim.get(row, 0.0))
        miss -= (miss @ self.normals[row]) * self.normals[row]
        self._aim[row] = self._aim.get(row, 0.0) - miss
        self._plans.pop(row, None)

    def _plan(self, row: int, q_now: np.ndarray) -> Approach | str:
        o = self.options
        point, normal = self.points[row] + self._aim.get(row, 0.0), self.normals[row]
        lift = self.fabric + self.radius
        length = o.standoff + o.approach_margin
        solved = np.linspace(0.0, length, max(int(np.ceil(length / WAYPOINT_SPACING)), 1) + 1)
        goals = point + (lift + o.standoff - solved)[:, None] * normal
        # the steps between solved waypoints, interpolated in joint space: over 5 mm the line bends by microns
        travel = np.r_[np.arange(0.0, length, o.step), length]
        why = "no pose within the joint limits less the margin"
        # a start of the taxel's own first (seeded by it), then the arm's posture, then the fixed spread: the
        # fingertip reaches each taxel with the hand turned its own way, which the calibration needs to tell the
        # fingertip's sphere from the skin's place (every touch from one posture left the sphere's centre 4 mm
        # off and the torso 3 mm: a sphere offset along the hand looks like a shifted skin)
        own = self.arm.lo + np.random.default_rng([IK_STARTS_SEED, row]).uniform(size=len(self.arm.cols)) * (
            self.arm.hi - self.arm.lo)
        for start in np.concatenate([own[None], q_now[None], self.starts]):
            path = [self.solve(goals[0], start[None])]
            if path[0] is None:
                continue
            if not self.clear(path[0][None])[0]:
                why = "no pose with the arm clear of the body"
                continue
            path = self.follow(path[0], goals[1:])
            if path is None:
                why = "the approach line leaves the joint limits less the margin"
                continue
            path = np.stack([np.interp(travel, solved, path[:, j]) for j in range(path.shape[1])], axis=1)
            if np.any(np.abs(np.diff(path, axis=0)) > MAX_JOINT_STEP):
                why = "the approach line needs a jump of the arm"
                continue
            if not self.clear(path).all():
                why = "the arm is not clear of the body on the approach"
                continue
            return Approach(int(self.slots[row]), point, normal, path, travel)
        return why


@dataclass
class TargetChooser:
    """Which taxel of the part to press next, and with which arm (``arms``: one per fingertip of the session).

    One no touch has reached first (of ``priority`` triangles first: the guidance's), then one whose touch fired
    only its neighbours (aimed again, up to ``retries`` times), then the least fired;
    among equals the one farthest from every taxel touched so far. An arm takes the targets it has not found
    out of its reach; the arm to use is the one whose best target is the least touched (the arm in use on a
    tie: an arm changes only when the other one has taxels to press that this one cannot reach). Taxels no
    pose of an arm reaches are marked for that arm; a taxel a touch was aborted at is not chosen again."""

    points: np.ndarray                # (S,) believed positions of the part's present taxels
    slots: np.ndarray                 # (S,) their slots
    arms: int = 1
    retries: int = 1                  # touches more at a target whose own taxel did not fire
    fired: np.ndarray = field(init=False)
    unreachable: np.ndarray = field(init=False)

    def __post_init__(self):
        self.fired = np.zeros(len(self.slots), int)
        self.tried = np.zeros(len(self.slots), int)
        self.unreachable = np.zeros((self.arms, len(self.slots)), bool)     # per arm
        self.skipped = np.zeros(len(self.slots), bool)
        self._row = {int(s): r for r, s in enumerate(self.slots)}
        self.last: int | None = None

    def record(self, slots, target: int | None = None) -> None:
        """The part's ``slots`` fired in a touch aimed at row ``target``: that target counts as touched once even
        where its own taxel did not fire (the skin a little off the belief), so it is not chosen again and
        again while every other taxel has been."""
        rows = [self._row[int(s)] for s in np.unique(slots) if int(s) in self._row]
        self.fired[rows] += 1
        if target is not None:
            self.tried[target] += 1

    def mark_unreachable(self, row: int, arm: int = 0) -> None:
        """No pose of ``arm`` reaches the taxel."""
        self.unreachable[arm, row] = True

    def skip(self, row: int) -> None:
        """A pose reaches it, but a touch there was aborted (no contact, or one elsewhere): not again."""
        self.skipped[row] = True

    @property
    def out_of_reach(self) -> np.ndarray:
        """(S,) no arm reaches the taxel."""
        return self.unreachable.all(axis=0)

    def reachable_unreached(self) -> int:
        return int(np.count_nonzero((self.fired == 0) & ~self.out_of_reach & ~self.skipped))

    def _score(self, priority=None) -> np.ndarray:
        score = np.maximum(self.fired, self.tried).astype(float)
        # a target whose touch fired only its neighbours (the skin a little off the belief) is aimed at again,
        # shifted (Planner.aim_again), before any taxel is touched a second time, up to ``retries`` times
        again = (self.fired == 0) & (self.tried >= 1) & (self.tried <= self.retries)
        score[again] = 1.0 - 1.0 / (1.0 + self.tried[again])
        if priority is not None:          # the guidance's triangles first among the least fired
            score = score - 0.5 * np.isin(self.slots // 12, list(priority))
        return score

    def arm(self, current: int = 0, priority=None) -> int | None:
        """The arm to press with next (None: no target is left for any)."""
        score = self._score(priority)
        best = [score[~self.unreachable[a] & ~self.skipped].min(initial=np.inf) for a in range(self.arms)]
        if not np.isfinite(min(best)):
            return None
        return current if best[current] <= min(best) else int(np.argmin(best))

    def next(self, priority=None, arm: int = 0) -> int | None:
        """The row of ``arm``'s next target, None when it has none left."""
        open_ = ~self.unreachable[arm] & ~self.skipped
        if not open_.any():
            return None
        score = self._score(priority)
        best = open_ & (score == score[open_].min())
        rows = np.flatnonzero(best)
        touched = np.flatnonzero((self.fired > 0) | (self.tried > 0))
        if len(touched):
            # farthest from every taxel touched so far: the touches spread over the part from the start, which
            # the calibration needs (sweeping to the nearest one left the torso's far side for the end: at 50
            # touches its true median 1.8 mm, where random touches had 1.2)
            d = np.linalg.norm(self.points[rows, None] - self.points[None, touched], axis=2).min(axis=1)
            rows = rows[np.argsort(-d, kind="stable")]
        self.last = int(rows[0])
        return self.last
