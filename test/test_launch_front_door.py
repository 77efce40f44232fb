"""The launch files as a ROS 2 user meets them (issue 60), under the real launch system from a colcon install.

* a launch killed (SIGTERM, SIGKILL, SIGHUP) ends its nodes as Ctrl-C does: the bag closed with every touch,
  the session's last calibration written, the ROS domain free again;
* a calibration that fails ends calibrate.launch.py with exit code 1 after the node's one line;
"""
from __future__ import annotations

import json
import os
import re
import signal
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from real_launch import require_launch
from ros_harness import Listener, unique_domain_id

require_launch()
pytest.importorskip("rclpy")
from std_msgs.msg import String  # noqa: E402
from test_colcon import workspace  # noqa: E402,F401 - the workspace fixture
from test_launch import WAIT_S, output, ros2_launch  # noqa: E402

from nao_skin.formats.bag import BagWriter, read_touches, write_touch_bag  # noqa: E402
from nao_skin.formats.salvage import LOCK_FILE  # noqa: E402
from nao_skin.model.skin import load_skin  # noqa: E402
from nao_skin.nodes.topics import LATCHED, PROGRESS_TOPIC, STATUS_TOPIC  # noqa: E402
from nao_skin.sim.simulate import simulate  # noqa: E402

pytestmark = [pytest.mark.middleware, pytest.mark.slow]
STARTED = re.compile(r"\[INFO\] \[(\w+)-\d+\]: process started with pid \[(\d+)\]")


def started_nodes(launch, names) -> dict:
    """``{pid: name}`` of the nodes the launch says it started, once it has said so for each of ``names``."""
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        found = {int(pid): name for name, pid in STARTED.findall(output(launch))}
        if set(names) <= set(found.values()):
            return found
        assert launch.alive(), output(launch)[-3000:]
        time.sleep(0.2)
    raise AssertionError(f"not every node started: {output(launch)[-3000:]}")


def running(pid: int) -> bool:
    """The process runs (not a zombie: its parent, the launch, may be gone and no one reaps it at once)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except (OSError, IndexError):
        return False


def wait_gone(pids, timeout: float = WAIT_S) -> list:
    """The processes still running after at most ``timeout`` s (polled)."""
    deadline = time.monotonic() + timeout
    while True:
        alive = [pid for pid in pids if running(pid)]
        if not alive or time.monotonic() >= deadline:
            return alive
        time.sleep(0.1)


def domain_free(domain: int) -> bool:
    from nao_skin.errors import ConfigError
    from nao_skin.session.claim import claim_domain

    try:
        claim_domain(domain).release()
    except ConfigError:
        return False
    return True


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL, signal.SIGHUP], ids=lambda s: s.name)
def test_a_launch_killed_ends_its_nodes_as_ctrl_c_does(workspace, tmp_path, sig):  # noqa: F811
    """launch 3.4.3 handles SIGINT only: SIGTERM or SIGHUP ended it at once (SIGKILL always does) and left the
    four nodes running, re-parented, the recorder writing, and the domain free for a second session beside
    them. Now the launch stops them as at Ctrl-C (SIGTERM, SIGHUP), and each node stops by itself when the
    launch is gone (SIGKILL): the bag closed with every touch, the session's calibration written."""
    ws, _, _ = workspace
    bag = tmp_path / "session"
    domain = unique_domain_id()
    listener = launch = None
    nodes: dict = {}
    try:
        listener = Listener(domain)
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        progress = listener.subscribe(String, PROGRESS_TOPIC, keep=lambda m: json.loads(m.data))
        launch = ros2_launch(ws, tmp_path, domain, "record.launch.py", "record_launch", bag=str(bag))
        nodes = started_nodes(launch, ("sim_robot", "pairing_recorder", "skin_heatmap", "calibrate"))
        # a live update, so that the session's end has a calibration to write
        assert listener.spin_until(lambda: any(s["state"] == "updated" for s in status), timeout=WAIT_S,
                                   procs=[launch]), (status[-1:], output(launch)[-3000:])
        reported = progress[-1]["touches"]
        os.kill(launch.popen.pid, sig)          # the launch process alone, as `kill PID` does
        left = wait_gone(nodes)
        assert not left, ({pid: nodes[pid] for pid in left}, output(launch)[-3000:])
        assert listener.spin_until(lambda: status[-1]["state"] == "ended", timeout=30), status[-1]
        assert launch.popen.wait(timeout=WAIT_S) is not None
        assert domain_free(domain)
    finally:
        if listener is not None:
            listener.close()
        if launch is not None:
            launch.stop(signal.SIGKILL)       # the launch's process group: any node left too
    ended = status[-1]
    assert not (bag / LOCK_FILE).exists(), "the recorder did not close its bag"
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["files"] and info["message_count"] > 0
    touches, report = read_touches(bag, load_skin())
    assert touches.n_touches >= reported and not report.skipped, report.lines()
    # the session's end calibrated the closed bag: every touch the recorder wrote
    assert ended["recorded"] == touches.n_touches and ended["complete"], (ended, touches.n_touches)
    assert Path(ended["calibration"]) == tmp_path / "session_calibration" / "calibration.yaml", ended
    assert Path(ended["calibration"]).is_file()
    if sig != signal.SIGKILL:       # the launch itself stopped them, as at Ctrl-C
        assert launch.popen.returncode == 0, output(launch)[-3000:]
        assert "Traceback" not in output(launch), output(launch)[-3000:]


def failing_input(case: str, where: Path) -> tuple:
    """``(path, what the node's line says)`` of an input whose calibration fails once read."""
    path = where / case.replace(" ", "_")
    if case == "not a recording":
        path.write_text("vm-1\n")
        return path, f"{path}: neither a rosbag2 recording"
    if case == "no touch":
        with BagWriter(path, "mcap", kind="touches"):     # a session that recorded nothing
            pass
        return path, f"{path}: no usable touch in the input"
    skin = load_skin()
    touches = simulate(skin, {"n_touches": 40, "pairs": [["l_hand", "torso"]]}, seed=5).touches
    write_touch_bag(path, touches.subset(np.arange(3)), skin)
    return path, "a mount needs at least 10"


@pytest.mark.parametrize("case", ["not a recording", "no touch", "too few touches"])
def test_a_calibration_that_fails_ends_the_calibrate_launch_with_exit_1(workspace, tmp_path, case):  # noqa: F811
    """The input exists, so the node starts; its calibration then fails. It logged one [ERROR], published nominal
    frames on and on, and Ctrl-C exited 0: now the node's one line, exit 2, and the launch ends with exit 1, as
    its docstring and the README say."""
    ws, _, _ = workspace
    bad, says = failing_input(case, tmp_path)
    out = tmp_path / "out"
    launch = ros2_launch(ws, tmp_path, unique_domain_id(), "calibrate.launch.py", "calibrate_launch",
                         inputs=str(bad), out_dir=str(out))
    try:
        code = launch.popen.wait(timeout=WAIT_S)
    finally:
        launch.stop(signal.SIGKILL)
    err = output(launch)
    said = [line for line in err.splitlines() if line.startswith("[calibrate-1]") and re.search("error", line, re.I)]
    assert code == 1, err[-3000:]
    assert len(said) == 1 and said[0].startswith("[calibrate-1] error: ") and says in said[0], said
    assert "calibrate-1 ended with exit code 2; the launch ends" in err and "Traceback" not in err, err[-3000:]
    assert not out.exists()
