"""The launch files as a ROS 2 user meets them (issue 60), under the real launch system from a colcon install.

* a launch killed (SIGTERM, SIGKILL, SIGHUP) ends its nodes as Ctrl-C does: the bag closed with every touch,
  the session's last calibration written, the ROS domain free again;
* a calibration that fails ends calibrate.launch.py with exit code 1 after the node's one line;
* calibrate.launch.py calibrates on the taxel files taxels:= names, as record.launch.py records with them;
* params_file:= of both launch files reaches the nodes (after the package's own files), and a mistake in it is
  one line before any node starts;
* a continued simulated capture plays new touches: each sitting's seed is kept in its bag and the next one plays
  another, and a seed given again is said in one line, as the repeats are during the session.
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
from test_launch import (WAIT_S, as_record_would, assert_started_as, output, ros2_launch,  # noqa: E402
                         stopped_once_written)

from nao_skin.formats.bag import BagWriter, read_touches, write_touch_bag  # noqa: E402
from nao_skin.formats.salvage import LOCK_FILE  # noqa: E402
from nao_skin.model.skin import load_skin  # noqa: E402
from nao_skin.nodes.topics import LATCHED, PROGRESS_TOPIC, SIM_STATUS_TOPIC, STATUS_TOPIC  # noqa: E402
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
    # the session's end calibrated the closed bag: every touch the recorder wrote ('recorded' leaves out the exact
    # duplicates a busy machine can make the recorder write, counted apart: docs/decisions.md, "A touch recorded
    # twice on a busy machine")
    assert ended["recorded"] + ended["duplicates"] == touches.n_touches and ended["complete"], \
        (ended, touches.n_touches)
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


def shifted_layout(src: Path, dst: Path, dx: float = 0.002) -> Path:
    """A copy of a skinManager taxel file with every taxel moved ``dx`` m along x: another robot's layout."""
    lines, after = [], False
    for line in src.read_text().splitlines():
        words = line.split()
        if after and len(words) == 6 and any(float(w) for w in words):
            words[0] = f"{float(words[0]) + dx:.8f}"
            line = " ".join(words)
        after = after or line.strip() == "[calibration]"
        lines.append(line)
    dst.write_text("\n".join(lines) + "\n")
    return dst


def test_calibrate_launch_calibrates_on_the_taxel_files_given(workspace, tmp_path):  # noqa: F811
    """A bag recorded with record.launch.py taxels:=... was calibrated on the default layouts: the launch file
    had no taxels:=. Now it names them as record.launch.py does, and the calibration is made on them."""
    from nao_skin.paths import config_dir

    ws, _, _ = workspace
    mine = shifted_layout(config_dir() / "layouts" / "l_hand.txt", tmp_path / "my l_hand.txt")
    skin = load_skin(taxel_files={"l_hand": mine})
    bag = tmp_path / "sitting"
    write_touch_bag(bag, simulate(skin, {"n_touches": 40, "pairs": [["l_hand", "torso"]]}, seed=5).touches, skin)
    out = tmp_path / "out"
    launch = ros2_launch(ws, tmp_path, unique_domain_id(), "calibrate.launch.py", "calibrate_launch",
                         inputs=str(bag), out_dir=str(out), taxels=f"'l_hand={mine}'")
    code = stopped_once_written(launch, out / "calibration.yaml")
    assert code == 0 and "Traceback" not in output(launch), output(launch)[-3000:]
    layout = yaml.safe_load((out / "calibration.yaml").read_text())["parts"]["l_hand"]["layout"]
    assert layout == {"file": mine.name, "sha256": skin.parts["l_hand"].layout_sha256}, layout


def test_calibrate_launch_takes_a_parameters_file_and_refuses_a_mistake_in_it(workspace, tmp_path):  # noqa: F811
    """Changing gate_mm meant editing the installed share/nao_skin/config/record.yaml. Now params_file:= (as
    nav2's launch files take one) applies after it; a parameter the node does not have is one line, exit 1,
    before the node starts."""
    ws, _, _ = workspace
    skin = load_skin()
    bag = tmp_path / "sitting"
    write_touch_bag(bag, simulate(skin, {"n_touches": 40, "pairs": [["l_hand", "torso"]]}, seed=5).touches, skin)
    mine = tmp_path / "mine.yaml"
    mine.write_text("calibrate:\n  ros__parameters:\n    gate_mm: 20\n    pose_weight: 0.25\n")
    out = tmp_path / "out"
    launch = ros2_launch(ws, tmp_path, unique_domain_id(), "calibrate.launch.py", "calibrate_launch",
                         inputs=str(bag), out_dir=str(out), params_file=str(mine))
    code = stopped_once_written(launch, out / "report.json")
    assert code == 0, output(launch)[-3000:]
    options = json.loads((out / "report.json").read_text())["options"]
    assert (options["gate_mm"], options["pose_weight"]) == (20.0, 0.25), options

    mine.write_text("calibrate:\n  ros__parameters:\n    gate_m: 20\n")
    launch = ros2_launch(ws, tmp_path, unique_domain_id(), "calibrate.launch.py", "refused_launch",
                         inputs=str(bag), out_dir=str(tmp_path / "out2"), params_file=str(mine))
    try:
        code = launch.popen.wait(timeout=WAIT_S)
    finally:
        launch.stop(signal.SIGKILL)
    err = output(launch)
    assert code == 1 and "process started" not in err and "Traceback" not in err, err[-3000:]
    assert f"params_file:={mine}: calibrate.gate_m (section calibrate): node 'calibrate' has no parameter 'gate_m'" \
        " (did you mean 'gate_mm'?)" in err, err[-3000:]


