"""Fingertip scenes in the bench (pure, no ROS): the real fingertip recordings over splits by pose, and the
simulator's fingertip scenes against the truth, alone and mixed with self-touches.

Real: each recording calibrated on ``REAL_SPLITS`` seeded splits by pose (the default options; the fingertip is
the recording's own, :data:`~nao_skin.paths.REAL_FINGERTIP`); the test split's mean distance from the fingertip
to its contact, mean ± std over the splits, against the goal, and the engine's seconds (median).

Simulated: the fingertip-torso preset at each size, every seed: the torso's true taxel median and the fingertip's
centre from the truth. Mixed: at each size, the fingertip-mixed preset's three scenes (both hands on the torso,
the right fingertip on it) each calibrated alone with that many touches and all three together with that many in
all (a third each): the torso's true median of each.
"""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from nao_skin.bench.rows import fmt
from nao_skin.calibration.engine import CalibrationOptions, calibrate
from nao_skin.model.skin import SkinModel
from nao_skin.paths import REAL_FINGERTIP

REAL_SPLITS = 5
# issue 61's goals: the test split's fingertip distance (mm) of each real recording, its seconds a calibration
REAL_GOALS_MM = {"r_finger_torso.legacy.txt": 2.8, "r_finger_l_hand.legacy.txt": 4.1}
SECONDS_GOAL = 0.5
SIM_SIZES = (250, 1000)
MIXED_SCENES = (("r_hand", "torso"), ("l_hand", "torso"), ("r_finger", "torso"))


def real_rows(directory: Path, layouts: dict, options: CalibrationOptions | None = None, say=print) -> list:
    """A row per real fingertip recording in ``directory`` (read with ``layouts``: part -> taxel file)."""
    from nao_skin.formats.inputs import Inputs, load_touches
    from nao_skin.model.skin import load_skin
    from nao_skin.touch.datasets import deduplicate

    options = options or CalibrationOptions()
    rows = []
    for name, (tip, part) in REAL_FINGERTIP.items():
        path = str(Path(directory) / name)
        skin = load_skin(taxel_files={part: layouts[part]})
        touches, _, _ = load_touches(Inputs((path,), {path: tip}), skin, log=lambda m: None)
        touches, n_dup = deduplicate(touches)
        train, test, seconds = [], [], []
        for seed in range(REAL_SPLITS):
            result = calibrate(touches, skin, replace(options, seed=seed))
            train.append(result.report.final["train"]["fingertip_mean_mm"])
            test.append(result.report.final["test"]["fingertip_mean_mm"])
            seconds.append(result.report.total_seconds)
        row = {"recording": name, "fingertip": tip, "part": part, "touches": touches.n_touches, "duplicates": n_dup,
               "train_mm": float(np.mean(train)), "train_std": float(np.std(train, ddof=1)),
               "test_mm": float(np.mean(test)), "test_std": float(np.std(test, ddof=1)),
               "seconds": float(np.median(seconds)), "goal_mm": REAL_GOALS_MM[name]}
        row["met"] = row["test_mm"] <= row["goal_mm"] and row["seconds"] <= SECONDS_GOAL
        say(f"{name}: test {row['test_mm']:.2f} ± {row['test_std']:.2f} mm over {REAL_SPLITS} splits,"
            f" {row['seconds']:.2f} s")
        rows.append(row)
    return rows


def sim_rows(skin: SkinModel, seeds, sizes=SIM_SIZES, say=print) -> list:
    """A row per size and seed of the fingertip-torso preset: the torso's true median, the fingertip's errors."""
    from nao_skin.sim.params import load_params
    from nao_skin.sim.simulate import simulate
    from nao_skin.touch.datasets import deduplicate

    rows = []
    for n in sizes:
        for seed in seeds:
            sim = simulate(skin, load_params("fingertip-torso", {"n_touches": n}), seed)
            touches, _ = deduplicate(sim.touches)
            t0 = time.perf_counter()
            final = calibrate(touches, skin, CalibrationOptions(), truth=sim.truth).report.final
            tip = final["truth_fingertip_error_mm"]["r_finger"]
            rows.append({"touches": n, "seed": seed, "torso_mm": final["truth_taxel_error_mm"]["torso"]["median"],
                         "centre_mm": tip["centre"], "radius_mm": tip["radius"],
                         "test_mm": final["test"]["fingertip_median_mm"], "seconds": time.perf_counter() - t0})
        say(f"fingertip-torso, {n} touches: torso true median"
            f" {np.mean([r['torso_mm'] for r in rows if r['touches'] == n]):.3f} mm over {len(seeds)} seeds")
    return rows


