"""Which points must coincide in a self-touch (thesis §2.3, §3.2.2), for all touches at once.

For every touch and every pair of skin parts that fire in it, the pairing
chooses, under the current calibration:

* kind 0 - the closest pair of contact COPs, one contact on each part;
* kind 1 - the closest pair of activated taxels of those two contacts;
* kind 2 - up to 5 closest taxel pairs of those two contacts, greedily, each
  taxel used once (eq. 2.5: L = min(5, P, Q));
* kinds 5 and 6 - point-to-plane rows (as in ICP): every activated taxel of
  one selected contact with the closest activated taxel of the other, only the
  distance along that taxel's normal counting (``Pairing.row_normal``). The
  two taxel lattices are offset tangentially by up to half a taxel spacing, so
  a closest taxel pair is millimetres apart even at the true calibration;
  along the normal that offset does not count. Kind 5 takes side A's taxels to
  B's surface, kind 6 B's to A's.

Kinds 1 and 2 are what the solver fits. The reported closest taxel pair
(:func:`pair_for_metrics`) is searched among every activated taxel of the two
parts in the touch instead (``taxel_rule="touch"``), as the closest COP pair
is among every contact: a figure that does not depend on which contacts this
pairing selected. Kind 4 reports the fitted pair beside it; kind 2 stays the
selected contacts' (eq. 2.5 counts their taxels).

Each choice becomes a residual row ``point_A - point_B`` whose points are
weighted sums of taxel positions (a COP is the weighted mean of its
contact's taxels), so a solver can re-evaluate the same rows under new
parameters without re-pairing, and re-pairing itself is a few vectorised
passes over all touches (segment minima with ``lexsort``), cheap enough to
repeat after every calibration step.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace
from itertools import combinations

import numpy as np

from nao_skin import se3
from nao_skin.calibration.contact import skin_beside, surface_rows, touch_weights
from nao_skin.calibration.kinds import (KIND_CONTACT_TAXEL, KIND_COP, KIND_COP_SKIN, KIND_FINGERTIP,  # noqa: F401
                                        KIND_NORMAL, KIND_PLANE_A, KIND_PLANE_B, KIND_SURFACE, KIND_TAXEL,
                                        KIND_TAXEL5, PLANE_WEIGHTS)
from nao_skin.errors import DataError
from nao_skin.model.skin import SkinCalibration, SkinModel, part_rank
from nao_skin.touch.contacts import activations_by_part, cop_weights, segment_mean
from nao_skin.touch.touches import TouchSet

KIND_NAMES = {"cop": KIND_COP, "taxel": KIND_TAXEL, "taxel5": KIND_TAXEL5, "contact_taxel": KIND_CONTACT_TAXEL,
              "plane_b": KIND_PLANE_B, "plane_a": KIND_PLANE_A, "surface": KIND_SURFACE,
              "cop_skin": KIND_COP_SKIN, "fingertip": KIND_FINGERTIP}
# the rows that say where a touch's contact lies against what touched it: the closest COP pair of two skins, a
# fingertip's contact (the gate, the first guess and the cost that judges one measure touches by them)
COP_LIKE = (KIND_COP, KIND_FINGERTIP)
TAXEL_RULES = ("contacts", "thesis", "touch")
METRIC_KINDS = ("cop", "taxel", "taxel5", "contact_taxel")
METRIC_TAXEL_RULE = "touch"
MAX_TAXEL_PAIRS = 5
DEFAULT_COP_RADIUS = 0.012   # thesis rule: taxel of B searched within this distance of COP_B (m)


@dataclass(frozen=True)
class PlaneRows:
    """How point-to-plane rows (kinds 5, 6) are weighted: by ``weight`` (:data:`PLANE_WEIGHTS`) times ``scale``."""

    weight: str = "touch"
    scale: float = 1.0


@dataclass
class Pairing:
    """Residual rows: each row is (point on side A) - (point on side B), each point a weighted sum of taxel positions."""
    row_touch: np.ndarray     # (M,) int touch row
    row_kind: np.ndarray      # (M,) int8: 0 = closest COP pair, 1 = closest taxel pair, 2 = one of up to 5 closest
                              # taxel pairs, 4 = closest taxel pair of the selected contacts (see KIND_*)
    row_parts: np.ndarray     # (M, 2) int: part index (into touches.part_names) of side A and side B
    term_row: np.ndarray      # (K,) int residual row of each term, sorted ascending
    term_part: np.ndarray     # (K,) int part index
    term_slot: np.ndarray     # (K,) int taxel slot
    term_weight: np.ndarray   # (K,) float: +w on side A, -w on side B; each side's |w| sum to 1
    distance: np.ndarray      # (M,) float metres, under the calibration used for pairing
    # (M, 3) unit normal along which a row is measured (point-to-plane rows), NaN for rows measured in
    # full; None when no row is projected
    row_normal: np.ndarray | None = None
    # (M, 3) what a row is expected to be at the true skin (the press model's, calibration/press.py), subtracted
    # from it; None when no row has one
    row_offset: np.ndarray | None = None
    # (M,) int: the fingertip (index into the touches' ``fingertips``) whose contact sphere is side B of a fingertip
    # row (:mod:`~nao_skin.calibration.fingertip`), -1 for rows of two skin parts; None when no row has one
    row_fingertip: np.ndarray | None = None
    # (M, 3) unit normal of the pressed skin at a fingertip row's contact, fixed while the pairing is: the
    # sphere's centre lies its radius along it (NaN for other rows); None when no row has one
    row_direction: np.ndarray | None = None

    @property
    def n_rows(self) -> int:
        return len(self.row_touch)

    def take_rows(self, keep: np.ndarray) -> "Pairing":
        """The rows ``keep`` (a boolean mask, in order) with their terms."""
        new_index = np.cumsum(keep) - 1
        tkeep = keep[self.term_row]
        extras = {name: _optional(getattr(self, name)[keep], fill) for name, fill in ROW_EXTRAS.items()
                  if getattr(self, name) is not None}
        return Pairing(row_touch=self.row_touch[keep], row_kind=self.row_kind[keep], row_parts=self.row_parts[keep],
                       term_row=new_index[self.term_row[tkeep]], term_part=self.term_part[tkeep],
                       term_slot=self.term_slot[tkeep], term_weight=self.term_weight[tkeep],
                       distance=self.distance[keep], **extras)


# the optional per-row arrays of a Pairing, each with what it holds on a row without one (None: no row has one)
ROW_EXTRAS = {"row_normal": np.nan, "row_offset": 0.0, "row_fingertip": -1, "row_direction": np.nan}


def _optional(values: np.ndarray, fill) -> np.ndarray | None:
    """``values`` of an optional row array, None when every row holds ``fill`` (no row has one)."""
    if isinstance(fill, float) and np.isnan(fill):
        return values if np.isfinite(values).any() else None
    return values if np.any(values != fill) else None


def row_extra(pairing: Pairing, name: str) -> np.ndarray:
    """Optional row array ``name`` of ``pairing`` (:data:`ROW_EXTRAS`) on every row, filled where it has none."""
    value = getattr(pairing, name)
    if value is not None:
        return value
    shape = (pairing.n_rows,) if name == "row_fingertip" else (pairing.n_rows, 3)
    return np.full(shape, ROW_EXTRAS[name], dtype=int if name == "row_fingertip" else float)


def concat_pairings(pairings: list) -> Pairing:
    """The rows of every pairing, one after the other (term rows renumbered)."""
    if len(pairings) == 1:
        return pairings[0]
    offs = np.cumsum([0] + [len(p.row_touch) for p in pairings[:-1]])
    extras = {name: _optional(np.concatenate([row_extra(p, name) for p in pairings]), fill)
              for name, fill in ROW_EXTRAS.items() if any(getattr(p, name) is not None for p in pairings)}
    return Pairing(
        row_touch=np.concatenate([p.row_touch for p in pairings]),
        row_kind=np.concatenate([p.row_kind for p in pairings]),
        row_parts=np.concatenate([p.row_parts for p in pairings]),
        term_row=np.concatenate([p.term_row + o for p, o in zip(pairings, offs)]),
        term_part=np.concatenate([p.term_part for p in pairings]),
        term_slot=np.concatenate([p.term_slot for p in pairings]),
        term_weight=np.concatenate([p.term_weight for p in pairings]),
        distance=np.concatenate([p.distance for p in pairings]), **extras)


# ---------------------------------------------------------------------- segment helpers
def _cross_pairs(group_a: np.ndarray, group_b: np.ndarray) -> tuple:
    """All ``(i, j)`` with ``group_a[i] == group_b[j]``, without a loop over groups."""
    if np.all(group_b[1:] >= group_b[:-1]):      # activations and contacts are stored grouped: no sort
        order_b, sorted_b = np.arange(len(group_b)), group_b
    else:
        order_b = np.argsort(group_b, kind="stable")
        sorted_b = group_b[order_b]
    start = np.searchsorted(sorted_b, group_a, side="left")
    return _runs(order_b, start, np.searchsorted(sorted_b, group_a, side="right") - start)


def _runs(order: np.ndarray, start: np.ndarray, count: np.ndarray) -> tuple:
    """``(k, order[start[k] + i])`` for every ``k`` and ``i < count[k]``: the rows of runs in a sorted order."""
    k = np.repeat(np.arange(len(start)), count)
    offset = np.arange(len(k)) - np.repeat(np.cumsum(count) - count, count)
    return k, order[np.repeat(start, count) + offset]


def _argmin_per_group(group: np.ndarray, key: np.ndarray) -> np.ndarray:
    """Index of the smallest ``key`` in each group (ties: lowest index), ordered by group."""
    if len(group) == 0:
        return np.zeros(0, dtype=int)
    key = np.asarray(key, dtype=float)
    new_group = group[1:] != group[:-1]
    if np.all(group[1:] >= group[:-1]) and not np.isnan(key).any():
        # already grouped (pairs of one touch or contact are built together): no sort needed
        starts = np.flatnonzero(np.concatenate(([True], new_group)))
        segment = np.cumsum(np.concatenate(([0], new_group)))
        cand = np.flatnonzero(key == np.minimum.reduceat(key, starts)[segment])
        return cand[np.concatenate(([True], segment[cand][1:] != segment[cand][:-1]))]
    # one stable argsort of "group + key scaled into [0, 1)" instead of a three-key lexsort
    span = float(np.max(key) - np.min(key)) if len(key) else 0.0
    scaled = (key - np.min(key)) / (span * (1.0 + 1e-9)) if span > 0 else np.zeros_like(key)
    order = np.argsort(group.astype(float) + scaled, kind="stable")
    g = group[order]
    return order[np.concatenate(([True], g[1:] != g[:-1]))]


def _gathered_distances(coords_a: np.ndarray, rows_a: np.ndarray, coords_b: np.ndarray, rows_b: np.ndarray):
    """``|a[rows_a] - b[rows_b]|`` for points stored one coordinate per row (``(3, N)``): 1-D gathers
    are ~4x faster than gathering ``(N, 3)`` rows on the pairing's hot path."""
    d2 = np.zeros(len(rows_a))
    for ca, cb in zip(coords_a, coords_b):      # 3 coordinates
        d2 += np.square(np.take(ca, rows_a) - np.take(cb, rows_b))
    return np.sqrt(d2, out=d2)


