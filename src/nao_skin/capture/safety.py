"""The safety gate of the capture: every command and every reading passes it; what it refuses stops the touch.

Each stop is an :class:`Abort` with a one-line reason (the node logs it and puts it on its diagnostics). The
gate judges; the loop (:mod:`nao_skin.capture.loop`) acts on its verdict: it retracts, and stops the session
where the reason is one to stop for (:attr:`Abort.session`).
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from nao_skin.capture.plan import Arm


class Abort(Exception):
    """A touch (``session=False``: the next one may go on) or the whole capture (``session=True``) stopped."""

    def __init__(self, reason: str, session: bool = False):
        super().__init__(reason)
        self.reason = reason
        self.session = session


# s the arm holds still, between two steps, for joint states (or skin readings) newer than stale_after before
# the capture stops: a loaded robot PC delays a stream for tenths of a second now and then (0.55 s seen on the
# 2-core test machine under load), where holding still harms nothing and a stopped capture costs the session
STALE_HOLD = 2.0
HOLD_POLL = 0.05             # s between two looks while holding


class SafetyGate:
    """The checks of :mod:`nao_skin.capture`: see each method. ``stop_requested()`` is True once anybody asked
    the capture to stop (Ctrl-C, the ``~/stop`` service); ``joint_age()`` is the age (s) of the newest joint
    state, None before the first; ``lost()`` says why NAOqi is gone, None while it is there; ``sleep(s)``
    (given: a real robot's session) lets :meth:`running` hold still up to ``hold`` s for fresh joint states."""

    def __init__(self, stale_after: float, stop_requested: Callable[[], bool],
                 joint_age: Callable[[], float | None], lost: Callable[[], str | None] = lambda: None,
                 sleep: Callable[[float], None] | None = None, hold: float = STALE_HOLD):
        self.stale_after = float(stale_after)
        self.stop_requested = stop_requested
        self.joint_age = joint_age
        self.lost = lost
        self.sleep, self.hold = sleep, float(hold) if sleep is not None else 0.0

    @staticmethod
    def command(q_arm: np.ndarray, arm: Arm) -> np.ndarray:
        """``q_arm`` as a command of ``arm``, or an Abort when a joint lies beyond its limits less the margin (a
        plan that would: nothing of it is sent)."""
        q_arm = np.asarray(q_arm, float)
        if q_arm.shape != (len(arm.names),) or not np.all(np.isfinite(q_arm)):
            raise Abort(f"command {q_arm!r} is not {len(arm.names)} finite angles", session=True)
        if not arm.within(q_arm)[0]:
            bad = int(np.flatnonzero(~((q_arm >= arm.lo - 1e-12) & (q_arm <= arm.hi + 1e-12)))[0])
            raise Abort(f"command {arm.names[bad]}={q_arm[bad]:.3f} rad beyond its limits less the margin"
                        f" [{arm.lo[bad]:.3f}, {arm.hi[bad]:.3f}]", session=True)
        return q_arm

    def running(self) -> None:
        """Abort (the session) when a stop was requested, NAOqi is gone or the joint states went stale (and
        stayed so while the arm held still for ``hold`` s)."""
        if self.stop_requested():
            raise Abort("stop requested", session=True)
        lost = self.lost()
        if lost:
            raise Abort(f"NAOqi lost ({lost})", session=True)
        age, held = self.joint_age(), 0.0
        while (age is None or age > self.stale_after) and held < self.hold and not self.stop_requested():
            self.sleep(HOLD_POLL)
            held += HOLD_POLL
            age = self.joint_age()
        if self.stop_requested():
            raise Abort("stop requested", session=True)
        if age is None or age > self.stale_after:
            said = "no joint states" if age is None else f"joint states {age:.2f} s old"
            raise Abort(f"{said} (stale after {self.stale_after:g} s{f', held {held:.1f} s' if held else ''})",
                        session=True)

    @staticmethod
    def contact(fired: dict, target: str) -> bool:
        """True when ``target`` fired; an Abort of the touch when any other part did (``fired``: part -> what
        fired, parts that fired only)."""
        others = sorted(p for p in fired if p != target)
        if others:
            raise Abort(f"contact on {', '.join(others)}, not the target {target}")
        return target in fired

    @staticmethod
    def approach(travelled: float, budget: float, target: str) -> None:
        """Abort the touch once the approach has gone its distance plus margin without a contact."""
        if travelled >= budget - 1e-9:
            raise Abort(f"no contact on {target} within {budget * 1000:.1f} mm of approach")
