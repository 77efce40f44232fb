"""Benchmark core: speed against error over calibration strategies, and the simulator's hard cases.

Two matrices, both pure (no ROS), both robust to a failing case:

* **Speed against error** (:func:`speed_matrix`): one row per strategy
  variant (the default, then one :class:`~nao_skin.calibrate.CalibrationOptions`
  knob changed per row, then a sweep over the number of training touches),
  run on the same inputs. Repetitions are interleaved (every variant once,
  then again) so that a slow spell of a shared machine hits all rows alike;
  the median is quoted. Errors: true taxel error against ground truth
  (simulated input) or closest-COP / closest-taxel means on train and test
  (real input).
* **Hard cases** (:func:`hard_case_matrix`): each simulator preset, several
  seeds, simulated in memory, deduplicated and calibrated with the truth at
  hand; per run: converged or not, final true errors, iterations,
  re-pairings, condition number of the last stage, held unknowns, touches set
  aside against the injected outliers, the held frames that their own
  correction made worse than nominal (the target), and the held frames'
  absolute error against the nominal skin's (information).

* **Kinematics** (:func:`kinematics_matrix`): presets x seeds, each simulated once and calibrated with
  ``kinematics`` off, on and auto: true taxel error per part and seconds side by side, the recovered
  joint offsets against the simulator's truth.

Any exception or NaN makes a row FAILED with its one-line reason; the matrix
goes on. Tables are markdown (:func:`speed_table`, :func:`hard_case_tables`),
the plot is :func:`plot_speed_vs_error`.
"""
from __future__ import annotations

import math
import time
import traceback
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from nao_skin.bench import TARGET_MM
from nao_skin.calibration.engine import CalibrationOptions, CalibrationReport, calibrate, truth_error
from nao_skin.calibration.layout import COMPONENTS
from nao_skin.calibration.pairing import robot_joints
from nao_skin.errors import one_line
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.touches import TouchSet

CONVERGED_MM = 1.0                  # final true median taxel error that counts as converged
HARD_PRESETS = ("default", "cad-rotation", "perturb-5cm", "few-touches", "outliers-20", "planar-poses", "noisy",
                "real-glue")
TOUCH_SWEEP = (50, 100, 200, 500)   # plus "all" = the default row
NOISY_RATIO_LIMIT = 2.0             # noisy's true median may be this many times the default's ("about 2x")
OUTLIER_RECALL_TARGET = 0.9
# the simulator label of the touches a preset injects as outliers: a touch whose
# activations no self-contact explains. The experimenter's hand and a stray taxel
# leave the true self-contact in the touch; those are handled by the robust loss
INJECTED_OUTLIER_LABEL = "non_self_contact"


# ------------------------------------------------------------------------------ inputs and variants
@dataclass
class BenchInput:
    """One recording the speed matrix runs on: its touches (deduplicated) and the skin they belong to."""

    name: str
    touches: TouchSet
    skin: SkinModel
    truth: SkinCalibration | None = None    # simulated inputs: errors against ground truth
    note: str = ""


@dataclass
class Variant:
    """A calibration strategy: the default options with ``knobs`` changed."""

    name: str
    knobs: dict = field(default_factory=dict)
    single_run: bool = False                # too slow to repeat: run once, the table says so

    def options(self, base: CalibrationOptions | None = None) -> CalibrationOptions:
        return replace(base or CalibrationOptions(), **self.knobs)


def strategy_variants(sweep=TOUCH_SWEEP) -> list:
    """The default, one knob changed per row, then the touch-count sweep."""
    d = CalibrationOptions()
    rows = [
        Variant(f"default ({d.strategy}, {d.reference} reference, {d.pairs} pairs, closing {d.closing_pairs}, "
                f"{'bounded' if d.bounded else 'free'}, {d.loss}, {d.jacobian} J)"),
        Variant("all at once (mount+patch+triangle together)", {"strategy": "all-at-once"}),
        Variant("simultaneous (no reference part)", {"reference": "simultaneous"}),
        Variant("COP pairs only (the closing stage too)", {"closing_pairs": "cop"}),
        Variant("COP and closest taxel pairs in every stage (pairs=both)", {"pairs": "both"}),
        Variant("taxel pairs only", {"pairs": "taxel", "closing_pairs": "taxel"}),
        Variant("point-to-plane rows instead of closest taxel pairs (cop+plane)",
                {"pairs": "cop+plane", "closing_pairs": "cop+plane"}),
        Variant("point-to-plane rows beside closest taxel pairs (both+plane)",
                {"pairs": "both+plane", "closing_pairs": "both+plane"}),
        Variant("bounded (the thesis' box on patch and triangle corrections)", {"bounded": True}),
        Variant("wider prior (starts at the bound: prior_strength=1)", {"prior_strength": 1.0}),
        Variant("fixed prior (bound/3, not widened by the touches)", {"prior_scale": "fixed"}),
        Variant("robust loss off (linear)", {"loss": "linear"}),
        Variant("no triangle level (levels=[mount, patch])", {"levels": ("mount", "patch")}),
        Variant("finite-difference Jacobian (2-point)", {"jacobian": "2-point"}, single_run=True),
    ]
    rows += [Variant(f"{n} training touches", {"max_touches": int(n)}) for n in sweep]
    return rows


