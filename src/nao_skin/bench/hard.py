"""The simulator's hard cases (:func:`hard_case_matrix`), pure (no ROS).

Each simulator preset, several seeds, simulated in memory, deduplicated and calibrated with the truth at
hand; per run: converged or not, final true errors, iterations, re-pairings, condition number of the
last stage, held unknowns, touches set aside against the injected outliers, the held frames that their
own correction made worse than nominal (the target), and the held frames' absolute error against the
nominal skin's (information). A failing case is a FAILED row with its one-line reason; the matrix goes
on. Tables: :func:`hard_case_tables`.
"""
from __future__ import annotations

import math
import time
import traceback
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from nao_skin.bench.rows import finite_calibration, fmt, nanmean, stage_totals
from nao_skin.calibration.engine import CalibrationOptions, calibrate, truth_error
from nao_skin.calibration.layout import COMPONENTS
from nao_skin.calibration.pairing import robot_joints
from nao_skin.calibration.stages import held_frames
from nao_skin.errors import one_line
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.touches import TouchSet

CONVERGED_MM = 1.0                  # final true median taxel error that counts as converged
HARD_PRESETS = ("default", "cad-rotation", "perturb-5cm", "few-touches", "outliers-20", "planar-poses", "noisy",
                "real-glue")
NOISY_RATIO_LIMIT = 2.0             # noisy's true median may be this many times the default's ("about 2x")
OUTLIER_RECALL_TARGET = 0.9
# the simulator label of the touches a preset injects as outliers: a touch whose
# activations no self-contact explains. The experimenter's hand and a stray taxel
# leave the true self-contact in the touch; those are handled by the robust loss
INJECTED_OUTLIER_LABEL = "non_self_contact"


@dataclass
class HardCaseSetup:
    """The simulated scene of the hard cases; a preset's own fields (e.g. few-touches' count) win."""

    pairs: list | None = None          # None: the simulator's pairs (all four thesis pairs)
    n_touches: int | None = None       # None: the preset's count (simulation.yaml)
    options: CalibrationOptions = field(default_factory=CalibrationOptions)


def _frame_row(part, frame: str) -> tuple:
    """``(kind, row)`` of a frame named like the calibration report ('mount', 'patch_3', 'triangle_12'):
    ``row`` indexes the part's patch or triangle arrays (None for the mount)."""
    if frame == "mount":
        return "mount", None
    kind, _, number = frame.partition("_")
    ids = {"patch": part.patch_ids, "triangle": part.triangle_ids}.get(kind)
    rows = np.flatnonzero(ids == int(number)) if ids is not None and number.isdigit() else []
    if len(rows) != 1:
        raise ValueError(f"unknown frame '{frame}'")
    return kind, int(rows[0])


def _frame_slots(part, frame: str) -> np.ndarray:
    """Slots of the taxels a frame carries."""
    kind, row = _frame_row(part, frame)
    present = part.slots
    if kind == "mount":
        return present
    tri_rows = part.slot_triangle[present]
    return present[(tri_rows if kind == "triangle" else part.triangle_patch[tri_rows]) == row]


def held_components(held: list) -> list:
    """``(part, frame, component columns)`` of the report's held entries (all six when none are named)."""
    return [(part, frame, [COMPONENTS.index(c) for c in comps]) for (part, frame), comps in held_frames(held).items()]


def untouched_triangles(touches: TouchSet, skin: SkinModel, parts) -> list:
    """'part/triangle_N' of every triangle no activation of ``touches`` falls on: the data cannot place it."""
    out = []
    for name in parts:
        if name not in touches.part_names:
            continue
        part = skin.parts[name]
        slots = touches.act_slot[touches.act_part == touches.part_index(name)]
        touched = np.unique(part.slot_triangle[slots])
        out += [f"{name}/triangle_{int(t)}" for i, t in enumerate(part.triangle_ids) if i not in touched]
    return out


def _frame_correction(corr, part, frame: str) -> np.ndarray:
    """View of one frame's 6-vector correction in a part's corrections."""
    kind, row = _frame_row(part, frame)
    if kind == "mount":
        return corr.mount
    return (corr.patches if kind == "patch" else corr.triangles)[row]


