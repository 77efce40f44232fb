"""The parameters each of our nodes declares, and the checks no single parameter's rule can make.

``{name: (default, description[, rule])}`` per node executable (:data:`NODE_PARAMS`):
the nodes declare them (:func:`nao_skin.nodes.runtime.declare`), and ``nao-skin
record`` and the launch file check a session's parameter files and overrides
against them before any node starts (:mod:`nao_skin.session.record`). No ROS
import here: ``nao-skin record --print`` runs where rclpy is not installed.
Defaults that belong to the engine, the live updates or the event detector are
theirs (``CalibrationOptions``, ``UpdateSchedule``, ``PartStates``, ``WarmStart``,
``LiveUpdates``, ``LIVE_CONFIG``), read from there.
"""
from __future__ import annotations

from nao_skin.calibration.options import OPTION_FIELDS, CalibrationOptions
from nao_skin.capture.plan import CaptureOptions
from nao_skin.errors import ConfigError, NaoSkinError
from nao_skin.guidance.capture import MAX_READ_TARGETS
from nao_skin.live.playback import check_timing
from nao_skin.live.updates import LiveUpdates, PartStates, UpdateSchedule, WarmStart
from nao_skin.model.skin import SkinModel, load_skin, parse_pairs, parse_taxel_files
from nao_skin.rules import (AT_LEAST_ONE, HOST, JOINT_NAMES, NON_NEGATIVE, PORT, POSITIVE, RATE, SECONDS,
                            SECONDS_OR_ZERO, WHOLE, YARP_PORT, YARP_PORT_OR_NONE, Rule)
from nao_skin.sim.params import check_pairs, default_params_file, load_params, pair_list
from nao_skin.touch import DEFAULT_FINGERTIP_GATE
from nao_skin.touch.events import LIVE_CONFIG

MAX_FLOAT = 1.7976931348623157e308    # a float range's open side (sys.float_info.max)

# every node that reads the skin builds it the way the commands do (model.skin.load_skin)
SKIN_PARAMS = {
    "skin_config": ("", "skin config YAML (empty: the package's config/nao_skin.yaml)"),
    "taxels": ([""], "skinManager taxel files replacing a part's layout, PART=FILE each (e.g. the robot's own);"
                     " empty entries are ignored"),
}

# the calibration options a calibrate node parameter sets, by the option's own name
NODE_OPTIONS = ("strategy", "reference", "pairs", "closing_pairs", "press_model", "bounded", "loss", "jacobian",
                "initial_guess", "gate_mm", "pose_weight", "prior_scale", "estimate_fabric", "fabric_thickness",
                "test_fraction", "seed", "warm_pairs", "warm_repairings")

DEFAULT_JOINTS = ["HeadYaw", "HeadPitch",
                  "LShoulderPitch", "LShoulderRoll", "LElbowYaw", "LElbowRoll", "LWristYaw",
                  "RShoulderPitch", "RShoulderRoll", "RElbowYaw", "RElbowRoll", "RWristYaw"]

# iCub skinDynLib SkinPart ids; the Nao build put the head on the unused right forearm id (thesis §3.1.1).
DEFAULT_PART_IDS = {"l_hand": 1, "r_hand": 4, "torso": 7, "head": 5}