def _segment_max(values: np.ndarray, segment: np.ndarray, n_segments: int) -> np.ndarray:
    """Largest value per segment id (0 where a segment has none)."""
    step = np.diff(segment)
    if len(segment) and segment[0] == 0 and segment[-1] == n_segments - 1 and np.all((step == 0) | (step == 1)):
        # every segment present, in order (how touch sets store activations): no scatter needed
        return np.maximum.reduceat(values, np.flatnonzero(np.concatenate(([True], segment[1:] != segment[:-1]))))
    out = np.zeros(n_segments)
    np.maximum.at(out, segment, values)
    return out


def _contact_activations(touches: TouchSet, contacts: np.ndarray) -> tuple:
    """The activations of ``contacts``: ``(position in contacts, activation)``, grouped by ``contacts``
    (as :func:`_cross_pairs` of the contacts and ``act_contact``, with each contact's activations found
    once per touch set instead of searched at every pairing)."""
    def segments():
        owner = touches.act_contact
        order = (np.arange(len(owner)) if np.all(owner[1:] >= owner[:-1])
                 else np.argsort(owner, kind="stable"))
        count = np.bincount(owner, minlength=len(touches.contact_touch))
        return order, np.cumsum(count) - count, count
    order, first, count = touches.derived(("contact activations",), segments)
    contacts = np.asarray(contacts)
    return _runs(order, first[contacts], count[contacts])


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


