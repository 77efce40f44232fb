"""The kinds of rows two touching skin parts give (thesis §2.3, §3.2.2), each built from a fit context.

For every touch and every pair of skin parts that fire in it, the pairing chooses, under the current
calibration, the closest pair of contact COPs, one contact on each part (:class:`~.context.SkinPair`), and from
it each kind of row:

* ``cop`` (kind 0) - the two COPs;
* ``taxel`` (kind 1) - the closest pair of activated taxels of those two contacts;
* ``taxel5`` (kind 2) - up to 5 closest taxel pairs of those two contacts, greedily, each taxel used once
  (eq. 2.5: L = min(5, P, Q));
* ``contact_taxel`` (kind 4) - the closest taxel pair of the two contacts whatever the taxel rule;
* ``plane_b``, ``plane_a`` (kinds 5 and 6) - point-to-plane rows (as in ICP): every activated taxel of one
  selected contact with the closest activated taxel of the other, only the distance along that taxel's normal
  counting (``Pairing.row_normal``). The two taxel lattices are offset tangentially by up to half a taxel
  spacing, so a closest taxel pair is millimetres apart even at the true calibration; along the normal that
  offset does not count. Kind 5 takes side A's taxels to B's surface, kind 6 B's to A's;
* ``surface`` (kind 7) and ``cop_skin`` (kind 8) - the contact model's rows (:mod:`~.contact`).

Kinds 1 and 2 are what the solver fits. The reported closest taxel pair (``taxel_rule="touch"``,
:class:`~.pairing.RowRules`) is searched among every activated taxel of the two parts in the touch instead, as
the closest COP pair is among every contact: a figure that does not depend on which contacts this pairing
selected. Kind 4 reports the fitted pair beside it; kind 2 stays the selected contacts' (eq. 2.5 counts their
taxels).

Each kind is a builder ``(context, pair, rules) -> RowBlock`` (:func:`~.rows.pair_touches` calls the ones
asked for, as it calls a fingertip's, :mod:`~.fingertip`); re-pairing is a few vectorised passes over all
touches (segment minima), cheap enough to repeat after every calibration step.
"""
from __future__ import annotations

from functools import partial

import numpy as np

from nao_skin.calibration.contact import skin_beside, surface_rows, touch_weights
from nao_skin.calibration.context import FitContext, SkinPair
from nao_skin.calibration.pairing import RowBlock, RowRules
from nao_skin.calibration.segments import argmin_per_group, contact_activations, cross_pairs, gathered_distances

MAX_TAXEL_PAIRS = 5


def cop_block(ctx: FitContext, pair: SkinPair, rules: RowRules) -> RowBlock:
    """The selected contacts' COPs (kind 0)."""
    act_slot, weight = ctx.touches.act_slot, ctx.cop_weights
    return RowBlock.between(pair.parts, pair.touch, pair.cop_distance,
                            (pair.group_a, act_slot[pair.act_a], weight[pair.act_a]),
                            (pair.group_b, act_slot[pair.act_b], weight[pair.act_b]))


def taxel_block(ctx: FitContext, pair: SkinPair, rules: RowRules) -> RowBlock:
    """The closest taxel pair, as ``rules.taxel_rule`` searches it (kind 1)."""
    pair_group, a_act, b_act, dpair = pair.taxel_pairs
    if rules.taxel_rule == "thesis":
        pick = _thesis_pick(ctx, pair, rules.cop_radius)
        found = (pair_group[pick], a_act[pick], b_act[pick], dpair[pick])
    elif rules.taxel_rule == "touch":
        found = ctx.memo(("closest in touch", pair.pa, pair.pb), lambda: _closest_in_touch(ctx, pair))
    else:
        closest = pair.closest
        found = (pair_group[closest], a_act[closest], b_act[closest], dpair[closest])
    return _taxel_pair_block(ctx, pair, *found)


def taxel5_block(ctx: FitContext, pair: SkinPair, rules: RowRules) -> RowBlock:
    """Up to :data:`MAX_TAXEL_PAIRS` closest taxel pairs of the selected contacts, greedily, each taxel used once
    (kind 2); each row's step says which round found it."""
    pair_group, a_act, b_act, dpair = pair.taxel_pairs
    valid = np.ones(len(dpair), dtype=bool)
    used = np.zeros(len(ctx.touches.act_slot), dtype=bool)
    picks = []
    for step in range(MAX_TAXEL_PAIRS):                 # <= 5 greedy rounds over all touches
        cand = np.flatnonzero(valid)
        if len(cand) == 0:
            break
        pick = cand[argmin_per_group(pair_group[cand], dpair[cand])]
        picks.append((pick, step))
        used[a_act[pick]] = True
        used[b_act[pick]] = True
        valid &= ~used[a_act] & ~used[b_act]
    if not picks:
        return _taxel_pair_block(ctx, pair, *(np.zeros(0, int),) * 3, np.zeros(0))
    pick = np.concatenate([p for p, _ in picks])
    step = np.concatenate([np.full(len(p), s) for p, s in picks])
    return _taxel_pair_block(ctx, pair, pair_group[pick], a_act[pick], b_act[pick], dpair[pick], step=step)


