"""Which nodes a record session runs, with which parameters: one description for both starters.

``launch/record.launch.py`` turns it into launch_ros ``Node`` actions and
``nao-skin record`` (machines without ``ros2 launch``) into processes, so both
start the same nodes with the same parameter files and overrides. No rclpy
import here: the launch file loads this module too.

Skin frames come from exactly one publisher: the ``calibrate`` node (current
calibration on /tf_static, replaced by each new calibration), while
robot_state_publisher gets the URDF with ``skin_frames:=false``.

Parameter overrides are checked against what each of our nodes declares
(:data:`nao_skin.session.params.NODE_PARAMS`) before anything starts: an
unknown node or parameter, or a value of the wrong type, is one ConfigError
line.
"""
from __future__ import annotations

import os
import re
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path

from nao_skin.errors import ConfigError, NaoSkinError
from nao_skin.formats.ros_params import names_the_node, parameters_for, read_params_file, sections_for
from nao_skin.model.skin import parse_pairs, parse_taxel_files
from nao_skin.model.urdf import expand_xacro
from nao_skin.paths import (config_dir, default_skin_config, parse_yaml, read_yaml,
                            yaml_value)
from nao_skin.rules import did_you_mean
from nao_skin.session.params import (CHECKS, NODE_PARAMS, PER_PART_NODES, ROS_NODE_PARAMS, params_file_said,
                                     per_part_params, skin_from_params)

ROBOTS = ("sim", "nao")
CONTROL = re.compile(r"[\x00-\x1f\x7f]")
SKIN_NODES = ("sim_robot", "yarp_skin_bridge", "pairing_recorder", "skin_heatmap", "calibrate", "fingertip_capture")   # read the skin
# set by `nao-skin record` and our launch files for their nodes: they stop when that process is gone
PARENT_ENV = "NAO_SKIN_PARENT_PID"
# what stops record, bench-live and a node as Ctrl-C does: a closed terminal (SIGHUP), a kill or timeout (SIGTERM)
YARP_HINT = ("yarp_skin_bridge needs YARP's Python bindings (pip package yarp-middleware, built from source): in"
             " the venv `make setup-test` or `docker/setup_venv.sh --with-yarp`, in a ROS workspace"
             " `pip install --break-system-packages yarp-middleware` or YARP built with its Python bindings")
# parameters a record session sets itself, with the argument that says it (launch spelling): given in a parameters
# file or by --param they would be overridden without a word
SESSION_SET = {("pairing_recorder", "bag_path"): "bag", ("calibrate", "recording"): "bag",
               ("pairing_recorder", "continues"): "continue_from", ("calibrate", "earlier_recordings"): "continue_from",
               ("skin_heatmap", "earlier_recordings"): "continue_from", ("pairing_recorder", "sim_seed"): "seed",
               ("pairing_recorder", "recorded_from"): "robot", ("fingertip_capture", "dry_run"): "capture"}
CAPTURE_MODES = ("false", "true", "dry")   # capture:=: no capture, the robot presses by itself, only plans
# parameters the scenes set (scene:=, --scene) when they are given: given as well, one would be overridden
SCENE_SET = {("sim_robot", "pairs"), ("pairing_recorder", "fingertip_scenes"), ("skin_heatmap", "fingertip_scenes"),
             ("calibrate", "guidance_pairs")}


def check_needs(specs) -> None:
    """Every Python module a node needs imports here (the nodes run on this interpreter): else one line saying
    what to install, before any node starts (``nao-skin record`` and the launch file)."""
    import importlib

    for spec in specs:
        for module, hint in spec.needs.items():
            try:
                importlib.import_module(module)
            except ImportError as exc:
                raise ConfigError(f"{hint} (import {module}: {' '.join(str(exc).split())})") from None


@dataclass
class NodeSpec:
    name: str                      # node name = key in the params files
    executable: str                # `ros2 run <package> <executable>`; ours: module nao_skin.nodes.<executable>
    params_files: list = field(default_factory=list)
    overrides: dict = field(default_factory=dict)
    package: str = "nao_skin"
    arguments: list = field(default_factory=list)
    optional: bool = False         # skipped by `nao-skin record` when the executable is not installed
    needs: dict = field(default_factory=dict)   # Python module the node imports -> what to install
    namespace: str = "/"           # the session's namespace: its topics and (as a prefix) its frames
    said: dict = field(default_factory=dict)    # how a message names a parameter file (the user's: params_file:=)

    @property
    def ours(self) -> bool:
        return self.package == "nao_skin"


def robot_description(calibration: str = "", skin_frames: bool = False) -> str:
    """The URDF for robot_state_publisher (:func:`~nao_skin.model.urdf.expand_xacro`): body only unless told."""
    return expand_xacro(calibration or None, skin_frames=skin_frames)


