"""What the launch files add to launch_ros' ``Node``: a nao_skin node that ends ends the launch.

``ros2 launch`` goes on when a process dies, and exits 0: a recording session whose recorder refused its
parameters would run on without it, and a calibration that failed would look like one that worked. The
launch's exit code is not a node's; launch returns 1 when an action raises, so a node that failed raises.
"""
from __future__ import annotations

from launch.actions import RegisterEventHandler, Shutdown
from launch.event_handlers import OnProcessExit


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


def installed(package: str) -> bool:
    """Whether ``ros2 run`` finds the package (robot_state_publisher, rviz2: not in every install)."""
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        get_package_prefix(package)
    except PackageNotFoundError:
        return False
    return True
