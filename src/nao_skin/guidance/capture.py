"""Guided capture, pure (no ROS): where the operator should press next, and a pose that gets the hand there.

It needs both the calibration's pairing (:mod:`nao_skin.calibration`) and
the simulator's pose solver (:mod:`nao_skin.sim`), which are independent of
each other: its package is the layer above them (``.importlinter``), under
the benchmark, the commands and the nodes that use it.

From the current calibration and the touches so far, :func:`guidance` says
which triangles (and patches) of which skin part the touches leave held at
the prior or only weakly determined, ranks them by what one more touch there
would add, and for each of the top ones names the touching pair (a hand on
the torso or the head; a hand triangle is reached by pressing it on the torso
or the head) and suggests joint angles that bring the two spots together,
solved by the simulator's batched pose solver (:func:`nao_skin.sim.poses.solve_poses`)
under the CURRENT calibration (what the robot believes, not a ground truth),
or says the target is unreachable.

Counting. Paired activations per triangle are counted as the calibration
engine counts them (``stages._activation_counts``): the touches whose closest
COP / taxel pairs (the kinds of ``options.pairs``) use the triangle, paired
under the current calibration over every hand-body pair of the touches. The
engine counts them on its training split, so a triangle needs
``needed = ceil(min_triangle_activations / (1 - test_fraction))`` (15 with
the defaults) paired activations in all the touches to be estimated.

Ranking rule. ``score = tier + share``, highest first:

* tier 3 -- the part is not calibrated yet (no result, or not among the
  calibrated parts), or the target is the pair of a hand and a body part that
  fewer than ``ceil(min_mount_touches / (1 - test_fraction))`` touches connect
  (left out, or about to be): one target per such pair, at the body part's
  least-covered triangles;
* tier 2 -- held: fewer than ``needed`` paired activations, or the report
  holds the triangle (all six components) or its patch;
* tier 1 -- weak: fewer than ``2 * needed`` paired activations, or the report
  holds some of the triangle's components;
* within a tier, ``0.99 * share``: for a triangle held for too few
  activations the share it already has (``count / needed``), so the one
  closest to being estimated comes first -- a touch there frees it soonest,
  where ranking the emptiest first spread the touches over triangles that
  then all stayed held (two pairs, seeds 0 and 1, 160 touches: 57 held
  frames against 62 and 64); otherwise the share still missing
  (``(goal - count) / goal``, ``goal = 2 * needed``); ties go to the part
  order (r_hand, l_hand, torso, head), then the triangle number.
  Well-covered triangles (``>= 2 * needed``, nothing held) are no targets.

The top ``candidates`` (48; None: all) are solved, in one batch per
touching pair (a triangle no touch has reached yet is often one no pose
reaches: the hand's back, the torso's sides); reachable targets come first
(in score order), the unreachable ones after them, marked ``pose=None``.

Ranking by expected gain. When the state is a calibration result with its
linearised posterior (:class:`~nao_skin.calibration.uncertainty.Posterior`),
the tier-3 targets still come first; every other triangle of the calibrated
parts (well-covered ones too) is a candidate, a uniform draw of them (seeded)
is solved, and the reachable ones are ranked by :attr:`Target.gain_mm2`, the
summed taxel variance a press there is predicted to remove
(:func:`_expected_gains`): the bound's greedy criterion at the estimate.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from nao_skin.calibration.layout import COMPONENTS
from nao_skin.calibration.options import CalibrationOptions
from nao_skin.calibration.plan import pair_counts
from nao_skin.calibration.report import paired_activation_counts
from nao_skin.calibration.stages import held_frames
from nao_skin.errors import DataError
from nao_skin.model.skin import SkinCalibration, SkinModel, part_rank
from nao_skin.plain import jsonable
from nao_skin.rules import finite_float
from nao_skin.sim.params import SimParams, make_params
from nao_skin.sim.poses import Spots, choose_spots, idle_joints, solve_poses
from nao_skin.touch.touches import TouchSet

TIER_NEW, TIER_HELD, TIER_WEAK, TIER_COVERED = 3, 2, 1, 0
DEFICIT_SPAN = 0.99     # a tier's scores stay below the next tier's
# the pose search of a suggestion: fewer restarts than the simulator, it runs after every live update
GUIDANCE_POSE = {"pose_restarts": 6, "pose_iterations": 40}
MAX_READ_TARGETS = 100   # targets a consumer of the guidance message reads, best first
# targets that get a pose: by tier, or (ranked by expected gain) a uniform draw of the triangles, as the bound
# draws its pool; 96 or 144 drawn bought nothing measurable at two to four times the guidance's time
# (docs/decisions.md, "Guidance by expected gain")
CANDIDATES = 48


@dataclass
class Target:
    """One place to press next: ``triangle_id`` of ``part``, pressed with the pair ``hand`` on ``touched``."""

    part: str
    triangle_id: int
    patch_id: int
    reason: str                   # 'not calibrated', 'pair left out', 'held', 'patch held', 'weak', ...
    score: float
    activations: int              # paired activations of the triangle so far
    needed: int                   # paired activations it needs to be estimated (all touches)
    hand: str
    touched: str                  # the part the hand presses: torso or head
    pose: dict | None             # NAOqi joint name -> rad (the pair's chains); None: unreachable
    point: list                   # target spot on ``part``, its chain-end frame (current calibration), m
    hand_triangle_id: int | None = None    # the hand triangle pressed (the target itself for a hand target)
    hand_point: list | None = None         # spot on the hand, hand chain-end frame, m
    touched_triangle_id: int | None = None  # the triangle pressed on ``touched``
    touched_point: list | None = None      # spot on ``touched``, its chain-end frame, m
    pose_error_mm: float | None = None      # the solver's spot-to-spot residual (current calibration)
    gain_mm2: float | None = None           # the summed taxel variance a press there is predicted to remove (mm^2)

    def to_dict(self) -> dict:
        return jsonable(dataclasses.asdict(self))


@dataclass
class PartCoverage:
    """Paired activations of one part's triangles and what is held."""

    part: str
    state: str                    # 'calibrated', 'not calibrated'
    triangle_ids: list
    activations: list             # per triangle, in the order of triangle_ids
    needed: int
    enough: int                   # triangles with >= needed paired activations
    total: int
    held: list                    # triangle ids held (too few activations, or held by the report)
    held_patches: list            # patch ids the report holds

    def to_dict(self) -> dict:
        return jsonable(dataclasses.asdict(self))