def held_frame_check(skin: SkinModel, calib: SkinCalibration, truth: SkinCalibration, held: list) -> list:
    """Held frames whose own correction takes their taxels farther from the truth than nominal.

    A frame's own error: its taxels with every other frame of the part at the
    truth and this frame's correction as calibrated, against the same with
    the held components of its correction at nominal (zero). What a held
    frame's taxels do through its parents (mount, patch), which the data did
    determine, is the parents' error, not this frame's (see
    :func:`held_frame_drift`). A frame listed as held that the calibration
    moved anyway in a held direction shows up here.
    """
    violations = []
    for part_name, frame, comps in held_components(held):
        part = skin.parts[part_name]
        true_pos, _ = part.taxel_positions(truth.parts[part_name])
        own, nominal = truth.parts[part_name].copy(), truth.parts[part_name].copy()
        estimated = _frame_correction(calib.parts[part_name], part, frame)
        _frame_correction(own, part, frame)[:] = estimated
        baseline = estimated.copy()
        baseline[comps] = 0.0
        _frame_correction(nominal, part, frame)[:] = baseline
        slots = _frame_slots(part, frame)
        own_mm, nominal_mm = (1000.0 * float(np.linalg.norm(part.taxel_positions(c)[0][slots] - true_pos[slots],
                                                             axis=1).mean()) for c in (own, nominal))
        if own_mm > nominal_mm + 1e-6:
            violations.append({"frame": f"{part_name}/{frame}", "final_mm": own_mm, "nominal_mm": nominal_mm})
    return violations


def held_frame_drift(skin: SkinModel, calib: SkinCalibration, truth: SkinCalibration, held: list) -> dict:
    """Absolute true error (mm) of the held frames' taxels, calibrated against nominal skin.

    Information, not a target: a held triangle rides on its patch and mount,
    which the data determined; where their true shifts happen to cancel, the
    nominal skin is already close and any estimate from few touches is
    farther (cad-rotation: nominal is exact but for the hand mounts).
    """
    nominal = skin.zero_calibration()
    errors = {}   # part -> per-slot true error (m) calibrated, nominal
    final, nom, worse = [], [], 0
    for part_name, frame in held_frames(held):
        part = skin.parts[part_name]
        if part_name not in errors:
            true_pos, _ = part.taxel_positions(truth.parts[part_name])
            errors[part_name] = [np.linalg.norm(part.taxel_positions(c.parts[part_name])[0] - true_pos, axis=1)
                                 for c in (calib, nominal)]
        slots = _frame_slots(part, frame)
        e_final, e_nom = (1000.0 * float(e[slots].mean()) for e in errors[part_name])
        final.append(e_final)
        nom.append(e_nom)
        worse += e_final > e_nom + 1e-6
    return {"frames": len(final), "worse": int(worse),
            "final_mean_mm": float(np.mean(final)) if final else float("nan"),
            "nominal_mean_mm": float(np.mean(nom)) if nom else float("nan")}


def simulate_case(skin: SkinModel, preset: str, seed: int, setup: HardCaseSetup) -> tuple:
    """One preset and seed simulated in memory with the setup's pairs and touches (few-touches keeps its
    own count), deduplicated: ``(SimResult, touches, duplicates removed)``."""
    from nao_skin.sim.params import load_params
    from nao_skin.sim.simulate import simulate
    from nao_skin.touch.datasets import deduplicate

    overrides = {}
    if setup.pairs is not None:
        overrides["pairs"] = [list(p) for p in setup.pairs]
    if setup.n_touches is not None and preset != "few-touches":
        overrides["n_touches"] = int(setup.n_touches)
    sim = simulate(skin, load_params(preset, overrides), seed)
    touches, n_dup = deduplicate(sim.touches)
    return sim, touches, n_dup


