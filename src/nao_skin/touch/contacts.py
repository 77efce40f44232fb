"""Contacts: clusters of activated taxels on one skin part, with their centre of pressure.

skinManager groups the activated taxels of a part into contacts: taxels whose
neighbours are within ``maxNeighborDist`` (12 mm by default) belong to one
contact. Its centre of pressure (COP) is the pressure-weighted mean of the
taxel positions (plain mean when no pressure is known), its geometric centre
the plain mean, its normal the normalised mean of the taxel normals.

Recorded skinManager contacts keep their taxel lists; their COP is always
recomputed from the current (calibrated) taxel positions, since the recorder's
COP belongs to the nominal layout. Activations that arrive without a
skinManager contact (``contact_id == -1``, raw compensated taxel ports) are
clustered here. Everything runs over all touches at once.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch import DEFAULT_MAX_NEIGHBOR_DIST
from nao_skin.touch.touches import TouchSet

_GROUP_SPACING = 1000.0             # metres between groups in the joint KD-tree: far beyond any skin


@dataclass
class ContactGeometry:
    """Per contact, in its part's local (chain end) frame under one calibration."""

    cop: np.ndarray          # (C, 3) centre of pressure
    geo_center: np.ndarray   # (C, 3) plain mean of the taxel positions
    normal: np.ndarray       # (C, 3) unit mean normal (zero if the normals cancel)
    n_taxels: np.ndarray     # (C,) activated taxels


def activation_local(touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None = None,
                     normals: bool = True) -> tuple:
    """``(positions, normals)`` of every activation, ``(A, 3)`` each, in its part's local frame
    (normals None unless asked for: pairing needs only the positions)."""
    pos = np.full((len(touches.act_slot), 3), np.nan)
    nor = np.full_like(pos, np.nan) if normals else None
    for p, (name, sel) in enumerate(zip(touches.part_names, activations_by_part(touches))):   # <= 4 parts
        if len(sel) == 0:
            continue
        part = skin.part(name)
        corr = calib.parts.get(name) if calib is not None else None
        local_pos, local_nor = part.taxel_positions(corr)
        pos[sel] = local_pos[touches.act_slot[sel]]
        if normals:
            nor[sel] = local_nor[touches.act_slot[sel]]
    return pos, nor


def activations_by_part(touches: TouchSet) -> list:
    """Rows of the activations of each part (in ``part_names`` order); computed once per touch set."""
    return touches.derived(("activations by part",),
                           lambda: [_read_only(np.flatnonzero(touches.act_part == p)) for p in range(len(touches.part_names))])


def _read_only(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)      # shared by every caller (TouchSet.derived)
    return a


def cop_weights(touches: TouchSet) -> np.ndarray:
    """(A,) weight of each activation in its contact's COP; each contact's weights sum to 1.

    Pressure-normalised when every taxel of the contact has a finite positive
    pressure sum, else 1/n (a binarised or pressure-less recording). Computed
    once per touch set (pairing asks at every re-pairing).
    """
    return touches.derived(("cop weights",), lambda: _read_only(_cop_weights(touches)))


def _cop_weights(touches: TouchSet) -> np.ndarray:
    n_c = len(touches.contact_touch)
    c = touches.act_contact
    p = touches.act_pressure
    count = np.bincount(c, minlength=n_c).astype(float)
    finite = np.bincount(c, weights=np.isfinite(p), minlength=n_c)
    total = np.bincount(c, weights=np.where(np.isfinite(p), p, 0.0), minlength=n_c)
    use_pressure = (finite == count) & (total > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        weighted = np.where(np.isfinite(p), p, 0.0) / total[c]
        plain = 1.0 / count[c]
    return np.where(use_pressure[c], weighted, plain)


def segment_mean(values: np.ndarray, segment: np.ndarray, n_segments: int, weights: np.ndarray | None = None):
    """Weighted sums of ``(A, 3)`` rows per segment id (weights default to 1/count)."""
    if weights is None:
        count = np.bincount(segment, minlength=n_segments).astype(float)
        weights = 1.0 / count[segment]
    # one bincount per column: np.add.at is an order of magnitude slower on hot paths (pairing)
    weighted = values * weights[:, None]
    return np.stack([np.bincount(segment, weights=weighted[:, d], minlength=n_segments)
                     for d in range(values.shape[1])], axis=1)


def contact_geometry(touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None = None,
                     local: tuple | None = None) -> ContactGeometry:
    """COP, geometric centre and normal of every contact under ``calib`` (local frames)."""
    pos, nor = local if local is not None else activation_local(touches, skin, calib)
    n_c = len(touches.contact_touch)
    cop = segment_mean(pos, touches.act_contact, n_c, cop_weights(touches))
    geo = segment_mean(pos, touches.act_contact, n_c)
    normal = segment_mean(nor, touches.act_contact, n_c)
    norm = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, norm, out=np.zeros_like(normal), where=norm > 1e-12)
    return ContactGeometry(cop, geo, normal, np.bincount(touches.act_contact, minlength=n_c))