# ---------------------------------------------------------------------- positions
def robot_joints(touches: TouchSet, skin: SkinModel) -> np.ndarray:
    """The touches' joint angles in the robot model's column order (NaN where a joint is not recorded)."""
    robot = skin.robot
    if tuple(touches.joint_names) == tuple(robot.joint_names):
        return touches.joints

    def reorder():
        q = np.full((touches.n_touches, len(robot.joint_names)), np.nan)
        for col, name in enumerate(touches.joint_names):
            if name in robot.joint_index:
                q[:, robot.joint_index[name]] = touches.joints[:, col]
        return q
    return touches.derived(("robot joints",), reorder, (robot,))


def chain_end_poses(touches: TouchSet, skin: SkinModel, part: str) -> np.ndarray:
    """(N, 4, 4) pose of the chain end a part (or a fingertip of the robot config) hangs off, in every touch.

    One batched FK per touch set and chain: pairing and solving re-use it
    under every new calibration (joint angles never change while calibrating,
    only the skin's corrections do).
    """
    chain = skin.parts[part].chain if part in skin.parts else skin.robot.fingertip(part).chain
    return touches.derived(("fk", chain), lambda: skin.robot.fk(chain, robot_joints(touches, skin)), (skin.robot,))


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


def activation_positions(touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None = None,
                         placed: dict | None = None) -> np.ndarray:
    """(A, 3) calibrated position of every activated taxel in the base frame (one FK per part; each
    part's slots placed once under ``calib``, then gathered per activation).

    ``placed``: the slots' chain-end positions per part under ``calib`` ((3, slots), coordinate first),
    filled as parts are placed: one dict shared by the calls that pair several part pairs under one
    calibration.
    """
    robot_skin = skin.with_kinematics(calib)   # the robot the calibration's kinematic corrections describe
    placed = {} if placed is None else placed
    parts, rows = _slot_rows(touches, skin)
    for name in parts:
        if name not in placed:
            positions = skin.part(name).taxel_positions(calib.parts.get(name) if calib is not None else None,
                                                        normals=False)
            placed[name] = np.ascontiguousarray(positions.T)
    if not parts:
        return np.zeros((0, 3))
    rot, trans = _activation_chains(touches, robot_skin)
    local = np.concatenate([placed[name] for name in parts], axis=1)
    # stored coordinate first (the transpose is a view): the pairing gathers one coordinate at a time
    return se3.transform_coordinates(rot, np.stack([np.take(row, rows) for row in local]), trans).T


