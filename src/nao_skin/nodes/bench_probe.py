"""The listener of ``nao-skin bench-live``: what the live suite delivers, counted as it arrives.

Not a node a session runs: the benchmark makes one in its own process, on the
session's private domain, and spins it between its checks.
"""
from __future__ import annotations

import json
import os
import time

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState, PointCloud2
from std_msgs.msg import String
from visualization_msgs.msg import MarkerArray

from nao_skin.formats.pointcloud import JOINT_STATES_TOPIC, taxels_topic
from nao_skin.nodes.topics import HEATMAP_TOPIC, LATCHED, PROGRESS_TOPIC, STATUS_TOPIC, relative


class LiveProbe:
    """Counts joint states and one part's skin messages, keeps the recorder's progress, the calibrate node's
    statuses ``(when, status)`` and the heat-map's messages ``(when, taxels shown)``."""

    def __init__(self, domain: int, skin_parts, counted_part: str):
        self.skin_parts = set(skin_parts)
        self.counts = {"joints": 0, "skin": 0}
        self.progress, self.updates, self.heat = [], [], []
        self.context = Context()
        # rclpy's own signal handler would shut the context down and let the window run on: the benchmark
        # handles the signals. The probe is found on this host only, as the nodes are (rcl reads it at init).
        discovery = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE")
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        try:
            rclpy.init(context=self.context, domain_id=domain, signal_handler_options=rclpy.SignalHandlerOptions.NO)
        finally:
            if discovery is None:
                os.environ.pop("ROS_AUTOMATIC_DISCOVERY_RANGE")
            else:
                os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = discovery
        self.node = Node("bench_live", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        node = self.node
        node.create_subscription(JointState, relative(JOINT_STATES_TOPIC), lambda m: self._count("joints"), 200)
        node.create_subscription(PointCloud2, relative(taxels_topic(counted_part)), lambda m: self._count("skin"), 200)
        node.create_subscription(String, PROGRESS_TOPIC, lambda m: self.progress.append(json.loads(m.data)), 10)
        node.create_subscription(String, STATUS_TOPIC,
                                 lambda m: self.updates.append((time.monotonic(), json.loads(m.data))), LATCHED)
        node.create_subscription(MarkerArray, HEATMAP_TOPIC, self._on_heat, 10)

    def _count(self, what: str) -> None:
        self.counts[what] += 1

    def _on_heat(self, msg) -> None:
        self.heat.append((time.monotonic(), sum(len(m.points) for m in msg.markers if m.ns in self.skin_parts)))

    def spin_once(self, timeout: float = 0.05) -> None:
        self.executor.spin_once(timeout_sec=timeout)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()
