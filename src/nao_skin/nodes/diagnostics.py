"""Every node's ``/diagnostics``: one ``diagnostic_msgs/DiagnosticStatus`` a second, what rqt_robot_monitor shows.

A node hands :func:`publish_diagnostics` a function returning its findings
(:class:`~nao_skin.live.diagnostics.Check` list, from the pure checks there); this only translates them,
as ``nao_skin: <node's fully qualified name>`` (``nao_skin: /nao2/calibrate``) with the node's ``hardware_id``,
on the ROS clock's stamp. ``/diagnostics`` is one topic for every namespace, so two robots' sessions on one
domain (``namespace:=``) are told apart by the name alone, as diagnostic_updater's ``use_fqn`` names them.
"""
from __future__ import annotations

import socket
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from nao_skin.errors import one_line
from nao_skin.live.diagnostics import ERROR, Check, summary
from nao_skin.nodes.topics import DIAGNOSTICS_TOPIC

PERIOD_S = 1.0
_LEVELS = {0: DiagnosticStatus.OK, 1: DiagnosticStatus.WARN, 2: DiagnosticStatus.ERROR}


def publish_diagnostics(node, checks, hardware_id: str = ""):
    """Publish ``checks(now)``'s findings (``now``: monotonic seconds) every second; returns the timer.
    A check that raises is an ERROR status saying so, never a node stopped for its diagnostics."""
    publisher = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
    name = f"nao_skin: {node.get_fully_qualified_name()}"
    hardware = hardware_id or socket.gethostname()

    def tick():
        try:
            found = list(checks(time.monotonic()))
        except Exception as exc:     # noqa: BLE001 - diagnostics say what broke, the node goes on
            found = [Check(ERROR, f"diagnostics failed: {one_line(exc)}")]
        level, message, values = summary(found)
        status = DiagnosticStatus(level=_LEVELS[level], name=name, message=message, hardware_id=hardware,
                                  values=[KeyValue(key=k, value=v) for k, v in values])
        array = DiagnosticArray(status=[status])
        array.header.stamp = node.get_clock().now().to_msg()
        publisher.publish(array)

    return node.create_timer(PERIOD_S, tick)