def record_session(robot: str = "sim", nao_ip: str = "", naoqi: bool = True, events_port: str = "",
                   bag_path: str = "", calibration: str = "", rviz: bool = False, taxels=(),
                   overrides: dict | None = None, with_robot_state_publisher: bool = True,
                   guided: bool = False, continue_from=(), namespace: str = "", spelling: str = "launch",
                   params_file: str = "", seed=None, scene=(), say=None, capture: str = "false") -> list:
    """The nodes of ``record.launch.py`` for these launch arguments.

    ``spelling``: how a message names the arguments, as the caller's user gave them: ``launch``
    (``nao_ip:=...``) or ``command`` (``nao-skin record --nao-ip ...``).

    ``taxels``: ``PART=FILE`` items, the robot's own layouts, given to every node that reads the skin.
    ``guided``: the simulated robot follows the guidance (robot sim only).
    ``continue_from``: bags of earlier sittings of this capture; the calibrate node calibrates their touches with
    the new recording's (live updates, guidance, the calibration written at the end).
    ``overrides``: ``{node name: {parameter: value}}`` applied last (tests, CLI ``--param``).
    ``namespace``: every node's namespace (``/nao2``): a second robot's session on the same ROS domain, its
    topics under the namespace and its TF frames prefixed with it (robot_state_publisher's ``frame_prefix``).
    ``params_file``: the user's ROS 2 parameters file, given to every node after the package's own files (so it
    overrides them) and before the session's own overrides; checked as they are, and a parameter of ours a
    section naming the node gives that the node does not have is one line too.
    ``capture``: ``true``: the fingertip_capture node presses the robot's fingertip on the torso through NAOqi
    (robot nao only) and the recorder takes its scene's fingertip touches; ``dry``: it only plans (markers in
    RViz), with either robot; ``false``: no capture.
    ``seed``: the simulated robot's seed (None or "": not given; a session continuing earlier sittings then picks
    one none of them played, so that it plays new touches). ``scene``: the scenes recorded, ``HAND-PART`` items
    (a comma list each, :func:`session_scenes`): the simulated robot plays them, the recorder takes the fingertip
    scenes' touches and the heat-map shows their fingertips. ``say``: where a line worth a look goes (stderr).
    """
    say = say or (lambda line: print(line, file=sys.stderr))
    namespace = _namespace(namespace, spelling)
    if robot not in ROBOTS:
        raise ConfigError(f"{_said('robot', repr(robot), spelling)}: expected one of {', '.join(ROBOTS)}")
    seed = None if seed is None or str(seed).strip() == "" else seed
    if seed is not None and robot != "sim":
        raise ConfigError(f"{_said('seed', seed, spelling)}: only the simulated robot ({_said('robot', 'sim', spelling)})"
                          f" plays a seed; {_said('robot', robot, spelling)} records the robot's own touches")
    if seed is not None:     # the node's own rule (_checked says where=value)
        seed = _checked(seed, *_declared(NodeSpec("sim_robot", "sim_robot"))["seed"],
                        "seed:" if spelling == "launch" else "--seed")
    user_file = _user_params_file(params_file, spelling)
    if robot == "sim":       # said, not ignored: an operator who gave the robot's address meant the robot
        for given, name in ((nao_ip, "nao_ip"), (events_port, "events_port"), (not naoqi, "naoqi")):
            if given:
                value = "false" if name == "naoqi" else given
                nao, sim = _said("robot", "nao", spelling), _said("robot", "sim", spelling)
                raise ConfigError(f"{_said(name, value, spelling)}: only {nao} reads it ({sim}, the default,"
                                  f" simulates the robot); give {nao} for the real one")
    capture = str(capture).strip().lower()
    if capture not in CAPTURE_MODES:
        raise ConfigError(f"{_said('capture', capture, spelling)}: expected one of {', '.join(CAPTURE_MODES)}")
    if capture == "true" and robot != "nao":
        raise ConfigError(f"{_said('capture', 'true', spelling)}: moves the robot's arm through NAOqi, with"
                          f" {_said('robot', 'nao', spelling)} only; {_said('capture', 'dry', spelling)} plans with"
                          f" either robot")
    if nao_ip and not naoqi and capture == "false":
        raise ConfigError(f"{_said('nao_ip', nao_ip, spelling)}: only naoqi_bridge reads it, and"
                          f" {_said('naoqi', 'false', spelling)} leaves it out (another driver publishes /joint_states)")
    for value, node, name in ((nao_ip, "naoqi_bridge", "nao_ip"), (events_port, "yarp_skin_bridge", "events_port")):
        if value:    # the node's own rule, before any node starts
            _, rule = _declared(NodeSpec(node, node))[name]
            try:
                rule.check(_said(name, value, spelling), value)
            except NaoSkinError as exc:
                raise ConfigError(str(exc)) from None
    scenes, tips = session_scenes(scene, spelling)
    cfg = config_dir()
    # one name for the recorder and the calibrate node (which calibrates on that bag on request)
    from nao_skin.formats.bag import SIMULATED, default_bag_name

    bag_path = str(Path(bag_path or default_bag_name()).expanduser().resolve())
    record_yaml, bridges_yaml = cfg / "record.yaml", cfg / "bridges.yaml"
    specs = []
    if guided and robot != "sim":
        raise ConfigError(f"{_said('guided', 'true', spelling)}: only the simulated robot"
                          f" ({_said('robot', 'sim', spelling)}) follows the guidance; on the real robot the"
                          f" operator does, from RViz or /nao_skin/guidance")
    if robot == "sim":
        specs.append(NodeSpec("sim_robot", "sim_robot", [record_yaml], {"guided": True} if guided else {}))
    else:
        if naoqi:
            specs.append(NodeSpec("naoqi_bridge", "naoqi_bridge", [bridges_yaml],
                                  {"nao_ip": nao_ip} if nao_ip else {}))
        specs.append(NodeSpec("yarp_skin_bridge", "yarp_skin_bridge", [bridges_yaml],
                              {"events_port": events_port} if events_port else {}, needs={"yarp": YARP_HINT}))
    source = SIMULATED if robot == "sim" else "the robot (naoqi_bridge or another joint state driver, yarp_skin_bridge)"
    earlier = _earlier_recordings(continue_from, robot, source)
    specs.append(NodeSpec("pairing_recorder", "pairing_recorder", [record_yaml],
                          {"bag_path": bag_path, "recorded_from": source,
                           **({"continues": earlier} if earlier else {})}))
    if capture != "false":
        specs.append(NodeSpec("fingertip_capture", "fingertip_capture", [bridges_yaml],
                              {"dry_run": capture == "dry", **({"nao_ip": nao_ip} if nao_ip else {})}))
    specs.append(NodeSpec("skin_heatmap", "skin_heatmap", [record_yaml],
                          {"earlier_recordings": earlier} if earlier else {}))
    # the calibration of the session is written beside its recording
    cal = {"recording": bag_path, "out_dir": f"{bag_path}_calibration"}
    if earlier:
        cal["earlier_recordings"] = earlier
    if calibration:
        cal["calibration"] = calibration
    specs.append(NodeSpec("calibrate", "calibrate", [record_yaml], cal))
    if with_robot_state_publisher:
        frames = {"frame_prefix": f"{namespace.strip('/')}/"} if namespace != "/" else {}
        specs.append(NodeSpec("robot_state_publisher", "robot_state_publisher",
                              overrides={"robot_description": ("__urdf__", calibration), **frames},
                              package="robot_state_publisher", optional=True))
    if rviz:
        specs.append(NodeSpec("rviz2", "rviz2", package="rviz2", optional=True,
                              arguments=["-d", str(cfg / "nao_skin.rviz")]))
    if scenes:
        _set_scenes({spec.name: spec for spec in specs}, scenes, tips, calibration)
    if taxels:       # checked here: a mistake is one line before anything starts; absolute for every node
        resolved = taxel_items(taxels, spelling)
        for spec in specs:
            if spec.name in SKIN_NODES:
                spec.overrides["taxels"] = resolved
    for spec in specs:
        spec.namespace = namespace
        if user_file is not None:
            spec.params_files.append(user_file[0])
            spec.said[str(user_file[0])] = user_file[1]
    by_name = {spec.name: spec for spec in specs}
    # the session's calibration goes beside its bag, unless the user's parameters file names another place
    out_dir = _file_given(by_name["calibrate"], user_file).get("out_dir")
    if out_dir is not None:
        by_name["calibrate"].overrides["out_dir"] = out_dir
    for node, values in (overrides or {}).items():
        # one bag for both: the calibrate node follows what the recorder writes, and the checks below (never
        # overwrite a bag) see the one --bag names
        bag_param = {"pairing_recorder": "bag_path", "calibrate": "recording"}.get(node)
        if bag_param in values:
            raise ConfigError(f"--param {node}.{bag_param}: the session's bag is set once, for the recorder and the"
                              f" calibrate node together: give --bag (launch: bag:=) instead")
        earlier_param = {"pairing_recorder": "continues", "calibrate": "earlier_recordings",
                         "skin_heatmap": "earlier_recordings"}.get(node)
        if earlier_param in values:       # one list for both, checked before any node starts
            raise ConfigError(f"--param {node}.{earlier_param}: give --continue-from BAG (launch: continue_from:=BAG)"
                              f" instead")
        for name in values:
            if (node, name) in SESSION_SET:
                raise ConfigError(f"--param {node}.{name}: {_set_by_session(node, name, 'command')}")
            if scenes and (node, name) in SCENE_SET:
                raise ConfigError(f"--param {node}.{name}: --scene sets it; give the scenes once, with --scene")
        if node not in by_name:
            raise ConfigError(f"--param {node}.{next(iter(values), '')}: no node '{node}' in this session"
                              f" (robot {robot}: {', '.join(by_name)})")
        spec = by_name[node]
        spec.overrides.update(typed_overrides(spec, values) if spec.ours else _as_yaml(values))
    if capture == "true":    # the recorder takes the touches of the scene the capture presses
        from nao_skin.session.params import FINGERTIP_CAPTURE

        scenes = by_name["fingertip_capture"].overrides.get("scenes", FINGERTIP_CAPTURE["scenes"][0])
        by_name["pairing_recorder"].overrides.setdefault("fingertip_scenes", list(scenes))
    # a node given a skin of its own (--param NODE.taxels=..., or in the user's parameters file): the session's
    # (--taxels) is checked with the files
    own_skin = {node for node, values in (overrides or {}).items() if {"skin_config", "taxels"} & set(values)}
    own_skin |= {spec.name for spec in specs if {"skin_config", "taxels"} & set(_file_given(spec, user_file))}

    def set_by_session(node: str, name: str) -> str | None:
        return _set_by_session(node, name, spelling) if (node, name) in SESSION_SET else None

    for spec in specs:
        _check_printable(spec)
        if spec.ours:
            _check_file_values(spec)
            _check_user_file(spec, user_file, set_by_session)
            _check_together(spec, spec.name in own_skin, spelling)
    _check_guided(by_name)
    if robot == "sim":
        _play_a_new_seed(by_name, earlier, seed, user_file, spelling, say)
    _check_files(bag_path, calibration, _start_values(by_name["calibrate"]), spelling)
    return specs