CALIBRATE = {
    **SKIN_PARAMS,
    "calibration": ("", "calibration published at start and used as prior (empty: nominal skin)"),
    "inputs": ([""], "bags (or legacy .txt) to calibrate from; empty entries are ignored"),
    "fingertips": ([""], "the fingertip that pressed the legacy .txt inputs' touches (the format does not say; a bag"
                         " does): NAME for every such input, or INPUT=NAME each (e.g. r_finger); empty entries are"
                         " ignored"),
    "recording": ("", "the recorder's bag: calibrated on an empty request when 'inputs' is empty"),
    "earlier_recordings": ([""], "bags of earlier sittings this record session continues: its live updates, guidance"
                                 " and empty requests calibrate their touches with the recording's"),
    "calibrate_on_start": (False, "run on 'inputs' right after start (ros2 run ... calibrate)"),
    "out_dir": ("nao_skin_calibration", "output directory (replaced when a run succeeds)"),
    "plots": (False, "write the report's plots too (slower)"),
    "live": (False, "recalibrate in the background while the recorder stores touches (on in a record session)"),
    # the live defaults are the live module's (UpdateSchedule, PartStates, WarmStart, LiveUpdates): defined once
    "live_every_touches": (UpdateSchedule.every_touches, "live: an update after this many new touches ...",
                           AT_LEAST_ONE),
    "live_period": (UpdateSchedule.period, "live: ... or this many seconds after the last one, if any touch came"
                                           " since", SECONDS),
    "live_done_median_mm": (PartStates.median_mm, "live: a part is done when its predicted taxel error's median"
                                                  " (mm) ...", POSITIVE),
    "live_done_p95_mm": (PartStates.p95_mm, "live: ... and p95 (mm), each times live_done_margin, are at most"
                                            " these (done until the prediction itself exceeds one)", POSITIVE),
    "live_done_margin": (PartStates.margin, "live: ... (how far the prediction may fall short of the true error,"
                                            " measured)",
                         Rule(float, low=1.0, high=10.0)),
    "guidance": (True, "live: after each update, publish where touches would help most on /nao_skin/guidance"),
    "guidance_targets": (5, "live: how many targets the guidance names (its readers take the first 100)",
                         Rule(int, low=1, high=MAX_READ_TARGETS)),
    "guidance_pairs": ([""], "live: the pairs the guidance may ask for, as 'hand-part' (e.g. l_hand-torso), or"
                             " fingertip scenes (r_finger-torso: the taxels no touch reached); empty: the skin"
                             " config's self_touch pairs"),
    "live_refresh": (WarmStart.refresh, "live: an update from scratch (the whole plan) beside the warm one whenever"
                                        " the touches grew this many times since the last such; the one the held-out"
                                        " touches pair closer is published (1: every update from scratch)",
                     Rule(float, low=1.0)),
    "live_scratch_below": (WarmStart.scratch_below, "live: below this many touches every update is from scratch (the"
                                                    " whole plan, as nao-skin calibrate on the same touches)", WHOLE),
    "live_max_move_mm": (LiveUpdates.MAX_MOVE_MM, "live: an update moving a calibrated part's taxels farther than this (mm) diverged:"
                               " not published", POSITIVE),
    # engine options (their defaults, help and rules come from CalibrationOptions' table, OPTION_FIELDS)
    **{name: (OPTION_FIELDS[name].default, OPTION_FIELDS[name].metadata["help"], OPTION_FIELDS[name].metadata["rule"])
       for name in NODE_OPTIONS},
}


NAOQI_BRIDGE = {
    "nao_ip": ("127.0.0.1", "IP address or host name of the robot running NAOqi", HOST),
    "nao_port": (9559, "NAOqi port", PORT),
    "rate": (50.0, "joint angle reads per second (Hz)", RATE),
    "joint_names": (DEFAULT_JOINTS, "NAOqi joint names to read and publish", JOINT_NAMES),
    "use_sensors": (True, "getAngles' useSensors: sensed (true) or commanded (false) angles"),
    "reconnect_min": (0.5, "first reconnection delay after the robot vanished (s)", SECONDS),
    "reconnect_max": (5.0, "longest reconnection delay (s)", SECONDS),
    "read_timeout": (2.0, "s a getAngles call may take before the robot counts as gone (then: reconnect)", SECONDS),
}


PAIRING_RECORDER = {
    **SKIN_PARAMS,
    "bag_path": ("", "touch bag to create (a new directory; empty: ./nao_skin_touches_<date>_<time>)"),
    "recorded_from": ("", "what the touches come from, kept in the bag's metadata (a record session sets it; a bag"
                          " of the simulated robot is said as such on every read)"),
    "continues": ([""], "the earlier sittings' bags the session continues, kept in the bag's metadata (a record"
                        " session sets it: nao-skin calibrate says when one of them is not among its inputs)"),
    "sim_seed": (-1, "the seed the simulated robot plays, kept in the bag's metadata (a record session with the"
                     " simulated robot sets it: a session continuing the bag plays another); -1: none",
                 Rule(int, low=-1)),
    "storage": ("mcap", "bag storage: mcap (survives kill -9 up to the last flush) or sqlite3",
                Rule(str, ("mcap", "sqlite3"))),
    "flush_period": (1.0, "seconds between flushes of the bag to disk", SECONDS),
    "progress_period": (1.0, "seconds between progress messages", SECONDS),
    "skin_tolerance": (LIVE_CONFIG.skin_tolerance, "s: skin samples of different parts this close are one moment",
                       NON_NEGATIVE),
    "joint_tolerance": (LIVE_CONFIG.joint_tolerance, "s: bracketing joint states must be this close to the touch",
                        NON_NEGATIVE),
    "min_interval": (LIVE_CONFIG.min_interval, "s: during one continuous press, at most one touch per interval",
                     NON_NEGATIVE),
    "release_gap": (LIVE_CONFIG.release_gap, "s: a part silent this long counts as released", NON_NEGATIVE),
    "fingertip_scenes": ([""], "fingertip scenes recorded, 'fingertip-part' (e.g. r_finger-torso): a part firing alone"
                               " while that fingertip is where it fired; empty: self-touches only"),
    "calibration": ("", "calibration that places the skin and the fingertips for fingertip_scenes (empty: nominal)"),
    "fingertip_gate_mm": (DEFAULT_FINGERTIP_GATE * 1000.0, "mm: a fingertip within this of the fired taxels' centre pressed them"
                                                 " (fingertip_scenes)", POSITIVE),
}


