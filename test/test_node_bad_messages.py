"""What arrives on a topic is anybody's: nodes skip a malformed message and stay up, over real DDS.

The heat-map node reads the guidance and the calibration status, the simulated robot (guided) the
guidance, the calibrate node the recorder's progress; each is fed messages of the wrong shape (a
triangle id that is a string or infinite, a state that is a mapping, a progress that is a list), then a
good one, which must still take effect. Each node stops with exit 0 and no traceback.
"""
from __future__ import annotations

import json

import pytest
from ros_harness import Listener, node_process, ros_env, unique_domain_id

pytest.importorskip("rclpy")
from std_msgs.msg import String  # noqa: E402
from visualization_msgs.msg import MarkerArray  # noqa: E402

from nao_skin.errors import DataError  # noqa: E402
from nao_skin.guidance.capture import targets_from_json  # noqa: E402
from nao_skin.nodes.calibrate import GUIDANCE_TOPIC, LATCHED, STATUS_TOPIC  # noqa: E402
from nao_skin.nodes.pairing_recorder import PROGRESS_TOPIC  # noqa: E402
from nao_skin.nodes.skin_heatmap import GUIDANCE_MARKERS_TOPIC  # noqa: E402

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
    for text in ("{", "[]", '{"targets": 3}'):
        with pytest.raises(DataError):
            targets_from_json(text, skin)


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
        bad = {GUIDANCE_TOPIC: ["{", "[]", json.dumps({"targets": BAD_TARGETS})],
               STATUS_TOPIC: ["{", json.dumps({"parts": {"head": {"a": 1}, "torso": ["done"]}}),
                              json.dumps({"parts": [1]})],
               PROGRESS_TOPIC: ["[]", json.dumps({"touches": 1e400}), json.dumps({"touches": "many"}),
                                json.dumps({"touches": -4})]}
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
