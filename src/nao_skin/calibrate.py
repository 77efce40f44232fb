"""The calibration engine: from touches to corrected skin frames.

One entry point, :func:`calibrate`, with its options as data
(:class:`CalibrationOptions`). The thesis' findings are the defaults: a
reference part is held fixed while the other is fitted (hands from the
torso, then the torso from the hands, then the head from the calibrated
hands), each part level by level (mount, then patches, then triangles),
patches and triangles bounded. Within a stage the touches are re-paired
under the new calibration and solved again until the pairing stops changing.

What the thesis had to do by hand is done here: the mount of a hand that is
~160 degrees off nominal is first found in closed form (a rigid fit of
per-touch contact points, refined ICP-style on the closest COP pairs), so the
local solver starts in the right basin. Touches that no self-contact explains
are set aside by a gate after the mount stage and listed. A triangle with
fewer than ``min_triangle_activations`` paired activations, or a direction
the touches do not excite (Jacobi-scaled normal equations ill-conditioned),
is held at its prior and listed.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

from . import se3
from .errors import DataError
from .pairing import Pairing, metrics, pair_touches
from .skin import PART_NAMES, SkinCalibration, SkinModel
from .solver import ParameterLayout, ResidualModel, SolveOptions, condition_number, gram, solve
from .touches import TouchSet

HANDS = ("r_hand", "l_hand")
REFERENCE_BODY = ("torso", "head")
KIND_ROWS = {"cop": (0,), "taxel": (1,), "both": (0, 1), "taxel5": (2,), "cop+taxel5": (0, 2)}


@dataclass
class CalibrationOptions:
    """Everything that changes how calibration runs; the defaults follow the thesis."""

    strategy: str = "sequential"        # "sequential" (mount, patches, triangles) or "all-at-once"
    reference: str = "fixed"            # "fixed" (one part is the reference) or "simultaneous"
    bounded: bool = True
    patch_bounds: tuple = (0.003, np.pi / 30)        # |translation| m, |rotation| rad per component
    triangle_bounds: tuple = (0.0005, np.pi / 40)
    pairs: str = "both"                 # residual rows: "cop", "taxel", "both", "taxel5"
    mount_pairs: str = "cop"            # rows for the mount stage (robust while far off)
    loss: str = "huber"
    f_scale: float = 0.004              # m
    jacobian: str = "analytic"          # or "2-point"
    initial_guess: str = "rigid-fit"    # or "none"
    min_triangle_activations: int = 10  # thesis' threshold
    min_mount_touches: int = 10         # fewer touches with a reference: the mount is not determined
    min_patch_touches: int = 20         # the thesis: patches need about twice the mount's data
    condition_limit: float = 1e7        # of the Jacobi-scaled normal equations
    max_repairings: int = 8
    repair_tolerance: float = 0.01     # stop re-pairing when fewer touches than this share change pairs
    max_iterations: int = 50
    gate_mm: float = 15.0               # touches farther than this after the mount fit are set aside
    test_fraction: float = 0.3
    seed: int = 0
    max_touches: int | None = None      # use only this many training touches (speed/error sweeps)
    fabric_thickness: float = 0.001     # m of fabric over the taxels of each part: touching skins meet
                                        # at their fabric surfaces, 2 x this apart at the taxel centres
    estimate_fabric: bool = True        # estimate the (pressed) fabric thickness from the touches,
                                        # starting from fabric_thickness, within fabric_bounds
    fabric_bounds: tuple = (0.0, 0.003)
    prior_strength: float = 3.0         # > 0: patches and triangles get a Gaussian prior whose std is
                                        # their bound / this; residual noise taken as residual_sigma
    residual_sigma: float = 0.002       # m, per coordinate of a paired-point difference
    joint_levels: tuple = ("mount", "patch", "triangle")   # what the joint refinement frees
    rounds: int = 1                     # passes over the plan of fixed-reference steps
    joint_refinement: bool = True       # finish with every part free at once (same stages): a part fitted
                                        # to a fixed reference inherits that reference's error, which a
                                        # joint solve of all parts removes (measured on simulated truth)

    def solve_options(self) -> SolveOptions:
        return SolveOptions(loss=self.loss, f_scale=self.f_scale, max_iterations=self.max_iterations,
                            jacobian=self.jacobian)

    def validate(self) -> None:
        checks = {
            "strategy": (self.strategy, ("sequential", "all-at-once")),
            "reference": (self.reference, ("fixed", "simultaneous")),
            "pairs": (self.pairs, tuple(KIND_ROWS)),
            "mount_pairs": (self.mount_pairs, tuple(KIND_ROWS)),
            "loss": (self.loss, ("huber", "linear")),
            "jacobian": (self.jacobian, ("analytic", "2-point")),
            "initial_guess": (self.initial_guess, ("rigid-fit", "none")),
        }
        for name, (value, allowed) in checks.items():
            if value not in allowed:
                raise DataError(f"calibration option {name}={value!r}: expected one of {', '.join(allowed)}")


@dataclass
class Step:
    """Fit ``targets`` against touches with ``references`` (fixed unless simultaneous)."""

    targets: tuple
    references: tuple

    @property
    def name(self) -> str:
        return "+".join(self.targets) + (" from " + "+".join(self.references) if self.references else "")


@dataclass
class CalibrationResult:
    calibration: SkinCalibration
    report: dict
    train: TouchSet
    test: TouchSet
    set_aside: list = field(default_factory=list)


# ---------------------------------------------------------------------- planning
def touching_pairs(touches: TouchSet) -> set:
    """Pairs of part names that fire together in at least one touch."""
    fired = touches.parts_of_touch()
    out = set()
    names = touches.part_names
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if np.any(fired[:, i] & fired[:, j]):
                out.add(frozenset((names[i], names[j])))
    return out


def plan_steps(touches: TouchSet, options: CalibrationOptions) -> list:
    """The multi-session plan the thesis found best, restricted to the pairs in the data."""
    pairs = touching_pairs(touches)
    if not pairs:
        raise DataError("no touch has two skin parts active together: nothing to calibrate from")
    present = sorted({p for pair in pairs for p in pair}, key=lambda n: PART_NAMES.index(n) if n in PART_NAMES else 99)
    if options.reference == "simultaneous":
        return [Step(tuple(present), ())]
    steps = []
    calibrated = set()
    for hand in HANDS:                      # hands from the torso (or, lacking it, from the head)
        for body in REFERENCE_BODY:
            if frozenset((hand, body)) in pairs:
                steps.append(Step((hand,), (body,)))
                calibrated.add(hand)
                break
    for body in REFERENCE_BODY:             # then torso and head from the calibrated hands
        refs = tuple(h for h in HANDS if h in calibrated and frozenset((h, body)) in pairs)
        if refs and not any(s.targets == (body,) for s in steps):
            steps.append(Step((body,), refs))
    for pair in pairs:                      # anything else (e.g. two hands): fit the second from the first
        a, b = sorted(pair, key=lambda n: PART_NAMES.index(n) if n in PART_NAMES else 99)
        if not any(set(s.targets) | set(s.references) >= {a, b} for s in steps):
            steps.append(Step((b,), (a,)))
    return steps


# ---------------------------------------------------------------------- helpers
def _select_rows(pairing: Pairing, kinds: tuple, inliers: np.ndarray | None = None) -> Pairing:
    """Rows of the given kinds (and of inlier touches only, if given)."""
    keep = np.isin(pairing.row_kind, kinds)
    if inliers is not None:
        keep &= inliers[pairing.row_touch]
    new_index = np.cumsum(keep) - 1
    tkeep = keep[pairing.term_row]
    return Pairing(row_touch=pairing.row_touch[keep], row_kind=pairing.row_kind[keep],
                   row_parts=pairing.row_parts[keep], term_row=new_index[pairing.term_row[tkeep]],
                   term_part=pairing.term_part[tkeep], term_slot=pairing.term_slot[tkeep],
                   term_weight=pairing.term_weight[tkeep], distance=pairing.distance[keep])


_SUBSETS: dict = {}


def _pair_subset(touches: TouchSet, pa: str, pb: str):
    """The touches where both parts fire, and their rows in ``touches`` (cached: pairing runs
    many times on the same set, and most touches of a multi-pair recording involve other pairs)."""
    key = (id(touches), touches.n_touches, pa, pb)
    hit = _SUBSETS.get(key)
    if hit is not None and hit[0] is touches:
        return hit[1], hit[2]
    fired = touches.parts_of_touch()
    rows = np.flatnonzero(fired[:, touches.part_index(pa)] & fired[:, touches.part_index(pb)])
    sub = touches.subset(rows)
    if len(_SUBSETS) > 64:
        _SUBSETS.clear()
    _SUBSETS[key] = (touches, sub, rows)
    return sub, rows


def pair_parts(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, pa: str, pb: str,
               kinds=("cop", "taxel", "taxel5")) -> Pairing:
    """``pair_touches`` for one pair of parts, computed on the touches where both fire only."""
    sub, rows = _pair_subset(touches, pa, pb)
    p = pair_touches(sub, skin, calib, kinds=kinds, parts=(pa, pb))
    remap = np.array([touches.part_index(n) for n in sub.part_names], dtype=int)
    return Pairing(row_touch=rows[p.row_touch], row_kind=p.row_kind, row_parts=remap[p.row_parts],
                   term_row=p.term_row, term_part=remap[p.term_part], term_slot=p.term_slot,
                   term_weight=p.term_weight, distance=p.distance)


def _pair_step(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, step: Step,
               kinds=("cop", "taxel", "taxel5")) -> Pairing:
    """Pair the touches of every (target, reference) combination of a step."""
    names = step.targets + step.references
    parts = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if a not in step.targets and b not in step.targets:
                continue
            pa, pb = sorted((a, b), key=lambda n: PART_NAMES.index(n) if n in PART_NAMES else 99)
            if pa in touches.part_names and pb in touches.part_names:
                p = pair_parts(touches, skin, calib, pa, pb, kinds)
                if len(p.row_touch):
                    parts.append(p)
    if not parts:
        return None
    return _concat_pairings(parts)


def _concat_pairings(pairings: list) -> Pairing:
    if len(pairings) == 1:
        return pairings[0]
    offs = np.cumsum([0] + [len(p.row_touch) for p in pairings[:-1]])
    return Pairing(
        row_touch=np.concatenate([p.row_touch for p in pairings]),
        row_kind=np.concatenate([p.row_kind for p in pairings]),
        row_parts=np.concatenate([p.row_parts for p in pairings]),
        term_row=np.concatenate([p.term_row + o for p, o in zip(pairings, offs)]),
        term_part=np.concatenate([p.term_part for p in pairings]),
        term_slot=np.concatenate([p.term_slot for p in pairings]),
        term_weight=np.concatenate([p.term_weight for p in pairings]),
        distance=np.concatenate([p.distance for p in pairings]))


def _bounds(layout: ParameterLayout, targets: tuple, levels: set, x: np.ndarray, options: CalibrationOptions):
    lower = np.full(layout.size, -np.inf)
    upper = np.full(layout.size, np.inf)
    free = _free_mask(layout, targets, levels)
    for name in targets:
        m, p, t, end = layout.offsets[name]
        if options.bounded:
            for (a, b), (bt, br) in (((p, t), options.patch_bounds), ((t, end), options.triangle_bounds)):
                lim = np.tile([bt, bt, bt, br, br, br], (b - a) // 6)
                lower[a:b] = -lim
                upper[a:b] = lim
    # values already beyond a bound (e.g. from a previous free run) stay feasible
    lower = np.minimum(lower, x)
    upper = np.maximum(upper, x)
    return free, lower, upper


def _activation_counts(pairing: Pairing, touches: TouchSet, skin: SkinModel, part: str) -> np.ndarray:
    """Paired activations per triangle row of ``part``: touches whose residual terms use that triangle."""
    pidx = touches.part_index(part)
    sp = skin.parts[part]
    sel = pairing.term_part == pidx
    tri = sp.slot_triangle[pairing.term_slot[sel]]
    touch = pairing.row_touch[pairing.term_row[sel]]
    key = np.unique(touch * 1000 + tri)
    return np.bincount(key % 1000, minlength=len(sp.triangle_ids))


def _hold_unobservable(model: ResidualModel, calib: SkinCalibration, free: np.ndarray, free_levels: dict,
                       limit: float) -> list:
    """Columns to hold at the prior: no information, or the weakest directions until cond <= limit.

    Conditioning is judged on the Jacobi-scaled normal equations so that
    metres and radians compare; each direction weaker than ``1/limit`` of the
    strongest holds the column that dominates it.
    """
    cols = np.flatnonzero(free)
    if len(cols) == 0:
        return []
    h = gram(model.jacobian(calib, free_levels, cols))
    d = np.diag(h)
    informed = d > 1e-12 * max(d.max(), 1e-300)
    held = set(cols[~informed].tolist())
    idx = np.flatnonzero(informed)
    for _ in range(3):   # one decomposition usually settles it; a second pass checks
        if len(idx) == 0:
            break
        sub = h[np.ix_(idx, idx)]
        s = np.sqrt(np.diag(sub))
        ev, vec = np.linalg.eigh(sub / np.outer(s, s))
        weak = np.flatnonzero(ev < ev[-1] / limit)
        if len(weak) == 0:
            break
        # each weak direction holds the unknown that dominates it (distinct ones first)
        drop = set()
        for k in weak:
            for i in np.argsort(-np.abs(vec[:, k])):
                if int(idx[i]) not in drop:
                    drop.add(int(idx[i]))
                    break
        held |= {int(cols[i]) for i in drop}
        idx = np.array([i for i in idx if i not in drop], dtype=int)
    return sorted(held)


def _touch_hashes(pairing: Pairing, n_touches: int) -> np.ndarray:
    """A number per touch that changes when the pairing of that touch changes."""
    code = (pairing.term_part.astype(float) * 4099.0 + pairing.term_slot + 1.0) * (1.0 + pairing.row_kind[pairing.term_row])
    touch = pairing.row_touch[pairing.term_row]
    return np.bincount(touch, weights=np.sin(code * 0.7071067811865476) * np.sign(pairing.term_weight), minlength=n_touches)


# ---------------------------------------------------------------------- first guess
def _touch_centroids(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, part: str, frame: str):
    """Per-touch mean of the part's activated taxels: in its chain-end frame ('local') or the base."""
    pidx = touches.part_index(part)
    sel = touches.act_part == pidx
    touch = touches.act_touch[sel]
    local, _ = skin.parts[part].taxel_positions(calib.parts[part])
    pts = local[touches.act_slot[sel]]
    if frame == "base":
        pts = se3.transform_points(skin.robot.fk(skin.parts[part].chain, touches.joints[touch]), pts)
    sums = np.zeros((touches.n_touches, 3))
    np.add.at(sums, touch, pts)
    counts = np.bincount(touch, minlength=touches.n_touches)
    return sums / np.maximum(counts, 1)[:, None], counts > 0


