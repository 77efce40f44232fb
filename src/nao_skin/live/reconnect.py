"""Reconnection with exponential back-off, logged once per outage (pure, clock passed in).

Bridges to middleware that can vanish (NAOqi on the robot, YARP ports) call
:meth:`Backoff.due` before an attempt, then :meth:`Backoff.failed` or
:meth:`Backoff.succeeded`. Each returns the one line to log, or ``None``:
the first failure of an outage and the recovery are logged, the retries in
between are not, so a robot switched off for an hour does not flood the log.
"""
from __future__ import annotations


class Backoff:
    def __init__(self, what: str, initial: float = 0.5, maximum: float = 5.0, factor: float = 2.0):
        if not 0 < initial <= maximum or factor < 1:
            raise ValueError(f"{what}: back-off needs 0 < initial <= maximum and factor >= 1")
        self.what = what
        self.initial, self.maximum, self.factor = float(initial), float(maximum), float(factor)
        self.delay = self.initial
        self.next_attempt = float("-inf")
        self.connected = False
        self.ever_connected = False              # an outage of a link never made is its first connection
        self.outage_start: float | None = None   # time of the first failure of the current outage
        self.attempts = 0                        # failed attempts in the current outage
        self.outages = 0                         # outages so far (first connection failures included)

    def due(self, now: float) -> bool:
        """Whether an attempt should be made now."""
        return not self.connected and now >= self.next_attempt

    def failed(self, now: float, reason: str) -> str | None:
        """An attempt failed, or a working link broke. Schedules the next attempt."""
        first = self.outage_start is None
        if first:
            self.outage_start = now
            self.outages += 1
            self.delay = self.initial
        else:
            self.delay = min(self.delay * self.factor, self.maximum)
        self.connected = False
        self.attempts += 1
        self.next_attempt = now + self.delay
        if first:
            every = f"{self.initial:g}" if self.initial == self.maximum else f"{self.initial:g}-{self.maximum:g}"
            return f"{self.what}: {reason}; retrying every {every} s (logged once per outage)"
        return None

    def succeeded(self, now: float) -> str | None:
        """An attempt worked; returns the recovery line if there was an outage."""
        self.connected = True
        line = None
        if self.outage_start is not None:
            line = (f"{self.what}: connected {'again ' if self.ever_connected else ''}after"
                    f" {now - self.outage_start:.1f} s ({self.attempts} failed attempts)")
        elif self.attempts == 0:
            line = f"{self.what}: connected"
        self.ever_connected = True
        self.outage_start = None
        self.attempts = 0
        self.delay = self.initial
        return line
