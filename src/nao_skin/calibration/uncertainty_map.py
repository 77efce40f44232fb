"""The uncertainty map: each triangle coloured by the calibration's predicted error there.

Every calibration and live update predicts each taxel's RMS error from its own linearised posterior
(:mod:`nao_skin.calibration.uncertainty`); a triangle's value is the median of its taxels'
(``report.json``'s ``final.predicted_triangle_error_mm``). The map shows where the calibration is still
unsure, so where a touch would teach it most. Its colour scale is none of the heat-map's (that one is
viridis-like, grey and red; the guidance magenta): white (sure) through orange to brown, logarithmic from
:data:`LOW_MM` (half the accuracy target's median) to :data:`HIGH_MM`, so that the first updates of a session
(1-3 mm) show where it is unsure as well as the last ones (near the 0.5 mm target) do; a value is white below
the scale and brown above it. The calibrate node publishes it for RViz; the report draws it on each part's
layout (``uncertainty.png``).
"""
from __future__ import annotations

import numpy as np

LOW_MM, HIGH_MM = 0.25, 4.0     # the colours' scale (mm, logarithmic): white at half the 0.5 mm target, brown at 8x it
_ANCHORS = np.array([[0.97, 0.97, 0.97], [1.0, 0.6, 0.1], [0.45, 0.18, 0.02]])   # white -> orange -> brown
ALPHA = 0.85
LIFT = 0.004                    # m: each disc floats this far above its triangle's taxels (clear of the heat-map)


def scale_position(values_mm) -> np.ndarray:
    """Where predicted errors (mm) fall on the map's scale: 0 at :data:`LOW_MM` and below, 1 at :data:`HIGH_MM`
    and above, logarithmic between."""
    v = np.maximum(np.asarray(values_mm, dtype=float), LOW_MM)
    return np.clip(np.log(v / LOW_MM) / np.log(HIGH_MM / LOW_MM), 0.0, 1.0)


def colours(values_mm) -> np.ndarray:
    """(N, 4) RGBA of predicted errors (mm) on the map's scale."""
    x = scale_position(values_mm)
    at = np.linspace(0.0, 1.0, len(_ANCHORS))
    rgb = np.stack([np.interp(x, at, _ANCHORS[:, c]) for c in range(3)], axis=-1)
    return np.concatenate([rgb, np.full(rgb.shape[:-1] + (1,), ALPHA)], axis=-1)


def colour_map():
    """The same scale for matplotlib: ``(colormap, norm)`` (the report's picture)."""
    from matplotlib.colors import LinearSegmentedColormap, LogNorm

    return (LinearSegmentedColormap.from_list("nao_skin_uncertainty", [tuple(a) for a in _ANCHORS]),
            LogNorm(vmin=LOW_MM, vmax=HIGH_MM, clip=True))


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
