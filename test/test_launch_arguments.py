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
                                            ("taxels", "l_hand='my file"), ("continue_from", '"a.bag')])
def test_record_launch_refuses_a_bad_argument_in_one_line(argument, value):
    module = launch_file("record.launch.py")
    defaults = {name: default for name, (default, _) in module.ARGUMENTS.items()}
    with pytest.raises(ConfigError) as refused:
        module._nodes(context_with(defaults, **{argument: value}))
    assert f"{argument}:={value}" in str(refused.value) and "\n" not in str(refused.value)


@pytest.mark.parametrize("argument,value", [("namespace", "é"), ("namespace", "a//b"), ("inputs", "'a.bag")])
def test_calibrate_launch_refuses_a_bad_argument_in_one_line(argument, value):
    module = launch_file("calibrate.launch.py")
    defaults = {"inputs": "a.bag", "out_dir": "out", "calibration": "", "namespace": ""}
    with pytest.raises(ConfigError) as refused:
        module._node(context_with(defaults, **{argument: value}))
    assert f"{argument}:={value}" in str(refused.value) and "\n" not in str(refused.value)


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