@dataclass
class Guidance:
    targets: list                 # Target, best first (reachable ones before unreachable ones)
    coverage: dict                # part -> PartCoverage
    pair_touches: dict            # 'hand-body' -> touches where both fire
    n_touches: int
    seconds: float = 0.0
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"n_touches": self.n_touches, "seconds": self.seconds, "pair_touches": dict(self.pair_touches),
                "targets": [t.to_dict() for t in self.targets],
                "coverage": {k: v.to_dict() for k, v in self.coverage.items()}, "notes": list(self.notes)}


def targets_from_json(text: str, skin: SkinModel, limit: int = MAX_READ_TARGETS) -> tuple:
    """The targets of a guidance message (``Guidance.to_dict`` as JSON) that name this skin's parts and
    triangles, as dicts with the fields a consumer reads, checked: ``(targets, skipped)``. Only the first
    ``limit`` are read (best first: a robot aims at a handful, RViz shows them; 20000 held the heat-map
    node for 7 s and drew 40000 markers).

    What arrives on a topic is anybody's: a message that is not the guidance's JSON is a DataError, a
    target that names another skin's part or triangle, or whose fields have the wrong type, is skipped
    and counted. ``pose`` is kept only when it maps joint names to finite angles.
    """
    import json

    try:
        doc = json.loads(text)
    except ValueError as exc:
        raise DataError(f"not JSON ({exc})") from None
    except RecursionError:
        raise DataError("JSON nested too deeply to be the guidance's") from None
    targets = doc.get("targets", []) if isinstance(doc, dict) else None
    if not isinstance(targets, list):
        raise DataError("not the guidance's JSON: no 'targets' list")

    def triangle(part, value):
        ok = isinstance(value, int) and not isinstance(value, bool) and value in skin.parts[part].triangle_ids
        return value if ok else None

    targets = targets[:limit]
    out = []
    for t in targets:
        if not isinstance(t, dict) or not all(isinstance(t.get(k), str) and t[k] in skin.parts
                                              for k in ("part", "touched")):
            continue
        # the hand: a skin part, or a fingertip of the robot pressing (a fingertip scene's target)
        if not isinstance(t.get("hand"), str) or not (t["hand"] in skin.parts or t["hand"] in skin.robot.fingertips):
            continue
        if triangle(t["part"], t.get("triangle_id")) is None:
            continue
        pose = t.get("pose")
        pose = (pose if isinstance(pose, dict) and pose and all(
            isinstance(k, str) and finite_float(v) is not None for k, v in pose.items()) else None)
        out.append({"part": t["part"], "triangle_id": t["triangle_id"], "hand": t["hand"], "touched": t["touched"],
                    "reason": t["reason"] if isinstance(t.get("reason"), str) else "",
                    "hand_triangle_id": (triangle(t["hand"], t.get("hand_triangle_id")) if t["hand"] in skin.parts
                                         else None),
                    "touched_triangle_id": triangle(t["touched"], t.get("touched_triangle_id")), "pose": pose})
    return out, len(targets) - len(out)


