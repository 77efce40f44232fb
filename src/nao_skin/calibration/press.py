"""The press model's expectation of a COP row: what two fired areas put between their COPs at the true skin.

A COP row (``cop_skin``) compares the centroids of two fired areas, and at the true skin they do not
coincide: each part samples the pressed spot at its own taxels, the hand's skin curves away from the
touched surface, the pressure falls off differently on the two sides. Measured on the simulator (seed 0,
250 touches per pair, no noise): a row is 1.09 mm long at the true skin (median), and its mean over
redraws of the press's spots at the same poses 0.78 mm: most of it is fixed by the pose, and it moves the
calibration (docs/decisions.md, "The press model's expectation").

:func:`press_offsets` predicts that part for every touch, at a calibration: a spot centred between the
row's two COPs, its radius and the press's reach averaged over :class:`~nao_skin.touch.press.PressModel`,
the hand moved along the touched part's normal until the two skins touch there, each taxel fired by the
simulator's rule (:mod:`nao_skin.touch.press`) unless another contact of the touch fired it. The rows then
fit the COP difference minus that expectation (:attr:`~nao_skin.calibration.pairing.Pairing.row_offset`).
"""
from __future__ import annotations

from functools import partial

import numpy as np

from nao_skin import se3
from nao_skin.calibration.contact import SURFACE_LATERAL
from nao_skin.calibration.kinds import KIND_COP_SKIN
from nao_skin.calibration.layout import ParameterLayout
from nao_skin.calibration.pairing import chain_end_poses
from nao_skin.calibration.plan import Step
from nao_skin.calibration.residuals import ResidualModel
from nao_skin.calibration.rows import pair_step, select_rows
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.press import (PressModel, contact_frame, nearest_lateral, press_pressure, separation,
                                  take_columns)
from nao_skin.touch.touches import TouchSet

CHUNK = 128    # rows per vectorised block (bounds memory at ~CHUNK * NEAREST**2 floats)
# taxels per part and row considered, laterally nearest the contact: a press fires none beyond a spot's radius
# (13 mm at most), and a part's surface within 8 mm of those is what their separation is measured to.
# Measured on the simulator: the same expectations as with the simulator's 96, in half the time
NEAREST = 64


def expected_cop_difference(hand: tuple, touched: tuple, contact: np.ndarray, normal: np.ndarray, fabric: float,
                            model: PressModel = PressModel(), lateral: float = SURFACE_LATERAL) -> np.ndarray:
    """``(R, 3)``: the expected COP of a press on the hand minus that on the touched part, each over its
    taxels with the other's skin beside them (within ``lateral`` in the contact plane; the whole fired area
    where none is), every taxel lifted by ``fabric`` along its normal, as the COP rows measure them.

    ``hand``, ``touched``: ``(positions, normals[, elsewhere])``, positions and normals ``(R, S, 3)`` in the
    base frame, every taxel of the part at each row's pose, ``elsewhere`` ``(R, S)`` the taxels another
    contact of the touch fired (another spot pressed them: not this one's); ``contact`` ``(R, 3)`` the
    spot's centre; ``normal`` ``(R, 3)`` the touched part's outward normal. The expectation is the ratio of
    the expected pressure-weighted sums over the grid of spot radii and reaches (``model``)."""
    out = np.zeros((len(contact), 3))
    radii, reaches = model.radii(), model.reaches()
    for start in range(0, len(contact), CHUNK):
        sl = slice(start, min(start + CHUNK, len(contact)))
        sides = []
        for is_touched, cloud in enumerate((hand, touched)):
            pos, nor = cloud[0][sl], cloud[1][sl]
            free = np.ones(pos.shape[:2], bool) if len(cloud) < 3 else ~cloud[2][sl]
            lat, height = contact_frame(pos, contact[sl], normal[sl])
            facing = np.einsum("nsk,nk->ns", nor, normal[sl]) * (1.0 if is_touched else -1.0) > 0.0
            cols = nearest_lateral(lat, NEAREST)
            sides.append([take_columns(lat, cols), take_columns(height, cols), take_columns(facing, cols),
                          take_columns(pos + fabric * nor, cols), take_columns(free, cols)])
        # the skins as they touch: the hand moved along the normal until its facing taxel nearest the
        # contact lies two fabrics above the touched part's (the calibration may hold them apart)
        surface = []
        for lat, height, facing, *_ in sides:
            nearest = np.argmin(np.where(facing, np.linalg.norm(lat, axis=2), np.inf), axis=1)
            surface.append(np.take_along_axis(height, nearest[:, None], axis=1)[:, 0])
        shift = 2.0 * fabric - (surface[0] - surface[1])
        sides[0][1] = sides[0][1] + shift[:, None]
        sides[0][3] = sides[0][3] + shift[:, None, None] * normal[sl][:, None]
        cops = []
        for is_touched in (0, 1):
            lat, height, _, lifted, free_c = sides[is_touched]
            o_lat, o_height, o_facing, _, _ = sides[1 - is_touched]
            sep, dist = separation(lat, height, o_lat, o_height, o_facing, touched=bool(is_touched))
            slack = sep - 2.0 * fabric
            centre = np.linalg.norm(lat, axis=2)
            weight = np.zeros_like(centre)
            for rho in radii:
                central = 1.0 - (centre / rho) ** 2
                for reach in reaches:
                    depth = 1.0 - slack / reach
                    weight += np.where((central > 0) & (depth > 0), press_pressure(depth, central), 0.0)
            weight = weight * free_c       # a taxel another contact of the touch fired is another spot's
            beside = weight * (dist <= lateral)
            weight = np.where((beside.sum(axis=1) > 0)[:, None], beside, weight)
            total = weight.sum(axis=1)
            cops.append(np.einsum("ns,nsk->nk", weight, lifted) / np.where(total > 0, total, 1.0)[:, None])
        out[sl] = cops[0] - cops[1]
    return out


