"""Live calibration in a record session, over real DDS: `nao-skin record` with the simulated robot (which
stands in for the robot's body), the real recorder and the calibrate node recalibrating in the background.

* while touches are still being recorded, updates arrive with increasing generation and touch counts;
* too few touches is not fatal: the node waits, then calibrates the pair the touches support while the
  other hand is still collecting (and, once it has a few touches, is left out and said so);
* a late joiner of /tf_static gets exactly the latest update, and when the session ends the last
  accepted calibration is written beside the recording.
"""
from __future__ import annotations

import json
import signal
import time

import pytest
from ros_harness import Listener, Proc, ros_env, unique_domain_id

pytest.importorskip("rclpy")
from std_msgs.msg import String  # noqa: E402
from test_node_calibrate import assert_frames  # noqa: E402
from test_record_session import record_cmd  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402

from nao_skin.model.skin import SkinCalibration, load_skin  # noqa: E402
from nao_skin.nodes.calibrate import LATCHED, STATUS_TOPIC  # noqa: E402
from nao_skin.nodes.pairing_recorder import PROGRESS_TOPIC  # noqa: E402
from nao_skin.nodes.sim_robot import STATUS_TOPIC as SIM_STATUS_TOPIC  # noqa: E402
from nao_skin.nodes.static_tf import TF_STATIC_QOS, TF_STATIC_TOPIC  # noqa: E402

pytestmark = [pytest.mark.middleware, pytest.mark.slow]


def test_updates_arrive_while_touches_are_recorded(tmp_path):
    bag = tmp_path / "touches"
    argv = record_cmd(bag, seed=3, per_pair=20) + [
        "--param", "sim_robot.pairs=[r_hand-torso, l_hand-torso]", "--param", "sim_robot.touch_period=0.35",
        "--param", "calibrate.live_every_touches=6", "--param", "calibrate.live_period=1.0"]
    domain = unique_domain_id()
    listener = session = None
    try:
        listener = Listener(domain)
        arrived: list = []             # when each status came
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED,
                                    keep=lambda m: arrived.append(time.monotonic()) or json.loads(m.data))
        sim = listener.subscribe(String, SIM_STATUS_TOPIC, keep=lambda m: json.loads(m.data))
        progress = listener.subscribe(String, PROGRESS_TOPIC, keep=lambda m: json.loads(m.data))
        session = Proc(argv, ros_env(domain), tmp_path, "record")
        updated = lambda: [s for s in status if s["state"] == "updated"]  # noqa: E731
        # updates while recording goes on: the recorder reports more touches after them
        assert listener.spin_until(lambda: len(updated()) >= 2 and progress
                                   and progress[-1]["touches"] > updated()[1]["touches"],
                                   timeout=120, procs=[session]), (status[-3:], progress[-1:])
        # every touch played and recorded, the last update made (none for 3 s since): the session settled
        assert listener.spin_until(lambda: sim and sim[-1]["done"] and status[-1]["state"] == "updated"
                                   and time.monotonic() - arrived[-1] > 3.0, timeout=120, procs=[session]), \
            status[-1:]
        live = updated()
        assert [s["generation"] for s in live] == sorted({s["generation"] for s in live})
        assert [s["touches"] for s in live] == sorted(s["touches"] for s in live)
        # too few touches waits, it does not fail; the supported pair goes first, the other hand collects
        first = next(i for i, s in enumerate(status) if s["state"] == "updated")
        assert any(s["state"] == "waiting" for s in status[:first]), status[:first]
        assert not any(s["state"] == "failed" for s in status), [s for s in status if s["state"] == "failed"]
        assert live[0]["parts"]["r_hand"] == "converging" and live[0]["parts"]["l_hand"] == "collecting"
        assert all(set(s["displacement_mm"]) <= {"r_hand", "l_hand", "torso"} for s in live)
        assert any(s["left_out"] for s in live) or live[0]["parts"]["l_hand"] == "collecting"
        # a late joiner gets exactly one TFMessage: the latest update
        joiner = listener.subscribe(TFMessage, TF_STATIC_TOPIC, qos=TF_STATIC_QOS)
        assert listener.spin_until(lambda: joiner, procs=[session])
        listener.spin_for(0.5)
        assert len(joiner) == 1
    finally:
        if listener is not None:
            listener.close()
        code = session.stop(signal.SIGINT) if session is not None else None
    assert code == 0, session.stderr()[-3000:]
    # the last accepted calibration is written beside the recording when the session ends
    out = tmp_path / "touches_calibration"
    written = SkinCalibration.load(out / "calibration.yaml", load_skin())
    report = json.loads((out / "report.json").read_text())
    assert report["parts"] == ["r_hand", "l_hand", "torso"]
    assert_frames(joiner[0], load_skin(), written)      # what the late joiner got is what was written