def rigid_mount_guess(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, target: str,
                      references: tuple, iterations: int = 6, trim: float = 0.25) -> np.ndarray:
    """Closed-form mount correction of ``target``: rigid fit of its touch points onto the references'.

    First per-touch centroids of all activations (pairing is meaningless while
    the mount is far off), then a few ICP rounds on the closest COP pairs
    with the worst ``trim`` share of touches left out (experimenter's hand).
    """
    part = skin.parts[target]
    ref_sum = np.zeros((touches.n_touches, 3))
    ref_ok = np.zeros(touches.n_touches, bool)
    for ref in references:
        c, ok = _touch_centroids(touches, skin, calib, ref, "base")
        use = ok & ~ref_ok
        ref_sum[use] = c[use]
        ref_ok |= ok
    own, own_ok = _touch_centroids(touches, skin, calib, target, "local")
    both = np.flatnonzero(ref_ok & own_ok)
    if len(both) < 3:
        raise DataError(f"part '{target}': {len(both)} touches with a reference part, at least 3 needed for a mount fit")
    chain = skin.robot.fk(part.chain, touches.joints[both])
    ref_local = se3.transform_points(se3.invert(chain), ref_sum[both])      # reference points in the chain-end frame
    # mount-frame coordinates of the target's points under the current correction
    mount_now = part.mount_nominal @ se3.pose_matrix(calib.parts[target].mount)
    own_mount = se3.transform_points(se3.invert(mount_now), own[both])
    fit = se3.rigid_fit(own_mount, ref_local)                               # chain-end <- mount
    for _ in range(iterations):
        resid = np.linalg.norm(se3.transform_points(fit, own_mount) - ref_local, axis=1)
        keep = resid <= np.quantile(resid, 1.0 - trim)
        fit = se3.rigid_fit(own_mount[keep], ref_local[keep])
    corr = calib.copy()
    corr.parts[target].mount = se3.pose_vector(se3.invert(part.mount_nominal) @ fit)
    # ICP on closest COP pairs: pairing becomes meaningful once the mount is near
    step = Step((target,), tuple(references))
    for _ in range(iterations):
        pairing = _pair_step(touches, skin, corr, step, ("cop",))
        if pairing is None:
            break
        rows = _select_rows(pairing, (0,))
        src, dst = _cop_points(rows, touches, skin, corr, target)
        if len(src) < 3:
            break
        mount_now = part.mount_nominal @ se3.pose_matrix(corr.parts[target].mount)
        src_m = se3.transform_points(se3.invert(mount_now), src)
        resid = np.linalg.norm(se3.transform_points(mount_now, src_m) - dst, axis=1)
        keep = resid <= np.quantile(resid, 1.0 - trim)
        fit = se3.rigid_fit(src_m[keep], dst[keep])
        corr.parts[target].mount = se3.pose_vector(se3.invert(part.mount_nominal) @ fit)
    return corr.parts[target].mount


