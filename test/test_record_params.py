"""Parameters and preconditions of a record session, checked before anything starts; its temporary files.

1. A float parameter given as an integer (``gate_mm: 20`` in a params file
   as ``ros2 launch`` passes it, ``-p progress_period:=1`` on a command line)
   is taken by real nodes and stored as a float; a string for it ends the
   node with one line and exit 2.
2. ``nao-skin record --param``: an unknown parameter, an unknown node, a
   value of the wrong type or out of the node's range is refused with one
   line (the node's parameters, the session's nodes) and exit 2, before any
   node starts; a node started without record refuses the same range.
3. ``nao-skin record --robot nao`` on a machine without YARP's Python
   bindings: one line saying what to install, exit 2, nothing started.
4. The temporary directory of generated parameter files is removed when
   record ends (printing only, stopped by a signal, a node failing), and
   kept with ``--keep-temp``.
"""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from ros_harness import ROOT, Listener, Proc, node_process, ros_env, unique_domain_id
from test_record_session import record_cmd

pytest.importorskip("rclpy")
from rcl_interfaces.msg import ParameterType  # noqa: E402
from rcl_interfaces.srv import GetParameters  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from nao_skin import cli  # noqa: E402
from nao_skin.nodes.topics import PROGRESS_TOPIC  # noqa: E402
from nao_skin.session.params import CALIBRATE, options_from_params  # noqa: E402

pytestmark = pytest.mark.middleware   # runs nao-skin record and its nodes over DDS

RECORD_YAML = ROOT / "config" / "record.yaml"


def get_parameters(listener: Listener, node: str, names: list, procs) -> list:
    """The node's parameter values through its real parameter service."""
    client = listener.node.create_client(GetParameters, f"/{node}/get_parameters")
    return listener.ask(client, GetParameters.Request(names=names), procs).values


def test_nodes_take_integers_for_float_parameters(tmp_path):
    env = ros_env(unique_domain_id())
    listener = calib = recorder = None
    try:
        listener = Listener(int(env["ROS_DOMAIN_ID"]))
        progress = listener.subscribe(String, PROGRESS_TOPIC, keep=lambda m: json.loads(m.data))
        # as ros2 launch passes it: a params file saying `gate_mm: 20`
        params = tmp_path / "calibrate.yaml"
        params.write_text(yaml.safe_dump({"calibrate": {"ros__parameters": {"gate_mm": 20}}}))
        assert "gate_mm: 20\n" in params.read_text()
        calib = node_process("calibrate", {}, env, tmp_path, params_file=params)
        # as typed on a command line: -p progress_period:=1
        recorder = node_process("pairing_recorder", {"bag_path": str(tmp_path / "bag"), "flush_period": 1,
                                                     "progress_period": 1}, env, tmp_path, params_file=RECORD_YAML)
        assert "progress_period:=1" in recorder.popen.args
        (gate,) = get_parameters(listener, "calibrate", ["gate_mm"], [calib])
        assert (gate.type, gate.double_value) == (ParameterType.PARAMETER_DOUBLE, 20.0)
        values = get_parameters(listener, "pairing_recorder", ["flush_period", "progress_period"], [recorder])
        assert [(v.type, v.double_value) for v in values] == [(ParameterType.PARAMETER_DOUBLE, 1.0)] * 2
        assert listener.spin_until(lambda: len(progress) >= 2, procs=[recorder])   # its progress timer runs
    finally:
        if listener is not None:
            listener.close()
        codes = [p.stop() for p in (calib, recorder) if p is not None]
    assert codes == [0, 0], calib.stderr()[-2000:] + recorder.stderr()[-2000:]


def test_node_refuses_a_string_for_a_float_parameter(tmp_path):
    node = node_process("calibrate", {"gate_mm": "abc"}, ros_env(unique_domain_id()), tmp_path,
                        params_file=RECORD_YAML)
    try:
        node.popen.wait(timeout=60)
    finally:
        code = node.stop()
    assert code == 2
    err = node.stderr()
    assert "Traceback" not in err
    assert "error: node 'calibrate': parameter 'gate_mm' must be a number like 15.0, not 'abc'" in err.splitlines()


