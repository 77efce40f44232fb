"""What a press fires: the rule the simulator fires taxels by, and what a calibration expects of it.

Two touching skins face each other across the fabric gap at a contact point ``c`` with the touched
part's outward normal ``n``. Everything is measured in the contact plane: a taxel's *lateral*
position (two coordinates along :func:`tangent_basis`) and its *height* along ``n``. The other
part's surface under a taxel is its laterally nearest facing taxel (up to :data:`NEIGHBOUR_REACH`
away; farther, the other body is taken to be there without skin, the mirror image). A taxel fires
under a pressure spot of radius ``rho`` when its separation from that surface exceeds the gap by
less than the press's ``reach``; its pressure falls off with that excess and away from the spot's
centre (:func:`press_pressure`).

The simulator draws spots, reach and gap per touch (:mod:`nao_skin.sim.contact`); a calibration
expects a spot centred on the contact with radius and reach uniform over :class:`PressModel`'s
ranges (:func:`nao_skin.calibration.press.expected_cop_difference`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NEAREST = 96             # taxels per part and touch considered (nearest to the contact, laterally)
NEIGHBOUR_REACH = 0.008  # lateral distance (m) up to which the other part's nearest taxel stands for its surface
PRESSURE_MAX = 255.0     # skinManager compensated scale


@dataclass(frozen=True)
class PressModel:
    """The press a calibration expects (m): a spot's radius and how far beyond the fabric gap a taxel
    still fires, each uniform over its range; the simulator's default press (``config/simulation.yaml``,
    ``spot_size`` and ``press_reach``). ``grid``: the points of each range the expectation averages."""

    spot_radius: tuple = (0.007, 0.013)
    reach: tuple = (0.002, 0.005)
    grid: tuple = (8, 4)

    def radii(self) -> np.ndarray:
        return _midpoints(self.spot_radius, self.grid[0])

    def reaches(self) -> np.ndarray:
        return _midpoints(self.reach, self.grid[1])


def _midpoints(span: tuple, n: int) -> np.ndarray:
    return span[0] + (np.arange(n) + 0.5) / n * (span[1] - span[0])


def tangent_basis(normal: np.ndarray):
    """Two unit vectors spanning the plane orthogonal to each ``(N, 3)`` normal."""
    helper = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(normal, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(normal, e1)


def contact_frame(points: np.ndarray, contact: np.ndarray, normal: np.ndarray) -> tuple:
    """``(lateral (N, S, 2), height (N, S))`` of points ``(N, S, 3)`` in each touch's contact plane."""
    e1, e2 = tangent_basis(normal)
    rel = points - contact[:, None]
    lat = np.stack([np.einsum("nsk,nk->ns", rel, e1), np.einsum("nsk,nk->ns", rel, e2)], axis=2)
    return lat, np.einsum("nsk,nk->ns", rel, normal)


def nearest_lateral(lat: np.ndarray, count: int = NEAREST) -> np.ndarray:
    """Per touch, the columns of the ``count`` points laterally nearest the contact, ascending."""
    dist = np.linalg.norm(lat, axis=2)
    count = min(count, dist.shape[1])
    cols = np.argpartition(dist, count - 1, axis=1)[:, :count]
    cols.sort(axis=1)
    return cols


def take_columns(a: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``a`` ``(N, S[, k])`` at the per-touch columns ``cols`` ``(N, C)`` (e.g. :func:`nearest_lateral`'s)."""
    return np.take_along_axis(a, cols if a.ndim == 2 else cols[..., None], axis=1)


def separation(lat: np.ndarray, height: np.ndarray, o_lat: np.ndarray, o_height: np.ndarray,
               o_facing: np.ndarray, touched: bool) -> tuple:
    """``(separation, lateral distance)`` of each point ``(N, S)`` from the other part's surface: the
    height difference to the other part's laterally nearest facing point (the hand's minus the touched
    part's), or the mirror image ``2 |height|`` where none lies within :data:`NEIGHBOUR_REACH`."""
    d = np.linalg.norm(lat[:, :, None] - o_lat[:, None], axis=3)
    d = np.where(o_facing[:, None], d, np.inf)
    nn = np.argmin(d, axis=2)
    dist = np.take_along_axis(d, nn[..., None], axis=2)[..., 0]
    other = np.take_along_axis(o_height, nn, axis=1)
    sep = (other - height) if touched else (height - other)
    return np.where(dist <= NEIGHBOUR_REACH, sep, 2.0 * np.abs(height)), dist


def press_pressure(depth: np.ndarray, central: np.ndarray) -> np.ndarray:
    """Pressure of a firing taxel: ``depth`` (1 at the gap, 0 at the press's reach beyond it) and
    ``central`` (1 at the spot's centre, 0 at its rim)."""
    return np.clip(PRESSURE_MAX * np.minimum(depth, 1.0) * (0.3 + 0.7 * central), 1.0, PRESSURE_MAX)
