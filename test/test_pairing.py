"""Pairing of touches (thesis §2.3, §3.2.2): closest COPs, closest taxel pair, up to 5 taxel pairs.

The vectorised pairing is checked against a plain per-touch oracle written
here from the definitions (using SkinModel.taxels_in_base), on the real
recording, under the nominal layout and under a moved calibration.
"""

import numpy as np
import pytest

from nao_skin.calibration.context import activation_positions
from nao_skin.calibration.pairing import KIND_CONTACT_TAXEL, KIND_COP, KIND_TAXEL, KIND_TAXEL5, RowRules, metrics, residuals
from nao_skin.calibration.rows import pair_for_metrics, pair_touches
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate
from nao_skin.touch.touches import TouchSet


def moved_calibration(skin):
    """A clearly non-nominal calibration: hand mount turned and shifted, one torso triangle moved."""
    calib = skin.zero_calibration()
    calib.parts["l_hand"].mount = np.array([0.004, -0.01, 0.02, 0.3, -0.5, 1.2])
    calib.parts["torso"].triangles[3] = np.array([0.0, 0.003, 0.002, 0.0, 0.1, 0.0])
    return calib


# ---------------------------------------------------------------------- oracle
def oracle(touches, skin, calib, t, pa, pb):
    """Per-touch pairing straight from the definitions (slow, obvious)."""
    q = np.zeros((1, len(skin.robot.joint_names)))
    for c, name in enumerate(touches.joint_names):
        q[0, skin.robot.joint_index[name]] = touches.joints[t, c]
    def contacts_of(p):
        out = []
        for c in np.flatnonzero((touches.contact_touch == t) & (touches.contact_part == p)):
            slots = touches.act_slot[touches.act_contact == c]
            pos = skin.taxels_in_base(touches.part_names[p], q, calib, slots[None])[0]
            out.append((slots, pos))
        return out
    A, B = contacts_of(pa), contacts_of(pb)
    best = min(((np.linalg.norm(a[1].mean(0) - b[1].mean(0)), i, j) for i, a in enumerate(A) for j, b in enumerate(B)))
    (sa, pa_pos), (sb, pb_pos) = A[best[1]], B[best[2]]
    d = np.linalg.norm(pa_pos[:, None] - pb_pos[None], axis=2)
    i, j = np.unravel_index(np.argmin(d), d.shape)
    greedy, dd = [], d.copy()
    for _ in range(min(5, len(sa), len(sb))):
        i2, j2 = np.unravel_index(np.argmin(dd), dd.shape)
        greedy.append((sa[i2], sb[j2], d[i2, j2]))
        dd[i2, :] = np.inf
        dd[:, j2] = np.inf
    return best[0], (sa, sb), (sa[i], sb[j], d[i, j]), greedy


def check_against_oracle(touches, skin, calib, rows):
    pairing = pair_touches(touches, skin, calib)
    pa, pb = touches.part_index("l_hand"), touches.part_index("torso")
    for t in rows:
        dcop, (sa, sb), closest, greedy = oracle(touches, skin, calib, t, pa, pb)
        mine = np.flatnonzero(pairing.row_touch == t)
        kinds = pairing.row_kind[mine]
        assert sorted(kinds.tolist()) == [0, 1] + [2] * len(greedy)
        cop_row = mine[kinds == KIND_COP][0]
        assert pairing.distance[cop_row] == pytest.approx(dcop, abs=1e-12)
        terms = pairing.term_row == cop_row
        side_a = terms & (pairing.term_weight > 0)
        assert sorted(pairing.term_slot[side_a].tolist()) == sorted(sa.tolist())
        assert sorted(pairing.term_slot[terms & (pairing.term_weight < 0)].tolist()) == sorted(sb.tolist())
        tax_row = mine[kinds == KIND_TAXEL][0]
        terms = pairing.term_row == tax_row
        assert pairing.distance[tax_row] == pytest.approx(closest[2], abs=1e-12)
        assert pairing.term_slot[terms & (pairing.term_weight > 0)].tolist() == [closest[0]]
        assert pairing.term_slot[terms & (pairing.term_weight < 0)].tolist() == [closest[1]]
        got = []
        for r in mine[kinds == KIND_TAXEL5]:
            terms = pairing.term_row == r
            got.append((pairing.term_slot[terms & (pairing.term_weight > 0)][0],
                        pairing.term_slot[terms & (pairing.term_weight < 0)][0], pairing.distance[r]))
        assert [(a, b) for a, b, _ in got] == [(a, b) for a, b, _ in greedy]
        np.testing.assert_allclose([x[2] for x in got], [x[2] for x in greedy], atol=1e-12)


