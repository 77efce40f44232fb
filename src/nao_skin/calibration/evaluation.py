"""How good a calibration is: closest-pair distances, true taxel error, which touches a self-contact explains."""
from __future__ import annotations

from functools import partial

import numpy as np

from nao_skin.calibration.contact import predicted_firing
from nao_skin.calibration.context import FitContext, PlacedSkin
from nao_skin.calibration.fingertip import fingertip_firing
from nao_skin.calibration.layout import ParameterLayout
from nao_skin.calibration.pairing import COP_LIKE, METRIC_KINDS, METRIC_TAXEL_RULE, RowRules, chain_end_poses, metrics
from nao_skin.calibration.residuals import ResidualModel
from nao_skin.calibration.rows import concat_pairings, fingertip_rows, pair_parts, pair_step
from nao_skin.model.skin import SkinCalibration, SkinModel, part_rank
from nao_skin.touch.touches import TouchSet


# The figures a calibration reports, in order, as reports name them: a self-touch's closest pairs, a fingertip
# touch's distance from the fingertip to its contact, and how well the skin predicts which taxels fire. A figure
# no touch measures (no fingertip scene; no self-touch) is NaN, and left out where figures are listed.
FIGURES = {"cop_mean_mm": "closest COP (mm)", "taxel_mean_mm": "closest taxel (mm)",
           "contact_taxel_mean_mm": "selected contacts' closest taxel (mm)",
           "fingertip_mean_mm": "fingertip to its contact (mm)", "fired_f1": "fired taxels predicted, F1 (%)"}


def contact_figure(figures: dict) -> tuple:
    """``(label, mean mm)`` of how far apart a calibration leaves the touches' contacts: the closest COP pairs
    where self-touches measure them, else the fingertips' distance (NaN: neither)."""
    for name, label in (("cop_mean_mm", "closest COP"), ("fingertip_mean_mm", "fingertip to its contact")):
        if name in measured(figures, (name,)):
            return label, float(figures[name])
    return "closest COP", float("nan")


def measured(figures: dict, names=tuple(FIGURES)) -> list:
    """The ``names`` whose value in ``figures`` is a number (what the touches measured)."""
    return [n for n in names if isinstance(figures.get(n), (int, float)) and np.isfinite(figures[n])]


def evaluate(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, steps: list, fired: bool = False) -> dict:
    """Closest-COP / closest-taxel / 5-taxel distances (and the fitted pair of the selected contacts,
    ``contact_taxel``) over every touching pair of the plan (:func:`pairing.pair_for_metrics`); with
    ``fired``, :func:`firing_prediction`'s figures too (the final figures: every stage's would cost a fifth
    of a calibration)."""
    if touches.n_touches == 0:
        return {"n_touches": 0}
    pairs = plan_pairs(steps)
    placed = PlacedSkin(skin, calib)   # each part's slots placed once for all its part pairs
    rules = RowRules(taxel_rule=METRIC_TAXEL_RULE)
    pairings = [pair_parts(touches, skin, calib, p[0], p[1], METRIC_KINDS, rules, placed) for p in pairs
                if p[0] in touches.part_names and p[1] in touches.part_names]
    pairings += [fingertip_rows(touches, skin, calib, tip, part, placed) for tip, part in plan_fingertips(steps)]
    pairings = [p for p in pairings if len(p.row_touch)]
    if not pairings:
        return {"n_touches": 0}
    out = metrics(concat_pairings(pairings))
    if fired:
        out.update(firing_prediction(touches, skin, calib, pairs, plan_fingertips(steps)))
    return out


def firing_prediction(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, pairs: list,
                      fingertips: list = ()) -> dict:
    """How well the calibrated skins predict which taxels fire, a figure that owes nothing to closest pairs.

    In every touch where both parts of a pair fire, each part's fired taxels predict the other part's
    (:func:`~nao_skin.calibration.contact.predicted_firing`); pooled over both directions, every pair and
    every touch: ``fired_precision`` (the share of the predicted taxels that fired), ``fired_recall`` (the
    share of the fired taxels predicted) and their harmonic mean ``fired_f1``, in percent. At the true skin
    neither is 100 (a press fires the torso beyond the edge of a hand's skin, a curved hand touches where it
    does not fire); a better calibration predicts more of what fired and less of what did not. In the touches
    of each fingertip scene ``(fingertip, part)``, the fingertip's sphere predicts the part's
    (:func:`~nao_skin.calibration.fingertip.fingertip_firing`), pooled with the rest.
    """
    ctx = FitContext.of(touches, skin, calib)
    hits = predicted = fired = 0
    for a, b in pairs:
        if a not in touches.part_names or b not in touches.part_names:
            continue
        ia, ib = touches.part_names.index(a), touches.part_names.index(b)
        for own, other in ((ia, ib), (ib, ia)):
            pred, fire = predicted_firing(ctx, own, other)
            hits += int(np.isin(pred, fire, assume_unique=True).sum())
            predicted += len(pred)
            fired += len(fire)
    for tip, part in fingertips:
        pred, fire = fingertip_firing(touches, skin, calib, tip, part)
        hits += int(np.isin(pred, fire, assume_unique=True).sum())
        predicted += len(pred)
        fired += len(fire)
    precision = 100.0 * hits / predicted if predicted else float("nan")
    recall = 100.0 * hits / fired if fired else float("nan")
    if not (predicted and fired):
        f1 = float("nan")
    else:
        f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return {"fired_precision": precision, "fired_recall": recall, "fired_f1": f1}