def run_hard_case(skin: SkinModel, preset: str, seed: int, setup: HardCaseSetup | None = None) -> dict:
    """Simulate one preset and seed in memory, calibrate it, check it. Never raises: a failure is a row."""
    setup = setup or HardCaseSetup()
    row = {"preset": preset, "seed": int(seed), "status": "ok", "converged": False}
    t0 = time.perf_counter()
    try:
        sim, touches, n_dup = simulate_case(skin, preset, seed, setup)
        row["touches"] = touches.n_touches
        result = calibrate(touches, skin, replace(setup.options), truth=sim.truth)
        rep = result.report
        if not finite_calibration(result.calibration):
            raise FloatingPointError("non-finite correction in the calibration")
        err = truth_error(skin, result.calibration, sim.truth, rep.parts, robot_joints(result.train, skin))
        row.update(parts=list(rep.parts), true_median_mm=err["all"]["median"], true_p95_mm=err["all"]["p95"],
                   true_max_mm=err["all"]["max"],
                   part_median_mm={p: err[p]["median"] for p in rep.parts})
        row.update(stage_totals(rep))
        row["held"] = list(rep.held)
        row["held_frames"] = len(held_frames(rep.held))
        row["held_violations"] = held_frame_check(skin, result.calibration, sim.truth, rep.held)
        row["held_drift"] = held_frame_drift(skin, result.calibration, sim.truth, rep.held)
        row["held_corrections"] = {f"{p}/{f}": _frame_correction(result.calibration.parts[p], skin.parts[p], f).tolist()
                                   for p, f in held_frames(rep.held)}
        fully_held = {h for h in rep.held if " " not in h}
        row["untouched_not_held"] = [f for f in untouched_triangles(result.train, skin, rep.parts)
                                     if f not in fully_held]
        row.update(_outlier_recall(result))
        row["converged"] = bool(row["true_median_mm"] <= CONVERGED_MM)
        nans = [k for k in ("true_median_mm", "true_p95_mm", "true_max_mm") if math.isnan(row[k])]
        if nans:
            row["status"] = f"FAILED: NaN in {', '.join(nans)}"
    except Exception as exc:  # noqa: BLE001 - a failing case is a row of the table
        row["status"] = "FAILED: " + one_line(exc, 200)
        row["trace"] = traceback.format_exc(limit=3)
    row["seconds"] = time.perf_counter() - t0
    return row


def _outlier_recall(result) -> dict:
    """Touches set aside (keys) against the injected outliers of the training split."""
    train = result.train
    aside = {s["touch"] for s in result.set_aside}
    keys = np.array([str(k) for k in train.keys])
    is_aside = np.isin(keys, list(aside)) if aside else np.zeros(len(keys), bool)
    out = {"set_aside": sorted(aside), "n_set_aside": len(aside)}
    labels = train.labels
    if INJECTED_OUTLIER_LABEL in labels:
        injected = np.asarray(labels[INJECTED_OUTLIER_LABEL], bool)
        any_outlier = np.asarray(labels.get("outlier", injected), bool)
        out.update(injected=int(injected.sum()), injected_set_aside=int((injected & is_aside).sum()),
                   recall=float((injected & is_aside).sum() / injected.sum()) if injected.any() else float("nan"),
                   set_aside_not_outlier=int((is_aside & ~any_outlier).sum()),
                   any_outlier=int(any_outlier.sum()), any_outlier_set_aside=int((any_outlier & is_aside).sum()))
    return out


def hard_case_matrix(skin: SkinModel, presets=HARD_PRESETS, seeds=range(20), setup: HardCaseSetup | None = None,
                     jobs: int = 1, say: Callable[[str], None] = print) -> list:
    """Every preset x seed (in ``jobs`` worker processes); rows in preset, seed order."""
    cases = [(p, int(s)) for p in presets for s in seeds]
    rows = []
    if jobs > 1:
        from nao_skin.bench.pool import worker_pool

        with worker_pool(jobs, len(cases)) as pool:
            futures = [pool.submit(run_hard_case, skin, p, s, setup) for p, s in cases]
            for fut in futures:
                rows.append(fut.result())
                say(f"[hard {len(rows)}/{len(cases)}] {_hard_summary(rows[-1])}")
    else:
        for p, s in cases:
            rows.append(run_hard_case(skin, p, s, setup))
            say(f"[hard {len(rows)}/{len(cases)}] {_hard_summary(rows[-1])}")
    return rows


