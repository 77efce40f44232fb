"""Self-touch events from separate joint and skin streams (events.EventDetector).

Streams are synthesised here at realistic rates (joints 100 Hz, skin 50 Hz
per part with its own phase); joint angles move linearly in time so the
interpolated angles at a skin stamp are known exactly.
"""
import numpy as np
import pytest

from nao_skin.model.skin import SkinModel
from nao_skin.paths import default_skin_config
from nao_skin.touch.events import RECOVERED, EventConfig, EventDetector, touchset_from_records


@pytest.fixture(scope="module")
def skin():
    return SkinModel.from_yaml(default_skin_config())


def angles(names, t):
    """Joint angles moving linearly in time: a known answer for interpolation (starting over every 20 s, so
    they stay angles a joint reaches, within two turns; a test interpolates within one period)."""
    return np.array([0.02 * (i + 1) * (t % 20.0) + 0.01 * i for i in range(len(names))])


def run(det, skin, t_end, presses, joint_rate=100.0, skin_rate=50.0, joint_gap=None, drop_joint=None,
        phases=None, mis_stamped=()):
    """Feed time-ordered messages; ``presses``: part -> function(t) giving active slots at t;
    ``mis_stamped``: ``(arrival, stamp)`` of joint states that arrive at one time stamped with another."""
    names = list(skin.robot.joint_names)
    if drop_joint:
        names.remove(drop_joint)
    msgs = []
    for t in np.arange(0.0, t_end, 1.0 / joint_rate):
        if joint_gap and joint_gap[0] <= t < joint_gap[1]:
            continue
        msgs.append((t, 0, "joints", None))
    for k, part in enumerate(presses):
        phase = (phases or {}).get(part, 0.003 * (k + 1))
        for t in np.arange(phase, t_end, 1.0 / skin_rate):
            msgs.append((t, 1, "skin", part))
    msgs += [(arrival, 0, "joints", stamp) for arrival, stamp in mis_stamped]
    msgs.sort(key=lambda m: (m[0], m[1]))
    out = []
    for t, _, what, part in msgs:
        if what == "joints":
            t = t if part is None else part
            out += det.add_joint_state(t, names, angles(skin.robot.joint_names, t)[[skin.robot.joint_index[n] for n in names]])
        else:
            out += det.add_skin(t, part, presses[part](t))
    return out + det.flush()


def hand_and_torso(skin, t0=0.2, t1=0.6):
    hand = skin.parts["l_hand"].slots[:4].tolist()
    torso = skin.parts["torso"].slots[:3].tolist()
    return {"l_hand": lambda t: hand if t0 <= t < t1 else [],
            "torso": lambda t: torso if t0 <= t < t1 else []}


def test_one_press_is_one_touch_with_interpolated_joints(skin):
    det = EventDetector.for_skin(skin)
    recs = run(det, skin, 1.0, hand_and_torso(skin))
    assert len(recs) == 1
    r = recs[0]
    assert 0.2 <= r.stamp < 0.25
    np.testing.assert_allclose(r.joints, angles(skin.robot.joint_names, r.stamp), atol=1e-12)
    assert sorted(det.part_names[c.part] for c in r.contacts) == ["l_hand", "torso"]
    assert det.counts["touches"] == 1 and det.counts["continued press"] > 5


def test_release_and_press_again_gives_a_new_touch(skin):
    hand = skin.parts["l_hand"].slots[:4].tolist()
    torso = skin.parts["torso"].slots[:3].tolist()
    on = lambda t: (0.2 <= t < 0.5) or (0.7 <= t < 0.9)     # noqa: E731
    presses = {"l_hand": lambda t: hand if on(t) else [], "torso": lambda t: torso if on(t) else []}
    det = EventDetector.for_skin(skin)
    assert [round(r.stamp, 1) for r in run(det, skin, 1.2, presses)] == [0.2, 0.7]


def test_changing_pattern_during_a_press_is_rate_limited(skin):
    hand = skin.parts["l_hand"].slots
    torso = skin.parts["torso"].slots[:3].tolist()
    # the hand slides: a new taxel set every frame for one second
    presses = {"l_hand": lambda t: hand[int(t * 50) % 40: int(t * 50) % 40 + 3].tolist(), "torso": lambda t: torso}
    det = EventDetector.for_skin(skin, EventConfig(min_interval=0.2))
    recs = run(det, skin, 1.0, presses)
    stamps = np.array([r.stamp for r in recs])
    assert 4 <= len(recs) <= 6
    assert np.all(np.diff(stamps) >= 0.2 - 1e-9)
    det = EventDetector.for_skin(skin, EventConfig(min_interval=0.0))
    assert len(run(det, skin, 1.0, presses)) >= 45              # every distinct pattern


