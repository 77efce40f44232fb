"""What arrives on a topic is anybody's: nodes skip a malformed message and stay up, over real DDS.

The heat-map node reads the guidance and the calibration status, the simulated robot (guided) the
guidance, the calibrate node the recorder's progress; each is fed messages of the wrong shape (a
triangle id that is a string or infinite, a state that is a mapping, a progress that is a list), then a
good one, which must still take effect. Each node stops with exit 0 and no traceback.
"""
from __future__ import annotations

import json
import time

import numpy as np
import pytest
from ros_harness import Listener, node_process, ros_env, unique_domain_id

pytest.importorskip("rclpy")
from rcl_interfaces.msg import Parameter as ParameterMsg  # noqa: E402
from rcl_interfaces.msg import ParameterValue  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402
from sensor_msgs.msg import JointState, PointCloud2  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from visualization_msgs.msg import MarkerArray  # noqa: E402

from nao_skin.errors import DataError  # noqa: E402
from nao_skin.formats.bag import read_touches  # noqa: E402
from nao_skin.formats.pointcloud import JOINT_STATES_TOPIC, taxels_array, taxels_topic  # noqa: E402
from nao_skin.guidance.capture import targets_from_json  # noqa: E402
from nao_skin.nodes.messages import cloud_from_array, joint_state_msg, stamp_to_msg  # noqa: E402
from nao_skin.nodes.topics import (GUIDANCE_MARKERS_TOPIC, GUIDANCE_TOPIC, LATCHED, PROGRESS_TOPIC,  # noqa: E402
                                   SIM_STATUS_TOPIC, STATUS_TOPIC)

GOOD = {"part": "torso", "triangle_id": 3, "hand": "l_hand", "touched": "torso", "reason": "held",
        "hand_triangle_id": None, "touched_triangle_id": 3, "pose": {"LShoulderPitch": 0.5}}
BAD_TARGETS = [{"part": "head", "triangle_id": "x"}, {**GOOD, "triangle_id": float("inf")},
               {**GOOD, "triangle_id": 999}, {**GOOD, "part": "l_arm"}, {**GOOD, "hand": ["l_hand"]}, "torso", None]


def test_the_guidance_parser_keeps_this_skins_targets_and_counts_the_rest(skin):
    text = json.dumps({"targets": [GOOD, *BAD_TARGETS, {**GOOD, "pose": {"LShoulderPitch": "up"}},
                                   {**GOOD, "touched_triangle_id": True}]})
    targets, skipped = targets_from_json(text, skin)
    assert skipped == len(BAD_TARGETS)
    assert targets[0] == GOOD
    assert targets[1]["pose"] is None and targets[2]["touched_triangle_id"] is None   # unusable fields dropped
    for text in ("{", "[]", '{"targets": 3}', "[" * 100_000 + "]" * 100_000):     # the last: RecursionError
        with pytest.raises(DataError):
            targets_from_json(text, skin)
    # an integer of 400 digits is JSON, but no angle: the pose is dropped (it was an OverflowError that
    # lost the message's valid targets)
    huge = json.dumps({"targets": [GOOD]}).replace('"LShoulderPitch": 0.5', '"LShoulderPitch": ' + "9" * 400)
    (target,), skipped = targets_from_json(huge, skin)
    assert target["pose"] is None and skipped == 0


def test_the_guidance_parser_reads_the_first_targets_only(skin):
    """20000 targets held the heat-map node for 7 s and drew 40000 markers."""
    targets, skipped = targets_from_json(json.dumps({"targets": [GOOD] * 20_000}), skin)
    assert len(targets) == 100 and skipped == 0


