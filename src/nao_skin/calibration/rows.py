"""The one door every kind of row comes through, and the pairing the solver asks for.

Each kind of row is a function ``(context, pair, rules) -> RowBlock`` (:data:`ROW_KINDS`): the skin kinds of
:mod:`~nao_skin.calibration.row_kinds` on a pair of skin parts, the fingertip's (:mod:`~nao_skin.calibration.fingertip`)
on a fingertip scene. :func:`pair_touches` builds the asked kinds of every pair from one
:class:`~nao_skin.calibration.context.FitContext` and assembles their blocks into one
:class:`~nao_skin.calibration.pairing.Pairing`; :func:`pair_step` pairs each part pair of a step on its own
touches, and its fingertip scenes, under one calibration; the rest selects and weights rows and tracks
re-pairing.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from itertools import combinations
from typing import Callable

import numpy as np

from nao_skin.calibration import row_kinds
from nao_skin.calibration.context import FitContext, PlacedSkin, SkinPair
from nao_skin.calibration.fingertip import FingertipScene, fingertip_block, fingertip_scene
from nao_skin.calibration.pairing import (KIND_CONTACT_TAXEL, KIND_COP, KIND_COP_SKIN, KIND_FINGERTIP,
                                          KIND_NAMES, KIND_NORMAL, KIND_PLANE_A, KIND_PLANE_B, KIND_SURFACE,
                                          KIND_TAXEL, KIND_TAXEL5, METRIC_KINDS, METRIC_TAXEL_RULE, Pairing,
                                          RowRules, assemble, concat_pairings)
from nao_skin.calibration.plan import Step
from nao_skin.errors import DataError
from nao_skin.model.skin import SkinCalibration, SkinModel, part_rank
from nao_skin.touch.touches import TouchSet


@dataclass(frozen=True)
class RowKind:
    """A kind of row: its number (:mod:`~nao_skin.calibration.kinds`), what it is built on (a
    :class:`~nao_skin.calibration.context.SkinPair` or a :class:`~nao_skin.calibration.fingertip.FingertipScene`)
    and its builder ``(context, pair, rules) -> RowBlock``."""

    kind: int
    on: type
    build: Callable


# every kind of row, in the order a touch's rows of one pair are put (the solver sums them in that order)
ROW_KINDS = (RowKind(KIND_COP, SkinPair, row_kinds.cop_block),
             RowKind(KIND_TAXEL, SkinPair, row_kinds.taxel_block),
             RowKind(KIND_TAXEL5, SkinPair, row_kinds.taxel5_block),
             RowKind(KIND_PLANE_B, SkinPair, row_kinds.plane_b_block),
             RowKind(KIND_PLANE_A, SkinPair, row_kinds.plane_a_block),
             RowKind(KIND_SURFACE, SkinPair, row_kinds.surface_block),
             RowKind(KIND_COP_SKIN, SkinPair, row_kinds.cop_skin_block),
             RowKind(KIND_CONTACT_TAXEL, SkinPair, row_kinds.contact_taxel_block),
             RowKind(KIND_FINGERTIP, FingertipScene, fingertip_block))


def build_rows(ctx: FitContext, pairs: list, kinds, rules: RowRules = RowRules()) -> Pairing:
    """The rows of ``kinds`` (names or numbers) of every pair in ``pairs`` (skin pairs and fingertip scenes of
    ``ctx``), each kind built on the pairs it is for, in one :class:`Pairing` (:func:`~.pairing.assemble`)."""
    want = {KIND_NAMES[k] if isinstance(k, str) else int(k) for k in kinds}
    return assemble([(number, rank, row_kind.kind, row_kind.build(ctx, pair, rules))
                     for number, pair in enumerate(pairs) for rank, row_kind in enumerate(ROW_KINDS)
                     if row_kind.kind in want and isinstance(pair, row_kind.on)])


def pair_touches(touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None = None,
                 kinds=("cop", "taxel", "taxel5"), parts: tuple | None = None, rules: RowRules = RowRules(),
                 placed: PlacedSkin | None = None) -> Pairing:
    """Pair every touch under ``calib`` (None: nominal layout): the rows of ``kinds`` of every pair of skin parts
    that fire together (``parts``: that pair alone, side A first), made as ``rules`` says. ``placed``: the skin
    already placed under ``calib`` (:class:`~nao_skin.calibration.context.PlacedSkin`)."""
    ctx = FitContext.of(touches, skin, calib, placed)
    return build_rows(ctx, [ctx.skin_pair(pa, pb) for pa, pb in _part_order(touches, parts)], kinds, rules)


def pair_for_metrics(touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None = None,
                     parts: tuple | None = None) -> Pairing:
    """The pairing the reported figures are computed on (:func:`~.pairing.metrics`): the closest COP pair, the
    closest taxel pair among every activated taxel of the two parts (``taxel``), up to 5 closest pairs of the
    selected contacts (``taxel5``) and their closest pair (``contact_taxel``, what the solver fits)."""
    return pair_touches(touches, skin, calib, METRIC_KINDS, parts, RowRules(taxel_rule=METRIC_TAXEL_RULE))


def fingertip_rows(touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None, fingertip: str, part: str,
                   placed: PlacedSkin | None = None) -> Pairing:
    """One row per touch of ``fingertip`` that fires ``part``: its contact nearest the fingertip against the
    fingertip's sphere (:mod:`~nao_skin.calibration.fingertip`)."""
    ctx = FitContext.of(touches, skin, calib, placed)
    return build_rows(ctx, [fingertip_scene(ctx, fingertip, part)], (KIND_FINGERTIP,))