def restrict_pairs(touches: TouchSet, pairs) -> TouchSet:
    """Touches in which at least one of the given part pairs fires together (e.g. ``[("l_hand", "torso")]``)."""
    fired = touches.parts_of_touch()
    keep = np.zeros(touches.n_touches, bool)
    for a, b in pairs:
        if a in touches.part_names and b in touches.part_names:
            keep |= fired[:, touches.part_index(a)] & fired[:, touches.part_index(b)]
    return touches.subset(keep)


# ------------------------------------------------------------------------------ one calibration, checked
def _finite_calibration(calib: SkinCalibration) -> bool:
    return all(np.all(np.isfinite(c.mount)) and np.all(np.isfinite(c.patches)) and np.all(np.isfinite(c.triangles))
               for c in calib.parts.values())


def _stage_totals(report: CalibrationReport) -> dict:
    stages = report.stages
    last = stages[-1] if stages else {}
    cond = last.get("condition")
    return {"iterations": int(sum(s.get("iterations", 0) for s in stages)),
            "repairings": int(sum(s.get("repairings", 0) for s in stages)),
            "condition": float(cond) if cond is not None else float("nan")}


def _errors(result, inp: BenchInput) -> dict:
    """The row's error columns; sim: true taxel error over the calibrated parts, real: pairing means."""
    rep = result.report
    out = {}
    if inp.truth is not None:
        poses = robot_joints(result.train, inp.skin)   # where kinematic corrections put the taxels
        err = truth_error(inp.skin, result.calibration, inp.truth, rep.parts, poses)
        before = truth_error(inp.skin, inp.skin.zero_calibration(), inp.truth, rep.parts, poses)
        out.update(true_median_mm=err["all"]["median"], true_p95_mm=err["all"]["p95"],
                   true_max_mm=err["all"]["max"], before_true_median_mm=before["all"]["median"],
                   part_true_mm={p: {"median": err[p]["median"], "p95": err[p]["p95"]} for p in rep.parts})
    final = rep.final
    for split in ("train", "test"):
        out[f"{split}_cop_mm"] = final[split].get("cop_mean_mm", float("nan"))
        out[f"{split}_taxel_mm"] = final[split].get("taxel_mean_mm", float("nan"))
        out[f"{split}_contact_taxel_mm"] = final[split].get("contact_taxel_mean_mm", float("nan"))
        acc = final.get(f"{split}_accepted", {})
        out[f"{split}_cop_explained_mm"] = acc.get("cop_mean_mm", float("nan"))
        out[f"{split}_taxel_explained_mm"] = acc.get("taxel_mean_mm", float("nan"))
    out["before_train_cop_mm"] = rep.before["train"].get("cop_mean_mm", float("nan"))
    return out


def _divergence(errors: dict) -> str:
    """Empty, or why a finished run is a failure anyway (NaN, or worse than where it started)."""
    bad = [k for k, v in errors.items() if isinstance(v, float) and math.isnan(v)
           and not k.endswith("explained_mm")]
    if bad:
        return f"NaN in {', '.join(bad)}"
    if "true_median_mm" in errors and errors["true_median_mm"] > errors["before_true_median_mm"]:
        return (f"diverged: true median {errors['true_median_mm']:.2f} mm > "
                f"{errors['before_true_median_mm']:.2f} mm before calibration")
    if errors["train_cop_mm"] > errors["before_train_cop_mm"]:
        return (f"diverged: train closest COP {errors['train_cop_mm']:.2f} mm > "
                f"{errors['before_train_cop_mm']:.2f} mm before calibration")
    return ""


# ------------------------------------------------------------------------------ speed against error
def speed_matrix(inputs: list, variants: list, repeat: int = 3, say: Callable[[str], None] = print) -> list:
    """One row per (input, variant): median seconds over ``repeat`` interleaved runs, errors of the last run."""
    rows = {(inp.name, v.name): {"input": inp.name, "strategy": v.name, "seconds_all": [], "status": "ok",
                                 "single_run": v.single_run, "knobs": dict(v.knobs)}
            for inp in inputs for v in variants}
    for rep in range(max(1, repeat)):
        for inp in inputs:
            for v in variants:
                row = rows[(inp.name, v.name)]
                if row["status"] != "ok" or (v.single_run and rep > 0):
                    continue
                t0 = time.perf_counter()
                try:
                    result = calibrate(inp.touches, inp.skin, v.options(), truth=inp.truth)
                    seconds = time.perf_counter() - t0
                    if not _finite_calibration(result.calibration):
                        raise FloatingPointError("non-finite correction in the calibration")
                    errors = _errors(result, inp)
                    row.update(errors)
                    row.update(_stage_totals(result.report))
                    row["train_touches"] = result.train.n_touches
                    why = _divergence(errors)
                    if why:
                        row["status"] = "FAILED: " + why
                    row["seconds_all"].append(seconds)
                except Exception as exc:  # noqa: BLE001 - a failing strategy is a row of the table
                    row["status"] = "FAILED: " + one_line(exc, 200)
                    row["trace"] = traceback.format_exc(limit=3)
                say(f"[speed {rep + 1}/{repeat}] {inp.name} | {v.name}: {_speed_summary(row)}")
    out = []
    for row in rows.values():
        secs = row["seconds_all"]
        row["seconds"] = float(np.median(secs)) if secs else float("nan")
        row["runs"] = len(secs)
        out.append(row)
    return out