def test_stale_or_missing_joints_drop_and_count(skin):
    # a press held wholly inside a gap of the joint states: lost, counted once (not once per moment tried)
    det = EventDetector.for_skin(skin, EventConfig(joint_tolerance=0.05))
    assert run(det, skin, 1.0, hand_and_torso(skin, 0.2, 0.35), joint_gap=(0.1, 0.4)) == []
    assert det.drops() == {"stale joints": 1}
    assert "more than 0.05 s away" in det.notes[0] and "\n" not in det.notes[0]

    det = EventDetector.for_skin(skin)
    assert run(det, skin, 1.0, hand_and_torso(skin), drop_joint="LElbowRoll") == []
    assert det.counts["missing joint"] == 1 and "'LElbowRoll'" in det.notes[0]
    # a joint no touching part needs may be missing
    det = EventDetector.for_skin(skin)
    assert len(run(det, skin, 1.0, hand_and_torso(skin), drop_joint="HeadYaw")) == 1


@pytest.mark.parametrize("gap", [(0.1, 0.4), (0.0, 0.4)])
def test_a_press_held_through_a_gap_in_the_joint_states_is_recorded_once_they_are_back(skin, gap):
    """A press starting while the joint states stall (a WiFi hiccup of NAOqi; from 0.0: the joint stream starts
    late) was lost whole: its first moment was dropped and every later one, of the same pattern, counted as
    the same press. Now the press's next moment min_interval on is tried again: one touch, at the first moment
    with joint states around it, with that moment's angles; nothing counted as dropped."""
    det = EventDetector.for_skin(skin, EventConfig(joint_tolerance=0.05))
    (touch,) = run(det, skin, 1.0, hand_and_torso(skin, 0.2, 0.6), joint_gap=gap)
    assert 0.4 <= touch.stamp < 0.45
    np.testing.assert_allclose(touch.joints, angles(skin.robot.joint_names, touch.stamp), atol=1e-12)
    assert det.drops() == {} and det.counts[RECOVERED] == 1 and det.counts["touches"] == 1
    assert "tried again" in det.notes[0]


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, 1e300, -100.0])
def test_a_non_finite_angle_drops_the_touch_that_needs_it_and_leaves_the_others(skin, bad):
    """An infinite HeadYaw in a bag was kept in hand-torso touches: every FK of the head chain then warned.
    An angle beyond two turns is no more a measurement: no joint of an arm or a head reaches it."""
    names = skin.robot.joint_names
    q = np.zeros(len(names))
    q[skin.robot.joint_index["LWristYaw"]] = bad
    q[skin.robot.joint_index["HeadYaw"]] = bad       # needed by no part of the touch: as if not reported
    det = EventDetector.for_skin(skin)
    det.add_joint_state(0.0, names, q)
    det.add_skin(0.01, "l_hand", [skin.parts["l_hand"].slots[0]])
    det.add_skin(0.01, "torso", [skin.parts["torso"].slots[0]])
    det.add_joint_state(0.02, names, q)
    assert det.flush() == [] and det.counts["missing joint"] == 1
    q[skin.robot.joint_index["LWristYaw"]] = 0.0
    det = EventDetector.for_skin(skin)
    det.add_joint_state(0.0, names, q)
    det.add_skin(0.01, "l_hand", [skin.parts["l_hand"].slots[0]])
    det.add_skin(0.01, "torso", [skin.parts["torso"].slots[0]])
    det.add_joint_state(0.02, names, q)
    (touch,) = det.flush()
    assert np.isnan(touch.joints[skin.robot.joint_index["HeadYaw"]])


def presses_every(skin, period, duration, t_end):
    hand = skin.parts["l_hand"].slots[:4].tolist()
    torso = skin.parts["torso"].slots[:3].tolist()
    on = lambda t: (t % period) < duration and t < t_end   # noqa: E731
    return {"l_hand": lambda t: hand if on(t) else [], "torso": lambda t: torso if on(t) else []}


@pytest.mark.parametrize("first", [False, True])
def test_one_joint_state_stamped_far_ahead_loses_no_touch(skin, first):
    """One JointState stamped 1e7 s ahead aged every real one out: the recorder dropped every later touch as
    'stamp out of order' (13 touches of a session became 1), without a word."""
    presses = presses_every(skin, 1.0, 0.3, 9.0)
    plain = run(EventDetector.for_skin(skin), skin, 10.0, presses)
    assert len(plain) == 9
    det = EventDetector.for_skin(skin)
    ahead = [(0.0 if first else 2.505, 1e7 + 2.5), (6.505, 1e7 + 6.5)]
    recs = run(det, skin, 10.0, presses, mis_stamped=ahead)
    assert [r.stamp for r in recs] == [r.stamp for r in plain]
    assert det.counts["joint state stamped ahead"] == 2 and det.counts["stamp out of order"] == 0
    # a clock that really jumps ahead (a new session's time) is followed, from its second joint state on
    det = EventDetector.for_skin(skin)
    names = skin.robot.joint_names
    out = []
    for t0 in (0.0, 1e6):
        for k in range(100):
            t = t0 + 0.01 * k
            out += det.add_joint_state(t, names, angles(names, t))
            if 0.5 <= t - t0 < 0.53:
                out += det.add_skin(t + 0.001, "l_hand", presses["l_hand"](0.0))
                out += det.add_skin(t + 0.001, "torso", presses["torso"](0.0))
    out += det.flush()
    assert len(out) == 2 and out[1].stamp > 1e6 and det.counts["joint state stamped ahead"] == 0