def _cop_points(rows: Pairing, touches: TouchSet, skin: SkinModel, calib: SkinCalibration, target: str):
    """For COP rows: the target's COP in its chain-end frame and the reference COP in the same frame."""
    tidx = touches.part_index(target)
    part = skin.parts[target]
    local, _ = part.taxel_positions(calib.parts[target])
    m = len(rows.row_touch)
    own = np.zeros((m, 3))
    is_target = rows.term_part == tidx
    np.add.at(own, rows.term_row[is_target], np.abs(rows.term_weight[is_target])[:, None] * local[rows.term_slot[is_target]])
    other = np.zeros((m, 3))
    for pidx in np.unique(rows.term_part[~is_target]):
        sel = rows.term_part == pidx
        name = touches.part_names[pidx]
        loc, _ = skin.parts[name].taxel_positions(calib.parts[name])
        fk = skin.robot.fk(skin.parts[name].chain, touches.joints[rows.row_touch[rows.term_row[sel]]])
        np.add.at(other, rows.term_row[sel],
                  np.abs(rows.term_weight[sel])[:, None] * se3.transform_points(fk, loc[rows.term_slot[sel]]))
    chain = skin.robot.fk(part.chain, touches.joints[rows.row_touch])
    return own, se3.transform_points(se3.invert(chain), other)