def session_scenes(items, spelling: str) -> tuple:
    """``(scenes, fingertip scenes)``: ``(hand or fingertip, part)`` of ``scene:=`` / ``--scene`` items, each a
    comma (or space) separated list of ``HAND-PART``, a self-touch pair of the skin config (``r_hand-torso``) or a
    fingertip scene of its ``fingertip_touch`` (``r_finger-torso``); anything else is one line naming the item.
    The skin config's scenes: a part's own taxel files (``--taxels``) change no scene."""
    words = [w for item in ([items] if isinstance(items, str) else items) for w in re.split(r"[,\s]+", str(item))]
    if not any(words):
        return (), ()
    where = "scene:=" if spelling == "launch" else "--scene"
    try:
        skin = load_skin_files({}, spelling)
        scenes = parse_pairs(words, skin.parts, where, tuple(skin.robot.fingertips))
    except NaoSkinError as exc:
        raise ConfigError(str(exc)) from None
    known = skin.self_touch.pairs() + skin.fingertip_touch.pairs()
    for hand, part in scenes:       # what neither the robot nor the simulated one presses
        if (hand, part) not in known:
            raise ConfigError(f"{where} '{hand}-{part}': not a scene of {skin.source} (self_touch:"
                              f" {', '.join(f'{h}-{b}' for h, b in skin.self_touch.pairs())}; fingertip_touch:"
                              f" {', '.join(f'{t}-{b}' for t, b in skin.fingertip_touch.pairs()) or 'none'})")
    return scenes, tuple((hand, part) for hand, part in scenes if hand in skin.robot.fingertips)


