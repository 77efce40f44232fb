"""What a ROS user reaches for: the ``~/calibrate`` Trigger service, ``/diagnostics``, parameter descriptors.

The pure level decisions (:mod:`nao_skin.live.diagnostics`) are tested alone; the descriptors on a real rclpy
node (no DDS traffic); the service, the diagnostics of a running session and ``ros2 param describe/set`` over
real DDS, with the calibrate node live on a bag the test wrote (it stands in for the recorder: it publishes the
progress) beside a pairing_recorder.
"""
from __future__ import annotations

import json

import pytest

from nao_skin.live.diagnostics import (DISK_ERROR_BYTES, DISK_WARN_BYTES, ERROR, OK, WARN, Check, RateWindow,
                                       age_check, count_check, disk_check, live_check, rate_check, summary)
from nao_skin.session.params import CALIBRATE, CHANGEABLE, NODE_PARAMS, changeable_params, rule_range

GIB = 1 << 30


# ---------------------------------------------------------------------------------------------- pure decisions
def test_a_stream_is_ok_near_its_rate_slow_below_half_and_missing_at_zero():
    assert rate_check("joint states", 48.0, 50.0).level == OK
    slow = rate_check("joint states", 12.0, 50.0)
    assert slow.level == WARN and slow.message == "joint states at 12.0 Hz, expected 50 Hz"
    none = rate_check("joint states", 0.0, 50.0)
    assert none.level == ERROR and none.message == "no joint states (expected 50 Hz)"
    assert rate_check("skin samples", 0.0, 50.0, required=False).level == WARN
    assert rate_check("joint states", None, 50.0).level == OK            # nothing measured yet
    assert rate_check("skin samples", 0.0, 0.0).level == OK              # no expected rate: said only
    assert dict(slow.values) == {"joint states rate (Hz)": "12.0", "joint states expected (Hz)": "50.0"}
    # what a node needs, not what its publisher sends (the recorder's joint states: one per joint_tolerance)
    needs = rate_check("joint states", 8.0, 10.0, needed="touch detection")
    assert needs.level == WARN and needs.message == "joint states at 8.0 Hz, touch detection needs 10 Hz"
    assert dict(needs.values) == {"joint states rate (Hz)": "8.0", "joint states needed (Hz)": "10.0"}
    assert rate_check("joint states", 100.0, 10.0, needed="touch detection").level == OK


def test_free_disk_warns_low_and_is_an_error_nearly_full():
    total = 500 * GIB
    assert disk_check("/bags/x", 20 * GIB, total).level == OK
    low = disk_check("/bags/x", DISK_WARN_BYTES - 1, total)
    assert low.level == WARN and "/bags/x" in low.message
    assert disk_check("/bags/x", DISK_ERROR_BYTES - 1, total).level == ERROR
    assert dict(low.values)["disk used (%)"] == "99.8"
    unknown = disk_check("/bags/x", None, None, error="no such file")
    assert unknown.level == ERROR and "no such file" in unknown.message


def test_ages_counts_and_the_calibrate_state():
    assert age_check("touch", None).values == (("touch age (s)", "never"),)
    assert age_check("recorder progress", 30.0, warn_after=10.0).level == WARN
    assert age_check("recorder progress", 3.0, warn_after=10.0).level == OK
    assert count_check("bad reads", 0).level == OK and count_check("bad reads", 2).message == "2 bad reads"
    failed = live_check({"state": "failed", "live": True, "error": "no bag"}, live=True, busy=False)
    assert failed.level == WARN and failed.message == "the last live update failed: no bag"
    done = live_check({"state": "updated", "generation": 3, "parts": {"torso": "done"}}, live=True, busy=True)
    assert done.level == OK and ("part torso", "done") in done.values and ("running", "yes") in done.values


def test_a_node_status_is_its_worst_finding():
    checks = [Check(OK, "", (("a", "1"),)), Check(WARN, "slow", (("b", "2"),)), Check(WARN, "old"),
              Check(OK, "fine")]
    assert summary(checks) == (WARN, "slow; old", (("a", "1"), ("b", "2")))
    assert summary([Check(values=(("a", "1"),))]) == (OK, "OK", (("a", "1"),))
    assert summary([]) == (OK, "OK", ())


def test_a_rate_is_measured_between_two_readings():
    window = RateWindow()
    assert window.rate(10, 100.0) is None
    assert window.rate(30, 102.0) == 10.0
    assert window.rate(30, 103.0) == 0.0


