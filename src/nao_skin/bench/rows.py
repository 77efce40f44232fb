"""What the benchmark's matrices share: a finished calibration checked, and figures as table cells."""
from __future__ import annotations

import math

import numpy as np

from nao_skin.calibration.engine import CalibrationReport
from nao_skin.model.skin import SkinCalibration


def finite_calibration(calib: SkinCalibration) -> bool:
    return all(np.all(np.isfinite(c.mount)) and np.all(np.isfinite(c.patches)) and np.all(np.isfinite(c.triangles))
               for c in calib.parts.values())


def stage_totals(report: CalibrationReport) -> dict:
    stages = report.stages
    last = stages[-1] if stages else {}
    cond = last.get("condition")
    return {"iterations": int(sum(s.get("iterations", 0) for s in stages)),
            "repairings": int(sum(s.get("repairings", 0) for s in stages)),
            "condition": float(cond) if cond is not None else float("nan")}


def fmt(v, digits=2) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float) and (abs(v) >= 1e4):
        return f"{v:.1e}"
    return f"{v:.{digits}f}" if isinstance(v, float) else str(v)


def median_or_nan(values: list) -> float:
    return float(np.median(values)) if values else float("nan")


def finite_range(values: list) -> list:
    finite = [v for v in values if not math.isnan(v)]
    return [min(finite), max(finite)] if finite else [float("nan"), float("nan")]


def nanmean(values: list) -> float:
    v = [x for x in values if not math.isnan(x)]
    return float(np.mean(v)) if v else float("nan")