def _set_scenes(by_name: dict, scenes: tuple, tips: tuple, calibration: str) -> None:
    """The scenes' parameters: the simulated robot plays every scene and the guidance asks for them, the recorder
    and the heat-map take the fingertip scenes (a self-touch the recorder takes whichever pair fired), placing
    the fingertips by the session's calibration as the calibrate node places the skin."""
    said = [f"{hand}-{part}" for hand, part in scenes]
    by_name["calibrate"].overrides["guidance_pairs"] = said
    if "sim_robot" in by_name:
        by_name["sim_robot"].overrides["pairs"] = said
    if tips:
        for node in ("pairing_recorder", "skin_heatmap"):
            by_name[node].overrides["fingertip_scenes"] = [f"{tip}-{part}" for tip, part in tips]
            if calibration:
                by_name[node].overrides["calibration"] = calibration


def calibrate_on_inputs(inputs, out_dir: str, calibration: str = "", taxels=(), namespace: str = "",
                        params_file: str = "", spelling: str = "launch", fingertip=()) -> NodeSpec:
    """The calibrate node of ``calibrate.launch.py`` for these launch arguments: it calibrates ``inputs`` once at
    start (config/record.yaml's section without its live updates: no recorder runs), writes ``out_dir`` and
    publishes the result. ``taxels``, ``namespace`` and ``params_file`` as :func:`record_session` takes them,
    checked as it checks them, before the node starts; ``fingertip``: the fingertip that pressed the text inputs'
    touches, NAME or INPUT=NAME items (``nao-skin calibrate --fingertip``)."""
    namespace = _namespace(namespace, spelling)
    # record.yaml's calibrate section is a record session's: here no live updates (no recorder runs)
    spec = NodeSpec("calibrate", "calibrate", [config_dir() / "record.yaml"],
                    {"inputs": list(inputs) or [""], "calibrate_on_start": True, "live": False, "out_dir": out_dir},
                    namespace=namespace)
    if calibration:
        spec.overrides["calibration"] = calibration
    if taxels:
        spec.overrides["taxels"] = taxel_items(taxels, spelling)
    if fingertip:
        from nao_skin.formats.inputs import parse_fingertips

        try:    # the items as given: an INPUT=NAME names the input as the inputs do
            parse_fingertips(fingertip, list(inputs), said=lambda item: _said("fingertip", item, spelling))
        except NaoSkinError as exc:
            raise ConfigError(str(exc)) from None
        spec.overrides["fingertips"] = list(fingertip)
    user_file = _user_params_file(params_file, spelling)
    if user_file is not None:
        spec.params_files.append(user_file[0])
        spec.said[str(user_file[0])] = user_file[1]
    # what the launch file sets itself: from its arguments, or fixed (it calibrates once, no recorder runs)
    from_arguments = {"inputs", "out_dir", *(["calibration"] if calibration else []), *(["taxels"] if taxels else []),
                      *(["fingertips"] if fingertip else [])}

    def set_here(node: str, name: str) -> str | None:
        if name in from_arguments:
            argument = {"fingertips": "fingertip"}.get(name, name)      # the node's parameter, the launch's argument
            return f"calibrate.launch.py sets it from {_said(argument, '...', spelling)}: give it there"
        if name in ("calibrate_on_start", "live", "recording", "earlier_recordings"):
            return "calibrate.launch.py calibrates its inputs once at start, without a record session"
        return None

    _check_printable(spec)
    _check_file_values(spec)
    _check_user_file(spec, user_file, set_here)
    values = _start_values(spec)
    try:     # the skin the node reads, with the taxel files named where the user named them
        load_skin_files(values, spelling)
    except NaoSkinError as exc:
        raise ConfigError(str(exc)) from None
    _check_together(spec, True, spelling)
    return spec


def taxel_items(taxels, spelling: str) -> list:
    """``PART=FILE`` items of ``--taxels`` / ``taxels:=`` as a node's ``taxels`` parameter: each checked with the
    skin config (one line naming it), the files absolute (every node reads them from its own directory)."""
    items = [f"{part}={path.resolve()}" for part, path in parse_taxel_files(taxels, _taxels_said(spelling)).items()]
    try:
        load_skin_files({"taxels": items}, spelling)
    except NaoSkinError as exc:
        raise ConfigError(str(exc)) from None
    return items