@pytest.mark.parametrize("node, params, line", [
    ("skin_heatmap", {"rate": 0.0}, "error: node 'skin_heatmap': parameter rate:=0.0: expected a number in [1e-05, 1000]"),
    ("skin_heatmap", {"rate": 1e-300},        # its timer period would overflow rcl's nanoseconds
     "error: node 'skin_heatmap': parameter rate:=1e-300: expected a number in [1e-05, 1000]"),
    ("skin_heatmap", {"legend_origin": [1.0, 2.0]},
     "error: node 'skin_heatmap': parameter legend_origin:=[1.0, 2.0]: expected 3 numbers"),
    ("skin_heatmap", {"rate": []}, "error: node 'skin_heatmap': parameter 'rate' must be a number like 10.0,"
                                   " not an empty list"),
    ("naoqi_bridge", {"reconnect_min": 10.0, "reconnect_max": 1.0},     # each within its rule, not together
     "error: parameters reconnect_min:=10.0 and reconnect_max:=1.0: the first delay is longer than the longest"),
    ("calibrate", {"live_every_touches": -3},
     "error: node 'calibrate': parameter live_every_touches:=-3: expected a whole number >= 1"),
    # a joint list read and published without a word: the same joint twice, a blank name
    ("naoqi_bridge", {"joint_names": ["HeadYaw", "HeadYaw"]},
     "error: node 'naoqi_bridge': parameter joint_names:=['HeadYaw', 'HeadYaw']: expected distinct joint names as"
     " NAOqi spells them (e.g. HeadYaw), at least one"),
    ("naoqi_bridge", {"joint_names": ["HeadYaw", ""]},
     "error: node 'naoqi_bridge': parameter joint_names:=['HeadYaw', '']: expected distinct joint names as"
     " NAOqi spells them (e.g. HeadYaw), at least one"),
    # a port name YARP refuses: the bridge ran on, YARP logging 'invalid source' twice a second
    ("yarp_skin_bridge", {"compensated_ports.torso": "nosl"},
     "error: node 'yarp_skin_bridge': parameter compensated_ports.torso:='nosl': expected empty (no port) or a"
     " YARP port name: '/' and no spaces, e.g. /nao/skin/torso_comp"),
])
def test_a_node_refuses_a_value_out_of_its_range_in_one_line(tmp_path, node, params, line):
    """``ros2 run`` / ``ros2 launch`` reach the node without record's checks: the node holds the same rule."""
    proc = node_process(node, params, ros_env(unique_domain_id()), tmp_path, params_file=RECORD_YAML)
    try:
        proc.popen.wait(timeout=60)
    finally:
        code = proc.stop()
    assert code == 2 and "Traceback" not in proc.stderr()
    assert line in proc.stderr().splitlines(), proc.stderr()[-2000:]


def test_the_live_calibrate_node_refuses_its_out_dir_at_start_not_when_the_session_ends(tmp_path):
    """The session's last live calibration goes to out_dir: a directory it may not replace was only said
    when the session ended, after every update of it."""
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("a user's notes\n")
    proc = node_process("calibrate", {"live": True, "out_dir": str(foreign)}, ros_env(unique_domain_id()), tmp_path,
                        params_file=RECORD_YAML)
    try:
        proc.popen.wait(timeout=60)
    finally:
        code = proc.stop()
    assert code == 2 and "Traceback" not in proc.stderr()
    assert (f"error: out_dir {foreign}: is a non-empty directory nao-skin did not write (it holds notes.txt);"
            f" choose a new or empty directory") in proc.stderr().splitlines(), proc.stderr()[-2000:]
    assert [p.name for p in foreign.iterdir()] == ["notes.txt"]
    # the calibration the session starts from, in the directory its end would replace (on request the node
    # refused it; live it was replaced)
    previous = tmp_path / "previous"
    assert cli.main(["calibrate", str(ROOT / "bags" / "sim_default" / "touches"), "--out", str(previous),
                     "--no-plots", "--quiet"]) == 0
    before = (previous / "calibration.yaml").read_bytes()
    proc = node_process("calibrate", {"live": True, "out_dir": str(previous),
                                      "calibration": str(previous / "calibration.yaml")},
                        ros_env(unique_domain_id()), tmp_path, params_file=RECORD_YAML)
    try:
        proc.popen.wait(timeout=60)
    finally:
        code = proc.stop()
    assert code == 2 and "Traceback" not in proc.stderr()
    assert (f"error: out_dir {previous}: contains the input {previous / 'calibration.yaml'}; writing there would"
            f" replace it, choose another directory") in proc.stderr().splitlines(), proc.stderr()[-2000:]
    assert (previous / "calibration.yaml").read_bytes() == before


