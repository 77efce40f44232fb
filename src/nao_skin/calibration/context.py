"""What every kind of row is built from: the touches under one calibration, computed once (a fit context).

Pairing touches under a calibration takes the activations' base-frame positions (and, for some kinds, their
normals), each contact's COP, the chain-end poses on the robot the calibration's kinematic corrections
describe, and per pair of skin parts the contact pair each touch selects (the closest COPs) with their
activations. A :class:`FitContext` computes each of these once, when a kind of row first asks, and every kind
reads them from it (:mod:`~nao_skin.calibration.row_kinds`, :mod:`~nao_skin.calibration.fingertip`). A
:class:`PlacedSkin` holds what does not depend on the touches (each part's slots placed under the calibration),
shared by the contexts of one calibration: a step pairs each part pair on its own touches.

A touch set keeps the contexts of the last :data:`CONTEXTS_KEPT` calibrations it was paired under: a stage ends
where its cost is measured, its touches set aside and the next stage starts, and the figures of that
calibration are measured on the same touches, each pairing the touches under it again.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from nao_skin import se3
from nao_skin.calibration.pairing import chain_end_poses
from nao_skin.calibration.segments import (argmin_per_group, contact_activations, cross_pairs, gathered_distances,
                                           segment_max)
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.contacts import activations_by_part, cop_weights, segment_mean
from nao_skin.touch.touches import TouchSet


# the contexts a touch set keeps, of the calibrations it was paired under last
CONTEXTS_KEPT = 3


def calibration_key(calib: SkinCalibration | None) -> tuple | None:
    """What a fit context reads from a calibration, as bytes: equal keys, equal contexts of the same touches.

    Every part's corrections, the kinematic corrections that are not zero (a zero one is the robot without it,
    :meth:`SkinModel.with_kinematics`), the fingertips' spheres and the fabric (a fingertip's rows lift the taxels
    by it); None for the nominal skin."""
    if calib is None:
        return None
    parts = tuple((name, c.mount.tobytes(), c.patches.tobytes(), c.triangles.tobytes())
                  for name, c in sorted(calib.parts.items()))
    return (parts, tuple(sorted((k, float(v)) for k, v in calib.kinematics.items() if v != 0.0)),
            tuple((k, np.asarray(v, float).tobytes()) for k, v in sorted(calib.fingertips.items())),
            calib.fabric_thickness)


class PlacedSkin:
    """A skin under one calibration (None: nominal): each part's slots placed in its chain-end frame, computed
    once per part when first asked, on the robot the calibration's kinematic corrections describe. It keeps a
    copy of the calibration: what it computed stays that calibration's whatever happens to the one it was given."""

    def __init__(self, skin: SkinModel, calib: SkinCalibration | None = None):
        self.skin = skin
        self.calib = None if calib is None else calib.copy()
        self.robot_skin = skin.with_kinematics(calib)
        self._slots: dict = {}

    def correction(self, part: str):
        return self.calib.parts.get(part) if self.calib is not None else None

    def slots(self, part: str) -> tuple:
        """``(positions, normals)`` ``(S, 3)`` of every slot of ``part`` in its chain-end frame (NaN: no taxel)."""
        hit = self._slots.get(part)
        if hit is None:
            hit = self._slots[part] = self.skin.part(part).taxel_positions(self.correction(part))
        return hit

    def slot_coordinates(self, part: str) -> np.ndarray:
        """``(3, S)``: :meth:`slots`' positions coordinate first (how the activations gather them)."""
        key = (part, "coordinates")
        hit = self._slots.get(key)
        if hit is None:
            hit = self._slots[key] = np.ascontiguousarray(self.slots(part)[0].T)
        return hit


