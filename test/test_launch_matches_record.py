"""``ros2 launch nao_skin record.launch.py`` and ``nao-skin record`` start the same nodes with the same parameters.

ROS 2's ``launch`` and ``launch_ros`` are not on PyPI, so they cannot run here:
minimal stand-ins of the four classes the launch file uses record what it
asks for (package, executable, node name, parameter files, overrides,
arguments), and that is compared with the command lines ``nao-skin record
--print`` builds. The launch file itself is the real one.
"""
import importlib.util
import shlex
import sys
import types

import pytest
import yaml
from ros_harness import ROOT  # noqa: E402

from nao_skin.formats.bag import write_touch_bag
from nao_skin.model.skin import load_skin
from nao_skin.session.record import command_line, record_session, robot_description
from nao_skin.sim.simulate import simulate


class _LaunchConfiguration:
    def __init__(self, name):
        self.name = name

    def perform(self, context):
        return context.arguments[self.name]


class _DeclareLaunchArgument:
    def __init__(self, name, default_value="", description=""):
        self.name, self.default_value, self.description = name, default_value, description


class _OpaqueFunction:
    def __init__(self, function):
        self.function = function


class _LaunchContext:
    def __init__(self, arguments):
        self.arguments, self.globals = arguments, {}

    def extend_globals(self, extensions):
        self.globals.update(extensions)


class _Node:
    def __init__(self, **kwargs):
        self.kwargs = kwargs


class _ParameterValue:
    def __init__(self, value, value_type=None):
        self.value = value


