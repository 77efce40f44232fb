"""What each live node says on ``/diagnostics``, pure: message rates, ages and free disk -> a level, a line, values.

Every nao_skin node publishes one ``diagnostic_msgs/DiagnosticStatus`` a second (``nao_skin: <node's fully
qualified name>``, e.g. ``nao_skin: /nao2/calibrate``, what rqt_robot_monitor shows): :mod:`nao_skin.nodes.diagnostics`
only translates what is decided here. A node gathers its findings (:class:`Check`: a level, a line, key-values) and
:func:`summary` folds them into its one status: the worst level, the lines said at that level, every key-value.
"""
from __future__ import annotations

from dataclasses import dataclass

# diagnostic_msgs/DiagnosticStatus' levels (OK, WARN, ERROR; STALE is the aggregator's)
OK, WARN, ERROR = 0, 1, 2
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR"}

SLOW_FRACTION = 0.5           # a stream below this share of its expected rate is slow: WARN
DISK_WARN_BYTES = 1 << 30     # free space where a bag is written: WARN below 1 GiB ...
DISK_ERROR_BYTES = 100 << 20  # ... ERROR below 100 MiB: nearly full (the recorder stops when a write fails)


@dataclass(frozen=True)
class Check:
    """One finding of a node: its level, a line saying it ("" when there is nothing to say) and key-values."""

    level: int = OK
    message: str = ""
    values: tuple = ()        # ((key, text), ...)


def summary(checks) -> tuple:
    """``(level, message, values)`` of a node's findings: the worst level; the lines of the findings at that
    level (``OK`` when all is well and none said anything); every finding's key-values, in order."""
    checks = list(checks)
    level = max((c.level for c in checks), default=OK)
    lines = [c.message for c in checks if c.level == level and c.message]
    values = tuple(kv for c in checks for kv in c.values)
    return level, "; ".join(lines) or LEVEL_NAMES[level], values


def hz(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.1f}"


def rate_check(label: str, rate: float | None, expected: float, required: bool = True, needed: str = "") -> Check:
    """A stream's measured ``rate`` (Hz; None: not measured yet) against the ``expected`` one (the rate its
    publisher is set to): OK at :data:`SLOW_FRACTION` of it or more, WARN below; none at all is ERROR for a
    ``required`` stream (the node cannot do its work without it), WARN for another. ``needed`` (what needs it):
    ``expected`` is instead the least rate the node can work with, whatever its publisher sends (a recorder does
    not know the robot's rate): said as such, slow below it."""
    values = ((f"{label} rate (Hz)", hz(rate)),) + (
        ((f"{label} {'needed' if needed else 'expected'} (Hz)", hz(expected)),) if expected > 0 else ())
    if rate is None or expected <= 0:
        return Check(OK, "", values)
    wants = f"{needed} needs {expected:g} Hz" if needed else f"expected {expected:g} Hz"
    if rate <= 0:
        return Check(ERROR if required else WARN, f"no {label} ({wants})", values)
    if rate < (1.0 if needed else SLOW_FRACTION) * expected:
        return Check(WARN, f"{label} at {rate:.1f} Hz, {wants}", values)
    return Check(OK, "", values)


def age_check(label: str, age: float | None, warn_after: float | None = None) -> Check:
    """How long ago something last happened (s; None: never): said, and WARN when ``warn_after`` is given and
    it is older (never counts as fine: a session starts with no touch)."""
    values = ((f"{label} age (s)", "never" if age is None else f"{age:.1f}"),)
    if age is not None and warn_after is not None and age > warn_after:
        return Check(WARN, f"last {label} {age:.0f} s ago", values)
    return Check(OK, "", values)


def disk_check(path: str, free: int | None, total: int | None, error: str = "",
               warn_bytes: int = DISK_WARN_BYTES, error_bytes: int = DISK_ERROR_BYTES) -> Check:
    """Free space where ``path`` is written (bytes of ``total``; None with ``error``: it could not be read): ERROR
    when nearly full (below ``error_bytes``), WARN below ``warn_bytes``."""
    if free is None:
        return Check(ERROR, f"free space of {path} unknown ({error})", (("free disk (MiB)", "unknown"),))
    values = (("free disk (MiB)", f"{free / (1 << 20):.0f}"), ("disk path", str(path)))
    if total:
        values += (("disk used (%)", f"{100.0 * (1 - free / total):.1f}"),)
    if free < error_bytes:
        return Check(ERROR, f"disk nearly full where {path} is written: {free / (1 << 20):.0f} MiB free", values)
    if free < warn_bytes:
        return Check(WARN, f"{free / (1 << 20):.0f} MiB free where {path} is written", values)
    return Check(OK, "", values)


def live_check(status: dict, live: bool, busy: bool) -> Check:
    """The calibrate node's state from its last status (``/nao_skin/calibration/status``): a failed calibration
    or live update is WARN (the last good frames stay on /tf_static), the rest OK."""
    state = status.get("state", "starting")
    values = [("state", str(state)), ("live", "yes" if live else "no"), ("running", "yes" if busy else "no")]
    for key in ("generation", "touches", "recorded", "ignored_requests"):
        if key in status:
            values.append((key, str(status[key])))
    parts = status.get("parts")
    if isinstance(parts, dict):
        values += [(f"part {name}", str(state)) for name, state in sorted(parts.items())]
    if state == "failed":
        return Check(WARN, f"the last {'live update' if status.get('live') else 'calibration'} failed:"
                           f" {status.get('error', '')}".rstrip(": "), tuple(values))
    if state == "waiting" and status.get("reason"):
        return Check(OK, f"waiting: {status['reason']}", tuple(values))
    return Check(OK, "", tuple(values))


def count_check(label: str, count: int, warn_at: int = 1) -> Check:
    """A count of things that went wrong (malformed messages, bad reads): said, WARN from ``warn_at``."""
    values = ((label, str(count)),)
    if count >= warn_at:
        return Check(WARN, f"{count} {label}", values)
    return Check(OK, "", values)


class RateWindow:
    """A stream's rate from its running count, measured between two calls (the diagnostics' period)."""

    def __init__(self):
        self._last: tuple | None = None      # (count, time)

    def rate(self, count: int, now: float) -> float | None:
        """Messages per second since the last call (None at the first: nothing measured yet)."""
        last, self._last = self._last, (count, now)
        if last is None or now <= last[1]:
            return None
        return max(0, count - last[0]) / (now - last[1])
