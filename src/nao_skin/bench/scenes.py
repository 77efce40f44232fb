"""Every scene at once in the bench (pure, no ROS): each scene predicted from the others, and where the scenes
place each part.

Real: the self-touch recording (``l_hand_torso``) and the two fingertip recordings calibrated together, with the
kinematics off (the default) and on; each scene's own test figure (calibrated alone, by pose), its figure predicted
from the other two (:func:`~nao_skin.calibration.scenes.cross_scene`), their ratio against issue 62's 1.25; the own
figures of the three calibrated together against alone (goal: at most 5 % worse); and the torso placed from the
self-touches against the torso placed from the fingertip on it (median over the taxels; goal: 3 mm).

Simulated: the scenes-kinematic preset (the same three scenes, arms whose kinematics err differently), every seed at
``SIM_TOUCHES`` touches per scene, kinematics on: each part's true taxel median with every scene together against
the worst scene alone (goal: together at most 0.5 mm).
"""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from nao_skin.bench.rows import fmt
from nao_skin.calibration.options import CalibrationOptions
from nao_skin.calibration.scenes import cross_scene, placement_spread
from nao_skin.model.skin import SkinModel

RATIO_GOAL = 1.25            # predicted over own test figure
OWN_WORSE_GOAL = 0.05        # own figures, together against alone
TORSO_GOAL_MM = 3.0          # the torso from the self-touches against the torso from the fingertip
SIM_GOAL_MM = 0.5
SIM_TOUCHES = 250
SELF_TOUCH = "l_hand_torso.legacy.txt"
KINEMATICS = ("off", "on")


def real_rows(self_touch: Path, fingertip_dir: Path, layouts: dict, say=print) -> list:
    """A row per kinematics mode: the three real recordings' cross-scene prediction and placements."""
    from nao_skin.formats.inputs import Inputs, load_touches
    from nao_skin.model.skin import load_skin
    from nao_skin.paths import REAL_FINGERTIP
    from nao_skin.touch.datasets import deduplicate

    skin = load_skin(taxel_files=dict(layouts))
    paths = [str(self_touch), *(str(Path(fingertip_dir) / name) for name in REAL_FINGERTIP)]
    tips = {str(Path(fingertip_dir) / name): tip for name, (tip, _) in REAL_FINGERTIP.items()}
    touches, _, _ = load_touches(Inputs(tuple(paths), tips), skin, log=lambda m: None)
    touches, _ = deduplicate(touches)
    rows = []
    for mode in KINEMATICS:
        options = replace(CalibrationOptions(), kinematics=mode)
        t0 = time.perf_counter()
        predictions, results = cross_scene(touches, skin, options)
        seconds = time.perf_counter() - t0
        together = results["all"]
        spread = placement_spread(skin, results)
        torso = _between(skin, "torso", results.get("l_hand+torso"), results.get("r_finger-torso"))
        scenes = []
        for p in predictions:
            ratios = p.ratios()
            worse = {f: p.together[f] / p.own["test"][f] - 1.0 for f in ratios if f in p.together}
            scenes.append({"scene": p.scene, "touches": p.touches, "own": p.own["test"], "predicted": p.predicted,
                           "ratio": ratios, "together": p.together, "together_worse": worse,
                           "met": bool(ratios) and max(ratios.values()) <= RATIO_GOAL})
        rows.append({"kinematics": mode, "scenes": scenes, "placement_spread_mm": spread, "torso_between_mm": torso,
                     "together_seconds": together.report.total_seconds, "cross_scene_seconds": seconds,
                     "together_test": together.report.final["test"]})
        say(f"scenes, kinematics {mode}: ratios " + ", ".join(
            f"{s['scene']} {max(s['ratio'].values()):.2f}" for s in scenes if s["ratio"])
            + f"; torso between the scenes {torso:.1f} mm; {seconds:.1f} s")
    return rows


def _between(skin: SkinModel, part: str, a, b) -> float:
    """Median distance (mm) of ``part``'s taxels as calibrations ``a`` and ``b`` place them."""
    if a is None or b is None:
        return float("nan")
    sp = skin.parts[part]
    pa = sp.taxel_positions(a.calibration.parts[part], normals=False)[sp.present]
    pb = sp.taxel_positions(b.calibration.parts[part], normals=False)[sp.present]
    return 1000.0 * float(np.median(np.linalg.norm(pa - pb, axis=1)))


