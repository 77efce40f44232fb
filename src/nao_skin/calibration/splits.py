"""Figures that hold across splits: the same calibration over several seeded train/test splits, mean and spread.

One 70/30 split decides a single run's figures, and on a recording of a few
hundred touches the test figure moves by tenths of a millimetre with the seed
(or with one touch more or less). The spread over repeated seeded splits says
how much of a difference is the split's.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from nao_skin.calibration.engine import CalibrationResult, calibrate
from nao_skin.calibration.evaluation import FIGURES, measured
from nao_skin.calibration.options import CalibrationOptions
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.touches import TouchSet

MAX_SPLITS = 100        # a calibration each: beyond, minutes of work for a spread that no longer moves


def split_spread(touches: TouchSet, skin: SkinModel, options: CalibrationOptions, k: int,
                 prior: SkinCalibration | None = None, first: CalibrationResult | None = None) -> dict:
    """Calibrate on ``k`` splits (seeds ``options.seed`` .. ``+ k - 1``); each final figure's mean, sample
    standard deviation, min and max over them, and the figures of every split.

    ``first``: the calibration already made with ``options.seed``, re-used.
    """
    seeds = [options.seed + i for i in range(k)]
    per_seed = []
    for seed in seeds:
        result = first if first is not None and seed == options.seed else \
            calibrate(touches, skin, replace(options, seed=seed), prior=prior)
        entry = {split: {f: result.report.final[split].get(f, float("nan")) for f in FIGURES}
                 for split in ("train", "test")}
        kin = result.report.kinematics
        if kin:    # kinematics=auto decides on each split's own test touches
            entry["kinematics"] = {"accepted": bool(kin.get("accepted")),
                                   **{f: kin.get("test_taxel_surface_mm", {}).get(f, float("nan"))
                                      for f in ("gain", "gain_low")}}
        per_seed.append(entry)
    out = {"k": k, "seeds": seeds, "kind": f"repeated seeded splits by {options.split_by}",
           "test_fraction": options.test_fraction}
    if any("kinematics" in s for s in per_seed):
        out["kinematics_kept"] = sum(s.get("kinematics", {}).get("accepted", False) for s in per_seed)
    for split in ("train", "test"):
        out[split] = {}
        for f in FIGURES:
            v = np.array([s[split][f] for s in per_seed], dtype=float)
            out[split][f] = {"mean": float(np.mean(v)), "std": float(np.std(v, ddof=1)) if k > 1 else 0.0,
                             "min": float(np.min(v)), "max": float(np.max(v))}
    out["per_seed"] = per_seed
    return out


def kinematics_kept_text(spread: dict) -> str:
    """``kinematics kept on 1 of 5`` when the splits calibrated with the kinematic path, else ''."""
    return f"kinematics kept on {spread['kinematics_kept']} of {spread['k']}" if "kinematics_kept" in spread else ""


def spread_figures(spread: dict) -> list:
    """The figures the splits measured (:data:`~nao_skin.calibration.evaluation.FIGURES`, in order)."""
    return measured({f: spread["train"][f]["mean"] for f in FIGURES})


def spread_text(spread: dict, figure: str) -> str:
    """``mean ± std`` train / test of one figure, e.g. ``4.54 ± 0.05 / 4.50 ± 0.20``."""
    return " / ".join(f"{spread[s][figure]['mean']:.2f} ± {spread[s][figure]['std']:.2f}" for s in ("train", "test"))


def spread_table(spread: dict) -> list:
    """Markdown rows: each figure's train and test mean ± std (min–max) over the splits."""
    lines = ["| figure | train mean ± std (min–max) | test mean ± std (min–max) |", "|---|---|---|"]
    for figure in spread_figures(spread):
        label = FIGURES[figure]
        cells = [f"{spread[s][figure]['mean']:.2f} ± {spread[s][figure]['std']:.2f}"
                 f" ({spread[s][figure]['min']:.2f}–{spread[s][figure]['max']:.2f})" for s in ("train", "test")]
        lines.append(f"| {label} | {cells[0]} | {cells[1]} |")
    return lines