# ---------------------------------------------------------------------- the real recording
def test_real_figures_under_identity_mount(real, real_skin):
    m = metrics(pair_touches(real, real_skin))
    assert m["n_touches"] == 810
    assert 74.0 < m["cop_mean_mm"] < 80.0          # real_selftouch/README.md: about 77 mm
    assert 66.0 < m["taxel_mean_mm"] < 72.0        # about 69 mm
    assert m["taxel_mean_mm"] <= m["taxel5_mean_mm"]
    assert m["cop_median_mm"] <= m["cop_p90_mm"]


def test_real_pairing_matches_per_touch_oracle_nominal(real, real_skin):
    rows = np.random.default_rng(1).choice(real.n_touches, 40, replace=False)
    check_against_oracle(real, real_skin, None, rows)


def test_real_repairing_under_a_moved_calibration_matches_oracle(real, real_skin):
    calib = moved_calibration(real_skin)
    rows = np.random.default_rng(2).choice(real.n_touches, 40, replace=False)
    check_against_oracle(real, real_skin, calib, rows)
    # and the calibration really changed the answer
    assert metrics(pair_touches(real, real_skin, calib))["cop_mean_mm"] != pytest.approx(
        metrics(pair_touches(real, real_skin))["cop_mean_mm"], abs=1.0)


def test_rows_rebuild_their_distances(real, real_skin):
    """Each row's weighted taxel sum reproduces its pairing distance; each side's weights sum to 1."""
    calib = moved_calibration(real_skin)
    pairing = pair_touches(real, real_skin, calib)
    res = residuals(pairing, real, real_skin, calib)
    np.testing.assert_allclose(np.linalg.norm(res, axis=1), pairing.distance, atol=1e-12)
    assert np.all(np.diff(pairing.term_row) >= 0)
    pos = np.bincount(pairing.term_row, weights=np.clip(pairing.term_weight, 0, None), minlength=pairing.n_rows)
    neg = np.bincount(pairing.term_row, weights=np.clip(pairing.term_weight, None, 0), minlength=pairing.n_rows)
    np.testing.assert_allclose(pos, 1.0)
    np.testing.assert_allclose(neg, -1.0)
    # side A is the hand (hands before torso), terms on each side belong to that side's part
    assert (pairing.row_parts[:, 0] == real.part_index("l_hand")).all()
    side = np.where(pairing.term_weight > 0, 0, 1)
    np.testing.assert_array_equal(pairing.term_part, pairing.row_parts[pairing.term_row, side])


def test_thesis_taxel_rule_is_never_closer_than_closest_pair(real, real_skin):
    """prepareData.m's rule picks one of the candidate pairs, so it can only be farther."""
    closest = pair_touches(real, real_skin, kinds=("taxel",))
    thesis = pair_touches(real, real_skin, kinds=("taxel",), rules=RowRules(taxel_rule="thesis"))
    np.testing.assert_array_equal(closest.row_touch, thesis.row_touch)
    assert np.all(thesis.distance >= closest.distance - 1e-15)
    assert np.any(thesis.distance > closest.distance + 1e-6)


# ---------------------------------------------------------------------- the reported closest taxel pair
def touch_oracle(touches, skin, calib, t, pa, pb):
    """Closest pair among every activated taxel of parts ``pa`` and ``pb`` in touch ``t``: (slot A, slot B, m)."""
    q = np.zeros((1, len(skin.robot.joint_names)))
    for c, name in enumerate(touches.joint_names):
        q[0, skin.robot.joint_index[name]] = touches.joints[t, c]
    def taxels_of(p):
        slots = touches.act_slot[(touches.act_touch == t) & (touches.act_part == p)]
        return slots, skin.taxels_in_base(touches.part_names[p], q, calib, slots[None])[0]
    (sa, pos_a), (sb, pos_b) = taxels_of(pa), taxels_of(pb)
    d = np.linalg.norm(pos_a[:, None] - pos_b[None], axis=2)
    i, j = np.unravel_index(np.argmin(d), d.shape)
    return sa[i], sb[j], d[i, j]