# ---------------------------------------------------------------------------- counting
def _pair_touches(touches: TouchSet, pairs) -> dict:
    """``{'hand-body': touches where both fire}`` of each of ``pairs`` (none: 0)."""
    counts = pair_counts(touches) if touches.n_touches else {}
    return {f"{hand}-{body}": counts.get(frozenset((hand, body)), 0) for hand, body in pairs}


# ---------------------------------------------------------------------------- ranking
def _state(state):
    """``(calibration, held, calibrated parts or None, fabric m or None, posterior or None)`` of a result, a
    calibration or None."""
    if state is None:
        return None, [], set(), None, None
    if isinstance(state, SkinCalibration):
        return state, [], None, None, None
    report = state.report
    fabric = getattr(report, "fabric_thickness_mm", float("nan"))
    return (state.calibration, list(report.held), set(report.parts),
            (fabric / 1000.0 if np.isfinite(fabric) else None), getattr(state, "posterior", None))


def guidance(touches: TouchSet, skin: SkinModel, state=None, options: CalibrationOptions | None = None, *,
             held=None, calibrated_parts=None, max_targets: int = 8, seed: int = 0, pairs=None,
             poses: bool = True, pose_params: SimParams | None = None,
             candidates: int | None = CANDIDATES) -> Guidance:
    """Where to press next; see the module docstring for the counting and the ranking rule.

    ``state``: a :class:`~nao_skin.calibration.engine.CalibrationResult` (its
    calibration, held frames and calibrated parts are used), a
    :class:`SkinCalibration` (with ``held`` / ``calibrated_parts`` given
    separately; ``calibrated_parts=None`` then means every part with touches),
    or None (nothing calibrated yet: the nominal layout). ``poses=False``
    skips the pose solve (targets then have ``pose=None``, in score order).
    """
    t0 = time.perf_counter()
    options = options or CalibrationOptions()
    rng = np.random.default_rng(seed)
    calib, rep_held, rep_parts, fabric, posterior = _state(state)
    calib = calib or skin.zero_calibration()
    held_map = held_frames(held if held is not None else rep_held)
    tip_scenes = [(h, b) for h, b in (pairs or ()) if h in skin.robot.fingertips and b in skin.parts]
    pairs = [(h, b) for h, b in (skin.self_touch.pairs() if pairs is None else pairs)
             if h in skin.parts and b in skin.parts]
    parts = sorted({p for pair in pairs for p in pair}, key=part_rank)
    if calibrated_parts is not None:
        rep_parts = set(calibrated_parts)
    elif rep_parts is None:
        rep_parts = {p for p in parts if p in touches.part_names}
    keep = 1.0 - options.test_fraction
    needed = int(np.ceil(options.min_triangle_activations / keep - 1e-9))
    needed_pair = int(np.ceil(options.min_mount_touches / keep - 1e-9))
    counts = (paired_activation_counts(touches, skin, calib, options, pairs) if touches.n_touches
              else {p: np.zeros(len(skin.parts[p].triangle_ids), int) for p in skin.parts})
    pair_n = _pair_touches(touches, pairs)

    # with the calibration's posterior, every triangle of the parts it covers is a candidate, ranked by what a
    # press there would teach; without (nothing calibrated yet, a calibration file) by the tiers alone
    gain_parts = set(posterior.layout.part_names) & rep_parts if posterior is not None else set()
    ranked_by_gain = bool(gain_parts)
    coverage, cands = {}, []
    for name in parts:
        sp = skin.parts[name]
        c = counts[name]
        calibrated = name in rep_parts
        held_patch_ids = [int(pid) for pid in sp.patch_ids
                          if held_map.get((name, f"patch_{int(pid)}")) == COMPONENTS]
        held_tris = []
        for row, tid in enumerate(sp.triangle_ids):
            comps = held_map.get((name, f"triangle_{int(tid)}"), ())
            pid = int(sp.patch_ids[sp.triangle_patch[row]])
            patch_held = pid in held_patch_ids
            all_held = comps == COMPONENTS
            whole = all_held or c[row] < needed
            if whole or patch_held:
                held_tris.append(int(tid))
            if not calibrated:
                tier, goal, reason = TIER_NEW, 2 * needed, "not calibrated"
            elif c[row] < needed or all_held:
                tier, goal, reason = TIER_HELD, needed, ("held" if c[row] < needed else "held by the solve")
            elif patch_held:
                tier, goal, reason = TIER_HELD, 2 * needed, f"patch {pid} held"
            elif c[row] < 2 * needed or comps:
                tier, goal, reason = TIER_WEAK, 2 * needed, ("weak" if not comps else f"held ({','.join(comps)})")
            elif ranked_by_gain and name in gain_parts:
                tier, goal, reason = TIER_COVERED, 2 * needed, "covered"
            else:
                continue
            share = min(1.0, max(0.0, (goal - c[row]) / goal))        # still missing
            if tier == TIER_HELD and c[row] < needed:
                share = 1.0 - share                                    # already there: closest to estimated first
            cands.append(dict(part=name, row=row, tier=tier, score=tier + DEFICIT_SPAN * share, reason=reason,
                              forced=None))
        coverage[name] = PartCoverage(name, "calibrated" if calibrated else "not calibrated",
                                      [int(t) for t in sp.triangle_ids], [int(v) for v in c], needed,
                                      int(np.sum(c >= needed)), len(c), sorted(held_tris), held_patch_ids)
    # a pair too few touches connect: its own targets, pressed with that very pair
    for hand, body in pairs:
        n = pair_n[f"{hand}-{body}"]
        if n < needed_pair:
            order = np.lexsort((np.arange(len(counts[body])), counts[body]))
            for row in order[:2]:
                deficit = (needed_pair - n) / needed_pair
                cands.append(dict(part=body, row=int(row), tier=TIER_NEW, score=TIER_NEW + DEFICIT_SPAN * deficit,
                                  reason=f"pair {hand}-{body} left out ({n} touches < {needed_pair})",
                                  forced=(hand, body)))
    if ranked_by_gain:     # the pose solve is the cost: a uniform draw of the triangles gets poses (the pool)
        draw = rng.permutation(len(cands))
        for d, order in zip(cands, draw):
            d["draw"] = int(order)
        cands.sort(key=lambda d: (d["tier"] < TIER_NEW, -d["score"] if d["tier"] == TIER_NEW else d["draw"],
                                  counts[d["part"]][d["row"]], part_rank(d["part"]), d["row"]))
    else:
        cands.sort(key=lambda d: (-d["score"], counts[d["part"]][d["row"]], part_rank(d["part"]), d["row"]))
    if candidates is not None:
        cands = cands[:max(candidates, max_targets)]
    targets = [_target(d, skin, counts, needed, pair_n, pairs) for d in cands]
    notes = []
    if poses and targets:
        p = pose_params or make_params(GUIDANCE_POSE)
        if fabric is not None:
            p = dataclasses.replace(p, fabric_thickness=fabric)
        _solve(targets, skin, calib, counts, p, rng, pairs)
        reachable = [t for t in targets if t.pose is not None]
        if ranked_by_gain:
            _expected_gains(reachable, skin, calib, posterior)
            reachable = ([t for t in reachable if t.gain_mm2 is None]
                         + sorted((t for t in reachable if t.gain_mm2 is not None), key=lambda t: -t.gain_mm2))
        unreachable = [t for t in targets if t.pose is None]
        if unreachable:
            notes.append(f"{len(unreachable)} of {len(targets)} candidate targets unreachable under the current"
                         f" calibration")
        targets = reachable + unreachable
    if tip_scenes:    # first: a taxel no touch reached is held at the prior, and a fingertip reaches where hands cannot
        targets = fingertip_targets(touches, skin, tip_scenes, needed) + targets
    return Guidance(targets[:max_targets], coverage, pair_n, touches.n_touches, time.perf_counter() - t0, notes)


