"""A record session's recording without ROS (session.recording.TouchRecording): the live streams in, a touch bag
out, and what the operator is told. The node (pairing_recorder) only translates messages to it: the tests of the
node over real DDS are in test_node_session.py, test_recording_survives.py and test_clock_skew.py."""
from __future__ import annotations

import json

import numpy as np
import pytest

from nao_skin.formats.bag import read_touches
from nao_skin.formats.inputs import load_touches
from nao_skin.formats.pointcloud import xyz
from nao_skin.live.clocks import MIN_MESSAGES, SKEW_LIMIT_S
from nao_skin.live.playback import Playback
from nao_skin.session.recording import MAX_LOGGED_ERRORS, TouchRecording
from nao_skin.sim.simulate import simulate
from nao_skin.touch.datasets import deduplicate
from nao_skin.touch.events import LIVE_CONFIG
from nao_skin.touch.inorder import WAIT_S
from recorded_touches import play_streams


def test_the_touches_played_are_the_touches_in_the_bag(skin, tmp_path):
    sim = simulate(skin, {"pairs": [["l_hand", "torso"], ["r_hand", "head"]], "n_touches": 6}, seed=1)
    touches, _ = deduplicate(sim.touches)
    recording = TouchRecording(skin, LIVE_CONFIG, tmp_path / "touches", "mcap")
    last = play_streams(recording, Playback(touches, skin, period=0.6, press=0.2, hold=0.05), start=1.7e9)
    # the contacts come only while pressed (as some drivers send them): what came after the last press waits for
    # them, until the node's flush timer finds it waited its time
    recording.flush(now=last + WAIT_S)
    progress = recording.progress()
    assert progress["touches"] == touches.n_touches == 12 and progress["pairs"] == {"l_hand+torso": 6, "r_hand+head": 6}
    assert 0 < progress["coverage"]["torso"] < 1
    assert all(abs(s) < 0.01 for s in progress["clock_skew_s"].values()) and recording.clock_warnings(
        progress["clock_skew_s"]) == recording.clock_warnings(progress["clock_skew_s"]) == []     # one clock
    assert recording.close().startswith(f"wrote 12 touches to {tmp_path / 'touches'}: ")
    assert recording.close() is None                       # closed once
    back, report = read_touches(tmp_path / "touches", skin)
    assert back.n_touches == 12 and report.n_skipped == 0
    np.testing.assert_allclose(back.joints, touches.joints[np.argsort(touches.stamps, kind="stable")])
    assert sorted(back.act_slot.tolist()) == sorted(touches.act_slot.tolist())


def test_a_recorder_held_up_for_seconds_records_every_touch_once(skin, tmp_path):
    """A recorder held up for 2.5 s gets the topics' backlogs when it runs again, the torso's 1.5 s after the
    others' (DDS repairs each topic on its own): read as they arrive, the parts' samples of one moment met no
    more and touches were lost without a word (3 of 12 here; 4 of 20 over DDS with a recorder stopped for 3 s).
    Read in the order of their stamps, every touch is in the bag once."""
    sim = simulate(skin, {"pairs": [["l_hand", "torso"], ["r_hand", "head"]], "n_touches": 6}, seed=1)
    touches, _ = deduplicate(sim.touches)
    recording = TouchRecording(skin, LIVE_CONFIG, tmp_path / "touches", "sqlite3")
    last = play_streams(recording, Playback(touches, skin, period=0.6, press=0.2, hold=0.05), start=1.7e9,
                 held=(1.5, 4.0, {"/skin/torso/taxels": 1.5, "/skin/torso/contacts": 1.5}))
    recording.flush(now=last + WAIT_S)
    assert recording.progress()["dropped"] == {}
    assert recording.close().startswith(f"wrote 12 touches to {tmp_path / 'touches'}: ")
    back, report = read_touches(tmp_path / "touches", skin)
    assert back.n_touches == 12 and report.n_skipped == 0
    np.testing.assert_allclose(back.joints, touches.joints[np.argsort(touches.stamps, kind="stable")])
    assert sorted(back.act_slot.tolist()) == sorted(touches.act_slot.tolist())
    assert np.all(np.isfinite(back.contact_cop))              # each touch with its contacts' COPs


