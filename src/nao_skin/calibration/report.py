"""Write a calibration where users apply it: YAML for the URDF, taxel files, report, plots.

Everything is written into a temporary sibling directory first and moved
into place at the end, so an interrupted or failed run leaves no half-done
output directory.
"""
from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import numpy as np

from nao_skin.calibration.engine import CalibrationResult
from nao_skin.calibration.evaluation import contact_figure, measured
from nao_skin.calibration.layout import COMPONENTS
from nao_skin.calibration.options import KIND_ROWS, CalibrationOptions
from nao_skin.calibration.pairing import KIND_NAMES
from nao_skin.calibration.plan import touching_pairs
from nao_skin.calibration.rows import concat_pairings, pair_for_metrics, pair_parts
from nao_skin.calibration.scenes import scenes_markdown
from nao_skin.calibration.splits import kinematics_kept_text, spread_table
from nao_skin.calibration.stages import held_frames
from nao_skin.errors import OutputError, OutputTaken, os_reason
from nao_skin.formats.outdir import CALIBRATION, replace_dir, staging_dir, write_marker
from nao_skin.model.skin import SkinCalibration, SkinModel, part_rank
from nao_skin.paths import free_sibling
from nao_skin.plain import jsonable
from nao_skin.touch.touches import TouchSet


TAKEN_TRIES = 5     # places tried when another process takes the one chosen as the output is moved there


def write_outputs(result: CalibrationResult, skin: SkinModel, out_dir: str | Path,
                  prior: SkinCalibration | None = None, plots: bool = True, command: str = "calibrate",
                  extra=None, replacing=None, beside: str | None = None) -> Path:
    """Write the calibration into ``out_dir``, marked as written by ``nao-skin COMMAND``; returns where.

    ``extra(directory)`` may add files beside ours before the directory is
    marked and moved into place (they are then ours too). An earlier output
    in ``out_dir`` is replaced only when :mod:`nao_skin.outdir` allows it;
    callers check the directory with ``check_output_dir`` before any work.
    ``replacing``: what may be replaced there (:func:`~nao_skin.formats.outdir.replace_dir`); when something
    else took the place meanwhile, the output goes to the first free ``<out_dir><beside>`` (with ``beside``;
    else :class:`~nao_skin.errors.OutputTaken` is raised).
    """
    given, out_dir = Path(out_dir), Path(os.path.realpath(out_dir))
    try:
        tmp = staging_dir(out_dir)
    except OSError as exc:
        raise OutputError(f"{given}: cannot write the calibration there ({os_reason(exc)})") from None
    try:
        calibrated = list(result.report.parts)
        result.calibration.save(tmp / "calibration.yaml", skin,
                                comment=f"parts calibrated from touches: {', '.join(calibrated)}")
        (tmp / "taxels").mkdir()
        for name in calibrated:
            skin.parts[name].write_taxel_file(tmp / "taxels" / f"{name}.txt", result.calibration.parts[name])
        (tmp / "report.json").write_text(json.dumps(jsonable(result.report.to_dict()), indent=2) + "\n")
        coverage = report_coverage(result, skin)
        (tmp / "report.md").write_text(markdown_report(result.report.to_dict(), coverage, pictures=plots))
        if plots:
            _plots(result, skin, prior or skin.zero_calibration(), tmp, calibrated)
            plot_coverage(coverage, skin, result.calibration, tmp / "coverage.png")
            plot_uncertainty(result.report.final.get("predicted_triangle_error_mm") or {}, skin,
                             result.calibration, tmp / "uncertainty.png")
        if extra is not None:
            extra(tmp)
        write_marker(tmp, command, CALIBRATION)
        # the places beside: <base><beside>, <base><beside>2, ... (a place already beside is not nested further)
        base, tried = Path(re.sub(rf"{re.escape(beside)}[0-9]*$", "", str(given)) if beside else given), []
        while True:
            try:
                replace_dir(tmp, out_dir, replacing=replacing)
                break
            except OutputTaken:
                if beside is None:
                    raise
                tried.append(str(given))
                if len(tried) == TAKEN_TRIES:
                    raise OutputTaken(f"{base}: the places tried ({', '.join(tried)}) were taken meanwhile by"
                                      f" other outputs, left as they are; nothing is written") from None
                # another process wrote there meanwhile (two nodes given one out_dir): its output stays
                given = Path(free_sibling(base, beside))
                out_dir, replacing = Path(os.path.realpath(given)), ()
    except OSError as exc:     # e.g. a full disk: the calibration is not written, an earlier one there stays
        shutil.rmtree(tmp, ignore_errors=True)
        raise OutputError(f"{given}: cannot write the calibration ({os_reason(exc)}); an earlier output there is"
                          f" unchanged") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return given


