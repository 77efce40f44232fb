"""A second publisher on a skin topic: the recorder says so once, over real DDS.

Two record sessions on one ROS_DOMAIN_ID (two robots in one lab, the defaults everywhere) hear each
other: the other robot's skin samples would be recorded as this one's touches. One bridge (or one
simulated robot) publishes a part's skin, so the recorder names every publisher of a topic that has
more than one and asks for a domain of each robot's own. Here a test node publishes /skin/l_hand/taxels
from two nodes, as a second session would, to a real pairing_recorder.
"""
from __future__ import annotations

import time

import pytest
from ros_harness import Listener, node_process, ros_env, unique_domain_id

pytest.importorskip("rclpy")
import rclpy  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from nao_skin.formats.pointcloud import taxels_topic  # noqa: E402
from nao_skin.nodes.topics import PROGRESS_TOPIC  # noqa: E402

pytestmark = pytest.mark.middleware


def test_the_recorder_names_a_second_publisher_of_a_skin_topic_once(tmp_path):
    domain = unique_domain_id()
    listener = recorder = other = None
    try:
        listener = Listener(domain)
        recorder = node_process("pairing_recorder", {"bag_path": str(tmp_path / "touches")}, ros_env(domain),
                                tmp_path)
        listener.node.create_publisher(PointCloud2, taxels_topic("torso"), 10)     # one publisher: fine
        listener.node.create_publisher(PointCloud2, taxels_topic("l_hand"), 10)
        progress = listener.subscribe(String, PROGRESS_TOPIC)
        assert listener.spin_until(lambda: len(progress) >= 4, procs=[recorder]), recorder.stderr()[-2000:]
        assert "publishers" not in recorder.stderr()     # one publisher per topic so far
        other = rclpy.create_node("other_session_bridge", context=listener.context)
        other.create_publisher(PointCloud2, taxels_topic("l_hand"), 10)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and recorder.alive() and "publishers" not in recorder.stderr():
            listener.spin_for(0.2)
        listener.spin_for(3.0)     # more progress checks: still said once
        err = recorder.stderr()
    finally:
        if other is not None:
            other.destroy_node()
        if listener is not None:
            listener.close()
        if recorder is not None:
            recorder.stop()
    said = [line for line in err.splitlines() if "publishers" in line]
    assert len(said) == 1, err[-2000:]
    assert f"{taxels_topic('l_hand')} has 2 publishers" in said[0]
    assert "/other_session_bridge" in said[0] and f"ROS_DOMAIN_ID ({domain})" in said[0]
    assert taxels_topic("torso") not in err and "Traceback" not in err