def test_descriptor_ranges_come_from_the_rules():
    assert rule_range(15.0, CALIBRATE["gate_mm"][2]) == (0.0, 1e4)
    low, high = rule_range(25, CALIBRATE["live_every_touches"][2])
    assert (low, high) == (1, 2 ** 63 - 1)
    assert rule_range(True, None) is None and rule_range("mcap", NODE_PARAMS["pairing_recorder"]["storage"][2]) is None
    for node, names in CHANGEABLE.items():       # every changeable parameter is one the node declares
        assert set(names) <= set(NODE_PARAMS[node]), node
    assert "live_every_touches" in changeable_params("calibrate", {"live": True})
    assert "live_every_touches" not in changeable_params("calibrate", {"live": False})   # applies nowhere then


# ---------------------------------------------------------------------------------------------- a real rclpy node
@pytest.mark.middleware
def test_descriptors_say_the_rule_and_only_changeable_parameters_are_applied():
    """A real rclpy node (no DDS traffic): the range and read-only flag ``ros2 param describe`` shows, a change
    held to the rule first, an integer for a float parameter taken as the float, the change applied."""
    rclpy = pytest.importorskip("rclpy")
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from nao_skin.nodes.runtime import declare

    context = Context()
    rclpy.init(context=context, domain_id=0)
    try:
        node = Node("calibrate", context=context, start_parameter_services=False,
                    parameter_overrides=[Parameter("live", value=True), Parameter("gate_mm", value=20)])
        applied = []
        values = declare(node, CALIBRATE, changeable=lambda v: changeable_params("calibrate", v),
                         on_change=applied.append)
        assert values["gate_mm"] == 20.0 and isinstance(values["gate_mm"], float)   # as today
        gate = node.describe_parameter("gate_mm")
        assert gate.read_only and gate.description == CALIBRATE["gate_mm"][1]
        assert [(r.from_value, r.to_value, r.step) for r in gate.floating_point_range] == [(0.0, 1e4, 0.0)]
        assert gate.additional_constraints.startswith("a number in [0, 10000]")
        every = node.describe_parameter("live_every_touches")
        assert not every.read_only and [(r.from_value, r.step) for r in every.integer_range] == [(1, 1)]
        assert node.describe_parameter("out_dir").read_only

        (refused,) = node.set_parameters([Parameter("gate_mm", value=5.0)])
        assert not refused.successful and refused.reason.startswith(
            "'gate_mm' is read when the node starts: restart the node with it (ros2 run: -p gate_mm:=VALUE;"
            " ros2 launch: params_file:=FILE holding calibrate: {ros__parameters: {gate_mm: VALUE}}; nao-skin record:"
            " --param calibrate.gate_mm=VALUE)"), refused.reason
        (out,) = node.set_parameters([Parameter("live_every_touches", value=0)])
        assert not out.successful and out.reason == "parameter live_every_touches:=0: expected a whole number >= 1"
        assert applied == []
        (ok,) = node.set_parameters([Parameter("live_every_touches", value=7)])
        (period,) = node.set_parameters([Parameter("live_period", value=3)])     # an integer for a float
        assert ok.successful and period.successful
        assert applied == [{"live_every_touches": 7}, {"live_period": 3.0}]
        assert node.get_parameter("live_period").type_ == Parameter.Type.DOUBLE
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