def test_a_skin_sample_stamped_far_back_makes_no_touch_twice(skin):
    """Torso samples stamped at 100 s amid a session's made the next real sample a new press: 51 touches
    stored where 13 were pressed."""
    hand = skin.parts["l_hand"].slots[:4].tolist()
    torso = skin.parts["torso"].slots[:3].tolist()
    base = 1000.0
    det = EventDetector.for_skin(skin)
    out = []
    for k in range(200):                      # one press of both parts from 0.2 to 1.8 s, a bad torso sample each 0.1 s
        t = base + 0.01 * k
        out += det.add_joint_state(t, skin.robot.joint_names, angles(skin.robot.joint_names, t))
        if k % 2 == 0:
            on = 20 <= k < 180
            out += det.add_skin(t + 0.001, "l_hand", hand if on else [])
            out += det.add_skin(t + 0.002, "torso", torso if on else [])
        if k % 10 == 5:
            out += det.add_skin(100.0, "torso", torso)
    out += det.flush()
    assert len(out) == 1 and det.counts["skin stamped behind"] == 20
    # a skin clock that really goes back (a second session after the first) is followed from its second sample
    # (the joint states' is not: their history keeps the latest 5 s, so such touches are dropped, and named)
    for k in range(100):
        t = 0.01 * k
        out += det.add_joint_state(t, skin.robot.joint_names, angles(skin.robot.joint_names, t))
        if k % 2 == 0:
            out += det.add_skin(t + 0.001, "l_hand", hand if 20 <= k < 60 else [])
            out += det.add_skin(t + 0.002, "torso", torso if 20 <= k < 60 else [])
    out += det.flush()
    assert det.counts["skin stamped behind"] == 22 and det.counts["continued press"] > 10


def test_joints_arriving_late_still_complete_the_touch(skin):
    """Skin delivered before the joint state that follows its stamp (different transports)."""
    det = EventDetector.for_skin(skin)
    names = skin.robot.joint_names
    assert det.add_joint_state(0.00, names, angles(names, 0.0)) == []
    assert det.add_skin(0.013, "l_hand", [skin.parts["l_hand"].slots[0]]) == []
    assert det.add_skin(0.015, "torso", [skin.parts["torso"].slots[0]]) == []
    assert det.add_skin(0.080, "torso", []) == []                # closes the moment; joints still missing
    out = det.add_joint_state(0.02, names, angles(names, 0.02))
    assert len(out) == 1 and out[0].stamp == pytest.approx(0.015)
    np.testing.assert_allclose(out[0].joints, angles(names, 0.015), atol=1e-12)
    # without any later joint state, flush drops and counts it
    det.add_skin(1.0, "l_hand", [skin.parts["l_hand"].slots[1]])
    det.add_skin(1.0, "torso", [skin.parts["torso"].slots[1]])
    assert det.flush() == [] and det.counts["no joint state after"] == 1


def test_three_parts_in_one_moment_and_contacts(skin):
    det = EventDetector.for_skin(skin)
    names = skin.robot.joint_names
    det.add_joint_state(0.45, names, np.zeros(len(names)))
    rh, lh, to = (skin.parts[p].slots for p in ("r_hand", "l_hand", "torso"))
    det.add_contacts(0.5, "torso", [4], np.array([[0.05, 0.0, 0.02]]))        # contacts before their taxels
    det.add_skin(0.5, "torso", to[:3], [1.0, 2.0, 3.0], [4, 4, 4])
    det.add_skin(0.51, "r_hand", rh[:2], None, [1, 2])
    det.add_skin(0.515, "l_hand", lh[:2])
    det.add_contacts(0.51, "r_hand", [1, 2], np.array([[0.0, 0.0, 0.1], [0.0, 0.0, 0.2]]))
    det.add_skin(0.55, "head", [skin.parts["head"].slots[0]])                 # alone, later: no touch
    det.add_skin(0.6, "nose", [3])
    recs = det.add_joint_state(0.6, names, np.zeros(len(names))) + det.flush()
    assert len(recs) == 1 and det.counts["unknown skin part"] == 1
    ts = touchset_from_records(recs, det.part_names, det.joint_names)
    assert ts.n_touches == 1 and sorted(ts.part_names[p] for p in set(ts.contact_part)) == ["l_hand", "r_hand", "torso"]
    by_part = {ts.part_names[p]: i for i, p in enumerate(ts.contact_part)}
    assert ts.contact_id.tolist().count(-1) == 1                              # l_hand sent no contact ids
    torso = by_part["torso"]
    np.testing.assert_allclose(ts.contact_cop[torso], [0.05, 0.0, 0.02])
    np.testing.assert_allclose(ts.act_pressure[ts.act_contact == torso], [1.0, 2.0, 3.0])
    r_rows = np.flatnonzero(ts.contact_part == ts.part_index("r_hand"))
    assert ts.contact_id[r_rows].tolist() == [1, 2]
    np.testing.assert_allclose(ts.contact_cop[r_rows][:, 2], [0.1, 0.2])


