"""The calibrate node when things go wrong, over real DDS: one line, a `failed` status, never stuck.

* a wrong option value stops the node at start with one line and exit 2;
* whatever breaks in the worker (here: ``out_dir`` below a regular file, an
  OSError, not a NaoSkinError) ends in a latched `failed` status naming it, and
  the node still calibrates the next request;
* a request while a calibration runs leaves the latched state `running`;
* a node stopped during a calibration says it is written only if it had got to its output.
"""
from __future__ import annotations

import json
import shutil

import pytest

pytest.importorskip("rclpy")
from ros_harness import Listener, node_process, ros_env, unique_domain_id  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from nao_skin.formats.bag import write_touch_bag  # noqa: E402
from nao_skin.model.skin import load_skin  # noqa: E402
from nao_skin.nodes.topics import LATCHED, REQUEST_TOPIC, STATUS_TOPIC  # noqa: E402
from nao_skin.sim.simulate import simulate  # noqa: E402

pytestmark = pytest.mark.middleware   # runs the calibrate node over DDS


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory):
    skin = load_skin()
    bag = tmp_path_factory.mktemp("bag") / "touches"
    write_touch_bag(bag, simulate(skin, {"n_touches": 32}, seed=5).touches, skin, storage="mcap")
    return bag


def test_a_wrong_option_value_stops_the_node_at_start_in_one_line(tmp_path):
    node = node_process("calibrate", {"test_fraction": 2.0}, ros_env(unique_domain_id()), tmp_path)
    code = node.popen.wait(timeout=60)
    node.stop()
    lines = [line for line in node.stderr().splitlines() if line.strip()]
    assert code == 2
    assert len(lines) == 1 and "parameter test_fraction:=2.0: expected a number in [0, 1)" in lines[0], lines


