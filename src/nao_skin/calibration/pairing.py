"""Residual rows as data: which points must coincide in a touch (thesis §2.3, §3.2.2), for all touches at once.

A :class:`Pairing` holds residual rows ``point_A - point_B`` whose points are weighted sums of taxel
positions (a COP is the weighted mean of its contact's taxels; side B of a fingertip row is the fingertip's
contact sphere), so a solver can re-evaluate the same rows under new parameters without re-pairing. Which
rows there are is each kind's choice (:mod:`~nao_skin.calibration.row_kinds`, built from one
:class:`~nao_skin.calibration.context.FitContext` by :func:`~nao_skin.calibration.rows.pair_touches`): each
kind gives a :class:`RowBlock`, and :func:`assemble` puts the blocks of a pairing into one ``Pairing``. The
figures reported on a pairing (:func:`metrics`) and its rows' residuals (:func:`residuals`) are here too.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nao_skin import se3
from nao_skin.calibration.kinds import (KIND_CONTACT_TAXEL, KIND_COP, KIND_COP_SKIN, KIND_FINGERTIP,  # noqa: F401
                                        KIND_NORMAL, KIND_PLANE_A, KIND_PLANE_B, KIND_SURFACE, KIND_TAXEL,
                                        KIND_TAXEL5, PLANE_WEIGHTS)
from nao_skin.model.skin import SkinCalibration, SkinModel
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
DEFAULT_COP_RADIUS = 0.012   # thesis rule: taxel of B searched within this distance of COP_B (m)


@dataclass(frozen=True)
class PlaneRows:
    """How point-to-plane rows (kinds 5, 6) are weighted: by ``weight`` (:data:`PLANE_WEIGHTS`) times ``scale``."""

    weight: str = "touch"
    scale: float = 1.0


@dataclass(frozen=True)
class RowRules:
    """How the rows of a pairing are made, beyond their kinds.

    ``taxel_rule`` chooses the closest taxel pair (kind 1): ``"contacts"`` - the closest pair among the taxels of
    the two selected contacts (default; what the solver fits); ``"touch"`` - the closest pair among every activated
    taxel of the two parts in the touch (the reported figure); ``"thesis"`` - prepareData.m (Pseudocode 5): the
    taxel of A closest to COP_A, then the taxel of B within ``cop_radius`` of COP_B closest to it (any taxel of B's
    contact if none is that close). Kind 2 is always searched in the selected contacts, and kind 4 is the
    ``"contacts"`` kind 1 whatever the rule. ``plane``: how point-to-plane rows (kinds 5, 6) are weighted.
    ``press``: ``{(part A, part B): (N, 3)}``, each touch's expected ``cop_skin`` row
    (:func:`~nao_skin.calibration.press.press_offsets`), its :attr:`Pairing.row_offset`; None for none.
    """

    taxel_rule: str = "contacts"
    cop_radius: float = DEFAULT_COP_RADIUS
    plane: PlaneRows = PlaneRows()
    press: dict | None = None

    def __post_init__(self):
        if self.taxel_rule not in TAXEL_RULES:
            raise ValueError(f"taxel_rule must be one of {', '.join(TAXEL_RULES)}, not {self.taxel_rule!r}")
        if self.plane.weight not in PLANE_WEIGHTS:
            raise ValueError(f"plane weight must be one of {', '.join(PLANE_WEIGHTS)}, not {self.plane.weight!r}")

    def on_touches(self, rows: np.ndarray) -> "RowRules":
        """These rules for the touches ``rows`` of the touch set ``press`` covers (a subset, in that order)."""
        if self.press is None:
            return self
        return RowRules(self.taxel_rule, self.cop_radius, self.plane, {k: v[rows] for k, v in self.press.items()})


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


@dataclass
class RowBlock:
    """The rows one kind builds for one pair (two skin parts, or a fingertip and the part it presses), each
    ``(side A) - (side B)``, with their terms (``term_row``: the block's own row numbers). The optional
    arrays are a :class:`Pairing`'s (:data:`ROW_EXTRAS`), None where the kind has none."""

    touch: np.ndarray          # (m,) int touch row
    parts: tuple               # (part A, part B) indices; part B -1: a fingertip's sphere is side B
    distance: np.ndarray       # (m,) metres, under the calibration paired at
    term_row: np.ndarray       # (k,) int row in this block
    term_part: np.ndarray      # (k,) int
    term_slot: np.ndarray      # (k,) int
    term_weight: np.ndarray    # (k,) float, +w on side A, -w on side B
    step: np.ndarray | None = None      # (m,) int: where among one touch's rows of the kind (None: all 0)
    normal: np.ndarray | None = None
    offset: np.ndarray | None = None
    fingertip: np.ndarray | None = None
    direction: np.ndarray | None = None

    @classmethod
    def between(cls, parts: tuple, touch: np.ndarray, distance: np.ndarray, side_a: tuple, side_b: tuple,
                **extras) -> "RowBlock":
        """Rows of the skin parts ``parts``, each side's terms given as ``(row, slot, weight)`` arrays (the
        weights positive: side B's enter negated)."""
        (row_a, slot_a, w_a), (row_b, slot_b, w_b) = side_a, side_b
        return cls(touch, parts, distance, np.concatenate((row_a, row_b)),
                   np.concatenate((np.full(len(row_a), parts[0]), np.full(len(row_b), parts[1]))),
                   np.concatenate((slot_a, slot_b)), np.concatenate((w_a, -w_b)), **extras)

    @classmethod
    def joined(cls, parts: tuple, blocks: list) -> "RowBlock":
        """The rows of ``blocks`` (of ``parts``) one after the other."""
        if not blocks:
            z = np.zeros(0, int)
            return cls(z, parts, np.zeros(0), z, z, z, np.zeros(0))
        first = np.cumsum([0] + [len(b.touch) for b in blocks[:-1]])
        extras = {name: np.concatenate([_block_extra(b, name) for b in blocks]) for name in BLOCK_EXTRAS
                  if any(getattr(b, name) is not None for b in blocks)}
        return cls(np.concatenate([b.touch for b in blocks]), parts, np.concatenate([b.distance for b in blocks]),
                   np.concatenate([b.term_row + f for b, f in zip(blocks, first)]),
                   *(np.concatenate([getattr(b, name) for b in blocks]) for name in ("term_part", "term_slot",
                                                                                      "term_weight")), **extras)


# a block's optional row arrays and the Pairing's they become
BLOCK_EXTRAS = {"step": None, "normal": "row_normal", "offset": "row_offset", "fingertip": "row_fingertip",
                "direction": "row_direction"}


def _block_extra(block: RowBlock, name: str) -> np.ndarray:
    """Optional array ``name`` of ``block`` on every row, filled as :data:`ROW_EXTRAS` says where it has none."""
    value = getattr(block, name)
    if value is not None:
        return value
    m = len(block.touch)
    if name == "step":
        return np.zeros(m, int)
    fill = ROW_EXTRAS[BLOCK_EXTRAS[name]]
    return np.full((m,) if name == "fingertip" else (m, 3), fill, dtype=int if name == "fingertip" else float)


def assemble(blocks: list) -> Pairing:
    """One :class:`Pairing` of ``(pair number, rank, kind, RowBlock)`` entries: the rows ordered by touch, then
    by the number of their pair, the rank of their kind and their step (each block in its own order after
    that); each row's terms in the order its block gives them."""
    blocks = [entry for entry in blocks if len(entry[3].touch)]
    if not blocks:
        z = np.zeros(0, dtype=int)
        return Pairing(z, z.astype(np.int8), np.zeros((0, 2), int), z, z, z, np.zeros(0), np.zeros(0))
    sizes = [len(b.touch) for _, _, _, b in blocks]
    block = RowBlock.joined((-1, -1), [b for _, _, _, b in blocks])
    per_row = [np.repeat([e[i] for e in blocks], sizes) for i in range(3)]
    parts = np.repeat([b.parts for _, _, _, b in blocks], sizes, axis=0)
    order = np.lexsort((np.arange(len(block.touch)), _block_extra(block, "step"), per_row[1], per_row[0],
                        block.touch))
    new_row = np.empty(len(order), dtype=int)
    new_row[order] = np.arange(len(order))
    t_row = new_row[block.term_row]
    t_order = np.argsort(t_row, kind="stable")
    extras = {pairing_name: _optional(getattr(block, name)[order], ROW_EXTRAS[pairing_name])
              for name, pairing_name in BLOCK_EXTRAS.items() if pairing_name and getattr(block, name) is not None}
    return Pairing(block.touch[order].astype(int), per_row[2][order].astype(np.int8), parts[order].astype(int),
                   t_row[t_order], block.term_part[t_order].astype(int), block.term_slot[t_order].astype(int),
                   block.term_weight[t_order].astype(float), block.distance[order].astype(float), **extras)


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