def test_a_node_names_what_it_was_given_and_does_not_have(tmp_path):
    """ROS ignores an override the node does not declare: a typo, or a mapping where a value belongs."""
    from visualization_msgs.msg import MarkerArray

    from nao_skin.nodes.topics import HEATMAP_TOPIC

    env = ros_env(unique_domain_id())
    params = tmp_path / "heatmap.yaml"
    params.write_text("skin_heatmap:\n  ros__parameters:\n    rate: {hz: 5}\n")
    node = node_process("skin_heatmap", {"rat": 5.0}, env, tmp_path, params_file=params)
    listener = None
    try:
        listener = Listener(int(env["ROS_DOMAIN_ID"]))
        heat = listener.subscribe(MarkerArray, HEATMAP_TOPIC)
        assert listener.spin_until(lambda: heat, procs=[node]), node.stderr()[-2000:]
    finally:
        if listener is not None:
            listener.close()
        code = node.stop()
    assert code == 0
    assert ("ignored parameters this node does not have: rat (did you mean 'rate'?), rate.hz (did you mean"
            " 'rate'?)") in node.stderr(), node.stderr()[-2000:]


def test_a_node_takes_an_empty_list_and_refuses_arguments_rcl_cannot_parse_in_one_line(tmp_path):
    from visualization_msgs.msg import MarkerArray

    from nao_skin.nodes.topics import HEATMAP_TOPIC

    env = ros_env(unique_domain_id())
    # '-p taxels:=[]': rcl gives an empty list no type; it means no layout file, as [''] does
    node = node_process("skin_heatmap", {"taxels": []}, env, tmp_path)
    listener = None
    try:
        listener = Listener(int(env["ROS_DOMAIN_ID"]))
        heat = listener.subscribe(MarkerArray, HEATMAP_TOPIC)
        assert listener.spin_until(lambda: heat, procs=[node]), node.stderr()[-2000:]   # up and drawing
    finally:
        if listener is not None:
            listener.close()
        code = node.stop()
    assert code == 0 and "Traceback" not in node.stderr()
    bad = Proc([sys.executable, "-m", "nao_skin.nodes.skin_heatmap", "--ros-args", "-p", "skin_config:={a: 1}"],
               env, tmp_path, "bad_args")
    try:
        bad.popen.wait(timeout=60)
    finally:
        code = bad.stop()
    assert code == 2 and "Traceback" not in bad.stderr()
    assert ("error: the ROS arguments: Couldn't parse parameter override rule: '-p skin_config:={a: 1}'."
            " Error: Unknown YAML event") in bad.stderr().splitlines(), bad.stderr()
    # a parameters file that is not there, or not YAML: our one line before rcl's two
    for text in (None, "calibrate: [\n"):
        params = tmp_path / "params.yaml"
        if text is not None:
            params.write_text(text)
        node = node_process("calibrate", {}, env, tmp_path, params_file=params)
        try:
            node.popen.wait(timeout=60)
        finally:
            code = node.stop()
        lines = node.stderr().strip().splitlines()
        assert code == 2 and len(lines) == 1 and lines[0].startswith(f"error: {params}: "), lines
    # a bare value, which rcl takes without a word: the node runs on its defaults, and says the file gave nothing
    params.write_text("gate_mm 20\n")
    node = node_process("calibrate", {}, env, tmp_path, params_file=params)
    try:
        deadline = time.monotonic() + 120
        while "gives no node any parameter" not in node.stderr() and node.popen.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        code = node.stop()
    assert f"warning: {params}: gives no node any parameter" in node.stderr().splitlines(), node.stderr()
    assert code == 0 and "Traceback" not in node.stderr(), node.stderr()