# ---------------------------------------------------------------------- evaluation
def evaluate(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, steps: list) -> dict:
    """Closest-COP / closest-taxel / 5-taxel distances over every touching pair of the plan."""
    if touches.n_touches == 0:
        return {"n_touches": 0}
    pairs = sorted({tuple(sorted((a, b), key=lambda n: PART_NAMES.index(n) if n in PART_NAMES else 99))
                    for s in steps for a in s.targets + s.references for b in s.targets + s.references if a != b})
    pairings = [pair_parts(touches, skin, calib, p[0], p[1]) for p in pairs
                if p[0] in touches.part_names and p[1] in touches.part_names]
    pairings = [p for p in pairings if len(p.row_touch)]
    if not pairings:
        return {"n_touches": 0}
    return metrics(_concat_pairings(pairings))


def truth_error(skin: SkinModel, calib: SkinCalibration, truth: SkinCalibration, parts=None) -> dict:
    """Distance of every calibrated taxel from its true position (chain-end frame), in mm."""
    out = {}
    errs_all = []
    for name in parts or skin.parts:
        if name not in truth.parts:
            continue
        p = skin.parts[name]
        est, _ = p.taxel_positions(calib.parts[name])
        true, _ = p.taxel_positions(truth.parts[name])
        e = np.linalg.norm(est[p.present] - true[p.present], axis=1) * 1000.0
        errs_all.append(e)
        out[name] = {"median": float(np.median(e)), "p95": float(np.percentile(e, 95)), "max": float(e.max())}
    if errs_all:
        e = np.concatenate(errs_all)
        out["all"] = {"median": float(np.median(e)), "p95": float(np.percentile(e, 95)), "max": float(e.max())}
    return out