def _taxels_said(spelling: str) -> str:
    return "taxels:=" if spelling == "launch" else "--taxels"


def load_skin_files(values: dict, spelling: str):
    """The skin of a node's ``skin_config`` and ``taxels`` values, a mistake in the files named as its user gave
    them (``taxels:=``, ``--taxels``)."""
    from nao_skin.model.skin import load_skin

    where = _taxels_said(spelling)
    return load_skin(values.get("skin_config") or None, parse_taxel_files(values.get("taxels") or [], where),
                     where=where)


def _set_by_session(node: str, name: str, spelling: str) -> str:
    """Why a parameter the session sets itself is refused where the user gave it, and what to give instead."""
    arg = SESSION_SET[(node, name)]
    value = {"bag": "DIR", "continue_from": "BAG", "seed": "N", "robot": "sim|nao"}[arg]
    why = {"bag": "the session's bag is set once, for the recorder and the calibrate node together",
           "continue_from": "the session's earlier sittings are named once, for every node that reads them",
           "seed": "the session keeps the simulated robot's seed in the bag",
           "robot": "the session says what it records from"}[arg]
    return f"{why}: give {_said(arg, value, spelling)} instead"


def _user_params_file(path: str, spelling: str) -> tuple | None:
    """``(absolute path, how a message names it)`` of the user's parameters file (``params_file:=`` /
    ``--params-file``), read as rcl reads it: one line naming it when it cannot be read or rcl would refuse it
    (every node would fail to start on it), None when none is given."""
    if not str(path).strip():
        return None
    said = _said("params_file", path, spelling)
    try:
        read_params_file(Path(path).expanduser())
    except NaoSkinError as exc:
        text = str(exc)
        for name in (str(Path(path).expanduser()), str(path)):
            text = text.removeprefix(f"{name}: ")
        raise ConfigError(f"{said}: {text}") from None
    return Path(path).expanduser().resolve(), said


def _file_given(spec: NodeSpec, user_file: tuple | None) -> dict:
    """What the user's parameters file gives the node, as rcl applies it."""
    if user_file is None:
        return {}
    return parameters_for(read_params_file(user_file[0]), spec.name, spec.namespace)


def _check_user_file(spec: NodeSpec, user_file: tuple | None, set_here) -> None:
    """What the user's parameters file gives one of our nodes, beyond the checks of every file's values: a
    parameter the starter sets itself (``set_here(node, name)``: why, and what to give instead; None: not one),
    which would be overridden without a word, and, in a section naming the node (not ``/**``: that one gives
    every node the same set), a parameter the node does not have, which ROS ignores without a word."""
    if user_file is None:
        return
    path, said = user_file
    known = _declared(spec)
    for section, given in sections_for(read_params_file(path), spec.name, spec.namespace):
        for name in given:
            why = set_here(spec.name, name)
            if why:
                raise ConfigError(f"{said}: {spec.name}.{name}: {why}")
            if names_the_node(section) and name not in known and name not in ROS_NODE_PARAMS:
                raise ConfigError(f"{said}: {spec.name}.{name} (section {section}): node '{spec.name}' has no"
                                  f" parameter '{name}'{did_you_mean(name, known)}; its parameters:"
                                  f" {', '.join(known)}")


def _play_a_new_seed(by_name: dict, earlier: list, seed, user_file: tuple | None, spelling: str, say) -> None:
    """The seed the simulated robot plays, kept in the bag's metadata (the recorder's ``sim_seed``). The same
    seed plays the same touches: a session continuing earlier sittings replayed their touches, every one an
    exact duplicate left out, so it plays the first seed from the package's that none of them played, unless
    the user gave one (``seed``, ``--param sim_robot.seed``, the parameters file): then a seed played before is
    said in one line."""
    from nao_skin.formats.bag import SIMULATED, recorded_from, simulator_seed
    from nao_skin.formats.inputs import is_text_input

    robot = by_name["sim_robot"]
    package = _start_values(NodeSpec("sim_robot", "sim_robot", [p for p in robot.params_files
                                                                if str(p) not in robot.said],
                                      namespace=robot.namespace))["seed"]
    played: dict = {}              # seed -> the earlier sitting that played it
    for path in earlier:
        if is_text_input(path):
            continue
        was = simulator_seed(Path(path))
        if was is None and recorded_from(Path(path)) == SIMULATED:
            was = package          # recorded before the seed was kept: the package's, as every session played then
        if was is not None:
            played.setdefault(was, path)
    given = None                   # (seed, as the user gave it)
    if seed is not None:
        given = (seed, _said("seed", seed, spelling))
    elif "seed" in robot.overrides:
        given = (robot.overrides["seed"], f"--param sim_robot.seed={robot.overrides['seed']}")
    elif "seed" in _file_given(robot, user_file):
        given = (_start_values(robot)["seed"], f"{user_file[1]}: sim_robot.seed")
    if given is not None:
        chosen = given[0]
        if chosen in played:
            say(f"{given[1]}: the earlier sitting {played[chosen]} played this seed too: the simulated robot plays"
                f" its touches again, each an exact duplicate left out; give another seed, or none (a continued"
                f" session picks one no sitting played)")
    else:
        chosen = package
        while chosen in played:
            chosen += 1
    robot.overrides["seed"] = chosen
    by_name["pairing_recorder"].overrides["sim_seed"] = chosen