def nao_skin(args, env=None, timeout=120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "nao_skin.cli", *args], env=env or ros_env(unique_domain_id()),
                          cwd=str(ROOT), capture_output=True, text=True, timeout=timeout)


def one_error_line(run: subprocess.CompletedProcess) -> str:
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("nao-skin record: error: "), run.stderr
    return lines[0]


def test_record_refuses_unknown_or_mistyped_parameters(tmp_path):
    bag = tmp_path / "touches"
    line = one_error_line(nao_skin(["record", "--print", "--bag", str(bag), "--param", "calibrate.gate_mmm=3"]))
    assert "calibrate.gate_mmm" in line and "did you mean 'gate_mm'?" in line
    assert line.split("its parameters: ")[1].split(", ") == list(CALIBRATE)

    line = one_error_line(nao_skin(["record", "--print", "--bag", str(bag), "--param", "calib.gate_mm=3"]))
    assert "no node 'calib'" in line
    assert "sim_robot, pairing_recorder, skin_heatmap, calibrate" in line

    line = one_error_line(nao_skin(["record", "--print", "--bag", str(bag), "--param", "calibrate.gate_mm=abc"]))
    assert "calibrate.gate_mm=abc" in line and "expected a number" in line

    # out of the range the node accepts: its own rule, checked here (a rate of 0 was a node's traceback)
    for item, expected in (("skin_heatmap.rate=0", "expected a number in [1e-05, 1000]"),
                           ("calibrate.live_every_touches=-3", "expected a whole number >= 1"),
                           ("calibrate.gate_mm=-1", "expected a number in [0, 10000]"),
                           ("pairing_recorder.storage=zip", "expected one of mcap, sqlite3")):
        line = one_error_line(nao_skin(["record", "--print", "--bag", str(bag), "--param", item]))
        assert f"--param {item}: {expected}" in line, line

    # parameters each within its rule but not together: the node's own check of them together, here, with
    # the values of record.yaml (a press longer than the period was a node's error after the others started)
    line = one_error_line(nao_skin(["record", "--print", "--bag", str(bag), "--param", "sim_robot.touch_period=0.3"]))
    assert line.startswith("nao-skin record: error: node sim_robot (parameters from ") and "record.yaml" in line
    assert line.endswith("press_duration 0.3 s + 2 x hold 0.1 s must be shorter than touch_period 0.3 s"
                         " (and press_duration > 0)"), line
    line = one_error_line(nao_skin(["record", "--robot", "nao", "--print", "--bag", str(bag),
                                    "--param", "naoqi_bridge.reconnect_min=10"]))
    assert "node naoqi_bridge" in line and "bridges.yaml" in line
    assert line.endswith("parameters reconnect_min:=10.0 and reconnect_max:=5.0: the first delay is longer than"
                         " the longest"), line

    # the robot's address and skinManager's port, by the bridges' own rules
    line = one_error_line(nao_skin(["record", "--robot", "nao", "--print", "--events-port", "-1"]))
    assert line.endswith("--events-port -1: expected a YARP port name: '/' and no spaces,"
                         " e.g. /skinManager/skin_events:o"), line
    for item, expected in (("naoqi_bridge.joint_names=[]", "expected distinct joint names as NAOqi spells them"),
                           ("yarp_skin_bridge.compensated_ports.head=/a port", "expected empty (no port) or a YARP")):
        line = one_error_line(nao_skin(["record", "--robot", "nao", "--print", "--param", item]))
        assert f"--param {item}: {expected}" in line, line
    for bad in ("not an ip!", "127.0.0.1:9559", "999.1.1.1"):     # a port in it was retried for ever, exit 0
        line = one_error_line(nao_skin(["record", "--robot", "nao", "--print", "--nao-ip", bad]))
        assert line.endswith(f"--nao-ip {bad}: expected an IPv4 address or a host name, e.g. 192.168.1.10 or"
                             f" nao.local (the port is nao_port)"), line

    # without --print: refused before any node starts (no bag, no "started")
    for item in ("calibrate.gate_mmm=3", "sim_robot.touch_period=0"):
        run = nao_skin(["record", "--bag", str(bag), "--param", item])
        one_error_line(run)
        assert not bag.exists()

    # an integer for a float is what people type: accepted, passed on as a float
    run = nao_skin(["record", "--print", "--bag", str(bag), "--param", "calibrate.gate_mm=20",
                    "--param", "pairing_recorder.flush_period=2", "--param", "skin_heatmap.rate=1e2"])
    assert run.returncode == 0, run.stderr
    assert "-p gate_mm:=20.0" in run.stdout and "-p flush_period:=2.0" in run.stdout
    assert "-p rate:=100.0" in run.stdout      # '1e2' as rcl reads it, where YAML 1.1 reads a string


