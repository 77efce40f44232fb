"""The launch files under the real ROS 2 launch system, as ``ros2 launch nao_skin ...`` runs them.

The package is built into a colcon workspace (test_colcon.py's), and ``test/ros2_launch.py`` does what
``ros2 launch`` does (ros2cli is not on PyPI): the launch file from the installed share directory, in the
real ``launch``/``launch_ros`` (Jazzy's, installed by docker/setup_venv.sh from ``../shared/wheels``). Every
launch argument is given at least once. robot_state_publisher and rviz2 are not installed here (no wheel):
the launch file leaves them out with a line, as ``nao-skin record`` does.
"""
from __future__ import annotations

import importlib.util
import json
import re
import shlex
import signal
import sys

import pytest
from real_launch import require_launch
from ros_harness import ROOT, Listener, Proc, unique_domain_id

require_launch()
pytest.importorskip("rclpy")
from std_msgs.msg import String  # noqa: E402
from test_colcon import _sourced_env, workspace  # noqa: E402,F401 - the workspace fixture
from tf2_msgs.msg import TFMessage  # noqa: E402
from thesis_format import write_thesis_file  # noqa: E402

from nao_skin.formats.bag import read_touches, write_touch_bag  # noqa: E402
from nao_skin.model.skin import load_skin  # noqa: E402
from nao_skin.nodes.topics import LATCHED, STATUS_TOPIC, TF_STATIC_TOPIC  # noqa: E402
from nao_skin.sim.simulate import simulate  # noqa: E402

pytestmark = [pytest.mark.middleware, pytest.mark.slow]
RUNNER = ROOT / "test" / "ros2_launch.py"
WAIT_S = 240.0        # generous: a bound on a hang, never reached when things work


def ros2_launch(ws, tmp_path, domain: int, file_name: str, name: str, **arguments) -> Proc:
    argv = [sys.executable, str(RUNNER), "nao_skin", file_name] + [f"{k}:={v}" for k, v in arguments.items()]
    return Proc(argv, _sourced_env(ws, domain), tmp_path, name)


def stopped_once_written(launch: Proc, path) -> int:
    """Ctrl-C to ``launch`` once ``path`` exists (a calibrate.launch.py that wrote its calibration): its exit code.
    The launch is killed whatever happens."""
    import time
    from pathlib import Path

    try:
        deadline = time.monotonic() + WAIT_S
        while not Path(path).is_file() and time.monotonic() < deadline:
            assert launch.alive(), output(launch)[-3000:]
            time.sleep(0.2)
        return launch.stop(signal.SIGINT, timeout=60)
    finally:
        launch.stop(signal.SIGKILL)


def output(proc: Proc) -> str:
    """What the launch printed: its own log and the nodes' lines (``output="screen"``) go to stdout."""
    return proc.stdout() + proc.stderr()


def live_parameters(listener: Listener, node: str, names, timeout: float = WAIT_S) -> dict:
    """``{name: value}`` of a running node's parameters, asked over DDS (what ``ros2 param get`` does)."""
    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python

    client = listener.node.create_client(GetParameters, f"{node}/get_parameters")
    try:
        names = sorted(names)
        values = listener.ask(client, GetParameters.Request(names=names), timeout=timeout).values
        return {name: parameter_value_to_python(v) for name, v in zip(names, values)}
    finally:
        listener.node.destroy_client(client)