def _speed_summary(row: dict) -> str:
    if row["status"] != "ok":
        return row["status"]
    s = f"{row['seconds_all'][-1]:.2f} s"
    if "true_median_mm" in row:
        return s + f", true taxel error median {row['true_median_mm']:.3f} mm, p95 {row['true_p95_mm']:.3f} mm"
    return s + (f", closest COP {row['train_cop_mm']:.2f} / {row['test_cop_mm']:.2f} mm, taxel "
                f"{row['train_taxel_mm']:.2f} / {row['test_taxel_mm']:.2f} mm (train / test)")


def headline(rows: list, input_name: str) -> str:
    """The default calibration of one input beside the finite-difference run of the same problem."""
    by = {r["strategy"]: r for r in rows if r["input"] == input_name}
    default = next((r for n, r in by.items() if n.startswith("default")), None)
    fd = next((r for r in by.values() if r["knobs"].get("jacobian") == "2-point"), None)
    if default is None:
        return f"{input_name}: no default row"

    def part(label, r):
        if r is None:
            return f"{label}: not run"
        if r["status"] != "ok":
            return f"{label}: {r['status']}"
        err = (f"true taxel error median {r['true_median_mm']:.2f} mm, p95 {r['true_p95_mm']:.2f} mm"
               if "true_median_mm" in r else
               f"closest COP {r['train_cop_mm']:.2f} / {r['test_cop_mm']:.2f} mm, closest taxel "
               f"{r['train_taxel_mm']:.2f} / {r['test_taxel_mm']:.2f} mm (train / test)")
        return f"{label} {r['seconds']:.2f} s ({r['runs']} run{'s' if r['runs'] != 1 else ''}), {err}"

    text = f"{input_name}: " + part("analytic Jacobian", default) + "; " + part("finite differences", fd)
    if fd is not None and default["status"] == fd["status"] == "ok" and default["seconds"] > 0:
        text += f"; speed-up x{fd['seconds'] / default['seconds']:.1f}"
    return text


# the accuracy and speed the project promises (issue 5), checked on the default rows
REAL_TARGET_MM = {"cop": 5.5, "taxel": 2.2}       # mean closest COP / closest taxel, train and test
REAL_TARGET_SECONDS = 2.0                          # whole sequential calibration of the real recording
REAL_SPLITS = 5                                    # seeded splits the real figures are averaged over
# the accuracy issue's goals (thesis: 5.49 / 2.67 mm, train only): said beside the targets, not counted as a
# failure of the bench; the figures on the mean over the splits, the seconds of the default row
REAL_GOAL_MM = {"cop": 4.3, "taxel": 1.8}
REAL_GOAL_SECONDS = 1.0


def target_lines(rows: list) -> list:
    """One line per input: the default row against the promised accuracy (and speed, for real inputs)."""
    out = []
    for name in dict.fromkeys(r["input"] for r in rows):
        row = next((r for r in rows if r["input"] == name and not r["knobs"]), None)
        if row is None or row["status"] != "ok":
            out.append(f"{name}: default row {'missing' if row is None else row['status']}")
            continue
        misses = []
        if "part_true_mm" in row:
            for part, e in row["part_true_mm"].items():
                for stat, limit in TARGET_MM.items():
                    if e[stat] > limit:
                        misses.append(f"{part} {stat} {e[stat]:.2f} > {limit} mm")
            goal = (f"true taxel error median <= {TARGET_MM['median']} mm and p95 <= {TARGET_MM['p95']} mm"
                    f" for each of {', '.join(row['part_true_mm'])}")
        else:
            for kind, limit in REAL_TARGET_MM.items():
                for split in ("train", "test"):
                    v = row[f"{split}_{kind}_mm"]
                    if not v <= limit:
                        misses.append(f"{split} closest {kind.upper() if kind == 'cop' else kind} {v:.2f} > {limit} mm")
            if row["seconds"] > REAL_TARGET_SECONDS:
                misses.append(f"{row['seconds']:.2f} s > {REAL_TARGET_SECONDS:g} s")
            goal = (f"closest COP <= {REAL_TARGET_MM['cop']} mm, closest taxel <= {REAL_TARGET_MM['taxel']} mm"
                    f" (train and test, all touches), <= {REAL_TARGET_SECONDS:g} s")
        note = ""
        if "part_true_mm" not in row:
            # the pair the solver fits, said beside the target for whoever reads the target as that pair
            fitted = (row["train_contact_taxel_mm"], row["test_contact_taxel_mm"])
            note = (f" (the selected contacts' closest taxel pair: {fitted[0]:.2f} / {fitted[1]:.2f} mm,"
                    f" {'also' if max(fitted) <= REAL_TARGET_MM['taxel'] else 'not'} within"
                    f" {REAL_TARGET_MM['taxel']} mm)")
        out.append(f"{name}: {goal}: " + ("met" if not misses else "NOT met: " + "; ".join(misses)) + note)
    return out