def contact_taxel_block(ctx: FitContext, pair: SkinPair, rules: RowRules) -> RowBlock:
    """The closest taxel pair of the selected contacts, whatever the taxel rule (kind 4)."""
    pair_group, a_act, b_act, dpair = pair.taxel_pairs
    closest = pair.closest
    return _taxel_pair_block(ctx, pair, pair_group[closest], a_act[closest], b_act[closest], dpair[closest])


def _plane_block(ctx: FitContext, pair: SkinPair, rules: RowRules, own_side: int) -> RowBlock:
    """Point-to-plane rows: every taxel of one side's selected contact (``own_side`` 0: A's, kind 5; 1: B's, kind
    6) with the closest taxel of the other side's, measured along that closest taxel's normal."""
    sides = ((pair.group_a, pair.act_a), (pair.group_b, pair.act_b))
    (own_g, own_act), (other_g, other_act) = sides[own_side], sides[1 - own_side]
    i, j = cross_pairs(own_g, other_g)                  # grouped by the own taxel i
    dist = ctx.taxel_distances(own_act[i], other_act[j])
    pick = argmin_per_group(i, dist)
    own, other, group = own_act[i[pick]], other_act[j[pick]], own_g[i[pick]]
    plane = rules.plane
    if plane.weight == "touch":
        w = 1.0 / np.sqrt(np.bincount(group, minlength=len(pair.touch))[group])
    elif plane.weight == "pressure":
        w = np.sqrt(ctx.cop_weights[own])     # a contact's COP weights sum to 1
    else:
        w = np.ones(len(own))
    w = plane.scale * w
    a_act, b_act = (own, other) if own_side == 0 else (other, own)
    normal = ctx.normals[other]
    coords = ctx.coordinates
    along = np.abs(np.einsum("ij,ij->i", coords[:, a_act].T - coords[:, b_act].T, normal))
    return _taxel_pair_block(ctx, pair, group, a_act, b_act, along, weight=w, normal=normal)


plane_b_block = partial(_plane_block, own_side=0)
plane_a_block = partial(_plane_block, own_side=1)


def cop_skin_block(ctx: FitContext, pair: SkinPair, rules: RowRules) -> RowBlock:
    """The closest COP pair's contacts, each COP over its taxels with the other part's skin beside them
    (:func:`~nao_skin.calibration.contact.skin_beside`). Where one side has no such taxel (the frames are still
    far off, or the contacts lie apart), the whole contacts' COPs: no touch loses its row. With ``rules.press``,
    each row's expectation at the true skin (the rows' :attr:`~.pairing.Pairing.row_offset`)."""
    n_g = len(pair.touch)
    act_slot, coords = ctx.touches.act_slot, ctx.coordinates
    beside = ctx.memo(("skin beside", pair.pa, pair.pb),
                      lambda: [skin_beside(ctx, pair.pb, pair.act_a), skin_beside(ctx, pair.pa, pair.act_b)])
    on_skin = ((np.bincount(pair.group_a, weights=beside[0], minlength=n_g) > 0)
               & (np.bincount(pair.group_b, weights=beside[1], minlength=n_g) > 0))
    sides, cops = [], []
    for g, act, near in ((pair.group_a, pair.act_a, beside[0]), (pair.group_b, pair.act_b, beside[1])):
        w = ctx.cop_weights[act] * np.where(on_skin[g], near, True)
        keep = w > 0
        share = w[keep] / np.bincount(g, weights=w, minlength=n_g)[g[keep]]
        sides.append((g[keep], act_slot[act[keep]], share))
        cops.append(np.stack([np.bincount(g[keep], weights=coords[d, act[keep]] * share, minlength=n_g)
                              for d in range(3)], axis=1))
    names = ctx.touches.part_names
    expected = (rules.press or {}).get((names[pair.pa], names[pair.pb]))
    return RowBlock.between(pair.parts, pair.touch, np.linalg.norm(cops[0] - cops[1], axis=1), *sides,
                            offset=None if expected is None else np.nan_to_num(expected[pair.touch]))