class FitContext:
    """The touches under one calibration, as every kind of row reads them (module docstring). Each quantity is
    computed when first asked and kept while the context lives; so are the per-pair selections
    (:meth:`skin_pair`) and whatever a kind keeps with :meth:`memo`."""

    def __init__(self, touches: TouchSet, placed: PlacedSkin):
        self.touches = touches
        self.placed = placed
        self._memo: dict = {}

    @classmethod
    def of(cls, touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None = None,
           placed: PlacedSkin | None = None) -> "FitContext":
        """The context of ``touches`` under ``calib``: the one the touches keep for that calibration (module
        docstring), else a new one, kept. ``placed``: the skin already placed under it (shared with other touch
        sets paired under the same calibration)."""
        kept = touches.derived(("fit contexts",), OrderedDict, (skin,))
        key = calibration_key(calib)
        ctx = kept.get(key)
        if ctx is None:
            ctx = kept[key] = cls(touches, placed if placed is not None else PlacedSkin(skin, calib))
            if len(kept) > CONTEXTS_KEPT:
                kept.popitem(last=False)
        else:
            kept.move_to_end(key)
        return ctx

    @property
    def skin(self) -> SkinModel:
        return self.placed.skin

    @property
    def calib(self) -> SkinCalibration | None:
        return self.placed.calib

    def memo(self, key: tuple, compute):
        """``compute()`` once per ``key`` while this context lives."""
        if key not in self._memo:
            self._memo[key] = compute()
        return self._memo[key]

    def chain_poses(self, name: str) -> np.ndarray:
        """(N, 4, 4) chain-end pose of a part (or fingertip) in every touch, on the robot the calibration describes."""
        return chain_end_poses(self.touches, self.placed.robot_skin, name)

    # ------------------------------------------------------------------ activations
    @cached_property
    def coordinates(self) -> np.ndarray:
        """(3, A) calibrated base-frame position of every activated taxel, coordinate first (the pairing gathers
        one coordinate at a time: 1-D gathers are ~4x faster than gathering (A, 3) rows)."""
        touches = self.touches
        parts, rows = _slot_rows(touches, self.skin)
        if not parts:
            return np.zeros((3, 0))
        rot, trans = _activation_chains(touches, self.placed.robot_skin)
        local = np.concatenate([self.placed.slot_coordinates(name) for name in parts], axis=1)
        return se3.transform_coordinates(rot, np.stack([np.take(row, rows) for row in local]), trans)

    @property
    def positions(self) -> np.ndarray:
        """(A, 3) calibrated base-frame position of every activated taxel (a view of :attr:`coordinates`)."""
        return self.coordinates.T

    @cached_property
    def normals(self) -> np.ndarray:
        """(A, 3) calibrated base-frame normal of every activated taxel."""
        parts, rows = _slot_rows(self.touches, self.skin)
        if not parts:
            return np.zeros((0, 3))
        rot, _ = _activation_chains(self.touches, self.placed.robot_skin)
        local = np.concatenate([self.placed.slots(name)[1] for name in parts]).T
        return se3.transform_coordinates(rot, np.stack([np.take(row, rows) for row in local])).T

    @property
    def cop_weights(self) -> np.ndarray:
        """(A,) weight of each activation in its contact's COP (each contact's sum to 1)."""
        return cop_weights(self.touches)

    @cached_property
    def cops(self) -> np.ndarray:
        """(C, 3) base-frame COP of every contact."""
        return segment_mean(self.positions, self.touches.act_contact, len(self.touches.contact_touch),
                            self.cop_weights)

    @cached_property
    def contact_radius(self) -> np.ndarray:
        """(C,) how far a contact's taxels lie from its COP at most: bounds every taxel distance of a contact pair."""
        act_contact = self.touches.act_contact
        return segment_max(se3.vector_norms(self.positions - self.cops[act_contact]), act_contact,
                           len(self.touches.contact_touch))

    def taxel_distances(self, act_a: np.ndarray, act_b: np.ndarray) -> np.ndarray:
        """Distance between the activations ``act_a[i]`` and ``act_b[i]``, for every ``i``."""
        return gathered_distances(self.coordinates, act_a, self.coordinates, act_b)

    # ------------------------------------------------------------------ pairs
    def skin_pair(self, pa: int, pb: int) -> "SkinPair":
        """The contact pair each touch of parts ``pa`` and ``pb`` selects (:class:`SkinPair`)."""
        return self.memo(("skin pair", pa, pb), lambda: SkinPair.select(self, pa, pb))