@pytest.mark.middleware
def test_rviz_tells_targets_no_pose_reaches_and_the_robot_plays_no_more_than_its_touches(tmp_path):
    """Targets without a pose were drawn and labelled as reachable ones; a guided robot told to start with more
    random touches than it has played them all (43 of 8)."""
    from nao_skin.live.heatmap import GUIDANCE_COLOUR
    from nao_skin.nodes.skin_heatmap import UNREACHED_ALPHA

    domain = unique_domain_id()
    env = ros_env(domain)
    listener = None
    nodes = []
    try:
        listener = Listener(domain)
        markers = listener.subscribe(MarkerArray, GUIDANCE_MARKERS_TOPIC, qos=LATCHED)
        robot = listener.subscribe(String, SIM_STATUS_TOPIC, keep=lambda m: json.loads(m.data))
        nodes = [node_process("skin_heatmap", {}, env, tmp_path),
                 node_process("sim_robot", {"guided": True, "touches_per_pair": 2, "guided_start": 40,
                                            "pairs": ["l_hand-torso"], "touch_period": 0.6,
                                            "wait_for_subscribers": 0}, env, tmp_path)]
        guidance = listener.node.create_publisher(String, GUIDANCE_TOPIC, LATCHED)
        assert listener.spin_until(lambda: guidance.get_subscription_count() >= 2, timeout=60, procs=nodes)
        guidance.publish(String(data=json.dumps({"targets": [GOOD, {**GOOD, "triangle_id": 4, "pose": None}]})))
        labels = lambda: {m.text: m.color.a for m in markers[-1].markers if m.ns == "guidance_label"} \
            if markers else {}  # noqa: E731
        assert listener.spin_until(lambda: len(labels()) == 2, timeout=30, procs=nodes), labels()
        assert listener.spin_until(lambda: robot and robot[-1]["done"], timeout=30, procs=nodes), robot[-1:]
    finally:
        if listener is not None:
            listener.close()
        codes = [node.stop() for node in nodes]
    assert labels() == {"1: torso triangle 3 with l_hand (held)": GUIDANCE_COLOUR[3],
                        "2: torso triangle 4 with l_hand (held; no pose reaches it)": pytest.approx(UNREACHED_ALPHA)}
    # the simulator records a touch twice now and then (a defect it plays as a robot's): at most one more
    assert robot[-1]["total"] == 2 and robot[-1]["played"] <= 3 and robot[-1]["done"], robot[-1]
    assert robot[-1]["aimed"] == 0 and robot[-1]["missed_aims"] == 0, robot[-1]
    assert codes == [0, 0], [node.stderr()[-2000:] for node in nodes]


@pytest.mark.middleware
def test_nodes_skip_malformed_messages_and_stay_up(tmp_path):
    domain = unique_domain_id()
    env = ros_env(domain)
    listener = None
    nodes = []
    try:
        listener = Listener(domain)
        markers = listener.subscribe(MarkerArray, GUIDANCE_MARKERS_TOPIC, qos=LATCHED)
        nodes = [node_process("skin_heatmap", {}, env, tmp_path),
                 node_process("sim_robot", {"guided": True, "touches_per_pair": 2, "guided_start": 1,
                                            "pairs": ["l_hand-torso"], "touch_period": 0.6}, env, tmp_path),
                 node_process("calibrate", {"live": True, "recording": str(tmp_path / "none"),
                                            "out_dir": str(tmp_path / "out")}, env, tmp_path)]
        publish = {topic: listener.node.create_publisher(String, topic, LATCHED if topic != PROGRESS_TOPIC else 10)
                   for topic in (GUIDANCE_TOPIC, STATUS_TOPIC, PROGRESS_TOPIC)}
        listener.spin_until(lambda: all(p.get_subscription_count() > 0 for p in publish.values()), timeout=60,
                            procs=nodes)
        deep = "[" * 100_000 + "]" * 100_000
        bad = {GUIDANCE_TOPIC: ["{", "[]", json.dumps({"targets": BAD_TARGETS}), deep],
               STATUS_TOPIC: ["{", json.dumps({"parts": {"head": {"a": 1}, "torso": ["done"]}}),
                              json.dumps({"parts": [1]}), deep],
               PROGRESS_TOPIC: ["[]", json.dumps({"touches": 1e400}), json.dumps({"touches": "many"}),
                                json.dumps({"touches": -4}), deep]}
        for topic, texts in bad.items():
            for text in texts:
                publish[topic].publish(String(data=text))
                listener.spin_for(0.2)
        # a good guidance and status after them still reach the markers
        publish[GUIDANCE_TOPIC].publish(String(data=json.dumps({"targets": [GOOD]})))
        publish[STATUS_TOPIC].publish(String(data=json.dumps({"parts": {"torso": "converging"}})))
        shown = lambda: markers and {(m.ns, m.text) for m in markers[-1].markers} >= {  # noqa: E731
            ("state", "torso: converging")} and any(m.ns == "guidance" for m in markers[-1].markers)
        assert listener.spin_until(shown, timeout=30, procs=nodes), [m.ns for m in markers[-1].markers]
        listener.spin_for(1.0)
        for node in nodes:
            assert node.alive(), f"{node.name}: {node.stderr()[-2000:]}"
    finally:
        if listener is not None:
            listener.close()
        codes = [node.stop() for node in nodes]
    for node, code in zip(nodes, codes):
        assert code == 0 and "Traceback" not in node.stderr(), f"{node.name} {code}: {node.stderr()[-2000:]}"
        # each message is judged by the node itself, not left to the last resort of run_node
        assert "a callback failed" not in node.stderr(), f"{node.name}: {node.stderr()[-2000:]}"
    # and said (a malformed status or progress had been dropped without a word)
    heatmap, _, calibrate = nodes
    assert f"skipped a malformed {STATUS_TOPIC} message ('{{'" in heatmap.stderr(), heatmap.stderr()[-2000:]
    assert f"skipped a malformed {PROGRESS_TOPIC} message ('[]'" in calibrate.stderr(), calibrate.stderr()[-2000:]