def surface_block(ctx: FitContext, pair: SkinPair, rules: RowRules) -> RowBlock:
    """The contact model's rows (:func:`~nao_skin.calibration.contact.surface_rows`) of the pair, A's taxels first."""
    touches = ctx.touches
    blocks = []
    for own, other, act, slot, normal, along in ctx.memo(("surface rows", pair.pa, pair.pb),
                                                         lambda: surface_rows(ctx, pair.pa, pair.pb)):
        m = len(act)
        if m == 0:
            continue
        order = np.argsort(touches.act_touch[act], kind="stable")
        act, slot, normal, along = act[order], slot[order], normal[order], along[order]
        row_touch = touches.act_touch[act]
        w = touch_weights(row_touch, touches.n_touches)
        local = np.arange(m)
        sides = [(local, touches.act_slot[act], w), (local, slot, w)]
        if own != pair.pa:       # rows are (side A) - (side B)
            sides = sides[::-1]
        blocks.append(RowBlock.between(pair.parts, row_touch, np.abs(along), *sides, normal=normal))
    return RowBlock.joined(pair.parts, blocks)


def _taxel_pair_block(ctx: FitContext, pair: SkinPair, group: np.ndarray, a_act: np.ndarray, b_act: np.ndarray,
                      dist: np.ndarray, *, weight: np.ndarray | None = None, **extras) -> RowBlock:
    """One row per taxel pair: activation ``a_act[i]`` against ``b_act[i]``, of the touch of group ``group[i]``
    (``weight``: each row's, default 1; ``extras``: the block's optional row arrays)."""
    w = np.ones(len(group)) if weight is None else weight
    local_row = np.arange(len(group))
    act_slot = ctx.touches.act_slot
    return RowBlock.between(pair.parts, pair.touch[group], dist, (local_row, act_slot[a_act], w),
                            (local_row, act_slot[b_act], w), **extras)


def _closest_in_touch(ctx: FitContext, pair: SkinPair) -> tuple:
    """Closest pair among every activated taxel of the two parts, per group (touch): ``(group, A activation,
    B activation, distance)``.

    The selected contacts' closest pair bounds the answer. Only pairs that could beat it are measured: contact
    pairs whose COPs are within the bound plus both contacts' radii, and in them the taxels within the bound
    plus the other contact's radius of its COP (on the real recording 14k of its ~260k taxel pairs at the
    nominal skin, 60k calibrated, where every pair is close).
    """
    touches, radius = ctx.touches, ctx.contact_radius
    group = np.searchsorted(pair.touch, touches.contact_touch[pair.contacts_a])
    bound = pair.taxel_pairs[3][pair.closest]
    slack = bound[group] * (1.0 + 1e-9) + 1e-12
    near = np.flatnonzero(pair.cop_distances - radius[pair.contacts_a] - radius[pair.contacts_b] <= slack)
    c_a, c_b, group, slack = pair.contacts_a[near], pair.contacts_b[near], group[near], slack[near]
    cop_coords = np.ascontiguousarray(ctx.cops.T)

    def side(own, other):
        k, act = contact_activations(touches, own)
        far = other[k]
        keep = gathered_distances(ctx.coordinates, act, cop_coords, far) - radius[far] <= slack[k]
        return k[keep], act[keep]

    k, a_act, b_act, dist = pair.candidates(*side(c_a, c_b), *side(c_b, c_a))
    owner = group[k]
    pick = argmin_per_group(owner, dist)
    return owner[pick], a_act[pick], b_act[pick], dist[pick]


def _thesis_pick(ctx: FitContext, pair: SkinPair, radius: float) -> np.ndarray:
    """prepareData.m: taxel of A nearest COP_A; then the taxel of B near COP_B nearest that taxel (indices into
    the pair's :attr:`~.context.SkinPair.taxel_pairs`)."""
    pair_group, a_act, b_act, dpair = pair.taxel_pairs
    pos = ctx.positions
    cop_a, cop_b = ctx.cops[pair.selected_a], ctx.cops[pair.selected_b]
    to_cop_a = np.linalg.norm(pos[a_act] - cop_a[pair_group], axis=1)
    # only pairs whose A taxel is the one nearest COP_A
    first = argmin_per_group(pair_group, to_cop_a)
    chosen_a = np.full(pair_group.max() + 1 if len(pair_group) else 0, -1)
    chosen_a[pair_group[first]] = a_act[first]
    on_a = a_act == chosen_a[pair_group]
    near_b = np.linalg.norm(pos[b_act] - cop_b[pair_group], axis=1) <= radius
    # groups with no B taxel within the radius fall back to every B taxel
    has_near = np.zeros(len(chosen_a), dtype=bool)
    has_near[pair_group[on_a & near_b]] = True
    ok = on_a & (near_b | ~has_near[pair_group])
    cand = np.flatnonzero(ok)
    return cand[argmin_per_group(pair_group[cand], dpair[cand])]