# ---------------------------------------------------------------------- main entry
def calibrate(touches: TouchSet, skin: SkinModel, options: CalibrationOptions | None = None,
              prior: SkinCalibration | None = None, truth: SkinCalibration | None = None,
              progress: Callable[[str], None] | None = None,
              split: tuple | None = None) -> CalibrationResult:
    """Calibrate the skin parts that the touches connect.

    ``split``: ``(train, test)`` touch sets; by default a seeded random 70/30
    split of ``touches`` (duplicates are expected to be removed before).
    """
    from .datasets import split as split_touches

    options = options or CalibrationOptions()
    options.validate()
    say = progress or (lambda msg: None)
    t_start = time.perf_counter()
    for name in touches.part_names:
        if name not in skin.parts:
            raise DataError(f"touches name skin part '{name}' that the skin config does not have"
                            f" (configured: {', '.join(skin.parts)})")
    train, test = split if split is not None else split_touches(touches, options.test_fraction, options.seed)
    if options.max_touches is not None and train.n_touches > options.max_touches:
        rng = np.random.default_rng(options.seed)
        train = train.subset(np.sort(rng.choice(train.n_touches, options.max_touches, replace=False)))
    steps = plan_steps(train, options)
    _check_enough(train, steps, options)
    calib = (prior or skin.zero_calibration()).copy()
    for name in skin.parts:
        calib.parts.setdefault(name, skin.parts[name].zero_correction())
    report = {"options": _options_dict(options), "plan": [s.name for s in steps], "stages": [],
              "before": {"train": evaluate(train, skin, calib, steps), "test": evaluate(test, skin, calib, steps)}}
    if truth is not None:
        report["before"]["truth_taxel_error_mm"] = truth_error(skin, calib, truth)
    inliers = np.ones(train.n_touches, bool)
    fabric = options.fabric_thickness
    last_step, last_cost, last_inliers = None, np.inf, -1
    set_aside = []
    levels_seq = ([{"mount"}, {"patch"}, {"triangle"}] if options.strategy == "sequential"
                  else [{"mount", "patch", "triangle"}])
    schedule = [(r, step) for r in range(max(1, options.rounds)) for step in steps]
    if options.joint_refinement and options.reference == "fixed" and len(steps) > 1:
        joint = Step(tuple(sorted({p for s in steps for p in s.targets + s.references},
                                  key=lambda n: PART_NAMES.index(n) if n in PART_NAMES else 99)), ())
        schedule.append((options.rounds, joint))
    report["plan"] = [("joint refinement: " if not st.references and options.reference == "fixed" else "") + st.name
                      for r, st in schedule if r == 0 or not st.references]
    report["parts"] = sorted({p for s in steps for p in s.targets}, key=lambda n: PART_NAMES.index(n) if n in PART_NAMES else 99)
    report["pairs"] = sorted(sorted(p, key=lambda n: PART_NAMES.index(n) if n in PART_NAMES else 99)
                             for p in touching_pairs(train))
    for round_no, step in schedule:
        if True:
            prefix = f"round {round_no + 1}: " if options.rounds > 1 and step.references else ""
            if not step.references and options.reference == "fixed":
                prefix = "joint refinement: "
            # closed-form first guess of each mount that has a reference to be fitted to
            if options.initial_guess == "rigid-fit" and round_no == 0 and (step.references or options.reference == "simultaneous"):
                t0 = time.perf_counter()
                for target, refs in _guess_targets(step):
                    guess_step = Step((target,), refs)
                    before = _stage_cost(train, skin, calib, guess_step, inliers)
                    if before * 1000.0 < options.gate_mm / 2:
                        continue   # already in the basin (e.g. the torso): the local solver takes it from here
                    guess = calib.copy()
                    guess.parts[target].mount = rigid_mount_guess(train, skin, calib, target, refs)
                    if _stage_cost(train, skin, guess, guess_step, inliers) < before:
                        calib = guess
                say(f"{prefix}{step.name}: rigid-fit first guess ({time.perf_counter() - t0:.2f} s)")
            joint_step = not step.references and options.reference == "fixed"
            for levels in levels_seq:
                if joint_step and not levels & set(options.joint_levels):
                    continue
                if joint_step:
                    levels = levels & set(options.joint_levels)
                cost_before = (last_cost if last_step is step and last_inliers == int(inliers.sum())
                               else _stage_cost(train, skin, calib, step, inliers))
                stage = _run_stage(train, skin, calib, step, step.targets, levels, options, inliers, say, fabric)
                stage["name"] = prefix + stage["name"]
                cost_after = _stage_cost(train, skin, stage["calibration"], step, inliers)
                if cost_after > 1.25 * cost_before and not (round_no == 0 and "mount" in levels):
                    # never silently diverge: a stage that leaves the touches much farther apart is undone
                    stage.pop("calibration")
                    stage["reverted"] = (f"undone: mean closest COP {1000 * cost_after:.2f} mm after vs"
                                         f" {1000 * cost_before:.2f} mm before")
                    say(f"{stage['name']}: {stage['reverted']}")
                else:
                    fabric = stage["fabric_thickness_mm"] / 1000.0
                    calib = stage.pop("calibration")
                    cost_before = cost_after
                last_step, last_cost, last_inliers = step, cost_before, int(inliers.sum())
                if "mount" in levels and options.gate_mm > 0:
                    gate = _gate(train, skin, calib, step, options.gate_mm, inliers)
                    for row, dist in gate:
                        inliers[row] = False
                        set_aside.append({"touch": str(train.keys[row]), "step": prefix + step.name,
                                          "reason": f"closest COP pair {dist:.1f} mm after the mount fit > gate {options.gate_mm:.0f} mm"})
                    stage["set_aside"] = len(gate)
                stage["train"] = evaluate(train, skin, calib, [step])
                stage["test"] = evaluate(test, skin, calib, [step])
                if truth is not None:
                    stage["truth_taxel_error_mm"] = truth_error(skin, calib, truth, step.targets)
                report["stages"].append(stage)
                say(f"{stage['name']}: train closest COP {stage['train'].get('cop_mean_mm', float('nan')):.2f} mm,"
                    f" taxel {stage['train'].get('taxel_mean_mm', float('nan')):.2f} mm"
                    f" ({stage['iterations']} iterations, {stage['repairings']} pairings, {stage['seconds']:.2f} s)")
    report["final"] = {"train": evaluate(train, skin, calib, steps), "test": evaluate(test, skin, calib, steps)}
    # the same gate on both splits: touches whose closest COP pair stays farther than gate_mm
    # are not explained by a self-contact (experimenter's hand, stray activations)
    for split_name, ts in (("train", train), ("test", test)):
        explained = _explained(ts, skin, calib, steps, options.gate_mm)
        report["final"][f"{split_name}_accepted"] = evaluate(ts.subset(explained), skin, calib, steps)
        report["final"][f"{split_name}_accepted"]["n_not_explained"] = int((~explained).sum())
    if truth is not None:
        report["final"]["truth_taxel_error_mm"] = truth_error(skin, calib, truth)
    report["fabric_thickness_mm"] = 1000.0 * fabric
    report["set_aside"] = set_aside
    report["n_set_aside"] = len(set_aside)
    report["held"] = sorted({h for s in report["stages"] for h in s["held"]})
    report["total_seconds"] = time.perf_counter() - t_start
    return CalibrationResult(calib, report, train, test, set_aside)