def speed_goal_lines(rows: list) -> list:
    """One line per real input: its default row's seconds against the accuracy issue's goal (said, not
    counted as a failure of the bench)."""
    out = []
    for name in dict.fromkeys(r["input"] for r in rows):
        row = next((r for r in rows if r["input"] == name and not r["knobs"]), None)
        if row is None or row["status"] != "ok" or "part_true_mm" in row:
            continue
        seconds = row["seconds"]
        out.append(f"{name}: the default calibration <= {REAL_GOAL_SECONDS:g} s: "
                   + (f"met ({seconds:.2f} s)" if seconds <= REAL_GOAL_SECONDS
                      else f"NOT met: {seconds:.2f} s > {REAL_GOAL_SECONDS:g} s"))
    return out


# ------------------------------------------------------------------------------ hard cases
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


def held_frames(held: list) -> list:
    """``(part, frame)`` of the report's held entries ('l_hand/triangle_3' or 'torso/patch_1 (rx,ry)')."""
    return [(part, frame) for part, frame, _ in held_components(held)]


def held_components(held: list) -> list:
    """``(part, frame, component columns)`` of the report's held entries (all six when none are named)."""
    out: dict = {}
    for entry in held:
        name, _, comps = entry.partition(" ")
        part, _, frame = name.partition("/")
        cols = [COMPONENTS.index(c) for c in comps.strip("()").split(",")] if comps else list(range(6))
        out.setdefault((part, frame), set()).update(cols)
    return [(part, frame, sorted(cols)) for (part, frame), cols in out.items()]


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
        if not _finite_calibration(result.calibration):
            raise FloatingPointError("non-finite correction in the calibration")
        err = truth_error(skin, result.calibration, sim.truth, rep.parts, robot_joints(result.train, skin))
        row.update(parts=list(rep.parts), true_median_mm=err["all"]["median"], true_p95_mm=err["all"]["p95"],
                   true_max_mm=err["all"]["max"],
                   part_median_mm={p: err[p]["median"] for p in rep.parts})
        row.update(_stage_totals(rep))
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
             "drift_final_mm": _nanmean([r["held_drift"]["final_mean_mm"] for r in ok]),
             "drift_nominal_mm": _nanmean([r["held_drift"]["nominal_mean_mm"] for r in ok]),
             "untouched_free": int(sum(len(r["untouched_not_held"]) for r in ok)),
             "min_recall": float(np.min([r["recall"] for r in ok if not math.isnan(r.get("recall", math.nan))]))
             if any(not math.isnan(r.get("recall", math.nan)) for r in ok) else float("nan")}
        s["target"], s["met"] = _target(preset, s, ok, default_median)
        out.append(s)
    return out


def _nanmean(values: list) -> float:
    v = [x for x in values if not math.isnan(x)]
    return float(np.mean(v)) if v else float("nan")


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
def _f(v, digits=2) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float) and (abs(v) >= 1e4):
        return f"{v:.1e}"
    return f"{v:.{digits}f}" if isinstance(v, float) else str(v)


