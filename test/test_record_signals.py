"""``nao-skin record`` ended by signals it cannot or may not ignore: its nodes never outlive it.

1. record killed with SIGKILL mid-session: within 2 s no node of the session
   runs any more, and the recorder closed its bag (metadata complete, no
   lock) with at least every touch its progress topic had reported.
2. record sent SIGHUP (the terminal or SSH session closed): it stops its
   nodes in order and exits 0; the bag is closed, with every touch the
   recorder wrote, equal to the simulator's first touches.
3. The nodes' own fallback: a recorder started with ``NAO_SKIN_PARENT_PID``
   by a plain parent (no parent-death signal) stops and closes its bag when
   that parent is killed with SIGKILL.
4. A recorder node sent SIGHUP itself closes its bag as on SIGINT, exit 0.
5. The disk full while recording: one line from the recorder, the session
   ends with exit 2, and the bag keeps every touch flushed before.
6. A Ctrl-C while a console script (a node as ``ros2 run`` starts it, or
   ``nao-skin``) still imports: one line, exit 130, no traceback.
7. Ctrl-C again and again while ``nao-skin`` exits after its work: its
   exit code and output stay as they were.
8. A session stopped with Ctrl-C while its simulated robot plays: the robot's
   last status says stopped, with the touches played, not done.

Node processes are found by the pids record prints on stderr and checked
by their command line in /proc, so no other test's process is matched.
"""
from __future__ import annotations

import json
import os
import re
import resource
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from ros_harness import ROOT, Listener, Proc, node_process, ros_env, unique_domain_id
from test_record_session import assert_same_touches, expected_touches, record_cmd

from nao_skin.formats.bag import SIMULATED, read_touches
from nao_skin.formats.salvage import LOCK_FILE
from nao_skin.model.skin import load_skin

pytest.importorskip("rclpy")
from std_msgs.msg import String  # noqa: E402

from nao_skin.nodes.calibrate import FINAL_ACK_S, FINAL_BUDGET_S, FINAL_WAIT_S, STOP_JOIN_S  # noqa: E402
from nao_skin.nodes.topics import PROGRESS_TOPIC  # noqa: E402

pytestmark = pytest.mark.middleware   # runs nao-skin record and its nodes over DDS

GONE_WITHIN_S = 2.0          # the bound for the nodes to stop after record died
# ... and the calibrate node's once it has stopped: its session end's bounded steps
SESSION_END_S = STOP_JOIN_S + FINAL_WAIT_S + FINAL_BUDGET_S + FINAL_ACK_S
STARTED = re.compile(r"record: started (.+) \(pids ([\d ]+)\)")


