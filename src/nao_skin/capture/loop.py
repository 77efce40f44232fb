"""The capture loop: touch after touch, the robot presses its fingertip on the target part, through ALMotion's calls.

A touch goes through the states ``to_standoff`` (a joint-space move to the standoff pose, over the rest pose when
the direct move would not keep clear of the body) -> ``approach`` (one step of ``step`` metres along the normal
at a time, the contact checked after each) -> ``press`` (after the first contact, on while the highest pressure
still rises, at most ``press_max`` beyond it) -> ``hold`` -> ``retract`` (back to the standoff pose). An
:class:`~nao_skin.capture.safety.Abort` in any state retracts; one of the session (stop requested, stale
joint states, a command beyond the limits, NAOqi gone) then ends the capture with :meth:`CaptureLoop.finish`,
which lowers the arm to its rest pose and drops the stiffness only once the arm is seen there.

``Motion`` is what the loop calls of NAOqi's ALMotion, by its names, so the node hands it the libqi proxy itself
and the tests a simulated body (:class:`nao_skin.sim.body.SimBody`). ``Contacts.fired(since)`` says which parts
fired (``{part: (slots, max pressure)}``) in skin readings taken after ``since`` on ``clock``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from nao_skin.capture.plan import Approach, Planner, TargetChooser
from nao_skin.capture.safety import Abort, SafetyGate
from nao_skin.errors import one_line

PRESSURE_RISE = 2.0   # of 255: a step of the press that adds less has met the skin (the pressure saturated)
AT_REST = 0.05        # rad: the arm is at rest when every joint is this close to the rest pose


class Motion(Protocol):
    """NAOqi's ALMotion calls the capture makes (same names and arguments)."""

    def setStiffnesses(self, names, stiffnesses) -> None: ...                  # noqa: N802, E704
    def angleInterpolationWithSpeed(self, names, angles, fraction) -> None: ...  # noqa: N802, E704
    def getAngles(self, names, useSensors) -> list: ...                        # noqa: N802, E704
    def killTasksUsingResources(self, names) -> None: ...                      # noqa: N802, E704


class Contacts(Protocol):
    def fired(self, since: float) -> dict: ...      # noqa: E704


class Clock(Protocol):
    def now(self) -> float: ...                      # noqa: E704
    def sleep(self, seconds: float) -> None: ...     # noqa: E704


@dataclass
class TouchResult:
    """What one target came to: ``touched`` (``fired``: the part's slots that fired), ``unreachable`` (no plan,
    the taxel marked), or ``aborted`` (``reason``)."""

    slot: int | None
    outcome: str
    reason: str = ""
    fired: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    contact_travel: float | None = None      # m from the standoff to the first contact
    deepest_travel: float | None = None      # m from the standoff to where the press stopped
    pressed: np.ndarray | None = None        # (V,) the arm's commanded angles where the press was held
    contact: np.ndarray | None = None        # (V,) ... where the skin first fired