def speed_table(rows: list, input_name: str) -> str:
    """Markdown table of one input's rows (simulated: true error; real: pairing distances)."""
    rs = [r for r in rows if r["input"] == input_name]
    sim = any("true_median_mm" in r for r in rs)
    if sim:
        head = ["strategy", "seconds (median)", "runs", "true taxel error median mm", "p95 mm", "iterations",
                "re-pairings", "status"]
    else:
        head = ["strategy", "seconds (median)", "runs", "closest COP mm train / test",
                "closest taxel mm train / test", "selected contacts' closest taxel mm train / test",
                "explained: COP / taxel mm test", "iterations", "re-pairings", "status"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rs:
        runs = f"{r['runs']}" + (" (slow: once)" if r["single_run"] else "")
        status = "ok" if r["status"] == "ok" else r["status"]
        if r["status"] != "ok" and not r["seconds_all"]:
            cells = [r["strategy"], "-", "0"] + ["-"] * (len(head) - 4) + [status]
        elif sim:
            cells = [r["strategy"], _f(r["seconds"]), runs, _f(r.get("true_median_mm"), 3),
                     _f(r.get("true_p95_mm"), 3), _f(r.get("iterations")), _f(r.get("repairings")), status]
        else:
            cells = [r["strategy"], _f(r["seconds"]), runs,
                     f"{_f(r.get('train_cop_mm'))} / {_f(r.get('test_cop_mm'))}",
                     f"{_f(r.get('train_taxel_mm'))} / {_f(r.get('test_taxel_mm'))}",
                     f"{_f(r.get('train_contact_taxel_mm'))} / {_f(r.get('test_contact_taxel_mm'))}",
                     f"{_f(r.get('test_cop_explained_mm'))} / {_f(r.get('test_taxel_explained_mm'))}",
                     _f(r.get("iterations")), _f(r.get("repairings")), status]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


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
            f"{_f(s['median_mm'], 3)} / {_f(s['worst_median_mm'], 3)}", _f(s["worst_p95_mm"], 3),
            _f(s["iterations"], 0), _f(s["repairings"], 0), _f(s["condition"], 0), _f(s["held_frames"], 0),
            str(s["violations"]), f"{_f(s['drift_final_mm'])} / {_f(s['drift_nominal_mm'])} ({s['drift_worse']})",
            str(s["untouched_free"]), _f(s["min_recall"]), s["target"], s["met"]]) + " |")
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
                                        _f(r["true_median_mm"], 3), _f(r["true_p95_mm"], 3), str(r["iterations"]),
                                        str(r["repairings"]), _f(r["condition"], 0), held or "none", aside, worse,
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