def cmdline(pid: int) -> bytes | None:
    """The process's command line while it runs (not a zombie), else None."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        return None if state in ("Z", "X") else Path(f"/proc/{pid}/cmdline").read_bytes()
    except (OSError, IndexError):
        return None


def session_nodes(session: Proc) -> dict:
    """``{pid: command line}`` of the nodes record says it started; each checked to be one of ours."""
    m = STARTED.search(session.stderr())
    assert m, session.stderr()[-2000:]
    nodes = {int(p): cmdline(int(p)) for p in m.group(2).split()}
    assert all(c is not None and b"nao_skin.nodes." in c for c in nodes.values()), nodes
    return nodes


def still_running(nodes: dict, within: float) -> list:
    """The nodes still running after at most ``within`` s (polled)."""
    deadline = time.monotonic() + within
    while True:
        alive = [pid for pid, c in nodes.items() if cmdline(pid) == c]
        if not alive or time.monotonic() >= deadline:
            return alive
        time.sleep(0.05)


def kill_left(nodes: dict) -> None:
    for pid in still_running(nodes, 0.0):
        os.kill(pid, signal.SIGKILL)


def assert_closed(bag: Path) -> dict:
    """The recorder closed the bag: final metadata (files and topics listed), no lock left."""
    assert not (bag / LOCK_FILE).exists(), "the recorder did not close its bag"
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["files"] and info["topics_with_message_count"] and info["message_count"] > 0
    return info


class RecordingSession:
    """``nao-skin record`` with the simulated robot, running until the recorder reported some touches.

    ``with RecordingSession(tmp_path, seed) as run:``; inside, ``run.session`` (the record process),
    ``run.nodes`` (pid -> cmdline of its nodes) and ``run.reported`` (touches the progress topic
    reported); on leaving, everything of the session is stopped whatever happened.
    """

    def __init__(self, tmp_path: Path, seed: int, per_pair: int = 3):
        self.tmp_path, self.seed, self.per_pair = tmp_path, seed, per_pair
        self.bag = tmp_path / "touches"
        self.want = expected_touches(load_skin(), per_pair, seed)
        self.listener = self.session = None
        self.nodes: dict = {}

    def __enter__(self) -> "RecordingSession":
        domain = unique_domain_id()
        try:
            self.listener = Listener(domain)
            progress = self.listener.subscribe(String, PROGRESS_TOPIC, keep=lambda m: json.loads(m.data))
            # TMPDIR: a record killed with SIGKILL cannot remove its temporary directory; it stays in the test's
            self.session = Proc(record_cmd(self.bag, self.seed, self.per_pair), ros_env(domain, TMPDIR=self.tmp_path),
                                self.tmp_path, "record")
            assert self.listener.spin_until(lambda: progress and progress[-1]["touches"] >= 3, timeout=60,
                                            procs=[self.session]), "recorder reported no touches"
            self.reported = progress[-1]["touches"]
            self.nodes = session_nodes(self.session)
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def __exit__(self, *exc) -> None:
        if self.listener is not None:
            self.listener.close()
        if self.session is not None:
            self.session.stop()
        kill_left(self.nodes)

    def recorded(self):
        """The bag's touches (closed properly, nothing skipped), checked against what the simulator played."""
        got, report = read_touches(self.bag, load_skin())
        # a session of the simulated robot: its bag says so on every read, and nothing else
        assert not report.skipped and not report.notes and \
            report.info == [f"{self.bag}: recorded from {SIMULATED}, not the robot"], report.lines()
        try:
            assert_same_touches(got, self.want.subset(np.arange(got.n_touches)))
        except AssertionError as exc:     # what the nodes said tells a lost touch from a wrong one
            raise AssertionError(f"{exc}\n--- record's stderr:\n{self.session.stderr()[-4000:]}") from None
        return got, report


def test_record_killed_with_sigkill_takes_its_nodes_along(tmp_path):
    with RecordingSession(tmp_path, seed=13) as run:
        assert len(run.nodes) >= 4
        os.kill(run.session.popen.pid, signal.SIGKILL)
        run.session.popen.wait(timeout=10)
        left = still_running(run.nodes, GONE_WITHIN_S)
        # the calibrate node ends as at Ctrl-C: it writes the session's last calibration first, each step of that
        # bounded (its final update over the touches since the last live one included); within 2 s it was gone
        # in 5 of 6 runs, 2.5 s after the kill in the sixth (2026-12-08)
        calibrate = [p for p in left if b"nao_skin.nodes.calibrate" in run.nodes[p]]
        left = [p for p in left if p not in calibrate] + still_running({p: run.nodes[p] for p in calibrate},
                                                                        SESSION_END_S)
        assert not left, f"nodes outlived record: {[run.nodes[p] for p in left]}"
    assert run.session.popen.returncode == -signal.SIGKILL
    assert_closed(run.bag)
    got, _ = run.recorded()
    assert got.n_touches >= run.reported


def test_a_killed_recorder_ends_the_session_naming_the_bag_that_keeps_its_touches(tmp_path):
    """kill -9 of the recorder alone (the OOM killer, a user's pkill): record stops the session, exits 1,
    and says where the touches are, not only "pairing_recorder exited with code -9"."""
    with RecordingSession(tmp_path, seed=23) as run:
        recorder = next(pid for pid, c in run.nodes.items() if b"nao_skin.nodes.pairing_recorder" in c)
        os.kill(recorder, signal.SIGKILL)
        code = run.session.popen.wait(timeout=60)
    err = run.session.stderr()
    assert code == 1 and "Traceback" not in err, err[-3000:]
    assert f"record: the bag {run.bag} keeps every touch recorded up to its last flush" in err, err[-3000:]
    got, report = read_touches(run.bag, load_skin())
    assert got.n_touches > 0 and dict(report.skipped) == {"truncated bag": 1}, report.lines()


