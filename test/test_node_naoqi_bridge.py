"""naoqi_bridge against a real libqi session serving an ALMotion-shaped service.

Only the robot's body is simulated: ``FakeMotion`` answers ``getAngles``
with fresh, never repeated angles (a mock of the robot, nothing else). The
bridge runs as its own process, talks libqi over TCP on loopback and
publishes over real DDS; the test subscribes to ``/joint_states``. The
service is stopped and restarted on the same port: the bridge must
recover, log the outage once, and never publish an angle twice (stale
angles republished as fresh would repeat a served value).
"""
from __future__ import annotations

import itertools
import threading

import pytest

qi = pytest.importorskip("qi")
from robot_body import free_port, serve_motion  # noqa: E402
from ros_harness import Listener, node_process, ros_env, unique_domain_id  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from nao_skin.session.params import DEFAULT_JOINTS  # noqa: E402

pytestmark = pytest.mark.middleware   # a libqi session served to the naoqi_bridge node, over DDS


class FakeMotion:
    """MOCK of the robot's body: ALMotion.getAngles with unique values per call, recorded."""

    def __init__(self, generation: int):
        self.generation = generation
        self.served: list = []
        self.use_sensors: set = set()
        self._seq = itertools.count(1)
        self._lock = threading.Lock()

    def getAngles(self, names, useSensors):  # noqa: N802 - NAOqi's method name
        with self._lock:
            seq = next(self._seq)
            values = [self.generation + seq * 1e-4 + i * 1e-7 for i in range(len(names))]
            self.served.append((tuple(names), tuple(values)))
            self.use_sensors.add(bool(useSensors))
        return values


def test_joint_states_and_recovery(tmp_path):
    port = free_port()
    domain = unique_domain_id()
    first = FakeMotion(1)
    robot = serve_motion(port, first)
    bridge = listener = None
    try:
        bridge = node_process("naoqi_bridge", {"nao_ip": "127.0.0.1", "nao_port": port, "rate": 50.0,
                                               "reconnect_min": 0.1, "reconnect_max": 0.3},
                              ros_env(domain), tmp_path)
        listener = Listener(domain)
        got = listener.subscribe(JointState, "/joint_states")
        assert listener.spin_until(lambda: len(got) >= 10, procs=[bridge]), "no /joint_states from the bridge"

        served_first = {v for _, v in first.served}
        for msg in got:
            assert list(msg.name) == DEFAULT_JOINTS
            assert tuple(msg.position) in served_first      # exactly what ALMotion returned, same order
        assert first.use_sensors == {True}
        assert all(n == tuple(DEFAULT_JOINTS) for n, _ in first.served)

        # The robot goes away: the bridge must stop publishing, keep retrying quietly.
        robot.close()
        robot = None
        n_at_stop = len(first.served)
        listener.spin_for(1.5)                    # several reconnect attempts happen meanwhile
        assert len(first.served) == n_at_stop
        during_outage = len(got)

        # ... and comes back on the same port with a new body.
        second = FakeMotion(2)
        robot = serve_motion(port, second)
        assert listener.spin_until(lambda: any(m.position[0] >= 2.0 for m in got[during_outage:]),
                                   procs=[bridge]), "bridge did not recover after the service restarted"

        values = [tuple(m.position) for m in got]
        assert len(values) == len(set(values)), "an angle set was published twice (stale data republished)"
        served_all = served_first | {v for _, v in second.served}
        assert set(values) <= served_all
        assert all(v[0] < 2.0 for v in got_values_before(got, during_outage))
    finally:
        if listener is not None:
            listener.close()
        code = bridge.stop() if bridge is not None else None
        if robot is not None:
            robot.close()
    assert code == 0, bridge.stderr()[-2000:]
    err = bridge.stderr()
    assert err.count("retrying") == 1, f"outage not logged exactly once:\n{err[-3000:]}"
    assert err.count("connected again") == 1, err[-3000:]


def got_values_before(got, n):
    return [tuple(m.position) for m in got[:n]]


class MoodyMotion(FakeMotion):
    """MOCK of the robot's body that answers getAngles as told: with angles, an error (NAOqi's answer to a
    joint name it does not know), None, or not at all for a while."""

    def __init__(self):
        super().__init__(3)
        self.mood = "ok"

    def getAngles(self, names, useSensors):  # noqa: N802 - NAOqi's method name
        mood = self.mood
        if mood == "error":
            raise RuntimeError("ALMotion.getAngles: wrong joint name 'Foo'")
        if mood == "none":
            return None
        if mood == "hang":
            threading.Event().wait(3.0)
        return super().getAngles(names, useSensors)


def test_a_robot_that_answers_with_errors_is_no_outage_and_one_that_hangs_is(tmp_path):
    """An error or a None from getAngles made the bridge drop the session and reconnect at every tick,
    logging an outage each time (16 lines in 2 s); a call that never answered left it silent."""
    port = free_port()
    domain = unique_domain_id()
    motion = MoodyMotion()
    robot = serve_motion(port, motion)
    bridge = listener = None
    try:
        bridge = node_process("naoqi_bridge", {"nao_ip": "127.0.0.1", "nao_port": port, "rate": 50.0,
                                               "reconnect_min": 0.1, "reconnect_max": 0.3, "read_timeout": 0.5},
                              ros_env(domain), tmp_path)
        listener = Listener(domain)
        got = listener.subscribe(JointState, "/joint_states")
        assert listener.spin_until(lambda: len(got) >= 5, procs=[bridge])
        for mood in ("error", "none"):
            motion.mood = mood
            listener.spin_for(1.5)
            motion.mood = "ok"
            n = len(got)
            assert listener.spin_until(lambda: len(got) >= n + 5, procs=[bridge]), mood
        motion.mood = "hang"
        listener.spin_for(1.5)
        motion.mood = "ok"
        n = len(got)
        assert listener.spin_until(lambda: len(got) >= n + 5, timeout=30, procs=[bridge]), "no recovery after a hang"
    finally:
        if listener is not None:
            listener.close()
        code = bridge.stop() if bridge is not None else None
        robot.close()
    err = bridge.stderr()
    assert code == 0 and "Traceback" not in err, err[-3000:]
    assert err.count("ALMotion.getAngles failed (") == 1 and "wrong joint name 'Foo'" in err, err[-3000:]
    assert err.count("ALMotion.getAngles returned NoneType, not a list of 12 angles") == 1, err[-3000:]
    # the only outage is the hang: said once, with its reason, and once recovered
    assert err.count("retrying") == 1 and "no answer from ALMotion.getAngles in 0.5 s" in err, err[-3000:]
    assert err.count("connected again") == 1, err[-3000:]
