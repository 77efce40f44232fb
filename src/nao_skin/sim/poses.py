"""Self-touch poses: joint angles that press a spot of the hand skin onto a spot of another part.

Each pose solves, for the arm joints (and the head joints when the head is
touched), ``hand_spot(q) = target_spot(q) + gap * target_normal(q)`` with the
two normals opposed, inside the joint limits. All poses (times the random
restarts) are solved together by one batched, projected Levenberg-Marquardt
with the analytic Jacobian of the revolute DH joints, so thousands of poses
cost a few dozen vectorised forward-kinematics calls.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from nao_skin import se3
from nao_skin.model.robot import REST_SPREAD
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.sim.params import SimParams

NORMAL_WEIGHT = 0.03       # m per unit of normal mismatch: 0.1 rad of tilt costs like 3 mm
LIMIT_MARGIN = 0.01        # rad kept from the joint limits (the real joints stop softly)



@dataclass
class Spots:
    """Chosen contact spots of one part, in its chain-end frame (true skin placement)."""

    triangle: np.ndarray     # (N,) row into SkinPart.triangle_ids
    point: np.ndarray        # (N, 3)
    normal: np.ndarray       # (N, 3) outward


def choose_spots(skin: SkinModel, part: str, truth: SkinCalibration, n: int, weight: np.ndarray,
                 p: SimParams, rng: np.random.Generator) -> Spots:
    """``n`` spots near triangle centres, triangle ``i`` drawn with probability ~ ``weight[i]``.

    With ``p.planar_band > 0`` spots stay in a band through the part's taxel
    centroid, across its longest extent: contacts then lie on one line of each
    part and the poses do not excite every direction.
    """
    sp = skin.parts[part]
    _, _, tri = sp.frame_poses(truth.parts.get(part))
    centres = tri[:, :3, 3]
    normals = tri[:, :3, 2]
    allowed = np.ones(len(centres), dtype=bool)
    band_dir = None
    if p.planar_band > 0:
        pts = centres - centres.mean(axis=0)
        _, _, vt = np.linalg.svd(pts, full_matrices=False)
        band_dir = vt[1]                              # across the band
        allowed = np.abs(pts @ band_dir) <= p.planar_band / 2
        if not np.any(allowed):
            allowed = np.abs(pts @ band_dir) <= np.min(np.abs(pts @ band_dir)) + 1e-9
    weight = np.where(allowed, weight, 0.0)
    if weight.sum() <= 0:
        weight = allowed.astype(float)
    row = rng.choice(len(centres), size=n, p=weight / weight.sum())
    # a random offset in the triangle's plane, uniform over a disc
    r = p.spot_radius * np.sqrt(rng.uniform(size=n))
    phi = rng.uniform(0, 2 * np.pi, size=n)
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.zeros(n)], axis=1)
    offset = se3.rotate_vectors(tri[row], local)
    if band_dir is not None:   # keep the offset along the band
        offset -= (offset @ band_dir)[:, None] * band_dir
    return Spots(row, centres[row] + offset, normals[row])


def _chain_joint_columns(skin: SkinModel, chain: str | None) -> list:
    if chain is None:
        return []
    robot = skin.robot
    return [(r, robot.joint_index[j]) for r, j in enumerate(robot.chains[chain].joints) if j is not None]


def idle_joints(skin: SkinModel, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, J) joint angles of a resting robot (the robot config's ``body: rest_posture``), within the limits."""
    robot = skin.robot
    q = np.zeros((n, len(robot.joint_names)))
    for j, name in enumerate(robot.joint_names):
        mean, spread = robot.body.rest_posture.get(name, (0.0, REST_SPREAD))
        q[:, j] = mean + rng.uniform(-spread, spread, size=n)
    return np.clip(q, robot.limits[:, 0] + LIMIT_MARGIN, robot.limits[:, 1] - LIMIT_MARGIN)


def _spot_kinematics(skin, chain, q, point, normal, cols):
    """Spot position, normal (base frame) and the (N, 3, V) derivatives over the chain's joints."""
    n = q.shape[0]
    if chain is None:
        return point, normal, np.zeros((n, 3, 0)), np.zeros((n, 3, 0))
    frames = skin.robot.fk_frames(chain, q)
    end = frames[:, -1]
    pos = se3.transform_points(end, point)
    nor = se3.rotate_vectors(end, normal)
    dp = np.empty((n, 3, len(cols)))
    dn = np.empty((n, 3, len(cols)))
    for k, (row, _) in enumerate(cols):    # <= 5 joints, vectorised over N
        before = frames[:, row - 1] if row > 0 else np.broadcast_to(np.eye(4), (n, 4, 4))
        z, o = before[:, :3, 2], before[:, :3, 3]
        dp[:, :, k] = np.cross(z, pos - o)
        dn[:, :, k] = np.cross(z, nor)
    return pos, nor, dp, dn


