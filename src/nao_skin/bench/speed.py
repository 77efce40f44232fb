"""Speed against error over calibration strategies (:func:`speed_matrix`), pure (no ROS).

One row per strategy variant (the default, then one
:class:`~nao_skin.calibration.options.CalibrationOptions` knob changed per row, then a sweep over the
number of training touches), run on the same inputs. Repetitions are interleaved (every variant once,
then again) so that a slow spell of a shared machine hits all rows alike; the median is quoted. Errors:
true taxel error against ground truth (simulated input) or closest-COP / closest-taxel means on train
and test (real input). A failing or diverging strategy is a FAILED row with its one-line reason; the
matrix goes on. The table is :func:`speed_table`, the plot :func:`plot_speed_vs_error`; a real input's
figures over seeded splits, :func:`real_split_lines`.
"""
from __future__ import annotations

import math
import time
import traceback
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from nao_skin.bench import TARGET_MM
from nao_skin.bench.rows import finite_calibration, fmt, stage_totals
from nao_skin.calibration.engine import CalibrationOptions, calibrate, truth_error
from nao_skin.calibration.pairing import robot_joints
from nao_skin.errors import one_line
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.touches import TouchSet

TOUCH_SWEEP = (50, 100, 200, 500)   # plus "all" = the default row


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
        Variant("whole COPs (pairs=cop: every taxel of the two contacts, the default until 2026-11-29)",
                {"pairs": "cop"}),
        Variant("COP pairs only (the closing stage too)", {"closing_pairs": "cop"}),
        Variant("COP and closest taxel pairs in every stage (pairs=both)", {"pairs": "both"}),
        Variant("taxel pairs only", {"pairs": "taxel", "closing_pairs": "taxel"}),
        Variant("point-to-plane rows instead of closest taxel pairs (cop+plane)",
                {"pairs": "cop+plane", "closing_pairs": "cop+plane"}),
        Variant("point-to-plane rows beside closest taxel pairs (both+plane)",
                {"pairs": "both+plane", "closing_pairs": "both+plane"}),
        Variant("surface rows beside the closing stage's COPs (closing_pairs=cop+surface)",
                {"closing_pairs": "cop+surface"}),
        Variant("press model (the plan again, on the COP rows less what a press is expected to put between them)",
                {"press_model": True}),
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
        out[f"{split}_fired_f1"] = final[split].get("fired_f1", float("nan"))
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
                    if not finite_calibration(result.calibration):
                        raise FloatingPointError("non-finite correction in the calibration")
                    errors = _errors(result, inp)
                    row.update(errors)
                    row.update(stage_totals(result.report))
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


# ------------------------------------------------------------------------------ table and plot
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
                "fired taxels predicted F1 % train / test", "explained: COP / taxel mm test", "iterations", "re-pairings", "status"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rs:
        runs = f"{r['runs']}" + (" (slow: once)" if r["single_run"] else "")
        status = "ok" if r["status"] == "ok" else r["status"]
        if r["status"] != "ok" and not r["seconds_all"]:
            cells = [r["strategy"], "-", "0"] + ["-"] * (len(head) - 4) + [status]
        elif sim:
            cells = [r["strategy"], fmt(r["seconds"]), runs, fmt(r.get("true_median_mm"), 3),
                     fmt(r.get("true_p95_mm"), 3), fmt(r.get("iterations")), fmt(r.get("repairings")), status]
        else:
            cells = [r["strategy"], fmt(r["seconds"]), runs,
                     f"{fmt(r.get('train_cop_mm'))} / {fmt(r.get('test_cop_mm'))}",
                     f"{fmt(r.get('train_taxel_mm'))} / {fmt(r.get('test_taxel_mm'))}",
                     f"{fmt(r.get('train_contact_taxel_mm'))} / {fmt(r.get('test_contact_taxel_mm'))}",
                     f"{fmt(r.get('train_fired_f1'), 1)} / {fmt(r.get('test_fired_f1'), 1)}",
                     f"{fmt(r.get('test_cop_explained_mm'))} / {fmt(r.get('test_taxel_explained_mm'))}",
                     fmt(r.get("iterations")), fmt(r.get("repairings")), status]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


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
