"""The uncertainty map: each triangle coloured by the calibration's predicted error there.

Every calibration and live update predicts each taxel's RMS error from its own linearised posterior
(:mod:`nao_skin.calibration.uncertainty`); a triangle's value is the median of its taxels'
(``report.json``'s ``final.predicted_triangle_error_mm``). The map shows where the calibration is still
unsure, so where a touch would teach it most. Its colour scale is none of the heat-map's (that one is
viridis-like, grey and red; the guidance magenta): white (sure) through orange to brown, full at
:data:`SCALE_MM`, twice the accuracy target's median. The calibrate node publishes it for RViz; the report
draws it on each part's layout (``uncertainty.png``).
"""
from __future__ import annotations

import numpy as np

SCALE_MM = 1.0                  # full scale of the colours: twice the 0.5 mm accuracy target (median)
_ANCHORS = np.array([[0.97, 0.97, 0.97], [1.0, 0.6, 0.1], [0.45, 0.18, 0.02]])   # white -> orange -> brown
ALPHA = 0.85
LIFT = 0.004                    # m: each disc floats this far above its triangle's taxels (clear of the heat-map)


def colours(values_mm, scale_mm: float = SCALE_MM) -> np.ndarray:
    """(N, 4) RGBA of predicted errors (mm) on the map's scale (0 to ``scale_mm``, clipped)."""
    x = np.clip(np.asarray(values_mm, dtype=float) / scale_mm, 0.0, 1.0)
    at = np.linspace(0.0, 1.0, len(_ANCHORS))
    rgb = np.stack([np.interp(x, at, _ANCHORS[:, c]) for c in range(3)], axis=-1)
    return np.concatenate([rgb, np.full(rgb.shape[:-1] + (1,), ALPHA)], axis=-1)


def colour_map():
    """The same scale as a matplotlib colormap (the report's picture)."""
    from matplotlib.colors import LinearSegmentedColormap

    return LinearSegmentedColormap.from_list("nao_skin_uncertainty", [tuple(a) for a in _ANCHORS])


def triangle_discs(part, triangles: dict) -> list:
    """``[(triangle id, centre, diameter, value mm)]`` of one part's triangles with a predicted value: a flat
    disc over the triangle's taxels in the triangle's own frame (its taxels lie in the frame's x-y plane), so
    a marker drawn with it follows the calibration through TF."""
    slots = part.slots
    rows = part.slot_triangle[slots]
    out = []
    for r, tid in enumerate(part.triangle_ids):
        value = triangles.get(int(tid), triangles.get(str(int(tid))))
        if value is None or not np.any(rows == r):
            continue
        xy = part.taxel_local[slots[rows == r]][:, :2]
        centre = xy.mean(axis=0)
        radius = float(np.max(np.linalg.norm(xy - centre, axis=1)))
        out.append((int(tid), np.array([centre[0], centre[1], LIFT]), 2.0 * radius + 0.004, float(value)))
    return out