def sim_rows(skin: SkinModel, seeds, say=print) -> list:
    """A row per seed of the scenes-kinematic preset: each part's true median, every scene together and alone."""
    from nao_skin.calibration.engine import calibrate
    from nao_skin.calibration.scenes import scene_labels
    from nao_skin.sim.params import load_params
    from nao_skin.sim.simulate import simulate
    from nao_skin.touch.datasets import deduplicate

    options = replace(CalibrationOptions(), kinematics="on")
    rows = []
    for seed in seeds:
        sim = simulate(skin, load_params("scenes-kinematic", {"n_touches": SIM_TOUCHES}), seed)
        touches, _ = deduplicate(sim.touches)
        labels = scene_labels(touches)
        t0 = time.perf_counter()
        together = calibrate(touches, skin, options, truth=sim.truth).report.final["truth_taxel_error_mm"]
        seconds = time.perf_counter() - t0
        alone = {}
        for name in sorted(set(labels)):
            final = calibrate(touches.subset(labels == name), skin, options, truth=sim.truth).report.final
            for part, v in final["truth_taxel_error_mm"].items():
                alone[part] = max(alone.get(part, 0.0), v["median"])
        rows.append({"seed": seed, "together_mm": {p: v["median"] for p, v in together.items()},
                     "worst_alone_mm": alone, "seconds": seconds})
    say(f"scenes-kinematic, {len(rows)} seeds: worst part together"
        f" {np.mean([max(r['together_mm'].values()) for r in rows]):.2f} mm")
    return rows


def tables(real: list, sim: list) -> list:
    """Markdown lines of the tables and their goals."""
    lines = []
    for row in real:
        lines += [f"Real, kinematics {row['kinematics']}: each scene calibrated alone (test split by pose, seed 0) and"
                  f" predicted from the other two (goal: ratio ≤ {RATIO_GOAL}):", "",
                  "| scene | touches | figure | own test (mm) | predicted (mm) | ratio | met | together (mm) |"
                  " together / own - 1 |", "|---|---|---|---|---|---|---|---|---|"]
        for s in row["scenes"]:
            for f, r in s["ratio"].items():
                worse = s["together_worse"].get(f)
                lines.append(f"| {s['scene']} | {s['touches']} | {f} | {fmt(s['own'][f])} | {fmt(s['predicted'][f])} |"
                             f" {r:.2f} | {'yes' if r <= RATIO_GOAL else 'NOT met'} | {fmt(s['together'].get(f))} |"
                             f" {'–' if worse is None else f'{100 * worse:+.0f} %'} |")
        torso = row["torso_between_mm"]
        lines += ["", f"- the torso from l_hand+torso against the torso from r_finger-torso: {fmt(torso)} mm (goal"
                      f" {TORSO_GOAL_MM:g}: {'met' if torso <= TORSO_GOAL_MM else 'NOT met'})",
                  f"- every scene together: {row['together_seconds']:.2f} s of engine time (goal 2 s); the"
                  f" cross-scene prediction {row['cross_scene_seconds']:.1f} s (goal 6 s)", ""]
        for part, by in row["placement_spread_mm"].items():
            lines.append(f"- placement spread of {part} (median mm from every scene together): "
                         + ", ".join(f"{k} {v:.1f}" for k, v in by.items()))
        lines.append("")
    if sim:
        parts = sorted({p for r in sim for p in r["together_mm"]})
        lines += [f"Simulated, scenes-kinematic, {SIM_TOUCHES} touches per scene, kinematics on, {len(sim)} seeds: each"
                  f" part's true taxel median, mean (max) over the seeds (goal: together ≤ {SIM_GOAL_MM} mm):", "",
                  "| part | every scene together (mm) | the worst scene alone (mm) |", "|---|---|---|"]
        for part in parts:
            tog = [r["together_mm"][part] for r in sim if part in r["together_mm"]]
            alone = [r["worst_alone_mm"][part] for r in sim if part in r["worst_alone_mm"]]
            lines.append(f"| {part} | {fmt(np.mean(tog))} ({fmt(np.max(tog))}) | {fmt(np.mean(alone))}"
                         f" ({fmt(np.max(alone))}) |")
        lines.append("")
    return lines
