"""One calibration stage: pair, hold what the data cannot determine, solve, re-pair until settled."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg
import scipy.linalg.lapack

from nao_skin.calibration.layout import COMPONENTS, FINGERTIPS, KINEMATICS, ParameterLayout
from nao_skin.calibration.options import KIND_ROWS
from nao_skin.calibration.plan import Step
from nao_skin.calibration.pairing import KIND_FINGERTIP, KIND_NAMES, Pairing, chain_end_poses
from nao_skin.calibration.residuals import ResidualModel, condition_number, gram
from nao_skin.calibration.rows import (pair_step, pairing_key, select_rows, touch_hashes, weighted_by_touch,
                                      with_normal_rows)
from nao_skin.calibration.solver import solve
from nao_skin.errors import DataError
from nao_skin.model.robot import MAX_FINGERTIP_RADIUS
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.datasets import pose_weights
from nao_skin.touch.touches import TouchSet

if TYPE_CHECKING:   # only for annotations: calibrate imports this module
    from nao_skin.calibration.options import CalibrationOptions


def fitted_kinds(options: "CalibrationOptions", levels: set) -> tuple:
    """Names of the pair kinds ('cop', 'taxel', 'taxel5') a stage of these levels fits."""
    names = {v: k for k, v in KIND_NAMES.items()}
    return tuple(names[k] for k in KIND_ROWS[options.mount_pairs if levels == {"mount"} else options.pairs])


@dataclass
class StageResult:
    """What one stage reached and how (cf. scipy's ``OptimizeResult``)."""

    name: str
    calibration: SkinCalibration
    iterations: int
    repairings: int
    condition: float | None          # Jacobi-scaled normal equations at the end
    held: list                       # what it held, compressed for the report
    held_components: set             # 'part/frame/comp' it held
    estimated_components: set        # 'part/frame/comp' it set free
    fabric_thickness_mm: float
    prior_sigma: dict
    seconds: float
    kinematics_held: list = ()       # kinematic unknowns it held (directions the touches do not excite)
    kinematics_std: dict | None = None   # std of the kinematic unknowns it estimated (rad, m)
    # the touches (all of them) paired for the kinds it fits, where it started and, when the pairing
    # settled, where it ended: rows.pairing_key of the calibration -> Pairing
    pairings: dict = field(default_factory=dict)
    fingertips_held: list = ()       # fingertip sphere components it held ('<fingertip>/<component>')

    def report(self, name: str | None = None) -> dict:
        """The stage's entry in the calibration report (``name``: with the plan's prefix)."""
        return {"name": name or self.name, "iterations": self.iterations, "repairings": self.repairings,
                "condition": self.condition, "held": self.held, "fabric_thickness_mm": self.fabric_thickness_mm,
                "prior_sigma": self.prior_sigma, "seconds": self.seconds}


@dataclass(frozen=True)
class Stage:
    """What one stage fits and how: the targets of ``step`` (paired with its references and fingertip scenes) at
    ``levels``, with ``options``. ``max_repairings``: instead of ``options.max_repairings`` (a warm update's
    ``options.warm_repairings``, a fixed-reference step's ``options.reference_repairings``); the last of them
    solves to ``options.max_iterations``, the others stop after ``options.repair_iterations``. ``condition``:
    report the condition number of the final normal equations (a Jacobian and an eigendecomposition more: a live
    update, which reports no stage, skips it)."""

    step: Step
    levels: frozenset
    options: "CalibrationOptions"
    max_repairings: int | None = None
    condition: bool = True


@dataclass(frozen=True)
class StageStart:
    """Where a stage starts: the calibration, the fabric estimate (m), the touches the gate kept (None: all), the
    prior std per group (:data:`PRIOR_GROUPS`; None: the options'), where the prior of the patches and triangles
    is centred (``anchor``; None: the calibration: a warm-started update centres it where its session started,
    or each update would count the touches of the one before again) and each touch's expected ``cop_skin`` row at
    the true skin (``press``, :func:`~nao_skin.calibration.press.press_offsets`), subtracted from the rows."""

    calibration: SkinCalibration
    fabric: float
    inliers: np.ndarray | None = None
    prior_sigma: dict | None = None
    anchor: SkinCalibration | None = None
    press: dict | None = None


def run_stage(touches: TouchSet, skin: SkinModel, stage: Stage, start: StageStart, say) -> StageResult:
    """One stage: pair, solve, re-pair under the new calibration, until the pairing settles.

    With ``options.prior_scale == 'empirical'`` a stage that frees every part it pairs (the joint refinement)
    re-estimates the prior's widths from the touches after each solve; the stage returns the last estimate.
    """
    t0 = time.perf_counter()
    step, levels, options, calib = stage.step, set(stage.levels), stage.options, start.calibration
    free_parts, inliers = step.targets, start.inliers
    name = f"{step.name}: {'+'.join(sorted(levels, key=['mount', 'patch', 'triangle', KINEMATICS].index))}"
    parts_in = tuple(p for p in step.targets + step.references if p in touches.part_names)
    # kinematic unknowns: the joint offsets and named links of the chains the stage's parts hang off
    kinematic = tuple(skin.robot.kinematic_names(step.chains(skin))) if KINEMATICS in levels else ()
    layout = ParameterLayout(skin, parts_in, kinematic, tuple(f for f in step.fingertip_names if f in touches.fingertips))
    kind_names = fitted_kinds(options, levels)
    # a step's fingertip scenes are fitted in each of its stages, whatever the options' rows of two parts
    kinds = tuple(KIND_NAMES[k] for k in kind_names) + ((KIND_FINGERTIP,) if layout.fingertip_names else ())
    # normal rows are built from the closest taxel (or COP) pairs: pair COPs too if neither is fitted
    normal_weight = options.normal_weight if levels & set(options.normal_levels) else 0.0
    pair_kinds = (kind_names if normal_weight <= 0 or {"cop", "taxel"} & set(kind_names)
                  else kind_names + ("cop",))
    free_levels = {p: set(levels) for p in free_parts}
    prior_x = layout.to_vector(calib, start.fabric)
    x = prior_x.copy()
    centre = prior_x if start.anchor is None else _anchored(layout, prior_x, start.anchor)
    hashes = None
    iterations = repairings = 0
    free = None
    held_names: list = []
    model = None
    last_cost = np.inf
    prior_sigma = dict(initial_prior_sigma(options) if start.prior_sigma is None else start.prior_sigma)
    pairings = {}
    limit = stage.max_repairings or options.max_repairings
    touch_weight = pose_weights(touches, options.pose_weight)
    rules = options.row_rules(start.press)
    result = None
    for repairings in range(1, limit + 1):
        current = layout.to_calibration(x, calib)
        pairing_all = pair_step(touches, skin, current, step, pair_kinds, rules)
        if pairing_all is None:
            raise DataError(f"{name}: no touch pairs the parts {', '.join(parts_in)}")
        pairing = select_rows(pairing_all, kinds, inliers)
        if len(pairing.row_touch) == 0:
            _nothing_to_fit(name, pairing_all, inliers, options)
        pairing = weighted_by_touch(with_normal_rows(pairing, pairing_all, normal_weight, inliers), touch_weight)
        new_hashes = touch_hashes(pairing, touches.n_touches)
        settled = hashes is not None and np.mean(np.abs(new_hashes - hashes) > 1e-9) < options.repair_tolerance
        if repairings == 1 or settled:   # where the stage starts and ends: what its cost is measured on
            pairings[pairing_key(current)] = (pairing_all if pair_kinds == kind_names
                                              else select_rows(pairing_all, kinds))
        if settled:
            break
        hashes = new_hashes
        on_robot = skin.with_kinematics(current)   # the robot the corrections so far describe
        model = ResidualModel(skin, partial(chain_end_poses, touches, on_robot), pairing, touches.part_names, layout,
                              calib, variable_parts=free_parts, fabric=x[layout.fabric_col],
                              kinematic_poses=(lambda c: partial(chain_end_poses, touches, skin.with_kinematics(c)))
                              if kinematic else None, fingertip_names=touches.fingertips)
        if free is None:   # what the data determines is decided once, on the first pairing
            free, lower, upper = _bounds(layout, free_parts, levels, x, options, pairing)
            _hold_thin_frames(free, layout, stage, pairing, touches, skin, lambda msg: say(f"{name}: {msg}"))
            # the scene's gauge (its chains' first joints about one line, turned with the base's skin): held at
            # the config's; the touches' residuals alone pull it anywhere (docs/decisions.md, "One robot, every
            # scene")
            gauge = skin.robot.rotation_gauge(step.chains(skin)) if layout.kinematic_cols else None
            if gauge in layout.kinematic_cols:
                free[layout.kinematic_cols[gauge]] = False
        # directions the touches do not excite are held; checked again after each re-pairing
        # because a new pairing can lose what the last one excited (holds only accumulate).
        # Held means at the prior: what an earlier solve of this stage moved there goes back.
        newly_held = _hold_unobservable(model, current, free, free_levels, options.condition_limit,
                                        prefer=set(layout.kinematic_cols.values()))
        free[newly_held] = False
        newly_held += _hold_undetermined_fingertips(model, current, free, free_levels, layout, options,
                                                    _prior_weights(layout, free_parts, options, prior_sigma))
        free[newly_held] = False
        x[newly_held] = prior_x[newly_held]
        held_names = [layout.describe(c) for c in np.flatnonzero(free_mask(layout, free_parts, levels) & ~free)]
        if not np.any(free):
            break
        weights = _prior_weights(layout, free_parts, options, prior_sigma)
        result = solve(model, x, free, lower, upper, free_levels, options.solve_options(last=repairings == limit),
                       prior=centre, prior_weights=weights)
        iterations += result.iterations
        x = result.x
        # the prior's width from the evidence once every part is free: fitted to a fixed reference,
        # a part's spread would include that reference's error
        if options.prior_scale == "empirical" and not step.references:
            prior_sigma = evidence_prior_sigma(result, x, free, weights, layout, free_parts, levels,
                                               prior_sigma, options)
        if last_cost - result.cost < 1e-4 * result.cost:
            break
        last_cost = result.cost
    calib_out = layout.to_calibration(x, calib)
    cond = (condition_number(model, calib_out, free_levels, np.flatnonzero(free))
            if stage.condition and model is not None and free is not None and np.any(free) else None)
    kinematics_held = [h.split("/", 1)[1] for h in held_names if h.startswith(f"{KINEMATICS}/")]
    for kname in kinematics_held:   # held at nominal: not a correction of the calibration
        calib_out.kinematics.pop(kname, None)
    fingertips_held = [h.split("/", 1)[1] for h in held_names if h.startswith(f"{FINGERTIPS}/")]
    held = [h for h in held_names if h != "fabric_thickness" and not h.startswith((f"{KINEMATICS}/", f"{FINGERTIPS}/"))]
    estimated = ({layout.describe(c) for c in np.flatnonzero(free_mask(layout, free_parts, levels) & free)
                  if c <= layout.fabric_col} if free is not None else set())
    std = (_kinematic_std(model, calib_out, free, layout, result, options) if kinematic and free is not None
           and np.any(free[list(layout.kinematic_cols.values())]) and result.normal_matrix is not None else None)
    if std:
        calib_out.kinematics_std = {**{k: v for k, v in calib.kinematics_std.items() if k in calib_out.kinematics},
                                    **std}
    if layout.fingertip_names and free is not None and result is not None and result.normal_matrix is not None:
        calib_out.fingertips_std = {**calib.fingertips_std,
                                    **_fingertip_std(model, calib_out, free, layout, result, options)}
    calib_out.fabric_thickness = float(x[layout.fabric_col])    # what its fingertip rows are measured at
    return StageResult(name, calib_out, iterations, repairings, cond, compress_held(held), set(held), estimated,
                       1000.0 * float(x[layout.fabric_col]), prior_sigma, time.perf_counter() - t0,
                       kinematics_held, std, pairings, fingertips_held)


def _nothing_to_fit(name: str, pairing_all: Pairing, inliers: np.ndarray | None, options) -> None:
    """Raise why a stage's pairing left no row to fit: the gate set every touch aside, or nothing paired."""
    if len(pairing_all.row_touch) and inliers is not None and not np.any(inliers[pairing_all.row_touch]):
        raise DataError(f"{name}: the gate set aside every touch that pairs these parts (farther apart than"
                        f" {options.gate_mm:g} mm after the mount fit): a gate that tight, or a recording"
                        f" that does not fit the robot config, the taxel files or the starting calibration"
                        f" (--gate-mm 0: no gate)")
    raise DataError(f"{name}: no paired activations left to fit")


def _hold_thin_frames(free: np.ndarray, layout: ParameterLayout, stage: Stage, pairing: Pairing, touches: TouchSet,
                      skin: SkinModel, say) -> None:
    """Hold (in ``free``) the patches of a part with fewer than ``min_patch_touches`` paired touches (patches need
    about twice the mount's data, thesis 2.5) and the triangles with fewer than ``min_triangle_activations``
    paired activations, where the stage frees them."""
    options = stage.options
    if "patch" in stage.levels:
        for p in stage.step.targets:
            pidx = touches.part_index(p)
            n_with = len(np.unique(pairing.row_touch[pairing.term_row[pairing.term_part == pidx]]))
            if n_with < options.min_patch_touches:
                _, pp, t, _ = layout.offsets[p]
                free[pp:t] = False
                say(f"{p} has {n_with} paired touches (< {options.min_patch_touches}): patches held")
    if "triangle" in stage.levels:
        for p in stage.step.targets:
            counts = _activation_counts(pairing, touches, skin, p)
            _, _, t, _ = layout.offsets[p]
            for tr in np.flatnonzero(counts < options.min_triangle_activations):
                free[t + 6 * tr: t + 6 * tr + 6] = False


# how far a kinematic correction may go: (m of a link length, rad of a joint offset); a real error is
# a few mm and degrees, anything near these is the solver trading the kinematics for a wrong pairing
KINEMATIC_BOUNDS = {True: 0.03, False: 0.2}
# m: how far a fingertip's sphere centre may move from the robot config's (the real hand's fitted point lies 1-2.5 cm
# from the CTU group's model's)
FINGERTIP_SHIFT = 0.05


def _posterior_std(model: ResidualModel, calib: SkinCalibration, free: np.ndarray, result, options,
                   columns: np.ndarray) -> np.ndarray | None:
    """Standard deviation of the unknowns in ``columns`` (NaN where held): the inverse of the last solve's normal
    matrix (robust row weights) times the residual variance per coordinate; None when it is singular. Rows of one
    touch are not independent (its taxel pairs share the pose), so read it as a lower bound."""
    cols = np.flatnonzero(free)
    dist = np.linalg.norm(model.residuals(calib), axis=1)
    w = np.where(dist <= options.f_scale, 1.0, options.f_scale / np.maximum(dist, 1e-15))
    dof = max(3 * len(dist) - len(cols), 1)
    s2 = float(np.sum(w * dist ** 2)) / dof
    try:
        cov = np.linalg.inv(result.normal_matrix) * s2
    except np.linalg.LinAlgError:
        return None
    pos = np.searchsorted(cols, columns)
    found = (pos < len(cols)) & (cols[np.minimum(pos, len(cols) - 1)] == columns)
    return np.where(found, np.sqrt(np.maximum(np.diag(cov)[np.minimum(pos, len(cols) - 1)], 0.0)), np.nan)


def _kinematic_std(model: ResidualModel, calib: SkinCalibration, free: np.ndarray, layout: ParameterLayout,
                   result, options) -> dict:
    """Standard deviation of each estimated kinematic unknown (:func:`_posterior_std`)."""
    names = list(layout.kinematic_cols)
    std = _posterior_std(model, calib, free, result, options, np.array([layout.kinematic_cols[n] for n in names]))
    return {} if std is None else {n: float(v) for n, v in zip(names, std) if np.isfinite(v)}


def _fingertip_std(model: ResidualModel, calib: SkinCalibration, free: np.ndarray, layout: ParameterLayout,
                   result, options) -> dict:
    """Standard deviations of each fingertip sphere's correction (4,) (:func:`_posterior_std`; NaN: held)."""
    out = {}
    for name, first in layout.fingertip_cols.items():
        std = _posterior_std(model, calib, free, result, options, np.arange(first, first + 4))
        if std is not None:
            out[name] = std
    return out

def _anchored(layout: ParameterLayout, prior_x: np.ndarray, anchor: SkinCalibration) -> np.ndarray:
    """``prior_x`` with the patch and triangle components of ``anchor`` (mounts and fabric have no prior
    to speak of: the solver's floor keeps them where the stage starts)."""
    centre = prior_x.copy()
    anchored = layout.to_vector(anchor)
    for m, p, t, end in layout.offsets.values():
        centre[p:end] = anchored[p:end]
    return centre


def _bounds(layout: ParameterLayout, targets: tuple, levels: set, x: np.ndarray, options: "CalibrationOptions",
            pairing: Pairing) -> tuple:
    """``(free, lower, upper)`` of a stage on its first pairing: the columns of ``targets`` at ``levels`` (the
    patches and triangles bounded where ``options.bounded``), the fabric where it is estimated, the kinematic
    corrections and the fingertips' spheres within their bounds."""
    lower = np.full(layout.size, -np.inf)
    upper = np.full(layout.size, np.inf)
    free = free_mask(layout, targets, levels)
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
    # the fabric is a property of the whole skin: estimated once the mounts are in place, from rows of two
    # skins (against a fingertip alone it is one unknown with the fingertip's radius)
    free[layout.fabric_col] = (options.estimate_fabric and levels != {"mount"}
                               and bool(np.any(pairing.row_kind != KIND_FINGERTIP)))
    lower[layout.fabric_col], upper[layout.fabric_col] = options.fabric_bounds
    for kname, col in layout.kinematic_cols.items():
        bound = KINEMATIC_BOUNDS[kname in layout.skin.robot.links]
        lower[col], upper[col] = min(-bound, x[col]), max(bound, x[col])
    for fname, col in layout.fingertip_cols.items():    # a sphere of a radius >= 0, near the config's
        radius = layout.skin.robot.fingertip(fname).radius
        lower[col:col + 4] = np.minimum([-FINGERTIP_SHIFT] * 3 + [-radius], x[col:col + 4])
        upper[col:col + 4] = np.maximum([FINGERTIP_SHIFT] * 3 + [MAX_FINGERTIP_RADIUS - radius], x[col:col + 4])
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
                       limit: float, prefer: set = frozenset()) -> list:
    """Columns to hold at the prior: no information, or the weakest directions until cond <= limit.

    Conditioning is judged on the Jacobi-scaled normal equations so that
    metres and radians compare; each direction weaker than ``1/limit`` of the
    strongest holds the column that dominates it, or a column of ``prefer`` that takes a large part
    in it: a kinematic unknown the skin's frames can stand for (a WristYaw offset and the hand
    mount turned about that axis are one direction) is held at nominal rather than the frame.
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
        scaled = sub / np.outer(s, s)
        if _clearly_conditioned(scaled, limit):   # usually nothing is weak: decided without eigenvalues
            break
        ev = np.linalg.eigvalsh(scaled)   # eigenvalues alone (3x cheaper)
        if ev[0] >= ev[-1] / limit:
            break
        ev, vec = np.linalg.eigh(scaled)
        weak = np.flatnonzero(ev < ev[-1] / limit)
        # each weak direction holds the unknown that dominates it (distinct ones first)
        drop = set()
        for k in weak:
            share = np.abs(vec[:, k])
            order = np.argsort(-share)
            preferred = [i for i in order if int(cols[idx[i]]) in prefer and share[i] >= 0.3 * share[order[0]]]
            for i in preferred + list(order):
                if int(idx[i]) not in drop:
                    drop.add(int(idx[i]))
                    break
        held |= {int(cols[i]) for i in drop}
        idx = np.array([i for i in idx if i not in drop], dtype=int)
    return sorted(held)

# m: a fingertip sphere's component the touches determine less well than this (posterior std at the rows' noise)
# is held at the robot config's: pressed on a flat part alone, the radius and the part's place along its normal are
# one unknown, and the fit would trade one for the other (simulator, fingertip-torso: radius 1.1 mm for a true 5,
# the torso 5 mm off)
FINGERTIP_DETERMINED = 0.001


def _hold_undetermined_fingertips(model: ResidualModel, calib: SkinCalibration, free: np.ndarray, free_levels: dict,
                                  layout: ParameterLayout, options, prior_weights: np.ndarray) -> list:
    """The free fingertip sphere columns whose posterior std (the free columns' normal equations with the patches'
    and triangles' prior, at ``options.residual_sigma`` per coordinate) exceeds :data:`FINGERTIP_DETERMINED`."""
    tips = [c for first in layout.fingertip_cols.values() for c in range(first, first + 4) if free[c]]
    if not tips:
        return []
    cols = np.flatnonzero(free)
    h = gram(model.jacobian(calib, free_levels, cols)) + np.diag(prior_weights[cols])
    try:
        var = inverse_diagonal(h)
    except np.linalg.LinAlgError:
        return tips
    std = options.residual_sigma * np.sqrt(np.maximum(var, 0.0))
    pos = np.searchsorted(cols, tips)
    return [c for c, k in zip(tips, pos) if not std[k] <= FINGERTIP_DETERMINED]


def _clearly_conditioned(scaled: np.ndarray, limit: float) -> bool:
    """Whether the eigenvalues of the symmetric ``scaled`` satisfy ``smallest >= largest / limit``
    by a margin that rounding cannot close (False: undecided, the eigenvalues decide).

    The largest eigenvalue is at most the largest absolute row sum ``b``; a Cholesky factorisation of
    ``scaled - 2 b / limit I`` exists only if the smallest exceeds ``2 b / limit``. Both tests, and
    the eigenvalues themselves, are exact up to ~n^2 eps b, far below ``b / limit`` while
    ``limit n^2 eps <= 0.25``. A factorisation costs a tenth of the eigenvalues at a few hundred unknowns.
    """
    n = len(scaled)
    bound = float(np.max(np.abs(scaled).sum(axis=1)))
    if not np.isfinite(bound) or limit * n * n * np.finfo(float).eps > 0.25:
        return False
    try:
        scipy.linalg.cholesky(scaled - (2.0 * bound / limit) * np.eye(n), lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        return False
    return True

PRIOR_GROUPS = ("patch_translation", "patch_rotation", "triangle_translation", "triangle_rotation")


def initial_prior_sigma(options: "CalibrationOptions") -> dict:
    """Prior std of each patch / triangle component (m, rad) before the touches say more: bound / prior_strength."""
    if options.prior_strength <= 0:
        return {}
    (pt, pr), (tt, tr) = options.patch_bounds, options.triangle_bounds
    return dict(zip(PRIOR_GROUPS, (pt / options.prior_strength, pr / options.prior_strength,
                                   tt / options.prior_strength, tr / options.prior_strength)))


def prior_group_columns(layout, parts, group: str) -> np.ndarray:
    """Columns of ``parts`` in one prior group, e.g. 'triangle_rotation'."""
    level, comp = group.split("_")
    out = []
    for p in parts:
        _, pp, t, end = layout.offsets[p]
        a, b = (pp, t) if level == "patch" else (t, end)
        cols = np.arange(a, b).reshape(-1, 6)
        out.append(cols[:, :3] if comp == "translation" else cols[:, 3:])
    return np.concatenate([c.ravel() for c in out]).astype(int) if out else np.zeros(0, int)


def _prior_weights(layout, parts, options, prior_sigma: dict):
    """Per-unknown prior weights (sigma_residual / sigma_prior)^2 for patches and triangles."""
    w = np.zeros(layout.size)
    for group, sigma in prior_sigma.items():
        w[prior_group_columns(layout, parts, group)] = (options.residual_sigma / sigma) ** 2
    return w


def evidence_prior_sigma(result, x: np.ndarray, free: np.ndarray, weights: np.ndarray, layout, parts,
                         levels, prior_sigma: dict, options: "CalibrationOptions") -> dict:
    """Widen the prior std of the groups a solve fitted when the touches say the skin is farther off.

    How far patches and triangles sit from the layout is a property of the
    robot's skin (how carefully it was glued), not of the thesis' bounds: a
    prior made from the bounds (bound / prior_strength) over-shrinks a skin
    glued on less carefully. MacKay's evidence update per group,
    ``sigma^2 = sum(x^2) / gamma`` over the group's corrections ``x`` (from the
    layout), with ``gamma = sum(1 - Sigma_jj / sigma^2)`` the number of
    components the touches determine (``Sigma``, the posterior covariance, from
    the solve's normal matrix). It only ever widens the prior, up to 3 x the
    bound: for groups the touches barely determine the update collapses towards
    zero (simulator, triangles: 0.05 mm where the truth is 0.17 mm per
    component, true error up 10 %), so the assumed width is the floor.
    """
    if result.normal_matrix is None or not prior_sigma or not set(levels) & {"patch", "triangle"}:
        return prior_sigma
    cols = np.flatnonzero(free)
    try:
        inv_diag = inverse_diagonal(result.normal_matrix)
    except np.linalg.LinAlgError:
        return prior_sigma
    if not np.all(np.isfinite(inv_diag)):
        return prior_sigma
    bounds = {"patch": options.patch_bounds, "triangle": options.triangle_bounds}
    floor = initial_prior_sigma(options)
    out = dict(prior_sigma)
    for group in prior_sigma:
        level, comp = group.split("_")
        if level not in levels:
            continue
        idx = np.flatnonzero(np.isin(cols, prior_group_columns(layout, parts, group)))   # positions among free
        determined = float(np.sum(np.clip(1.0 - weights[cols[idx]] * inv_diag[idx], 0.0, 1.0)))
        if determined < 1.0:
            continue   # the touches say next to nothing about this group: keep what was assumed
        bound = bounds[level][0 if comp == "translation" else 1]
        sigma = np.sqrt(float(np.sum(x[cols[idx]] ** 2)) / determined)
        out[group] = float(np.clip(sigma, floor[group], 3.0 * bound))
    return out


def inverse_diagonal(h: np.ndarray) -> np.ndarray:
    """``diag(h^-1)`` of a symmetric positive definite ``h``: the column sums of ``L^-1`` squared, ``L`` its
    Cholesky factor (a third of the work of an LU inverse; it runs after every solve of a joint stage).
    A matrix that is not positive definite falls back to the LU inverse (LinAlgError if singular)."""
    factor, info = scipy.linalg.lapack.dpotrf(h, lower=1, clean=1)
    if info == 0:
        inv_factor, info = scipy.linalg.lapack.dtrtri(factor, lower=1)
    if info != 0:
        return np.diag(np.linalg.inv(h)).copy()
    return np.einsum("ij,ij->j", inv_factor, inv_factor)


def free_mask(layout, parts, levels):
    mask = np.zeros(layout.size, bool)
    for p in parts:
        m, pp, t, end = layout.offsets[p]
        if "mount" in levels:
            mask[m:pp] = True
        if "patch" in levels:
            mask[pp:t] = True
        if "triangle" in levels:
            mask[t:end] = True
    if KINEMATICS in levels:
        mask[list(layout.kinematic_cols.values())] = True
    for first in layout.fingertip_cols.values():     # a fingertip scene's sphere is free wherever it is fitted
        mask[first:first + 4] = True
    return mask

def compress_held(names: list) -> list:
    """'part/frame/comp' entries -> 'part/frame' when all six components are held."""
    by_frame: dict = {}
    for n in names:
        frame, comp = n.rsplit("/", 1)
        by_frame.setdefault(frame, []).append(comp)
    return [f if len(c) == 6 else f"{f} ({','.join(sorted(c, key=COMPONENTS.index))})" for f, c in by_frame.items()]


def held_frames(held) -> dict:
    """``{(part, frame): held component names}`` of entries as :func:`compress_held` writes them
    ('l_hand/triangle_3 (rx,ry)'; all of :data:`COMPONENTS` when an entry names none), in their order; a frame
    listed twice holds the union."""
    out: dict = {}
    for entry in held or ():
        name, _, comps = str(entry).partition(" ")
        part, _, frame = name.partition("/")
        out.setdefault((part, frame), set()).update(comps.strip("()").split(",") if comps else COMPONENTS)
    return {key: tuple(c for c in COMPONENTS if c in comps) for key, comps in out.items()}
