"""The contact measurement model: a fired taxel lies on the other part's skin, at the fabric's distance.

Two touching skins meet at their fabric surfaces, and a taxel fires where the other part presses it. So
every activated taxel of one part has the other part's skin right beside it: the laterally nearest taxel
of the other part (any of its taxels, fired or not: the skin is there whether or not it fired), facing
it, lies across the two fabrics along the touched part's normal. One *surface row* per activated taxel:

    r = n . (x_own - x_other)          (both points lifted by the fabric along their own normals)

with ``n`` the touched part's normal (the part that is not a hand; side B of the pairing). Where both
skins are flat there, ``r`` is zero at the true calibration, whatever the lattices' sideways offset;
where one of them curves away, a taxel that fired can sit up to how far a press reaches beyond the
touching point (the simulator: 2-5 mm), so the rows are one-sided there. Unlike a COP pair, the row does
not compare the centroids of two different fired areas (a press at the edge of the hand's skin fires the
torso beyond that edge), so it has no sideways bias; it says nothing sideways either, which is what the
COP rows beside it are for (docs/method.md, "The contact model").

A taxel whose nearest facing taxel of the other part lies more than ``lateral`` sideways has no skin of
the other part beside it (beyond the edge of a hand's skin): it gets no row.
"""
from __future__ import annotations

import numpy as np
import scipy.spatial

from nao_skin.calibration.context import FitContext

SURFACE_LATERAL = 0.004   # m: the other part's skin counts as beside a taxel up to this far sideways
NEIGHBOURS = 6            # nearest taxels of the other part searched for one that faces the taxel
# m: a fired taxel predicts that the other part's facing taxels this close to it fire. Touching taxels are
# two fabrics apart (about 2 mm) and the lattices (pitch about 6 mm) offset sideways by up to half a pitch,
# so at the true skin every fired taxel has one or two of the other's within it
PREDICT_RADIUS = 0.004


def _in_other_frame(ctx: FitContext, other: int, act: np.ndarray) -> tuple:
    """The activations ``act`` in the other part's chain-end frame, where its taxels are one fixed cloud (one tree
    per call, every touch at once): ``(slots, local, local_n, tree, rot, x, n_own)`` -- the other part's present
    slots with their calibrated positions and normals there and a tree of those positions, its chain-end rotation
    in each activation's touch, the activations' positions and normals in that frame."""
    part = ctx.skin.part(ctx.touches.part_names[other])
    pos_all, nor_all = ctx.placed.slots(part.name)
    slots = part.slots
    local, local_n = pos_all[slots], nor_all[slots]
    fk = ctx.chain_poses(part.name)[ctx.touches.act_touch[act]]
    rot, trans = fk[:, :3, :3], fk[:, :3, 3]
    x = np.einsum("aji,aj->ai", rot, ctx.positions[act] - trans)
    n_own = np.einsum("aji,aj->ai", rot, ctx.normals[act])
    return slots, local, local_n, scipy.spatial.cKDTree(local), rot, x, n_own


def _nearest(tree, x: np.ndarray, k: int, radius: float = np.inf) -> tuple:
    """``(near, within)``: the rows ``(A, k)`` of the ``k`` points of ``tree`` nearest each of ``x`` (0 where none
    is within ``radius``) and whether each is."""
    dist, near = tree.query(x, k=k, distance_upper_bound=radius)
    dist, near = dist.reshape(len(x), k), near.reshape(len(x), k)
    within = np.isfinite(dist)
    return np.where(within, near, 0), within


def _facing(n_own: np.ndarray, local_n: np.ndarray, near: np.ndarray) -> np.ndarray:
    """``(A, k)``: whether each neighbour ``near`` faces its activation (their normals ``n_own``)."""
    return np.einsum("ak,aik->ai", n_own, local_n[near]) < 0.0


def _facing_neighbours(ctx: FitContext, other: int, act: np.ndarray, radius: float = np.inf) -> tuple:
    """The other part's :data:`NEIGHBOURS` nearest taxels to each activation of ``act`` (within ``radius``), in
    that part's chain-end frame (:func:`_in_other_frame`): ``(slots, local, local_n, rot, x, n_own, near,
    facing)`` -- as :func:`_in_other_frame`'s, the neighbours' rows ``(A, k)`` and whether each faces its
    activation (a neighbour past ``radius`` does not)."""
    slots, local, local_n, tree, rot, x, n_own = _in_other_frame(ctx, other, act)
    near, within = _nearest(tree, x, min(NEIGHBOURS, len(slots)), radius)
    return slots, local, local_n, rot, x, n_own, near, within & _facing(n_own, local_n, near)


