"""The capture end to end, over DDS and a real libqi session: fingertip_capture drives the simulated body.

What is simulated is the robot's body only (test/capture_body.py: :class:`nao_skin.sim.body.SimBody` served as
ALMotion behind a real libqi session, its skin on the skin topics). The nodes are the real ones, each a process
of its own: naoqi_bridge reads the body's angles over libqi onto /joint_states, pairing_recorder records the
fingertip touches into a real bag, fingertip_capture moves the arm over libqi. A Ctrl-C (SIGINT) reaches the
capture during an approach: each arm retracts, goes to rest and only then loses its stiffness; the recorder
wrote a touch of every press it made, and the bag reads back every touch it wrote.
"""
from __future__ import annotations

import json
import re
import signal

import numpy as np
import pytest

qi = pytest.importorskip("qi")
from capture_body import SkinPublisher, qi_body  # noqa: E402
from robot_body import free_port, serve_motion  # noqa: E402
from ros_harness import Listener, node_process, ros_env, unique_domain_id  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from nao_skin.capture.loop import AT_REST  # noqa: E402
from nao_skin.capture.plan import CaptureOptions, arm_of  # noqa: E402
from nao_skin.formats.bag import read_touches  # noqa: E402
from nao_skin.sim.params import load_params  # noqa: E402

pytestmark = pytest.mark.middleware

OPTIONS = CaptureOptions()
PRESSES = 2          # touches made before the Ctrl-C


def test_the_capture_touches_records_and_retracts_at_ctrl_c(skin, tmp_path):
    body = qi_body(skin, ("r_finger", "l_finger"), "torso", load_params("fingertip-torso"), seed=0)
    port = free_port()
    robot = serve_motion(port, body)
    domain = unique_domain_id()
    env = ros_env(domain)
    bag = tmp_path / "touches"
    procs, listener, skin_pub = [], None, None
    try:
        listener = Listener(domain)
        skin_pub = SkinPublisher(listener.node, body)
        status = listener.subscribe(String, "/nao_skin/capture/status", keep=lambda m: json.loads(m.data))
        bridge = node_process("naoqi_bridge", {"nao_port": port, "rate": 50.0}, env, tmp_path)
        recorder = node_process("pairing_recorder", {"bag_path": str(bag),
                                                     "fingertip_scenes": ["r_finger-torso", "l_finger-torso"]},
                                env, tmp_path)
        procs += [bridge, recorder]
        # the capture starts once the recorder hears the streams (else its first touch could go unheard)
        progress = listener.subscribe(String, "/nao_skin/recorder/progress")
        assert listener.spin_until(lambda: len(progress) >= 2, timeout=120, procs=procs), "no recorder progress"
        capture = node_process("fingertip_capture", {"nao_port": port, "max_touches": 40}, env, tmp_path)
        procs.append(capture)

        def approaching() -> bool:
            touched = status[-1]["touched"] if status else 0
            last = body.log[-1] if body.log else None
            return touched >= PRESSES and last is not None and last[0] == "command" and \
                last[4] == OPTIONS.approach_speed
        assert listener.spin_until(approaching, timeout=240, procs=procs), \
            f"no approach after {PRESSES} touches: {status[-1:]} {capture.stderr()[-3000:]}"
        made = len([k for k in body.log if k[0] == "command"])
        assert capture.stop(signal.SIGINT, timeout=120) == 0, capture.stderr()[-3000:]
        procs.remove(capture)
        err = capture.stderr()

        # each arm: from the approach back to the standoff, to rest, and only then no stiffness
        arms = [arm_of(skin, tip, OPTIONS.limit_margin) for tip in ("r_finger", "l_finger")]
        after = body.log[made:]
        fractions = [k[4] for k in after if k[0] == "command"]
        # stopped in an approach: its last step, the retract, then both arms to rest
        assert fractions[-4:] == [OPTIONS.approach_speed, OPTIONS.retract_speed, OPTIONS.move_speed,
                                  OPTIONS.move_speed], fractions
        for arm in arms:
            mine = [k for k in after if tuple(k[2]) == arm.names]
            assert mine[-1][0] == "stiffness" and mine[-1][3] == 0.0, mine
            rest = np.array([skin.robot.body.rest_posture[n][0] for n in arm.names])
            q_off = mine[-1][4][[body.index[n] for n in arm.names]]
            assert np.max(np.abs(q_off - rest)) <= AT_REST
        assert "capture stopped: stop requested" in err
        # never a command beyond the limits less the margin; no press on more than press_max beyond its first
        # contact, give or take the step in which the skin read it (in real time the skin reads during a step,
        # the capture knows at its end)
        by_names = {a.names: a for a in arms}
        assert all(by_names[tuple(k[2])].within(np.array(k[3]))[0] for k in body.log if k[0] == "command")
        assert body.beyond and max(body.beyond) <= OPTIONS.press_max + OPTIONS.step

        # nothing recorded is lost: each press the capture made is in the bag, as a fingertip touch
        said = re.search(r"capture stopped: (\d+) touches; arm rest", err)
        assert said, err[-3000:]
        touched = int(said.group(1))
        assert recorder.stop(signal.SIGINT, timeout=60) == 0, recorder.stderr()[-3000:]
        procs.remove(recorder)
        wrote = re.search(r"wrote (\d+) touches to ", recorder.stderr())
        assert wrote and int(wrote.group(1)) >= touched, recorder.stderr()[-2000:]     # each press recorded
        touches, report = read_touches(bag, skin)
        assert touches.n_touches == int(wrote.group(1)) >= PRESSES and not report.skipped, report.lines()
        assert {touches.fingertips[i] if i >= 0 else None for i in touches.touch_fingertip} <= {"r_finger", "l_finger"}
    finally:
        for p in procs:
            p.stop(signal.SIGINT, timeout=60)
        if skin_pub is not None:
            skin_pub.close()
        if listener is not None:
            listener.close()
        robot.close()