FAST = ("sim_robot:\n  ros__parameters:\n    pairs: [l_hand-torso]\n    touches_per_pair: 20\n"
        "    touch_period: 0.4\n    press_duration: 0.15\n    hold: 0.05\n"
        "calibrate:\n  ros__parameters:\n    live_every_touches: 4\n    live_period: 1.0\n")


def sitting(ws, tmp_path, bag: Path, name: str, **arguments) -> tuple:
    """One sitting of record.launch.py with the simulated robot, until it has played every touch, then Ctrl-C:
    ``(launch, the calibrate node's statuses, the nodes' parameters as the launch started them)``."""
    domain = unique_domain_id()
    listener = launch = None
    code = None
    try:
        listener = Listener(domain)
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        sim = listener.subscribe(String, SIM_STATUS_TOPIC, keep=lambda m: json.loads(m.data))
        specs = as_record_would(robot="sim", bag_path=str(bag), **{
            {"continue_from": "continue_from", "params_file": "params_file", "seed": "seed"}[k]:
            ([v] if k == "continue_from" else v) for k, v in arguments.items()})
        launch = ros2_launch(ws, tmp_path, domain, "record.launch.py", name, bag=str(bag), **arguments)
        assert listener.spin_until(lambda: sim and sim[-1]["done"], timeout=WAIT_S, procs=[launch]), \
            (sim[-1:], output(launch)[-3000:])
        assert listener.spin_until(lambda: any(s["state"] == "updated" for s in status), timeout=WAIT_S,
                                   procs=[launch]), (status[-1:], output(launch)[-3000:])
        assert_started_as(listener, specs)
        code = launch.stop(signal.SIGINT, timeout=60)
    finally:
        if listener is not None:
            listener.close()
        if launch is not None and code is None:
            launch.stop(signal.SIGKILL)
    assert code == 0 and "Traceback" not in output(launch), output(launch)[-3000:]
    return launch, status, {spec.name: spec for spec in specs}


def test_a_continued_simulated_capture_plays_new_touches(workspace, tmp_path):  # noqa: F811
    """continue_from:=B with the simulated robot replayed B's seed: every new touch an exact duplicate of one in
    B, dropped (39 of 39), and not a word until the end. Now the seed B's simulated robot played is kept in B and
    the continuing sitting plays one no sitting played; given the same seed again (seed:=), the launch says so in
    one line and the calibrate node says the repeats while the sitting runs. The parameters file (params_file:=)
    makes the sittings short."""
    from nao_skin.formats.bag import simulator_seed
    from nao_skin.touch.datasets import repeats_of

    ws, _, _ = workspace
    fast = tmp_path / "fast.yaml"
    fast.write_text(FAST)
    first, second, third = (tmp_path / name for name in ("first", "second", "third"))
    _, _, nodes = sitting(ws, tmp_path, first, "first_launch", params_file=str(fast))
    assert nodes["sim_robot"].overrides["seed"] == 1 and simulator_seed(first) == 1
    launch, status, nodes = sitting(ws, tmp_path, second, "second_launch", params_file=str(fast),
                                    continue_from=str(first))
    assert simulator_seed(second) == 2 and nodes["sim_robot"].overrides["seed"] == 2
    earlier, _ = read_touches(first, load_skin())
    new, _ = read_touches(second, load_skin())
    assert new.n_touches >= 15 and repeats_of(new, earlier) == 0, (new.n_touches, repeats_of(new, earlier))
    assert "repeat touches of the earlier sittings" not in output(launch)
    # the first seed again, given: said before the nodes start, and the repeats while the sitting runs
    launch, _, _ = sitting(ws, tmp_path, third, "third_launch", params_file=str(fast), continue_from=str(second),
                           seed="1")
    err = output(launch)
    assert f"record.launch.py: seed:=1: the earlier sitting {first} played this seed too" in err, err[-3000:]
    repeats = [line for line in err.splitlines() if "repeat touches of the earlier sittings' bags exactly" in line]
    assert len(repeats) == 1 and repeats[0].startswith("[calibrate-"), repeats
    again, _ = read_touches(third, load_skin())
    assert simulator_seed(third) == 1 and repeats_of(again, earlier) == again.n_touches > 0


def test_record_launch_gives_its_parameters_file_to_the_nodes(workspace, tmp_path):  # noqa: F811
    """params_file:= reaches every node of ours after config/record.yaml (the live nodes' parameters are what
    nao-skin record --params-file would give them), namespaced and /** sections as rcl applies them."""
    ws, _, _ = workspace
    mine = tmp_path / "mine.yaml"
    mine.write_text(FAST + "/**:\n  ros__parameters:\n    use_sim_time: false\n"
                           "/**/pairing_recorder:\n  ros__parameters:\n    flush_period: 0.5\n"
                           "/**/calibrate:\n  ros__parameters:\n    gate_mm: 20\n")
    _, _, nodes = sitting(ws, tmp_path, tmp_path / "bag", "record_launch", params_file=str(mine))
    assert mine in nodes["calibrate"].params_files