SIM_ROBOT = {
    **SKIN_PARAMS,
    "preset": ("default", "simulation preset of config/simulation.yaml"),
    "seed": (1, "simulator seed: the same seed plays the same touches", WHOLE),
    "touches_per_pair": (20, "accepted touches per self-touch pair", AT_LEAST_ONE),
    "pairs": ([""], "pairs to play as 'hand-part' (e.g. l_hand-torso); empty: the preset's pairs"),
    "joint_rate": (100.0, "joint state rate (Hz)", RATE),
    "skin_rate": (50.0, "skin message rate per part (Hz), like skinManager's period", RATE),
    "touch_period": (1.0, "seconds between the starts of two presses", SECONDS),
    "press_duration": (0.3, "seconds each press lasts", SECONDS),
    "hold": (0.1, "seconds the arm holds still before and after a press", SECONDS_OR_ZERO),
    "loop": (False, "start again after the last touch"),
    "wait_for_subscribers": (0, "start only when each skin taxels topic has this many subscribers (0: at once)",
                             WHOLE),
    "wait_timeout": (20.0, "longest wait for subscribers (s), then play anyway", SECONDS_OR_ZERO),
    "guided": (False, "follow /nao_skin/guidance: the next touches aim at its top targets"),
    "guided_start": (20, "guided: random touches before the first batch aimed at the guidance",
                     AT_LEAST_ONE),
    "guided_batch": (5, "guided: touches per batch aimed at the guidance's top targets", AT_LEAST_ONE),
}


_CAPTURE = CaptureOptions()     # the capture's defaults are its options': defined once


def _fraction(high: float) -> Rule:
    """A speed fraction of NAOqi's interpolation, in (0, ``high``]: a capture never asks for more."""
    return Rule(float, low=0.0, low_open=True, high=high)


FINGERTIP_CAPTURE = {
    **SKIN_PARAMS,
    "nao_ip": ("127.0.0.1", "IP address or host name of the robot running NAOqi", HOST),
    "nao_port": (9559, "NAOqi port", PORT),
    "scenes": (["r_finger-torso", "l_finger-torso"], "what presses what, 'fingertip-part': fingertip scenes of the"
                                                     " skin config on one part fixed to the base (the torso); each"
                                                     " arm takes the taxels the other cannot reach"),
    "calibration": ("", "calibration the poses are planned under (empty: nominal)"),
    "dry_run": (False, "only plan: the poses and approaches as markers on nao_skin/capture/markers, nothing moves"),
    "max_touches": (250, "targets tried at most (touched, unreachable or aborted), then the arm goes to rest",
                    AT_LEAST_ONE),
    "limit_margin": (_CAPTURE.limit_margin, "rad kept from every joint limit in every command",
                     Rule(float, low=0.0, high=0.5)),
    "standoff": (_CAPTURE.standoff, "m: the fingertip this far off the skin before the approach",
                 Rule(float, low=0.005, high=0.1)),
    "approach_margin": (_CAPTURE.approach_margin, "m: the approach goes at most this far beyond the believed"
                                                  " surface, then stops (no contact)", Rule(float, low=0.0, high=0.02)),
    "press_max": (_CAPTURE.press_max, "m the press goes on beyond the first contact at most (while the highest"
                                      " pressure still rises)", Rule(float, low=0.0, high=0.01)),
    "hold": (_CAPTURE.hold, "s the press is held", Rule(float, low=0.0, high=10.0)),
    "move_speed": (_CAPTURE.move_speed, "speed fraction of the moves between targets", _fraction(0.5)),
    "approach_speed": (_CAPTURE.approach_speed, "speed fraction of the approach and the press", _fraction(0.2)),
    "retract_speed": (_CAPTURE.retract_speed, "speed fraction of the retract", _fraction(0.5)),
    "stiffness": (_CAPTURE.stiffness, "the arm's stiffness while it moves", Rule(float, low=0.1, high=1.0)),
    "stale_after": (_CAPTURE.stale_after, "s: joint states, or the skin's readings after a step, older than this"
                                          " hold the arm still; still so 2 s later, the capture stops",
                    Rule(float, low=0.02, high=10.0)),
    "naoqi_timeout": (20.0, "s a NAOqi call may take (a move at the slowest speed: up to ~12 s) before NAOqi"
                            " counts as lost", Rule(float, low=0.1, high=120.0)),
}


