"""calibrate node over real DDS: skin frames on /tf_static for late joiners, replaced by each calibration.

The node starts with a given (non-nominal) calibration, is asked to calibrate
a small simulated touch bag twice, and subscribers join before, between and
after: each late joiner receives exactly one TFMessage, holding every skin
frame exactly once, equal to the calibration current at that moment (the
start file, then the calibration.yaml each run wrote).
"""
from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("rclpy")
from ros_harness import Listener, node_process, ros_env, unique_domain_id  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402

from nao_skin.calibration.uncertainty_map import colours  # noqa: E402

from nao_skin.formats.bag import write_touch_bag  # noqa: E402
from nao_skin.model.skin import SkinCalibration  # noqa: E402
from nao_skin.model.skin import load_skin  # noqa: E402
from nao_skin.model.skin import skin_frame_transforms  # noqa: E402
from nao_skin.nodes.topics import LATCHED, REQUEST_TOPIC, STATUS_TOPIC, TF_STATIC_TOPIC, UNCERTAINTY_TOPIC  # noqa: E402
from nao_skin.sim.simulate import simulate  # noqa: E402

pytestmark = pytest.mark.middleware   # runs the calibrate node over DDS


def as_table(msg: TFMessage) -> dict:
    """child -> (parent, 4x4) of a TFMessage; fails on a frame given twice."""
    out = {}
    for ts in msg.transforms:
        assert ts.child_frame_id not in out, f"frame {ts.child_frame_id} published twice"
        t, q = ts.transform.translation, ts.transform.rotation
        m = np.eye(4)
        m[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()     # ROS order x, y, z, w
        m[:3, 3] = [t.x, t.y, t.z]
        out[ts.child_frame_id] = (ts.header.frame_id, m)
    return out


def assert_frames(msg: TFMessage, skin, calib: SkinCalibration):
    got = as_table(msg)
    want = {child: (parent, m) for parent, child, m in skin_frame_transforms(skin, calib)}
    assert set(got) == set(want)
    for child, (parent, m) in want.items():
        assert got[child][0] == parent, child
        np.testing.assert_allclose(got[child][1], m, atol=1e-8, err_msg=child)
    assert len({(ts.header.stamp.sec, ts.header.stamp.nanosec) for ts in msg.transforms}) == 1


def late_joiner(listener: Listener) -> list:
    return listener.subscribe(TFMessage, TF_STATIC_TOPIC, qos=LATCHED)


def test_late_joiners_get_exactly_the_latest_calibration(tmp_path):
    skin = load_skin()
    sim = simulate(skin, {"n_touches": 32}, seed=5)     # enough per pair for mounts and patches
    bag = tmp_path / "touches"
    write_touch_bag(bag, sim.touches, skin, storage="mcap")
    start = skin.zero_calibration()
    start.parts["torso"].mount[:] = [0.002, -0.001, 0.003, 0.01, 0.0, -0.02]   # not the nominal skin
    start_file = tmp_path / "start.yaml"
    start.save(start_file, skin)
    start = SkinCalibration.load(start_file, skin)        # as the node reads it (YAML rounding)
    out_dir = tmp_path / "calibration"
    domain = unique_domain_id()
    listener = node = None
    try:
        listener = Listener(domain)
        node = node_process("calibrate", {"calibration": str(start_file), "inputs": [str(bag)],
                                          "out_dir": str(out_dir)}, ros_env(domain), tmp_path)
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        assert listener.spin_until(lambda: status and status[-1]["state"] == "published", procs=[node])

        first = late_joiner(listener)
        assert listener.spin_until(lambda: len(first) >= 1, procs=[node])
        listener.spin_for(0.5)                            # a second (wrong) message would show up here
        assert len(first) == 1
        assert_frames(first[0], skin, start)
        no_map = listener.subscribe(MarkerArray, UNCERTAINTY_TOPIC, qos=LATCHED)
        listener.spin_for(0.5)
        assert no_map == []                               # a calibration given, not made: nothing predicted

        request = listener.node.create_publisher(String, REQUEST_TOPIC, 10)
        for run in (1, 2):
            assert listener.spin_until(lambda: request.get_subscription_count() >= 1, procs=[node])
            n_status = len(status)
            request.publish(String(data=""))              # empty: the node's own inputs
            ended = lambda: [s for s in status[n_status:] if s["state"] in ("done", "failed", "busy")]  # noqa: E731
            assert listener.spin_until(ended, timeout=120, procs=[node]), status[-1:]
            assert ended()[0]["state"] == "done" and ended()[0]["generation"] == 1 + run, ended()[0]
            calib = SkinCalibration.load(out_dir / "calibration.yaml", skin)
            assert listener.spin_until(lambda: len(first) >= 1 + run, procs=[node]), "live subscriber missed it"
            joiners = [late_joiner(listener), late_joiner(listener)]
            assert listener.spin_until(lambda: all(len(j) >= 1 for j in joiners), procs=[node])
            listener.spin_for(0.5)
            for j in joiners:                             # exactly one message, the newest calibration
                assert len(j) == 1
                assert_frames(j[0], skin, calib)
            assert_frames(first[-1], skin, calib)
        assert not np.allclose(calib.parts["l_hand"].mount, 0.0)   # the calibration really changed frames
        # the uncertainty map of the last calibration: a disc per triangle of each calibrated part, in the
        # triangle's frame, coloured by the predicted error report.json holds for it
        predicted = json.loads((out_dir / "report.json").read_text())["final"]["predicted_triangle_error_mm"]
        assert set(predicted) == {"r_hand", "l_hand", "torso", "head"}
        maps = listener.subscribe(MarkerArray, UNCERTAINTY_TOPIC, qos=LATCHED)
        assert listener.spin_until(lambda: len(maps) >= 1, procs=[node])
        markers = maps[0].markers
        assert markers[0].action == Marker.DELETEALL      # the last map's discs go with it
        discs = {(m.ns, m.id): m for m in markers[1:]}
        assert set(discs) == {(part, int(t)) for part, values in predicted.items() for t in values}
        for (part, tid), m in discs.items():
            assert m.type == Marker.CYLINDER and m.header.frame_id == skin.parts[part].triangle_frame(tid)
            want = colours([predicted[part][str(tid)]])[0]
            np.testing.assert_allclose([m.color.r, m.color.g, m.color.b, m.color.a], want, atol=1e-6)
    finally:
        if listener is not None:
            listener.close()
        code = node.stop() if node is not None else None
    assert code == 0, node.stderr()[-3000:]