def check_touch_rule(touches, skin, calib, pa, pb):
    """Every touch's reported closest taxel pair is the oracle's; the fitted pair (kind 4) is the
    ``"contacts"`` rule's kind 1 and never closer."""
    p = pair_for_metrics(touches, skin, calib, parts=(pa, pb))
    fitted = pair_touches(touches, skin, calib, kinds=("taxel",), parts=(pa, pb))
    ia, ib = touches.part_index(pa), touches.part_index(pb)
    rows = np.flatnonzero(p.row_kind == KIND_TAXEL)
    assert len(rows) == len(np.unique(p.row_touch)) > 0
    for r in rows:
        slot_a, slot_b, dist = touch_oracle(touches, skin, calib, p.row_touch[r], ia, ib)
        terms = p.term_row == r
        assert p.distance[r] == pytest.approx(dist, abs=1e-12)
        assert p.term_slot[terms & (p.term_weight > 0)].tolist() == [slot_a]
        assert p.term_slot[terms & (p.term_weight < 0)].tolist() == [slot_b]
    contact = p.row_kind == KIND_CONTACT_TAXEL
    np.testing.assert_array_equal(p.row_touch[contact], fitted.row_touch)
    np.testing.assert_array_equal(p.distance[contact], fitted.distance)
    assert np.all(p.distance[rows] <= p.distance[contact] + 1e-15)
    return p.distance[rows], p.distance[contact]


def test_reported_closest_taxel_pair_searches_every_activated_taxel_of_the_touch(real, real_skin):
    for calib in (None, moved_calibration(real_skin)):
        touch_wide, in_contacts = check_touch_rule(real, real_skin, calib, "l_hand", "torso")
        # the real touches hold several contacts per part: the wider search finds closer pairs
        assert np.sum(touch_wide < in_contacts - 1e-6) > 20
    m = metrics(pair_for_metrics(real, real_skin))
    assert m["taxel_mean_mm"] < m["contact_taxel_mean_mm"] == pytest.approx(
        metrics(pair_touches(real, real_skin))["taxel_mean_mm"], abs=1e-12)


def test_reported_closest_taxel_pair_where_the_skins_meet(skin):
    """Simulated touches under their true calibration: the skins meet, so the pruning bound is a
    millimetre or two with other contacts close by, a regime unlike the nominal skin's 7 cm; the
    search must still find the closest pair. Stray contacts (outliers-20) add far ones."""
    for preset, pair in (("default", ("l_hand", "torso")), ("outliers-20", ("r_hand", "head"))):
        sim = simulate(skin, load_params(preset, {"pairs": [list(pair)], "n_touches": 40}), 7)
        check_touch_rule(sim.touches, skin, sim.truth, *pair)


# ---------------------------------------------------------------------- small hand-made touches
def make_touches(skin, touches_spec, joints=None):
    """touches_spec: list of touches, each a list of (part, [slots], [pressures] or None)."""
    parts = tuple(skin.parts)
    jn = tuple(skin.robot.joint_names)
    c_touch, c_part, a_contact, a_slot, a_press = [], [], [], [], []
    for t, spec in enumerate(touches_spec):
        for part, slots, press in spec:
            c = len(c_touch)
            c_touch.append(t)
            c_part.append(parts.index(part))
            a_contact += [c] * len(slots)
            a_slot += list(slots)
            a_press += list(press) if press is not None else [np.nan] * len(slots)
    n = len(touches_spec)
    q = np.zeros((n, len(jn))) if joints is None else joints
    return TouchSet(parts, jn, np.arange(n, dtype=float), [str(i) for i in range(n)], q,
                    np.array(c_touch), np.array(c_part), np.arange(len(c_touch)), np.full((len(c_touch), 3), np.nan),
                    np.array(a_contact), np.array(a_slot), np.array(a_press, dtype=float))


def test_cop_weights_follow_pressure(skin):
    hand, torso = skin.parts["r_hand"].slots, skin.parts["torso"].slots
    ts = make_touches(skin, [[("r_hand", hand[:3], [1.0, 1.0, 2.0]), ("torso", torso[:2], None)]])
    pairing = pair_touches(ts, skin, kinds=("cop",))
    assert pairing.n_rows == 1
    np.testing.assert_allclose(pairing.term_weight, [0.25, 0.25, 0.5, -0.5, -0.5])
    pos = activation_positions(ts, skin)
    expected = 0.25 * pos[0] + 0.25 * pos[1] + 0.5 * pos[2] - 0.5 * (pos[3] + pos[4])
    assert pairing.distance[0] == pytest.approx(np.linalg.norm(expected), abs=1e-12)


