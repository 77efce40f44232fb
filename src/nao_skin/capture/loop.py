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
    def __init__(self, planner: Planner, chooser: TargetChooser, motion: Motion, contacts: Contacts,
                 gate: SafetyGate, clock: Clock, contact_wait: float = 0.0,
                 log: Callable[[str], None] = lambda line: None,
                 on_abort: Callable[[str], None] = lambda reason: None,
                 on_plan: Callable[[Approach], None] = lambda approach: None):
        self.planner, self.chooser, self.motion, self.contacts = planner, chooser, motion, contacts
        self.gate, self.clock, self.contact_wait = gate, clock, float(contact_wait)
        self.options = planner.options
        self.names = list(planner.arm.names)
        self.part = planner.part
        self.log, self.on_abort, self.on_plan = log, on_abort, on_plan
        self.state = "idle"
        self.results: list = []
        self.commands = 0
        self.stopped: str | None = None       # why the session stopped
        self.priority = None                  # the guidance's triangles of the part, best first

    # ------------------------------------------------------------------ motion through the gate
    def _move(self, q_arm: np.ndarray, fraction: float) -> None:
        q_arm = self.gate.command(q_arm)          # nothing beyond the limits less the margin is ever sent
        try:
            self.motion.angleInterpolationWithSpeed(self.names, [float(v) for v in q_arm], float(fraction))
        except Exception as exc:  # noqa: BLE001 - libqi raises RuntimeError and others: the robot is gone
            raise Abort(f"NAOqi lost ({one_line(exc)})", session=True) from None
        self.commands += 1

    def _angles(self) -> np.ndarray:
        try:
            return np.asarray(self.motion.getAngles(self.names, True), float)
        except Exception as exc:  # noqa: BLE001 - as in _move
            raise Abort(f"NAOqi lost ({one_line(exc)})", session=True) from None

    # ------------------------------------------------------------------ the session
    def start(self) -> None:
        self.gate.running()
        try:
            self.motion.setStiffnesses(self.names, float(self.options.stiffness))
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
        row = self.chooser.next(self.priority)
        if row is None:
            return None
        q_now = self._angles()
        plan = self.planner.plan(row, q_now)
        if isinstance(plan, str):
            self.chooser.mark_unreachable(row)
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
        fired_slots, first, k, last = [], None, 0, -np.inf
        for k in range(1, len(plan.path)):
            gate.running()
            self._move(plan.path[k], o.approach_speed)
            fired = self._fired()
            if gate.contact(fired, self.part):
                slots, pressure = fired[self.part]
                fired_slots.append(slots)
                if first is None:
                    first = k
                    self.state = "press"
                # the fabric stopped giving (the pressure no longer rises): the fingertip is on the skin
                if pressure <= last + PRESSURE_RISE:
                    break
                last = pressure
            elif first is None:
                gate.approach(plan.travel[k], plan.budget, self.part)
            # never deeper than press_max beyond the first contact, whether or not the skin still reads it: the
            # next step is not made when it would go farther
            if first is not None and (k + 1 == len(plan.path)
                                      or plan.travel[k + 1] - plan.travel[first] > o.press_max + 1e-9):
                break
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
        return TouchResult(plan.slot, "touched", fired=slots, contact_travel=float(plan.travel[first]),
                           deepest_travel=float(plan.travel[k]), pressed=plan.path[k].copy(),
                           contact=plan.path[first].copy())

    def _fired(self) -> dict:
        """What fired since this moment less ``contact_wait`` (the skin's readings of the step just made)."""
        since = self.clock.now()
        if self.contact_wait > 0:
            self.clock.sleep(self.contact_wait)
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
        """Lower the arm to its rest pose, then drop the stiffness, only once the arm is seen there: a raised
        arm without stiffness falls on whatever is below it."""
        if self.state == "idle":
            return
        self.state = "to_rest"
        rest = self.planner.rest[self.planner.arm.cols]
        try:
            self._move(rest, self.options.move_speed)
            at = self._angles()
        except Abort as abort:
            self.log(f"stiffness kept: the arm could not be lowered ({abort.reason})")
            self.on_abort(f"stiffness kept: {abort.reason}")
            self.state = "stiff"
            return
        if np.max(np.abs(at - rest)) > AT_REST:
            self.log(f"stiffness kept: the arm is not at rest ({np.max(np.abs(at - rest)):.2f} rad off)")
            self.on_abort("stiffness kept: the arm is not at rest")
            self.state = "stiff"
            return
        try:
            self.motion.setStiffnesses(self.names, 0.0)
        except Exception as exc:  # noqa: BLE001
            self.log(f"stiffness not dropped: NAOqi lost ({one_line(exc)})")
        self.state = "rest"

    def plan_only(self, n: int) -> list:
        """Dry run: the approaches to the next ``n`` targets (as if each fired its own taxel), nothing moved."""
        q = self.planner.rest[self.planner.arm.cols]
        out = []
        while len(out) < n:
            row = self.chooser.next(self.priority)
            if row is None:
                break
            plan = self.planner.plan(row, q)
            if isinstance(plan, str):
                self.chooser.mark_unreachable(row)
                continue
            self.chooser.record([plan.slot])
            self.on_plan(plan)
            out.append(plan)
            q = plan.path[0]
        return out