def plan_fingertips(steps: list) -> list:
    """The fingertip scenes ``(fingertip, part)`` of the steps, each once."""
    return list(dict.fromkeys(fp for s in steps for fp in s.fingertips))


def plan_pairs(steps: list) -> list:
    """The part pairs that touch within the steps (each pair once, hands first): what :func:`evaluate` measures."""
    return sorted({tuple(sorted((a, b), key=part_rank))
                   for s in steps for a in s.targets + s.references for b in s.targets + s.references if a != b})


TRUTH_POSES = 200   # poses the true taxel error is measured at when the kinematics differ (evenly spaced)


def truth_error(skin: SkinModel, calib: SkinCalibration, truth: SkinCalibration, parts=None,
                poses: np.ndarray | None = None) -> dict:
    """Distance of every calibrated taxel from its true position, in mm.

    In the chain-end frame while both robots are the config's. When the calibration or the
    truth corrects the kinematics, a taxel's place depends on the pose: it is measured in the
    base frame at ``poses`` (the touches' joint angles, up to :data:`TRUTH_POSES` of them), the
    calibrated skin on the calibrated robot against the true skin on the true robot (a WristYaw
    offset and a hand mount turned about that axis are then the same, as they are to the touches).
    """
    out = {}
    errs_all = []
    posed = poses is not None and len(poses) > 0 and bool(calib.kinematics or truth.kinematics)
    if posed:
        q = np.asarray(poses)[np.unique(np.linspace(0, len(poses) - 1, min(TRUTH_POSES, len(poses))).astype(int))]
        est_skin, true_skin = skin.with_kinematics(calib), skin.with_kinematics(truth)
    for name in parts or skin.parts:
        if name not in truth.parts:
            continue
        p = skin.parts[name]
        if posed:
            est = est_skin.taxels_in_base(name, q, calib)[:, p.present]
            true = true_skin.taxels_in_base(name, q, truth)[:, p.present]
            e = np.linalg.norm(est - true, axis=2).ravel() * 1000.0
        else:
            est, _ = p.taxel_positions(calib.parts[name])
            true, _ = p.taxel_positions(truth.parts[name])
            e = np.linalg.norm(est[p.present] - true[p.present], axis=1) * 1000.0
        errs_all.append(e)
        out[name] = {"median": float(np.median(e)), "p95": float(np.percentile(e, 95)), "max": float(e.max())}
    if errs_all:
        e = np.concatenate(errs_all)
        out["all"] = {"median": float(np.median(e)), "p95": float(np.percentile(e, 95)), "max": float(e.max())}
    return out


def fingertip_truth_error(skin: SkinModel, calib: SkinCalibration, truth: SkinCalibration) -> dict:
    """``{fingertip: {"centre": mm, "radius": mm}}``: how far each fingertip sphere the calibration holds is from
    the true one (the centre's distance, the radius' difference)."""
    out = {}
    for name in calib.fingertips:
        centre, radius = calib.fingertip_sphere(skin.robot, name)
        true_centre, true_radius = truth.fingertip_sphere(skin.robot, name)
        out[name] = {"centre": 1000.0 * float(np.linalg.norm(centre - true_centre)),
                     "radius": 1000.0 * abs(radius - true_radius)}
    return out


def closest_cop_cost(touches, skin, calib, step, inliers) -> float:
    """Mean closest-COP distance (m) of the inlier touches, each capped at 50 mm (a far-off
    minority must not decide)."""
    pairing = pair_step(touches, skin, calib, step, ("cop",))
    if pairing is None or len(pairing.row_touch) == 0:
        return np.inf
    rows = np.isin(pairing.row_kind, COP_LIKE) & inliers[pairing.row_touch]
    return float(np.mean(np.minimum(pairing.distance[rows], 0.05))) if np.any(rows) else np.inf


