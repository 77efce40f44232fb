"""Fingertip rows: where a fingertip of the robot pressed a skin part, the part's contact and the fingertip meet.

In a fingertip touch only the pressed part fires. The fingertip is a sphere in its chain's end frame
(:class:`~nao_skin.model.robot.Fingertip`: centre ``c``, radius ``r``, each corrected by the calibration), and
it meets the skin at the fabric surface over the contact. One row per touch::

    row = (COP + fabric * normals) + r * n - T_chain(q) c

``COP`` the pressure-weighted mean of the contact's taxels (the contact of the touch nearest the fingertip, chosen
as pairing chooses the closest COP pair), each taxel lifted by the fabric along its own normal as in every row of
:class:`~nao_skin.calibration.residuals.ResidualModel`, and ``n`` the contact's calibrated mean normal in the base
frame, fixed while the pairing is (as a point-to-plane row's normal, ICP's rule). Side A of the row is the
contact's taxels (terms, as any row's), side B the fingertip: :attr:`Pairing.row_fingertip` names it and
:attr:`Pairing.row_direction` holds ``n``. The distance of a row is the fingertip's contact point (on its sphere,
facing the skin) from the contact's COP at the fabric surface: what a fingertip scene reports.

The rows are built as every kind of row is (:func:`~nao_skin.calibration.rows.pair_touches`): from a fit context
(:class:`~nao_skin.calibration.context.FitContext`), the scene (:class:`FingertipScene`) standing where a pair
of skin parts stands for the others.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nao_skin import se3
from nao_skin.calibration.context import FitContext
from nao_skin.calibration.pairing import RowBlock, RowRules, chain_end_poses
from nao_skin.calibration.segments import argmin_per_group, contact_activations
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.contacts import segment_mean
from nao_skin.touch.touches import TouchSet

DEFAULT_FABRIC = 0.001      # m: a calibration that has not estimated the fabric (CalibrationOptions' default)


def fabric_of(calib: SkinCalibration | None) -> float:
    """The fabric thickness a calibration's fingertip rows lift the taxels by (its estimate, else the default)."""
    return DEFAULT_FABRIC if calib is None or calib.fabric_thickness is None else float(calib.fabric_thickness)


def fingertip_centres(touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None, fingertip: str,
                      rows: np.ndarray | None = None) -> tuple:
    """``(centres (K, 3), radius)``: the fingertip's sphere centre in the base frame in each touch of ``rows``
    (all by default), on the robot ``calib``'s kinematic corrections describe."""
    centre, radius = (calib or SkinCalibration()).fingertip_sphere(skin.robot, fingertip)
    poses = chain_end_poses(touches, skin.with_kinematics(calib), fingertip)
    poses = poses if rows is None else poses[rows]
    return se3.transform_points(poses, centre), radius


@dataclass(frozen=True, eq=False)
class FingertipScene:
    """A fingertip pressing a part, under a fit context's calibration: in each of its touches that fire the part,
    the part's contact nearest the fingertip (as a skin pair selects its closest COPs), with its activations.

    ``touch`` the touches (one row each), ``group``/``act``/``weight`` the selected contacts' activations (the
    row of each, the activation, its COP weight), ``direction`` each contact's mean normal and ``distance`` the
    fingertip's contact point from the contact's COP at the fabric surface (module docstring)."""

    fingertip: int          # index into the touches' fingertips (-1: not among them)
    part: int
    touch: np.ndarray
    group: np.ndarray
    act: np.ndarray
    weight: np.ndarray
    direction: np.ndarray
    distance: np.ndarray

    @property
    def parts(self) -> tuple:
        return (self.part, -1)

    @classmethod
    def select(cls, ctx: FitContext, fingertip: str, part: str) -> "FingertipScene":
        touches = ctx.touches
        if fingertip not in touches.fingertips or part not in touches.part_names:
            return cls._none(-1, -1)
        f, p = touches.fingertips.index(fingertip), touches.part_index(part)
        contacts = np.flatnonzero((touches.contact_part == p)
                                  & (touches.fingertip_of_touch[touches.contact_touch] == f))
        if len(contacts) == 0:
            return cls._none(f, p)
        group, act = contact_activations(touches, contacts)
        weight = ctx.cop_weights[act]
        pos, normals = ctx.positions, ctx.normals
        lifted = segment_mean(pos[act] + fabric_of(ctx.calib) * normals[act], group, len(contacts), weight)
        normal = segment_mean(normals[act], group, len(contacts), weight)
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        touch = touches.contact_touch[contacts]
        centre, radius = (ctx.calib or SkinCalibration()).fingertip_sphere(ctx.skin.robot, fingertip)
        residual = lifted + radius * normal - se3.transform_points(ctx.chain_poses(fingertip)[touch], centre)
        distance = np.linalg.norm(residual, axis=1)
        best = argmin_per_group(touch, distance)          # the contact nearest the fingertip, per touch
        keep = np.isin(group, best)
        row_of = np.full(len(contacts), -1)
        row_of[best] = np.arange(len(best))
        return cls(f, p, touch[best], row_of[group[keep]], act[keep], weight[keep], normal[best], distance[best])

    @classmethod
    def _none(cls, f: int, p: int) -> "FingertipScene":
        z = np.zeros(0, int)
        return cls(f, p, z, z, z, np.zeros(0), np.zeros((0, 3)), np.zeros(0))