def _check_enough(train: TouchSet, steps: list, options: CalibrationOptions) -> None:
    """Stop before solving when the touches cannot determine what is asked (one line)."""
    fired = train.parts_of_touch()
    for step in steps:
        for target in step.targets:
            others = [p for p in step.targets + step.references if p != target]
            t = train.part_index(target)
            with_ref = fired[:, t] & np.any(fired[:, [train.part_index(o) for o in others]], axis=1)
            n = int(with_ref.sum())
            need = options.min_mount_touches
            if n < need:
                raise DataError(f"part '{target}': {n} training touches with {'/'.join(others)}; calibrating its mount"
                                f" needs at least {need} (about {int(np.ceil(need / (1 - options.test_fraction)))}"
                                f" touches before the {int(options.test_fraction * 100)} % test split)")


def _guess_targets(step: Step) -> list:
    """(target, references) for the closed-form mount fit: a fixed step's targets, or in a
    simultaneous step each hand against the body parts it touches."""
    if step.references:
        return [(t, step.references) for t in step.targets]
    bodies = tuple(p for p in step.targets if p in REFERENCE_BODY)
    return [(h, bodies) for h in step.targets if h in HANDS and bodies]


def _options_dict(options: CalibrationOptions) -> dict:
    out = asdict(options)
    out["patch_bounds"] = list(options.patch_bounds)
    out["triangle_bounds"] = list(options.triangle_bounds)
    return out