def _residual(skin, hand_chain, target_chain, q, hs, hn, ts, tn, gap, hcols, tcols):
    hp, hnn, hdp, hdn = _spot_kinematics(skin, hand_chain, q, hs, hn, hcols)
    contact_local = ts + gap[:, None] * tn       # where the hand spot must be, target frame
    tp, tnn, tdp, tdn = _spot_kinematics(skin, target_chain, q, contact_local, tn, tcols)
    res = np.concatenate([hp - tp, NORMAL_WEIGHT * (hnn + tnn)], axis=1)
    jac = np.concatenate([
        np.concatenate([hdp, -tdp], axis=2),
        NORMAL_WEIGHT * np.concatenate([hdn, tdn], axis=2)], axis=1)
    return res, jac


def levenberg_marquardt(residual, q: np.ndarray, cols: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                        iterations: int) -> tuple:
    """Batched, projected Levenberg-Marquardt over the joint columns ``cols`` of every row of ``q`` at once:
    ``residual(q) -> ((N, R) residuals, (N, R, len(cols)) Jacobian)``, each step kept within ``[lo, hi]``.
    Returns the joint angles and their residuals."""
    res, jac = residual(q)
    cost = np.einsum("ij,ij->i", res, res)
    lam = np.full(len(q), 1e-3)
    eye = np.eye(len(cols))
    for _ in range(iterations):
        jtj = np.einsum("nri,nrj->nij", jac, jac)
        jtr = np.einsum("nri,nr->ni", jac, res)
        damp = lam[:, None, None] * (np.einsum("nii->ni", jtj)[:, :, None] * eye + 1e-6 * eye)
        step = np.linalg.solve(jtj + damp, -jtr[:, :, None])[:, :, 0]
        trial = q.copy()
        trial[:, cols] = np.clip(q[:, cols] + step, lo, hi)
        t_res, t_jac = residual(trial)
        t_cost = np.einsum("ij,ij->i", t_res, t_res)
        better = t_cost < cost
        q[better], res[better], jac[better], cost[better] = trial[better], t_res[better], t_jac[better], t_cost[better]
        lam = np.where(better, np.maximum(lam / 3.0, 1e-7), np.minimum(lam * 4.0, 1e7))
    return q, res


def solve_poses(skin: SkinModel, hand: str, target: str, hand_spots: Spots, target_spots: Spots,
                gap: np.ndarray, q_idle: np.ndarray, truth: SkinCalibration, p: SimParams,
                rng: np.random.Generator, hand_counts: np.ndarray | None = None):
    """Solve N poses, each from ``k = p.pose_restarts`` random starts.

    ``hand_spots`` holds ``N * k`` spots: restart ``j`` of target ``i`` tries
    hand spot ``i * k + j``, so a target that one side of the hand cannot reach
    is tried with others. Among the restarts that meet the tolerances and do
    not push the hand into the touched part or the torso, the one on the
    least-touched hand triangle (``hand_counts``) wins. Returns ``(q (N, J),
    ok (N,), chosen (N,) row into hand_spots, position_error (N,),
    normal_error_rad (N,), ok_per_restart (N * k,))``; where ``ok`` is false
    the target is unreachable.
    """
    robot = skin.robot
    hand_chain, target_chain = skin.parts[hand].chain, skin.parts[target].chain
    hcols, tcols = _chain_joint_columns(skin, hand_chain), _chain_joint_columns(skin, target_chain)
    cols = np.array([c for _, c in hcols + tcols], dtype=int)
    n, k = len(gap), p.pose_restarts
    lo = robot.limits[cols, 0] + LIMIT_MARGIN
    hi = robot.limits[cols, 1] - LIMIT_MARGIN
    rep = lambda a: np.repeat(a, k, axis=0)  # noqa: E731 - rows of every restart
    hs, hn = hand_spots.point, hand_spots.normal
    ts, tn = rep(target_spots.point), rep(target_spots.normal)
    g = rep(gap)
    q = rep(q_idle).copy()
    q[:, cols] = rng.uniform(lo, hi, size=(n * k, len(cols)))
    q, res = levenberg_marquardt(lambda qq: _residual(skin, hand_chain, target_chain, qq, hs, hn, ts, tn, g, hcols,
                                                      tcols), q, cols, lo, hi, p.pose_iterations)
    cost = np.einsum("ij,ij->i", res, res)
    pos_err = np.linalg.norm(res[:, :3], axis=1)
    # normal mismatch |nh + nt| = 2 sin(angle / 2)
    ang_err = 2.0 * np.arcsin(np.clip(np.linalg.norm(res[:, 3:], axis=1) / NORMAL_WEIGHT / 2.0, 0.0, 1.0))
    ok = (pos_err <= p.pose_tolerance) & (ang_err <= np.radians(p.normal_tolerance_deg))
    rows = np.flatnonzero(ok)
    if len(rows):
        target_rows = Spots(*(np.repeat(a, k, axis=0)[rows] for a in
                              (target_spots.triangle, target_spots.point, target_spots.normal)))
        ok[rows] &= ~penetrates(skin, hand, target, q[rows], target_rows, p, truth)
    counts = np.zeros(1 + hand_spots.triangle.max()) if hand_counts is None else hand_counts
    # feasible first, then the least-touched hand triangle, then the smallest residual
    score = np.where(ok, counts[hand_spots.triangle] + cost / (1.0 + cost), 1e9 + cost)
    best = np.argmin(score.reshape(n, k), axis=1) + np.arange(n) * k
    return q[best], ok[best], best, pos_err[best], ang_err[best], ok


