"""The record session's description: parameter files match the nodes, one publisher per frame.

``launch/record.launch.py`` and ``nao-skin record`` both start what
:func:`nao_skin.session.record.record_session` lists; here its parameter files
are checked against the parameters each node declares (no typo goes
unnoticed, every parameter is commented), and the URDF given to
robot_state_publisher is checked to share no frame with the calibrate node
while still being the parent of every skin mount.
"""
from __future__ import annotations

import array
import re
import xml.etree.ElementTree as ET

import pytest
import yaml
from ros_harness import ROOT

from nao_skin.model.skin import load_skin, skin_frame_transforms
from nao_skin.session.params import NODE_PARAMS, per_part_params
from nao_skin.session.record import command_line, record_session, robot_description

pytest.importorskip("rclpy")

def declared(node: str, parts) -> dict:
    """``{name: default}`` of what the node declares, per-part families (``part_ids.l_hand``) included."""
    return {name: default for name, (default, *_) in {**NODE_PARAMS[node], **per_part_params(node, parts)}.items()}


def flatten(d: dict, prefix: str = "") -> set:
    out = set()
    for k, v in d.items():
        if isinstance(v, dict):
            out |= flatten(v, f"{prefix}{k}.")
        else:
            out.add(prefix + k)
    return out


# where a session deliberately starts a node off its own default (``ros2 run`` alone gets the default)
SESSION_CHOICES = {
    ("record.yaml", "sim_robot", "wait_for_subscribers"): 2,   # recorder and heat-map listen before it plays
    ("record.yaml", "calibrate", "live"): True,                 # a record session calibrates as touches come in
}


@pytest.mark.parametrize("config", ["record.yaml", "bridges.yaml"])
def test_params_files_match_the_nodes(config):
    parts = list(load_skin().parts)
    path = ROOT / "config" / config
    doc = yaml.safe_load(path.read_text())
    for key, body in doc.items():
        node = key.removeprefix("/**/")      # a section for the node in any namespace
        assert key == f"/**/{node}", f"{config}: {key} (a section that reaches the node in a namespace too)"
        given = flatten(body["ros__parameters"])
        defaults = declared(node, parts)
        assert given == set(defaults), f"{config}: {node}"
        # a value the file repeats is the node's own default: a copy that drifted (skin_tolerance 0.03 against
        # the node's 0.015) started every record session off what the node documents; the skinManager part
        # ids (part_ids.<part>) too
        for name in given:
            value = body["ros__parameters"]
            for key in name.split("."):
                value = value[key]
            want = SESSION_CHOICES.get((config, node, name), defaults[name])
            assert value == want, f"{config}: {node}.{name}: {value!r}, the node's default is {defaults[name]!r}"
    # every parameter line carries a comment saying what it is
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        m = re.match(r"^\s{4,}(\w+):\s*(\S.*)$", line)
        if m and m.group(1) != "ros__parameters" and not line.lstrip().startswith("#"):
            assert "#" in line or line.rstrip().endswith(",") or m.group(2).startswith("["), \
                f"{config}:{lineno}: parameter without a comment"


@pytest.mark.parametrize("kwargs, launch, command", [
    ({"nao_ip": "10.0.0.9"}, "nao_ip:=10.0.0.9: only robot:=nao reads it (robot:=sim, the default",
     "--nao-ip 10.0.0.9: only --robot nao reads it (--robot sim, the default"),
    ({"robot": "nao", "guided": True}, "guided:=true: only the simulated robot (robot:=sim)",
     "--guided: only the simulated robot (--robot sim)"),
    ({"robot": "nao", "nao_ip": "not an ip!"}, "nao_ip:=not an ip!: expected an IPv4 address",
     "--nao-ip not an ip!: expected an IPv4 address"),
])
def test_a_session_names_its_arguments_as_its_starter_takes_them(kwargs, launch, command):
    """One description for ros2 launch and nao-skin record: each user reads the arguments as they typed them."""
    from nao_skin.errors import ConfigError

    for spelling, expected in (("launch", launch), ("command", command)):
        with pytest.raises(ConfigError) as caught:
            record_session(**kwargs, spelling=spelling)
        assert str(caught.value).startswith(expected), (spelling, str(caught.value))