def _fmt(v) -> str:
    return "–" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.2f}"


def _percent(share):
    return None if share is None else 100.0 * share


def kinematics_section(kin: dict) -> list:
    """report.md lines of the kinematic corrections: value and std per joint offset (deg) and link (mm),
    what was held and why; none when the calibration left the kinematics alone (kinematics=off)."""
    if not kin:
        return []
    test = kin.get("test_taxel_surface_mm", {})
    lines = ["", f"## Kinematics (kinematics={kin['mode']}: {'kept' if kin.get('accepted') else 'not kept'})", "",
             f"Test split's closest taxel mean at the fabric surfaces: {_fmt(test.get('before'))} mm with the skin"
             f" alone, {_fmt(test.get('after'))} mm with the kinematic unknowns over {test.get('touches', '–')}"
             f" touches: {_fmt(_percent(test.get('gain')))} % closer, at least {_fmt(_percent(test.get('gain_low')))} %"
             f" at 95 % confidence.", ""]
    if kin.get("corrections"):
        lines += ["| joint / link | correction | std | unit |", "|---|---|---|---|"]
        for name, c in kin["corrections"].items():
            scale, unit = (1000.0, "mm") if c["unit"] == "m" else (np.degrees(1.0), "deg")
            lines.append(f"| {name} | {_fmt(scale * c['value'])} | {_fmt(scale * c['std'])} | {unit} |")
    if kin.get("held"):
        lines += ["", "Held at the robot config:", ""]
        lines += [f"- {h['name']}: {h['reason']}" for h in kin["held"]]
    return lines


def fingertips_section(tips: dict, truth: dict) -> list:
    """report.md lines of the fingertips' contact spheres: centre (mm, in the chain's end frame) and radius with
    their std, what was held at the robot config; the distance from the true sphere where known."""
    if not tips:
        return []
    lines = ["", "## Fingertips (contact spheres, in the end frame of their chains)", "",
             "| fingertip | chain | centre x, y, z (mm) | radius (mm) | std x, y, z, radius (mm) | held |"
             + (" true centre off (mm) | true radius off (mm) |" if truth else ""),
             "|---|---|---|---|---|---|" + ("---|---|" if truth else "")]
    for name, t in tips.items():
        std = " ".join(_fmt(1000.0 * v) for v in t["std"]) if t.get("std") else "–"
        off = ([_fmt(truth[name]["centre"]), _fmt(truth[name]["radius"])] if name in truth else ["–", "–"]) \
            if truth else []
        lines.append(f"| {name} | {t['chain']} | {', '.join(_fmt(1000.0 * v) for v in t['point'])} |"
                     f" {_fmt(1000.0 * t['radius'])} | {std} | {', '.join(t['held']) or 'none'} |"
                     + "".join(f" {v} |" for v in off))
    return lines


