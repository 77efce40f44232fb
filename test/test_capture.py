"""The capture core (nao_skin.capture): inverse kinematics within the limits less the margin, the approach, the
target chooser, every safety stop, and the loop driving the simulated body (nao_skin.sim.body, a mock of the
robot's body only) in its virtual time. Each safety stop's test fails without that stop: it checks what the
body was commanded, not only the reason said."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from nao_skin.capture.loop import AT_REST, CaptureLoop
from nao_skin.capture.plan import Approach, CaptureOptions, Planner, TargetChooser
from nao_skin.capture.safety import Abort, SafetyGate
from nao_skin.errors import ConfigError
from nao_skin.sim.body import SimBody
from nao_skin.sim.params import load_params

OPTIONS = CaptureOptions()


@pytest.fixture(scope="module")
def planner(skin):
    return Planner(skin, skin.zero_calibration(), "r_finger", "torso", OPTIONS)


@pytest.fixture(scope="module")
def approach(planner):
    """The plan to a taxel the right fingertip reaches from its rest pose (the first the chooser names)."""
    chooser = TargetChooser(planner.points, planner.slots)
    for _ in range(30):
        row = chooser.next()
        plan = planner.plan(row, planner.rest[planner.arm.cols])
        if isinstance(plan, Approach):
            return row, plan
        chooser.mark_unreachable(row)
    pytest.fail("no taxel of the torso reachable by the right fingertip")


def make_body(skin, seed=0):
    return SimBody(skin, "r_finger", "torso", load_params("fingertip-torso"), seed=seed)


class Session:
    """A loop over a simulated body; ``contacts`` replaces the body's skin, ``stop``/``age`` the node's flags."""

    def __init__(self, skin, planner, contacts=None, body=None):
        self.body = body or make_body(skin)
        self.stop = False
        self.age = 0.0
        self.aborts = []
        self.chooser = TargetChooser(planner.points, planner.slots)
        self.gate = SafetyGate(OPTIONS.stale_after, lambda: self.stop, lambda: self.age)
        self.loop = CaptureLoop(planner, self.chooser, self.body, contacts or self.body, self.gate, self.body.clock,
                                on_abort=self.aborts.append)

    def only(self, row):
        """The chooser names ``row`` first."""
        self.chooser.fired[:] = 1
        self.chooser.fired[row] = 0
        return self

    def stiffness_changes(self):
        return [(value, q) for kind, _, _, value, q in self.body.log if kind == "stiffness"]


def at_rest(planner, body):
    return np.max(np.abs(body.arm_angles(planner.arm.names) - planner.rest[planner.arm.cols])) <= AT_REST


# ---------------------------------------------------------------------------- planning
def test_the_approach_is_a_straight_line_down_the_normal_within_the_limits_less_the_margin(planner, approach):
    row, plan = approach
    arm = planner.arm
    assert arm.within(plan.path).all()
    # the limits less the margin are what the robot config says less 0.02 rad
    limits = planner.skin.robot.limits[arm.cols]
    assert np.allclose(arm.lo, limits[:, 0] + OPTIONS.limit_margin) and np.allclose(arm.hi, limits[:, 1] - 0.02)
    tip = planner.fingertip(plan.path)
    surface = plan.point + (planner.fabric + planner.radius) * plan.normal     # the centre at first contact
    along = (tip - surface) @ plan.normal
    assert along[0] == pytest.approx(OPTIONS.standoff, abs=5e-4)              # the standoff: 2 cm off
    assert along[-1] == pytest.approx(-OPTIONS.approach_margin, abs=5e-4)     # ... to the margin beyond
    assert np.all(np.diff(along) < 0)                                          # always towards the skin
    sideways = np.linalg.norm((tip - surface) - along[:, None] * plan.normal, axis=1)
    assert sideways.max() < 5e-4                                               # on the normal
    assert plan.budget == pytest.approx(OPTIONS.standoff + OPTIONS.approach_margin)
    assert planner.clear(plan.path).all()


def test_a_pose_with_the_forearm_on_the_skin_is_not_clear(planner):
    """Of random arm poses, every one with a point of the forearm (elbow to hand end) over the torso's skin and
    lower than the clearance, or under it, is refused; poses with the forearm high over it are not."""
    from nao_skin import se3

    arm = planner.arm
    q = arm.lo + np.random.default_rng(3).uniform(size=(3000, len(arm.cols))) * (arm.hi - arm.lo)
    end = planner.skin.robot.fk(arm.chain, planner.full(q))
    probes = se3.transform_points(end[:, None], np.linspace(0, 1, 5)[:, None] * planner.skin.robot.body.hand_end)
    height = planner.surface_height(probes.reshape(-1, 3)).reshape(len(q), -1).min(axis=1)
    low = height < OPTIONS.clearance
    clear = planner.clear(q)
    assert low.sum() > 10 and not clear[low].any()
    assert clear[np.isfinite(height) & ~low].any()


def test_a_taxel_out_of_reach_gets_a_reason_not_a_pose(skin):
    """The right fingertip on the torso's far left side, its joints kept 0.3 rad from their limits: no pose."""
    planner = Planner(skin, skin.zero_calibration(), "r_finger", "torso",
                      dataclasses.replace(OPTIONS, limit_margin=0.3))
    row = int(np.argmax(planner.points[:, 1]))                                # the torso's far left side
    why = planner.plan(row, planner.rest[planner.arm.cols])
    assert isinstance(why, str) and "limits" in why
    with pytest.raises(ConfigError, match="limit_margin 1 rad leaves no range to a joint of r_arm"):
        Planner(skin, skin.zero_calibration(), "r_finger", "torso", dataclasses.replace(OPTIONS, limit_margin=1.0))


