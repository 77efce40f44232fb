"""``nao-skin bench-live``: throughput of the live suite over real DDS (a benchmark, not a test).

Starts sim_robot (looping, joint states at 100 Hz, 4 skin parts at 50 Hz
with taxels and contacts), pairing_recorder, skin_heatmap and the calibrate
node recalibrating live on the recorder's bag (as in a record session, with
an update every ``--update-every`` touches) as processes on a private ROS
domain, listens for ``--seconds`` and prints:

* the load actually delivered (joint states and skin messages per second);
* the recorder's processing time per skin message (p50 / p99 / max, measured
  in its callbacks; target p99 <= 5 ms) while the live updates run;
* the live updates made in the window and their seconds;
* the heat-map's publish rate with all taxels of all parts (target 10 Hz).

``--no-calibrate`` leaves the calibrate node out (the recorder's figures
without live updates, to compare).

``--record-stops N`` measures instead how long ``nao-skin record`` takes to
end after Ctrl-C: N sessions of the simulated robot with live updates, each
sent SIGINT once its calibrate node has made a live update and the robot has
played on; SIGINT to exit, median and worst (target <= 5 s).

The nodes' logs and the recorder's bag go to a temporary directory, removed
when the command ends (also on error or Ctrl-C) unless ``--keep-temp``.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

NAME = "bench-live"
HELP = "benchmark the live suite: recorder time per skin message, heat-map rate (prints numbers)"


def add_arguments(parser) -> None:
    parser.add_argument("--seconds", type=float, default=30.0, help="measurement window (s)")
    parser.add_argument("--domain", type=int, default=0, help="ROS domain id (default: from the pid)")
    parser.add_argument("--touch-period", type=float, default=0.6, help="s between simulated presses")
    parser.add_argument("--update-every", type=int, default=5,
                        help="live calibration: an update every this many new touches (default 5: updates run"
                             " back to back for most of the window)")
    parser.add_argument("--update-input", metavar="BAG",
                        help="live calibration: recalibrate this recording at each update instead of the recorder's"
                             " young bag, e.g. bags/sim_default (4000 touches: the updates of a long session)")
    parser.add_argument("--no-calibrate", action="store_true",
                        help="without the calibrate node (no live updates), to compare the recorder's figures")
    parser.add_argument("--record-stops", type=int, default=0, metavar="N",
                        help="instead: N nao-skin record sessions stopped with Ctrl-C (SIGINT) while they record, and"
                             " the seconds from SIGINT to record's exit (median and worst; target <= 5 s)")
    parser.add_argument("--keep-temp", action="store_true",
                        help="keep the temporary directory with the nodes' logs and the recorded bag"
                             " (default: removed when the command ends)")


# ROS 2 domain ids (ROS_DOMAIN_ID) a DDS participant can take on Linux; 0 here: one from the pid
DOMAINS = range(0, 233)


MAX_SECONDS = 86400.0    # a window of a day at most (a node's periods are capped there too)


def sim_robot_overrides(args) -> dict:
    """The simulated robot's parameters of the run: presses every ``--touch-period`` s."""
    return {"loop": True, "touches_per_pair": 60, "touch_period": args.touch_period,
            "press_duration": min(0.3, args.touch_period / 2), "hold": 0.05, "wait_for_subscribers": 2}


def check_arguments(args) -> None:
    """Each number in its range, the update input a recording that gives touches, before any node starts (a NaN
    window never ends)."""
    from nao_skin.errors import DataError
    from nao_skin.formats.inputs import check_inputs
    from nao_skin.live.playback import check_timing

    for flag, value in (("--seconds", args.seconds), ("--touch-period", args.touch_period)):
        if not 0 < value <= MAX_SECONDS:
            raise DataError(f"{flag} {value}: expected seconds above 0, at most {MAX_SECONDS:g}")
    robot = sim_robot_overrides(args)
    check_timing(robot["touch_period"], robot["press_duration"], robot["hold"], "--touch-period")
    if not 0 <= args.record_stops <= 1000:
        raise DataError(f"--record-stops {args.record_stops}: expected a whole number from 0 to 1000")
    if args.update_every < 1:
        raise DataError(f"--update-every {args.update_every}: expected a whole number >= 1")
    if args.domain not in DOMAINS:
        raise DataError(f"--domain {args.domain}: expected a ROS domain id in {DOMAINS.start}..{DOMAINS.stop - 1}")
    if args.update_input:
        check_inputs([args.update_input])
        # read once here: on a file that holds no touches every update would fail while the benchmark ends well
        from nao_skin.calibration.pipeline import load_inputs
        from nao_skin.model.skin import load_skin

        load_inputs([args.update_input], load_skin(), log=lambda msg: None)