def activation_normals(touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None = None) -> np.ndarray:
    """(A, 3) calibrated base-frame normal of every activated taxel (as :func:`activation_positions`)."""
    robot_skin = skin.with_kinematics(calib)
    parts, rows = _slot_rows(touches, skin)
    if not parts:
        return np.zeros((0, 3))
    rot, _ = _activation_chains(touches, robot_skin)
    local = np.concatenate([skin.part(name).taxel_positions(calib.parts.get(name) if calib is not None else None)[1]
                            for name in parts]).T
    return se3.transform_coordinates(rot, np.stack([np.take(row, rows) for row in local])).T


# ---------------------------------------------------------------------- pairing
def pair_touches(touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None = None,
                 kinds=("cop", "taxel", "taxel5"), parts: tuple | None = None, *,
                 taxel_rule: str = "contacts", cop_radius: float = DEFAULT_COP_RADIUS,
                 placed: dict | None = None, plane: PlaneRows = PlaneRows(), press: dict | None = None) -> Pairing:
    """Pair every touch under ``calib`` (None: nominal layout).

    ``taxel_rule`` chooses the closest taxel pair (kind 1): ``"contacts"`` -
    the closest pair among the taxels of the two selected contacts (default;
    what the solver fits); ``"touch"`` - the closest pair among every
    activated taxel of the two parts in the touch (the reported figure);
    ``"thesis"`` - prepareData.m (Pseudocode 5): the taxel of A closest to
    COP_A, then the taxel of B within ``cop_radius`` of COP_B closest to it
    (any taxel of B's contact if none is that close). Kind 2 is always
    searched in the selected contacts, and kind 4 is the ``"contacts"`` kind 1
    whatever the rule. ``placed``: see :func:`activation_positions`.
    ``plane``: how point-to-plane rows (kinds 5, 6) are made. ``press``: ``{(part A, part B): (N, 3)}``, each
    touch's expected ``cop_skin`` row (:func:`~nao_skin.calibration.press.press_offsets`), its
    :attr:`Pairing.row_offset`.
    """
    want = {KIND_NAMES[k] if isinstance(k, str) else int(k) for k in kinds}
    if taxel_rule not in TAXEL_RULES:
        raise ValueError(f"taxel_rule must be one of {', '.join(TAXEL_RULES)}, not {taxel_rule!r}")
    pos = activation_positions(touches, skin, calib, placed)
    weight = cop_weights(touches)
    n_c = len(touches.contact_touch)
    cop = segment_mean(pos, touches.act_contact, n_c, weight)

    rows = []    # per block: touch, kind, part a, part b, distance, order within the touch
    terms = []   # per block: local row, part, slot, weight  (row numbers offset later)
    n_rows = 0

    def add(block_touch, kind, pa, pb, dist, seq, t_row, t_part, t_slot, t_weight, normal=None, offset=None):
        nonlocal n_rows
        m = len(block_touch)
        normal = np.full((m, 3), np.nan) if normal is None else normal
        offset = np.zeros((m, 3)) if offset is None else offset
        rows.append((block_touch, np.full(m, kind), np.full(m, pa), np.full(m, pb), dist, seq, normal, offset))
        terms.append((t_row + n_rows, t_part, t_slot, t_weight))
        n_rows += m

    coords = np.ascontiguousarray(pos.T)     # one coordinate per row: 1-D gathers are ~4x faster than (N, 3) rows

    def candidates(ga, act_a, gb, act_b):
        """Every taxel pair (one taxel per side) within each group, grouped: group, A and B activation, distance."""
        i, j = _cross_pairs(ga, gb)
        a, b = act_a[i], act_b[j]
        return ga[i], a, b, _gathered_distances(coords, a, coords, b)

    if taxel_rule == "touch" and KIND_TAXEL in want:
        # a contact's taxels lie within this of its COP: bounds every taxel distance of a contact pair
        radius = _segment_max(se3.vector_norms(pos - cop[touches.act_contact]), touches.act_contact, n_c)

    plane_kinds = [k for k in (KIND_PLANE_B, KIND_PLANE_A) if k in want]
    if plane_kinds or want & {KIND_SURFACE, KIND_COP_SKIN}:
        if plane.weight not in PLANE_WEIGHTS:
            raise ValueError(f"plane weight must be one of {', '.join(PLANE_WEIGHTS)}, not {plane.weight!r}")
        normals = activation_normals(touches, skin, calib)
        poses = lambda name: chain_end_poses(touches, skin.with_kinematics(calib), name)  # noqa: E731

    fires = touches.parts_of_touch()
    for pair_no, (pa, pb) in enumerate(_part_order(touches, parts)):
        both = fires[:, pa] & fires[:, pb]
        ca = np.flatnonzero((touches.contact_part == pa) & both[touches.contact_touch])
        cb = np.flatnonzero((touches.contact_part == pb) & both[touches.contact_touch])
        ia, ib = _cross_pairs(touches.contact_touch[ca], touches.contact_touch[cb])
        cA, cB = ca[ia], cb[ib]
        dcop_all = se3.vector_norms(cop[cA] - cop[cB])
        best = _argmin_per_group(touches.contact_touch[cA], dcop_all)
        sel_a, sel_b, dcop = cA[best], cB[best], dcop_all[best]
        group_touch = touches.contact_touch[sel_a]
        n_g = len(sel_a)
        order_key = np.full(n_g, pair_no)
        # taxels of the selected contacts, grouped by group number
        ga, act_a = _contact_activations(touches, sel_a)
        gb, act_b = _contact_activations(touches, sel_b)

        if KIND_COP in want:
            add(group_touch, KIND_COP, pa, pb, dcop, order_key * 10,
                np.concatenate((ga, gb)), np.concatenate((np.full(len(ga), pa), np.full(len(gb), pb))),
                np.concatenate((touches.act_slot[act_a], touches.act_slot[act_b])),
                np.concatenate((weight[act_a], -weight[act_b])))
        if KIND_COP_SKIN in want:
            expected = (press or {}).get((touches.part_names[pa], touches.part_names[pb]))
            _add_cop_skin_rows(add, touches, skin, calib, pa, pb, pair_no * 10 + KIND_COP_SKIN, group_touch,
                               ga, act_a, gb, act_b, pos, normals, poses, weight, coords,
                               None if expected is None else np.nan_to_num(expected[group_touch]))
        if KIND_SURFACE in want:
            _add_surface_rows(add, touches, skin, calib, pa, pb, pair_no * 10 + KIND_SURFACE, pos, normals, poses)
        for kind in plane_kinds:
            _add_plane_rows(add, kind, group_touch, pa, pb, pair_no * 10 + kind, ga, act_a, gb, act_b, coords,
                            normals, weight, plane, touches.act_slot)
        if not want & {KIND_TAXEL, KIND_TAXEL5, KIND_CONTACT_TAXEL}:
            continue
        pair_group, a_act, b_act, dpair = candidates(ga, act_a, gb, act_b)
        closest = _argmin_per_group(pair_group, dpair)
        if KIND_CONTACT_TAXEL in want:
            _add_taxel_rows(add, group_touch, KIND_CONTACT_TAXEL, pa, pb, pair_no * 10 + 8, pair_group[closest],
                            a_act[closest], b_act[closest], dpair[closest], touches.act_slot)
        if KIND_TAXEL in want:
            if taxel_rule == "thesis":
                pick = _thesis_pick(pair_group, a_act, b_act, dpair, pos, cop[sel_a], cop[sel_b], cop_radius)
                found = (pair_group[pick], a_act[pick], b_act[pick], dpair[pick])
            elif taxel_rule == "touch":
                found = _closest_in_touch(touches, coords, cop, cA, cB, dcop_all, radius,
                                          np.searchsorted(group_touch, touches.contact_touch[cA]),
                                          dpair[closest], candidates)
            else:
                found = (pair_group[closest], a_act[closest], b_act[closest], dpair[closest])
            _add_taxel_rows(add, group_touch, KIND_TAXEL, pa, pb, pair_no * 10 + 1, *found, touches.act_slot)
        if KIND_TAXEL5 in want:
            valid = np.ones(len(dpair), dtype=bool)
            used = np.zeros(len(touches.act_slot), dtype=bool)
            picks = []
            for step in range(MAX_TAXEL_PAIRS):                 # <= 5 greedy rounds over all touches
                cand = np.flatnonzero(valid)
                if len(cand) == 0:
                    break
                pick = cand[_argmin_per_group(pair_group[cand], dpair[cand])]
                picks.append((pick, step))
                used[a_act[pick]] = True
                used[b_act[pick]] = True
                valid &= ~used[a_act] & ~used[b_act]
            if picks:
                pick = np.concatenate([p for p, _ in picks])
                step = np.concatenate([np.full(len(p), s) for p, s in picks])
                _add_taxel_rows(add, group_touch, KIND_TAXEL5, pa, pb, pair_no * 10 + 2 + step / 10.0,
                                pair_group[pick], a_act[pick], b_act[pick], dpair[pick], touches.act_slot)
    return _assemble(rows, terms)


