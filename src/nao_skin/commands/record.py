"""``nao-skin record``: the record session of ``launch/record.launch.py`` without ``ros2 launch``.

Starts the same nodes with the same parameter files and overrides
(:func:`nao_skin.session.record.record_session`) as child processes, stops
them on SIGINT/SIGTERM/SIGHUP (the recorder then writes and closes its bag),
when one of them fails, or after ``--duration`` seconds. External
executables (robot_state_publisher, rviz2) are started when installed and
skipped with a note otherwise.

The nodes never outlive this process: on Linux each gets SIGTERM from the
kernel when it dies, however it dies (``kill -9`` included), and each of our
nodes also watches its parent (:data:`~nao_skin.session.record.PARENT_ENV`).
Overrides and the Python modules a node needs are checked before anything
starts. Generated parameter files live in a temporary directory removed at
the end unless ``--keep-temp``.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

NAME = "record"
HELP = "record self-touch: start the bridges or the simulated robot, the recorder, heat-map and calibrate node"


def add_arguments(parser) -> None:
    parser.add_argument("--robot", choices=["sim", "nao"], default="sim", help="simulated robot or the real Nao")
    parser.add_argument("--nao-ip", default="", help="robot address for naoqi_bridge (robot nao)")
    parser.add_argument("--no-naoqi", action="store_true",
                        help="do not start naoqi_bridge (another driver publishes /joint_states)")
    parser.add_argument("--events-port", default="", help="skinManager's skin events port (robot nao)")
    parser.add_argument("--bag", default="", help="touch bag to write (default: ./nao_skin_touches_<date>_<time>)")
    parser.add_argument("--calibration", default="", help="calibration to start from (default: nominal)")
    parser.add_argument("--continue-from", action="append", default=[], metavar="BAG",
                        help="a bag of an earlier sitting of this capture: the live calibration, the guidance and the"
                             " calibration written at the end cover its touches too (repeatable; the new touches go"
                             " to a new bag, --bag)")
    parser.add_argument("--taxels", action="append", default=[], metavar="PART=FILE",
                        help="the robot's own skinManager taxel file of a part, for every node that reads the skin;"
                             " repeatable")
    parser.add_argument("--rviz", action="store_true", help="also start rviz2 with config/nao_skin.rviz")
    parser.add_argument("--namespace", default="", metavar="NS",
                        help="every node in this ROS namespace (e.g. /nao2): its topics under it, its TF frames"
                             " prefixed with it, so a second robot records on the same ROS domain")
    parser.add_argument("--guided", action="store_true",
                        help="robot sim: the simulated robot's next touches follow the guidance (/nao_skin/guidance)")
    parser.add_argument("--capture", choices=["false", "true", "dry"], default="false",
                        help="fingertip capture: true: the robot presses its fingertip on the torso by itself (robot"
                             " nao, through NAOqi); dry: only the planned approaches in RViz")
    parser.add_argument("--seed", type=int, default=None, metavar="N",
                        help="robot sim: the simulated robot's seed, the same seed plays the same touches (default:"
                             " config/record.yaml's; continuing earlier sittings, one none of them played)")
    parser.add_argument("--scene", action="append", default=[], metavar="HAND-PART",
                        help="the scenes recorded, as record.launch.py's scene:=: self-touch pairs (r_hand-torso) and"
                             " fingertip scenes (r_finger-torso), comma separated or repeated; the simulated robot"
                             " plays them, the recorder takes the fingertip scenes' touches (default: the simulated"
                             " robot's preset, self-touches only)")
    parser.add_argument("--params-file", default="", metavar="FILE",
                        help="a ROS 2 parameters file for the nodes, applied after config/record.yaml and"
                             " config/bridges.yaml (as record.launch.py's params_file:=); --param still wins")
    parser.add_argument("--param", action="append", default=[], metavar="NODE.NAME=VALUE",
                        help="override a node parameter, e.g. sim_robot.touches_per_pair=5 (repeatable; a later one"
                             " wins, as with ros2's -p); checked against the parameters the node declares before"
                             " anything starts")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: until Ctrl-C)")
    parser.add_argument("--print", action="store_true", help="print the node command lines and exit")
    parser.add_argument("--keep-temp", action="store_true",
                        help="keep the temporary directory of generated parameter files (e.g. the URDF for"
                             " robot_state_publisher) and print its path; by default it is removed when record ends")


def parse_overrides(items) -> dict:
    """``NODE.NAME=VALUE`` items as ``{node: {name: value text}}``; the node's declared type parses the text."""
    from nao_skin.errors import ConfigError

    out: dict = {}
    for item in items:
        key, sep, value = item.partition("=")
        node, dot, name = key.partition(".")
        if not sep or not dot or not name:
            raise ConfigError(f"--param {item!r}: expected NODE.NAME=VALUE")
        out.setdefault(node, {})[name] = value
    return out