def fitted_pair_cost(touches, skin, calib, step, inliers, kinds, fabric: float, pairing=None,
                     rules: RowRules = RowRules()) -> float:
    """What a stage fits, measured as it fits it: the touches paired under ``calib`` for ``kinds``,
    distances between the paired points lifted to the fabric surfaces (``fabric`` m over the
    taxels), each kind's capped mean (50 mm), averaged over the kinds.

    Taxel-centre distances alone grow when the fabric estimate grows, however good the fit.
    ``pairing``: that pairing, when a stage already made it (:attr:`StageResult.pairings`); ``rules``: how the
    stage made its rows (with the rows' expectations it fitted them with,
    :func:`~nao_skin.calibration.press.press_offsets`).
    """
    fitted = _fitted_distances(touches, skin, calib, step, kinds, fabric, pairing, rules)
    if fitted is None:
        return np.inf
    dist, pairing = fitted
    means = [float(np.mean(dist[rows]))
             for rows in ((pairing.row_kind == k) & inliers[pairing.row_touch] for k in np.unique(pairing.row_kind))
             if np.any(rows)]
    return float(np.mean(means)) if means else np.inf


def fitted_touch_distances(touches, skin, calib, step, kinds, fabric: float, pairing=None) -> np.ndarray:
    """Per touch, the mean of its capped distances (m) as :func:`fitted_pair_cost` measures them; NaN
    where a touch has no pair (``pairing``: the touches' pairing under ``calib``, when at hand)."""
    fitted = _fitted_distances(touches, skin, calib, step, kinds, fabric, pairing)
    if fitted is None:
        return np.full(touches.n_touches, np.nan)
    dist, pairing = fitted
    rows = np.bincount(pairing.row_touch, minlength=touches.n_touches)
    total = np.bincount(pairing.row_touch, dist, minlength=touches.n_touches)
    return np.divide(total, rows, out=np.full(touches.n_touches, np.nan), where=rows > 0)


def _fitted_distances(touches, skin, calib, step, kinds, fabric, pairing=None, rules: RowRules = RowRules()):
    """``(distance per row capped at 50 mm, pairing)``, or None when nothing pairs."""
    if pairing is None:
        pairing = pair_step(touches, skin, calib, step, kinds, rules)
    if pairing is None or len(pairing.row_touch) == 0:
        return None
    parts = tuple(p for p in step.targets + step.references if p in touches.part_names)
    skin = skin.with_kinematics(calib)
    model = ResidualModel(skin, partial(chain_end_poses, touches, skin), pairing, touches.part_names,
                          ParameterLayout(skin, parts), calib, fabric=fabric, fingertip_names=touches.fingertips)
    return np.minimum(np.linalg.norm(model.residuals(calib), axis=1), 0.05), pairing


def paired_gain(before: np.ndarray, after: np.ndarray, z: float) -> dict:
    """How much closer ``after`` brings the same items than ``before`` (per-item figures, NaN: not
    measured; items measured both times count): the means, the share gained, ``1 - mean(after) /
    mean(before)``, and that share less ``z`` standard errors of the paired differences, a one-sided
    lower confidence bound (``z`` 1.645: 95 %)."""
    both = np.isfinite(before) & np.isfinite(after)
    b, a = before[both], after[both]
    n = len(b)
    if n < 2 or not b.mean() > 0:
        return {"before": float(np.mean(b)) if n else np.nan, "after": float(np.mean(a)) if n else np.nan,
                "gain": np.nan, "gain_low": np.nan, "touches": n}
    d = b - a
    gain = d.mean() / b.mean()
    return {"before": float(b.mean()), "after": float(a.mean()), "gain": float(gain),
            "gain_low": float(gain - z * d.std(ddof=1) / np.sqrt(n) / b.mean()), "touches": n}


def explained(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, steps: list, gate_mm: float) -> np.ndarray:
    """Touches whose closest COP pair (over the plan's part pairs) is within ``gate_mm``."""
    ok = np.ones(touches.n_touches, bool)
    if gate_mm <= 0 or touches.n_touches == 0:
        return ok
    best = np.full(touches.n_touches, np.inf)
    for step in steps:
        p = pair_step(touches, skin, calib, step, ("cop",))
        if p is not None and len(p.row_touch):
            np.minimum.at(best, p.row_touch, p.distance * 1000.0)
    return ok & ((best <= gate_mm) | ~np.isfinite(best))

def gate_touches(touches, skin, calib, step, gate_mm, inliers, pairing=None) -> list:
    """``(touch, mm)`` of the inlier touches whose closest COP pair (any part pair of the step) is
    farther than ``gate_mm``, the farthest pair's distance each, by touch (``pairing``: the touches'
    COP pairs under ``calib``, when at hand)."""
    if pairing is None:
        pairing = pair_step(touches, skin, calib, step, ("cop",))
    rows = np.isin(pairing.row_kind, COP_LIKE)
    worst = np.full(touches.n_touches, -np.inf)
    np.maximum.at(worst, pairing.row_touch[rows], pairing.distance[rows] * 1000.0)
    far = np.flatnonzero(inliers & (worst > gate_mm))
    return [(int(t), float(worst[t])) for t in far]