def fingertip_targets(touches: TouchSet, skin: SkinModel, scenes, needed: int = 0) -> list:
    """Targets for fingertip ``scenes`` (``(fingertip, part)``): the triangles of each pressed part with taxels no
    touch (of any kind) has activated yet, most such taxels first (ties: the part's order, then the triangle's).
    A fingertip presses nearly a point, so it reaches taxels a hand's broad contact does not: where it helps most.
    ``reason`` says how many taxels of the triangle no touch reached; no pose (a fingertip's is the operator's)."""
    out = []
    for tip, name in scenes:
        sp = skin.parts[name]
        slots = sp.slots
        reached = np.zeros(sp.n_slots, bool)
        if name in touches.part_names:
            reached[touches.act_slot[touches.act_part == touches.part_index(name)]] = True
        rows = sp.slot_triangle[slots]
        total = np.bincount(rows, minlength=len(sp.triangle_ids))
        never = np.bincount(rows, weights=~reached[slots], minlength=len(sp.triangle_ids)).astype(int)
        active = np.bincount(rows, weights=reached[slots], minlength=len(sp.triangle_ids)).astype(int)
        for row in np.flatnonzero(never):
            share = never[row] / max(total[row], 1)
            out.append(Target(name, int(sp.triangle_ids[row]), int(sp.patch_ids[sp.triangle_patch[row]]),
                              f"{never[row]} of {total[row]} taxels never reached", TIER_NEW + DEFICIT_SPAN * share,
                              int(active[row]), needed, tip, name, None, []))
    out.sort(key=lambda t: (-t.score, part_rank(t.part), t.triangle_id))
    return out