def fingertip_scene(ctx: FitContext, fingertip: str, part: str) -> FingertipScene:
    """The scene of ``fingertip`` pressing ``part`` under the context's calibration (kept while it lives)."""
    return ctx.memo(("fingertip scene", fingertip, part), lambda: FingertipScene.select(ctx, fingertip, part))


def fingertip_block(ctx: FitContext, scene: FingertipScene, rules: RowRules) -> RowBlock:
    """One row per touch of the scene: its selected contact's taxels (side A, the COP's weights) against the
    fingertip's sphere (side B, :attr:`~.pairing.Pairing.row_fingertip`, along the contact's normal)."""
    m = len(scene.touch)
    return RowBlock(scene.touch, scene.parts, scene.distance, scene.group, np.full(len(scene.act), scene.part),
                    ctx.touches.act_slot[scene.act], scene.weight, fingertip=np.full(m, scene.fingertip),
                    direction=scene.direction)


def fingertip_pairs(touches: TouchSet) -> dict:
    """``{(fingertip, part): touches}`` of every fingertip and the part its touches fire."""
    f = touches.fingertip_of_touch
    fired = touches.parts_of_touch()
    out = {}
    for i, name in enumerate(touches.fingertips):
        for p, part in enumerate(touches.part_names):
            n = int(np.sum((f == i) & fired[:, p]))
            if n:
                out[(name, part)] = n
    return out


# m: a fingertip presses the taxels of the pressed part within this of its contact point (the point of its sphere
# facing the skin, at the fabric surface): the taxel pitch (about 6 mm) less a little, as a fired skin taxel
# predicts the other part's within PREDICT_RADIUS (calibration.contact)
FINGERTIP_PREDICT_RADIUS = 0.005


def fingertip_firing(touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None, fingertip: str,
                     part: str, radius: float = FINGERTIP_PREDICT_RADIUS) -> tuple:
    """Which taxels of ``part`` the fingertip's sphere predicts fire in its touches, against which did:
    ``(predicted, fired)``, sorted ``touch * S + slot`` codes (``S`` the part's slot count), as
    :func:`~nao_skin.calibration.contact.predicted_firing` gives them for two skins. The fingertip presses where its
    sphere comes nearest the part's fabric surface (its contact point); a taxel is predicted when its fabric surface
    lies within ``radius`` of that point and faces the fingertip."""
    import scipy.spatial

    if fingertip not in touches.fingertips or part not in touches.part_names:
        return np.zeros(0, int), np.zeros(0, int)
    f, p = touches.fingertips.index(fingertip), touches.part_index(part)
    sp = skin.part(part)
    act = np.flatnonzero((touches.act_part == p) & (touches.fingertip_of_touch[touches.act_touch] == f))
    fired = np.unique(touches.act_touch[act] * sp.n_slots + touches.act_slot[act])
    rows = np.unique(touches.act_touch[act])
    if len(rows) == 0:
        return np.zeros(0, int), fired
    pos, nor = sp.taxel_positions(calib.parts.get(part) if calib is not None else None)
    slots = sp.slots
    surface = pos[slots] + fabric_of(calib) * nor[slots]
    tree = scipy.spatial.cKDTree(surface)
    # the sphere's centre in the part's chain-end frame, per touch, and its point nearest the skin
    centre, r = fingertip_centres(touches, skin, calib, fingertip, rows)
    local = se3.transform_points(se3.invert(chain_end_poses(touches, skin.with_kinematics(calib), part)[rows]), centre)
    _, nearest = tree.query(local)
    towards = surface[nearest] - local
    point = local + r * towards / np.maximum(np.linalg.norm(towards, axis=1, keepdims=True), 1e-12)
    near = tree.query_ball_point(point, radius)
    counts = np.array([len(n) for n in near])
    k = np.repeat(np.arange(len(rows)), counts)
    taxel = np.concatenate([np.asarray(n, int) for n in near]) if counts.sum() else np.zeros(0, int)
    facing = np.einsum("ij,ij->i", local[k] - surface[taxel], nor[slots][taxel]) > 0.0
    predicted = np.unique(rows[k[facing]] * sp.n_slots + slots[taxel[facing]])
    return predicted, fired