class CaptureLoop:
    """The loop over one fingertip's ``Planner`` or several (one per arm, each its own fingertip: the torso's
    side one arm cannot reach the other does); ``chooser`` with as many ``arms``. One arm moves at a time: the
    other waits at its rest pose, stiff."""

    def __init__(self, planners, chooser: TargetChooser, motion: Motion, contacts: Contacts,
                 gate: SafetyGate, clock: Clock,
                 log: Callable[[str], None] = lambda line: None,
                 on_abort: Callable[[str], None] = lambda reason: None,
                 on_plan: Callable[[Approach], None] = lambda approach: None):
        self.planners = [planners] if isinstance(planners, Planner) else list(planners)
        if chooser.arms != len(self.planners):
            raise ValueError(f"a chooser of {chooser.arms} arms for {len(self.planners)} planners")
        self.active = 0
        self.chooser, self.motion, self.contacts = chooser, motion, contacts
        self.gate, self.clock = gate, clock
        self.options = self.planners[0].options
        self.part = self.planners[0].part
        self.log, self.on_abort, self.on_plan = log, on_abort, on_plan
        self.state = "idle"
        self.results: list = []
        self.commands = 0
        self.stopped: str | None = None       # why the session stopped
        self.priority = None                  # the guidance's triangles of the part, best first

    @property
    def planner(self) -> Planner:
        """The planner of the arm in use."""
        return self.planners[self.active]

    @property
    def names(self) -> list:
        return list(self.planner.arm.names)

    # ------------------------------------------------------------------ motion through the gate
    def _move(self, q_arm: np.ndarray, fraction: float, planner: Planner | None = None) -> None:
        arm = (planner or self.planner).arm
        q_arm = self.gate.command(q_arm, arm)     # nothing beyond the limits less the margin is ever sent
        try:
            self.motion.angleInterpolationWithSpeed(list(arm.names), [float(v) for v in q_arm], float(fraction))
        except Exception as exc:  # noqa: BLE001 - libqi raises RuntimeError and others: the robot is gone
            raise Abort(f"NAOqi lost ({one_line(exc)})", session=True) from None
        self.commands += 1

    def _angles(self, planner: Planner | None = None) -> np.ndarray:
        try:
            return np.asarray(self.motion.getAngles(list((planner or self.planner).arm.names), True), float)
        except Exception as exc:  # noqa: BLE001 - as in _move
            raise Abort(f"NAOqi lost ({one_line(exc)})", session=True) from None

    # ------------------------------------------------------------------ the session
    def start(self) -> None:
        self.gate.running()
        try:
            for planner in self.planners:
                self.motion.setStiffnesses(list(planner.arm.names), float(self.options.stiffness))
        except Exception as exc:  # noqa: BLE001
            raise Abort(f"NAOqi lost ({one_line(exc)})", session=True) from None
        self.state = "started"

    def run(self, max_touches: int, until_done: bool = True) -> list:
        """Touch until ``max_touches`` targets were tried, every reachable taxel fired (``until_done``), or a
        stop; then :meth:`finish`. Returns the results."""
        try:
            self.start()
            while len(self.results) < max_touches and self.stopped is None:
                if until_done and self.chooser.reachable_unreached() == 0:
                    break
                if self.touch() is None:
                    break
        except Abort as abort:
            self._abort(abort)
        finally:
            self.finish()
        return self.results

    def touch(self) -> TouchResult | None:
        """One target, None when no target is left."""
        self.gate.running()
        arm = self.chooser.arm(self.active, self.priority)
        if arm is None:
            return None
        if arm != self.active:        # the arm in use goes to rest (stiff) before the other one moves
            self.state = "to_rest"
            self._move(self.planner.rest[self.planner.arm.cols], self.options.move_speed)
            self.active = arm
        row = self.chooser.next(self.priority, self.active)
        q_now = self._angles()
        plan = self.planner.plan(row, q_now)
        if isinstance(plan, str):
            self.chooser.mark_unreachable(row, self.active)
            result = TouchResult(int(self.chooser.slots[row]), "unreachable", plan)
            self.results.append(result)
            return result
        self.on_plan(plan)
        try:
            result = self._press(plan, q_now, row)
        except Abort as abort:
            self._retract(plan)
            if abort.session:
                raise
            self._abort(abort, session=False)
            # a touch stopped on the way is not tried again: the next target is another taxel
            self.chooser.skip(row)
            result = TouchResult(plan.slot, "aborted", abort.reason)
        self.results.append(result)
        return result

    def _press(self, plan: Approach, q_now: np.ndarray, row: int) -> TouchResult:
        o, gate = self.options, self.gate
        self.state = "to_standoff"
        if not self.planner.transit_clear(q_now, plan.path[0]):
            self._move(self.planner.rest[self.planner.arm.cols], o.move_speed)
        self._move(plan.path[0], o.move_speed)
        self.state = "approach"
        steps = list(zip(plan.path[1:], plan.travel[1:]))      # (arm angles, travel from the standoff)
        fired_slots, first, last, i = [], None, -np.inf, 0
        contact = pressed = deepest = None
        while i < len(steps):
            q, travel = steps[i]
            gate.running()
            self._move(q, o.approach_speed)
            pressed, deepest = q, travel
            fired = self._fired()
            if gate.contact(fired, self.part):
                slots, pressure = fired[self.part]
                fired_slots.append(slots)
                if first is None:
                    first, contact = travel, q
                    self.state = "press"
                    # the press in half steps: the fabric's last millimetres decide how far beyond the skin goes
                    halves = [((a + b) / 2, (ta + tb) / 2) for (a, ta), (b, tb) in zip(steps[i:], steps[i + 1:])]
                    steps = steps[:i + 1] + [x for pair in zip(halves, steps[i + 1:]) for x in pair]
                # the fabric stopped giving (the pressure no longer rises): the fingertip is on the skin
                if pressure <= last + PRESSURE_RISE:
                    break
                last = pressure
            elif first is None:
                gate.approach(travel, plan.budget, self.part)
            # never deeper than press_max beyond the first contact, whether or not the skin still reads it: the
            # next step is not made when it would go farther
            if first is not None and (i + 1 == len(steps) or steps[i + 1][1] - first > o.press_max + 1e-9):
                break
            i += 1
        self.state = "hold"
        gate.running()
        self.clock.sleep(o.hold)
        fired = self._fired()
        if gate.contact(fired, self.part):
            fired_slots.append(fired[self.part][0])
        self._retract(plan)
        slots = np.unique(np.concatenate(fired_slots)) if fired_slots else np.zeros(0, int)
        self.chooser.record(slots, row)
        self.planner.aim_again(row, slots)
        return TouchResult(plan.slot, "touched", fired=slots, contact_travel=float(first),
                           deepest_travel=float(deepest), pressed=np.array(pressed), contact=np.array(contact))

    def _fired(self) -> dict:
        """What fired since this moment, read ``contact_wait`` later (the skin's readings of the step just made)."""
        since = self.clock.now()
        self.clock.sleep(self.options.contact_wait)
        return self.contacts.fired(since)

    def _retract(self, plan: Approach) -> None:
        """Back to the standoff pose (the approach line reversed: one short joint-space move)."""
        self.state = "retract"
        try:
            self._move(plan.path[0], self.options.retract_speed)
        except Abort as abort:
            self.log(f"cannot retract: {abort.reason}")
            raise

    def _abort(self, abort: Abort, session: bool = True) -> None:
        line = f"capture {'stopped' if session else 'touch aborted'}: {abort.reason}"
        if session:
            self.stopped = abort.reason
        self.log(line)
        self.on_abort(line)

    def finish(self) -> None:
        """Lower each arm to its rest pose, then drop its stiffness, only once the arm is seen there: a raised
        arm without stiffness falls on whatever is below it."""
        if self.state == "idle":
            return
        self.state = "to_rest"
        order = [self.active] + [a for a in range(len(self.planners)) if a != self.active]
        kept = []
        for a in order:
            planner = self.planners[a]
            rest = planner.rest[planner.arm.cols]
            try:
                self._move(rest, self.options.move_speed, planner)
                off = float(np.max(np.abs(self._angles(planner) - rest)))
            except Abort as abort:
                kept.append(f"{planner.arm.chain} could not be lowered ({abort.reason})")
                continue
            if off > AT_REST:
                kept.append(f"{planner.arm.chain} is not at rest ({off:.2f} rad off)")
                continue
            try:
                self.motion.setStiffnesses(list(planner.arm.names), 0.0)
            except Exception as exc:  # noqa: BLE001
                self.log(f"stiffness not dropped: NAOqi lost ({one_line(exc)})")
        if kept:
            line = "stiffness kept: " + "; ".join(kept)
            self.log(line)
            self.on_abort(line)
            self.state = "stiff"
            return
        self.state = "rest"

    def plan_only(self, n: int) -> list:
        """Dry run: the approaches to the next ``n`` targets (as if each fired its own taxel), nothing moved."""
        q = [p.rest[p.arm.cols] for p in self.planners]
        out = []
        while len(out) < n:
            arm = self.chooser.arm(self.active, self.priority)
            if arm is None:
                break
            self.active = arm
            row = self.chooser.next(self.priority, arm)
            plan = self.planner.plan(row, q[arm])
            if isinstance(plan, str):
                self.chooser.mark_unreachable(row, arm)
                continue
            self.chooser.record([plan.slot])
            self.on_plan(plan)
            out.append(plan)
            q[arm] = plan.path[0]
        return out