def _expected_gains(targets: list, skin: SkinModel, calib: SkinCalibration, posterior) -> None:
    """Each target's :attr:`Target.gain_mm2` (a tier-3 one, or one whose pair the posterior does not cover,
    keeps None): its press at its pose, the contact row's Jacobian the taxels nearest its two spots give (the
    hand's in the base frame at the pose, minus the touched part's), and what that row removes from the
    posterior (:meth:`~nao_skin.calibration.uncertainty.Posterior.variance_lowered`)."""
    covered = set(posterior.layout.part_names)
    robot = skin.robot
    positions: dict = {}
    information = posterior.taxel_information()
    for t in targets:
        if t.score >= TIER_NEW or t.hand not in covered or t.touched not in covered or t.pose is None:
            continue
        q = np.zeros(len(robot.joint_names))
        for name, value in t.pose.items():
            q[robot.joint_index[name]] = value
        row = np.zeros((3, len(posterior.free)))
        for part, point, sign in ((t.hand, t.hand_point, 1.0), (t.touched, t.touched_point, -1.0)):
            sp = skin.parts[part]
            if part not in positions:
                positions[part] = sp.taxel_positions(calib.parts.get(part), normals=False)[sp.slots]
            nearest = int(np.argmin(np.linalg.norm(positions[part] - np.asarray(point), axis=1)))
            taxel = posterior.taxels_of(part)[nearest]
            rotation = robot.fk(sp.chain, q)[0, :3, :3]
            row += sign * rotation @ posterior.taxel_jacobian[3 * taxel:3 * taxel + 3].toarray()
        t.gain_mm2 = 1e6 * posterior.variance_lowered(row, information)


def _target(d: dict, skin: SkinModel, counts: dict, needed: int, pair_n: dict, pairs) -> Target:
    """A candidate with its touching pair: hand targets on the body part with fewer touches, body targets
    with the hand with fewer touches on it (the solve may switch to the other one)."""
    name, row = d["part"], d["row"]
    sp = skin.parts[name]
    if d["forced"]:
        hand, touched = d["forced"]
    elif any(h == name for h, _ in pairs):
        options = [b for h, b in pairs if h == name]
        hand, touched = name, min(options, key=lambda b: (pair_n[f"{name}-{b}"], part_rank(b)))
    else:
        options = [h for h, b in pairs if b == name]
        hand, touched = min(options, key=lambda h: (pair_n[f"{h}-{name}"], part_rank(h))), name
    return Target(name, int(sp.triangle_ids[row]), int(sp.patch_ids[sp.triangle_patch[row]]), d["reason"],
                  float(d["score"]), int(counts[name][row]), needed, hand, touched, None, [])