@pytest.mark.parametrize("params, says", [
    ({"inputs": ["{tmp}/no_such_bag"]}, "parameter inputs: {tmp}/no_such_bag: no such file or directory"),
    ({"inputs": [""]}, "parameter inputs: empty; calibrate_on_start needs the bags"),
    ({"out_dir": "/dev/null"}, "out_dir /dev/null: is an existing file, not a directory"),
    ({"out_dir": "{tmp}/notes"}, "out_dir {tmp}/notes: is a non-empty directory nao-skin did not write"),
])
def test_a_calibration_at_start_that_cannot_run_stops_the_node_in_one_line(tmp_path, small_bag, params, says):
    """calibrate_on_start with a missing input or an out_dir it may not write logged an error, then ran on
    with nothing to do and exited 0 at Ctrl-C: now one line and exit 2 at start, as a bad parameter."""
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "mine.txt").write_text("the user's\n")
    given = {"inputs": [str(small_bag)], "out_dir": str(tmp_path / "cal"), "calibrate_on_start": True}
    given.update({k: [x.format(tmp=tmp_path) for x in v] if isinstance(v, list) else v.format(tmp=tmp_path)
                  for k, v in params.items()})
    node = node_process("calibrate", given, ros_env(unique_domain_id()), tmp_path)
    try:
        code = node.popen.wait(timeout=60)
    finally:
        node.stop()
    lines = [line for line in node.stderr().splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and says.format(tmp=tmp_path) in lines[0], lines
    assert (tmp_path / "notes" / "mine.txt").read_text() == "the user's\n"


def test_a_calibration_at_start_that_fails_ends_the_node_in_its_one_line_with_exit_2(tmp_path, small_bag):
    """The inputs are there, so the node starts; the calibration then fails (too few touches). The node logged
    one error and published nominal frames on until Ctrl-C, exit 0: ros2 run ... calibrate_on_start:=true
    could not tell a failed calibration from one that worked. Now its one line and exit 2."""
    import numpy as np

    skin = load_skin()
    few = tmp_path / "few"
    write_touch_bag(few, simulate(skin, {"n_touches": 32}, seed=5).touches.subset(np.arange(3)), skin)
    node = node_process("calibrate", {"inputs": [str(few)], "calibrate_on_start": True,
                                      "out_dir": str(tmp_path / "cal")}, ros_env(unique_domain_id()), tmp_path)
    try:
        code = node.popen.wait(timeout=120)
    finally:
        node.stop()
    said = [line for line in node.stderr().splitlines() if "error" in line.lower()]
    assert code == 2 and len(said) == 1 and said[0].startswith("error: ") and "a mount needs at least 10" in said[0], \
        node.stderr()[-3000:]
    assert "Traceback" not in node.stderr() and not (tmp_path / "cal").exists()


def test_a_request_that_fails_in_a_live_session_leaves_the_session_running(tmp_path, small_bag):
    """The calibration at start ends the node when it fails; a request in a record session does not: the
    session records on, and says the failure in its status."""
    domain = unique_domain_id()
    listener = node = None
    try:
        listener = Listener(domain)
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        node = node_process("calibrate", {"live": True, "recording": str(small_bag), "live_every_touches": 1000,
                                          "live_period": 86400.0, "out_dir": str(tmp_path / "cal")},
                            ros_env(domain), tmp_path)
        request = listener.node.create_publisher(String, REQUEST_TOPIC, 10)
        assert listener.spin_until(lambda: request.get_subscription_count() >= 1 and status, procs=[node])
        request.publish(String(data=str(tmp_path / "no_such_bag")))
        assert listener.spin_until(lambda: status[-1]["state"] == "failed", timeout=120, procs=[node]), status[-1:]
        n = len(status)
        request.publish(String(data=""))          # the session's recording: still calibrated
        assert listener.spin_until(lambda: any(s["state"] == "done" for s in status[n:]), timeout=120,
                                   procs=[node]), status[-1:]
    finally:
        if listener is not None:
            listener.close()
        code = node.stop() if node is not None else None
    assert code == 0, node.stderr()[-3000:]


def test_any_failure_of_a_calibration_ends_in_a_failed_status(tmp_path, small_bag):
    blocker = tmp_path / "notes.txt"
    blocker.write_text("a file where the output's parent should be\n")
    domain = unique_domain_id()
    listener = node = None
    try:
        listener = Listener(domain)
        node = node_process("calibrate", {"inputs": [str(small_bag)], "out_dir": str(blocker / "calibration")},
                            ros_env(domain), tmp_path)
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        request = listener.node.create_publisher(String, REQUEST_TOPIC, 10)
        assert listener.spin_until(lambda: request.get_subscription_count() >= 1 and status, procs=[node])
        request.publish(String(data=""))
        ended = lambda: [s for s in status if s["state"] in ("done", "failed")]  # noqa: E731
        assert listener.spin_until(ended, timeout=120, procs=[node]), status[-1:]
        failed = ended()[0]
        assert failed["state"] == "failed" and "notes.txt" in failed["error"] and "\n" not in failed["error"]
        assert blocker.read_text() == "a file where the output's parent should be\n"
        # not stuck: with the obstacle gone, the next request calibrates
        blocker.unlink()
        n = len(status)
        request.publish(String(data=""))
        assert listener.spin_until(lambda: any(s["state"] == "done" for s in status[n:]), timeout=120,
                                   procs=[node]), status[-1:]
    finally:
        if listener is not None:
            listener.close()
        code = node.stop() if node is not None else None
    assert code == 0, node.stderr()[-3000:]


def test_a_request_while_busy_leaves_the_running_state_latched(tmp_path, small_bag):
    domain = unique_domain_id()
    listener = node = None
    try:
        listener = Listener(domain)
        node = node_process("calibrate", {"inputs": [str(small_bag)], "out_dir": str(tmp_path / "cal"),
                                          "plots": True},             # plots: a run long enough to ask again
                            ros_env(domain), tmp_path)
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        request = listener.node.create_publisher(String, REQUEST_TOPIC, 10)
        assert listener.spin_until(lambda: request.get_subscription_count() >= 1 and status, procs=[node])
        request.publish(String(data=""))
        assert listener.spin_until(lambda: any(s["state"] == "running" for s in status), procs=[node])
        request.publish(String(data=""))
        assert listener.spin_until(lambda: any(s.get("ignored_requests") == 1 or s["state"] in ("done", "failed")
                                               for s in status), timeout=120, procs=[node]), status
        during = [s for s in status if s.get("ignored_requests")]
        assert during, "the first calibration ended before the second request (it takes seconds)"
        assert during[0]["state"] == "running" and during[0]["inputs"] == [str(small_bag)]
        assert listener.spin_until(lambda: status[-1]["state"] == "done", timeout=120, procs=[node]), status[-1]
        late = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        assert listener.spin_until(lambda: late, procs=[node])
        assert late[-1]["state"] == "done"
    finally:
        if listener is not None:
            listener.close()
        code = node.stop() if node is not None else None
    assert code == 0, node.stderr()[-3000:]


def test_a_request_calibrates_as_the_first_did_and_a_node_on_record_yaml_without_a_recording_is_no_session(
        tmp_path, small_bag):
    """Each request started from the last one's result, so the same request gave another calibration each
    time (and not nao-skin calibrate's). And calibrate.launch.py's node (record.yaml's section: live) ended
    saying "the session ends without a live calibration ...: none is written" beside the one it had written."""
    from nao_skin.paths import config_dir

    out_dir = tmp_path / "cal"
    domain = unique_domain_id()
    listener = node = None
    calibrations = []
    try:
        listener = Listener(domain)
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        request = listener.node.create_publisher(String, REQUEST_TOPIC, 10)
        node = node_process("calibrate", {"inputs": [str(small_bag)], "calibrate_on_start": True,
                                          "out_dir": str(out_dir), "plots": False}, ros_env(domain), tmp_path,
                            params_file=config_dir() / "record.yaml")
        for _ in range(2):
            n = len([s for s in status if s["state"] == "done"])
            assert listener.spin_until(lambda: len([s for s in status if s["state"] == "done"]) > n
                                       and request.get_subscription_count() >= 1, timeout=120,
                                       procs=[node]), status[-1:]
            calibrations.append((out_dir / "calibration.yaml").read_text())
            request.publish(String(data=""))
        assert listener.spin_until(lambda: len([s for s in status if s["state"] == "done"]) == 3, timeout=120,
                                   procs=[node]), status[-1:]
        calibrations.append((out_dir / "calibration.yaml").read_text())
    finally:
        if listener is not None:
            listener.close()
        code = node.stop() if node is not None else None
    assert code == 0, node.stderr()[-3000:]
    assert calibrations[1] == calibrations[0] and calibrations[2] == calibrations[0]
    assert "the session ends" not in node.stderr() and "live calibration" not in node.stderr()


def test_a_request_during_a_live_update_keeps_the_update_state_latched(tmp_path):
    """A request refused while a live update ran replaced the latched status with a bare
    {"ignored_requests": 1}: no state, no generation. The node runs in the test's process here, its update lock
    held as a live update holds it, so the request surely meets it running."""
    from rclpy.parameter import Parameter

    from nao_skin.nodes.calibrate import CalibrateNode

    listener = node = None
    try:
        listener = Listener(unique_domain_id())
        node = CalibrateNode(context=listener.context,
                             parameter_overrides=[Parameter("out_dir", value=str(tmp_path / "cal"))])
        listener.executor.add_node(node)
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        request = listener.node.create_publisher(String, REQUEST_TOPIC, 10)
        assert listener.spin_until(lambda: request.get_subscription_count() >= 1 and status)
        update = {"state": "updated", "live": True, "generation": 3, "touches": 120}
        assert node._busy.acquire(blocking=False)          # what a live update holds while it runs
        node._status(update)
        for n in (1, 2):
            request.publish(String(data=str(tmp_path / "touches")))
            assert listener.spin_until(lambda: status[-1].get("ignored_requests") == n), status[-1]
            assert status[-1] == {**update, "ignored_requests": n}
        assert not (tmp_path / "cal").exists()
    finally:
        if node is not None:
            node.destroy_node()
        if listener is not None:
            listener.close()


def test_a_node_stopped_during_a_calibration_says_it_is_not_written(tmp_path):
    """Stopped then, the node waited 10 s and ended with exit 0 and not a word: the calibration asked for was
    simply never there. The request names its bag as a JSON list: the path holds a space, which the words of a
    request cannot carry."""
    from nao_skin.paths import package_dir

    bag = tmp_path / "sp ace" / "touches"
    bag.parent.mkdir()
    shutil.copytree(package_dir() / "bags" / "sim_default" / "touches", bag)
    domain = unique_domain_id()
    listener = node = None
    try:
        listener = Listener(domain)
        node = node_process("calibrate", {"out_dir": str(tmp_path / "cal"), "jacobian": "2-point", "plots": True},
                            ros_env(domain), tmp_path)       # 4000 touches, finite differences: half a minute
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        request = listener.node.create_publisher(String, REQUEST_TOPIC, 10)
        assert listener.spin_until(lambda: request.get_subscription_count() >= 1 and status, procs=[node])
        request.publish(String(data=json.dumps([str(bag)])))
        assert listener.spin_until(lambda: status[-1]["state"] == "running", procs=[node]), status[-1]
        assert status[-1]["inputs"] == [str(bag)]
        assert listener.spin_until(lambda: "touches after removing" in node.stderr(), timeout=60, procs=[node])
    finally:
        if listener is not None:
            listener.close()
        code = node.stop(timeout=30.0) if node is not None else None
    assert code == 0, node.stderr()[-3000:]
    assert f"stopped during the calibration of {bag}: it is written only if it had got to its output" \
        in node.stderr(), node.stderr()[-3000:]
    assert not (tmp_path / "cal").exists()


def test_a_request_names_its_bags_by_their_words_or_as_a_json_list():
    from nao_skin.nodes.calibrate import request_paths

    assert request_paths("") == [] and request_paths("  a.bag  b ") == ["a.bag", "b"]
    assert request_paths('["/x/sp ace/é bag", ""]') == ["/x/sp ace/é bag"]
    assert request_paths('["a", 5]') == ['["a",', "5]"]          # no list of paths: its words, refused as inputs


def test_a_live_session_that_ends_before_any_update_says_no_calibration_is_written(tmp_path):
    """A short session (or one whose touches never sufficed) wrote nothing beside its bag and said nothing."""
    import signal

    domain = unique_domain_id()
    listener = node = None
    out_dir = tmp_path / "touches_calibration"
    try:
        listener = Listener(domain)
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        node = node_process("calibrate", {"live": True, "recording": str(tmp_path / "touches"),
                                          "out_dir": str(out_dir)}, ros_env(domain), tmp_path)
        assert listener.spin_until(lambda: status, timeout=60, procs=[node])
        node.popen.send_signal(signal.SIGINT)
        code = node.popen.wait(timeout=30)
    finally:
        if listener is not None:
            listener.close()
        if node is not None:
            node.stop()
    assert code == 0, node.stderr()[-2000:]
    assert f"the session ends without a live calibration (no live update ran): none is written to {out_dir}" \
        in node.stderr()
    assert not out_dir.exists()


def test_two_nodes_given_one_out_dir_each_keep_their_calibration(tmp_path, small_bag):
    """Two calibrate nodes started together with one out_dir (two `ros2 run` in one directory: the default
    out_dir is relative) both found it free, and the second to finish replaced the first's calibration while
    both said they had written it. Now each calibration is where its node says, and none is lost."""
    import time

    out_dir = tmp_path / "nao_skin_calibration"
    nodes = []
    try:
        for seed in (1, 2):
            nodes.append(node_process("calibrate", {"inputs": [str(small_bag)], "calibrate_on_start": True,
                                                    "out_dir": str(out_dir), "seed": seed, "plots": False},
                                      ros_env(unique_domain_id()), tmp_path, name=f"calibrate_{seed}"))
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline and not all("calibrated from" in n.stderr() for n in nodes):
            assert all(n.popen.poll() is None for n in nodes), [n.stderr()[-2000:] for n in nodes]
            time.sleep(0.2)
    finally:
        codes = [n.stop() for n in nodes]
    assert codes == [0, 0], [n.stderr()[-2000:] for n in nodes]
    written = {}
    for seed, node in zip((1, 2), nodes):
        line = next(x for x in node.stderr().splitlines() if "calibrated from" in x)
        written[seed] = line.rsplit(" -> ", 1)[1].strip()
    assert sorted(written.values()) == [str(out_dir), f"{out_dir}.new"], written
    for seed, place in written.items():       # each node's own calibration is where it says
        assert json.loads((tmp_path / place / "report.json").read_text())["options"]["seed"] == seed


@pytest.mark.parametrize("written_as", ["", "/"])
def test_the_node_writes_beside_a_calibration_it_did_not_write(tmp_path, small_bag, written_as):
    """`ros2 run nao_skin calibrate` twice in one directory replaced the first run's nao_skin_calibration without
    a word: now the earlier one stays and the new one goes to <out_dir>.new (then replaced by the node's next);
    with out_dir written 'DIR/' (a shell's completion) it went into the earlier output, as DIR/.new."""
    from nao_skin.cli import main as cli_main

    out_dir = tmp_path / "nao_skin_calibration"
    assert cli_main(["calibrate", str(small_bag), "--out", str(out_dir), "--no-plots", "--quiet"]) == 0
    earlier = (out_dir / "calibration.yaml").read_bytes()
    domain = unique_domain_id()
    listener = node = None
    try:
        listener = Listener(domain)
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        node = node_process("calibrate", {"inputs": [str(small_bag)], "calibrate_on_start": True,
                                          "out_dir": str(out_dir) + written_as}, ros_env(domain), tmp_path)
        assert listener.spin_until(lambda: [s for s in status if s["state"] in ("done", "failed")], timeout=120,
                                   procs=[node]), status[-1:]
    finally:
        if listener is not None:
            listener.close()
        if node is not None:
            node.stop()
    done = [s for s in status if s["state"] in ("done", "failed")][-1]
    assert done["state"] == "done" and done["out_dir"] == f"{out_dir}.new", done
    assert (out_dir / "calibration.yaml").read_bytes() == earlier
    assert (tmp_path / "nao_skin_calibration.new" / "calibration.yaml").is_file()
    assert f"out_dir {out_dir} holds a calibration this node did not write" in node.stderr()
    assert "another output was written there" not in node.stderr()