SKIN_HEATMAP = {
    **SKIN_PARAMS,
    "rate": (10.0, "marker updates per second (Hz)", RATE),
    "taxel_diameter": (0.005, "sphere diameter of a taxel (m)", POSITIVE),
    "legend_origin": ([0.0, -0.25, 0.15], "where the colour bar starts, in the base frame (m)",
                      Rule(tuple, length=3)),
    "earlier_recordings": ([""], "bags of earlier sittings the record session continues: their touches count"
                                 " as presses from the start"),
    "fingertip_scenes": ([""], "fingertip scenes of the session, 'fingertip-part' (e.g. r_finger-torso): each"
                               " fingertip's contact sphere shown in its arm's end frame; empty: none"),
    "calibration": ("", "calibration that places the fingertips of fingertip_scenes (empty: the robot config's)"),
}


YARP_SKIN_BRIDGE = {
    **SKIN_PARAMS,
    "events_port": ("/skinManager/skin_events:o", "skinManager's skin events (skinContactList) output port",
                    YARP_PORT),
    "local_prefix": ("/nao_skin/skin_bridge", "prefix of the YARP ports this bridge opens", YARP_PORT),
    "compensated_threshold": (0.0, "a compensated taxel value above this counts as activated (0-255 scale)",
                              Rule(float, low=0.0, high=255.0)),
    "stamp": ("envelope", "what stamps the messages: envelope (the time skinManager wrote, on its host's clock) or"
                          " receive (this machine's clock when the bridge reads: when skinManager's host clock"
                          " differs from the one stamping /joint_states)", Rule(str, ("envelope", "receive"))),
    "reconnect_period": (1.0, "seconds between checks that the YARP connections still exist", SECONDS),
    "status_period": (1.0, "seconds between /skin/bridge_status messages", SECONDS),
}


def params_file_said(node: str, name: str, value: str = "VALUE") -> str:
    """How a launch user gives one node's parameter: a ROS 2 parameters file (``params_file:=`` of our launch
    files) with the node's section."""
    return f"params_file:=FILE holding {node}: {{ros__parameters: {{{name}: {value}}}}}"


def at_start_said(node: str, name: str, value: str = "VALUE") -> str:
    """How a user gives one node's parameter when it starts, whichever way they started it (a node cannot know)."""
    return (f"ros2 run: -p {name}:={value}; ros2 launch: {params_file_said(node, name, value)}; nao-skin record:"
            f" --param {node}.{name}={value}")


# the parameters every rclpy node declares itself (rclpy 7): a parameters file may give them to any node
ROS_NODE_PARAMS = ("use_sim_time", "start_type_description_service")

NODE_PARAMS = {"calibrate": CALIBRATE, "naoqi_bridge": NAOQI_BRIDGE, "pairing_recorder": PAIRING_RECORDER,
               "sim_robot": SIM_ROBOT, "skin_heatmap": SKIN_HEATMAP, "yarp_skin_bridge": YARP_SKIN_BRIDGE,
               "fingertip_capture": FINGERTIP_CAPTURE}


# the parameters a node applies when they are set while it runs (ros2 param set), with the boolean parameter
# they need on (None: always); every other one is read when the node starts (read-only, said so by its
# descriptor and on a change)
CHANGEABLE = {
    "calibrate": {"live_every_touches": "live", "live_period": "live", "guidance": "live",
                  "guidance_targets": "live", "plots": None},
    "naoqi_bridge": {"rate": None, "use_sensors": None, "read_timeout": None},
    "yarp_skin_bridge": {"compensated_threshold": None},
}