def test_record_refuses_what_its_nodes_would_fail_on_before_any_starts(tmp_path):
    """An earlier output where the session's calibration goes (`nao-skin calibrate --out foo_calibration`,
    then `record --bag foo`) was replaced at the session's end without a word; a simulator preset or
    pair it does not know, a calibration that does not exist, each ended a node after the others had
    started and left an empty bag behind, its name taken."""
    bag = tmp_path / "foo"
    earlier = tmp_path / "foo_calibration"
    earlier.mkdir()
    (earlier / "calibration.yaml").write_text("mine\n")
    line = one_error_line(nao_skin(["record", "--bag", str(bag)]))
    assert f"calibration output {earlier}: exists already" in line and "calibrate.out_dir=NEW_DIR" in line
    assert (earlier / "calibration.yaml").read_text() == "mine\n" and not bag.exists()
    other = tmp_path / "other"
    for item, expected in (("sim_robot.preset=nosuch", "unknown preset 'nosuch'"),
                           ("sim_robot.pairs=[l_hand-nose]", "'l_hand-nose': expected HAND-PART"),
                           (f"calibrate.calibration={tmp_path / 'none.yaml'}", "none.yaml: cannot read calibration"),
                           ("calibrate.out_dir=/dev/null", "calibration output /dev/null: exists already"),
                           # a node's own layout that is not there: the recorder died after the others were up
                           (f"pairing_recorder.taxels=[l_hand={tmp_path / 'nope.txt'}]",
                            "node pairing_recorder (parameters from"),
                           # the calibrate node died on these at its start, and the empty bag took the name
                           ("calibrate.guidance_pairs=[x]", "parameter guidance_pairs: 'x': expected HAND-PART"),
                           # said as config/simulation.yaml's fault
                           ("sim_robot.pairs=[l_hand-torso,l_hand-torso]",
                            "parameter pairs: 'l_hand-torso' is given twice"),
                           (f"calibrate.out_dir={other}", f"calibration output {other}: is the bag {other}"),
                           (f"calibrate.out_dir={other / 'cal'}", f"calibration output {other / 'cal'}: lies inside"
                                                                   f" the bag {other}"),
                           (f"calibrate.out_dir={tmp_path / 'new'}/..", f"calibration output {tmp_path / 'new'}/..:"
                                                                         f" holds the bag {other}")):
        line = one_error_line(nao_skin(["record", "--bag", str(other), "--param", item]))
        assert expected in line, line
        assert not other.exists()


def _config_copy(tmp_path, edit) -> Path:
    """A copy of the package's config directory whose record.yaml ``edit`` (text -> text) changed."""
    import shutil

    cfg = tmp_path / "config"
    if cfg.exists():
        shutil.rmtree(cfg)
    shutil.copytree(ROOT / "config", cfg)
    (cfg / "record.yaml").write_text(edit((ROOT / "config" / "record.yaml").read_text()))
    return cfg