# ---------------------------------------------------------------------------------------------- over real DDS
@pytest.mark.middleware
def test_trigger_diagnostics_and_parameters_of_a_running_session(tmp_path):
    pytest.importorskip("rclpy")
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rcl_interfaces.srv import DescribeParameters, GetParameters, SetParameters
    from ros_harness import Listener, node_process, ros_env, unique_domain_id
    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    from nao_skin.formats.bag import write_touch_bag
    from nao_skin.model.skin import load_skin
    from nao_skin.nodes.topics import DIAGNOSTICS_TOPIC, LATCHED, PROGRESS_TOPIC, STATUS_TOPIC
    from nao_skin.sim.simulate import simulate

    skin = load_skin()
    touches = simulate(skin, {"pairs": [["r_hand", "torso"]], "n_touches": 40}, seed=6).touches
    bag = tmp_path / "touches"
    write_touch_bag(bag, touches, skin)
    domain = unique_domain_id()
    env = ros_env(domain)
    listener = calibrate = recorder = None
    try:
        listener = Listener(domain)
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        diagnostics = listener.subscribe(DiagnosticArray, DIAGNOSTICS_TOPIC)
        progress = listener.node.create_publisher(String, PROGRESS_TOPIC, 10)
        # an update only after 1000 touches or a day: the first comes at once (none ran yet), the next only
        # once live_every_touches is set lower
        calibrate = node_process("calibrate", {"live": True, "recording": str(bag), "live_every_touches": 1000,
                                               "live_period": 86400.0, "out_dir": str(tmp_path / "cal")},
                                 env, tmp_path)
        # the recorder's own progress ({"touches": 0}) would stand in the test's way: none in this test's time
        recorder = node_process("pairing_recorder", {"bag_path": str(tmp_path / "recorded"),
                                                     "progress_period": 86400.0}, env, tmp_path)
        procs = [calibrate, recorder]
        node = listener.node
        trigger = node.create_client(Trigger, "/calibrate/calibrate")
        describe = node.create_client(DescribeParameters, "/calibrate/describe_parameters")
        setter = node.create_client(SetParameters, "/calibrate/set_parameters")
        getter = node.create_client(GetParameters, "/calibrate/get_parameters")
        assert listener.spin_until(lambda: all(c.service_is_ready() for c in (trigger, describe, setter, getter))
                                   and progress.get_subscription_count() >= 1 and status, timeout=90, procs=procs)

        def answer(future):
            assert listener.spin_until(future.done, timeout=60, procs=procs)
            return future.result()

        # ~/calibrate: two requests at once; the first calibrates the recording and is answered when that is
        # done, the second is answered that one is running (a calibration takes seconds)
        seen = len(status)
        first, second = (trigger.call_async(Trigger.Request()) for _ in range(2))
        busy, calibrated = answer(second), answer(first)
        assert calibrated.success and str(tmp_path / "cal") in calibrated.message, calibrated.message
        assert not busy.success and "running" in busy.message, busy.message
        assert listener.spin_until(lambda: any(s["state"] in ("done", "failed") for s in status[seen:]),
                                   timeout=120, procs=procs), status[seen:]
        done = next(s for s in status[seen:] if s["state"] in ("done", "failed"))
        assert done["state"] == "done" and done["touches"] > 0, done

        # /diagnostics: one status per node and message, levels as rqt_robot_monitor shows them
        def latest(name):
            found = [s for array in diagnostics for s in array.status if s.name == name]
            return found[-1] if found else None

        assert listener.spin_until(lambda: latest("nao_skin: /calibrate") and latest("nao_skin: /pairing_recorder"),
                                   timeout=60, procs=procs)
        assert all(len(array.status) == 1 for array in diagnostics)

        def values(status):
            return {kv.key: kv.value for kv in status.values}

        # the calibration's end reaches the node's next status
        assert listener.spin_until(lambda: values(latest("nao_skin: /calibrate")).get("state") == "done",
                                   timeout=60, procs=procs)
        mine = latest("nao_skin: /calibrate")
        assert mine.level == DiagnosticStatus.OK and mine.hardware_id, mine
        assert values(mine)["running"] == "no" and values(mine)["live"] == "yes"
        # the recorder gets no joint states here: an error saying so, with the free disk where the bag goes
        assert listener.spin_until(lambda: latest("nao_skin: /pairing_recorder").level == DiagnosticStatus.ERROR,
                                   timeout=60, procs=procs)
        rec = latest("nao_skin: /pairing_recorder")
        assert "no joint states (touch detection needs 10 Hz)" in rec.message, rec.message
        assert {"free disk (MiB)", "joint states rate (Hz)", "touch age (s)"} <= set(values(rec))

        # descriptors: the rule as a range, read-only where a change cannot apply
        described = listener.ask(describe, DescribeParameters.Request(names=["gate_mm", "live_every_touches"]), procs)
        gate, every = described.descriptors
        assert gate.read_only and [(r.from_value, r.to_value) for r in gate.floating_point_range] == [(0.0, 1e4)]
        assert not every.read_only and every.integer_range[0].from_value == 1

        def set_param(name, value: ParameterValue):
            request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=value)])
            return listener.ask(setter, request, procs).results[0]      # the same value twice is one change

        refused = set_param("gate_mm", ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=5.0))
        assert not refused.successful and "'gate_mm' is read when the node starts" in refused.reason, refused.reason

        # live_every_touches applied: the first update at once, then none for 1 new touch, until it is set to 1
        seen = len(status)
        progress.publish(String(data=json.dumps({"touches": touches.n_touches})))
        assert listener.spin_until(lambda: any(s.get("live") for s in status[seen:]), timeout=120, procs=procs)
        first_update = next(s for s in status[seen:] if s.get("live"))
        assert first_update["state"] == "updated", first_update
        progress.publish(String(data=json.dumps({"touches": touches.n_touches + 1})))
        seen = len(status)
        result = set_param("live_every_touches", ParameterValue(type=ParameterType.PARAMETER_INTEGER,
                                                               integer_value=1))
        assert result.successful, result.reason
        got = listener.ask(getter, GetParameters.Request(names=["live_every_touches"]), procs)
        assert got.values[0].integer_value == 1
        assert listener.spin_until(lambda: any(s.get("live") for s in status[seen:]), timeout=120, procs=procs)
        again = next(s for s in status[seen:] if s.get("live"))
        assert again["generation"] > first_update["generation"], again
    finally:
        if listener is not None:
            listener.close()
        codes = {p.name: p.stop() for p in (calibrate, recorder) if p is not None}
    assert codes == {"calibrate": 0, "pairing_recorder": 0}, (calibrate.stderr()[-3000:], recorder.stderr()[-3000:])
    assert "applied live_every_touches:=1" in calibrate.stderr()