def changeable_params(executable: str, values: dict) -> set:
    """The parameters ``executable``'s node applies when set, given its values at start (:data:`CHANGEABLE`)."""
    return {name for name, needs in CHANGEABLE.get(executable, {}).items() if needs is None or values.get(needs)}


def rule_range(default, rule: Rule | None) -> tuple | None:
    """``(low, high)`` a number parameter's rule keeps it in, for its descriptor (a whole-number rule for an
    integer parameter, a number rule for a float one; a missing side is the type's limit), else None. An open
    side (``> 0``) is the closed one here: the rule itself refuses the edge."""
    if rule is None or rule.optional or (rule.low is None and rule.high is None):
        return None
    if isinstance(default, bool):
        return None
    if isinstance(default, int) and rule.kind is int:
        return (int(rule.low) if rule.low is not None else -(2 ** 63),
                int(rule.high) if rule.high is not None else 2 ** 63 - 1)
    if isinstance(default, float) and rule.kind is float:
        return (float(rule.low) if rule.low is not None else -MAX_FLOAT,
                float(rule.high) if rule.high is not None else MAX_FLOAT)
    return None


# nodes that declare parameters per configured skin part (:func:`per_part_params`)
PER_PART_NODES = ("yarp_skin_bridge",)


def per_part_params(executable: str, parts) -> dict:
    """``{<family>.<part>: (default, description[, rule])}``: what a node declares for each configured skin part."""
    if executable not in PER_PART_NODES:
        return {}
    return {**{f"part_ids.{n}": (DEFAULT_PART_IDS.get(n, -1), f"skinManager skinPart id of '{n}' (-1: not bridged)")
               for n in parts},
            **{f"compensated_ports.{n}": ("", f"compensated taxel port of '{n}' (empty: none)", YARP_PORT_OR_NONE)
               for n in parts}}


def skin_from_params(params: dict) -> SkinModel:
    """The skin model of a node's ``skin_config`` and ``taxels`` parameters (:data:`SKIN_PARAMS`)."""
    return load_skin(params["skin_config"] or None, parse_taxel_files(params["taxels"], "parameter taxels"),
                     where="parameter taxels")


def options_from_params(params: dict) -> CalibrationOptions:
    """The engine options of the calibrate node's parameters, each checked by its rule (ints for floats are fine)."""
    return CalibrationOptions.from_mapping({name: params[name] for name in NODE_OPTIONS},
                                           where="parameter {name}:={value!r}")


def sim_overrides(touches_per_pair: int, pairs, parts=None, fingertips=()) -> dict:
    """Simulator parameter overrides from sim_robot's parameters (also used by tests to recompute)."""
    out = {"n_touches": int(touches_per_pair)}
    pairs = parse_pairs(pairs, parts, where="parameter pairs:", fingertips=fingertips)
    if pairs:
        out["pairs"] = [list(p) for p in pairs]
    return out


def check_naoqi_bridge(p: dict, where: str = "") -> None:
    if p["reconnect_min"] > p["reconnect_max"]:
        raise ConfigError(f"{where + ': ' if where else ''}parameters reconnect_min:={p['reconnect_min']} and"
                          f" reconnect_max:={p['reconnect_max']}: the first delay is longer than the longest")


def check_sim_robot(p: dict, where: str = "sim_robot") -> tuple:
    """Presses that do not overlap, a preset and pairs the simulator knows for this skin: ``(skin, simulation
    parameters)`` of the node."""
    check_timing(p["touch_period"], p["press_duration"], p["hold"], where)
    skin = skin_from_params(p)
    params = load_params(p["preset"], sim_overrides(p["touches_per_pair"], p["pairs"], skin.parts,
                                                    tuple(skin.robot.fingertips)))
    # the pairs that press, the preset's or the parameter's, against what the skin config makes touch: said
    # before a session starts, naming where they come from
    check_pairs(pair_list(params), skin, where=f"{where}: parameter pairs" if any(p["pairs"])
                else f"{where}: preset '{p['preset']}' of {default_params_file()}")
    return skin, params