def _alternatives(t: Target, pairs) -> list:
    """``(hand, touched)`` pairs that can press the target: its own first."""
    own = (t.hand, t.touched)
    if t.reason.startswith("pair "):
        return [own]
    if any(h == t.part for h, _ in pairs):
        alt = [(t.part, b) for h, b in pairs if h == t.part]
    else:
        alt = [(h, t.part) for h, b in pairs if b == t.part]
    return [own] + [a for a in alt if a != own]


def _spot_weights(counts: np.ndarray, needed: int) -> np.ndarray:
    """Weight of each triangle as the partner spot: the fewer paired activations, the likelier."""
    return 1.0 / (1.0 + counts / max(needed, 1)) ** 2


def _solve(targets: list, skin: SkinModel, calib: SkinCalibration, counts: dict, p: SimParams,
           rng: np.random.Generator, pairs) -> None:
    """Poses for every target, batched per touching pair; each target tries its pair, then the others."""
    pairs_all = sorted({a for t in targets for a in _alternatives(t, pairs)},
                       key=lambda a: (part_rank(a[0]), part_rank(a[1])))
    k = p.pose_restarts
    # per (hand, touched): the targets that try it, in their order of preference
    results: dict = {}
    for hand, touched in pairs_all:
        rows = [i for i, t in enumerate(targets) if (hand, touched) in _alternatives(t, pairs)]
        if not rows:
            continue
        sp_h, sp_t = skin.parts[hand], skin.parts[touched]
        _, _, tri_h = sp_h.frame_poses(calib.parts.get(hand))
        _, _, tri_t = sp_t.frame_poses(calib.parts.get(touched))
        n = len(rows)
        need = targets[0].needed
        w_h = _spot_weights(counts[hand], need)
        w_t = _spot_weights(counts[touched], need)
        t_spots = choose_spots(skin, touched, calib, n, w_t, p, rng)
        h_spots = choose_spots(skin, hand, calib, n * k, w_h, p, rng)
        for j, i in enumerate(rows):
            t = targets[i]
            if t.part == touched:
                r = int(np.flatnonzero(sp_t.triangle_ids == t.triangle_id)[0])
                t_spots.triangle[j], t_spots.point[j], t_spots.normal[j] = r, tri_t[r, :3, 3], tri_t[r, :3, 2]
            if t.part == hand:   # every restart on the target triangle (random starts of the joints)
                r = int(np.flatnonzero(sp_h.triangle_ids == t.triangle_id)[0])
                sl = slice(j * k, (j + 1) * k)
                h_spots.triangle[sl], h_spots.point[sl], h_spots.normal[sl] = r, tri_h[r, :3, 3], tri_h[r, :3, 2]
        gap = np.full(n, 2.0 * p.fabric_thickness)
        q, ok, best, pos_err, _, _ = solve_poses(skin, hand, touched, h_spots, Spots(*(
            np.asarray(a) for a in (t_spots.triangle, t_spots.point, t_spots.normal))), gap,
            idle_joints(skin, n, rng), calib, p, rng, counts[hand].astype(float))
        joints = _pair_joints(skin, hand, touched)
        for j, i in enumerate(rows):
            results.setdefault(i, {})[(hand, touched)] = (
                bool(ok[j]), {skin.robot.joint_names[c]: float(q[j, c]) for c in joints},
                int(sp_h.triangle_ids[h_spots.triangle[best[j]]]), h_spots.point[best[j]].tolist(),
                int(sp_t.triangle_ids[t_spots.triangle[j]]), t_spots.point[j].tolist(), 1000.0 * float(pos_err[j]))
    for i, t in enumerate(targets):
        tried = results.get(i, {})
        choice = next((a for a in _alternatives(t, pairs) if a in tried and tried[a][0]), None)
        if choice is None:
            choice = (t.hand, t.touched)
            if choice not in tried:
                continue
        ok, pose, h_tri, h_pt, t_tri, t_pt, err = tried[choice]
        t.hand, t.touched = choice
        t.pose = pose if ok else None
        t.hand_triangle_id, t.hand_point, t.touched_triangle_id, t.touched_point = h_tri, h_pt, t_tri, t_pt
        t.point = h_pt if t.part == t.hand else t_pt
        t.pose_error_mm = err


def _pair_joints(skin: SkinModel, hand: str, touched: str) -> list:
    robot = skin.robot
    cols = []
    for part in (hand, touched):
        chain = skin.parts[part].chain
        if chain is not None:
            cols += [robot.joint_index[j] for j in robot.chains[chain].joints if j is not None]
    return sorted(set(cols))