@pytest.fixture()
def launch_file(monkeypatch, tmp_path):
    """launch/record.launch.py loaded with the stand-ins in place of launch and launch_ros (its claim of the ROS
    domain in the test's directory: the test process holds it while it runs)."""
    monkeypatch.setattr("nao_skin.session.claim.LOCK_DIR", tmp_path)
    modules = {
        "launch": {"LaunchDescription": list},
        "launch.actions": {"DeclareLaunchArgument": _DeclareLaunchArgument, "OpaqueFunction": _OpaqueFunction},
        "launch.substitutions": {"LaunchConfiguration": _LaunchConfiguration},
        "launch_ros": {},
        "launch_ros.actions": {"Node": _Node},
        "launch_ros.parameter_descriptions": {"ParameterValue": _ParameterValue},
    }
    for name, attrs in modules.items():
        module = types.ModuleType(name)
        module.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location("record_launch", ROOT / "launch" / "record.launch.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def launched(launch_file, **arguments) -> dict:
    """{node name: (package, executable, params files, overrides, arguments)} of the launch file."""
    entities = launch_file.generate_launch_description()
    declared = {e.name: e.default_value for e in entities if isinstance(e, _DeclareLaunchArgument)}
    unknown = set(arguments) - set(declared)
    assert not unknown, unknown
    context = _LaunchContext({**declared, **arguments})
    out = {}
    for entity in entities:
        if isinstance(entity, _OpaqueFunction):
            for node in entity.function(context):
                k = node.kwargs
                files = [p for p in k["parameters"] if isinstance(p, str)]
                overrides = {}
                for d in (p for p in k["parameters"] if isinstance(p, dict)):
                    overrides.update({key: v.value if isinstance(v, _ParameterValue) else v for key, v in d.items()})
                out[k["name"]] = (k["package"], k["executable"], files, overrides, list(k["arguments"]))
    return out


def recorded(tmp_path, **session) -> dict:
    """The same description from the command lines ``nao-skin record`` runs (optional ones included)."""
    out = {}
    for spec in record_session(**session):
        argv = command_line(spec, tmp_path) if spec.ours else \
            [spec.executable] + list(spec.arguments) + _ros_args(spec, tmp_path)
        cut = argv.index("--ros-args")
        ros = argv[cut + 1:]
        files, overrides = [], {}
        for flag, value in zip(ros[::2], ros[1::2]):
            if flag == "--params-file":
                doc = yaml.safe_load(open(value)) if value.startswith(str(tmp_path)) else None
                if doc is None:
                    files.append(value)
                else:
                    overrides.update(doc[spec.name]["ros__parameters"])
            elif flag == "-p":
                key, _, text = value.partition(":=")
                overrides[key] = yaml.safe_load(text)
            else:
                assert (flag, value) == ("-r", f"__node:={spec.name}"), (flag, value)
        head = argv[:cut]
        executable = head[2].rsplit(".", 1)[1] if spec.ours else spec.executable
        arguments = head[3:] if spec.ours else head[1:]
        out[spec.name] = (spec.package, executable, files, overrides, arguments)
    return out


def _ros_args(spec, tmp_path):
    """An external executable's ``--ros-args`` as command_line writes them, without needing it installed."""
    argv = command_line(spec.__class__(spec.name, "nao_skin_external_stand_in", spec.params_files,
                                       spec.overrides, "nao_skin", list(spec.arguments)), tmp_path)
    return argv[argv.index("--ros-args"):]


@pytest.mark.parametrize("arguments", [
    {},
    {"guided": "true"},
    {"continue_from": "EARLIER_SITTINGS"},
    {"robot": "nao", "nao_ip": "127.0.0.1", "events_port": "/skinManager/skin_events:o", "rviz": "true"},
    {"robot": "nao", "naoqi": "false", "calibration": str(ROOT / "config" / "calibration_nominal.yaml"),
     "taxels": f"l_hand={ROOT / 'config' / 'layouts' / 'l_hand.txt'} torso={ROOT / 'config' / 'layouts' / 'torso.txt'}"},
])
def test_the_launch_file_starts_what_nao_skin_record_starts(tmp_path, launch_file, arguments):
    bag = str(tmp_path / "session_bag")
    if arguments.get("continue_from"):       # two earlier sittings' bags, one named with a space
        earlier = [tmp_path / "sitting 1", tmp_path / "sitting2"]
        skin = load_skin()
        for seed, path in enumerate(earlier):
            write_touch_bag(path, simulate(skin, {"n_touches": 12}, seed=seed).touches, skin)
        arguments = {**arguments, "continue_from": " ".join(shlex.quote(str(p)) for p in earlier)}
    via_launch = launched(launch_file, bag=bag, **arguments)
    session = dict(robot=arguments.get("robot", "sim"), nao_ip=arguments.get("nao_ip", ""),
                   naoqi=arguments.get("naoqi", "true") == "true", events_port=arguments.get("events_port", ""),
                   bag_path=bag, calibration=arguments.get("calibration", ""),
                   rviz=arguments.get("rviz", "false") == "true", taxels=arguments.get("taxels", "").split(),
                   guided=arguments.get("guided", "false") == "true",
                   continue_from=shlex.split(arguments.get("continue_from", "")))
    via_record = recorded(tmp_path, **session)
    assert set(via_launch) == set(via_record)
    for name in via_launch:
        assert via_launch[name] == via_record[name], name
    # what both pass to robot_state_publisher is the body without skin frames (one publisher per frame)
    if arguments.get("taxels"):      # the robot's own layouts reach every node that reads the skin
        assert {n for n, v in via_launch.items() if "taxels" in v[3]} == \
            {"yarp_skin_bridge", "pairing_recorder", "skin_heatmap", "calibrate"}
    if arguments.get("guided"):
        assert via_launch["sim_robot"][3]["guided"] is True
    if arguments.get("continue_from"):
        for node, param in (("calibrate", "earlier_recordings"), ("skin_heatmap", "earlier_recordings"),
                            ("pairing_recorder", "continues")):
            assert via_launch[node][3][param] == [str(p) for p in earlier], node
    urdf = via_launch["robot_state_publisher"][3]["robot_description"]
    assert urdf == robot_description(session["calibration"], skin_frames=False) and "skin_mount" not in urdf


def test_the_comparison_sees_a_difference(tmp_path, launch_file, monkeypatch):
    """A launch file that drops an override is caught (the test above can fail)."""
    bag = str(tmp_path / "session_bag")
    original = launch_file._nodes

    def dropping(context):
        nodes = original(context)
        for node in nodes:
            for p in node.kwargs["parameters"]:
                if isinstance(p, dict):
                    p.pop("bag_path", None)
        return nodes

    monkeypatch.setattr(launch_file, "_nodes", dropping)
    assert launched(launch_file, bag=bag) != recorded(tmp_path, bag_path=bag)


def test_the_launch_file_claims_the_domain_while_it_runs_and_is_refused_one_another_session_holds(
        tmp_path, launch_file, monkeypatch):
    """Two sessions on one ROS_DOMAIN_ID record each other's touches: the launch file claims the domain before
    any node starts, as `nao-skin record` does (test_domain_claim.py), is refused while another session holds
    it, and holds it as long as its launch context lives."""
    from test_domain_claim import Holder

    from nao_skin.errors import ConfigError
    from nao_skin.session.claim import claim_domain

    monkeypatch.setenv("ROS_DOMAIN_ID", "57")
    holder = Holder(57, tmp_path)
    try:
        with pytest.raises(ConfigError, match=f"another nao-skin session \\(pid {holder.pid}\\) runs on ROS_DOMAIN_ID"):
            launched(launch_file, bag=str(tmp_path / "b"))
    finally:
        holder.end()
    declared = {e.name: e.default_value for e in launch_file.generate_launch_description()
                if isinstance(e, _DeclareLaunchArgument)}
    context = _LaunchContext({**declared, "bag": str(tmp_path / "b")})
    launch_file._nodes(context)                        # its session ended: the domain is free again
    with pytest.raises(ConfigError, match="another nao-skin session"):
        claim_domain(57, tmp_path)                    # held while the launch context lives
    del context
    claim_domain(57, tmp_path).release()


def test_record_print_shows_these_command_lines(tmp_path):
    import subprocess

    bag = tmp_path / "b"
    run = subprocess.run([sys.executable, "-m", "nao_skin.cli", "record", "--print", "--bag", str(bag)],
                         capture_output=True, text=True, timeout=60, cwd=str(tmp_path))
    assert run.returncode == 0, run.stderr
    printed = {line.split(": ", 1)[0]: shlex.split(line.split(": ", 1)[1]) for line in run.stdout.splitlines()
               if ": " in line}
    assert {"sim_robot", "pairing_recorder", "skin_heatmap", "calibrate"} <= set(printed)
    assert f"bag_path:={bag}" in printed["pairing_recorder"]