def _hard_summary(row: dict) -> str:
    head = f"{row['preset']} seed {row['seed']}: "
    if row["status"] != "ok":
        return head + row["status"]
    text = (head + f"{'converged' if row['converged'] else 'NOT converged'}, true median {row['true_median_mm']:.3f} mm,"
            f" p95 {row['true_p95_mm']:.3f} mm, {row['iterations']} iterations, {row['repairings']} pairings,"
            f" {row['held_frames']} frames held, {row['n_set_aside']} set aside")
    if row.get("injected"):
        text += f" ({row['injected_set_aside']}/{row['injected']} injected outliers)"
    if row.get("held_violations"):
        text += f", {len(row['held_violations'])} held frames made worse than nominal by their own correction"
    return text + f" ({row['seconds']:.1f} s)"


def hard_case_summary(rows: list) -> list:
    """Per preset: counts, error spread and whether its target is met (with the reason when not)."""
    by: dict = {}
    for r in rows:
        by.setdefault(r["preset"], []).append(r)
    default_ok = [r["true_median_mm"] for r in by.get("default", []) if r["status"] == "ok"]
    default_median = float(np.median(default_ok)) if default_ok else float("nan")
    out = []
    for preset, rs in by.items():
        ok = [r for r in rs if r["status"] == "ok"]
        med = [r["true_median_mm"] for r in ok]
        s = {"preset": preset, "runs": len(rs), "failed": len(rs) - len(ok),
             "converged": sum(r["converged"] for r in ok),
             "median_mm": float(np.median(med)) if med else float("nan"),
             "worst_median_mm": float(np.max(med)) if med else float("nan"),
             "worst_p95_mm": float(np.max([r["true_p95_mm"] for r in ok])) if ok else float("nan"),
             "iterations": float(np.median([r["iterations"] for r in ok])) if ok else float("nan"),
             "repairings": float(np.median([r["repairings"] for r in ok])) if ok else float("nan"),
             "condition": float(np.max([r["condition"] for r in ok])) if ok else float("nan"),
             "held_frames": float(np.median([r["held_frames"] for r in ok])) if ok else float("nan"),
             "violations": int(sum(len(r["held_violations"]) for r in ok)),
             "drift_worse": int(sum(r["held_drift"]["worse"] for r in ok)),
             "drift_final_mm": nanmean([r["held_drift"]["final_mean_mm"] for r in ok]),
             "drift_nominal_mm": nanmean([r["held_drift"]["nominal_mean_mm"] for r in ok]),
             "untouched_free": int(sum(len(r["untouched_not_held"]) for r in ok)),
             "min_recall": float(np.min([r["recall"] for r in ok if not math.isnan(r.get("recall", math.nan))]))
             if any(not math.isnan(r.get("recall", math.nan)) for r in ok) else float("nan")}
        s["target"], s["met"] = _target(preset, s, ok, default_median)
        out.append(s)
    return out


def _target(preset: str, s: dict, ok: list, default_median: float) -> tuple:
    """(what the preset must achieve, "yes" or why not)."""
    problems = [f"{s['failed']} failed"] if s["failed"] else []
    n = s["runs"]
    if preset in ("default", "cad-rotation", "perturb-5cm"):
        target = f"{n}/{n} converge (true median <= {CONVERGED_MM:g} mm)"
        if s["converged"] < n:
            problems.append(f"{s['converged']}/{n} converged")
    elif preset == "outliers-20":
        target = f"{n}/{n} converge, >= {OUTLIER_RECALL_TARGET:.0%} of injected outliers set aside"
        if s["converged"] < n:
            problems.append(f"{s['converged']}/{n} converged")
        low = [r for r in ok if r.get("recall", 1.0) < OUTLIER_RECALL_TARGET]
        if low:
            problems.append(f"recall below target in {len(low)} runs (min {s['min_recall']:.2f})")
    elif preset in ("few-touches", "planar-poses"):
        target = "held frames listed, none made worse than nominal by its own correction"
        if s["untouched_free"]:
            problems.append(f"{s['untouched_free']} untouched triangles not held")
        if s["violations"]:
            problems.append(f"{s['violations']} held frames made worse than nominal by their own correction")
        if ok and all(r["held_frames"] == 0 for r in ok):
            problems.append("no frame held")
    elif preset == "noisy":
        target = f"true median <= {NOISY_RATIO_LIMIT:g} x default's ({default_median:.2f} mm)"
        if not math.isnan(default_median) and not math.isnan(s["median_mm"]):
            ratio = s["median_mm"] / default_median
            s["ratio_to_default"] = ratio
            if ratio > NOISY_RATIO_LIMIT:
                problems.append(f"x{ratio:.2f} of default")
        else:
            problems.append("no default run to compare with")
    else:
        target = "no failure"
    return target, ("yes" if not problems else "NO: " + "; ".join(problems))


