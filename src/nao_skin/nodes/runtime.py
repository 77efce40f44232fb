"""Starting and stopping nao_skin nodes: one place for rclpy set-up, parameters and clean shutdown.

Every node module has ``main(args=None)`` calling :func:`run_node`: it
initialises rclpy (``--ros-args`` from the command line, so ``ros2 run``,
``ros2 launch`` and ``nao-skin record`` pass parameters the same way), spins
until SIGINT/SIGTERM, then calls the node's ``close()`` so that buffered data
is written before the process ends.
"""
from __future__ import annotations

import signal
import sys
import threading

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

from ..errors import NaoSkinError


def declare(node, params: dict) -> dict:
    """Declare ``{name: (default, description)}`` and return ``{name: value}``."""
    out = {}
    for name, (default, text) in params.items():
        node.declare_parameter(name, default, ParameterDescriptor(description=text))
        value = node.get_parameter(name).value
        out[name] = value
    return out


def run_node(factory, args=None) -> int:
    """Create the node with ``factory()``, spin it, shut it down cleanly on SIGINT/SIGTERM."""
    rclpy.init(args=sys.argv if args is None else args, signal_handler_options=rclpy.SignalHandlerOptions.NO)
    stop = threading.Event()

    def on_signal(signum, frame):      # noqa: ARG001 - signal handler signature
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    node = None
    code = 0
    try:
        try:
            node = factory()
        except NaoSkinError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        # one thread: a node's callbacks never run concurrently (the recorder's detector is not
        # thread-safe); slow work (polling NAOqi, YARP reads, calibration) has its own threads
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        try:
            while not stop.is_set() and rclpy.ok():
                executor.spin_once(timeout_sec=0.1)
        except ExternalShutdownException:
            pass
        finally:
            executor.shutdown(timeout_sec=1.0)
    finally:
        if node is not None:
            close = getattr(node, "close", None)
            if close is not None:
                close()
            node.destroy_node()
        rclpy.try_shutdown()
    return code
