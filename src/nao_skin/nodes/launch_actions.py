"""What the launch files add to launch_ros' ``Node``: a nao_skin node that ends ends the launch, and a launch that
ends, however, ends its nodes as Ctrl-C does.

``ros2 launch`` goes on when a process dies, and exits 0: a recording session whose recorder refused its
parameters would run on without it, and a calibration that failed would look like one that worked. The
launch's exit code is not a node's; launch returns 1 when an action raises, so a node that failed raises.

launch 3.4.3 (Jazzy) stops its processes on SIGINT only: ``kill PID`` (SIGTERM) and a closed terminal (SIGHUP)
end the launch process at once (it installs no handler for them; its own SIGTERM handling cancels its run and
says "using SIGTERM can result in orphaned processes"), and SIGKILL always does: the nodes ran on, re-parented,
the recorder writing, and the session's claim of its ROS domain (held by the launch process) was released, so a
second session could start beside them. So :func:`stopping_as_on_ctrl_c` makes SIGTERM and SIGHUP shut the
launch down as SIGINT does, and :func:`watching_the_launch` gives our nodes the launch's pid: each stops by
itself, closing what it writes, once the launch is gone (the parent watch of ``nao-skin record``'s nodes).
"""
from __future__ import annotations

import os
import signal
import threading

from launch.actions import OpaqueFunction, RegisterEventHandler, Shutdown
from launch.event_handlers import OnProcessExit

from nao_skin.session.record import PARENT_ENV


class NodeEnded(RuntimeError):
    """A nao_skin node ended with an error while the launch ran: the launch ends with exit code 1."""


def ending_the_launch(node) -> list:
    """``[node, handler]``: when the node's process ends while the launch runs, the launch shuts down; with
    exit code 1 and one line naming the node when the node failed (its own line above says why)."""

    def on_exit(event, context):
        if context.is_shutdown:        # Ctrl-C or another node's end: the nodes' exits are part of it
            return None
        if event.returncode:
            raise NodeEnded(f"{event.process_name} ended with exit code {event.returncode}; the launch ends")
        return [Shutdown(reason=f"{event.process_name} ended")]

    return [node, RegisterEventHandler(OnProcessExit(target_action=node, on_exit=on_exit))]


def watching_the_launch() -> dict:
    """``additional_env`` of a node of ours: the launch process's pid, so that the node stops as on Ctrl-C when
    the launch is gone (SIGKILL, or a launch that ended without stopping it), as it does when ``nao-skin record``
    is (:func:`nao_skin.nodes.runtime.run_node`). Called in an OpaqueFunction: in the launch process."""
    return {PARENT_ENV: str(os.getpid())}


def stopping_as_on_ctrl_c() -> OpaqueFunction:
    """An action making SIGTERM and SIGHUP shut the launch down as SIGINT does: each process is sent SIGINT
    (then launch's own SIGTERM and SIGKILL after its timeouts) and the launch waits for them, so its exit code
    and the nodes' last lines come as after Ctrl-C. A second SIGTERM does what launch does without this (it ends
    its run at once; the nodes then stop by themselves), a second SIGHUP nothing.

    launch reads signals through its ``AsyncSafeSignalManager`` (Python's wakeup fd): a handler added to the
    asyncio loop runs only after launch's own SIGTERM handler has cancelled the run, so the handler goes to
    that manager, which launch 3.4.3 keeps in a class attribute. Where it is not found (another launch), nothing
    changes: the nodes still stop by themselves once the launch is gone (:func:`watching_the_launch`)."""
    return OpaqueFunction(function=_install_stop_signals)


def _install_stop_signals(context):
    import launch.logging
    from launch.events import Shutdown as ShutdownEvent
    from launch.utilities.signal_management import AsyncSafeSignalManager

    manager = getattr(AsyncSafeSignalManager, "_AsyncSafeSignalManager__current", None)
    if manager is None or not hasattr(manager, "handle") or threading.current_thread() is not threading.main_thread():
        return None       # (Python sets signal handlers in the main thread only, where ros2 launch runs)
    logger = launch.logging.get_logger("launch")

    def stopper(before):
        received = []

        def stop(signum):
            if received:               # again: as launch does without us (its own handler, else nothing)
                if before is not None:
                    before(signum)
                return
            received.append(signum)
            name = signal.Signals(signum).name
            logger.warning(f"{name}: the nodes are stopped as at Ctrl-C")
            # not due to SIGINT: the processes did not get this signal from a terminal, so each is sent SIGINT
            context.emit_event_sync(ShutdownEvent(reason=name, due_to_sigint=False))
        return stop

    for signum in (signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(signum) == signal.SIG_IGN:    # e.g. SIGHUP under nohup: stays ignored
            continue
        before = manager.handle(signum, None)
        manager.handle(signum, stopper(before))
        if signal.getsignal(signum) == signal.SIG_DFL:
            # a Python-level handler, so that the signal reaches the manager (through Python's wakeup fd)
            # instead of ending the process
            signal.signal(signum, _noop)
    return None


def _noop(signum, frame):      # noqa: ARG001 - signal handler signature
    pass


def installed(package: str) -> bool:
    """Whether ``ros2 run`` finds the package (robot_state_publisher, rviz2: not in every install)."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        get_package_prefix(package)
    except PackageNotFoundError:
        return False
    return True