def test_the_chooser_takes_unreached_taxels_farthest_first_and_never_an_unreachable_one(planner):
    chooser = TargetChooser(planner.points, planner.slots)
    first = chooser.next()
    chooser.record(planner.slots[[first]])
    second = chooser.next()
    assert second != first and chooser.fired[second] == 0
    d = np.linalg.norm(planner.points - planner.points[first], axis=1)
    d[chooser.fired > 0] = np.inf
    assert d[second] == d[np.isfinite(d)].max()                   # the farthest unreached one: spread
    chooser.mark_unreachable(second)
    assert all(chooser.next() != second for _ in range(5))
    chooser.fired[:] = 1
    other = int(np.flatnonzero(planner.slots // 12 != planner.slots[7] // 12)[-1])
    chooser.fired[[7, other]] = 0
    assert chooser.next(priority=[int(planner.slots[other] // 12)]) == other    # the guidance's triangle first
    assert chooser.next(priority=[int(planner.slots[7] // 12)]) == 7
    chooser.unreachable[:] = True
    assert chooser.next() is None and chooser.reachable_unreached() == 0 and chooser.arm() is None


def test_a_target_that_fired_only_its_neighbours_is_aimed_at_again_once_before_a_second_touch_anywhere(planner):
    chooser = TargetChooser(planner.points, planner.slots)
    chooser.fired[:] = 1
    chooser.fired[[3, 9]] = 0
    chooser.tried[:] = 1
    assert chooser.next() in (3, 9)            # tried once, its taxel never fired: before every taxel fired once
    missed = chooser.next()
    chooser.record(planner.slots[[missed + 1]], target=missed)    # the neighbour fired again, not the target
    assert chooser.next() == ({3, 9} - {missed}).pop()
    chooser.tried[[3, 9]] = 2                  # its retries used up: a taxel like any touched one
    assert chooser.next() not in (3, 9) and chooser.reachable_unreached() == 2
    once = TargetChooser(planner.points, planner.slots, retries=0)    # no retry: tried once is touched once
    once.tried[3] = 1
    assert once._score()[3] == 1.0


def test_the_other_arm_takes_the_taxels_one_cannot_reach(planner):
    chooser = TargetChooser(planner.points, planner.slots, arms=2)
    assert chooser.arm(0) == 0 and chooser.arm(1) == 1            # the arm in use while it has targets
    chooser.unreachable[0, :200] = True
    chooser.fired[200:] = 1                                       # arm 0 has touched all it reaches
    assert chooser.arm(0) == 1 and chooser.next(arm=1) < 200      # arm 1 takes what arm 0 cannot reach


# ---------------------------------------------------------------------------- the gate
def test_the_gate_refuses_a_command_beyond_the_limits_less_the_margin(planner):
    gate = SafetyGate(0.5, lambda: False, lambda: 0.0)
    inside = 0.5 * (planner.arm.lo + planner.arm.hi)
    assert np.array_equal(gate.command(inside, planner.arm), inside)
    beyond = inside.copy()
    beyond[1] = planner.arm.hi[1] + 0.001                     # within the joint's limit, not the margin
    with pytest.raises(Abort, match="beyond its limits less the margin") as caught:
        gate.command(beyond, planner.arm)
    assert caught.value.session
    with pytest.raises(Abort):
        gate.command(np.full(len(inside), np.nan), planner.arm)


def test_stale_joint_states_hold_the_arm_still_then_stop_the_capture():
    """With a clock to wait on (a robot's session), joint states late for a moment hold the arm (no Abort once
    fresh ones come within the hold); late for longer, the capture stops, saying it held."""
    clock = {"t": 0.0}
    fresh_at = {"t": 0.3}

    def age():
        return 0.8 if clock["t"] < fresh_at["t"] else 0.01

    def sleep(s):
        clock["t"] += s

    gate = SafetyGate(0.5, lambda: False, age, sleep=sleep, hold=2.0)
    gate.running()                                          # fresh after 0.3 s of holding: on
    assert 0.3 <= clock["t"] < 0.4
    clock["t"], fresh_at["t"] = 0.0, 10.0
    with pytest.raises(Abort, match=r"joint states 0.80 s old \(stale after 0.5 s, held 2.0 s\)"):
        gate.running()
    with pytest.raises(Abort, match="joint states 0.80 s old"):      # no clock (the pure loop): at once
        SafetyGate(0.5, lambda: False, lambda: 0.8).running()


def test_a_plan_beyond_the_limits_is_never_sent(skin, planner, approach, monkeypatch):
    row, plan = approach
    bad = plan.path.copy()
    bad[3:, 0] = planner.arm.hi[0] + 0.01                     # an approach waypoint beyond the margin
    monkeypatch.setattr(planner, "plan", lambda r, q: dataclasses.replace(plan, path=bad))
    s = Session(skin, planner).only(row)
    s.loop.run(1)
    sent = s.body.commands()
    assert planner.arm.within(sent).all(), "a command beyond the limits less the margin reached the body"
    assert "beyond its limits less the margin" in s.loop.stopped
    assert at_rest(planner, s.body) and s.stiffness_changes()[-1][0] == 0.0


class NoSkin:
    """A skin that never fires (a target that is not where the robot believes it)."""

    def fired(self, since):
        return {}


def test_an_approach_without_contact_stops_at_its_distance_plus_margin_and_retracts(skin, planner, approach):
    row, plan = approach
    s = Session(skin, planner, contacts=NoSkin()).only(row)
    result = s.loop.touch()
    budget = 1000 * (OPTIONS.standoff + OPTIONS.approach_margin)
    assert result.outcome == "aborted" and f"no contact on torso within {budget:.1f} mm" in result.reason
    sent = s.body.commands()
    # the deepest command is the plan's last waypoint, never beyond; then back at the standoff
    tip = planner.fingertip(sent)
    depth = (plan.point + (planner.fabric + planner.radius) * plan.normal - tip) @ plan.normal
    assert depth.max() <= OPTIONS.approach_margin + 1e-6
    assert np.allclose(sent[-1], plan.path[0])
    assert s.chooser.skipped[row] and len(s.aborts) == 1 and "touch aborted" in s.aborts[0]


class OtherPart:
    """The skin reports a contact on the left hand (the arm brushed something else), never on the torso."""

    def fired(self, since):
        return {"l_hand": (np.array([3]), 120.0)}


def test_a_contact_on_another_part_aborts_the_touch_and_retracts(skin, planner, approach):
    row, plan = approach
    s = Session(skin, planner, contacts=OtherPart()).only(row)
    result = s.loop.touch()
    assert result.outcome == "aborted" and result.reason == "contact on l_hand, not the target torso"
    sent = s.body.commands()
    assert len(sent) == 3 and np.allclose(sent[1], plan.path[1])       # standoff, one step, retract
    assert np.allclose(sent[-1], plan.path[0])


class StopAfter:
    """The body's skin; ``hook`` runs at the n-th reading (a Ctrl-C or stale joints mid-approach)."""

    def __init__(self, body, n, hook):
        self.body, self.n, self.hook = body, n, hook

    def fired(self, since):
        self.n -= 1
        if self.n == 0:
            self.hook()
        return self.body.fired(since)


@pytest.mark.parametrize("what", ["stop", "stale"])
def test_a_stop_or_stale_joint_states_mid_approach_retract_and_lower_the_arm_before_the_stiffness(
        skin, planner, approach, what):
    row, plan = approach
    body = make_body(skin)
    s = Session(skin, planner, body=body).only(row)

    def hook():
        if what == "stop":
            s.stop = True
        else:
            s.age = OPTIONS.stale_after + 0.1

    s.loop.contacts = StopAfter(body, 3, hook)
    s.loop.run(5)
    assert s.loop.stopped == ("stop requested" if what == "stop" else "joint states 0.60 s old (stale after 0.5 s)")
    sent = body.commands()
    assert len(sent) == 1 + 3 + 1 + 1         # standoff, three steps, the retract, the rest pose
    assert np.allclose(sent[-2], plan.path[0]) and np.allclose(sent[-1], planner.rest[planner.arm.cols])
    (on, _), (off, q_off) = s.stiffness_changes()
    assert on == OPTIONS.stiffness and off == 0.0
    assert np.max(np.abs(q_off[planner.arm.cols] - planner.rest[planner.arm.cols])) <= AT_REST
    assert len(s.aborts) == 1 and s.aborts[0].startswith("capture stopped: ")


class StuckBody(SimBody):
    """The arm does not get to its rest pose (held, blocked): it stays where the capture left it."""

    def angleInterpolationWithSpeed(self, names, angles, fraction):  # noqa: N802
        rest = np.array([self.skin.robot.body.rest_posture[n][0] for n in names])
        if np.allclose(angles, rest):
            self.log.append(("command", self.clock.now(), list(names), list(map(float, angles)), fraction))
            return
        super().angleInterpolationWithSpeed(names, angles, fraction)


def test_the_stiffness_is_never_dropped_with_the_arm_raised(skin, planner, approach):
    row, _ = approach
    body = StuckBody(skin, "r_finger", "torso", load_params("fingertip-torso"), seed=0)
    s = Session(skin, planner, body=body).only(row)
    s.loop.run(1)
    assert [v for v, _ in s.stiffness_changes()] == [OPTIONS.stiffness]        # on, never off
    assert s.loop.state == "stiff" and "stiffness kept" in s.aborts[-1]


def test_naoqi_lost_mid_approach_stops_the_session_and_keeps_the_stiffness(skin, planner, approach):
    row, _ = approach
    body = make_body(skin)
    s = Session(skin, planner, body=body).only(row)
    s.loop.contacts = StopAfter(body, 2, lambda: setattr(body, "lost", True))
    s.loop.run(3)
    assert s.loop.stopped.startswith("NAOqi lost")
    assert [v for v, _ in s.stiffness_changes()] == [OPTIONS.stiffness]


# ---------------------------------------------------------------------------- touches
def test_touches_fire_the_target_press_at_most_2_mm_and_end_at_rest(skin, planner):
    s = Session(skin, planner)
    results = s.loop.run(10, until_done=False)
    touched = [r for r in results if r.outcome == "touched"]
    assert len(touched) >= 3
    assert all(len(r.fired) for r in touched)
    assert s.chooser.fired.sum() >= len(touched)
    assert planner.arm.within(s.body.commands()).all()
    # the simulator's ground truth: no press went on more than 2 mm beyond where the skin first fired
    assert len(s.body.beyond) >= len(touched)
    assert max(s.body.beyond) <= 0.002
    assert at_rest(planner, s.body) and s.stiffness_changes()[-1][0] == 0.0
    assert s.loop.stopped is None


def test_a_dry_run_plans_and_moves_nothing(skin, planner):
    s = Session(skin, planner)
    shown = []
    s.loop.on_plan = shown.append
    plans = s.loop.plan_only(3)
    assert len(plans) == 3 and shown == plans and len({p.slot for p in plans}) == 3
    assert s.body.log == []
