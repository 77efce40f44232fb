"""The capture end to end, over DDS and a real libqi session: fingertip_capture drives the simulated body.

What is simulated is the robot's body only (test/capture_body.py: :class:`nao_skin.sim.body.SimBody` served as
ALMotion behind a real libqi session, its skin on the skin topics). The nodes are the real ones, each a process
of its own: naoqi_bridge reads the body's angles over libqi onto /joint_states, pairing_recorder records the
fingertip touches into a real bag, fingertip_capture moves the arm over libqi. A Ctrl-C (SIGINT) reaches the
capture during an approach, or the ``~/stop`` service, stale joint states or a lost NAOqi stop it: each arm
retracts, goes to rest and only then loses its stiffness (NAOqi lost: nothing more is commanded, the stiffness
is kept); the recorder wrote a touch of every press it made, and the bag reads back every touch it wrote.
"""
from __future__ import annotations

import json
import os
import re
import signal
import threading
import time

import numpy as np
import pytest

qi = pytest.importorskip("qi")
from capture_body import SkinPublisher, qi_body  # noqa: E402
from robot_body import free_port, serve_motion  # noqa: E402
from ros_harness import Listener, node_process, ros_env, unique_domain_id  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from nao_skin.capture.loop import AT_REST  # noqa: E402
from nao_skin.capture.plan import CaptureOptions, arm_of  # noqa: E402
from nao_skin.formats.bag import read_touches  # noqa: E402
from nao_skin.sim.params import load_params  # noqa: E402

pytestmark = pytest.mark.middleware

OPTIONS = CaptureOptions()
PRESSES = 2          # touches made before the Ctrl-C


STOPS = ("ctrl-c", "~/stop", "stale joint states", "naoqi lost")


@pytest.mark.parametrize("stop", STOPS)
def test_the_capture_touches_records_and_stops_safely(stop, skin, tmp_path):
    """Two presses, then, during an approach, one of the capture's stops: Ctrl-C (SIGINT), the ``~/stop`` Trigger
    service, the joint states gone stale (the bridge held by SIGSTOP), NAOqi lost (the robot's libqi session
    closed). Where NAOqi is still there, each arm retracts, goes to rest and only then loses its stiffness;
    where it is gone, nothing more is commanded and the stiffness is kept. Either way the stop is one line, and
    every press made is in the bag."""
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
        said = _stop_capture(stop, listener, capture, bridge, robot, status, procs)
        assert capture.stop(signal.SIGINT, timeout=120) == 0, capture.stderr()[-3000:]
        procs.remove(capture)
        err = capture.stderr()
        assert f"capture stopped: {said}" in err, err[-3000:]

        arms = [arm_of(skin, tip, OPTIONS.limit_margin) for tip in ("r_finger", "l_finger")]
        after = body.log[made:]
        fractions = [k[4] for k in after if k[0] == "command"]
        if stop == "naoqi lost":
            # nothing reached the robot after it was gone; the arm keeps its stiffness, and the log says so
            assert not any(k[0] == "stiffness" and k[3] == 0.0 for k in after), after
            assert "stiffness kept" in err, err[-3000:]
        else:
            if stop == "ctrl-c":
                # stopped in an approach: its last step, the retract, then both arms to rest
                assert fractions[-4:] == [OPTIONS.approach_speed, OPTIONS.retract_speed, OPTIONS.move_speed,
                                          OPTIONS.move_speed], fractions
            else:
                # the stop came a moment later (a service call, 0.5 s of joint states missing): both arms to rest
                assert fractions[-2:] == [OPTIONS.move_speed, OPTIONS.move_speed], fractions
            for arm in arms:      # each arm: at rest, and only then no stiffness
                mine = [k for k in after if tuple(k[2]) == arm.names]
                assert mine[-1][0] == "stiffness" and mine[-1][3] == 0.0, mine
                rest = np.array([skin.robot.body.rest_posture[n][0] for n in arm.names])
                q_off = mine[-1][4][[body.index[n] for n in arm.names]]
                assert np.max(np.abs(q_off - rest)) <= AT_REST
        # never a command beyond the limits less the margin; no press on more than press_max beyond its first
        # contact, give or take the step in which the skin read it (in real time the skin reads during a step,
        # the capture knows at its end)
        by_names = {a.names: a for a in arms}
        assert all(by_names[tuple(k[2])].within(np.array(k[3]))[0] for k in body.log if k[0] == "command")
        assert body.beyond and max(body.beyond) <= OPTIONS.press_max + OPTIONS.step

        # nothing recorded is lost: each press the capture made is in the bag, as a fingertip touch
        ended = re.search(r"capture stopped: (\d+) touches; arm ", err)
        assert ended, err[-3000:]
        touched = int(ended.group(1))
        if bridge.alive():
            os.kill(bridge.popen.pid, signal.SIGCONT)
        assert recorder.stop(signal.SIGINT, timeout=60) == 0, recorder.stderr()[-3000:]
        procs.remove(recorder)
        wrote = re.search(r"wrote (\d+) touches to ", recorder.stderr())
        assert wrote and int(wrote.group(1)) >= touched, recorder.stderr()[-2000:]     # each press recorded
        touches, report = read_touches(bag, skin)
        assert touches.n_touches == int(wrote.group(1)) >= PRESSES and not report.skipped, report.lines()
        assert {touches.fingertips[i] if i >= 0 else None for i in touches.touch_fingertip} <= {"r_finger", "l_finger"}
    finally:
        for p in procs:
            if p.alive():
                os.kill(p.popen.pid, signal.SIGCONT)
            p.stop(signal.SIGINT, timeout=60)
        if skin_pub is not None:
            skin_pub.close()
        if listener is not None:
            listener.close()
        robot.close()