def mixed_rows(skin: SkinModel, seeds, sizes=SIM_SIZES, say=print) -> list:
    """A row per size and seed: the torso's true median calibrated from the self-touches alone, the fingertip's
    touches alone and the three scenes mixed, each with ``size`` touches in all."""
    from nao_skin.sim.params import load_params
    from nao_skin.sim.simulate import simulate
    from nao_skin.touch.datasets import deduplicate

    rows = []
    for n in sizes:
        for seed in seeds:
            # one simulation of every scene (the same truth), each pair with all the touches a kind alone needs
            sim = simulate(skin, load_params("fingertip-mixed", {"n_touches": n}), seed)
            touches, _ = deduplicate(sim.touches)
            pair = touches.labels["pair"]
            rng = np.random.default_rng(seed)
            own = {}
            for kind, scenes, share in (("self", ("r_hand-torso", "l_hand-torso"), n // 2),
                                        ("fingertip", ("r_finger-torso",), n), ("mixed", None, n // 3)):
                rows_of = [np.flatnonzero(pair == s) for s in (scenes or [f"{h}-{p}" for h, p in MIXED_SCENES])]
                keep = np.sort(np.concatenate([rng.choice(r, min(share, len(r)), replace=False) for r in rows_of]))
                final = calibrate(touches.subset(keep), skin, CalibrationOptions(), truth=sim.truth).report.final
                own[kind] = final["truth_taxel_error_mm"]["torso"]["median"]
            rows.append({"touches": n, "seed": seed, **{f"{k}_mm": v for k, v in own.items()}})
        done = [r for r in rows if r["touches"] == n]
        say(f"mixed, {n} touches: torso true median self {np.mean([r['self_mm'] for r in done]):.3f}, fingertip"
            f" {np.mean([r['fingertip_mm'] for r in done]):.3f}, mixed {np.mean([r['mixed_mm'] for r in done]):.3f} mm")
    return rows


def tables(real: list, sim: list, mixed: list) -> list:
    """Markdown lines of the three tables and their goals."""
    lines = []
    if real:
        lines += [f"Real recordings, the default calibration over {REAL_SPLITS} seeded splits by pose (30 % test):", "",
                  "| recording | touches | fingertip to its contact, train (mm) | test (mm) | goal (mm) | seconds |"
                  " met |", "|---|---|---|---|---|---|---|"]
        lines += [f"| {r['recording']} | {r['touches']} | {fmt(r['train_mm'])} ± {fmt(r['train_std'])} |"
                  f" {fmt(r['test_mm'])} ± {fmt(r['test_std'])} | {r['goal_mm']:g} | {r['seconds']:.2f} |"
                  f" {'yes' if r['met'] else 'NOT met'} |" for r in real]
        lines.append("")
    if sim:
        lines += ["Simulated, fingertip-torso (the right fingertip alone on the torso), mean over the seeds (min–max):",
                  "", "| touches | seeds | torso true median (mm) | fingertip centre off (mm) | radius off (mm) |"
                  " test fingertip median (mm) | seconds |", "|---|---|---|---|---|---|---|"]
        for n in sorted({r["touches"] for r in sim}):
            rs = [r for r in sim if r["touches"] == n]
            cells = [f"{fmt(np.mean(v))} ({fmt(np.min(v))}–{fmt(np.max(v))})" for v in
                     ([r[k] for r in rs] for k in ("torso_mm", "centre_mm", "radius_mm", "test_mm"))]
            lines.append(f"| {n} | {len(rs)} | " + " | ".join(cells) + f" | {np.median([r['seconds'] for r in rs]):.2f} |")
        lines.append("")
    if mixed:
        lines += ["Self-touches, fingertip touches and both, the same number of touches in all (the torso's true median,"
                  " mm, mean over the seeds; mixed no worse than either alone in how many seeds):", "",
                  "| touches | seeds | self-touches alone | fingertip alone | mixed | mixed <= both alone |",
                  "|---|---|---|---|---|---|"]
        for n in sorted({r["touches"] for r in mixed}):
            rs = [r for r in mixed if r["touches"] == n]
            ok = sum(r["mixed_mm"] <= min(r["self_mm"], r["fingertip_mm"]) for r in rs)
            lines.append(f"| {n} | {len(rs)} | " + " | ".join(fmt(np.mean([r[k] for r in rs])) for k in
                                                              ("self_mm", "fingertip_mm", "mixed_mm")) + f" | {ok} of {len(rs)} |")
        lines.append("")
    return lines