def _part_order(touches: TouchSet, parts) -> list:
    """Ordered (side A, side B) part index pairs: the given pair, or hands before torso/head."""
    if parts is not None:
        missing = [p for p in parts if p not in touches.part_names]
        if len(parts) != 2 or parts[0] == parts[1] or missing:
            raise DataError(f"pairing: parts {tuple(parts)!r} must be two different skin parts of the touch set"
                            f" ({', '.join(touches.part_names)})")
        return [(touches.part_names.index(parts[0]), touches.part_names.index(parts[1]))]
    names = touches.part_names
    rank = sorted(range(len(names)), key=lambda i: part_rank(names[i]))
    return list(combinations(rank, 2))


def select_rows(pairing: Pairing, kinds: tuple, inliers: np.ndarray | None = None) -> Pairing:
    """Rows of the given kinds (and of inlier touches only, if given)."""
    keep = np.isin(pairing.row_kind, kinds)
    if inliers is not None:
        keep &= inliers[pairing.row_touch]
    return pairing.take_rows(keep)

def with_normal_rows(selected: Pairing, pairing: Pairing, weight: float, inliers: np.ndarray | None = None) -> Pairing:
    """``selected`` plus one normal row per closest-taxel row of ``pairing`` (closest-COP
    rows where it has no taxel rows, e.g. in a mount stage).

    Touching surfaces face each other, so the normals at the contact cancel:
    the row is ``weight * (n_A + n_B)`` (``weight`` in metres per radian of
    disagreement), ``n`` the closest taxels' normals or the contacts' mean
    normals. Points alone leave the rotation about a band of contacts nearly
    free; the normals pin it (simulated planar poses: a hand mount 45 degrees
    off fits the points better than the truth, while its normals disagree by
    30 degrees against 0.5 at the truth). A taxel row has two terms against a
    COP row's dozen: the same information for a fraction of the Jacobian.
    """
    if weight <= 0:
        return selected
    source = next((k for k in (KIND_TAXEL, KIND_COP, KIND_COP_SKIN) if np.any(pairing.row_kind == k)), KIND_COP)
    src = select_rows(pairing, (source,), inliers)
    if len(src.row_touch) == 0:
        return selected
    normal = Pairing(row_touch=src.row_touch, row_kind=np.full(len(src.row_touch), KIND_NORMAL, np.int8),
                     row_parts=src.row_parts, term_row=src.term_row, term_part=src.term_part,
                     term_slot=src.term_slot, term_weight=weight * np.abs(src.term_weight),
                     distance=np.full(len(src.row_touch), np.nan))
    return concat_pairings([selected, normal])