def pair_for_metrics(touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None = None,
                     parts: tuple | None = None) -> Pairing:
    """The pairing the reported figures are computed on (:func:`metrics`): the closest COP pair, the
    closest taxel pair among every activated taxel of the two parts (``taxel``), up to 5 closest
    pairs of the selected contacts (``taxel5``) and their closest pair (``contact_taxel``, what the
    solver fits)."""
    return pair_touches(touches, skin, calib, kinds=METRIC_KINDS, parts=parts, taxel_rule=METRIC_TAXEL_RULE)


def _closest_in_touch(touches, coords, cop, cA, cB, dcop, radius, group, bound, candidates) -> tuple:
    """Closest pair among every activated taxel of the two parts, per group (touch): ``(group, A
    activation, B activation, distance)``.

    ``cA``/``cB``: every contact pair of the touches, ``group`` its group; ``bound`` per group: the
    selected contacts' closest pair, which the answer cannot exceed. Only pairs that could beat it
    are measured: contact pairs whose COPs are within the bound plus both contacts' radii, and in
    them the taxels within the bound plus the other contact's radius of its COP (on the real
    recording 14k of its ~260k taxel pairs at the nominal skin, 60k calibrated, where every pair
    is close). ``coords``: the activations' positions one coordinate per row.
    """
    slack = bound[group] * (1.0 + 1e-9) + 1e-12
    near = np.flatnonzero(dcop - radius[cA] - radius[cB] <= slack)
    cA, cB, group, slack = cA[near], cB[near], group[near], slack[near]

    cop_coords = np.ascontiguousarray(cop.T)

    def side(own, other):
        k, act = _contact_activations(touches, own)
        far = other[k]
        keep = _gathered_distances(coords, act, cop_coords, far) - radius[far] <= slack[k]
        return k[keep], act[keep]

    ka, act_a = side(cA, cB)
    kb, act_b = side(cB, cA)
    k, a_act, b_act, dist = candidates(ka, act_a, kb, act_b)
    owner = group[k]
    pick = _argmin_per_group(owner, dist)
    return owner[pick], a_act[pick], b_act[pick], dist[pick]