def penetrates(skin: SkinModel, hand: str, target: str, q: np.ndarray, target_spots: Spots,
               p: SimParams, truth: SkinCalibration | None = None) -> np.ndarray:
    """(N,) True where the hand would have to pass through the touched part or the torso.

    Local test only: hand taxels near the contact must not sit more than
    ``penetration_tolerance`` behind the target surface, approximated by its
    tangent plane at the spot; the elbow and the hand's end must be outside a
    box around the torso.
    """
    hp = skin.parts[hand]
    local, _ = hp.taxel_positions(truth.parts.get(hand) if truth else None)
    local = local[hp.slots]
    hand_end = skin.robot.fk(hp.chain, q)
    taxels = se3.transform_points(hand_end[:, None], local[None])              # (N, S, 3)
    t_end = skin.robot.fk(skin.parts[target].chain, q)
    spot = se3.transform_points(t_end, target_spots.point)
    normal = se3.rotate_vectors(t_end, target_spots.normal)
    rel = taxels - spot[:, None]
    height = np.einsum("nsk,nk->ns", rel, normal)
    lateral = np.linalg.norm(rel - height[..., None] * normal[:, None], axis=2)
    behind = (lateral < 0.03) & (height < -p.penetration_tolerance)
    return behind.any(axis=1) | ~outside_body(skin, hp.chain, q)


def outside_body(skin: SkinModel, chain: str, q: np.ndarray) -> np.ndarray:
    """(N,) True where the arm ``chain`` keeps out of the robot config's torso box: its end frame's origin (the
    elbow) and the hand's far end (``body.hand_end``); all True without a box."""
    body = skin.robot.body
    if body.box is None:
        return np.ones(len(q), bool)
    hand_end = skin.robot.fk(chain, q)
    far = [] if body.hand_end is None else [se3.transform_points(hand_end, body.hand_end)]
    probes = np.stack([hand_end[:, :3, 3]] + far, axis=1)
    return ~np.all((probes >= body.box[:, 0]) & (probes <= body.box[:, 1]), axis=2).any(axis=1)


@dataclass
class PoseSet:
    """Accepted self-touch poses of one pair (true joints, true skin), base frame."""

    q: np.ndarray             # (N, J) true joint angles
    contact: np.ndarray       # (N, 3) midway between the two touching skin surfaces
    normal: np.ndarray        # (N, 3) outward normal of the touched part (towards the hand)
    gap: np.ndarray           # (N,) distance between the two taxel surfaces (fabric on both)
    hand_triangle: np.ndarray     # (N,) triangle row of the hand spot
    target_triangle: np.ndarray   # (N,) triangle row of the target spot
    attempted: int            # target spots tried
    unreachable: int          # of which no pose was found (skipped)

    ROWS = ("q", "contact", "normal", "gap", "hand_triangle", "target_triangle")

    @classmethod
    def empty(cls, n_joints: int) -> "PoseSet":
        return cls(np.zeros((0, n_joints)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, int),
                   np.zeros(0, int), 0, 0)

    def take(self, rows) -> "PoseSet":
        """The poses of ``rows`` (the counts of spots tried stay the set's)."""
        rows = np.asarray(rows, int)
        return dataclasses.replace(self, **{name: getattr(self, name)[rows] for name in self.ROWS})

    @classmethod
    def concat(cls, sets, n_joints: int) -> "PoseSet":
        if not sets:
            return cls.empty(n_joints)
        return cls(*(np.concatenate([getattr(s, name) for s in sets]) for name in cls.ROWS),
                   attempted=sum(s.attempted for s in sets), unreachable=sum(s.unreachable for s in sets))


