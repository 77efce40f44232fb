"""One calibration stage: pair, hold what the data cannot determine, solve, re-pair until settled."""
from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from .calib_pairs import KIND_ROWS, pair_step, select_rows, touch_hashes, with_normal_rows
from .errors import DataError
from .pairing import KIND_NAMES, Pairing
from .skin import SkinCalibration, SkinModel
from .solver import ParameterLayout, ResidualModel, condition_number, gram, solve
from .touches import TouchSet

if TYPE_CHECKING:   # only for annotations: calibrate imports this module
    from .calibrate import CalibrationOptions


def fitted_kinds(options: "CalibrationOptions", levels: set) -> tuple:
    """Names of the pair kinds ('cop', 'taxel', 'taxel5') a stage of these levels fits."""
    names = {v: k for k, v in KIND_NAMES.items()}
    return tuple(names[k] for k in KIND_ROWS[options.mount_pairs if levels == {"mount"} else options.pairs])


def run_stage(touches, skin, calib, step, free_parts, levels, options, inliers, say, fabric) -> dict:
    """One stage: pair, solve, re-pair under the new calibration, until the pairing settles."""
    t0 = time.perf_counter()
    name = f"{step.name}: {'+'.join(sorted(levels, key=['mount', 'patch', 'triangle'].index))}"
    parts_in = tuple(p for p in step.targets + step.references if p in touches.part_names)
    layout = ParameterLayout(skin, parts_in)
    kinds = KIND_ROWS[options.mount_pairs if levels == {"mount"} else options.pairs]
    kind_names = fitted_kinds(options, levels)
    # normal rows are built from the closest taxel (or COP) pairs: pair COPs too if neither is fitted
    normal_weight = options.normal_weight if set(levels) & set(options.normal_levels) else 0.0
    pair_kinds = (kind_names if normal_weight <= 0 or {"cop", "taxel"} & set(kind_names)
                  else kind_names + ("cop",))
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
        pairing_all = pair_step(touches, skin, current, step, pair_kinds)
        if pairing_all is None:
            raise DataError(f"{name}: no touch pairs the parts {', '.join(parts_in)}")
        pairing = select_rows(pairing_all, kinds, inliers)
        if len(pairing.row_touch) == 0:
            raise DataError(f"{name}: no paired activations left to fit")
        pairing = with_normal_rows(pairing, pairing_all, normal_weight, inliers)
        new_hashes = touch_hashes(pairing, touches.n_touches)
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
        # because a new pairing can lose what the last one excited (holds only accumulate).
        # Held means at the prior: what an earlier solve of this stage moved there goes back.
        newly_held = _hold_unobservable(model, current, free, free_levels, options.condition_limit)
        free[newly_held] = False
        x[newly_held] = prior_x[newly_held]
        held_names = [layout.describe(c) for c in np.flatnonzero(free_mask(layout, free_parts, levels) & ~free)]
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
    held = [h for h in held_names if h != "fabric_thickness"]
    estimated = ({layout.describe(c) for c in np.flatnonzero(free_mask(layout, free_parts, levels) & free)}
                 if free is not None else set())
    return {"name": name, "calibration": calib_out, "iterations": iterations, "repairings": repairings,
            "condition": cond, "held": compress_held(held),
            # unknowns ('part/frame/comp') this stage set free or held: the report's final list of
            # held frames is what no stage estimated (popped by calibrate, not reported per stage)
            "_estimated": estimated, "_held": set(held),
            "fabric_thickness_mm": 1000.0 * float(x[layout.fabric_col]), "seconds": time.perf_counter() - t0}

def _bounds(layout: ParameterLayout, targets: tuple, levels: set, x: np.ndarray, options: "CalibrationOptions"):
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
    return mask

def compress_held(names: list) -> list:
    """'part/frame/comp' entries -> 'part/frame' when all six components are held."""
    by_frame: dict = {}
    for n in names:
        frame, comp = n.rsplit("/", 1)
        by_frame.setdefault(frame, []).append(comp)
    order = ("tx", "ty", "tz", "rx", "ry", "rz")
    return [f if len(c) == 6 else f"{f} ({','.join(sorted(c, key=order.index))})" for f, c in by_frame.items()]
