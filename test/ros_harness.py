"""Helpers for tests that run real nodes over real DDS: processes, listeners, bounded waits.

* every test gets its own ROS domain id and localhost-only discovery: the id is
  claimed with a lock in /tmp for as long as the test runs, so the pytest-xdist
  workers of one run, and other runs on the machine, never share one (two
  tests on one domain hear each other's messages, and their record sessions
  refuse each other's domain claim);
* nodes run as subprocesses in their own process group, stopped with SIGINT
  (then SIGKILL of the group) in ``finally`` blocks: nothing outlives a test;
* waits are bounded and poll a predicate; nothing asserts on wall-clock time.
"""
from __future__ import annotations

import fcntl
import itertools
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from nao_skin.session.record import param_text

ROOT = Path(__file__).resolve().parents[1]
WAIT_S = 20.0                      # generous upper bound for a 2-core CI machine; polls end much earlier
ASK_AGAIN_S = 2.0                  # a service request unanswered this long is sent again (Listener.ask)
_counter = itertools.count()
TEST_DOMAINS = range(10, 100)      # their DDS ports (7400 + 250 * id ...) stay below the ephemeral ports
_held_domains: dict[int, int] = {}   # domain id -> descriptor of its flocked test lock file


def _test_lock(domain: int) -> Path:
    return Path("/tmp") / f"nao_skin_test_domain_{domain}.lock"


def _flocked_inodes() -> set:
    """Inodes of the files someone holds a flock on (/proc/locks: read, so that no claim is disturbed)."""
    try:
        lines = Path("/proc/locks").read_text().splitlines()
    except OSError:
        return set()
    inodes = set()
    for line in lines:
        fields = line.split()
        if "FLOCK" in fields and len(fields) >= 6:
            for f in fields:
                if f.count(":") == 2:          # MAJ:MIN:INODE
                    inodes.add(int(f.rsplit(":", 1)[1]))
                    break
    return inodes


def _session_holds(domain: int, flocked: set) -> bool:
    """A running record session (or launch) claims ``domain`` (nao_skin.session.claim's lock is held)."""
    from nao_skin.session.claim import lock_path

    try:
        return os.stat(lock_path(domain)).st_ino in flocked
    except OSError:
        return False


def unique_domain_id() -> int:
    """A domain id in 10..99 that no other test on this machine uses while this one runs: an exclusive flock
    on ``/tmp/nao_skin_test_domain_<id>.lock`` (the kernel drops it if the process dies), released by
    :func:`release_domains` when the test ends (conftest.py), and no record session claims (test or not)."""
    flocked = _flocked_inodes()
    start = os.getpid() * 13 + next(_counter) * 7        # spread the searches of parallel workers
    for k in range(len(TEST_DOMAINS)):
        domain = TEST_DOMAINS[(start + k) % len(TEST_DOMAINS)]
        if domain in _held_domains or _session_holds(domain, flocked):
            continue
        fd = os.open(_test_lock(domain), os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        _held_domains[domain] = fd
        return domain
    raise RuntimeError(f"every ROS domain in {TEST_DOMAINS} is taken by running tests or sessions")


def release_domains() -> None:
    """Give back the domains this process's test claimed (its nodes have been stopped)."""
    while _held_domains:
        _, fd = _held_domains.popitem()
        os.close(fd)


def ros_env(domain_id: int, **extra) -> dict:
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               RMW_IMPLEMENTATION="rmw_fastrtps_cpp", PYTHONUNBUFFERED="1")
    env.pop("ROS_STATIC_PEERS", None)
    src = str(ROOT / "src")
    env["PYTHONPATH"] = src + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.update({k: str(v) for k, v in extra.items()})
    return env