def surface_rows(ctx: FitContext, pa: int, pb: int, lateral: float = SURFACE_LATERAL) -> list:
    """Surface rows of the part pair ``(pa, pb)`` (indices into ``touches.part_names``; ``pb`` the touched
    part) in the touches where both fire, both ways: ``[(own, other, act, slot, normal, along), ...]`` with
    ``act`` the activations of ``own`` that get a row, ``slot`` the facing slot of ``other``, ``normal`` the
    row's direction (base frame) and ``along`` its signed length under the context's calibration.
    """
    touches = ctx.touches
    fires = touches.parts_of_touch()
    both = fires[:, pa] & fires[:, pb]
    act_touch, act_part = touches.act_touch, touches.act_part
    out = []
    for own, other in ((pa, pb), (pb, pa)):
        act = np.flatnonzero((act_part == own) & both[act_touch])
        if len(act) == 0:
            continue
        slots, local, local_n, rot, x, n_own, near, facing = _facing_neighbours(ctx, other, act)
        first = np.argmax(facing, axis=1)
        found = facing[np.arange(len(act)), first]
        j = near[np.arange(len(act)), first]
        # the touched part's normal: the other's taxel when it is the touched one, else the taxel's own
        n = local_n[j] if other == pb else n_own
        d = x - local[j]
        along = np.einsum("ak,ak->a", d, n)
        side = np.linalg.norm(d - along[:, None] * n, axis=1)
        keep = found & (side <= lateral)
        normal = np.einsum("aij,aj->ai", rot[keep], n[keep])
        out.append((own, other, act[keep], slots[j[keep]], normal, along[keep]))
    return out


def touch_weights(act_touch: np.ndarray, n_touches: int) -> np.ndarray:
    """``1 / sqrt(n)`` per row, ``n`` the rows of its touch and direction: a touch's surface rows of one
    direction weigh as much together as one row of it, however many taxels fire."""
    count = np.bincount(act_touch, minlength=n_touches)
    return 1.0 / np.sqrt(np.maximum(count[act_touch], 1))


def predicted_firing(ctx: FitContext, own: int, other: int, radius: float = PREDICT_RADIUS) -> tuple:
    """Which taxels of part ``other`` the fired taxels of part ``own`` predict fire, in the touches where
    both fire, against which did: ``(predicted, fired)``, each a sorted array of ``touch * S + slot`` codes
    (``S`` the other part's slot count). A fired taxel predicts the other part's taxels that face it within
    ``radius`` (:data:`PREDICT_RADIUS`)."""
    touches = ctx.touches
    fires = touches.parts_of_touch()
    both = fires[:, own] & fires[:, other]
    act_touch, act_part = touches.act_touch, touches.act_part
    name = touches.part_names[other]
    n_slots = ctx.skin.part(name).n_slots
    theirs = np.flatnonzero((act_part == other) & both[act_touch])
    fired = np.unique(act_touch[theirs] * n_slots + touches.act_slot[theirs])
    act = np.flatnonzero((act_part == own) & both[act_touch])
    if len(act) == 0:
        return np.zeros(0, int), fired
    slots, _, _, _, _, _, near, hit = _facing_neighbours(ctx, other, act, radius)
    row, col = np.nonzero(hit)
    predicted = np.unique(act_touch[act[row]] * n_slots + slots[near[row, col]])
    return predicted, fired


def skin_beside(ctx: FitContext, other: int, act: np.ndarray, lateral: float = SURFACE_LATERAL) -> np.ndarray:
    """Per activation of ``act``: whether part ``other``'s skin lies beside it, one of the other part's
    :data:`NEIGHBOURS` taxels nearest it facing it within ``lateral`` sideways (measured along that taxel's
    normal). A press at the edge of a hand's skin fires the torso beyond the edge too; those torso taxels have no
    hand skin beside them, and a COP that counts them is not the hand's (docs/method.md, "The contact model")."""
    if len(act) == 0:
        return np.zeros(0, bool)
    slots, local, local_n, tree, _, x, n_own = _in_other_frame(ctx, other, act)
    # the nearest taxel settles most (on the real recording five in six): when it is beside, one of the
    # neighbours is; the others are searched among all of them
    beside = _beside_among(local, local_n, x, n_own, _nearest(tree, x, 1)[0], lateral)
    rest = np.flatnonzero(~beside)
    if len(rest):
        near, _ = _nearest(tree, x[rest], min(NEIGHBOURS, len(slots)))
        beside[rest] = _beside_among(local, local_n, x[rest], n_own[rest], near, lateral)
    return beside


def _beside_among(local: np.ndarray, local_n: np.ndarray, x: np.ndarray, n_own: np.ndarray, near: np.ndarray,
                  lateral: float) -> np.ndarray:
    """Per activation (at ``x``, normal ``n_own``): whether one of its neighbours ``near`` faces it within
    ``lateral`` sideways."""
    n = local_n[near]
    d = x[:, None] - local[near]
    along = np.einsum("aik,aik->ai", d, n)
    side = np.linalg.norm(d - along[..., None] * n, axis=2)
    return np.any(_facing(n_own, local_n, near) & (side <= lateral), axis=1)