def _thesis_pick(pair_group, a_act, b_act, dpair, pos, cop_a, cop_b, radius):
    """prepareData.m: taxel of A nearest COP_A; then the taxel of B near COP_B nearest that taxel."""
    to_cop_a = np.linalg.norm(pos[a_act] - cop_a[pair_group], axis=1)
    # only pairs whose A taxel is the one nearest COP_A
    first = _argmin_per_group(pair_group, to_cop_a)
    chosen_a = np.full(pair_group.max() + 1 if len(pair_group) else 0, -1)
    chosen_a[pair_group[first]] = a_act[first]
    on_a = a_act == chosen_a[pair_group]
    near_b = np.linalg.norm(pos[b_act] - cop_b[pair_group], axis=1) <= radius
    # groups with no B taxel within the radius fall back to every B taxel
    has_near = np.zeros(len(chosen_a), dtype=bool)
    has_near[pair_group[on_a & near_b]] = True
    ok = on_a & (near_b | ~has_near[pair_group])
    cand = np.flatnonzero(ok)
    return cand[_argmin_per_group(pair_group[cand], dpair[cand])]


def _add_taxel_rows(add, group_touch, kind, pa, pb, seq, group, a_act, b_act, dist, act_slot,
                    row_weight=None, normal=None):
    m = len(group)
    local_row = np.arange(m)
    w = np.ones(m) if row_weight is None else row_weight
    add(group_touch[group], kind, pa, pb, dist, np.broadcast_to(seq, (m,)).astype(float),
        np.concatenate((local_row, local_row)), np.concatenate((np.full(m, pa), np.full(m, pb))),
        np.concatenate((act_slot[a_act], act_slot[b_act])), np.concatenate((w, -w)), normal)