def guidance_pairs(p: dict, skin: SkinModel) -> tuple:
    """The calibrate node's ``guidance_pairs``: 'hand-part' strings to (hand, part) pairs of the skin's parts, or
    fingertip scenes of its ``fingertip_touch`` ('r_finger-torso': the guidance names the taxels no touch reached);
    none given: the skin config's self-touch pairs (the four thesis pairs on the Nao)."""
    given = parse_pairs(p["guidance_pairs"], skin.parts, "parameter guidance_pairs:", tuple(skin.robot.fingertips))
    touching = skin.self_touch.pairs()
    scenes = skin.fingertip_touch.pairs()
    for hand, part in given:
        if (hand, part) not in touching and (hand, part) not in scenes:   # a press no pose (or operator) makes
            raise ConfigError(f"parameter guidance_pairs: '{hand}-{part}' is not a self-touch pair of the skin config"
                              f" (a hand of its 'touching' pressed on a part it touches: "
                              f"{', '.join(f'{h}-{b}' for h, b in touching)}) nor one of its fingertip scenes"
                              f" ({', '.join(f'{f}-{b}' for f, b in scenes) or 'none'})")
    return given or touching


def fingertip_scenes(p: dict, skin: SkinModel) -> tuple:
    """The pairing_recorder's ``fingertip_scenes``: 'fingertip-part' strings as ``(fingertip, part)`` scenes of the
    skin config's ``fingertip_touch``."""
    given = parse_pairs(p["fingertip_scenes"], skin.parts, "parameter fingertip_scenes:", tuple(skin.robot.fingertips))
    known = skin.fingertip_touch.pairs()
    for tip, part in given:
        if (tip, part) not in known:
            raise ConfigError(f"parameter fingertip_scenes: '{tip}-{part}' is not a fingertip scene of the skin config"
                              f" (fingertip_touch: {', '.join(f'{f}-{b}' for f, b in known) or 'none'})")
    return given


def check_pairing_recorder(p: dict, where: str = "pairing_recorder") -> None:
    """Fingertip scenes of the skin the node reads."""
    try:
        fingertip_scenes(p, skin_from_params(p))
    except NaoSkinError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def check_skin_heatmap(p: dict, where: str = "skin_heatmap") -> None:
    """Fingertip scenes of the skin the node reads."""
    check_pairing_recorder(p, where)


def check_calibrate(p: dict, where: str = "calibrate") -> None:
    """Guidance pairs of the skin the node reads."""
    try:
        guidance_pairs(p, skin_from_params(p))
    except NaoSkinError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def capture_setup(p: dict, where: str = "fingertip_capture") -> tuple:
    """``(skin, calibration, fingertips, part, options)`` of the fingertip_capture node's parameters: the scenes
    fingertip scenes of the skin config, each fingertip once, all on one part fixed to the base; the calibration
    read against the skin."""
    import dataclasses

    from nao_skin.model.skin import SkinCalibration

    try:
        skin = skin_from_params(p)
        scenes = fingertip_scenes({"fingertip_scenes": list(p["scenes"])}, skin)
        tips, parts = [t for t, _ in scenes], {part for _, part in scenes}
        if not scenes or len(parts) != 1 or len(set(tips)) != len(tips):
            raise ConfigError(f"parameter scenes:={list(p['scenes'])!r}: expected 'fingertip-part' scenes of one part,"
                              f" each fingertip once, e.g. ['r_finger-torso', 'l_finger-torso']")
        part, = parts
        if skin.parts[part].chain is not None:
            raise ConfigError(f"parameter scenes:={list(p['scenes'])!r}: the capture presses a part fixed to the base"
                              f" (the torso), not {part}")
        calibration = SkinCalibration.load(p["calibration"], skin) if p["calibration"] else skin.zero_calibration()
        fields = {f.name for f in dataclasses.fields(CaptureOptions)}
        options = CaptureOptions(**{k: float(v) for k, v in p.items() if k in fields})
    except NaoSkinError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return skin, calibration, tips, part, options


def check_fingertip_capture(p: dict, where: str = "fingertip_capture") -> None:
    capture_setup(p, where)


# what no single parameter's rule can say: checked by `nao-skin record` before any node starts, by the node
# again at its start
CHECKS = {"calibrate": check_calibrate, "naoqi_bridge": check_naoqi_bridge, "sim_robot": check_sim_robot,
          "pairing_recorder": check_pairing_recorder, "skin_heatmap": check_skin_heatmap,
          "fingertip_capture": check_fingertip_capture}