@pytest.mark.parametrize("edit, expected", [
    (lambda t: t.replace("joint_rate: 100.0", "joint_rate: .nan", 1), "sim_robot.joint_rate=nan: expected a number"),
    (lambda t: t.replace("flush_period: 1.0", "flush_period: -1.0", 1),
     "pairing_recorder.flush_period=-1.0: expected a number in (0"),
    (lambda t: t.replace("seed: 1 ", "seed: one ", 1), "sim_robot.seed=one: expected an integer"),
    # rcl refuses such a file in every node that reads it, in two lines each, after the bag was made
    (lambda t: t + "extra_node: 5\n", "'extra_node' is a value where a node name maps to its ros__parameters"),
    (lambda t: t.replace("joint_rate: 100.0", "joint_rate:", 1), "sim_robot.joint_rate has no value (line 13)"
                                                                  " (ROS refuses the whole file)"),
], ids=["nan", "negative", "type", "structure", "no-value"])
def test_record_refuses_a_bad_value_in_its_parameter_file_before_any_node_starts(tmp_path, edit, expected):
    """The same value refused given with --param went through when record.yaml held it: every node started,
    one refused it, and an empty bag took the name (exit 0 when the session ended before that node read its
    parameters; an adversarial review, 2026-11-28)."""
    cfg = _config_copy(tmp_path, edit)
    assert (cfg / "record.yaml").read_text() != RECORD_YAML.read_text()
    bag = tmp_path / "touches"
    line = one_error_line(nao_skin(["record", "--bag", str(bag), "--duration", "30"],
                                   env=ros_env(unique_domain_id(), NAO_SKIN_CONFIG=cfg)))
    assert f"{cfg / 'record.yaml'}: " in line and expected in line, line
    assert not bag.exists()


def test_record_checks_a_parameter_file_value_only_where_no_override_replaces_it(tmp_path):
    cfg = _config_copy(tmp_path, lambda t: t.replace("joint_rate: 100.0", "joint_rate: .nan", 1))
    env = ros_env(unique_domain_id(), NAO_SKIN_CONFIG=cfg)
    run = nao_skin(["record", "--print", "--bag", str(tmp_path / "b"), "--param", "sim_robot.joint_rate=50"], env=env)
    assert run.returncode == 0, run.stderr
    assert "joint_rate:=50.0" in run.stdout, run.stdout


def test_record_refuses_a_guided_start_the_simulated_robot_would_refuse(tmp_path):
    """guided_start 0 passed record's checks, and sim_robot then died on it after the other nodes were up."""
    line = one_error_line(nao_skin(["record", "--print", "--guided", "--bag", str(tmp_path / "b"),
                                    "--param", "sim_robot.guided_start=0"]))
    assert "--param sim_robot.guided_start=0" in line, line


@pytest.mark.parametrize("off, says", [
    (["--param", "calibrate.guidance=false"], "(calibrate.guidance=false here)"),
    (["--param", "calibrate.live=false"], "(calibrate.live=false here)"),
    (["--param", "calibrate.live=false", "--param", "calibrate.guidance=false"],
     "(calibrate.live=false and calibrate.guidance=false here)"),
])
def test_record_refuses_a_guided_robot_without_the_guidance_it_follows(tmp_path, off, says):
    """`record --guided` with the calibrate node's guidance or live updates off exited 0 and played random
    touches only, every batch logged 'random (no guidance yet)'."""
    line = one_error_line(nao_skin(["record", "--print", "--guided", "--bag", str(tmp_path / "b"), *off]))
    assert "sim_robot.guided=true follows the guidance" in line and says in line, line
    run = nao_skin(["record", "--print", "--bag", str(tmp_path / "b"), *off])     # not guided: fine
    assert run.returncode == 0, run.stderr


@pytest.mark.parametrize("pairs, bad", [("[head-torso]", "head-torso"), ("[torso-l_hand]", "torso-l_hand"),
                                        ("[l_hand-torso, r_hand-l_hand]", "r_hand-l_hand")])
def test_record_refuses_guidance_pairs_no_self_touch_makes(tmp_path, pairs, bad):
    """guidance_pairs took any two parts: with head-torso the guidance named 48 of 48 targets unreachable,
    one triangle twice."""
    line = one_error_line(nao_skin(["record", "--print", "--bag", str(tmp_path / "b"),
                                    "--param", f"calibrate.guidance_pairs={pairs}"]))
    assert f"parameter guidance_pairs: '{bad}' is not a self-touch pair of the skin config" in line, line
    assert "l_hand-torso" in line and "r_hand-head" in line