def predicted_section(final: dict, pictures: bool = True) -> list:
    """report.md lines of the predicted taxel error per part (and the true one beside it, when known);
    ``pictures``: uncertainty.png is written beside (named only then)."""
    predicted = final.get("predicted_taxel_error_mm")
    if not predicted:
        return []
    truth = final.get("truth_taxel_error_mm") or {}
    lines = ["", "## Predicted taxel error (linearised posterior at the estimate)", "",
             f"Each taxel's predicted RMS error from the kept touches' rows linearised at the calibration, their noise"
             f" {_fmt(final.get('predicted_noise_mm'))} mm per coordinate (robust spread of their residuals), and the"
             f" calibration's prior; held patches and triangles at their prior. What an efficient estimator reaches,"
             f" had the pairing no wrong pairs and the noise no tails.", "",
             "| part | predicted median (mm) | predicted p95 (mm) |"
             + (" true median (mm) | true p95 (mm) |" if truth else ""),
             "|---|---|---|" + ("---|---|" if truth else "")]
    for part, v in predicted.items():
        true = [_fmt(truth.get(part, {}).get(k)) for k in ("median", "p95")] if truth else []
        lines.append(f"| {part} | {_fmt(v['median'])} | {_fmt(v['p95'])} |" + "".join(f" {t} |" for t in true))
    if final.get("predicted_triangle_error_mm"):
        lines += ["", "Per triangle (the median of its taxels): report.json's `final.predicted_triangle_error_mm`"
                  + (", and the picture uncertainty.png (white: sure; orange to brown: up to 1 mm and more)" if pictures
                     else "") + "; the calibrate node shows the same map in RViz."]
    return lines


def _set_aside_text(final: dict) -> str:
    """How far apart the touches the gate set aside are, beside the kept ones (the warnings judge those)."""
    aside, kept = final.get("train_set_aside"), final.get("train_kept")
    if not aside or not kept:
        return ""
    label, far = contact_figure(aside)
    return (f" ({label} mean {_fmt(far)} mm under the calibration; the"
            f" {kept.get('n_touches', 0)} training touches kept: {_fmt(contact_figure(kept)[1])} mm)")