def solve_spots(skin: SkinModel, hand: str, target: str, t_spots: Spots, h_spots: Spots, truth: SkinCalibration,
                p: SimParams, rng: np.random.Generator, counts: np.ndarray | None = None) -> tuple:
    """``(poses, ok, ok_all)``: a pose for each target spot (``pose_restarts`` hand spots each), pressed with a
    fabric gap drawn per touch, from the robot at rest (:func:`solve_poses`, ``counts``: its hand triangle
    weights); ``ok`` which reached their spot, ``ok_all`` per hand spot. Every row is in ``poses``, reached or
    not: its hand triangle the best restart's."""
    m = len(t_spots.triangle)
    gap = np.maximum(2 * p.fabric_thickness + rng.normal(0.0, p.scaled("fabric_jitter"), size=m), 0.0)
    q, ok, best, _, _, ok_all = solve_poses(skin, hand, target, h_spots, t_spots, gap,
                                            idle_joints(skin, m, rng), truth, p, rng, counts)
    end = skin.robot.fk(skin.parts[target].chain, q)
    normal = se3.rotate_vectors(end, t_spots.normal)
    contact = se3.transform_points(end, t_spots.point) + 0.5 * gap[:, None] * normal
    poses = PoseSet(q, contact, normal, gap, h_spots.triangle[best], t_spots.triangle, m, int(np.count_nonzero(~ok)))
    return poses, ok, ok_all


MAX_ROUNDS = 10


def find_poses(skin: SkinModel, truth: SkinCalibration, hand: str, target: str, n: int, p: SimParams,
               rng: np.random.Generator) -> PoseSet:
    """``n`` reachable self-touch poses of ``hand`` on ``target``, spread over both skins.

    Works in rounds: each round proposes spots favouring the triangles touched
    least so far, solves them all at once, and keeps the reachable ones;
    unreachable targets are skipped and counted.
    """
    sp_h, sp_t = skin.parts[hand], skin.parts[target]
    # per triangle: accepted touches, spots tried, spots that worked (hand, target)
    counts = [np.zeros(len(sp_h.triangle_ids)), np.zeros(len(sp_t.triangle_ids))]
    tries = [np.zeros_like(c) for c in counts]
    works = [np.zeros_like(c) for c in counts]
    k = p.pose_restarts
    kept = []
    accepted = 0
    rate = 0.5
    for _ in range(MAX_ROUNDS):
        need = n - accepted
        if need <= 0:
            break
        # least-touched triangles first, but not those that keep failing (out of reach)
        weight = [((w + 0.5) / (t + 1.0)) ** 2 / (1.0 + c) for c, t, w in zip(counts, tries, works)]
        # rounds of about a third of the set, so coverage steers the next ones
        m = int(min(np.ceil(need / rate * 1.2) + 4, max(n / 3 / rate, 24)))
        t_spots = choose_spots(skin, target, truth, m, weight[1], p, rng)
        h_spots = choose_spots(skin, hand, truth, m * k, weight[0], p, rng)
        poses, ok, ok_all = solve_spots(skin, hand, target, t_spots, h_spots, truth, p, rng, counts[0])
        rate = max(ok.mean(), 0.05)
        np.add.at(tries[0], h_spots.triangle, 1)
        np.add.at(works[0], h_spots.triangle, ok_all)
        np.add.at(tries[1], t_spots.triangle, 1)
        np.add.at(works[1], t_spots.triangle, ok)
        chosen = poses.take(np.flatnonzero(ok)[:need])
        kept.append(chosen)
        np.add.at(counts[0], chosen.hand_triangle, 1)
        np.add.at(counts[1], chosen.target_triangle, 1)
        accepted += len(chosen.q)
    return PoseSet.concat(kept, len(skin.robot.joint_names))
