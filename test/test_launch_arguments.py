"""Launch arguments with bad values end the launch in one line naming the argument, before any node starts:
the launch files' own functions are called here as launch calls them (no node, no workspace)."""
from __future__ import annotations

import importlib.util

import pytest
from real_launch import require_launch
from ros_harness import ROOT

require_launch()
from launch import LaunchContext  # noqa: E402

from nao_skin.errors import ConfigError  # noqa: E402
from nao_skin.session.record import NAMESPACE_MAX, launch_flag, launch_namespace, record_session  # noqa: E402


def launch_file(name: str):
    spec = importlib.util.spec_from_file_location(name.replace(".", "_"), ROOT / "launch" / name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def context_with(defaults: dict, **arguments) -> LaunchContext:
    context = LaunchContext()
    context.launch_configurations.update({**defaults, **arguments})
    return context


@pytest.mark.parametrize("argument,value", [("guided", "maybe"), ("rviz", "yes please"), ("naoqi", "ture"),
                                            ("taxels", "l_hand='my file"), ("continue_from", '"a.bag'),
                                            ("capture", "maybe"), ("capture", "true")])
def test_record_launch_refuses_a_bad_argument_in_one_line(argument, value):
    module = launch_file("record.launch.py")
    defaults = {name: default for name, (default, _) in module.ARGUMENTS.items()}
    with pytest.raises(ConfigError) as refused:
        module._nodes(context_with(defaults, **{argument: value}))
    assert f"{argument}:={value}" in str(refused.value) and "\n" not in str(refused.value)


@pytest.mark.parametrize("argument,value", [("namespace", "é"), ("namespace", "a//b"), ("inputs", "'a.bag")])
def test_calibrate_launch_refuses_a_bad_argument_in_one_line(argument, value):
    module = launch_file("calibrate.launch.py")
    defaults = {name: "a.bag" if default is None else default for name, (default, _) in module.ARGUMENTS.items()}
    with pytest.raises(ConfigError) as refused:
        module._node(context_with(defaults, **{argument: value}))
    assert f"{argument}:={value}" in str(refused.value) and "\n" not in str(refused.value)


def test_capture_starts_the_capture_node_and_the_recorder_takes_its_touches(tmp_path):
    """capture:=true with robot:=nao: fingertip_capture at the robot's address, the recorder told its scene;
    capture:=dry plans with the simulated robot too and moves nothing (dry_run), the recorder as without it."""
    bag = str(tmp_path / "touches")
    specs = {s.name: s for s in record_session("nao", nao_ip="10.0.0.7", bag_path=bag, capture="true",
                                               with_robot_state_publisher=False)}
    assert specs["fingertip_capture"].overrides == {"dry_run": False, "nao_ip": "10.0.0.7"}
    assert specs["naoqi_bridge"].overrides["nao_ip"] == "10.0.0.7"
    assert specs["pairing_recorder"].overrides["fingertip_scenes"] == ["r_finger-torso", "l_finger-torso"]
    specs = {s.name: s for s in record_session("sim", bag_path=bag, capture="dry", with_robot_state_publisher=False)}
    assert specs["fingertip_capture"].overrides == {"dry_run": True}
    assert "fingertip_scenes" not in specs["pairing_recorder"].overrides
    assert "fingertip_capture" not in {s.name for s in record_session("sim", bag_path=bag)}


def test_a_launch_flag_reads_as_launch_conditions_read_it():
    assert [launch_flag("rviz", v) for v in ("true", "True", "1", "false", "FALSE", "0")] == [True] * 3 + [False] * 3


def test_a_namespace_too_long_for_the_names_under_it_is_refused_before_any_node_starts():
    """Every node would fail on a service name under it, each with a traceback, after the bag was made."""
    from rclpy.validate_full_topic_name import validate_full_topic_name
    from rclpy.validate_namespace import validate_namespace

    longest = "/" + "n" * (NAMESPACE_MAX - 1)
    assert launch_namespace(longest) == longest
    validate_namespace(longest)
    for node in ("robot_state_publisher", "yarp_skin_bridge", "pairing_recorder"):
        validate_full_topic_name(f"{longest}/{node}/set_parameters_atomically", is_service=True)
    with pytest.raises(ConfigError, match=r"^--namespace /n+: \d+ characters"):
        record_session("sim", namespace=longest + "n", spelling="command")


def _defaults(module) -> dict:
    return {name: "a.bag" if default is None else default for name, (default, _) in module.ARGUMENTS.items()}


@pytest.mark.parametrize("text, says", [
    # a parameter of ours the section naming the node gives, which the node does not have
    ("calibrate:\n  ros__parameters:\n    gate_m: 20\n",
     "{file}: calibrate.gate_m (section calibrate): node 'calibrate' has no parameter 'gate_m' (did you mean"
     " 'gate_mm'?)"),
    ("/**/sim_robot:\n  ros__parameters:\n    touch_period: fast\n",
     "{file}: sim_robot.touch_period=fast: expected a number like 1.0"),
    ("pairing_recorder:\n  ros__parameters:\n    bag_path: /tmp/x\n",
     "{file}: pairing_recorder.bag_path: the session's bag is set once, for the recorder and the calibrate node"
     " together: give bag:=DIR instead"),
    ("calibrate: [1, 2]\n", "{file}: 'calibrate' is a value where a node name maps to its ros__parameters"),
])
def test_record_launch_checks_its_parameters_file_before_any_node_starts(tmp_path, text, says):
    """params_file:= of record.launch.py, checked as the package's own files are (and, where a section names one
    of our nodes, a parameter it does not have): one line naming the argument."""
    module = launch_file("record.launch.py")
    path = tmp_path / "mine.yaml"
    path.write_text(text)
    context = context_with(_defaults(module), bag=str(tmp_path / "b"), params_file=str(path))
    with pytest.raises(ConfigError) as refused:
        module._nodes(context)
    said = str(refused.value)
    assert said.startswith(says.format(file=f"params_file:={path}").split(" (did")[0]) and "\n" not in said, said
    if "did you mean" in says:
        assert "did you mean 'gate_mm'?" in said


def test_a_parameters_file_rcl_takes_is_never_refused_for_what_it_gives_other_nodes(tmp_path):
    """A /** section gives every node the same set (use_sim_time, a parameter of one node only), and a section
    of another namespace (a second robot's session) is not this session's: rcl takes both without a word; so
    does a file that gives no parameter. (What the launch file calls, without claiming the ROS domain.)"""
    path = tmp_path / "shared.yaml"
    path.write_text("/**:\n  ros__parameters:\n    use_sim_time: false\n    gate_mm: 20\n"
                    "/nao2/calibrate:\n  ros__parameters:\n    no_such_parameter: 1\n"
                    "calibrate:\n  ros__parameters:\n    use_sim_time: false\n")
    specs = record_session("sim", bag_path=str(tmp_path / "b"), params_file=str(path))
    assert all(path in spec.params_files for spec in specs)
    (tmp_path / "empty.yaml").write_text("")
    assert record_session("sim", bag_path=str(tmp_path / "b"), params_file=str(tmp_path / "empty.yaml"))


@pytest.mark.parametrize("arguments, says", [
    ({"robot": "nao", "seed": "3"}, "seed:=3: only the simulated robot (robot:=sim) plays a seed"),
    ({"seed": "-1"}, "seed:=-1: expected a whole number >= 0"),
    ({"seed": "two"}, "seed:=two: expected an integer like 1"),
])
def test_record_launch_refuses_a_seed_it_cannot_play(tmp_path, arguments, says):
    module = launch_file("record.launch.py")
    with pytest.raises(ConfigError) as refused:
        module._nodes(context_with(_defaults(module), bag=str(tmp_path / "b"), **arguments))
    assert str(refused.value).startswith(says) and "\n" not in str(refused.value), str(refused.value)


@pytest.mark.parametrize("argument, value, says", [
    ("taxels", "foot={layout}", "taxels:= foot={layout}: unknown skin part 'foot'"),
    ("taxels", "l_hand={missing}", "taxels:= 'l_hand={missing}': {missing}: no such file"),
    ("params_file", "{missing}", "params_file:={missing}: cannot read ROS parameters file"),
    ("params_file", "{mine}", "params_file:={mine}: calibrate.out_dir: calibrate.launch.py sets it from out_dir:="),
])
def test_calibrate_launch_checks_its_taxels_and_parameters_file_in_one_line(tmp_path, argument, value, says):
    from nao_skin.paths import config_dir

    module = launch_file("calibrate.launch.py")
    mine = tmp_path / "mine.yaml"
    mine.write_text("calibrate:\n  ros__parameters:\n    out_dir: elsewhere\n")
    names = {"layout": config_dir() / "layouts" / "l_hand.txt", "missing": tmp_path / "none", "mine": mine}
    with pytest.raises(ConfigError) as refused:
        module._node(context_with(_defaults(module), **{argument: value.format(**names)}))
    assert str(refused.value).startswith(says.format(**names)) and "\n" not in str(refused.value), str(refused.value)