def _add_plane_rows(add, kind, group_touch, pa, pb, seq, ga, act_a, gb, act_b, coords, normals, cop_weight,
                    plane: PlaneRows, act_slot):
    """Point-to-plane rows: every taxel of one side's selected contact with the closest taxel of the
    other side's, measured along that closest taxel's normal (kind 5: A's taxels, B's normals)."""
    own_g, own_act, other_g, other_act = (ga, act_a, gb, act_b) if kind == KIND_PLANE_B else (gb, act_b, ga, act_a)
    i, j = _cross_pairs(own_g, other_g)                  # grouped by the own taxel i
    dist = _gathered_distances(coords, own_act[i], coords, other_act[j])
    pick = _argmin_per_group(i, dist)
    own, other, group = own_act[i[pick]], other_act[j[pick]], own_g[i[pick]]
    if plane.weight == "touch":
        w = 1.0 / np.sqrt(np.bincount(group, minlength=len(group_touch))[group])
    elif plane.weight == "pressure":
        w = np.sqrt(cop_weight[own])     # a contact's COP weights sum to 1
    else:
        w = np.ones(len(own))
    w = plane.scale * w
    a_act, b_act = (own, other) if kind == KIND_PLANE_B else (other, own)
    normal = normals[other]
    along = np.abs(np.einsum("ij,ij->i", coords[:, a_act].T - coords[:, b_act].T, normal))
    _add_taxel_rows(add, group_touch, kind, pa, pb, seq, group, a_act, b_act, along, act_slot, w, normal)


def _add_cop_skin_rows(add, touches, skin, calib, pa, pb, seq, group_touch, ga, act_a, gb, act_b, pos, normals,
                       poses, weight, coords, expected=None):
    """The closest COP pair's contacts, each COP over its taxels with the other part's skin beside them
    (:func:`~nao_skin.calibration.contact.skin_beside`). Where one side has no such taxel (the frames are
    still far off, or the contacts lie apart), the whole contacts' COPs: no touch loses its row. ``poses(name)``:
    a part's chain-end pose in every touch, on the robot ``calib`` describes. ``expected``: each row's
    expectation at the true skin (the rows' :attr:`Pairing.row_offset`), None for none."""
    n_g = len(group_touch)
    beside = [skin_beside(touches, skin, calib, other, act, pos, normals, poses)
              for act, other in ((act_a, pb), (act_b, pa))]
    on_skin = ((np.bincount(ga, weights=beside[0], minlength=n_g) > 0)
               & (np.bincount(gb, weights=beside[1], minlength=n_g) > 0))
    parts, slots, t_rows, t_weights, cops = [], [], [], [], []
    for sign, part, g, act, near in ((1.0, pa, ga, act_a, beside[0]), (-1.0, pb, gb, act_b, beside[1])):
        w = weight[act] * np.where(on_skin[g], near, True)
        keep = w > 0
        share = w[keep] / np.bincount(g, weights=w, minlength=n_g)[g[keep]]
        t_rows.append(g[keep])
        parts.append(np.full(keep.sum(), part))
        slots.append(touches.act_slot[act[keep]])
        t_weights.append(sign * share)
        cops.append(np.stack([np.bincount(g[keep], weights=coords[d, act[keep]] * share, minlength=n_g)
                              for d in range(3)], axis=1))
    add(group_touch, KIND_COP_SKIN, pa, pb, np.linalg.norm(cops[0] - cops[1], axis=1), np.full(n_g, float(seq)),
        np.concatenate(t_rows), np.concatenate(parts), np.concatenate(slots), np.concatenate(t_weights),
        offset=expected)