def markdown_report(report: dict, coverage: dict | None = None, pictures: bool = True) -> str:
    """report.md from the report's dict; ``coverage`` (:func:`report_coverage`) adds the coverage table;
    ``pictures``: the plots are written beside it (coverage.png is named only then)."""
    labels = {"cop_mean_mm": "closest COP mean (mm)", "taxel_mean_mm": "closest taxel mean (mm)",
              "contact_taxel_mean_mm": "selected contacts' closest taxel mean (mm)",
              "taxel5_mean_mm": "5 taxel pairs mean (mm)", "fingertip_mean_mm": "fingertip to its contact mean (mm)",
              "fired_f1": "fired taxels predicted F1 (%)"}
    final_train = report["final"].get("train", {})
    # the self-touch columns where self-touches are measured (or nothing is), the fingertip's where fingertips are
    fingertip = bool(measured(final_train, ("fingertip_mean_mm",)))
    keys = ([k for k in labels if k not in ("fingertip_mean_mm", "fired_f1")]
            if measured(final_train, ("cop_mean_mm",)) or not fingertip else [])
    keys += ["fingertip_mean_mm"] * fingertip + ["fired_f1"]
    lines = ["# Skin calibration report", "",
             f"Plan: {' → '.join(report['plan'])}", "",
             f"Total time: {report['total_seconds']:.2f} s. Touches set aside: {report['n_set_aside']}"
             + _set_aside_text(report["final"]) + ".", "",
             *([f"**Warning: {w}.**" for w in report.get("warnings") or []] + [""] if report.get("warnings") else []),
             "Closest taxel: the closest pair among every activated taxel of the two touching parts; selected"
             " contacts': the closest pair of the two contacts whose COPs are closest (what the solver fits)."
             + (" Fingertip to its contact: from the point of the fingertip's contact sphere facing the skin to the"
                " COP of its nearest contact, at the fabric surface." if "fingertip_mean_mm" in keys else "")
             + " Fired taxels predicted: each part's fired taxels predict the other part's facing taxels within"
             " 4 mm (a fingertip's sphere the taxels within 5 mm of its contact point); F1 of the predicted against"
             " the fired (percent; higher is better, owes nothing to closest pairs).", "",
             "| stage | set | touches | " + " | ".join(labels[k] for k in keys) + " | seconds |",
             "|---|---|---|" + "---|" * len(keys) + "---|"]
    rows = [("before", report["before"], None)]
    rows += [(s["name"], s, s["seconds"]) for s in report["stages"]]
    rows += [("final", report["final"], None)]
    accepted = {"train": report["final"].get("train_accepted", {}), "test": report["final"].get("test_accepted", {})}
    rows += [("final, touches a self-contact explains", accepted, None)]
    if report["final"].get("train_set_aside"):      # the gate's choice, apart: what the calibration is judged by
        rows += [("final, touches kept", {"train": report["final"]["train_kept"]}, None),
                 ("final, touches set aside", {"train": report["final"]["train_set_aside"]}, None)]
    unmeasured = 0
    for name, entry, secs in rows:
        if name != "final" and not any(entry.get(split) for split in ("train", "test")):
            unmeasured += 1            # a live update's warm start measures the final figures only
            continue
        for split in (s for s in ("train", "test") if s in entry):
            m = entry[split]
            lines.append(f"| {name} | {split} | {m.get('n_touches', 0)} | "
                         + " | ".join(_fmt(m.get(k)) for k in keys) + f" | {_fmt(secs) if split == 'train' else ''} |")
    if unmeasured:
        lines += ["", f"{unmeasured} rows measured on no split are left out: a live update, warm-started from the"
                      f" one before, measures its final figures only, and its time is its own, not the session's"
                      f" (`nao-skin calibrate` on the bag gives every stage's)."]
    truth = report["final"].get("truth_taxel_error_mm")
    if truth:
        lines += ["", "## True taxel error (simulation ground truth)", "",
                  "| part | before median (mm) | final median (mm) | final p95 (mm) | final max (mm) |", "|---|---|---|---|---|"]
        before = report["before"].get("truth_taxel_error_mm", {})
        for part, v in truth.items():
            lines.append(f"| {part} | {_fmt(before.get(part, {}).get('median'))} | {_fmt(v['median'])} | "
                         f"{_fmt(v['p95'])} | {_fmt(v['max'])} |")
    lines += predicted_section(report["final"], pictures)
    spread = report.get("splits")
    if spread:
        lines += ["", f"## Over {spread['k']} {spread['kind']} (seeds {spread['seeds'][0]}..{spread['seeds'][-1]},"
                      f" {int(100 * spread['test_fraction'])} % test)", "", *spread_table(spread)]
        if kinematics_kept_text(spread):
            gains = ", ".join(f"{100 * s['kinematics']['gain']:.1f} % ({100 * s['kinematics']['gain_low']:.1f} %)"
                              for s in spread["per_seed"])
            lines += ["", f"{kinematics_kept_text(spread).capitalize()} splits; each split's held-out gain with"
                          f" them (its 95 % bound): {gains}."]
    lines += scenes_markdown(report.get("scenes") or {})
    lines += ["", "## What the touches say about the skin", "",
              f"- fabric over the taxels (each skin): {_fmt(report.get('fabric_thickness_mm'))} mm"]
    sigma = report.get("prior_sigma") or {}
    for group, value in sigma.items():   # prior std per component of every patch / triangle
        unit, scale = ("mm", 1000.0) if group.endswith("translation") else ("deg", np.degrees(1.0))
        lines.append(f"- prior std of {group.replace('_', ' ')}: {_fmt(scale * value)} {unit}")
    lines += kinematics_section(report.get("kinematics") or {})
    lines += fingertips_section(report.get("fingertips") or {}, report["final"].get("truth_fingertip_error_mm") or {})
    if report.get("left_out"):
        lines += ["", "## Left out: too few touches (held at the prior)", ""]
        lines += [f"- {e['pair']}: {e['reason']}" for e in report["left_out"]]
    if coverage:
        lines += ["", *coverage_lines(coverage, pictures)]
    if report.get("held"):
        lines += ["", "## Held at their prior (not determined by the touches)", ""]
        lines += [f"- {h}" for h in report["held"]]
    if report.get("set_aside"):
        lines += ["", "## Touches set aside", ""]
        lines += [f"- touch {s['touch']} ({s['step']}): {s['reason']}" for s in report["set_aside"]]
    lines.append("")
    return "\n".join(lines)


def _pair_distances(touches, skin, calib, pairs):
    """Closest-taxel distances per touch and the triangle each used on every part."""
    pairings = [pair_for_metrics(touches, skin, calib, parts=p) for p in pairs]
    pairings = [p for p in pairings if len(p.row_touch)]
    if not pairings:
        return None
    return concat_pairings(pairings)