def test_three_parts_give_three_ordered_pairs_and_parts_filter(skin):
    rh, lh, to = (skin.parts[n].slots for n in ("r_hand", "l_hand", "torso"))
    ts = make_touches(skin, [[("torso", to[:2], None), ("l_hand", lh[:2], None), ("r_hand", rh[:2], None)],
                             [("torso", to[5:7], None), ("l_hand", lh[5:8], None)]])
    pairing = pair_touches(ts, skin, kinds=("cop",))
    names = [(ts.part_names[a], ts.part_names[b]) for a, b in pairing.row_parts]
    assert pairing.row_touch.tolist() == [0, 0, 0, 1]
    assert names == [("r_hand", "l_hand"), ("r_hand", "torso"), ("l_hand", "torso"), ("l_hand", "torso")]
    only = pair_touches(ts, skin, kinds=("cop", "taxel"), parts=("torso", "l_hand"))
    assert only.row_touch.tolist() == [0, 0, 1, 1]
    assert {(ts.part_names[a], ts.part_names[b]) for a, b in only.row_parts} == {("torso", "l_hand")}
    assert only.row_kind.tolist() == [KIND_COP, KIND_TAXEL, KIND_COP, KIND_TAXEL]


def test_taxel5_uses_each_taxel_once_and_at_most_min_count(skin):
    lh, to = skin.parts["l_hand"].slots, skin.parts["torso"].slots
    ts = make_touches(skin, [[("l_hand", lh[:8], None), ("torso", to[:3], None)],
                             [("l_hand", lh[10:17], None), ("torso", to[20:30], None)]])
    pairing = pair_touches(ts, skin, kinds=("taxel5",))
    assert (pairing.row_kind == KIND_TAXEL5).all()
    assert np.bincount(pairing.row_touch).tolist() == [3, 5]
    for t in (0, 1):
        rows = np.flatnonzero(pairing.row_touch == t)
        terms = np.isin(pairing.term_row, rows)
        a = pairing.term_slot[terms & (pairing.term_weight > 0)]
        b = pairing.term_slot[terms & (pairing.term_weight < 0)]
        assert len(set(a)) == len(a) and len(set(b)) == len(b)
        assert np.all(np.diff(pairing.distance[rows]) >= 0)       # greedy picks come closest first


def test_single_part_touch_gives_no_row_and_metrics_of_nothing(skin):
    ts = make_touches(skin, [[("torso", skin.parts["torso"].slots[:3], None)]])
    pairing = pair_touches(ts, skin)
    assert pairing.n_rows == 0
    m = metrics(pairing)
    assert m["n_touches"] == 0 and np.isnan(m["cop_mean_mm"])


def test_normal_rows_ask_the_touching_normals_to_cancel(real_skin, real):
    """The solver's normal rows: one per closest-taxel row (COP rows when there are none),
    both sides' normals added with the weight, so facing surfaces give zero."""
    from nao_skin.calibration.pairing import KIND_COP, KIND_NORMAL, KIND_TAXEL
    from nao_skin.calibration.rows import select_rows, with_normal_rows

    touches = real.subset(np.arange(40))
    full = pair_touches(touches, real_skin, None, kinds=("cop", "taxel"))
    selected = select_rows(full, (KIND_COP, KIND_TAXEL))
    out = with_normal_rows(selected, full, 0.005)
    normal = out.row_kind == KIND_NORMAL
    n_taxel = int(np.sum(full.row_kind == KIND_TAXEL))
    assert normal.sum() == n_taxel and out.n_rows == selected.n_rows + n_taxel
    w = out.term_weight[normal[out.term_row]]
    assert np.all(w > 0)
    # each normal row's weights sum to the weight on each side (two sides)
    sums = np.bincount(out.term_row, weights=out.term_weight, minlength=out.n_rows)[normal]
    np.testing.assert_allclose(sums, 2 * 0.005)
    cop_only = select_rows(full, (KIND_COP,))
    from_cop = with_normal_rows(cop_only, cop_only, 0.005)
    assert int(np.sum(from_cop.row_kind == KIND_NORMAL)) == cop_only.n_rows
    assert with_normal_rows(selected, full, 0.0) is selected


def test_argmin_per_group_matches_its_definition_sorted_or_not():
    """The sort-free path (groups already contiguous) and the sorting path agree with a plain loop,
    ties going to the lowest index."""
    from nao_skin.calibration.segments import argmin_per_group

    rng = np.random.default_rng(0)
    for trial in range(200):
        n = int(rng.integers(1, 150))
        group = np.sort(rng.integers(0, 20, n)) if trial % 2 == 0 else rng.integers(0, 20, n)
        key = rng.integers(0, 4, n).astype(float) if trial % 3 == 0 else rng.normal(size=n)
        expected = [np.flatnonzero(group == g)[np.argmin(key[group == g])] for g in np.unique(group)]
        assert np.array_equal(argmin_per_group(group, key), expected), trial