class Proc:
    """A subprocess in its own process group, with its output in files."""

    def __init__(self, argv, env, log_dir: Path, name: str, preexec_fn=None):
        self.name = name
        self.out_path = Path(log_dir) / f"{name}.out"
        self.err_path = Path(log_dir) / f"{name}.err"
        self._out = open(self.out_path, "wb")
        self._err = open(self.err_path, "wb")
        self.popen = subprocess.Popen(argv, env=env, stdout=self._out, stderr=self._err, cwd=str(ROOT),
                                      start_new_session=True, preexec_fn=preexec_fn)

    def alive(self) -> bool:
        return self.popen.poll() is None

    def send(self, sig) -> None:
        if self.alive():
            try:
                os.killpg(self.popen.pid, sig)
            except ProcessLookupError:
                pass

    def stop(self, sig=signal.SIGINT, timeout: float = 15.0):
        """Signal the group, wait, SIGKILL what is left. Returns the exit code."""
        self.send(sig)
        try:
            self.popen.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.send(signal.SIGKILL)
            self.popen.wait(timeout=5.0)
        finally:
            try:                          # helpers the process started in its group
                os.killpg(self.popen.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
            self._out.close()
            self._err.close()
        return self.popen.returncode

    def stderr(self) -> str:
        if not self._err.closed:
            self._err.flush()
        return self.err_path.read_text(errors="replace")

    def stdout(self) -> str:
        if not self._out.closed:
            self._out.flush()
        return self.out_path.read_text(errors="replace")


def node_process(module: str, params: dict, env, log_dir, name: str | None = None, params_file=None) -> Proc:
    """``python -m nao_skin.nodes.<module> --ros-args ...`` as a :class:`Proc`."""
    argv = [sys.executable, "-m", f"nao_skin.nodes.{module}", "--ros-args"]
    if params_file:
        argv += ["--params-file", str(params_file)]
    for k, v in params.items():
        argv += ["-p", f"{k}:={param_text(v)}"]   # as nao-skin record writes them
    return Proc(argv, env, log_dir, name or module)


class Listener:
    """An rclpy node in its own context (own DDS participant) on the test's domain."""

    def __init__(self, domain_id: int, name: str = "test_listener"):
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        os.environ["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
        os.environ.pop("ROS_STATIC_PEERS", None)
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def subscribe(self, msg_type, topic: str, qos=100, keep=None) -> list:
        """Subscribe; returns the list the messages are appended to (``keep`` maps a message first)."""
        got: list = []
        self.node.create_subscription(msg_type, topic, (lambda m: got.append(keep(m) if keep else m)), qos)
        return got

    def spin_until(self, predicate, timeout: float = WAIT_S, procs=()) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            for p in procs:
                if not p.alive():
                    raise AssertionError(f"{p.name} exited with {p.popen.returncode}: {p.stderr()[-2000:]}")
            self.executor.spin_once(timeout_sec=0.05)
        return bool(predicate())

    def spin_for(self, duration: float) -> None:
        deadline = time.monotonic() + duration
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)

    def ask(self, client, request, procs=(), timeout: float = 60.0):
        """The reply to ``request`` (one a node may answer twice: asking is all it does, as GetParameters)
        through ``client``, sent again while unanswered. A service counts as ready once the client's request
        reaches it, which can be before its reply writer has found the client: the reply then goes to
        nobody, and only asking again gets one (docs/decisions.md, "A service reply that went to nobody")."""
        deadline = time.monotonic() + timeout
        assert self.spin_until(client.service_is_ready, timeout=timeout, procs=procs), f"{client.srv_name}: no service"
        while True:
            future = client.call_async(request)
            if self.spin_until(future.done, timeout=min(ASK_AGAIN_S, max(0.0, deadline - time.monotonic())),
                               procs=procs):
                return future.result()
            client.remove_pending_request(future)
            assert time.monotonic() < deadline, f"{client.srv_name}: no answer in {timeout:g} s"

    def close(self) -> None:
        try:
            self.executor.shutdown(timeout_sec=1.0)
        finally:
            self.node.destroy_node()
            self.context.try_shutdown()