def same_value(a, b) -> bool:
    if isinstance(a, (list, tuple)) or isinstance(b, (list, tuple)):
        return isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)) and len(a) == len(b) \
            and all(map(same_value, a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool) \
            and not isinstance(b, bool):
        return float(a) == float(b)
    return a == b


def as_record_would(**session) -> list:
    """What ``nao-skin record`` starts for these arguments (the one session description,
    :func:`~nao_skin.session.record.record_session`), made before the session: it refuses a bag that exists."""
    from nao_skin.session.record import record_session

    return record_session(**session)


def assert_started_as(listener: Listener, specs) -> None:
    """Every nao_skin node the launch started runs with the parameters ``nao-skin record`` gives it (``specs``):
    asked of the live nodes, so what launch_ros wrote into its parameter files and what rcl read from them is
    what is compared."""
    from nao_skin.session.record import _start_values

    prefix = specs[0].namespace.rstrip("/")
    for spec in (s for s in specs if s.ours):
        want = _start_values(spec)
        got = live_parameters(listener, f"{prefix}/{spec.name}", want)
        differ = {k: (got[k], want[k]) for k in want if not same_value(got[k], want[k])}
        assert not differ, (spec.name, differ)


def frames_of(messages) -> set:
    return {t.child_frame_id for m in messages for t in m.transforms}


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """A small simulated recording as a bag and as a thesis-format text file (whose name has a space)."""
    where = tmp_path_factory.mktemp("recordings")
    skin = load_skin()
    touches = simulate(skin, {"n_touches": 40, "pairs": [["l_hand", "torso"]]}, seed=5).touches
    bag = where / "sitting"       # a rosbag2 directory: no ".bag", which AnyReader takes for ROS 1
    write_touch_bag(bag, touches, skin)
    text = where / "thesis sitting.txt"
    write_thesis_file(text, simulate(skin, {"n_touches": 40, "pairs": [["r_hand", "torso"]]}, seed=6).touches, skin)
    return bag, text


def test_calibrate_launch_calibrates_a_bag_and_a_thesis_file(workspace, tmp_path, recordings):  # noqa: F811
    """``inputs`` is a list, which launch_ros writes into its parameter file as a Python tuple: the node read
    that file as rcl does (before, our own check refused it and the launch ran on without its only node)."""
    ws, _, prefix = workspace
    bag, text = recordings
    out = tmp_path / "calibrated"
    domain = unique_domain_id()
    listener = launch = None
    try:
        listener = Listener(domain)
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        frames = listener.subscribe(TFMessage, TF_STATIC_TOPIC, qos=LATCHED)
        launch = ros2_launch(ws, tmp_path, domain, "calibrate.launch.py", "calibrate_launch",
                             inputs=shlex.join([str(bag), str(text)]), out_dir=str(out),
                             calibration=str(prefix / "share" / "nao_skin" / "config" / "calibration_nominal.yaml"))
        assert listener.spin_until(lambda: status and status[-1]["state"] in ("done", "failed"),
                                   timeout=WAIT_S, procs=[launch]), (status[-2:], output(launch)[-3000:])
        assert status[-1]["state"] == "done", status[-1]
        assert listener.spin_until(lambda: any("skin_mount" in f for f in frames_of(frames)), timeout=60)
        code = launch.stop(signal.SIGINT, timeout=60)
    finally:
        if listener is not None:
            listener.close()
        if launch is not None and launch.alive():
            launch.stop(signal.SIGKILL)
    err = output(launch)
    assert code == 0 and "Traceback" not in err, err[-3000:]
    report = json.loads((out / "report.json").read_text())
    assert report["input"]["files"] == [str(bag), str(text)], report["input"]
    assert (out / "calibration.yaml").is_file()


def test_a_failing_node_ends_the_launch_with_its_reason_and_exit_code_1(workspace, tmp_path):  # noqa: F811
    ws, _, _ = workspace
    missing = tmp_path / "no such bag"
    launch = ros2_launch(ws, tmp_path, unique_domain_id(), "calibrate.launch.py", "calibrate_launch",
                         inputs=shlex.quote(str(missing)), out_dir=str(tmp_path / "out"))
    try:
        code = launch.popen.wait(timeout=WAIT_S)
    finally:
        launch.stop(signal.SIGKILL)
    err = output(launch)
    assert code == 1, err[-3000:]
    assert f"[calibrate-1] error: parameter inputs: {missing}: no such file or directory" in err.splitlines(), err
    assert "calibrate-1 ended with exit code 2; the launch ends" in err and "Traceback" not in err, err
    assert not (tmp_path / "out").exists()


def test_record_launch_records_the_simulated_robot_and_ends_cleanly_on_ctrl_c(workspace, tmp_path,  # noqa: F811
                                                                           recordings):
    """robot:=sim with the guidance, an earlier sitting continued, the robot's own taxel files and a calibration
    to start from: touches are recorded, live updates reach /tf_static, and Ctrl-C leaves the bag and the
    session's last calibration written."""
    ws, _, prefix = workspace
    share = prefix / "share" / "nao_skin"
    earlier, _ = recordings
    bag = tmp_path / "session"
    taxels = " ".join(f"{part}={share / 'config' / 'layouts' / f'{part}.txt'}" for part in ("l_hand", "torso"))
    domain = unique_domain_id()
    listener = launch = None
    code = None
    try:
        listener = Listener(domain)
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        frames = listener.subscribe(TFMessage, TF_STATIC_TOPIC, qos=LATCHED)
        specs = as_record_would(robot="sim", bag_path=str(bag), guided=True, continue_from=[str(earlier)],
                                taxels=taxels.split(), calibration=str(share / "config" / "calibration_nominal.yaml"))
        launch = ros2_launch(ws, tmp_path, domain, "record.launch.py", "record_launch",
                             robot="sim", bag=str(bag), guided="true", rviz="false",
                             continue_from=shlex.quote(str(earlier)), taxels=taxels,
                             calibration=str(share / "config" / "calibration_nominal.yaml"))
        # a live update over the earlier sitting's 40 touches and some of this one's
        updated = lambda: [s for s in status if s["state"] == "updated" and s["touches"] > 40]  # noqa: E731
        assert listener.spin_until(updated, timeout=WAIT_S, procs=[launch]), (status[-2:], output(launch)[-3000:])
        assert updated()[0]["earlier"] == 40, updated()[0]
        assert any("skin_mount" in f for f in frames_of(frames))
        assert_started_as(listener, specs)
        code = launch.stop(signal.SIGINT, timeout=60)
    finally:
        if listener is not None:
            listener.close()
        if launch is not None and code is None:
            launch.stop(signal.SIGKILL)
    err = output(launch)
    assert code == 0 and "Traceback" not in err, err[-3000:]
    assert "robot_state_publisher is not installed: the session runs without it" in err
    recorded, _ = read_touches(bag, load_skin())
    assert recorded.n_touches > 0
    assert (tmp_path / "session_calibration" / "calibration.yaml").is_file(), sorted(tmp_path.iterdir())


def test_record_launch_with_the_real_robot_in_a_namespace_starts_its_bridges(workspace, tmp_path):  # noqa: F811
    """robot:=nao with its address and skin port, in a namespace: the NAOqi and YARP bridges start (no robot
    answers here, so they wait for it) with the parameters ``nao-skin record`` would give them, the nodes'
    topics and services are under the namespace and the skin frames carry it as a prefix; Ctrl-C ends the
    session. Where YARP's Python bindings are missing, the launch ends before any node starts, with the one
    line saying what to install."""
    ws, _, _ = workspace
    bag = tmp_path / "robot"
    domain = unique_domain_id()
    listener = Listener(domain)
    frames = listener.subscribe(TFMessage, TF_STATIC_TOPIC, qos=LATCHED)
    status = listener.subscribe(String, f"/nao9/{STATUS_TOPIC}", qos=LATCHED, keep=lambda m: json.loads(m.data))
    specs = as_record_would(namespace="/nao9", robot="nao", nao_ip="127.0.0.1",
                            events_port="/skinManager/skin_events:o", bag_path=str(bag))
    launch = ros2_launch(ws, tmp_path, domain, "record.launch.py", "record_launch", robot="nao", namespace="/nao9",
                         nao_ip="127.0.0.1", naoqi="true", events_port="/skinManager/skin_events:o", bag=str(bag))
    try:
        if importlib.util.find_spec("yarp") is None:
            code = launch.popen.wait(timeout=WAIT_S)
            assert code == 1 and "yarp_skin_bridge needs YARP's Python bindings" in output(launch), output(launch)
            assert not bag.exists()
            return
        started = [re.compile(rf"\[{node}-\d+\]: process started") for node in
                   ("naoqi_bridge", "yarp_skin_bridge", "pairing_recorder", "calibrate", "skin_heatmap")]
        assert _wait_for_lines(launch, started), output(launch)[-3000:]
        assert listener.spin_until(lambda: status, timeout=WAIT_S, procs=[launch]), output(launch)[-3000:]
        assert listener.spin_until(lambda: frames_of(frames), timeout=60)
        assert all(f.startswith("nao9/") for f in frames_of(frames)), sorted(frames_of(frames))[:5]
        assert_started_as(listener, specs)
        code = launch.stop(signal.SIGINT, timeout=60)
    finally:
        listener.close()
        if launch.alive():
            launch.stop(signal.SIGKILL)
    assert code == 0 and "Traceback" not in output(launch), output(launch)[-3000:]


def _wait_for_lines(proc: Proc, lines, timeout: float = WAIT_S) -> bool:
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if all(line.search(output(proc)) for line in lines):
            return True
        if not proc.alive():
            return False
        time.sleep(0.2)
    return False


def test_record_launch_is_refused_where_a_session_holds_its_domain(workspace, tmp_path):  # noqa: F811
    """One session per ROS domain and namespace (two would record each other's touches): the launch file claims
    it before any node starts, and ends with the one line when another session holds it."""
    from test_domain_claim import Holder

    from nao_skin.session.claim import LOCK_DIR

    ws, _, _ = workspace
    domain = unique_domain_id()
    holder = Holder(domain, LOCK_DIR)
    try:
        launch = ros2_launch(ws, tmp_path, domain, "record.launch.py", "record_launch", bag=str(tmp_path / "b"))
        try:
            code = launch.popen.wait(timeout=WAIT_S)
        finally:
            launch.stop(signal.SIGKILL)
    finally:
        holder.end()
    assert code == 1, output(launch)[-3000:]
    assert f"another nao-skin session (pid {holder.pid}) runs on ROS_DOMAIN_ID {domain}" in output(launch)
    assert not (tmp_path / "b").exists()