def test_a_skin_stream_on_another_clock_is_said_once_after_two_checks(skin, tmp_path):
    recording = TouchRecording(skin, LIVE_CONFIG, tmp_path / "touches", "sqlite3")
    for i in range(MIN_MESSAGES + 5):
        t = 100.0 + 0.02 * i
        recording.joint_state(t, list(skin.robot.joint_names), np.zeros(len(skin.robot.joint_names)), t + 0.002)
        for part, behind in (("torso", 3.0), ("head", 0.0)):
            recording.taxels(part, t - behind, np.zeros(0, int), np.zeros(0), np.zeros(0, int), t + 0.003)
    skew = recording.progress()["clock_skew_s"]
    assert skew["/skin/torso/taxels"] == pytest.approx(3.001) and abs(skew["/skin/head/taxels"]) < SKEW_LIMIT_S
    assert recording.clock_warnings(skew) == []            # one check's window can still hold a start-up queue
    [said] = recording.clock_warnings(skew)
    assert said.startswith("/skin/torso/taxels is stamped 3.00 s behind /joint_states")
    assert recording.clock_warnings(skew) == []            # said once
    recording.close()


def test_bad_messages_are_all_counted_and_the_first_few_said(skin, tmp_path):
    recording = TouchRecording(skin, LIVE_CONFIG, tmp_path / "touches", "sqlite3")
    said = [recording.bad_message() for _ in range(MAX_LOGGED_ERRORS + 3)]
    assert said == [True] * MAX_LOGGED_ERRORS + [False] * 3
    assert recording.progress()["dropped"]["bad message"] == MAX_LOGGED_ERRORS + 3
    recording.close()


def test_a_stream_that_never_comes_is_said_once_and_in_the_last_line(skin, tmp_path):
    """A robot session whose bridges read nothing (NAOqi unreachable, no yarpserver) ended with 'wrote 0
    touches' and nothing else: now each silent stream is said once after a while, and at the end."""
    recording = TouchRecording(skin, LIVE_CONFIG, tmp_path / "touches", "sqlite3")
    assert recording.silence_warnings(3.0) == []                    # too early to tell
    said = recording.silence_warnings(12.0)
    assert [line.split(":")[0] for line in said] == ["no joint states in 12 s", "no skin samples in 12 s"]
    assert "naoqi_bridge" in said[0] and "yarp_skin_bridge" in said[1]
    assert recording.silence_warnings(20.0) == []                   # once
    recording.joint_state(5.0, list(skin.robot.joint_names), np.zeros(len(skin.robot.joint_names)), 5.0)
    assert recording.close().endswith("{} (no skin samples ever arrived)")
    fresh = TouchRecording(skin, LIVE_CONFIG, tmp_path / "other", "sqlite3")
    assert fresh.close().endswith("{} (no joint states and no skin samples ever arrived)")
    # the simulated robot's session: no bridge to blame (a 2400-touch robot simulates for 12 s before it plays,
    # and the warning sent the operator to NAOqi and skinManager)
    from nao_skin.formats.bag import SIMULATED

    simulated = TouchRecording(skin, LIVE_CONFIG, tmp_path / "sim", "sqlite3", recorded_from=SIMULATED)
    said = simulated.silence_warnings(12.0)
    assert len(said) == 2 and all("is sim_robot running? It simulates its touches before it plays" in line for line in said)
    assert not any("naoqi_bridge" in line or "yarp" in line for line in said)
    simulated.close()


class Checked:
    """A recording as the pairing_recorder node drives it: beside the messages, once a second of the arrival
    clock, its flush timer and its progress timer's outage check; ``said``: ``(time, line)`` of what it said."""

    def __init__(self, recording, start: float):
        self.recording, self.next, self.said = recording, start + 1.0, []

    def __getattr__(self, name):
        method = getattr(self.recording, name)

        def call(*args, arrived):
            while arrived >= self.next:
                self.recording.flush(self.next)
                self.said += [(self.next, line) for line in self.recording.outage_warnings()]
                self.next += 1.0
            return method(*args, arrived=arrived)

        return call


def test_joint_states_that_stop_mid_session_are_said_once_back_and_the_touches_lost_counted(skin, tmp_path):
    """NAOqi gone for 3.5 s mid-session while the skin goes on: the touches pressed then have no arm pose. Said
    once the joint states are back, by their stamps (the recorder waits 10 s for late joint states before it
    can tell a stalled stream from a late one), and counted in the last line."""
    sim = simulate(skin, {"pairs": [["l_hand", "torso"]], "n_touches": 8}, seed=3)
    touches, _ = deduplicate(sim.touches)
    recording = TouchRecording(skin, LIVE_CONFIG, tmp_path / "touches", "mcap")
    checked = Checked(recording, 100.0)
    # no joint state from 2.8 to 6.3 s of the play: touches 3 to 5 have no pose
    last = play_streams(checked, Playback(touches, skin, period=1.0, press=0.2, hold=0.1), start=100.0,
                        no_joints=(2.8, 6.3))
    recording.flush(last + WAIT_S)
    said = [line for _, line in checked.said] + recording.outage_warnings()
    assert len(said) == 1 and said[0].startswith("joint states again after 3.5 s without (by their stamps): touches"
                                                 " pressed in the gap are not recorded"), said
    line = recording.close()
    lost = recording.dropped()
    assert sum(lost.values()) == 3 and recording.n_touches == 5, lost
    assert line.endswith(f'{{"l_hand+torso": 5}}; not recorded: {json.dumps(lost)}'), line


