"""Which nodes a record session runs, with which parameters: one description for both starters.

``launch/record.launch.py`` turns it into launch_ros ``Node`` actions and
``nao-skin record`` (machines without ``ros2 launch``) into processes, so both
start the same nodes with the same parameter files and overrides. No rclpy
import here: the launch file loads this module too.

Skin frames come from exactly one publisher: the ``calibrate`` node (current
calibration on /tf_static, replaced by each new calibration), while
robot_state_publisher gets the URDF with ``skin_frames:=false``.
"""
from __future__ import annotations

import shutil
import sys
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from ..config import config_dir
from ..errors import ConfigError

ROBOTS = ("sim", "nao")


@dataclass
class NodeSpec:
    name: str                      # node name = key in the params files
    executable: str                # `ros2 run <package> <executable>`; ours: module nao_skin.nodes.<executable>
    params_files: list = field(default_factory=list)
    overrides: dict = field(default_factory=dict)
    package: str = "nao_skin"
    arguments: list = field(default_factory=list)
    optional: bool = False         # skipped by `nao-skin record` when the executable is not installed

    @property
    def ours(self) -> bool:
        return self.package == "nao_skin"


def urdf_dir() -> Path:
    share = config_dir().parent / "urdf"
    return share


def robot_description(calibration: str = "", skin_frames: bool = False) -> str:
    """The URDF (xacro expanded in-process); body only unless ``skin_frames``."""
    import xacro

    args = {"skin_frames": "true" if skin_frames else "false"}
    if calibration:
        args["calibration"] = str(Path(calibration).resolve())
    doc = xacro.process_file(str(urdf_dir() / "nao_skin.urdf.xacro"), mappings=args)
    return doc.toprettyxml(indent="  ")


def record_session(robot: str = "sim", nao_ip: str = "", naoqi: bool = True, events_port: str = "",
                   bag_path: str = "", calibration: str = "", rviz: bool = False,
                   overrides: dict | None = None, with_robot_state_publisher: bool = True) -> list:
    """The nodes of ``record.launch.py`` for these launch arguments.

    ``overrides``: ``{node name: {parameter: value}}`` applied last (tests, CLI ``--param``).
    """
    if robot not in ROBOTS:
        raise ConfigError(f"robot:={robot!r}: expected one of {', '.join(ROBOTS)}")
    cfg = config_dir()
    # one name for the recorder and the calibrate node (which calibrates on that bag on request)
    bag_path = str(Path(bag_path or f"nao_skin_touches_{datetime.now():%Y%m%d_%H%M%S}").expanduser().resolve())
    record_yaml, bridges_yaml = cfg / "record.yaml", cfg / "bridges.yaml"
    specs = []
    if robot == "sim":
        specs.append(NodeSpec("sim_robot", "sim_robot", [record_yaml]))
    else:
        if naoqi:
            specs.append(NodeSpec("naoqi_bridge", "naoqi_bridge", [bridges_yaml],
                                  {"nao_ip": nao_ip} if nao_ip else {}))
        specs.append(NodeSpec("yarp_skin_bridge", "yarp_skin_bridge", [bridges_yaml],
                              {"events_port": events_port} if events_port else {}))
    specs.append(NodeSpec("pairing_recorder", "pairing_recorder", [record_yaml], {"bag_path": bag_path}))
    specs.append(NodeSpec("skin_heatmap", "skin_heatmap", [record_yaml]))
    cal = {"recording": bag_path}
    if calibration:
        cal["calibration"] = calibration
    specs.append(NodeSpec("calibrate", "calibrate", [record_yaml], cal))
    if with_robot_state_publisher:
        specs.append(NodeSpec("robot_state_publisher", "robot_state_publisher",
                              overrides={"robot_description": ("__urdf__", calibration)},
                              package="robot_state_publisher", optional=True))
    if rviz:
        specs.append(NodeSpec("rviz2", "rviz2", package="rviz2", optional=True,
                              arguments=["-d", str(cfg / "nao_skin.rviz")]))
    for spec in specs:
        spec.overrides.update((overrides or {}).get(spec.name, {}))
    return specs


def param_text(value) -> str:
    """A value as ``-p name:=value`` text (YAML flow syntax)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(param_text(v) for v in value) + "]"
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    return repr(value)


def command_line(spec: NodeSpec, work_dir: Path) -> list | None:
    """argv of one node for ``nao-skin record``; None when an optional external executable is missing."""
    if spec.ours:
        argv = [sys.executable, "-m", f"nao_skin.nodes.{spec.executable}"]
    else:
        exe = shutil.which(spec.executable)
        if exe is None:
            prefix = shutil.which("ros2")
            if prefix is None:
                return None
            argv = ["ros2", "run", spec.package, spec.executable]
        else:
            argv = [exe]
    argv += list(spec.arguments) + ["--ros-args", "-r", f"__node:={spec.name}"]
    for f in spec.params_files:
        argv += ["--params-file", str(f)]
    extra = {}
    for k, v in spec.overrides.items():
        if isinstance(v, tuple) and v and v[0] == "__urdf__":
            extra[k] = robot_description(v[1], skin_frames=False)
        else:
            argv += ["-p", f"{k}:={param_text(v)}"]
    if extra:        # a URDF is too long for the command line: a params file
        import yaml

        path = Path(work_dir) / f"{spec.name}.params.yaml"
        path.write_text(yaml.safe_dump({spec.name: {"ros__parameters": extra}}))
        argv += ["--params-file", str(path)]
    return argv
