"""Helpers for tests that run real nodes over real DDS: processes, listeners, bounded waits.

* every test gets its own ROS domain id (pid-derived, so parallel runs on
  one machine do not cross-talk) and localhost-only discovery;
* nodes run as subprocesses in their own process group, stopped with SIGINT
  (then SIGKILL of the group) in ``finally`` blocks: nothing outlives a test;
* waits are bounded and poll a predicate; nothing asserts on wall-clock time.
"""
from __future__ import annotations

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
_counter = itertools.count()


def unique_domain_id() -> int:
    """A domain id in 10..99 from the pid and a counter (valid DDS port range)."""
    return 10 + (os.getpid() * 13 + next(_counter) * 7) % 90


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

    def close(self) -> None:
        try:
            self.executor.shutdown(timeout_sec=1.0)
        finally:
            self.node.destroy_node()
            self.context.try_shutdown()