@pytest.mark.middleware
def test_the_trigger_answers_with_the_calibrations_result_and_the_node_goes_on_meanwhile(tmp_path):
    """``success=True`` meant "started", also for a calibration that then failed, and the reply named the status
    topic without the node's namespace. Now the reply is the result, once the calibration has ended (where it
    was written, or the one line why not), names topics as the node resolves them, and the node answers other
    requests meanwhile."""
    import shutil
    import sys

    import numpy as np

    pytest.importorskip("rclpy")
    from rcl_interfaces.srv import GetParameters
    from ros_harness import Listener, Proc, ros_env, unique_domain_id
    from std_srvs.srv import Trigger

    from nao_skin.formats.bag import write_touch_bag
    from nao_skin.model.skin import load_skin
    from nao_skin.sim.simulate import simulate

    skin = load_skin()
    touches = simulate(skin, {"pairs": [["r_hand", "torso"]], "n_touches": 40}, seed=6).touches
    bag = tmp_path / "touches"
    write_touch_bag(bag, touches, skin)
    out = tmp_path / "cal"
    domain = unique_domain_id()
    listener = node = None
    try:
        listener = Listener(domain)
        node = Proc([sys.executable, "-m", "nao_skin.nodes.calibrate", "--ros-args", "-r", "__ns:=/nao7",
                     "-p", f"inputs:=['{bag}']", "-p", f"out_dir:={out}", "-p", "plots:=true"],   # plots: seconds
                    ros_env(domain), tmp_path, "calibrate")
        trigger = listener.node.create_client(Trigger, "/nao7/calibrate/calibrate")
        getter = listener.node.create_client(GetParameters, "/nao7/calibrate/get_parameters")
        assert listener.spin_until(lambda: trigger.service_is_ready() and getter.service_is_ready(), timeout=90,
                                   procs=[node])

        def answer(future):
            assert listener.spin_until(future.done, timeout=120, procs=[node])
            return future.result()

        first = trigger.call_async(Trigger.Request())
        assert listener.spin_until(lambda: "touches after removing" in node.stderr(), timeout=60, procs=[node])
        # while it calibrates: a second request is refused at once (handled after the first had ended, it would
        # have calibrated again), and the node answers other services
        busy = answer(trigger.call_async(Trigger.Request()))
        plots = answer(getter.call_async(GetParameters.Request(names=["plots"])))
        assert not busy.success and "running" in busy.message and "/nao7/nao_skin/calibration/status" in busy.message, \
            busy.message
        assert plots.values[0].bool_value
        done = answer(first)
        assert done.success and done.message.endswith(f"touches -> {out}"), done.message
        assert (out / "calibration.yaml").is_file()
        # the same bag with too few touches now: the answer is the failure's line
        shutil.rmtree(bag)
        write_touch_bag(bag, touches.subset(np.arange(3)), skin)
        failed = answer(trigger.call_async(Trigger.Request()))
        assert not failed.success and "a mount needs at least 10" in failed.message, failed.message
    finally:
        if listener is not None:
            listener.close()
        code = node.stop() if node is not None else None
    assert code == 0, node.stderr()[-3000:]