def _add_surface_rows(add, touches, skin, calib, pa, pb, seq, pos, normals, poses):
    """The contact model's rows (:mod:`nao_skin.calibration.contact`) of one part pair, A's taxels first."""
    for own, other, act, slot, normal, along in surface_rows(touches, skin, calib, pa, pb, pos, normals, poses):
        m = len(act)
        if m == 0:
            continue
        order = np.argsort(touches.act_touch[act], kind="stable")
        act, slot, normal, along = act[order], slot[order], normal[order], along[order]
        row_touch = touches.act_touch[act]
        w = touch_weights(row_touch, touches.n_touches)
        local = np.arange(m)
        parts = (np.full(m, own), np.full(m, other))
        slots = (touches.act_slot[act], slot)
        if own != pa:       # rows are (side A) - (side B)
            parts, slots = parts[::-1], slots[::-1]
        add(row_touch, KIND_SURFACE, pa, pb, np.abs(along), np.full(m, float(seq)), np.concatenate((local, local)),
            np.concatenate(parts), np.concatenate(slots), np.concatenate((w, -w)), normal)


def _assemble(rows, terms) -> Pairing:
    if not rows:
        z = np.zeros(0, dtype=int)
        return Pairing(z, z.astype(np.int8), np.zeros((0, 2), int), z, z, z, np.zeros(0), np.zeros(0))
    touch, kind, pa, pb, dist, seq, normal, offset = (np.concatenate(c) for c in zip(*rows))
    t_row, t_part, t_slot, t_weight = (np.concatenate(c) for c in zip(*terms))
    order = np.lexsort((np.arange(len(touch)), seq, touch))       # by touch, then part pair and kind
    new_row = np.empty(len(order), dtype=int)
    new_row[order] = np.arange(len(order))
    t_row = new_row[t_row]
    t_order = np.argsort(t_row, kind="stable")
    return Pairing(touch[order].astype(int), kind[order].astype(np.int8),
                   np.stack([pa[order], pb[order]], axis=1).astype(int),
                   t_row[t_order], t_part[t_order].astype(int), t_slot[t_order].astype(int),
                   t_weight[t_order].astype(float), dist[order].astype(float),
                   normal[order] if np.isfinite(normal).any() else None,
                   offset[order] if np.any(offset) else None)


# ---------------------------------------------------------------------- evaluation
def residuals(pairing: Pairing, touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None = None) -> np.ndarray:
    """(M, 3) residual of every row under ``calib`` (rows fixed, positions re-evaluated)."""
    q = robot_joints(touches, skin)
    skin = skin.with_kinematics(calib)
    out = np.zeros((pairing.n_rows, 3))
    t_touch = pairing.row_touch[pairing.term_row]
    for p, name in enumerate(touches.part_names):
        sel = np.flatnonzero(pairing.term_part == p)
        if len(sel) == 0:
            continue
        corr = calib.parts.get(name) if calib is not None else None
        local, _ = skin.part(name).taxel_positions(corr)
        rows, inverse = np.unique(t_touch[sel], return_inverse=True)
        world = se3.transform_points(skin.chain_poses(name, q[rows])[inverse], local[pairing.term_slot[sel]])
        np.add.at(out, pairing.term_row[sel], world * pairing.term_weight[sel, None])
    return out


def _stats(values_m: np.ndarray, prefix: str) -> dict:
    v = np.asarray(values_m, dtype=float) * 1000.0
    if len(v) == 0:
        return {f"{prefix}_mean_mm": float("nan"), f"{prefix}_median_mm": float("nan"),
                f"{prefix}_p90_mm": float("nan")}
    return {f"{prefix}_mean_mm": float(np.mean(v)), f"{prefix}_median_mm": float(np.median(v)),
            f"{prefix}_p90_mm": float(np.percentile(v, 90))}


def metrics(pairing: Pairing) -> dict:
    """Mean / median / 90th percentile (mm) of per-touch distances for each kind, and the touch count.

    For kind 2 a touch's distance is the mean over its (up to 5) pairs first.
    A touch with several firing part pairs counts once per pair. Fingertip rows (``fingertip``: the distance
    from the fingertip to its contact) where the pairing has any.
    """
    out = {}
    fingertip = ("fingertip",) if np.any(pairing.row_kind == KIND_FINGERTIP) else ()
    for name in METRIC_KINDS + fingertip:
        kind = KIND_NAMES[name]
        sel = pairing.row_kind == kind
        dist = pairing.distance[sel]
        if kind == KIND_TAXEL5 and np.any(sel):
            # a touch's pairs of one part pair are consecutive rows (pair_touches orders rows by touch,
            # then part pair and kind; concatenated pairings keep that within each part pair)
            touch, parts = pairing.row_touch[sel], pairing.row_parts[sel]
            new = np.concatenate(([True], (touch[1:] != touch[:-1]) | np.any(parts[1:] != parts[:-1], axis=1)))
            group = np.cumsum(new) - 1
            dist = np.bincount(group, weights=dist) / np.bincount(group)
        out.update(_stats(dist, name))
    out["n_touches"] = int(len(np.unique(pairing.row_touch)))
    return out
