"""Contacts: maxNeighborDist clustering, COP / geometric centre / normal, recorded contacts kept."""
import numpy as np
import pytest

from nao_skin.model.skin import SkinModel
from nao_skin.paths import default_skin_config
from nao_skin.touch.contacts import (DEFAULT_MAX_NEIGHBOR_DIST, activation_local, cluster_contacts, cluster_labels,
                                     contact_geometry, cop_weights)
from nao_skin.touch.touches import TouchSet


@pytest.fixture(scope="module")
def skin():
    return SkinModel.from_yaml(default_skin_config())


def touchset(skin, contacts):
    """contacts: list of (touch, part, contact_id, slots, pressures or None)."""
    parts = tuple(skin.parts)
    n = max(c[0] for c in contacts) + 1
    a_contact, a_slot, a_press = [], [], []
    for i, (_, _, _, slots, press) in enumerate(contacts):
        a_contact += [i] * len(slots)
        a_slot += list(slots)
        a_press += list(press) if press is not None else [np.nan] * len(slots)
    return TouchSet(parts, tuple(skin.robot.joint_names), np.arange(n, dtype=float), [str(i) for i in range(n)],
                    np.zeros((n, len(skin.robot.joint_names))), np.array([c[0] for c in contacts]),
                    np.array([parts.index(c[1]) for c in contacts]), np.array([c[2] for c in contacts]),
                    np.full((len(contacts), 3), np.nan), np.array(a_contact), np.array(a_slot),
                    np.array(a_press, dtype=float))


def test_cluster_labels_chain_threshold_and_groups():
    # five points 10 mm apart on a line: one cluster at 12 mm (neighbour of a neighbour), five at 8 mm
    line = np.c_[np.arange(5) * 0.010, np.zeros(5), np.zeros(5)]
    assert cluster_labels(line, np.zeros(5, int), 0.012).tolist() == [0, 0, 0, 0, 0]
    assert cluster_labels(line, np.zeros(5, int), 0.008).tolist() == [0, 1, 2, 3, 4]
    # the same points in two groups never merge across groups
    pts = np.r_[line[:2], line[:2]]
    assert cluster_labels(pts, np.array([0, 0, 1, 1]), 0.012).tolist() == [0, 0, 1, 1]
    assert cluster_labels(np.zeros((0, 3)), np.zeros(0, int), 0.012).tolist() == []


def two_distant_triangles(skin, part="r_hand"):
    p = skin.parts[part]
    tri = p.slot_triangle
    first = p.slots[tri[p.slots] == 0][:4]
    centre0 = p.positions[first].mean(axis=0)
    # the triangle whose taxels are farthest from triangle 0
    far_t = max(set(tri[p.slots].tolist()), key=lambda t: np.linalg.norm(p.positions[p.slots[tri[p.slots] == t]].mean(0) - centre0))
    second = p.slots[tri[p.slots] == far_t][:3]
    return first, second


def test_unclustered_activations_are_split_recorded_contacts_kept(skin):
    a, b = two_distant_triangles(skin)
    t_slots = skin.parts["torso"].slots[:2]
    ts = touchset(skin, [(0, "r_hand", -1, np.r_[a, b], None), (0, "torso", 7, t_slots, None),
                         (1, "r_hand", 3, np.r_[a, b], None), (1, "torso", 4, t_slots, None)])
    out = cluster_contacts(ts, skin)
    # touch 0: the raw hand activations become two contacts; touch 1: skinManager's contact is kept as it is
    assert out.contact_touch.tolist() == [0, 0, 0, 1, 1]
    hand = out.part_index("r_hand")
    assert out.contact_part.tolist() == [hand, hand, out.part_index("torso"), hand, out.part_index("torso")]
    assert out.contact_id.tolist() == [-1, -1, 7, 3, 4]
    groups = [sorted(out.act_slot[out.act_contact == c].tolist()) for c in range(5)]
    assert groups[:2] == [sorted(a.tolist()), sorted(b.tolist())]
    assert groups[3] == sorted(np.r_[a, b].tolist())
    assert np.all(np.diff(out.act_contact) >= 0)
    # asked to, it re-clusters recorded contacts too
    again = cluster_contacts(ts, skin, recluster_all=True)
    assert len(again.contact_touch) == 6
    # with a threshold larger than the part, everything stays together
    assert len(cluster_contacts(ts, skin, max_neighbor_dist=1.0).contact_touch) == 4


def test_default_threshold_keeps_a_triangle_together(skin):
    a, _ = two_distant_triangles(skin)
    ts = touchset(skin, [(0, "r_hand", -1, a, None)])
    assert DEFAULT_MAX_NEIGHBOR_DIST == pytest.approx(0.012)
    assert len(cluster_contacts(ts, skin).contact_touch) == 1


def test_cop_geo_center_and_normal(skin):
    a, _ = two_distant_triangles(skin, "torso")
    press = np.array([1.0, 3.0, 0.0, 4.0])
    ts = touchset(skin, [(0, "torso", 0, a, press), (0, "torso", 1, a, [1.0, np.nan, 1.0, 1.0])])
    w = cop_weights(ts)
    np.testing.assert_allclose(w[:4], press / press.sum())
    np.testing.assert_allclose(w[4:], 0.25)             # one unknown pressure: plain mean
    g = contact_geometry(ts, skin)
    pos = skin.parts["torso"].positions[a]
    np.testing.assert_allclose(g.cop[0], (press[:, None] * pos).sum(0) / press.sum(), atol=1e-12)
    np.testing.assert_allclose(g.cop[1], pos.mean(0), atol=1e-12)
    np.testing.assert_allclose(g.geo_center, [pos.mean(0)] * 2, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(g.normal, axis=1), 1.0)
    assert g.n_taxels.tolist() == [4, 4]


def test_cop_follows_the_calibration(skin):
    """Recorded contacts keep their taxels; their COP is recomputed from the calibrated layout."""
    a, b = two_distant_triangles(skin)
    ts = touchset(skin, [(0, "r_hand", 0, a, None), (0, "r_hand", 1, b, None)])
    calib = skin.zero_calibration()
    shift = np.array([0.002, -0.003, 0.004])
    calib.parts["r_hand"].mount[:3] = shift
    rot = skin.parts["r_hand"].mount_nominal[:3, :3]
    moved = contact_geometry(ts, skin, calib).cop - contact_geometry(ts, skin).cop
    np.testing.assert_allclose(moved, [rot @ shift] * 2, atol=1e-12)
    local, _ = activation_local(ts, skin, calib)
    np.testing.assert_allclose(local, skin.parts["r_hand"].positions[ts.act_slot] + rot @ shift, atol=1e-12)