@dataclass(frozen=True, eq=False)
class SkinPair:
    """Part A and part B (indices into the touches' part names) in the touches where both fire: every contact
    pair of a touch (``contacts_a``, ``contacts_b``, their COPs ``cop_distances`` apart) and per touch the
    closest of them (``selected_a``, ``selected_b``, ``cop_distance`` apart), one group per touch of ``touch``,
    with the selected contacts' activations (``group_a``, ``act_a``: each activation of A's selected contact and
    its group; ``group_b``, ``act_b`` B's)."""

    context: FitContext
    pa: int
    pb: int
    contacts_a: np.ndarray
    contacts_b: np.ndarray
    cop_distances: np.ndarray
    selected_a: np.ndarray
    selected_b: np.ndarray
    cop_distance: np.ndarray
    touch: np.ndarray
    group_a: np.ndarray
    act_a: np.ndarray
    group_b: np.ndarray
    act_b: np.ndarray

    @classmethod
    def select(cls, ctx: FitContext, pa: int, pb: int) -> "SkinPair":
        touches = ctx.touches
        fires = touches.parts_of_touch()
        both = fires[:, pa] & fires[:, pb]
        ca = np.flatnonzero((touches.contact_part == pa) & both[touches.contact_touch])
        cb = np.flatnonzero((touches.contact_part == pb) & both[touches.contact_touch])
        ia, ib = cross_pairs(touches.contact_touch[ca], touches.contact_touch[cb])
        contacts_a, contacts_b = ca[ia], cb[ib]
        cop_distances = se3.vector_norms(ctx.cops[contacts_a] - ctx.cops[contacts_b])
        best = argmin_per_group(touches.contact_touch[contacts_a], cop_distances)
        selected_a, selected_b = contacts_a[best], contacts_b[best]
        return cls(ctx, pa, pb, contacts_a, contacts_b, cop_distances, selected_a, selected_b, cop_distances[best],
                   touches.contact_touch[selected_a], *contact_activations(touches, selected_a),
                   *contact_activations(touches, selected_b))

    @property
    def parts(self) -> tuple:
        return (self.pa, self.pb)

    @cached_property
    def taxel_pairs(self) -> tuple:
        """Every taxel pair of the selected contacts (one taxel per side), grouped: ``(group, A activation,
        B activation, distance)``."""
        return self.candidates(self.group_a, self.act_a, self.group_b, self.act_b)

    @cached_property
    def closest(self) -> np.ndarray:
        """The closest of :attr:`taxel_pairs` in each group (indices into them)."""
        return argmin_per_group(self.taxel_pairs[0], self.taxel_pairs[3])

    def candidates(self, group_a, act_a, group_b, act_b) -> tuple:
        """Every pair of an activation of ``act_a`` and one of ``act_b`` in the same group, grouped:
        ``(group, A activation, B activation, distance)``."""
        i, j = cross_pairs(group_a, group_b)
        a, b = act_a[i], act_b[j]
        return group_a[i], a, b, self.context.taxel_distances(a, b)


def _activation_chains(touches: TouchSet, skin: SkinModel) -> tuple:
    """``(R, t)`` of the chain end of every activation, coordinate first: ``R[i, j]`` and ``t[i]`` are
    contiguous rows over the activations (:func:`se3.transform_coordinates`)."""
    def gather():
        rot = np.full((3, 3, len(touches.act_slot)), np.nan)
        trans = np.full((3, len(touches.act_slot)), np.nan)
        for name, sel in zip(touches.part_names, activations_by_part(touches)):   # <= 4 parts
            if len(sel):
                rot[:, :, sel], trans[:, sel] = se3.split_coordinates(
                    chain_end_poses(touches, skin, name)[touches.act_touch[sel]])
        return rot, trans
    return touches.derived(("activation chains",), gather, (skin,))


def _slot_rows(touches: TouchSet, skin: SkinModel) -> tuple:
    """``(parts, rows)``: the parts that fire, and the row of every activation's slot in their slot tables
    placed one after the other (``parts`` order)."""
    def rows():
        parts = [name for name, sel in zip(touches.part_names, activations_by_part(touches)) if len(sel)]
        first = np.cumsum([0] + [skin.part(name).n_slots for name in parts])
        offset = np.zeros(len(touches.part_names), int)
        for k, name in enumerate(parts):
            offset[touches.part_names.index(name)] = first[k]
        return parts, offset[touches.act_part] + touches.act_slot
    return touches.derived(("activation slot rows",), rows, (skin,))


def activation_positions(touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None = None) -> np.ndarray:
    """(A, 3) calibrated position of every activated taxel in the base frame (:attr:`FitContext.positions`)."""
    return FitContext.of(touches, skin, calib).positions


def activation_normals(touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None = None) -> np.ndarray:
    """(A, 3) calibrated base-frame normal of every activated taxel (:attr:`FitContext.normals`)."""
    return FitContext.of(touches, skin, calib).normals