def _press(skin, part: str, n: int = 4):
    """``n`` present taxel slots of ``part`` with their nominal positions, pressed."""
    slots = np.flatnonzero(skin.parts[part].present)[:n]
    return taxels_array(slots, skin.parts[part].taxel_positions(None)[0][slots], np.full(n, 40.0),
                        np.zeros(n, int))


@pytest.mark.middleware
def test_the_recorder_outlives_a_malformed_request_and_unplaceable_stamps_and_keeps_every_touch(tmp_path, skin):
    """A SetParameters request rclpy's own service cannot parse (type 99) ended the node with a traceback,
    and with it a record session; a negative stamp crashed the bag writer; joint states naming only the
    head's joints (a second driver) cost every touch near them. Each is skipped now, or merged per
    joint, and every touch of the session is in the bag."""
    domain = unique_domain_id()
    listener = recorder = None
    bag = tmp_path / "touches"
    names = list(skin.robot.joint_names)
    head = ["HeadYaw", "HeadPitch"]
    n_touches = 6
    try:
        listener = Listener(domain)
        recorder = node_process("pairing_recorder", {"bag_path": str(bag), "flush_period": 0.2}, ros_env(domain),
                                tmp_path)
        joints = listener.node.create_publisher(JointState, JOINT_STATES_TOPIC, 100)
        clouds = {p: listener.node.create_publisher(PointCloud2, taxels_topic(p), 100) for p in ("l_hand", "torso")}
        setter = listener.node.create_client(SetParameters, "/pairing_recorder/set_parameters")
        assert listener.spin_until(lambda: setter.service_is_ready() and all(
            c.get_subscription_count() > 0 for c in clouds.values()), timeout=60, procs=[recorder])

        def ask(name: str, value: ParameterValue):
            future = setter.call_async(SetParameters.Request(parameters=[ParameterMsg(name=name, value=value)]))
            listener.spin_until(future.done, timeout=3)
            return future.result()

        assert ask("flush_period", ParameterValue(type=99)) is None     # no answer, and the node goes on
        refused = ask("flush_period", ParameterValue(type=3, double_value=2.0)).results[0]
        assert not refused.successful and "read when the node starts" in refused.reason, refused.reason

        released = taxels_array(np.zeros(0, int), np.zeros((0, 3)))
        frame = {p: skin.parts[p].parent_frame for p in clouds}
        base = time.time()
        for k in range(n_touches):
            t = base + 0.6 * k
            for dt in (-0.05, -0.02, 0.02, 0.05):     # full joint states, each followed by a head-only one
                joints.publish(joint_state_msg(names, np.zeros(len(names)), stamp_to_msg(t + dt)))
                joints.publish(joint_state_msg(head, np.zeros(2), stamp_to_msg(t + dt + 0.005)))
            joints.publish(joint_state_msg(names, np.full(len(names), np.nan), stamp_to_msg(t + 0.01)))
            joints.publish(joint_state_msg(names, np.zeros(len(names)), stamp_to_msg(-0.5)))
            for part, pub in clouds.items():
                pub.publish(cloud_from_array(_press(skin, part), frame[part], stamp_to_msg(t)))
            listener.spin_for(0.05)
            # a released sample without a stamp, and one before 1970, in the middle of the press
            clouds["torso"].publish(cloud_from_array(released, frame["torso"], None))
            clouds["l_hand"].publish(cloud_from_array(_press(skin, "l_hand"), frame["l_hand"], stamp_to_msg(-0.5)))
            for part, pub in clouds.items():
                pub.publish(cloud_from_array(released, frame[part], stamp_to_msg(t + 0.3)))
            joints.publish(joint_state_msg(names, np.zeros(len(names)), stamp_to_msg(t + 0.35)))
            listener.spin_for(0.1)
        listener.spin_for(1.0)
        assert recorder.alive(), recorder.stderr()[-2000:]
    finally:
        if listener is not None:
            listener.close()
        code = recorder.stop() if recorder is not None else None
    err = recorder.stderr()
    assert code == 0 and "Traceback" not in err, err[-3000:]
    assert "a callback failed and was skipped (ValueError" in err, err[-3000:]
    assert "header stamp" in err and "not set" in err and "before 1970" in err, err[-3000:]
    touches, _ = read_touches(bag, skin)
    assert touches.n_touches == n_touches, err[-3000:]