_NAMESPACE_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _namespace(text: str, spelling: str) -> str:
    """The session's namespace as ROS writes it (``/nao2``; ``/`` for none), or one line saying what rmw would
    refuse in it (each part a letter or ``_`` then letters, digits or ``_``)."""
    parts = [p for p in text.strip().split("/") if p] if text.strip() not in ("", "/") else []
    bad = [p for p in parts if not _NAMESPACE_TOKEN.fullmatch(p)]
    if bad or (text.strip() and "//" in text.strip()):
        raise ConfigError(f"{_said('namespace', text, spelling)}: expected a ROS namespace such as /nao2 (each part"
                          f" a letter or '_', then letters, digits or '_')")
    namespace = "/" + "/".join(parts)
    if len(namespace) > NAMESPACE_MAX:    # else every node fails to start, on a name under it
        raise ConfigError(f"{_said('namespace', text, spelling)}: {len(namespace)} characters; ROS names under it"
                          f" (e.g. {namespace[:12]}...{_LONGEST_NAME_UNDER}) would exceed {_NAME_MAX}: at most"
                          f" {NAMESPACE_MAX}")
    return namespace


# rmw's longest topic or service name (255 less the DDS prefix), and the longest a session's node makes under its
# namespace (robot_state_publisher's parameter service): the longest namespace a session can have
_NAME_MAX = 255 - 8
_LONGEST_NAME_UNDER = "/robot_state_publisher/set_parameters_atomically"
NAMESPACE_MAX = _NAME_MAX - len(_LONGEST_NAME_UNDER)


def launch_namespace(text: str) -> str:
    """A launch file's ``namespace:=`` as ROS writes it (``/`` for none), or one line saying what is wrong with it."""
    return _namespace(text, "launch")


def launch_words(name: str, text: str) -> list:
    """A launch file's list argument, split as a shell splits (quotes for a path with a space); one line naming
    the argument where a quote is not closed."""
    import shlex

    try:
        return shlex.split(text)
    except ValueError as exc:
        raise ConfigError(f"{name}:={text}: {str(exc).lower()} (quote a path with a space: \"'my file' other\")")\
            from None


def launch_flag(name: str, text: str) -> bool:
    """A launch file's true/false argument, as launch's own conditions read one (``true``/``1``, ``false``/``0``,
    any case); one line for anything else: ``guided:=maybe`` (or a typo of ``false``) is not quietly false."""
    value = text.strip().lower()
    if value not in ("true", "1", "false", "0"):
        raise ConfigError(f"{name}:={text}: expected true or false")
    return value in ("true", "1")


def _said(name: str, value: str, spelling: str) -> str:
    """A session argument as its user gave it: ``name:=value`` to ros2 launch, the option to nao-skin record."""
    if spelling == "launch":
        return f"{name}:={value}"
    flag = {"naoqi": "--no-naoqi", "guided": "--guided"}.get(name)     # options without a value
    return flag or f"--{name.replace('_', '-')} {value}"


def _earlier_recordings(paths, robot: str, source: str) -> list:
    """The recordings of earlier sittings a session continues, as absolute paths: those named and, before each, the
    sittings it continued in turn (its metadata's ``nao_skin.continues``, those still there: continuing the last
    sitting continues the capture). Each checked before any node starts: a recording nao-skin reads, none named
    twice, none still being recorded, none recorded from the other robot (a calibration of both would mix the
    simulated robot's touches with the real one's); what they hold is checked with the skin
    (:func:`_check_files`)."""
    from nao_skin.formats.bag import SIMULATED, continued_bags, recorded_from
    from nao_skin.formats.inputs import check_inputs, find_bag, is_text_input, recording_of
    from nao_skin.formats.salvage import recording_lock

    paths = [str(Path(p).expanduser()) for p in paths if str(p).strip()]
    if not paths:
        return []
    try:
        check_inputs(paths)     # before resolving: a loop of links is one line here
        paths = [str(Path(p).resolve()) for p in paths]
    except NaoSkinError as exc:
        raise ConfigError(f"continue from {exc}") from None
    ordered: list = []
    seen: set = set()

    def with_earlier(path: str) -> None:
        recording = recording_of(Path(path))
        if recording in seen:
            return
        seen.add(recording)
        if not is_text_input(path):
            for earlier in continued_bags(find_bag(Path(path))):
                try:
                    check_inputs([earlier])
                except NaoSkinError:    # moved away, or no recording now: the calibrate node says so as it starts
                    continue
                with_earlier(earlier)
        # the recording itself (a bag in a simulator's output folder: a new bag put beside it would be a second)
        ordered.append(path if is_text_input(path) else str(find_bag(Path(path))))

    for path in paths:
        with_earlier(path)
    for path in ordered:
        if is_text_input(path):                        # the thesis' text format: no recorder, no lock
            continue
        bag = find_bag(Path(path))
        lock = recording_lock(bag if bag.is_dir() else bag.parent)
        if lock is not None and lock.state == "open":
            raise ConfigError(f"continue from {path}: is being recorded now (by process {lock.pid}); continue it"
                              f" once that session has ended")
        was = recorded_from(bag)
        if was and (was == SIMULATED) != (source == SIMULATED):
            raise ConfigError(f"continue from {path}: was recorded from {was}; this session records {source}:"
                              f" one calibration of both would mix the simulated robot's touches with the real one's")
    return ordered