def test_a_touch_stamped_out_of_order_is_named_and_its_neighbours_kept(skin):
    """Touch-bag input (exact stamps): one touch's messages stamped 20 s early, as a clock step would.

    The touch before it used to be lost without a word (its moment replaced
    unclosed); the early one is dropped with its own reason.
    """
    det = EventDetector.for_skin(skin, EventConfig(skin_tolerance=0.0, joint_tolerance=0.0, min_interval=0.0,
                                                   release_gap=0.0))
    names = skin.robot.joint_names
    hand = skin.parts["l_hand"].slots[:4].tolist()
    torso = skin.parts["torso"].slots[:3].tolist()
    stamps = [100.0 + 2.0 * k for k in range(12)]
    stamps[6] -= 20.0
    out = []
    for k, t in enumerate(stamps):
        out += det.add_joint_state(t, names, angles(names, t))
        out += det.add_skin(t, "l_hand", hand if k % 2 else hand[:2])
        out += det.add_skin(t, "torso", torso)
    out += det.flush()
    assert sorted(r.stamp for r in out) == sorted(stamps[:6] + stamps[7:])
    # both parts' samples of it lie 20 s behind the parts' latest: ignored there, each named
    assert det.counts["skin stamped behind"] == 2 and det.counts["touches"] == 11
    assert any("stamps out of order" in n and f"{stamps[6]:.6f}" in n for n in det.notes)


def test_joint_states_naming_some_joints_or_nan_ones_are_merged_per_joint(skin):
    """A second driver publishing the head's joints between the full states (ROS allows it), or a state
    with NaN, lost every touch near it ("missing joint"). Each joint is interpolated from the nearest
    states that give it; a needed joint no state gives within the tolerance still drops the touch."""
    names = list(skin.robot.joint_names)
    head = ["HeadYaw", "HeadPitch"]
    cols = [skin.robot.joint_index[n] for n in head]
    hand, torso = skin.parts["l_hand"].slots[:4].tolist(), skin.parts["torso"].slots[:3].tolist()
    for extra in ("head only", "all NaN"):
        det = EventDetector.for_skin(skin)
        out = []
        for k in range(10):      # a touch every 0.1 s, full states every 0.02 s, the extra one beside each
            t0 = 0.1 * k
            for t in t0 + np.array([0.0, 0.02, 0.04, 0.06, 0.08]):
                out += det.add_joint_state(t, names, angles(names, t))
                if extra == "head only":
                    out += det.add_joint_state(t + 0.011, head, angles(names, t + 0.011)[cols])
                else:
                    out += det.add_joint_state(t + 0.011, names, np.full(len(names), np.nan))
                if t == t0 + 0.02:
                    out += det.add_skin(t + 0.005, "l_hand", hand)
                    out += det.add_skin(t + 0.005, "torso", torso)
                if t == t0 + 0.06:     # released
                    out += det.add_skin(t + 0.005, "l_hand", [])
                    out += det.add_skin(t + 0.005, "torso", [])
        out += det.flush()
        assert len(out) == 10 and det.counts["missing joint"] == 0, (extra, det.counts, det.notes[:2])
        for r in out:
            np.testing.assert_allclose(r.joints, angles(names, r.stamp), atol=1e-12)
    # the arm's states stop, only the head's go on: the arm joints are missing, not guessed
    det = EventDetector.for_skin(skin)
    det.add_joint_state(0.0, names, angles(names, 0.0))
    for t in (0.3, 0.4, 0.5, 0.6):
        det.add_joint_state(t, head, angles(names, t)[cols])
    det.add_skin(0.45, "l_hand", hand)
    det.add_skin(0.45, "torso", torso)
    det.add_joint_state(0.7, head, angles(names, 0.7)[cols])
    assert det.flush() == [] and det.counts["missing joint"] == 1