def test_joint_states_that_stay_away_are_said_while_they_are_away(skin, tmp_path):
    """NAOqi gone for 14 s mid-session (a rehearsal): the operator is told while it is away, to stop touching
    (once the recorder has waited its time for late joint states), and again when it is back."""
    sim = simulate(skin, {"pairs": [["l_hand", "torso"]], "n_touches": 22}, seed=3)
    touches, _ = deduplicate(sim.touches)
    recording = TouchRecording(skin, LIVE_CONFIG, tmp_path / "touches", "mcap")
    checked = Checked(recording, 100.0)
    play_streams(checked, Playback(touches, skin, period=1.0, press=0.2, hold=0.1), start=100.0,
                 no_joints=(2.8, 17.0))
    (away_at, away), (back_at, back) = checked.said
    assert away.startswith("no joint states for 2 s of skin samples, and none came in the 10 s the recorder waits"
                           " for late ones: a touch pressed now has no arm pose and cannot be recorded; stop touching"
                           " until they are back (is anything publishing /joint_states?"), away
    assert away_at < 117.0 <= back_at and back.startswith("joint states again after 14.2 s without"), checked.said
    recording.close()


def test_a_recorder_held_up_says_no_joint_state_was_missing(skin, tmp_path):
    """A recorder held up from 1.5 to 4 s of the play gets the skin's backlog first and the joint states' 1.5 s
    later (DDS repairs each topic on its own): on a busy machine it said "no joint states for 2 s while skin
    samples go on" and "joint states again after 3.5 s without: touches pressed in the gap are not recorded",
    every touch recorded (the gap was the recorder's, not the stream's). Judged by the stamps: nothing said."""
    sim = simulate(skin, {"pairs": [["l_hand", "torso"], ["r_hand", "head"]], "n_touches": 6}, seed=1)
    touches, _ = deduplicate(sim.touches)
    recording = TouchRecording(skin, LIVE_CONFIG, tmp_path / "touches", "sqlite3")
    checked = Checked(recording, 1.7e9)
    last = play_streams(checked, Playback(touches, skin, period=0.6, press=0.2, hold=0.05), start=1.7e9,
                        held=(1.5, 4.0, {"/joint_states": 1.5}))
    recording.flush(last + WAIT_S)
    assert checked.said == [] and recording.outage_warnings() == []
    assert recording.progress()["dropped"] == {} and recording.n_touches == 12
    recording.close()


def test_a_bag_of_the_simulated_robot_says_so_on_every_read(skin, tmp_path):
    """`nao-skin record` runs the simulated robot by default: its bag looked like one of the robot. Its metadata
    now says what the recorder was fed, and every read of it notes a simulated one (while it grows, too)."""
    from nao_skin.formats.bag import SIMULATED, GrowingBag

    sim = simulate(skin, {"pairs": [["l_hand", "torso"]], "n_touches": 3}, seed=2)
    touches, _ = deduplicate(sim.touches)
    notes = {}
    for name, source in (("sim", SIMULATED), ("robot", "the robot"), ("unsaid", "")):
        recording = TouchRecording(skin, LIVE_CONFIG, tmp_path / name, "mcap", source)
        play_streams(recording, Playback(touches, skin, period=0.6, press=0.2, hold=0.05), start=1.7e9)
        recording.flush()
        _, growing = GrowingBag(tmp_path / name, skin).read()
        recording.close()
        _, closed = read_touches(tmp_path / name, skin)
        notes[name] = ([n for n in growing.info if "recorded from" in n], [n for n in closed.info if "recorded from" in n])
        assert not any("recorded from" in n for n in growing.notes + closed.notes)     # what it is, no warning
    said = f"{tmp_path / 'sim'}: recorded from {SIMULATED}, not the robot"
    assert notes["sim"][1] == [said] and len(notes["sim"][0]) == 1 and "simulated robot" in notes["sim"][0][0]
    assert notes["robot"] == notes["unsaid"] == ([], [])
    # nao-skin calibrate logs what it reads on stdout and summarises what is worth a look on stderr: there the
    # line informs, with the input's summary line, and is no warning
    logged, summarised = [], []
    load_touches([tmp_path / "sim"], skin, log=logged.append, summary=summarised.append)
    assert said in logged and not summarised, (logged, summarised)