# ------------------------------------------------------------------------------ tables
def hard_case_tables(rows: list) -> str:
    """Summary per preset, then one line per run."""
    summary = hard_case_summary(rows)
    head = ["preset", "runs", "converged", "failed", "true median mm (median / worst)", "worst p95 mm",
            "iterations", "re-pairings", "max condition", "held frames", "held: own correction worse than nominal",
            "held taxels, absolute: mean mm ours / nominal (frames worse)",
            "untouched not held", "min outlier recall", "target", "met"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for s in summary:
        lines.append("| " + " | ".join([
            s["preset"], str(s["runs"]), f"{s['converged']}/{s['runs']}", str(s["failed"]),
            f"{fmt(s['median_mm'], 3)} / {fmt(s['worst_median_mm'], 3)}", fmt(s["worst_p95_mm"], 3),
            fmt(s["iterations"], 0), fmt(s["repairings"], 0), fmt(s["condition"], 0), fmt(s["held_frames"], 0),
            str(s["violations"]), f"{fmt(s['drift_final_mm'])} / {fmt(s['drift_nominal_mm'])} ({s['drift_worse']})",
            str(s["untouched_free"]), fmt(s["min_recall"]), s["target"], s["met"]]) + " |")
    head2 = ["preset", "seed", "converged", "true median mm", "p95 mm", "iterations", "re-pairings", "condition",
             "held", "set aside (injected outliers among them)", "held: own correction worse than nominal",
             "held, absolute: frames worse than nominal", "status"]
    lines += ["", "| " + " | ".join(head2) + " |", "|" + "---|" * len(head2)]
    for r in rows:
        if r["status"] != "ok":
            lines.append("| " + " | ".join([r["preset"], str(r["seed"])] + ["-"] * (len(head2) - 3) + [r["status"]]) + " |")
            continue
        aside = str(r["n_set_aside"]) + (f" ({r['injected_set_aside']}/{r['injected']})" if r.get("injected") else "")
        held = ", ".join(r["held"]) if len(r["held"]) <= 8 else ", ".join(r["held"][:8]) + f", ... ({len(r['held'])} in all)"
        worse = ", ".join(f"{v['frame']} {v['final_mm']:.2f}>{v['nominal_mm']:.2f}" for v in r["held_violations"]) or "none"
        lines.append("| " + " | ".join([r["preset"], str(r["seed"]), "yes" if r["converged"] else "NO",
                                        fmt(r["true_median_mm"], 3), fmt(r["true_p95_mm"], 3), str(r["iterations"]),
                                        str(r["repairings"]), fmt(r["condition"], 0), held or "none", aside, worse,
                                        f"{r['held_drift']['worse']}/{r['held_drift']['frames']}",
                                        r["status"]]) + " |")
    return "\n".join(lines)


def outlier_listing(rows: list, preset: str = "outliers-20") -> str:
    """The touches each run of ``preset`` set aside, by key (the stamps of the simulated recording)."""
    out = []
    for r in rows:
        if r["preset"] == preset and r["status"] == "ok":
            out.append(f"- seed {r['seed']}: {r['n_set_aside']} set aside"
                       + (f", {r['injected_set_aside']} of {r['injected']} injected outliers" if r.get("injected") else "")
                       + ": " + (", ".join(r["set_aside"]) or "none"))
    return "\n".join(out)
