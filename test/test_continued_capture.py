"""A capture over several sittings (``nao-skin record --continue-from BAG``, launch ``continue_from:=``).

Hours of moving the arm by hand do not fit one session (a battery, a break, a recorder that died): the next
sitting records to a new bag and its live calibration, guidance and the calibration written at its end cover
the earlier sittings' touches too. These tests check the pure parts on real bag files: the live calibration of
a recording that continues earlier bags, and what a record session refuses before any node starts. A real
session over DDS continuing a real one is in ``test_live_calibration.py``.
"""
from __future__ import annotations

import shutil
import subprocess
import sys

import numpy as np
import pytest

from nao_skin.calibration.options import CalibrationOptions
from nao_skin.errors import ConfigError, DataError
from nao_skin.formats.bag import SIMULATED, BagWriter, touch_messages, write_touch_bag
from nao_skin.formats.salvage import write_lock
from nao_skin.live.updates import PartStates
from nao_skin.model.taxel_file import write_taxel_file
from nao_skin.session.live import LiveCalibration
from nao_skin.session.record import record_session
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate
from nao_skin.touch.datasets import deduplicate


@pytest.fixture(scope="module")
def touches(skin):
    params = load_params("default", {"pairs": [["r_hand", "torso"]], "n_touches": 60})
    out, _ = deduplicate(simulate(skin, params, seed=6).touches)
    return out


def live(skin, recording, earlier):
    return LiveCalibration(skin, CalibrationOptions(), recording, skin.zero_calibration(), 2.0, PartStates(), 20.0,
                           earlier=earlier, scratch_below=0)


def test_a_session_continuing_an_earlier_bag_calibrates_its_touches_first_then_with_the_new_ones(skin, touches,
                                                                                                 tmp_path):
    earlier, recording = tmp_path / "sitting1", tmp_path / "sitting2"
    write_touch_bag(earlier, touches.subset(np.arange(40)), skin, storage="mcap")
    session = live(skin, recording, [earlier])
    assert session.read_earlier() == 40
    # before the new sitting's first touch (its bag not made yet): the earlier touches alone, not a failure
    first = session.update()
    assert first.status["state"] == "updated" and first.status["touches"] == 40, first.status
    assert first.status["earlier"] == 40 and first.status["parts"]["r_hand"] == "converging"
    # the new sitting's touches come (its bag names the sitting it continues, as the recorder's does): one
    # calibration of both, warm from the earlier sitting's
    with BagWriter(recording, "mcap", kind="touches", continues=[str(earlier)]) as bag:
        for args in touch_messages(touches.subset(np.arange(40, 60)), skin):
            bag.write_touch(*args)
    second = session.update()
    assert second.status["state"] == "updated" and second.status["touches"] == 60, second.status
    assert second.status["earlier"] == 40 and not second.status["from_scratch"]
    assert second.accepted.report.input["files"] == [str(earlier), str(recording)]
    assert not [n for n in second.accepted.report.input["notes"] if "continues the capture" in n]
    # an earlier bag moved away during the session: what was read is held, the updates go on with every touch,
    # and nothing says the sitting is missing
    shutil.move(earlier, tmp_path / "moved")
    third = session.update()
    assert third.status["state"] == "updated" and third.status["touches"] == 60, third.status
    assert not [n for n in third.accepted.report.input["notes"] if "continues the capture" in n]


def test_without_earlier_bags_a_recording_not_made_yet_is_a_failed_update_as_before(skin, tmp_path):
    out = live(skin, tmp_path / "not_yet", []).update()
    assert out.status["state"] == "failed" and "not_yet" in out.status["error"] and "earlier" not in out.status


def test_an_earlier_bag_that_cannot_be_read_is_one_line_at_the_start(skin, touches, tmp_path):
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
    with pytest.raises(DataError, match="bad"):
        live(skin, tmp_path / "new", [bad]).read_earlier()
    # a node started without nao-skin record's checks (ros2 run ... -p earlier_recordings:=...) checks them too
    good = tmp_path / "good"
    write_touch_bag(good, touches.subset(np.arange(20)), skin)
    with pytest.raises(DataError, match="the same recording as the input"):
        live(skin, tmp_path / "new", [good, f"{good}/"]).read_earlier()
    with pytest.raises(DataError, match="the recording is among the earlier sittings it continues"):
        live(skin, good, [good]).read_earlier()


