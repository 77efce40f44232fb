"""Pairing for the solver: each part pair paired on its own touches, rows selected, re-pairing tracked."""
from __future__ import annotations

import dataclasses

import numpy as np

from nao_skin.calibration.pairing import (KIND_COP, KIND_COP_SKIN, KIND_NORMAL, KIND_TAXEL, Pairing, PlaneRows,  # noqa: F401
                                          concat_pairings, pair_touches)
from nao_skin.calibration.plan import Step
from nao_skin.model.skin import SkinCalibration, SkinModel, part_rank
from nao_skin.touch.touches import TouchSet


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
               kinds=("cop", "taxel", "taxel5"), taxel_rule: str = "contacts", placed: dict | None = None,
               plane: PlaneRows = PlaneRows(), press: dict | None = None) -> Pairing:
    """``pair_touches`` for one pair of parts, computed on the touches where both fire only
    (``placed``: see :func:`~nao_skin.calibration.pairing.activation_positions`; ``press``: the expected
    ``cop_skin`` rows of every touch of ``touches``, see :func:`~nao_skin.calibration.pairing.pair_touches`)."""
    sub, rows = _pair_subset(touches, pa, pb)
    p = pair_touches(sub, skin, calib, kinds=kinds, parts=(pa, pb), taxel_rule=taxel_rule, placed=placed,
                     plane=plane, press=None if press is None else {k: v[rows] for k, v in press.items()})
    remap = np.array([touches.part_index(n) for n in sub.part_names], dtype=int)
    return dataclasses.replace(p, row_touch=rows[p.row_touch], row_parts=remap[p.row_parts],
                               term_part=remap[p.term_part])

def pair_step(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, step: Step,
               kinds=("cop", "taxel", "taxel5"), plane: PlaneRows = PlaneRows(), press: dict | None = None) -> Pairing:
    """Pair the touches of every (target, reference) combination of a step (``press``: see
    :func:`~nao_skin.calibration.pairing.pair_touches`), and its fingertip scenes' touches
    (:func:`~nao_skin.calibration.fingertip.fingertip_rows`, whatever ``kinds``)."""
    from nao_skin.calibration.fingertip import fingertip_rows

    names = step.targets + step.references
    parts = []
    placed: dict = {}   # each part's slots placed once for all its part pairs
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if a not in step.targets and b not in step.targets:
                continue
            pa, pb = sorted((a, b), key=part_rank)
            if pa in touches.part_names and pb in touches.part_names:
                p = pair_parts(touches, skin, calib, pa, pb, kinds, placed=placed, plane=plane, press=press)
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