def weighted_by_touch(pairing: Pairing, touch_weight: np.ndarray | None) -> Pairing:
    """``pairing`` with each row's terms times its touch's weight (None: as it is)."""
    if touch_weight is None:
        return pairing
    return dataclasses.replace(pairing, term_weight=pairing.term_weight
                               * touch_weight[pairing.row_touch[pairing.term_row]])


def _pair_subset(touches: TouchSet, pa: str, pb: str):
    """The touches where both parts fire, and their rows in ``touches`` (kept: pairing runs
    many times on the same set, and most touches of a multi-pair recording involve other pairs)."""
    def subset():
        fired = touches.parts_of_touch()
        rows = np.flatnonzero(fired[:, touches.part_index(pa)] & fired[:, touches.part_index(pb)])
        return touches.subset(rows), rows
    return touches.derived(("pair subset", pa, pb), subset)

def pair_parts(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, pa: str, pb: str,
               kinds=("cop", "taxel", "taxel5"), rules: RowRules = RowRules(),
               placed: PlacedSkin | None = None) -> Pairing:
    """:func:`pair_touches` for one pair of parts, computed on the touches where both fire only (``rules.press``:
    of every touch of ``touches``)."""
    sub, rows = _pair_subset(touches, pa, pb)
    p = pair_touches(sub, skin, calib, kinds, (pa, pb), rules.on_touches(rows), placed)
    remap = np.array([touches.part_index(n) for n in sub.part_names], dtype=int)
    return dataclasses.replace(p, row_touch=rows[p.row_touch], row_parts=remap[p.row_parts],
                               term_part=remap[p.term_part])


def pair_step(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, step: Step,
              kinds=("cop", "taxel", "taxel5"), rules: RowRules = RowRules()) -> Pairing | None:
    """Pair the touches of every (target, reference) combination of a step, and its fingertip scenes' touches
    (:func:`fingertip_rows`, whatever ``kinds``); None when nothing pairs."""
    names = step.targets + step.references
    parts = []
    placed = PlacedSkin(skin, calib)   # each part's slots placed once for all its part pairs
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if a not in step.targets and b not in step.targets:
                continue
            pa, pb = sorted((a, b), key=part_rank)
            if pa in touches.part_names and pb in touches.part_names:
                p = pair_parts(touches, skin, calib, pa, pb, kinds, rules, placed)
                if len(p.row_touch):
                    parts.append(p)
    for tip, part in step.fingertips:
        p = fingertip_rows(touches, skin, calib, tip, part, placed)
        if len(p.row_touch):
            parts.append(p)
    if not parts:
        return None
    return concat_pairings(parts)


def pairing_key(calib: SkinCalibration) -> tuple:
    """What pairing reads from a calibration, as bytes: equal keys, equal pairings of the same touches.

    Every part's corrections, the kinematic corrections that are not zero (a zero one is the
    robot without it, :meth:`SkinModel.with_kinematics`) and the fingertips' spheres.
    """
    parts = tuple((name, c.mount.tobytes(), c.patches.tobytes(), c.triangles.tobytes())
                  for name, c in sorted(calib.parts.items()))
    return (parts, tuple(sorted((k, float(v)) for k, v in calib.kinematics.items() if v != 0.0)),
            tuple((k, np.asarray(v, float).tobytes()) for k, v in sorted(calib.fingertips.items())))

def touch_hashes(pairing: Pairing, n_touches: int) -> np.ndarray:
    """A number per touch that changes when the pairing of that touch changes."""
    code = (pairing.term_part.astype(float) * 4099.0 + pairing.term_slot + 1.0) * (1.0 + pairing.row_kind[pairing.term_row])
    touch = pairing.row_touch[pairing.term_row]
    return np.bincount(touch, weights=np.sin(code * 0.7071067811865476) * np.sign(pairing.term_weight), minlength=n_touches)