def session_with(tmp_path, earlier, robot="sim", **kwargs):
    return record_session(robot, bag_path=str(tmp_path / "new_bag"), continue_from=earlier,
                          with_robot_state_publisher=False, **kwargs)


def test_the_calibrate_node_gets_the_earlier_bags_as_absolute_paths(skin, touches, tmp_path, monkeypatch):
    write_touch_bag(tmp_path / "sitting1", touches.subset(np.arange(20)), skin)
    monkeypatch.chdir(tmp_path)
    (calibrate,) = [s for s in session_with(tmp_path, ["sitting1"]) if s.name == "calibrate"]
    assert calibrate.overrides["earlier_recordings"] == [str(tmp_path / "sitting1")]
    (calibrate,) = [s for s in session_with(tmp_path, []) if s.name == "calibrate"]
    assert "earlier_recordings" not in calibrate.overrides


def test_a_session_refuses_earlier_bags_it_cannot_continue_before_any_node_starts(skin, touches, tmp_path):
    bag = tmp_path / "sitting1"
    write_touch_bag(bag, touches.subset(np.arange(20)), skin)
    # an aborted sitting's bag, with no touch: refused before the new bag is made
    with BagWriter(tmp_path / "aborted", kind="touches", source=SIMULATED):
        pass
    with pytest.raises(ConfigError, match=f"continue from {tmp_path / 'aborted'}: holds no touch"):
        session_with(tmp_path, [str(tmp_path / "aborted")])
    assert not (tmp_path / "new_bag").exists()
    with pytest.raises(ConfigError, match=r"continue from .*missing: no such file or directory"):
        session_with(tmp_path, [str(tmp_path / "missing")])
    with pytest.raises(ConfigError, match="the same recording as the input"):
        session_with(tmp_path, [str(bag), str(bag / "")])
    with pytest.raises(ConfigError, match="give --continue-from BAG"):
        session_with(tmp_path, [], overrides={"calibrate": {"earlier_recordings": f"[{bag}]"}})
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    with pytest.raises(ConfigError, match=f"continue from {tmp_path / 'loop'}: cannot read"):
        session_with(tmp_path, [str(tmp_path / "loop")])
    with pytest.raises(ConfigError, match=f"calibration output {bag / 'cal'}: lies inside the bag {bag}"):
        session_with(tmp_path, [str(bag)], overrides={"calibrate": {"out_dir": str(bag / "cal")}})
    # a bag still being recorded (its recorder's lock names a running process: this one)
    write_lock(bag)
    with pytest.raises(ConfigError, match=f"continue from {bag}: is being recorded now"):
        session_with(tmp_path, [str(bag)])


def test_a_session_of_the_real_robot_refuses_to_continue_a_simulated_one(skin, touches, tmp_path):
    simulated = tmp_path / "simulated_sitting"
    with BagWriter(simulated, kind="touches", source=SIMULATED) as bag:
        for args in touch_messages(touches.subset(np.arange(20)), skin):
            bag.write_touch(*args)
    with pytest.raises(ConfigError, match="mix the simulated robot's touches with the real one's"):
        session_with(tmp_path, [str(simulated)], robot="nao")
    assert [s for s in session_with(tmp_path, [str(simulated)]) if s.name == "calibrate"]   # sim continues sim
    # the robot's own sitting: continued by the robot's next one, not by the simulated robot
    (recorder,) = [s for s in session_with(tmp_path, [], robot="nao") if s.name == "pairing_recorder"]
    robot = tmp_path / "robot_sitting"
    with BagWriter(robot, kind="touches", source=recorder.overrides["recorded_from"]) as bag:
        for args in touch_messages(touches.subset(np.arange(20)), skin):
            bag.write_touch(*args)
    (calibrate,) = [s for s in session_with(tmp_path, [str(robot)], robot="nao") if s.name == "calibrate"]
    assert calibrate.overrides["earlier_recordings"] == [str(robot)]
    with pytest.raises(ConfigError, match="mix the simulated robot's touches with the real one's"):
        session_with(tmp_path, [str(robot)])