def test_record_checks_the_parameters_where_rclpy_is_not_installed(tmp_path):
    """The nodes' parameters are plain data (nao_skin.session.params): `record --print` with an override
    checked them by importing the node modules, which import rclpy, and ended in a traceback without it."""
    blocked = ("import sys; sys.modules['rclpy'] = None; from nao_skin.cli import main; sys.exit(main(sys.argv[1:]))")
    base = [sys.executable, "-c", blocked, "record", "--print", "--bag", str(tmp_path / "b")]
    env = ros_env(unique_domain_id())
    run = subprocess.run([*base, "--param", "calibrate.gate_mm=20", "--param", "sim_robot.seed=3"], env=env,
                         cwd=str(ROOT), capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert "gate_mm:=20.0" in run.stdout and "seed:=3" in run.stdout, run.stdout
    run = subprocess.run([*base, "--param", "sim_robot.touch_period=0.1", "--param", "sim_robot.press_duration=0.3"],
                         env=env, cwd=str(ROOT), capture_output=True, text=True, timeout=120)
    assert "Traceback" not in run.stderr
    assert "touch_period" in one_error_line(run)


def test_record_for_the_nao_without_yarp_says_what_to_install(tmp_path):
    # stands in for a machine without YARP's Python bindings: `import yarp` fails in the record process
    shim = tmp_path / "no_yarp"
    shim.mkdir()
    (shim / "yarp.py").write_text('raise ImportError("no YARP Python bindings on this machine")\n')
    env = ros_env(unique_domain_id())
    env["PYTHONPATH"] = str(shim) + ":" + env["PYTHONPATH"]
    bag = tmp_path / "touches"
    run = nao_skin(["record", "--robot", "nao", "--nao-ip", "127.0.0.1", "--bag", str(bag)], env=env)
    line = one_error_line(run)
    assert "yarp_skin_bridge needs YARP's Python bindings" in line
    assert "make setup-test" in line and "--with-yarp" in line and "yarp-middleware" in line
    assert not bag.exists()
    # started alone (ros2 run): the same line, exit 2, not a traceback of the import
    node = node_process("yarp_skin_bridge", {}, env, tmp_path)
    deadline = time.monotonic() + 60
    while node.alive() and time.monotonic() < deadline:
        time.sleep(0.1)
    code = node.stop()
    err = [x for x in node.stderr().splitlines() if x.strip()]
    assert code == 2 and len(err) == 1 and "Traceback" not in err[0], (code, err)
    assert "yarp_skin_bridge needs YARP's Python bindings" in err[0] and "--break-system-packages" in err[0]


def record_temp_dirs(tmp) -> list:
    return sorted(tmp.glob("nao_skin_record_*"))


def test_record_removes_its_temporary_directory(tmp_path):
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = ros_env(unique_domain_id(), TMPDIR=tmp)
    bag = tmp_path / "touches"

    run = nao_skin(["record", "--print", "--bag", str(bag)], env=env)
    assert run.returncode == 0 and "pairing_recorder:" in run.stdout, run.stderr
    assert record_temp_dirs(tmp) == []

    run = nao_skin(["record", "--print", "--bag", str(bag), "--keep-temp"], env=env)
    assert run.returncode == 0, run.stderr
    (kept,) = record_temp_dirs(tmp)
    assert f"record: kept the temporary files in {kept}" in run.stderr
    kept.rmdir()

    # a session stopped by SIGTERM: the directory exists while it runs, and is gone after
    session = Proc(record_cmd(bag, 3, 1), env, tmp_path, "record")
    try:
        deadline = time.monotonic() + 60
        while "record: started" not in session.stderr() and session.alive() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert "record: started" in session.stderr(), session.stderr()[-2000:]
        assert len(record_temp_dirs(tmp)) == 1
    finally:
        code = session.stop(signal.SIGTERM, timeout=30)
    assert code == 0, session.stderr()[-3000:]
    assert record_temp_dirs(tmp) == []

    # a parameter a node would refuse at start ends the session with one line naming the node and exit 2, as
    # every other mistake, before any node starts (it was the node's own line among the others' logs): the
    # directory is removed too
    missing = tmp_path / "no_such_taxels.txt"
    run = nao_skin(["record", "--bag", str(tmp_path / "b2"), "--param", f"pairing_recorder.taxels=[l_hand={missing}]"],
                   env=env)
    assert run.returncode == 2 and "node pairing_recorder" in one_error_line(run), run.stderr
    assert f"{missing}: no such file" in run.stderr and not (tmp_path / "b2").exists()
    assert record_temp_dirs(tmp) == []


def test_the_calibrate_node_takes_the_warm_update_options_from_the_session_config():
    """record.yaml's warm_repairings reaches the engine: an operator can let each live update re-pair more."""
    session = yaml.safe_load(RECORD_YAML.read_text())["/**/calibrate"]["ros__parameters"]
    params = {name: value for name, (value, *_) in CALIBRATE.items()}
    assert options_from_params({**params, **session}).warm_repairings == session["warm_repairings"]
    assert options_from_params({**params, "warm_repairings": 3}).warm_repairings == 3
    # and how a press held still is weighed (a lab may compare its live figures without the pose weights)
    assert options_from_params({**params, **session}).pose_weight == session["pose_weight"] == 0.5
    assert options_from_params({**params, "pose_weight": 0.0}).pose_weight == 0.0


def test_a_node_that_has_ended_keeps_its_exit_code_whatever_stop_signal_follows(tmp_path):
    """The recorder ends with 2 (its disk is full) while record, stopped by the user a moment later, sends it
    SIGTERM: arriving during CPython's finalisation, which puts the default action back, the signal ended the
    process, and record counts a SIGTERM death as a clean stop (exit 0 after a full disk). The window cannot be
    hit on demand; what closes it can be checked: once the node is done, the stop signals are ignored (a state
    finalisation leaves alone) and a SIGTERM changes nothing."""
    script = (
        "import os, signal, time\n"
        "from nao_skin.errors import DataError\n"
        "from nao_skin.nodes.runtime import run_node\n"
        "def factory():\n"
        "    raise DataError('cannot write the bag (No space left on device)')\n"
        "code = run_node(factory, ['node'])\n"
        "print([signal.getsignal(s) is signal.SIG_IGN for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)])\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"
        "time.sleep(0.2)\n"
        "raise SystemExit(code)\n")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                         env=ros_env(unique_domain_id()))
    assert run.stdout.splitlines() == ["[True, True, True]"], run.stderr
    assert run.returncode == 2 and "error: cannot write the bag (No space left on device)" in run.stderr