def _stage_cost(touches, skin, calib, step, inliers) -> float:
    pairing = _pair_step(touches, skin, calib, step, ("cop",))
    if pairing is None or len(pairing.row_touch) == 0:
        return np.inf
    rows = pairing.row_kind == 0
    d = pairing.distance[rows]
    d = d[inliers[pairing.row_touch[rows]]]
    return float(np.mean(np.minimum(d, 0.05)))  # capped: a far-off minority must not decide


def _explained(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, steps: list, gate_mm: float) -> np.ndarray:
    """Touches whose closest COP pair (over the plan's part pairs) is within ``gate_mm``."""
    ok = np.ones(touches.n_touches, bool)
    if gate_mm <= 0 or touches.n_touches == 0:
        return ok
    best = np.full(touches.n_touches, np.inf)
    for step in steps:
        p = _pair_step(touches, skin, calib, step, ("cop",))
        if p is not None and len(p.row_touch):
            np.minimum.at(best, p.row_touch, p.distance * 1000.0)
    return ok & ((best <= gate_mm) | ~np.isfinite(best))


def _gate(touches, skin, calib, step, gate_mm, inliers) -> list:
    pairing = _pair_step(touches, skin, calib, step, ("cop",))
    rows = np.flatnonzero(pairing.row_kind == 0)
    out = {}
    for r in rows:
        t = int(pairing.row_touch[r])
        d = float(pairing.distance[r]) * 1000.0
        if inliers[t] and d > gate_mm:
            out[t] = max(out.get(t, 0.0), d)
    return sorted(out.items())