def test_record_hangup_closes_the_bag(tmp_path):
    with RecordingSession(tmp_path, seed=17) as run:
        run.session.popen.send_signal(signal.SIGHUP)     # record only, as a closing terminal does
        code = run.session.popen.wait(timeout=30)
    assert code == 0, run.session.stderr()[-3000:]
    assert not still_running(run.nodes, 0.0)
    info = assert_closed(run.bag)
    wrote = re.search(r"wrote (\d+) touches", run.session.stderr())
    assert wrote, run.session.stderr()[-3000:]
    got, report = run.recorded()
    assert got.n_touches == int(wrote.group(1)) >= run.reported
    assert info["message_count"] == report.n_read


def test_a_full_disk_ends_the_session_in_one_line_and_keeps_every_touch_flushed_before(tmp_path):
    """The stand-in for a full disk is a real failing write: a file size limit (RLIMIT_FSIZE) on the
    session, so a write past it fails (EFBIG, "File too large") as one on a full disk does (ENOSPC,
    seen on a 400 kB tmpfs: the same lines). The bag fills after about twenty touches of the sixty."""
    limit = 60_000
    bag = tmp_path / "touches"
    want = expected_touches(load_skin(), 15, 19)

    def limited() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    session = Proc(record_cmd(bag, 19, 15), ros_env(unique_domain_id()), tmp_path, "record", preexec_fn=limited)
    try:
        code = session.popen.wait(timeout=180)
    finally:
        session.stop()
    err = session.stderr()
    assert code == 2, err[-3000:]
    assert "Traceback" not in err, err[-3000:]
    line = re.search(r"error: (\S+): cannot write the bag \(File too large\) after (\d+) touches; recording"
                     r" stopped\. The bag keeps the (\d+) touches flushed before", err)
    assert line and line.group(1) == str(bag), err[-3000:]
    assert "record: pairing_recorder exited with code 2; stopping the session" in err
    flushed = int(line.group(3))
    assert 0 < flushed < want.n_touches
    assert (bag / LOCK_FILE).exists()           # left as it is: readers take it for an unclosed recording
    got, report = read_touches(bag, load_skin())
    assert flushed <= got.n_touches <= int(line.group(2))
    assert_same_touches(got, want.subset(np.arange(got.n_touches)))


SPAWN = ("import os, subprocess, sys\n"
         "env = dict(os.environ, NAO_SKIN_PARENT_PID=str(os.getpid()))\n"
         "p = subprocess.Popen(sys.argv[1:], env=env)\n"
         "print(p.pid, flush=True)\n"
         "p.wait()\n")


def test_node_stops_when_its_parent_is_killed_without_a_death_signal(tmp_path):
    domain = unique_domain_id()
    bag = tmp_path / "touches"
    listener = parent = None
    nodes: dict = {}
    argv = [sys.executable, "-c", SPAWN, sys.executable, "-m", "nao_skin.nodes.pairing_recorder", "--ros-args",
            "--params-file", str(ROOT / "config" / "record.yaml"), "-p", f"bag_path:={bag}"]
    try:
        listener = Listener(domain)
        progress = listener.subscribe(String, PROGRESS_TOPIC, keep=lambda m: json.loads(m.data))
        parent = Proc(argv, ros_env(domain), tmp_path, "parent")
        assert listener.spin_until(lambda: len(progress) >= 1, timeout=60, procs=[parent]), "recorder did not start"
        pid = int(parent.stdout().split()[0])
        nodes = {pid: cmdline(pid)}
        assert b"nao_skin.nodes.pairing_recorder" in nodes[pid]
        os.kill(parent.popen.pid, signal.SIGKILL)
        parent.popen.wait(timeout=10)
        left = still_running(nodes, GONE_WITHIN_S)
        assert not left, "the recorder outlived the process that started it"
    finally:
        if listener is not None:
            listener.close()
        if parent is not None:
            parent.stop()
        kill_left(nodes)
    assert f"the process that started this node (pid {parent.popen.pid}: nao-skin record or ros2 launch) is gone;" \
           f" stopping" in parent.stderr()
    assert not (bag / LOCK_FILE).exists()
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["files"], "the recorder did not close its bag"