def test_record_says_a_missing_earlier_bag_in_one_line_with_exit_2(tmp_path):
    run = subprocess.run([sys.executable, "-m", "nao_skin.cli", "record", "--bag", str(tmp_path / "new"),
                          "--continue-from", str(tmp_path / "gone")], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "Traceback" not in run.stderr, run.stderr
    assert run.stderr.strip().splitlines()[-1].endswith(f"continue from {tmp_path / 'gone'}: no such file or"
                                                         f" directory"), run.stderr
    assert not (tmp_path / "new").exists()


def test_calibrating_a_continuing_bag_without_the_bags_it_continues_says_so(skin, touches, tmp_path):
    """The bag of a sitting that continued earlier ones names them in its metadata: a calibration of it alone
    would leave their touches out, and says so in one line; with them among the inputs nothing is said."""
    from nao_skin.calibration.pipeline import load_inputs

    first, second = tmp_path / "sitting1", tmp_path / "sitting2"
    write_touch_bag(first, touches.subset(np.arange(30)), skin)
    with BagWriter(second, kind="touches", continues=[str(first)]) as bag:
        for args in touch_messages(touches.subset(np.arange(30, 60)), skin):
            bag.write_touch(*args)
    said: list = []
    alone = load_inputs([str(second)], skin, summary=said.append)
    line = (f"{second}: continues the capture of {first} (record.launch.py continue_from:=, nao-skin record"
            f" --continue-from), not among the inputs")
    assert alone.touches.n_touches == 30 and [s for s in said if s.startswith(line)], said
    said.clear()
    both = load_inputs([str(first / ""), str(second)], skin, summary=said.append)    # named another way: the same
    assert both.touches.n_touches == 60 and not [s for s in said if "continues the capture" in s], said
    stats = subprocess.run([sys.executable, "-m", "nao_skin.cli", "stats", str(second)], capture_output=True,
                           text=True, timeout=120)
    assert stats.returncode == 0 and line in stats.stdout + stats.stderr, stats.stdout + stats.stderr


@pytest.mark.middleware
def test_the_heatmap_of_a_continuing_session_starts_with_the_earlier_sittings_presses(skin, touches, tmp_path):
    """skin_heatmap given an earlier sitting's bag (real node, real DDS): before any skin message, every taxel
    is coloured by how often the earlier touches activated it; a bag it cannot read is one line and exit 2."""
    pytest.importorskip("rclpy")
    from ros_harness import Listener, node_process, ros_env, unique_domain_id
    from visualization_msgs.msg import MarkerArray

    from nao_skin.live.heatmap import ActivationCounts, palette, triangle_slots
    from nao_skin.nodes.topics import HEATMAP_TOPIC

    earlier = tmp_path / "sitting1"
    write_touch_bag(earlier, touches, skin)
    want = ActivationCounts({n: p.n_slots for n, p in skin.parts.items()})
    want.add_touches(touches)
    assert want.max_count() > 1 and sum(int((c > 0).sum()) for c in want.counts.values()) > 50
    domain = unique_domain_id()
    listener = node = None
    try:
        listener = Listener(domain)
        heat = listener.subscribe(MarkerArray, HEATMAP_TOPIC, qos=5)
        node = node_process("skin_heatmap", {"earlier_recordings": [str(earlier)]}, ros_env(domain), tmp_path)
        assert listener.spin_until(lambda: heat, timeout=60, procs=[node])
    finally:
        if listener is not None:
            listener.close()
        code = node.stop() if node is not None else None
    assert code == 0, node.stderr()[-3000:]
    markers = {(m.ns, m.id): m for m in heat[-1].markers}
    pal = palette()
    for name, part in skin.parts.items():
        expect = want.colour_indices(name)
        for tid, slots in triangle_slots(part):
            colours = np.array([[c.r, c.g, c.b, c.a] for c in markers[(name, tid)].colors])
            np.testing.assert_allclose(colours, pal[expect[slots]], atol=1e-6, err_msg=f"{name} triangle {tid}")
    bad = node_process("skin_heatmap", {"earlier_recordings": [str(tmp_path / "gone")]}, ros_env(domain), tmp_path)
    bad.popen.wait(timeout=60)
    code = bad.stop()
    err = bad.stderr()
    assert code == 2 and "Traceback" not in err and f"{tmp_path / 'gone'}: no such file or directory" in err, err


def test_a_sitting_whose_recorder_died_is_continued_with_every_touch_it_flushed(skin, touches, tmp_path):
    """The sitting before ended with its recorder killed (the bag unclosed, its lock naming a process that is
    gone): the next sitting continues it, and reads every touch the recorder had flushed."""
    import json
    import socket

    from nao_skin.formats.salvage import LOCK_FILE

    earlier = tmp_path / "killed_sitting"
    writer = BagWriter(earlier, "mcap", kind="touches", live=True, source=SIMULATED)
    writer.__enter__()
    for args in touch_messages(touches.subset(np.arange(25)), skin):
        writer.write_touch(*args)
    writer.flush()                                          # what a recorder's last flush wrote before its kill
    gone = subprocess.Popen(["true"])
    gone.wait()
    (earlier / LOCK_FILE).write_text(json.dumps({"pid": gone.pid, "host": socket.gethostname(), "start": "0"}))
    (calibrate,) = [s for s in session_with(tmp_path, [str(earlier)]) if s.name == "calibrate"]
    session = live(skin, tmp_path / "next_sitting", calibrate.overrides["earlier_recordings"])
    assert session.read_earlier() == 25
    assert session.update().status["touches"] == 25


def test_a_sitting_recorded_with_other_taxel_files_is_refused_unless_the_session_reads_them(skin, touches,
                                                                                             tmp_path):
    """The torso's taxel file the earlier sitting was recorded with lies 30 mm off the one the session reads:
    its touches would pull every live update apart (a rehearsal: every update 'diverged'); with that sitting's
    file given (--taxels) it is continued."""
    from nao_skin.model.skin import load_skin

    torso = skin.parts["torso"]
    shifted = tmp_path / "torso_shifted.txt"
    pos, nor = torso.taxel_positions(normals=True)
    write_taxel_file(shifted, np.nan_to_num(pos) + [0.03, 0.0, 0.0], np.nan_to_num(nor), torso.present, "torso")
    other = load_skin(taxel_files={"torso": shifted})       # the simulated robot of that sitting read it too
    played = simulate(other, load_params("default", {"pairs": [["r_hand", "torso"]], "n_touches": 30}), seed=6)
    write_touch_bag(tmp_path / "sitting1", played.touches, other)
    with pytest.raises(ConfigError, match=r"continue from .*sitting1: part 'torso': the recorded contact COPs lie a"
                                          r" median 30 mm .*give that sitting's, --taxels PART=FILE"):
        session_with(tmp_path, [str(tmp_path / "sitting1")])
    assert session_with(tmp_path, [str(tmp_path / "sitting1")], taxels=[f"torso={shifted}"])


def test_the_thesis_text_format_is_continued_too(tmp_path, real_dir):
    legacy = real_dir / "l_hand_torso.legacy.txt"
    taxels = [f"l_hand={real_dir / 'l_hand.taxels.txt'}", f"torso={real_dir / 'torso.taxels.txt'}"]
    (calibrate,) = [s for s in session_with(tmp_path, [str(legacy)], taxels=taxels) if s.name == "calibrate"]
    assert calibrate.overrides["earlier_recordings"] == [str(legacy.resolve())]      # through links, as every path


def test_continuing_the_last_sitting_continues_the_sittings_it_continued(skin, touches, tmp_path):
    """s2 continued s1: a session continuing s2 continues s1 too (before it), once even when s1 is also named;
    an s1 no longer there is left out (the calibrate node says so as it starts)."""
    s1, s2 = tmp_path / "s1", tmp_path / "s2"
    write_touch_bag(s1, touches.subset(np.arange(30)), skin)
    with BagWriter(s2, kind="touches", continues=[str(s1)]) as bag:
        for args in touch_messages(touches.subset(np.arange(30, 60)), skin):
            bag.write_touch(*args)

    def earlier(*named):
        (calibrate,) = [s for s in session_with(tmp_path, [str(p) for p in named]) if s.name == "calibrate"]
        return calibrate.overrides["earlier_recordings"]

    assert earlier(s2) == [str(s1), str(s2)]
    assert earlier(s1, s2) == earlier(s2, s1) == [str(s1), str(s2)]
    shutil.move(s1, tmp_path / "s1_elsewhere")
    assert earlier(s2) == [str(s2)]
    s1.mkdir()                                  # something else took its name: no recording, left out as well
    assert earlier(s2) == [str(s2)]
    # a cycle (each names the other, as copied metadata might): each once, then it ends
    y, z = tmp_path / "y", tmp_path / "z"
    for this, other in ((y, z), (z, y)):
        with BagWriter(this, kind="touches", continues=[str(other)]) as bag:
            for args in touch_messages(touches.subset(np.arange(20)), skin):
                bag.write_touch(*args)
    assert earlier(y) == [str(z), str(y)]
    said: list = []
    LiveCalibration(skin, CalibrationOptions(), tmp_path / "s3", skin.zero_calibration(), 2.0, PartStates(), 20.0,
                    earlier=[s2]).read_earlier(summary=said.append)
    assert [line for line in said if line.startswith(f"{s2}: continues the capture of {s1}")], said


def test_a_capture_folder_moved_whole_still_knows_its_sittings(skin, touches, tmp_path):
    """The bags name the sittings they continue relative to themselves too: a capture folder moved or copied whole
    (to another machine) is found there, and calibrating all of it says nothing is missing."""
    from nao_skin.calibration.pipeline import load_inputs
    from nao_skin.formats.bag import continued_bags

    capture = tmp_path / "capture"
    capture.mkdir()
    write_touch_bag(capture / "s1", touches.subset(np.arange(30)), skin)
    with BagWriter(capture / "s2", kind="touches", continues=[str(capture / "s1")]) as bag:
        for args in touch_messages(touches.subset(np.arange(30, 60)), skin):
            bag.write_touch(*args)
    moved = tmp_path / "copied_elsewhere"
    shutil.copytree(capture, moved)
    assert continued_bags(moved / "s2") == [str(moved / "s1")]
    said: list = []
    load_inputs([str(moved / "s1"), str(moved / "s2")], skin, summary=said.append)
    assert not [line for line in said if "continues the capture" in line], said
    shutil.rmtree(capture)
    shutil.move(moved, capture.with_name("moved"))
    assert continued_bags(tmp_path / "moved" / "s2") == [str(tmp_path / "moved" / "s1")]


def test_a_simulator_output_folder_is_continued_as_the_bag_it_holds(skin, touches, tmp_path):
    """The session names the recording itself (a new bag put in that folder would make it hold two)."""
    folder = tmp_path / "simulated"
    folder.mkdir()
    write_touch_bag(folder / "touches", touches.subset(np.arange(20)), skin)
    (calibrate,) = [s for s in session_with(tmp_path, [str(folder)]) if s.name == "calibrate"]
    assert calibrate.overrides["earlier_recordings"] == [str(folder / "touches")]


def test_earlier_touches_count_one_press_per_activation(skin):
    """ActivationCounts.add_touches against a count by hand: touch 0 presses torso slots 3 and 5 and r_hand slot 3,
    touch 1 torso slot 5 again; a part the heat-map does not draw and a slot beyond the layout are skipped."""
    from nao_skin.live.heatmap import ActivationCounts

    class Activations:      # the TouchSet fields add_touches reads
        part_names = ["torso", "r_hand", "elbow"]
        act_part = np.array([0, 0, 1, 0, 2, 0])
        act_slot = np.array([3, 5, 3, 5, 0, 9999])

    counts = ActivationCounts({"torso": 384, "r_hand": 384})
    counts.add_touches(Activations())
    torso, hand = np.zeros(384, int), np.zeros(384, int)
    torso[3], torso[5], hand[3] = 1, 2, 1
    np.testing.assert_array_equal(counts.counts["torso"], torso)
    np.testing.assert_array_equal(counts.counts["r_hand"], hand)


def test_an_update_stopped_between_its_stages_changes_nothing_and_the_next_one_runs(skin, touches, tmp_path):
    """A session's end stops a live update it no longer needs, and a final one past its time, between two stages
    of the calibration (the recording is read whole first): the update says 'stopped', the last accepted
    calibration stays, and the next update calibrates every touch."""
    bag = tmp_path / "sitting"
    write_touch_bag(bag, touches.subset(np.arange(40)), skin)
    calibration = live(skin, bag, [])
    asked: list = []
    out = calibration.update(stop=lambda: asked.append(1) or True)
    assert out.status["state"] == "stopped" and out.status["touches"] == 40 and len(asked) == 1, out.status
    assert out.accepted is None and calibration.last is None and out.touches.n_touches == 40
    first = calibration.update()
    assert first.status["state"] == "updated" and first.status["touches"] == 40 and calibration.last is not None
    write_touch_bag(tmp_path / "more", touches.subset(np.arange(60)), skin)
    later = live(skin, tmp_path / "more", [])
    later.update()
    accepted = later.last
    out = later.update(stop=lambda: True)      # a warm update, stopped at its first stage's end
    assert out.status["state"] == "stopped" and later.last is accepted
    assert later.update().status["state"] == "updated" and later.last is not accepted
