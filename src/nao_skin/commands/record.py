"""``nao-skin record``: the record session of ``launch/record.launch.py`` without ``ros2 launch``.

Starts the same nodes with the same parameter files and overrides
(:func:`nao_skin.nodes.session.record_session`) as child processes, forwards
SIGINT/SIGTERM to them (the recorder then writes and closes its bag), and
stops when one of them fails or after ``--duration`` seconds. External
executables (robot_state_publisher, rviz2) are started when installed and
skipped with a note otherwise.
"""
from __future__ import annotations

import os
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
    parser.add_argument("--rviz", action="store_true", help="also start rviz2 with config/nao_skin.rviz")
    parser.add_argument("--param", action="append", default=[], metavar="NODE.NAME=VALUE",
                        help="override a node parameter, e.g. sim_robot.touches_per_pair=5 (repeatable)")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: until Ctrl-C)")
    parser.add_argument("--print", action="store_true", help="print the node command lines and exit")


def parse_overrides(items) -> dict:
    import yaml

    from ..errors import ConfigError

    out: dict = {}
    for item in items:
        key, sep, value = item.partition("=")
        node, dot, name = key.partition(".")
        if not sep or not dot or not name:
            raise ConfigError(f"--param {item!r}: expected NODE.NAME=VALUE")
        out.setdefault(node, {})[name] = yaml.safe_load(value) if value else ""
    return out


def run(args) -> int:
    from ..nodes.session import command_line, record_session

    specs = record_session(args.robot, nao_ip=args.nao_ip, naoqi=not args.no_naoqi, events_port=args.events_port,
                           bag_path=args.bag, calibration=args.calibration, rviz=args.rviz,
                           overrides=parse_overrides(args.param))
    work = Path(tempfile.mkdtemp(prefix="nao_skin_record_"))
    commands = []
    for spec in specs:
        argv = command_line(spec, work)
        if argv is None:
            print(f"record: {spec.executable} ({spec.package}) is not installed here; skipped", file=sys.stderr)
            continue
        commands.append((spec.name, argv))
    if args.print:
        for name, argv in commands:
            print(f"{name}: {' '.join(argv)}")
        return 0

    stop = {"signal": None}

    def on_signal(signum, frame):      # noqa: ARG001 - signal handler signature
        stop["signal"] = signum

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    procs = []
    try:
        for name, argv in commands:
            # own process group: a Ctrl-C in the terminal reaches the children only through us, in order
            procs.append((name, subprocess.Popen(argv, start_new_session=True)))
        print(f"record: started {', '.join(n for n, _ in procs)} (pids {' '.join(str(p.pid) for _, p in procs)})",
              file=sys.stderr, flush=True)
        deadline = time.monotonic() + args.duration if args.duration > 0 else None
        failed = None
        while stop["signal"] is None and failed is None:
            if deadline is not None and time.monotonic() >= deadline:
                break
            for name, p in procs:
                if p.poll() is not None:
                    failed = (name, p.returncode)
            time.sleep(0.1)
        if failed is not None:
            print(f"record: {failed[0]} exited with code {failed[1]}; stopping the session", file=sys.stderr)
    finally:
        codes = _stop_all(procs)
        for s, handler in old.items():
            signal.signal(s, handler)
    bad = {n: c for n, c in codes.items() if c not in (0, None)}
    if bad:
        print(f"record: exit codes {bad}", file=sys.stderr)
        return 1
    return 0


def _stop_all(procs, timeout: float = 20.0) -> dict:
    """SIGINT every child (the recorder closes its bag), wait, then SIGKILL what is left."""
    for _, p in procs:
        if p.poll() is None:
            try:
                os.killpg(p.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
    deadline = time.monotonic() + timeout
    codes = {}
    for name, p in procs:
        try:
            codes[name] = p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            print(f"record: {name} did not stop after SIGINT; killed", file=sys.stderr)
            os.killpg(p.pid, signal.SIGKILL)
            codes[name] = p.wait()
    return codes