def _plots(result: CalibrationResult, skin: SkinModel, prior: SkinCalibration, out: Path, calibrated: list):
    from matplotlib.figure import Figure   # no pyplot: no backend or global figure state

    pairs = [tuple(p) for p in result.report.pairs]

    # 1. error distributions before/after
    fig = Figure(figsize=(11, 4))
    axes = fig.subplots(1, 2)
    for ax, (split, touches) in zip(axes, (("train", result.train), ("test", result.test))):
        for label, calib, color in (("before", prior, "tab:gray"), ("after", result.calibration, "tab:blue")):
            p = _pair_distances(touches, skin, calib, pairs)
            if p is None:
                continue
            for kind, style in ((0, "-"), (1, "--")):
                d = p.distance[p.row_kind == kind] * 1000.0
                if len(d):
                    ax.hist(np.clip(d, 0, 100), bins=50, range=(0, 100), histtype="step", linestyle=style,
                            color=color, label=f"{label}: {'closest COP' if kind == 0 else 'closest taxel'}")
        ax.set_xlabel("distance between paired points (mm, clipped at 100)")
        ax.set_ylabel("touches")
        ax.set_title(f"{split} set")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "errors_before_after.png", dpi=110)

    # 2. per-triangle closest-taxel error after calibration
    p = _pair_distances(result.train, skin, result.calibration, pairs)
    if p is not None:
        fig = Figure(figsize=(11, 2.6 * len(calibrated)))
        axes = fig.subplots(len(calibrated), 1, squeeze=False)
        rows = np.flatnonzero(p.row_kind == 1)
        for ax, name in zip(axes[:, 0], calibrated):
            pidx = result.train.part_index(name)
            part = skin.parts[name]
            sel = np.isin(p.term_row, rows) & (p.term_part == pidx)
            tri = part.slot_triangle[p.term_slot[sel]]
            dist = p.distance[p.term_row[sel]] * 1000.0
            counts = np.bincount(tri, minlength=len(part.triangle_ids))
            sums = np.bincount(tri, weights=dist, minlength=len(part.triangle_ids))
            mean = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
            ax.bar(np.arange(len(part.triangle_ids)), mean, color="tab:blue")
            ax.set_xticks(np.arange(len(part.triangle_ids)))
            ax.set_xticklabels([str(t) for t in part.triangle_ids], fontsize=7)
            ax.set_ylabel("mean mm")
            ax.set_title(f"{name}: closest-taxel distance per triangle after calibration (train)", fontsize=9)
        axes[-1, 0].set_xlabel("triangle")
        fig.tight_layout()
        fig.savefig(out / "triangle_errors.png", dpi=110)

    # 3. the skin before and after, in each part's own frame
    fig = Figure(figsize=(5 * len(calibrated), 4.5))
    for i, name in enumerate(calibrated):
        ax = fig.add_subplot(1, len(calibrated), i + 1, projection="3d")
        part = skin.parts[name]
        before, _ = part.taxel_positions(prior.parts.get(name))
        after, _ = part.taxel_positions(result.calibration.parts[name])
        b, a = before[part.present] * 1000, after[part.present] * 1000
        ax.scatter(*b.T, s=4, c="tab:gray", label="before")
        ax.scatter(*a.T, s=4, c="tab:red", label="after")
        ax.set_title(f"{name} ({part.parent_frame}, mm)", fontsize=9)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "skin_before_after.png", dpi=110)