def cluster_labels(positions: np.ndarray, group: np.ndarray, max_neighbor_dist: float) -> np.ndarray:
    """Connected components of points closer than ``max_neighbor_dist`` within the same ``group``.

    One KD-tree over all points: groups are shifted far apart so no pair
    crosses a group. Labels are numbered in order of first appearance.
    """
    n = len(positions)
    if n == 0:
        return np.zeros(0, dtype=int)
    shifted = np.asarray(positions, dtype=float).copy()
    shifted[:, 0] += np.asarray(group, dtype=float) * _GROUP_SPACING
    pairs = cKDTree(shifted).query_pairs(r=max_neighbor_dist, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=int)
    rank[np.argsort(first)] = np.arange(len(first))
    return rank[inverse]


def cluster_contacts(touches: TouchSet, skin: SkinModel, calib: SkinCalibration | None = None,
                     max_neighbor_dist: float = DEFAULT_MAX_NEIGHBOR_DIST, recluster_all: bool = False) -> TouchSet:
    """Split contacts into skinManager-style clusters.

    By default only contacts without a skinManager id (``contact_id == -1``:
    raw taxel data, all activations of a part in one provisional contact) are
    split; recorded contacts are kept. ``recluster_all=True`` re-clusters every
    contact, e.g. after a calibration has moved the taxels. New contacts get
    id -1 and no recorded COP (NaN).
    """
    if len(touches.act_slot) == 0:
        return touches
    todo = np.ones(len(touches.contact_touch), dtype=bool) if recluster_all else touches.contact_id == -1
    if not np.any(todo):
        return touches
    pos, _ = activation_local(touches, skin, calib)
    act_todo = todo[touches.act_contact]
    sel = np.flatnonzero(act_todo)
    # keep contacts untouched where not asked; cluster the rest per (old contact)
    labels = cluster_labels(pos[sel], touches.act_contact[sel], max_neighbor_dist)
    n_new = labels.max() + 1
    # each new cluster inherits touch and part of the contact it came from
    src_contact = np.zeros(n_new, dtype=int)
    src_contact[labels] = touches.act_contact[sel]
    kept = np.flatnonzero(~todo)
    # contact rows: kept ones and new clusters, ordered by touch then by first appearance
    old_of_row = np.concatenate([kept, src_contact])
    is_new = np.concatenate([np.zeros(len(kept), bool), np.ones(n_new, bool)])
    order = np.lexsort((np.arange(len(old_of_row)), old_of_row, touches.contact_touch[old_of_row]))
    new_row = np.empty(len(order), dtype=int)
    new_row[order] = np.arange(len(order))
    act_contact = np.empty(len(touches.act_contact), dtype=int)
    kept_row = np.full(len(touches.contact_touch), -1)
    kept_row[kept] = new_row[: len(kept)]
    act_contact[~act_todo] = kept_row[touches.act_contact[~act_todo]]
    act_contact[sel] = new_row[len(kept) + labels]
    src = old_of_row[order]
    cop = touches.contact_cop[src].copy()
    cop[is_new[order]] = np.nan
    cid = touches.contact_id[src].copy()
    cid[is_new[order]] = -1
    # activations grouped by their contact row, as TouchSet readers expect
    act_order = np.argsort(act_contact, kind="stable")
    return TouchSet(touches.part_names, touches.joint_names, touches.stamps, list(touches.keys), touches.joints,
                    touches.contact_touch[src], touches.contact_part[src], cid, cop,
                    act_contact[act_order], touches.act_slot[act_order], touches.act_pressure[act_order],
                    dict(touches.labels), touches.fingertips, touches.touch_fingertip)