def test_recorder_node_closes_its_bag_on_sighup(tmp_path):
    domain = unique_domain_id()
    bag = tmp_path / "touches"
    listener = recorder = None
    try:
        listener = Listener(domain)
        progress = listener.subscribe(String, PROGRESS_TOPIC, keep=lambda m: json.loads(m.data))
        recorder = node_process("pairing_recorder", {"bag_path": str(bag)}, ros_env(domain), tmp_path,
                                params_file=ROOT / "config" / "record.yaml")
        assert listener.spin_until(lambda: len(progress) >= 1, timeout=60, procs=[recorder]), "recorder did not start"
        assert (bag / LOCK_FILE).exists()
        recorder.popen.send_signal(signal.SIGHUP)
        code = recorder.popen.wait(timeout=30)
    finally:
        if listener is not None:
            listener.close()
        if recorder is not None:
            recorder.stop()
    assert code == 0, recorder.stderr()[-2000:]
    # nothing published here: its last line says so (a robot whose bridges read nothing ended with 'wrote 0')
    assert "wrote 0 touches" in recorder.stderr()
    assert "(no joint states and no skin samples ever arrived)" in recorder.stderr()
    assert not (bag / LOCK_FILE).exists()
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["files"], "the recorder did not close its bag"


def _wait_until_mapped(popen, library: str, timeout: float = 60.0) -> None:
    """Until the process has ``library`` (a shared object's name) in its memory map; an AssertionError when it
    ended before (a process that ended and is not yet waited for has an empty map: that was a 60 s wait)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            if library in Path(f"/proc/{popen.pid}/maps").read_text():
                return
        except OSError:
            pass
        if popen.poll() is not None:
            raise AssertionError(f"pid {popen.pid} ended (exit code {popen.returncode}) before it loaded {library}")
        time.sleep(0.001)
    raise AssertionError(f"pid {popen.pid} did not load {library} in {timeout:.0f} s")


@pytest.mark.parametrize("after_s", [0.0, 0.2])
@pytest.mark.parametrize("argv", [["calibrate"], ["nao-skin", "stats", str(ROOT / "bags" / "sim_default")]],
                         ids=["node", "command"])
def test_a_ctrl_c_while_a_console_script_imports_ends_in_one_line(tmp_path, argv, after_s):
    """``ros2 run nao_skin calibrate`` runs the console script in lib/nao_skin, ``nao-skin stats`` imports
    numpy and the engine once its command runs; a Ctrl-C in the first second lands while they import rclpy and scipy, before the node's own
    stop handler. That ends in one line and exit 130 (or, had it started, as a stop: exit 0), never in a
    traceback (from inside the import, or as the ImportError a C extension's import makes of it).

    The Ctrl-C is sent ``after_s`` after numpy's extension is loaded: the imports have begun, however
    fast this machine. (Before, in the first ~50 ms, Python itself starts, twice with the PyPI ROS wheels,
    whose site hook re-executes it to set LD_LIBRARY_PATH: no code of the package runs yet, and nothing
    of its own can hold a signal there.)"""
    script = Path(sys.executable).parent / argv[0]       # pip puts the console scripts beside python
    assert script.is_file(), f"{script}: the package's console scripts are not installed (pip install -e .)"
    proc = Proc([str(script), *argv[1:]], ros_env(unique_domain_id()), tmp_path, argv[0])
    try:
        _wait_until_mapped(proc.popen, "_multiarray_umath")
        time.sleep(after_s)
        proc.popen.send_signal(signal.SIGINT)
        code = proc.popen.wait(timeout=30)
    finally:
        proc.stop()
    err = proc.stderr()
    assert "Traceback" not in err, err[-2000:]
    assert code in (0, 130), (code, err[-2000:])
    if code == 130:      # in the console script's imports, or in the command's own (its KeyboardInterrupt)
        assert err.strip().splitlines()[-1] in (f"{argv[0]}: interrupted while starting",
                                                f"{' '.join(argv[:2])}: interrupted"), err[-2000:]


@pytest.mark.parametrize("argv", [["nao-skin", "record", "--help"], ["nao-skin", "stats", "--help"]],
                         ids=["record", "stats"])
def test_a_ctrl_c_as_a_console_script_ends_changes_nothing(tmp_path, argv):
    """Ctrl-C pressed again and again while ``nao-skin`` finishes: its output has been written, so the
    exit code stays the command's and nothing but its output is printed. CPython's own exit puts SIGINT
    back to its default before the process ends; a Ctrl-C then ended it by the signal (exit -2, what
    the command had printed still in its buffer)."""
    script = Path(sys.executable).parent / argv[0]
    env = {**ros_env(unique_domain_id()), "PYTHONUNBUFFERED": "1"}    # the help text is in the file at once
    proc = Proc([str(script), *argv[1:]], env, tmp_path, argv[0])
    try:
        deadline = time.monotonic() + 60
        while "usage:" not in proc.stdout() and proc.alive() and time.monotonic() < deadline:
            time.sleep(0.001)
        while proc.alive():                 # from the help text on, until the process is gone
            proc.popen.send_signal(signal.SIGINT)
            time.sleep(0.002)
        code = proc.popen.wait(timeout=30)
    finally:
        proc.stop()
    err = proc.stderr()
    assert "Traceback" not in err, err[-2000:]
    assert code in (0, 130), (code, err[-2000:])
    assert proc.stdout().startswith("usage: nao-skin"), proc.stdout()[:200]


def test_a_bag_removed_mid_session_is_rescued_and_record_does_not_say_nothing_was_recorded(tmp_path):
    """`rm -rf` of the bag being recorded: the recorder copies every touch to <bag>.rescued and ends the session
    (exit 2) saying so; record's "nothing was recorded" (for a session that ended before the recorder made its
    bag) must not follow it, and the copy reads as one with nothing lost."""
    import shutil

    with RecordingSession(tmp_path, seed=29) as run:
        shutil.rmtree(run.bag)
        code = run.session.popen.wait(timeout=60)
    err = run.session.stderr()
    rescued = tmp_path / "touches.rescued"
    assert code == 2 and "Traceback" not in err, err[-3000:]
    assert f"every touch written so far is copied to {rescued}" in err, err[-3000:]
    assert "nothing was recorded" not in err, err[-3000:]
    got, report = read_touches(rescued, load_skin())
    assert got.n_touches >= run.reported and not report.skipped, report.lines()


def test_a_simulated_robot_stopped_while_it_simulates_ends_without_playing(tmp_path):
    """sim_robot simulates its touches before it spins (seconds for many touches). A stop then (record killed,
    whose death reaches its nodes as SIGTERM) waited for the whole simulation: it outlived record by that
    long, and played to nobody (an adversarial review, 2026-11-28). Now the signal ends the simulation."""
    domain = unique_domain_id()
    listener = robot = None
    try:
        listener = Listener(domain)
        robot = node_process("sim_robot", {"touches_per_pair": 5000}, ros_env(domain), tmp_path)
        # the node exists (its participant is discovered) before it simulates: then the simulation is under way
        assert listener.spin_until(lambda: "sim_robot" in listener.node.get_node_names(), timeout=60,
                                   procs=[robot]), "sim_robot did not start"
        robot.popen.send_signal(signal.SIGTERM)
        code = robot.popen.wait(timeout=60)
    finally:
        if listener is not None:
            listener.close()
        if robot is not None:
            robot.stop()
    assert code == 0, robot.stderr()[-2000:]
    assert "simulated" not in robot.stderr(), robot.stderr()[-2000:]


def test_a_simulated_robot_stopped_part_way_says_stopped_not_done(tmp_path):
    """A record session stopped with Ctrl-C while its simulated robot plays: its last status says how many of
    the touches it played and that it was stopped, not ``done`` (it said done after a Ctrl-C with 191 of 240
    touches played, issue 51 item 7)."""
    domain = unique_domain_id()
    listener = session = None
    code = None
    try:
        listener = Listener(domain)
        sim = listener.subscribe(String, "/sim_robot/status", keep=lambda m: json.loads(m.data))
        session = Proc(record_cmd(tmp_path / "touches", seed=3, per_pair=20), ros_env(domain), tmp_path, "record")
        assert listener.spin_until(lambda: sim and sim[-1]["played"] >= 2, timeout=120, procs=[session]), sim[-1:]
        assert not sim[-1]["done"] and sim[-1]["played"] < sim[-1]["total"], sim[-1]
        code = session.stop(signal.SIGINT)
        listener.spin_for(1.0)       # what arrived while the session stopped
    finally:
        if listener is not None:
            listener.close()
        if session is not None and code is None:
            session.stop(signal.SIGINT)
    assert code == 0, session.stderr()[-3000:]
    last = sim[-1]
    assert last["done"] is False and last.get("stopped") is True, last
    assert 2 <= last["played"] < last["total"], last