# ---------------------------------------------------------------------------- coverage
def paired_activation_counts(touches: TouchSet, skin: SkinModel, calib: SkinCalibration,
                             options: CalibrationOptions | None = None, pairs=None) -> dict:
    """``{part: (T,) paired activations per triangle row}`` over the part pairs ``pairs`` of the touches.

    As ``stages._activation_counts`` counts them for a triangle stage: per
    touch and triangle once, over the pair kinds of ``options.pairs`` (closest
    COP and taxel pairs by default), paired under ``calib``. ``pairs``: part
    name pairs (default: every pair of parts that fires together).
    """
    options = options or CalibrationOptions()
    names = {v: k for k, v in KIND_NAMES.items()}
    kinds = tuple(names[k] for k in KIND_ROWS[options.pairs])
    kind_codes = np.array(KIND_ROWS[options.pairs])
    out = {name: np.zeros(len(part.triangle_ids), int) for name, part in skin.parts.items()}
    if pairs is None:
        pairs = [tuple(sorted(p, key=part_rank)) for p in touching_pairs(touches)] if touches.n_touches else []
    keys: dict = {}
    for a, b in pairs:
        if a not in touches.part_names or b not in touches.part_names:
            continue
        p = pair_parts(touches, skin, calib, *sorted((a, b), key=part_rank), kinds)
        if not len(p.row_touch):
            continue
        term_ok = np.isin(p.row_kind, kind_codes)[p.term_row]
        for name in (a, b):
            sel = term_ok & (p.term_part == touches.part_index(name))
            tri = skin.parts[name].slot_triangle[p.term_slot[sel]]
            keys.setdefault(name, []).append(p.row_touch[p.term_row[sel]] * 10000 + tri)
    for name, k in keys.items():
        key = np.unique(np.concatenate(k))
        out[name] += np.bincount(key % 10000, minlength=len(out[name]))
    return out


def report_coverage(result: CalibrationResult, skin: SkinModel) -> dict:
    """Per calibrated part: paired activations per triangle on the training touches, under the final
    calibration, against ``min_triangle_activations``; held triangles and patches from the report."""
    options = CalibrationOptions.from_mapping(result.report.options)
    pairs = [tuple(p) for p in result.report.pairs]
    counts = paired_activation_counts(result.train, skin, result.calibration, options, pairs)
    held = held_frames(result.report.held)
    out = {}
    for name in result.report.parts:
        sp = skin.parts[name]
        c = counts[name]
        frames = {frame: comps for (part, frame), comps in held.items() if part == name}
        tri_held = [(int(f.split("_")[1]), comps) for f, comps in frames.items() if f.startswith("triangle_")]
        out[name] = {"triangle_ids": [int(t) for t in sp.triangle_ids], "activations": [int(v) for v in c],
                     "needed": int(options.min_triangle_activations),
                     "enough": int(np.sum(c >= options.min_triangle_activations)), "total": len(c),
                     "held_triangles": sorted(t for t, comps in tri_held if comps == COMPONENTS),
                     "partly_held_triangles": sorted(f"{t} ({','.join(comps)})" for t, comps in tri_held
                                                     if comps != COMPONENTS),
                     "held_patches": sorted(f.split("_")[1] + ("" if comps == COMPONENTS else f" ({','.join(comps)})")
                                            for f, comps in frames.items() if f.startswith("patch_"))}
    return out


def coverage_lines(coverage: dict, picture: bool = True) -> list:
    """The coverage table of report.md: triangles with enough paired activations, held triangles; ``picture``:
    coverage.png is written beside it."""
    lines = ["## Coverage: paired activations per triangle (training touches)", "",
             "| part | triangles with enough (>= needed) / total | fewest / median activations | held triangles"
             " | partly held triangles | held patches |", "|---|---|---|---|---|---|"]
    for name, c in coverage.items():
        acts = np.array(c["activations"])
        lines.append(f"| {name} | {c['enough']} / {c['total']} (>= {c['needed']}) |"
                     f" {int(acts.min()) if len(acts) else 0} / {float(np.median(acts)) if len(acts) else 0:g} |"
                     f" {', '.join(map(str, c['held_triangles'])) or '–'} |"
                     f" {', '.join(c['partly_held_triangles']) or '–'} | {', '.join(c['held_patches']) or '–'} |")
    if picture:
        lines += ["", "The picture: coverage.png (taxels coloured by their triangle's paired activations, held"
                      " triangles crossed)."]
    return lines


def _layout_xy(part, corr) -> np.ndarray:
    """(S, 2) mm: a part's taxels (its present slots) projected on their best-fit plane, for a flat picture."""
    pos, _ = part.taxel_positions(corr)
    pts = pos[part.slots]
    centre = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centre, full_matrices=False)
    return (pts - centre) @ vt[:2].T * 1000.0


