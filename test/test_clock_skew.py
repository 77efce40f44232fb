"""The skin and the joints on different clocks: the recorder says so, once per skin topic, over real DDS.

When skinManager's host keeps another clock than the PC stamping ``/joint_states``, every touch
would silently take the arm pose of another moment (joint states arrive all the time, so the joint
tolerance cannot tell). Here a test node publishes joint states stamped now and two parts' skin
samples stamped 3 s in the past, a third part's stamped now, all at once, to a real
pairing_recorder: its progress reports each skin topic's lag behind the joint states, and its log
warns for the two late ones only.
"""
from __future__ import annotations

import json
import time

import numpy as np
import pytest
from ros_harness import Listener, node_process, ros_env, unique_domain_id

from nao_skin.live.clocks import MIN_MESSAGES, SKEW_LIMIT_S, ArrivalLags

pytest.importorskip("rclpy")
from sensor_msgs.msg import JointState, PointCloud2  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from nao_skin.formats.pointcloud import JOINT_STATES_TOPIC, taxels_array, taxels_topic  # noqa: E402
from nao_skin.nodes.messages import cloud_from_array, joint_state_msg, stamp_to_msg  # noqa: E402
from nao_skin.nodes.topics import PROGRESS_TOPIC  # noqa: E402

BEHIND_S = 3.0


def test_arrival_lags_compare_each_stream_with_the_reference():
    lags = ArrivalLags()
    for i in range(MIN_MESSAGES - 1):
        lags.add("joints", 100.0 + i, 100.002 + i)
        lags.add("skin", 97.0 + i, 100.003 + i)
    assert lags.skew("joints") == {}                      # too few messages to judge yet
    lags.add("joints", 200.0, 200.002)
    lags.add("skin", 197.0, 200.003)
    lags.add("skin", 0.0, 200.0)                          # one outlier does not move a median
    assert lags.skew("joints") == pytest.approx({"skin": 3.001})
    assert ArrivalLags().skew("joints") == {}


def test_a_queue_is_no_other_clock_and_a_stamp_from_the_future_decides_nothing():
    """Messages that waited in a queue arrive late whatever their clock: the joint states of a busy
    start-up, 0.8 s late for most of a window, are on the skin's clock all the same."""
    lags = ArrivalLags()
    for i in range(40):
        lags.add("joints", 100.0 + i, 100.8 + i)          # queued
        lags.add("skin", 100.0 + i, 100.003 + i)
    for i in range(40, 50):
        lags.add("joints", 100.0 + i, 100.002 + i)        # the queue drained
        lags.add("skin", 100.0 + i, 100.003 + i)
    assert abs(lags.skew("joints")["skin"]) < 0.01
    lags.add("skin", 300.0, 150.0)                        # one stamp 150 s ahead of its arrival
    assert abs(lags.skew("joints")["skin"]) < 0.01


@pytest.mark.middleware
def test_the_recorder_warns_when_a_skin_topic_is_stamped_by_another_clock(tmp_path, skin):
    domain = unique_domain_id()
    listener = recorder = None
    try:
        listener = Listener(domain)
        progress = listener.subscribe(String, PROGRESS_TOPIC, keep=lambda m: json.loads(m.data))
        recorder = node_process("pairing_recorder", {"bag_path": str(tmp_path / "touches")}, ros_env(domain),
                                tmp_path)
        joints = listener.node.create_publisher(JointState, JOINT_STATES_TOPIC, 50)
        late = {"l_hand": BEHIND_S, "torso": BEHIND_S, "r_hand": 0.0}
        clouds = {p: listener.node.create_publisher(PointCloud2, taxels_topic(p), 50) for p in late}
        released = taxels_array(np.zeros(0, int), np.zeros((0, 3)))
        names = list(skin.robot.joint_names)

        def skewed():
            skew = progress[-1].get("clock_skew_s", {}) if progress else {}
            return {taxels_topic(p) for p in late} <= set(skew)

        def warned():
            return recorder.stderr().count(" is stamped ") >= sum(b > SKEW_LIMIT_S for b in late.values())

        def publish_until(done, timeout: float) -> None:
            deadline = time.monotonic() + timeout
            while not done() and time.monotonic() < deadline and recorder.alive():
                now = time.time()
                joints.publish(joint_state_msg(names, np.zeros(len(names)), stamp_to_msg(now)))
                for part, behind in late.items():
                    clouds[part].publish(cloud_from_array(released, skin.parts[part].parent_frame,
                                                          stamp_to_msg(now - behind)))
                listener.spin_for(0.02)

        publish_until(skewed, 60)
        assert skewed(), (progress[-1:], recorder.stderr()[-2000:])
        publish_until(warned, 20)   # the warnings come with the second progress in a row that shows the skew
    finally:
        if listener is not None:
            listener.close()
        if recorder is not None:
            recorder.stop()
    skew = progress[-1]["clock_skew_s"]
    for part, behind in late.items():
        assert skew[taxels_topic(part)] == pytest.approx(behind, abs=0.2), skew
    err = recorder.stderr()
    assert "Traceback" not in err
    for part, behind in late.items():
        said = [line for line in err.splitlines() if f"{taxels_topic(part)} is stamped" in line]
        if behind > SKEW_LIMIT_S:
            assert len(said) == 1 and f"stamped {behind:.2f} s behind {JOINT_STATES_TOPIC}" in said[0], err[-2000:]
            assert "stamp:=receive" in said[0]
        else:
            assert not said, said