def _check_printable(spec: NodeSpec) -> None:
    """A text parameter with a control character (a newline, a tab) is refused: on the ``-p`` line ROS reads it
    as YAML, which folds a newline into a space, so the recorder would write another bag than the one named."""
    for name, value in spec.overrides.items():
        for text in value if isinstance(value, list) else [value]:
            if isinstance(text, str) and CONTROL.search(text):
                what = "bag" if (spec.name, name) == ("pairing_recorder", "bag_path") else f"{spec.name}.{name}"
                raise ConfigError(f"{what} {text!r}: holds a control character (a newline, a tab), which a ROS"
                                  f" parameter does not carry as it is; use printable characters")


def _check_together(spec: NodeSpec, own_skin: bool = False, spelling: str = "command") -> None:
    """The node's own check of its parameters taken together (:data:`~nao_skin.session.params.CHECKS`) on the
    values it will start with: declared defaults, then its parameter files, then the overrides; and, with
    ``own_skin``, the skin it reads (``--param NODE.taxels=...``, a parameters file's)."""
    check = CHECKS.get(spec.executable)
    reads_own_skin = own_skin and spec.name in SKIN_NODES
    if check is None and not reads_own_skin:
        return
    values = _start_values(spec)
    files = ", ".join(spec.said.get(str(f), str(f)) for f in spec.params_files) or "its defaults"
    where = f"node {spec.name} (parameters from {files}{' and --param' if spelling == 'command' else ''})"
    if reads_own_skin:
        try:
            skin_from_params(values)
        except NaoSkinError as exc:
            raise ConfigError(f"{where}: {exc}") from None
    if check is not None:
        check(values, where)


def _start_values(spec: NodeSpec) -> dict:
    """The parameters a node of ours starts with: declared defaults, then its parameter files, then the overrides."""
    values = node_parameters(spec)
    for _, given in _file_sections(spec):
        values.update(given)
    values.update(spec.overrides)
    return values


def _file_sections(spec: NodeSpec) -> list:
    """``[(path, {name: value})]``: what each of the node's parameter files gives it, as rcl reads the file."""
    return [(path, parameters_for(read_params_file(path), spec.name, spec.namespace))
            for path in spec.params_files]


def _check_file_values(spec: NodeSpec) -> None:
    """Each parameter the node declares, as its parameter files give it, of the node's type and within its
    rule: the node would refuse it only once started, beside the others, after the bag was made. Values an
    override replaces, and names the node does not declare (it warns of those), are not checked."""
    known = _declared(spec)
    for path, given in _file_sections(spec):
        for name, value in given.items():
            if name not in known or name in spec.overrides:
                continue
            _checked(value, *known[name], f"{spec.said.get(str(path), path)}: {spec.name}.{name}")


def _check_guided(by_name: dict) -> None:
    """A simulated robot that follows the guidance needs a calibrate node that publishes it (live updates with
    guidance): else every touch of a "guided" session is random, and nothing said so."""
    robot, calibrate = by_name.get("sim_robot"), by_name.get("calibrate")
    if robot is None or calibrate is None or not _start_values(robot).get("guided"):
        return
    values = _start_values(calibrate)
    off = [f"calibrate.{name}=false" for name in ("live", "guidance") if not values.get(name)]
    if off:
        raise ConfigError(f"sim_robot.guided=true follows the guidance, which the calibrate node publishes only with"
                          f" live updates and guidance on ({' and '.join(off)} here); drop --guided or the"
                          f" {' and '.join(o.split('=')[0] for o in off)} setting")


def _param_said(node: str, name: str, value: str, spelling: str) -> str:
    """How the user sets one node's parameter in a session: ``--param`` of nao-skin record, a parameters file of
    the launch (its section for the node)."""
    return f"--param {node}.{name}={value}" if spelling == "command" else params_file_said(node, name, value)


def _check_files(bag_path: str, calibration: str, calibrate_params: dict, spelling: str = "command") -> None:
    """What the nodes read and write first, checked before any starts: one line here instead of a node dying
    after the others are up (a bag is never overwritten; a calibration must fit the skin the nodes read)."""
    from nao_skin.formats.bag import enclosing_bag
    from nao_skin.formats.inputs import read_sitting
    from nao_skin.formats.outdir import check_writable
    from nao_skin.model.urdf import check_calibration_origins

    bag = Path(bag_path)
    if bag.exists() or bag.is_symlink():
        raise ConfigError(f"bag {bag}: exists already; a bag is never overwritten, name a new one")
    outer = enclosing_bag(bag)
    if outer is not None:
        raise ConfigError(f"bag {bag}: lies inside the bag {outer}; a bag is never written into another, choose a"
                          f" place outside it")
    check_writable(bag, f"bag {bag}")
    # the session's calibration is written there at its end, replacing what the session itself wrote:
    # anything there before (an earlier `nao-skin calibrate --out` of that name) would be lost
    if "out_dir" in calibrate_params and not str(calibrate_params["out_dir"]).strip():
        raise ConfigError(f"{_param_said('calibrate', 'out_dir', repr(''), spelling)}: the session's calibration needs"
                          f" a directory (default: <bag>_calibration)")
    earlier = [path for path in calibrate_params.get("earlier_recordings") or [] if path]
    out = Path(calibrate_params["out_dir"]).expanduser() if calibrate_params.get("out_dir") else None
    if out is not None:
        # the node refuses an out_dir that is, lies in or holds what it reads: said here, before the bag is made
        o = Path(os.path.abspath(out))
        for read in (bag, *earlier):
            b = Path(os.path.abspath(read))
            relation = "is" if o == b else "lies inside" if b in o.parents else "holds" if o in b.parents else None
            if relation:
                raise ConfigError(f"calibration output {out}: {relation} the bag {read}; the calibration is written"
                                  f" beside the recordings, not in them: choose another"
                                  f" ({_param_said('calibrate', 'out_dir', 'NEW_DIR', spelling)})")
        if out.exists() or out.is_symlink():
            raise ConfigError(f"calibration output {out}: exists already; the session writes its calibration there"
                              f" and replaces nothing it did not write: name another bag, or"
                              f" {_param_said('calibrate', 'out_dir', 'NEW_DIR', spelling)}")
        check_writable(out, f"calibration output {out}")
    skin = load_skin_files(calibrate_params, spelling)
    for path in earlier:
        try:     # read as the calibrate node will at its start: one that holds no touch or fits another skin
            read_sitting(path, skin)
        except NaoSkinError as exc:
            raise ConfigError(f"continue from {exc}") from None
    calibration = calibrate_params.get("calibration") or calibration
    if calibration:    # its corrections go to the nodes, its origins to robot_state_publisher's URDF: they must agree
        check_calibration_origins(calibration, skin)