def _fired_elsewhere(touches: TouchSet, pairing, rows: np.ndarray, part: int, n_slots: int,
                     slots: np.ndarray) -> np.ndarray:
    """``(len(rows), len(slots))``: which of the part's taxels (``slots`` of its ``n_slots``) fired in the row's
    touch but are not among the row's terms: another contact's, another spot's, which the row's spot did not
    press. One row per touch (``rows``: one part pair's)."""
    fired = np.zeros((len(rows), n_slots), bool)
    where = np.full(pairing.n_rows, -1)
    where[rows] = np.arange(len(rows))
    in_touch = np.full(touches.n_touches, -1)
    in_touch[pairing.row_touch[rows]] = np.arange(len(rows))
    mine = (touches.act_part == part) & (in_touch[touches.act_touch] >= 0)
    fired[in_touch[touches.act_touch[mine]], touches.act_slot[mine]] = True
    terms = np.flatnonzero((pairing.term_part == part) & (where[pairing.term_row] >= 0))
    fired[where[pairing.term_row[terms]], pairing.term_slot[terms]] = False
    return fired[:, slots]


def press_offsets(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, fabric: float, parts: tuple,
                  model: PressModel = PressModel()) -> dict:
    """``{(part A, part B): (N, 3)}``: for every touch (N: ``touches``) the press model's expected ``cop_skin``
    row of that part pair (side A minus side B, the touched part), NaN where the pair has no row; the rows as
    the pairing makes them at ``calib``, the robot it describes."""
    names = touches.part_names
    pairing = pair_step(touches, skin, calib, Step(tuple(parts), ()), ("cop_skin",))
    out: dict = {}
    if pairing is None:
        return out
    pairing = select_rows(pairing, (KIND_COP_SKIN,))
    robot = skin.with_kinematics(calib)
    poses = partial(chain_end_poses, touches, robot)
    # each side's COP and the touched side's normal, under calib, without the fabric
    model_rows = ResidualModel(skin, poses, pairing, names, ParameterLayout(skin, tuple(parts), ()), calib)
    x = model_rows.positions(calib)
    w = pairing.term_weight
    side = np.zeros((2, pairing.n_rows, 3))
    for k, sel in enumerate((w > 0, w < 0)):
        for d in range(3):
            side[k, :, d] = np.bincount(pairing.term_row[sel], weights=x[sel, d] * np.abs(w[sel]),
                                        minlength=pairing.n_rows)
    normal = np.zeros((pairing.n_rows, 3))
    touched_terms = np.flatnonzero(w < 0)
    for p in np.unique(pairing.term_part[touched_terms]):
        sel = touched_terms[pairing.term_part[touched_terms] == p]
        _, nor = skin.part(names[p]).taxel_positions(calib.parts.get(names[p]))
        rot = poses(names[p])[pairing.row_touch[pairing.term_row[sel]], :3, :3]
        n_world = np.einsum("kij,kj->ki", rot, nor[pairing.term_slot[sel]]) * -w[sel, None]
        for d in range(3):
            normal[:, d] += np.bincount(pairing.term_row[sel], weights=n_world[:, d], minlength=pairing.n_rows)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    for pa, pb in sorted(set(map(tuple, pairing.row_parts.tolist()))):
        rows = np.flatnonzero((pairing.row_parts[:, 0] == pa) & (pairing.row_parts[:, 1] == pb))
        touch = pairing.row_touch[rows]
        clouds = []
        for p in (pa, pb):
            part = skin.part(names[p])
            pos, nor = part.taxel_positions(calib.parts.get(names[p]))
            fk = poses(names[p])[touch][:, None]
            clouds.append((se3.transform_points(fk, pos[part.slots][None]),
                           se3.rotate_vectors(fk, nor[part.slots][None]),
                           _fired_elsewhere(touches, pairing, rows, p, part.n_slots, part.slots)))
        table = np.full((touches.n_touches, 3), np.nan)
        table[touch] = expected_cop_difference(clouds[0], clouds[1], 0.5 * (side[0, rows] + side[1, rows]),
                                               normal[rows], fabric, model)
        out[(names[pa], names[pb])] = table
    return out