def _last_line(path: Path) -> str:
    """The last line a node wrote to its error log (its one-line reason), or that it wrote none."""
    try:
        lines = [line for line in path.read_text(errors="replace").splitlines() if line.strip()]
    except OSError:
        lines = []
    return lines[-1].strip() if lines else "no message"


def run(args) -> int:
    check_arguments(args)
    work = Path(tempfile.mkdtemp(prefix="nao_skin_bench_"))
    try:
        return _record_stops(args, work) if args.record_stops else _measure(args, work)
    finally:
        if args.keep_temp:
            print(f"bench-live: nodes' logs and the recorded bag kept in {work}", file=sys.stderr)
        else:
            shutil.rmtree(work, ignore_errors=True)


def session_nodes(args, work: Path) -> list:
    """The record session the benchmark runs (:func:`~nao_skin.session.record.record_session`, robot:=sim): the
    recorder writes ``work/touches``, the calibrate node updates live on it, or on ``--update-input``."""
    from nao_skin.session.record import record_session

    overrides = {"sim_robot": sim_robot_overrides(args),
                 "calibrate": {"live": True, "live_every_touches": args.update_every, "live_period": 1.0}}
    specs = record_session("sim", bag_path=str(work / "touches"), overrides=overrides,
                           with_robot_state_publisher=False)
    if args.no_calibrate:
        return [spec for spec in specs if spec.name != "calibrate"]
    if args.update_input:      # every update over another recording than the session's (checked above)
        next(spec for spec in specs if spec.name == "calibrate").overrides["recording"] = str(
            Path(args.update_input).resolve())
    return specs


RECORD_STOP_TARGET_S = 5.0      # Ctrl-C of nao-skin record to its exit


def _record_stops(args, work: Path) -> int:
    """``--record-stops``: sessions of ``nao-skin record --robot sim`` (live updates every ``--update-every``
    touches), each stopped by SIGINT 1 s after its calibrate node said a live update; the seconds to record's
    exit."""
    import numpy as np

    from nao_skin.errors import STOP_SIGNALS

    domain = args.domain or 10 + os.getpid() % 90
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONUNBUFFERED="1")
    interrupted = threading.Event()
    previous_handlers = {s: signal.signal(s, lambda signum, frame: interrupted.set()) for s in STOP_SIGNALS}
    period = args.touch_period
    robot = [f"--param=sim_robot.{k}={v}" for k, v in {"touch_period": period, "press_duration": min(0.3, period / 2),
                                                      "hold": 0.05, "touches_per_pair": 60, "loop": True}.items()]
    seconds, codes = [], []
    try:
        for n in range(args.record_stops):
            if interrupted.is_set():
                raise KeyboardInterrupt
            log = work / f"record_{n}.err"
            argv = [sys.executable, "-m", "nao_skin.cli", "record", "--robot", "sim", "--bag", str(work / f"bag_{n}"),
                    *robot, f"--param=calibrate.live_every_touches={args.update_every}",
                    "--param=calibrate.live_period=1.0"]
            with open(log, "wb") as err:
                proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
            try:
                deadline = time.monotonic() + 120
                while "] [calibrate]: live update" not in log.read_text(errors="replace"):
                    if proc.poll() is not None or time.monotonic() > deadline or interrupted.is_set():
                        break
                    time.sleep(0.1)
                if proc.poll() is not None or interrupted.is_set() or time.monotonic() > deadline:
                    if not interrupted.is_set():
                        print(f"bench-live: record session {n} made no live update (exit code {proc.poll()}):"
                              f" {_last_line(log)}", file=sys.stderr)
                        return 2
                    raise KeyboardInterrupt
                time.sleep(1.0)                     # the robot plays on, the next update may be running
                t0 = time.monotonic()
                proc.send_signal(signal.SIGINT)
                codes.append(proc.wait())
                seconds.append(time.monotonic() - t0)
            finally:
                if proc.poll() is None:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
            print(f"bench-live: record session {n}: SIGINT to exit {seconds[-1]:.2f} s (exit code {codes[-1]})",
                  file=sys.stderr)
    finally:
        for s, handler in previous_handlers.items():
            signal.signal(s, handler)
    worst = max(seconds)
    met = "met" if worst <= RECORD_STOP_TARGET_S else "NOT met"
    print(f"record Ctrl-C to exit: median {float(np.median(seconds)):.2f} s, worst {worst:.2f} s over"
          f" {len(seconds)} sessions (target <= {RECORD_STOP_TARGET_S:g} s: {met}); exit codes {sorted(set(codes))}")
    return 0 if all(c == 0 for c in codes) else 1