def node_parameters(spec: NodeSpec) -> dict:
    """``{name: default}`` of every parameter one of our nodes declares
    (:data:`~nao_skin.session.params.NODE_PARAMS`, and those per skin part)."""
    return {name: default for name, (default, _) in _declared(spec).items()}


def _declared(spec: NodeSpec) -> dict:
    """``{name: (default, rule or None)}`` of every parameter one of our nodes declares."""
    params = {name: (default, rule[0] if rule else None) for name, (default, _, *rule)
              in NODE_PARAMS[spec.executable].items()}
    if spec.executable in PER_PART_NODES:
        skin_config = spec.overrides.get("skin_config") or str(default_skin_config())
        doc = read_yaml(skin_config, "skin config")
        parts = doc.get("parts") if isinstance(doc, dict) else None
        if not isinstance(parts, dict):
            raise ConfigError(f"{skin_config}: a skin config needs a 'parts' mapping")
        params.update({name: (default, rule[0] if rule else None) for name, (default, _, *rule)
                       in per_part_params(spec.executable, parts).items()})
    return params


def typed_overrides(spec: NodeSpec, values: dict) -> dict:
    """``values`` (text as typed after ``--param``, or Python values) as the types the node declares.

    An integer is taken for a float parameter (``gate_mm=20``); anything else
    of the wrong type, or a name the node does not declare, is a ConfigError.
    """
    known = _declared(NodeSpec(spec.name, spec.executable, overrides={**spec.overrides, **values}))
    out = {}
    for name, value in values.items():
        where = f"--param {spec.name}.{name}"
        if name not in known:
            raise ConfigError(f"{where}: node '{spec.name}' has no parameter '{name}'{did_you_mean(name, known)};"
                              f" its parameters: {', '.join(known)}")
        out[name] = _checked(value, *known[name], where)
    return out


def _checked(value, default, rule, where: str):
    """``value`` as the type of ``default``, within the node's ``rule``: the node's own check, made before
    any node starts (ConfigError naming ``where``)."""
    typed = _typed(value, default, where)
    if rule is not None:
        try:
            rule.check(f"{where}={_text(value)}", typed)
        except NaoSkinError as exc:
            raise ConfigError(str(exc)) from None
    return typed


def _typed(value, default, where: str):
    """``value`` as the type of ``default``; a str is parsed as YAML unless the parameter is a string."""
    import yaml

    shown = _text(value)     # as given: the text typed after --param, not what YAML made of it
    if isinstance(value, str) and isinstance(default, float) and not isinstance(default, bool):
        try:            # '1e3' as rcl reads it (YAML 1.1 wants '1.0e+3')
            return float(value)
        except ValueError:
            pass
    if isinstance(value, str) and not isinstance(default, (str, list)) and not value.strip():
        # as an empty value of an option is: no number or switch, and not a way to ask for the default
        raise ConfigError(f"{where}={shown}: an empty value; give {_KIND[type(default)]}, or leave it out for the"
                          f" node's default {param_text(default)}")
    if isinstance(value, str) and not isinstance(default, str):
        try:
            value = parse_yaml(value) if value else [""]     # a list: no item, as rcl's '[]' (which has no type)
        except yaml.YAMLError:
            raise ConfigError(f"{where}={shown}: not a valid value (YAML flow syntax, e.g. [a, b])") from None
    if isinstance(default, list):
        items = value if isinstance(value, list) else [value]
        kind = type(default[0]) if default else str
        typed = [_scalar(v, kind) for v in items]
        if any(v is None for v in typed):
            raise ConfigError(f"{where}={shown}: expected a list like {param_text(default)}")
        return typed
    typed = _scalar(value, type(default))
    if typed is None:
        raise ConfigError(f"{where}={shown}: expected {_KIND[type(default)]} like {param_text(default)}")
    return typed


_KIND = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


def _scalar(value, kind):
    """``value`` as ``kind`` (bool, int, float, str), an int also as float; None when it is not one."""
    if kind is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    return value if type(value) is kind else None


def _as_yaml(values: dict) -> dict:
    """Overrides of a node we know no parameters of: text as YAML, as ``ros2 run -p`` would take it."""
    return {name: yaml_value(value) if isinstance(value, str) and value else value for name, value in values.items()}


def _text(value) -> str:
    return value if isinstance(value, str) else param_text(value)


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
    if spec.namespace != "/":
        argv += ["-r", f"__ns:={spec.namespace}"]
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
        path.write_text(yaml.safe_dump({"/**": {"ros__parameters": extra}}))      # the file is this node's alone
        argv += ["--params-file", str(path)]
    return argv