def test_session_nodes_and_shared_bag(tmp_path):
    sim = {s.name: s for s in record_session("sim", bag_path=str(tmp_path / "b"))}
    assert set(sim) == {"sim_robot", "pairing_recorder", "skin_heatmap", "calibrate", "robot_state_publisher"}
    assert sim["pairing_recorder"].overrides["bag_path"] == sim["calibrate"].overrides["recording"]
    nao = {s.name for s in record_session("nao", nao_ip="10.0.0.2", rviz=True)}
    assert {"naoqi_bridge", "yarp_skin_bridge", "rviz2"} <= nao and "sim_robot" not in nao
    assert "naoqi_bridge" not in {s.name for s in record_session("nao", naoqi=False)}
    spec = record_session("sim", overrides={"sim_robot": {"seed": 3}})[0]
    argv = command_line(spec, tmp_path)
    assert argv[1:3] == ["-m", "nao_skin.nodes.sim_robot"] and "seed:=3" in argv
    assert str(ROOT / "config" / "record.yaml") in argv


def test_urdf_for_the_session_leaves_skin_frames_to_the_calibrate_node():
    skin = load_skin()
    links = {link.get("name") for link in ET.fromstring(robot_description()).iter("link")}
    tf = skin_frame_transforms(skin, skin.zero_calibration())
    children = [child for _, child, _ in tf]
    assert len(children) == len(set(children))
    assert not links & set(children), "a skin frame would have two publishers"
    assert {parent for parent, _, _ in tf} <= links | set(children), "skin frames not attached to the body"
    full = {link.get("name") for link in ET.fromstring(robot_description(skin_frames=True)).iter("link")}
    assert set(children) <= full                   # same frames as the URDF with skin frames


def test_launch_files_compile():
    for name in ("record.launch.py", "calibrate.launch.py"):
        compile((ROOT / "launch" / name).read_text(), name, "exec")


def test_every_default_keeps_its_own_rule_and_a_later_change_is_held_to_it():
    """A node's rule is checked at declaration and on ``ros2 param set`` (a real rclpy node, no DDS traffic)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from nao_skin.nodes.runtime import declare

    for node, params in NODE_PARAMS.items():      # a default outside its own rule would stop every session
        for name, (default, _, *rule) in params.items():
            if rule:
                rule[0].check(f"{node}.{name}", default)
    context = Context()
    rclpy.init(context=context, domain_id=0)
    try:
        node = Node("rule_check", context=context, start_parameter_services=False)
        values = declare(node, {"rate": NODE_PARAMS["skin_heatmap"]["rate"]})
        assert values == {"rate": 10.0}
        (refused,) = node.set_parameters([Parameter("rate", Parameter.Type.DOUBLE, 0.0)])
        assert not refused.successful and refused.reason == "parameter rate:=0.0: expected a number in [1e-05, 1000]"
        # a valid value is refused too: the node reads its parameters when it starts, and taking it
        # without effect would tell the user it did
        (valid,) = node.set_parameters([Parameter("rate", Parameter.Type.DOUBLE, 2.5)])
        assert not valid.successful and node.get_parameter("rate").value == 10.0
        assert valid.reason.startswith("'rate' is read when the node starts: restart the node with it (ros2 run:"
                                       " -p rate:=")
        # a double array arrives as array.array: judged by its values
        declare(node, {"legend_origin": NODE_PARAMS["skin_heatmap"]["legend_origin"]})
        for values, rule_ok in (([1.0, 2.0, 3.0], True), ([1.0, 2.0], False)):
            (result,) = node.set_parameters([Parameter("legend_origin", Parameter.Type.DOUBLE_ARRAY,
                                                       array.array("d", values))])
            assert not result.successful and ("read when the node starts" in result.reason) == rule_ok, result.reason
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