def plot_uncertainty(triangles: dict, skin: SkinModel, calib: SkinCalibration, path: Path) -> None:
    """The uncertainty map on each calibrated part's layout: its taxels coloured by their triangle's predicted
    error (:mod:`nao_skin.calibration.uncertainty_map`'s scale, as in RViz)."""
    from matplotlib.figure import Figure   # no pyplot: no backend or global figure state

    from nao_skin.calibration.uncertainty_map import colour_map

    names = [n for n in triangles if triangles[n]]
    if not names:
        return
    fig = Figure(figsize=(4.6 * len(names), 4.4))
    axes = fig.subplots(1, len(names), squeeze=False)
    for ax, name in zip(axes[0], names):
        sp = skin.parts[name]
        xy = _layout_xy(sp, calib.parts.get(name))
        tids = sp.triangle_ids[sp.slot_triangle[sp.slots]]
        values = np.array([triangles[name].get(int(t), np.nan) for t in tids])
        cmap, norm = colour_map()
        sc = ax.scatter(*xy.T, s=8, c=values, cmap=cmap, norm=norm, edgecolors="0.6", linewidths=0.2)
        ax.set_aspect("equal")
        ax.set_title(f"{name}: predicted error per triangle (median {np.nanmedian(values):.2f} mm)", fontsize=8)
        ax.set_xlabel("mm (best-fit plane of the taxels)", fontsize=7)
        ax.tick_params(labelsize=6)
        bar = fig.colorbar(sc, ax=ax, shrink=0.7)
        bar.set_label("predicted RMS error (mm)", fontsize=7)
        ticks = [v for v in (0.25, 0.5, 1.0, 2.0, 4.0) if norm.vmin <= v <= norm.vmax]
        bar.set_ticks(ticks, labels=[f"{v:g}" for v in ticks])
        bar.ax.minorticks_off()
        bar.ax.tick_params(labelsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_coverage(coverage: dict, skin: SkinModel, calib: SkinCalibration, path: Path) -> None:
    """Per calibrated part, its taxels on the layout (projected on their best-fit plane) coloured by the
    paired activations of their triangle (grey: none), held triangles crossed in red."""
    from matplotlib.colors import LogNorm
    from matplotlib.figure import Figure   # no pyplot: no backend or global figure state

    names = list(coverage)
    if not names:
        return
    fig = Figure(figsize=(4.6 * len(names), 4.4))
    axes = fig.subplots(1, len(names), squeeze=False)
    vmax = max(max(c["activations"], default=1) for c in coverage.values()) or 1
    for ax, name in zip(axes[0], names):
        sp = skin.parts[name]
        c = coverage[name]
        slots = sp.slots
        xy = _layout_xy(sp, calib.parts.get(name))
        acts = np.array(c["activations"])[sp.slot_triangle[slots]]
        ax.scatter(*xy[acts == 0].T, s=6, c="0.7", label="no paired activation")
        sc = ax.scatter(*xy[acts > 0].T, s=6, c=acts[acts > 0], cmap="viridis",
                        norm=LogNorm(vmin=1, vmax=max(vmax, 2)))
        held = set(c["held_triangles"]) | {int(t.split()[0]) for t in c["partly_held_triangles"]}
        rows = sp.slot_triangle[slots]
        for tid in held:
            r = np.flatnonzero(sp.triangle_ids == tid)
            if len(r):
                m = xy[rows == r[0]].mean(axis=0)
                full = tid in c["held_triangles"]
                ax.plot(*m, marker="x", ms=9 if full else 6, mew=2 if full else 1, color="tab:red")
                ax.annotate(str(tid), m, fontsize=6, color="tab:red", xytext=(3, 3), textcoords="offset points")
        ax.set_aspect("equal")
        ax.set_title(f"{name}: {c['enough']}/{c['total']} triangles >= {c['needed']} paired activations",
                     fontsize=8)
        ax.set_xlabel("mm (best-fit plane of the taxels)", fontsize=7)
        ax.tick_params(labelsize=6)
        fig.colorbar(sc, ax=ax, shrink=0.7).set_label("paired activations of the triangle", fontsize=7)
    axes[0, 0].plot([], [], "x", color="tab:red", label="held triangle")
    axes[0, 0].legend(fontsize=6, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