# ------------------------------------------------------------------------------ plot
def plot_speed_vs_error(rows: list, path) -> None:
    """Seconds (log x) against error, one point per strategy, one panel per input."""
    from matplotlib.figure import Figure   # no pyplot: no backend or global figure state

    inputs = list(dict.fromkeys(r["input"] for r in rows))
    fig = Figure(figsize=(7.5 * max(1, len(inputs)), 6))
    axes = fig.subplots(1, max(1, len(inputs)), squeeze=False)
    for ax, name in zip(axes[0], inputs):
        rs = [r for r in rows if r["input"] == name and r["status"] == "ok" and r["seconds_all"]]
        sim = any("true_median_mm" in r for r in rs)
        key, label = (("true_median_mm", "true taxel error, median (mm)") if sim
                      else ("test_taxel_mm", "closest taxel pair, test mean (mm)"))
        for r in rs:
            y = r[key]
            marker = "s" if r["knobs"].get("max_touches") else ("^" if r["single_run"] else "o")
            ax.scatter(r["seconds"], y, marker=marker, s=40)
            ax.annotate(r["strategy"].split(" (")[0], (r["seconds"], y), textcoords="offset points", xytext=(4, 3),
                        fontsize=7)
        failed = [r["strategy"].split(" (")[0] for r in rows if r["input"] == name and r["status"] != "ok"]
        if failed:
            ax.text(0.01, 0.01, "FAILED: " + ", ".join(failed), transform=ax.transAxes, fontsize=7, color="red")
        ax.set_xscale("log")
        if rs and max(r[key] for r in rs) > 10 * max(min(r[key] for r in rs), 1e-9):
            ax.set_yscale("log")
        ax.set_xlabel("calibration time (s, median of repetitions)")
        ax.set_ylabel(label)
        ax.set_title(name, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def legacy_read_times(path, skin: SkinModel, repeat: int = 3) -> dict:
    """Seconds to read a thesis text file (parse and check every touch) through the exact reader (Python's
    ``ast``) and the fast one (the C JSON decoder), median of ``repeat`` interleaved runs, and whether both
    load the same touches with the same skip reasons."""
    from nao_skin.formats.legacy import read_legacy

    exact_s, fast_s = [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        exact, exact_report = read_legacy(path, skin, exact=True)
        t1 = time.perf_counter()
        fast, fast_report = read_legacy(path, skin)
        fast_s.append(time.perf_counter() - t1)
        exact_s.append(t1 - t0)
    same = (exact.keys == fast.keys and exact_report.skipped == fast_report.skipped
            and all(np.array_equal(getattr(exact, f), getattr(fast, f), equal_nan=True)
                    for f in ("stamps", "joints", "contact_touch", "contact_part", "contact_id", "contact_cop",
                              "act_contact", "act_slot", "act_pressure")))
    return {"exact_s": float(np.median(exact_s)), "fast_s": float(np.median(fast_s)), "same_touches": bool(same),
            "touches": exact.n_touches}


def real_split_lines(inp: BenchInput, k: int = REAL_SPLITS) -> tuple:
    """The default calibration of a real input over ``k`` seeded splits: ``(spread, markdown lines)``, the
    targets judged on the mean."""
    from nao_skin.calibration.splits import split_spread, spread_table

    spread = split_spread(inp.touches, inp.skin, CalibrationOptions(), k)
    lines = spread_table(spread)

    def judged(limits: dict) -> str:
        misses = [f"{sp} closest {kind.upper() if kind == 'cop' else kind} mean"
                  f" {spread[sp][kind + '_mean_mm']['mean']:.2f} > {limit} mm"
                  for kind, limit in limits.items() for sp in ("train", "test")
                  if not spread[sp][kind + "_mean_mm"]["mean"] <= limit]
        return (f"closest COP <= {limits['cop']} mm, closest taxel <= {limits['taxel']} mm, train and test): "
                + ("met" if not misses else "NOT met: " + "; ".join(misses)))

    lines += ["", f"Targets on the mean over the {k} splits ({judged(REAL_TARGET_MM)}",
              f"Goal of the accuracy issue on the same mean ({judged(REAL_GOAL_MM)}"]
    return spread, lines


# ------------------------------------------------------------------------------ kinematics
KINEMATIC_MODES = ("off", "on", "auto")
KINEMATIC_PRESETS = ("kinematic-error",) + HARD_PRESETS
# the goals: on the kinematic preset the skin alone leaves the hands > 1 mm (median) off and the
# kinematic unknowns bring every part to <= 0.5 mm median and <= 1.5 mm p95; on every other preset the
# option moves the true error by no more than this; recovered offsets within this where determined
KINEMATIC_GOALS = {"off_hands_median_mm": 1.0, "on_median_mm": TARGET_MM["median"], "on_p95_mm": TARGET_MM["p95"],
                   "unchanged_mm": 0.02,
                   "offset_deg": 0.2}


def run_kinematic_case(skin: SkinModel, preset: str, seed: int, setup: HardCaseSetup | None = None,
                       modes=KINEMATIC_MODES) -> list:
    """One preset and seed simulated once, calibrated with each ``kinematics`` mode: one row per mode.
    Never raises: a failure is a row."""
    setup = setup or HardCaseSetup()
    rows = []
    try:
        sim, touches, _ = simulate_case(skin, preset, seed, setup)
    except Exception as exc:  # noqa: BLE001 - a failing case is a row of the table
        return [{"preset": preset, "seed": int(seed), "mode": m, "status": "FAILED: " + one_line(exc, 200)}
                for m in modes]
    truth_kin = sim.truth.kinematics
    for mode in modes:
        row = {"preset": preset, "seed": int(seed), "mode": mode, "status": "ok"}
        try:
            result = calibrate(touches, skin, replace(setup.options, kinematics=mode), truth=sim.truth)
            rep = result.report
            # over the calibrated parts only (the final report's 'all' counts every part of the skin)
            err = truth_error(skin, result.calibration, sim.truth, rep.parts, robot_joints(result.train, skin))
            row.update(parts=list(rep.parts), seconds=rep.total_seconds, true_median_mm=err["all"]["median"],
                       true_p95_mm=err["all"]["p95"],
                       part_true_mm={p: {"median": err[p]["median"], "p95": err[p]["p95"]} for p in rep.parts})
            kin = rep.kinematics or {}
            row["accepted"] = bool(kin.get("accepted", False))
            held_out = kin.get("test_taxel_surface_mm", {})
            row["held_out_gain"] = held_out.get("gain", float("nan"))        # what auto decides on
            row["held_out_gain_low"] = held_out.get("gain_low", float("nan"))
            row["held"] = [h["name"] for h in kin.get("held", [])]
            # recovered against the truth: joints in degrees, links in mm (the truth's, 0 when it has none)
            row["recovered"] = {
                n: {"value": c["value"] * (1000.0 if c["unit"] == "m" else np.degrees(1.0)),
                    "true": truth_kin.get(n, 0.0) * (1000.0 if c["unit"] == "m" else np.degrees(1.0)),
                    "std": c["std"] * (1000.0 if c["unit"] == "m" else np.degrees(1.0)), "unit": c["unit"]}
                for n, c in kin.get("corrections", {}).items()}
            row.update(offset_errors(row["recovered"]))
            if any(math.isnan(row[k]) for k in ("true_median_mm", "true_p95_mm")):
                row["status"] = "FAILED: NaN true error"
        except Exception as exc:  # noqa: BLE001
            row["status"] = "FAILED: " + one_line(exc, 200)
            row["trace"] = traceback.format_exc(limit=3)
        rows.append(row)
    return rows


def offset_errors(recovered: dict) -> dict:
    """The recovered joint offsets against the truth (deg): the worst error over every estimate, and over
    those the touches determine to the goal's precision (two standard deviations within it), the others named
    with their std."""
    joints = {n: v for n, v in recovered.items() if v["unit"] == "rad"}
    determined = [abs(v["value"] - v["true"]) for v in joints.values()
                  if 2.0 * v["std"] <= KINEMATIC_GOALS["offset_deg"]]
    return {"max_offset_error_deg": max((abs(v["value"] - v["true"]) for v in joints.values()), default=float("nan")),
            "max_determined_offset_error_deg": max(determined, default=float("nan")),
            "determined_offsets": len(determined),
            "weak_offsets": {n: v["std"] for n, v in joints.items() if 2.0 * v["std"] > KINEMATIC_GOALS["offset_deg"]}}


def kinematics_matrix(skin: SkinModel, presets=KINEMATIC_PRESETS, seeds=range(20), setup: HardCaseSetup | None = None,
                      jobs: int = 1, say: Callable[[str], None] = print) -> list:
    """Every preset x seed x mode (each preset and seed simulated once, in ``jobs`` worker processes)."""
    cases = [(p, int(s)) for p in presets for s in seeds]
    rows = []

    def report(case_rows):
        rows.extend(case_rows)
        r0 = case_rows[0]
        say(f"[kinematics {len(rows) // len(case_rows)}/{len(cases)}] {r0['preset']} seed {r0['seed']}: "
            + ", ".join(f"{r['mode']} {_f(r.get('true_median_mm'), 3)} / {_f(r.get('true_p95_mm'), 3)} mm"
                        f" ({_f(r.get('seconds'), 1)} s)" if r["status"] == "ok" else f"{r['mode']} {r['status']}"
                        for r in case_rows))
    if jobs > 1:
        from nao_skin.bench.pool import worker_pool

        with worker_pool(jobs, len(cases)) as pool:
            for fut in [pool.submit(run_kinematic_case, skin, p, s, setup) for p, s in cases]:
                report(fut.result())
    else:
        for p, s in cases:
            report(run_kinematic_case(skin, p, s, setup))
    return rows


def kinematics_summary(rows: list) -> list:
    """Per preset and mode: true error per part (median over seeds of each run's median, worst p95), seconds,
    worst recovered joint offset, and the change against kinematics=off of the same runs."""
    off = {(r["preset"], r["seed"]): r for r in rows if r["mode"] == "off" and r["status"] == "ok"}
    by: dict = {}
    for r in rows:
        by.setdefault((r["preset"], r["mode"]), []).append(r)
    out = []
    for (preset, mode), rs in by.items():
        ok = [r for r in rs if r["status"] == "ok"]
        parts = sorted({p for r in ok for p in r["parts"]}, key=lambda p: ok[0]["parts"].index(p) if p in ok[0]["parts"]
                       else len(ok[0]["parts"]))
        s = {"preset": preset, "mode": mode, "runs": len(rs), "failed": len(rs) - len(ok),
             "median_mm": _median([r["true_median_mm"] for r in ok]),
             "worst_median_mm": max((r["true_median_mm"] for r in ok), default=float("nan")),
             "worst_p95_mm": max((r["true_p95_mm"] for r in ok), default=float("nan")),
             "parts": {p: {"median": _median([r["part_true_mm"][p]["median"] for r in ok if p in r["part_true_mm"]]),
                           "worst_median": max((r["part_true_mm"][p]["median"] for r in ok if p in r["part_true_mm"]),
                                               default=float("nan")),
                           "worst_p95": max((r["part_true_mm"][p]["p95"] for r in ok if p in r["part_true_mm"]),
                                            default=float("nan"))} for p in parts},
             "seconds": _median([r["seconds"] for r in ok]),
             "accepted": sum(r.get("accepted", False) for r in ok),
             "gain_low_range": _range([r.get("held_out_gain_low", math.nan) for r in ok]),
             "max_offset_error_deg": max((r["max_offset_error_deg"] for r in ok
                                          if not math.isnan(r.get("max_offset_error_deg", math.nan))),
                                         default=float("nan")),
             "max_determined_offset_error_deg": max(
                 (r["max_determined_offset_error_deg"] for r in ok
                  if not math.isnan(r.get("max_determined_offset_error_deg", math.nan))), default=float("nan")),
             "determined_offsets": sum(r.get("determined_offsets", 0) for r in ok),
             "weak_offsets": sorted({n for r in ok for n in r.get("weak_offsets", {})}),
             "weak_offset_std_deg": [min((s for r in ok for s in r.get("weak_offsets", {}).values()),
                                         default=float("nan")),
                                     max((s for r in ok for s in r.get("weak_offsets", {}).values()),
                                         default=float("nan"))],
             "max_change_mm": max((abs(r["true_median_mm"] - off[(preset, r["seed"])]["true_median_mm"]) for r in ok
                                   if (preset, r["seed"]) in off), default=float("nan"))}
        out.append(s)
    return out


def _median(values: list) -> float:
    return float(np.median(values)) if values else float("nan")


def _range(values: list) -> list:
    finite = [v for v in values if not math.isnan(v)]
    return [min(finite), max(finite)] if finite else [float("nan"), float("nan")]


def kinematics_goal_lines(rows: list) -> list:
    """The issue's goals, each with what was measured and whether it is met."""
    g = KINEMATIC_GOALS
    lines = []
    summary = {(s["preset"], s["mode"]): s for s in kinematics_summary(rows)}
    ke_off, ke_on = summary.get(("kinematic-error", "off")), summary.get(("kinematic-error", "on"))
    if ke_off:
        hands = {p: v["median"] for p, v in ke_off["parts"].items() if p.endswith("hand")}
        ok = all(v > g["off_hands_median_mm"] for v in hands.values())
        lines.append(f"kinematic-error, off: hands' true median > {g['off_hands_median_mm']:g} mm: "
                     + ", ".join(f"{p} {v:.2f} mm" for p, v in hands.items()) + (" - met" if ok else " - NOT met"))
    if ke_on:
        runs = [r for r in rows if r["preset"] == "kinematic-error" and r["mode"] == "on" and r["status"] == "ok"]
        good = [r for r in runs if all(v["median"] <= g["on_median_mm"] and v["p95"] <= g["on_p95_mm"]
                                       for v in r["part_true_mm"].values())]
        lines.append(f"kinematic-error, on: every part median <= {g['on_median_mm']:g} mm and p95 <= {g['on_p95_mm']:g}"
                     f" mm in {len(good)}/{ke_on['runs']} seeds (worst part median "
                     f"{max(v['worst_median'] for v in ke_on['parts'].values()):.2f} mm, worst p95"
                     f" {ke_on['worst_p95_mm']:.2f} mm)" + (" - met" if len(good) == ke_on["runs"] else " - NOT met"))
        worst = ke_on["max_offset_error_deg"]
        lines.append(f"kinematic-error, on: recovered joint offsets within {g['offset_deg']:g} deg: worst"
                     f" {_f(worst)} deg over every estimate" + (" - met" if worst <= g["offset_deg"] else " - NOT met"))
        determined = ke_on["max_determined_offset_error_deg"]
        weak = ke_on["weak_offsets"]
        lines.append(f"kinematic-error, on: where determined (std <= {g['offset_deg'] / 2:g} deg from the normal"
                     f" equations, {ke_on['determined_offsets']} estimates): worst {_f(determined)} deg"
                     + (" - met" if determined <= g["offset_deg"] else " - NOT met")
                     + (f"; weakly determined: {', '.join(weak)} (std {_f(ke_on['weak_offset_std_deg'][0])}"
                        f"-{_f(ke_on['weak_offset_std_deg'][1])} deg)" if weak else ""))
    for (preset, mode), s in summary.items():
        if preset == "kinematic-error" or mode == "off":
            continue
        ok = s["max_change_mm"] <= g["unchanged_mm"]
        lines.append(f"{preset}, {mode}: true median moved by at most {_f(s['max_change_mm'], 3)} mm against off"
                     f" (goal <= {g['unchanged_mm']:g} mm)" + (" - met" if ok else " - NOT met"))
    return lines


def kinematics_tables(rows: list) -> str:
    """Summary per preset and mode (per part), then the recovered offsets of the kinematic preset."""
    summary = kinematics_summary(rows)
    parts = list(dict.fromkeys(p for s in summary for p in s["parts"]))
    head = ["preset", "kinematics", "runs", "failed", "true median mm (median / worst)", "worst p95 mm"]
    head += [f"{p} median / worst p95 mm" for p in parts]
    head += ["seconds (median)", "kept (auto)", "held-out gain, 95 % bound (auto) %", "max change vs off mm",
             "worst joint offset error deg"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for s in summary:
        cells = [s["preset"], s["mode"], str(s["runs"]), str(s["failed"]),
                 f"{_f(s['median_mm'], 3)} / {_f(s['worst_median_mm'], 3)}", _f(s["worst_p95_mm"], 3)]
        cells += [f"{_f(s['parts'][p]['median'], 3)} / {_f(s['parts'][p]['worst_p95'], 3)}" if p in s["parts"] else "-"
                  for p in parts]
        low = s["gain_low_range"]
        cells += [_f(s["seconds"]), f"{s['accepted']}/{s['runs'] - s['failed']}" if s["mode"] == "auto" else "-",
                  f"{_f(100 * low[0], 1)} to {_f(100 * low[1], 1)}" if s["mode"] == "auto" else "-",
                  _f(s["max_change_mm"], 3) if s["mode"] != "off" else "-", _f(s["max_offset_error_deg"])]
        lines.append("| " + " | ".join(cells) + " |")
    rec = [r for r in rows if r["mode"] == "on" and r["status"] == "ok" and r.get("recovered")
           and r["preset"] == "kinematic-error"]
    if rec:
        names = list(dict.fromkeys(n for r in rec for n in r["recovered"]))
        lines += ["", "Recovered (kinematics=on) against the truth: estimate / true (std); joints deg, links mm;"
                      " held unknowns are '-'", "",
                  "| seed | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
        for r in rec:
            lines.append(f"| {r['seed']} | " + " | ".join(
                f"{r['recovered'][n]['value']:.2f} / {r['recovered'][n]['true']:.2f} ({r['recovered'][n]['std']:.2f})"
                if n in r["recovered"] else "-" for n in names) + " |")
    return "\n".join(lines)