def test_a_session_ended_before_the_recorder_made_its_bag_says_nothing_was_recorded(tmp_path):
    """A `record --duration` shorter than the nodes' start (or a Ctrl-C as it starts) ended with exit 0, no bag
    and no word of it; now one line says so. A session that ends with an empty bag leaves the recorder's own
    line ("wrote 0 touches") and the calibrate node's (no live update ran), not a failed update over nothing."""
    bag = tmp_path / "touches"
    env = ros_env(unique_domain_id())
    run = nao_skin(["record", "--duration", "0.3", "--bag", str(bag)], env=env)
    assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr
    assert f"record: nothing was recorded: the session ended before the recorder made its bag ({bag})" \
        in run.stderr, run.stderr
    assert not bag.exists()
    # the simulated robot waits for subscribers that never come: no touch is played
    run = nao_skin(["record", "--duration", "6", "--bag", str(bag), "--param", "sim_robot.wait_for_subscribers=50",
                    "--param", "sim_robot.wait_timeout=60"], env=env)
    assert run.returncode == 0 and "nothing was recorded" not in run.stderr, run.stderr
    assert f"wrote 0 touches to {bag}" in run.stderr and "no usable touch" not in run.stderr, run.stderr
    assert "the session ends without a live calibration (no live update ran)" in run.stderr, run.stderr