def _run_stage(touches, skin, calib, step, free_parts, levels, options, inliers, say, fabric) -> dict:
    """One stage: pair, solve, re-pair under the new calibration, until the pairing settles."""
    t0 = time.perf_counter()
    name = f"{step.name}: {'+'.join(sorted(levels, key=['mount', 'patch', 'triangle'].index))}"
    parts_in = tuple(p for p in step.targets + step.references if p in touches.part_names)
    layout = ParameterLayout(skin, parts_in)
    kinds = KIND_ROWS[options.mount_pairs if levels == {"mount"} else options.pairs]
    kind_names = tuple({0: "cop", 1: "taxel", 2: "taxel5"}[k] for k in kinds)
    free_levels = {p: set(levels) for p in free_parts}
    prior_x = layout.to_vector(calib, fabric)
    x = prior_x.copy()
    hashes = None
    iterations = repairings = 0
    free = None
    held_names: list = []
    model = None
    last_cost = np.inf
    for repairings in range(1, options.max_repairings + 1):
        current = layout.to_calibration(x, calib)
        pairing = _pair_step(touches, skin, current, step, kind_names)
        if pairing is None:
            raise DataError(f"{name}: no touch pairs the parts {', '.join(parts_in)}")
        pairing = _select_rows(pairing, kinds, inliers)
        if len(pairing.row_touch) == 0:
            raise DataError(f"{name}: no paired activations left to fit")
        new_hashes = _touch_hashes(pairing, touches.n_touches)
        if hashes is not None and np.mean(np.abs(new_hashes - hashes) > 1e-9) < options.repair_tolerance:
            break
        hashes = new_hashes
        model = ResidualModel(skin, touches.joints, pairing, touches.part_names, layout, calib,
                              variable_parts=free_parts, fabric=x[layout.fabric_col])
        if free is None:   # what the data determines is decided once, on the first pairing
            free, lower, upper = _bounds(layout, free_parts, levels, x, options)
            # the fabric is a property of the whole skin: estimated once the mounts are in place
            free[layout.fabric_col] = options.estimate_fabric and levels != {"mount"}
            lower[layout.fabric_col], upper[layout.fabric_col] = options.fabric_bounds
            if "patch" in levels:   # patches need about twice the mount's data (thesis 2.5)
                for p in free_parts:
                    pidx = touches.part_index(p)
                    n_with = len(np.unique(pairing.row_touch[pairing.term_row[pairing.term_part == pidx]]))
                    if n_with < options.min_patch_touches:
                        _, pp, t, _ = layout.offsets[p]
                        free[pp:t] = False
                        say(f"{name}: {p} has {n_with} paired touches (< {options.min_patch_touches}): patches held")
            if "triangle" in levels:
                for p in free_parts:
                    counts = _activation_counts(pairing, touches, skin, p)
                    _, _, t, _ = layout.offsets[p]
                    for tr in np.flatnonzero(counts < options.min_triangle_activations):
                        free[t + 6 * tr: t + 6 * tr + 6] = False
        # directions the touches do not excite are held; checked again after each re-pairing
        # because a new pairing can lose what the last one excited (holds only accumulate)
        free[_hold_unobservable(model, current, free, free_levels, options.condition_limit)] = False
        held_names = [layout.describe(c) for c in np.flatnonzero(_free_mask(layout, free_parts, levels) & ~free)]
        if not np.any(free):
            break
        result = solve(model, x, free, lower, upper, free_levels, options.solve_options(), prior=prior_x,
                       prior_weights=_prior_weights(layout, free_parts, options))
        iterations += result.iterations
        x = result.x
        if last_cost - result.cost < 1e-4 * result.cost:
            break
        last_cost = result.cost
    calib_out = layout.to_calibration(x, calib)
    cond = condition_number(model, calib_out, free_levels, np.flatnonzero(free)) if model is not None else None
    return {"name": name, "calibration": calib_out, "iterations": iterations, "repairings": repairings,
            "condition": cond, "held": _compress_held([h for h in held_names if h != "fabric_thickness"]),
            "fabric_thickness_mm": 1000.0 * float(x[layout.fabric_col]), "seconds": time.perf_counter() - t0}


def _prior_weights(layout, parts, options):
    """Per-unknown prior weights (sigma_residual / sigma_prior)^2 for patches and triangles."""
    w = np.zeros(layout.size)
    if options.prior_strength <= 0:
        return w
    for p in parts:
        _, pp, t, end = layout.offsets[p]
        for (a, b), (bt, br) in (((pp, t), options.patch_bounds), ((t, end), options.triangle_bounds)):
            sig = np.tile([bt, bt, bt, br, br, br], (b - a) // 6) / options.prior_strength
            w[a:b] = (options.residual_sigma / sig) ** 2
    return w


def _free_mask(layout, parts, levels):
    mask = np.zeros(layout.size, bool)
    for p in parts:
        m, pp, t, end = layout.offsets[p]
        if "mount" in levels:
            mask[m:pp] = True
        if "patch" in levels:
            mask[pp:t] = True
        if "triangle" in levels:
            mask[t:end] = True
    return mask


def _compress_held(names: list) -> list:
    """'part/frame/comp' entries -> 'part/frame' when all six components are held."""
    by_frame: dict = {}
    for n in names:
        frame, comp = n.rsplit("/", 1)
        by_frame.setdefault(frame, []).append(comp)
    return [f if len(c) == 6 else f"{f} ({','.join(c)})" for f, c in by_frame.items()]