def _measure(args, work: Path) -> int:
    import numpy as np

    from nao_skin.errors import STOP_SIGNALS
    from nao_skin.model.skin import load_skin
    from nao_skin.nodes.bench_probe import LiveProbe
    from nao_skin.session.processes import die_with_parent, stop_all
    from nao_skin.session.record import PARENT_ENV, command_line

    domain = args.domain or 10 + os.getpid() % 90
    specs = session_nodes(args, work)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONUNBUFFERED="1", **{PARENT_ENV: str(os.getpid())})
    skin_parts = set(load_skin().parts)
    probe = LiveProbe(domain, skin_parts, "torso")
    interrupted = threading.Event()
    # SIGTERM (a timeout, a CI job cancelled) and SIGHUP stop the run as Ctrl-C does: the nodes are stopped and
    # the temporary directory removed; a kill -9 of this process reaches them as in record (parent death)
    previous_handlers = {s: signal.signal(s, lambda signum, frame: interrupted.set()) for s in STOP_SIGNALS}
    preexec = die_with_parent(os.getpid())
    procs = []
    progress = probe.progress
    try:
        for spec in specs:
            procs.append((spec.name, subprocess.Popen(command_line(spec, work), env=env, start_new_session=True,
                                                      stdout=subprocess.DEVNULL,
                                                      stderr=open(work / f"{spec.name}.err", "wb"),
                                                      preexec_fn=preexec)))
        # wait until the play has started (the recorder reports touches), then measure a clean window
        deadline = time.monotonic() + 60
        while (time.monotonic() < deadline and not (progress and progress[-1]["touches"] > 0)
               and not interrupted.is_set()):
            probe.spin_once()
        if interrupted.is_set():
            raise KeyboardInterrupt
        ended = [(name, p.returncode) for name, p in procs if p.poll() is not None]
        if ended or not progress or not progress[-1]["touches"]:
            # a node that stopped (a parameter it refused) leaves a window of zeros: no figure to print
            where = f"see {work}" if args.keep_temp else "run again with --keep-temp to keep the nodes' logs"
            name, code = ended[0] if ended else (None, None)
            why = (f"node {name} ended (exit code {code}): {_last_line(work / f'{name}.err')}" if ended else
                   "the recorder never reported progress" if not progress else "no touch was recorded in 60 s")
            print(f"bench-live: {why}; {where}", file=sys.stderr)
            return 2
        start_counts = dict(probe.counts)
        start_heat = len(probe.heat)
        start_progress_n = progress[-1]["skin_message_ms"]["n"]
        t0 = time.monotonic()
        while time.monotonic() - t0 < args.seconds and not interrupted.is_set():
            probe.spin_once()
        if interrupted.is_set():
            raise KeyboardInterrupt
        window = time.monotonic() - t0
    finally:
        stop_all(procs, lambda line: print(f"bench-live: {line}", file=sys.stderr))
        probe.close()
        for s, handler in previous_handlers.items():
            signal.signal(s, handler)
    last = progress[-1]
    ms = last["skin_message_ms"]
    joints_hz = (probe.counts["joints"] - start_counts["joints"]) / window
    skin_hz = (probe.counts["skin"] - start_counts["skin"]) / window
    hs = np.array([when for when, _ in probe.heat[start_heat:]])
    heat_hz = (len(hs) - 1) / (hs[-1] - hs[0]) if len(hs) > 1 else 0.0
    print(f"load: /joint_states {joints_hz:.1f} Hz, skin {skin_hz:.1f} Hz per part x {len(skin_parts)} parts"
          f" (taxels + contacts: {2 * len(skin_parts) * skin_hz:.0f} skin messages/s), window {window:.1f} s")
    print(f"recorder: {ms['n'] - start_progress_n} skin messages in the window ({ms['n']} recent kept),"
          f" time per skin message p50 {ms['p50']:.3f} ms, p99 {ms['p99']:.3f} ms, max {ms['max']:.3f} ms"
          f" (target p99 <= 5 ms); {last['touches']} touches recorded")
    if not args.no_calibrate:
        updates = probe.updates
        live = [u for when, u in updates if t0 <= when <= t0 + window and u.get("state") == "updated"]
        secs = np.array([u["seconds"] for u in live])
        busy = secs.sum() / window if len(secs) else 0.0
        print(f"live calibration: {len(live)} updates in the window (every {args.update_every} touches),"
              + (f" {np.median(secs):.2f} s median, {secs.max():.2f} s max each, up to"
                 f" {max(u['touches'] for u in live)} touches; the calibrate node was busy {100 * busy:.0f} % of the"
                 f" window" if len(live) else " none finished")
              + "; " + ", ".join(f"{k}: {v}" for k, v in Counter(u.get("state") for _, u in updates).items()))
    print(f"heat-map: {heat_hz:.2f} Hz with {probe.heat[-1][1] if probe.heat else 0} taxels per message"
          f" (target 10 Hz)")
    return 0