def run(args) -> int:
    import math

    from nao_skin.errors import ConfigError
    from nao_skin.errors import STOP_SIGNALS
    from nao_skin.session.claim import claim_domain
    from nao_skin.session.record import check_needs, record_session

    if not (args.duration >= 0 and math.isfinite(args.duration)):     # NaN, -5, inf would all mean 'forever'
        raise ConfigError(f"--duration {args.duration}: expected seconds >= 0 (0: until Ctrl-C)")

    specs = record_session(args.robot, nao_ip=args.nao_ip, naoqi=not args.no_naoqi, events_port=args.events_port,
                           bag_path=args.bag, calibration=args.calibration, rviz=args.rviz, taxels=args.taxels,
                           overrides=parse_overrides(args.param), guided=args.guided,
                           continue_from=args.continue_from, namespace=args.namespace, spelling="command",
                           params_file=args.params_file, seed=args.seed, scene=args.scene,
                           say=lambda line: _say(f"record: {line}"), capture=args.capture)
    claim = None
    if not args.print:
        check_needs(specs)
        # one session per ROS domain and namespace: two would record each other's touches
        claim = claim_domain(namespace=specs[0].namespace)
        if claim.problem:
            _say(f"record: {claim.problem}")
    stop = {"signal": None}

    def on_signal(signum, frame):      # noqa: ARG001 - signal handler signature
        stop["signal"] = signum

    # from here on a signal only sets the flag: the finally blocks below always run
    old = {s: signal.signal(s, on_signal) for s in STOP_SIGNALS}
    work = Path(tempfile.mkdtemp(prefix="nao_skin_record_"))
    try:
        return _session(specs, work, args, stop)
    finally:
        if args.keep_temp:
            _say(f"record: kept the temporary files in {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)
        if claim is not None:
            claim.release()
        for s, handler in old.items():
            signal.signal(s, handler)


def _session(specs, work: Path, args, stop: dict) -> int:
    from nao_skin.session.processes import die_with_parent, stop_all
    from nao_skin.session.record import PARENT_ENV, command_line

    commands = []
    for spec in specs:
        argv = command_line(spec, work)
        if argv is None:
            _say(f"record: {spec.executable} ({spec.package}) is not installed here; skipped")
            continue
        commands.append((spec.name, argv))
    if args.print:
        for name, argv in commands:
            print(f"{name}: {' '.join(argv)}")
        if not args.keep_temp and any(str(work) in a for _, argv in commands for a in argv):
            _say(f"record: the parameter files under {work} are removed on exit; --keep-temp keeps them")
        return 0

    env = dict(os.environ, **{PARENT_ENV: str(os.getpid())})
    preexec = die_with_parent(os.getpid())
    procs = []
    failed = None       # (name, exit code) of the first node that ended by itself
    try:
        for name, argv in commands:
            if stop["signal"] is not None:
                break
            # own process group: a Ctrl-C in the terminal reaches the children only through us, in order
            procs.append((name, subprocess.Popen(argv, start_new_session=True, env=env, preexec_fn=preexec)))
        _say(f"record: started {', '.join(n for n, _ in procs)} (pids {' '.join(str(p.pid) for _, p in procs)})")
        deadline = time.monotonic() + args.duration if args.duration > 0 else None
        while stop["signal"] is None and failed is None:
            if deadline is not None and time.monotonic() >= deadline:
                break
            for name, p in procs:
                if p.poll() is not None:
                    failed = (name, p.returncode)
            time.sleep(0.1)
        if failed is not None:
            _say(f"record: {failed[0]} exited with code {failed[1]}; stopping the session")
    finally:
        codes = stop_all(procs, lambda line: _say(f"record: {line}"))
    bag = next((spec.overrides.get("bag_path") for spec in specs if spec.name == "pairing_recorder"), None)
    if bag and not os.path.lexists(bag) and codes.get("pairing_recorder", 1) == 0:   # not moved, not failed
        _say(f"record: nothing was recorded: the session ended before the recorder made its bag ({bag})")
    bad = {n: c for n, c in codes.items() if c not in (0, None)}
    if bad:
        _say(f"record: exit codes {bad}")
        if bag and any(c not in (0, 2, None) for c in bad.values()):     # killed or crashed: it said nothing
            _say(f"record: the bag {bag} keeps every touch recorded up to its last flush; nao-skin reads it as"
                 f" it is (nao-skin stats {bag})")
        # a node that ends with 2 (also while it stops: a full disk as the bag closes) said in one line what
        # in its input, parameters or output is wrong: so does record
        return 2 if 2 in bad.values() else 1
    return 0


def _say(line: str) -> None:
    """One line on stderr; a closed terminal (SIGHUP) must not keep record from stopping its nodes."""
    try:
        print(line, file=sys.stderr, flush=True)
    except OSError:
        pass