def _stop_capture(stop: str, listener, capture, bridge, robot, status: list, procs: list) -> str:
    """Stop the capture the way ``stop`` says; once its loop has ended (its status "stopped"), the reason it
    gives in its log line."""
    if stop == "ctrl-c":
        return "stop requested"
    if stop == "~/stop":
        client = listener.node.create_client(Trigger, "/fingertip_capture/stop")
        reply = listener.ask(client, Trigger.Request(), procs=procs)
        assert reply.success, reply.message
        reason = "stop requested"
    elif stop == "stale joint states":
        os.kill(bridge.popen.pid, signal.SIGSTOP)       # its joint states stop; it is not gone
        reason = "joint states"
    else:
        robot.close()
        reason = "NAOqi lost"
    assert listener.spin_until(lambda: status and status[-1]["state"] == "stopped", timeout=120,
                               procs=[capture]), status[-1:]
    return reason


def test_the_skin_is_read_by_when_it_was_taken_however_late_its_message_comes():
    """The capture node's skin readings (real threads; the stamps of another clock, as a robot's): a reading of
    the target taken after the step counts once it comes, however late; one that comes after the step but was
    taken before it does not; none taken within ``late_after`` stops the capture, and a stop ends the wait."""
    from nao_skin.capture.safety import Abort
    from nao_skin.nodes.fingertip_capture import SkinReadings

    empty = (np.zeros(0, int), np.zeros(0))
    readings = SkinReadings("torso", late_after=5.0, stopping=threading.Event())
    t0, robot_t0 = time.monotonic(), time.time() + 1000.0     # the robot's clock: another origin

    def stamp(at: float) -> float:          # a reading taken at ``at`` (this process's monotonic s)
        return robot_t0 + (at - t0)

    for part in ("torso", "l_hand"):
        readings.add(part, stamp(t0), *empty)
    time.sleep(0.05)
    step_end = time.monotonic()

    def backlog_then_fresh() -> None:
        time.sleep(0.3)
        readings.add("torso", stamp(step_end - 0.02), np.array([7]), np.array([40.0]))    # taken before the step end
        readings.add("l_hand", stamp(time.monotonic()), *empty)                           # not the target
        time.sleep(0.2)
        readings.add("torso", stamp(time.monotonic()), np.array([5]), np.array([25.0]))

    thread = threading.Thread(target=backlog_then_fresh)
    thread.start()
    fired = readings.fired(step_end)
    thread.join()
    assert list(fired) == ["torso"] and fired["torso"][0].tolist() == [5] and fired["torso"][1] == 25.0, fired

    stopping = threading.Event()
    hasty = SkinReadings("torso", late_after=0.2, stopping=stopping)
    hasty.add("torso", stamp(time.monotonic()), *empty)
    with pytest.raises(Abort, match="skin readings late: none of torso"):
        hasty.fired(time.monotonic())
    patient = SkinReadings("torso", late_after=60.0, stopping=stopping)
    threading.Timer(0.2, lambda: (stopping.set(), patient.wake())).start()
    with pytest.raises(Abort, match="stop requested"):
        patient.fired(time.monotonic())
