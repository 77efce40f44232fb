"""What values a setting takes, as data: one :class:`Rule` per calibration option and node parameter.

The command line, the nodes' parameter declarations and ``nao-skin record``'s checks before any node
starts all read the same rules, so a value out of range is the same one line wherever it is given.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

from nao_skin.errors import DataError


@dataclass(frozen=True)
class Rule:
    """What values an option takes; :meth:`check` returns the value typed, or raises one line naming it."""

    kind: type                      # bool, int, float, str or tuple
    choices: tuple = ()             # allowed values (str) or allowed items (tuple)
    low: float | None = None
    high: float | None = None
    high_open: bool = False
    low_open: bool = False
    length: int | None = None       # tuple of this many numbers
    optional: bool = False          # None allowed
    why: str = ""                   # said after a value out of range
    pattern: str = ""               # a str must match this whole (regular expression) instead of a choice;
                                    # a tuple of them: at least one, each matching, none twice (names)

    def describe(self) -> str:
        if self.kind is bool:
            return "true or false"
        if self.kind is str:
            return "one of " + ", ".join(self.choices) if self.choices else (self.why or f"a text like {self.pattern}")
        if self.kind is tuple and self.choices:
            return "a list of " + ", ".join(self.choices) + ", each at most once"
        if self.kind is tuple and self.pattern:
            return self.why or f"a list of distinct names like {self.pattern}"
        what = "a whole number" if self.kind is int else "a number"
        if self.kind is tuple:
            what = f"{self.length} numbers"
        def number(v):
            return f"{int(v)}" if self.kind is int else f"{v:g}"

        if self.low is not None and self.high is not None:
            what += (f" in {'(' if self.low_open else '['}{number(self.low)}, {number(self.high)}"
                     f"{')' if self.high_open else ']'}")
        elif self.low is not None:
            what += f" {'>' if self.low_open else '>='} {number(self.low)}"
        return what + (" or null" if self.optional else "")

    def _number(self, value, kind):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError
        if kind is int:
            # a float beyond 2**53 is no whole number any more ('1.0e+22' passed as one)
            if float(value) != int(value) or (isinstance(value, float) and abs(value) > 2.0 ** 53):
                raise ValueError
            return int(value)
        value = float(value)
        if not math.isfinite(value):
            raise ValueError
        return value

    def _in_range(self, v) -> bool:
        return not ((self.low is not None and (v < self.low or (self.low_open and v == self.low)))
                    or (self.high is not None and (v > self.high or (self.high_open and v == self.high))))

    def check(self, where: str, value):
        said = self.why and not self.pattern      # a pattern's why is its description
        bad = DataError(f"{where}: expected {self.describe()}" + (f" ({self.why})" if said else ""))
        if value is None and self.optional:
            return None
        if self.kind is bool:
            if not isinstance(value, bool):
                raise bad
            return value
        if self.kind is str:
            if isinstance(value, bool) and {"on", "off"} <= set(self.choices):
                value = "on" if value else "off"   # a node's parameter file (YAML 1.1) reads on/off as booleans
            if (value not in self.choices if self.choices else
                    not isinstance(value, str) or not re.fullmatch(self.pattern or ".*", value)):
                raise bad
            return value
        if self.kind is tuple:
            if isinstance(value, str) or not isinstance(value, (list, tuple)):
                raise bad
            if self.choices:     # twice is no more than once, and would be run or reported twice
                if any(v not in self.choices for v in value) or len(set(value)) != len(value):
                    raise bad
                return tuple(value)
            if self.pattern:
                if (not value or len(set(map(str, value))) != len(value)
                        or not all(isinstance(v, str) and re.fullmatch(self.pattern, v) for v in value)):
                    raise bad
                return tuple(value)
            try:
                out = tuple(self._number(v, float) for v in value)
            except (ValueError, OverflowError):     # OverflowError: an integer beyond any float
                raise bad from None
            if len(out) != self.length or not all(self._in_range(v) for v in out):
                raise bad
            return out
        try:
            out = self._number(value, self.kind)
        except (ValueError, OverflowError):
            raise bad from None
        if not self._in_range(out):
            raise bad
        return out


def finite_float(value) -> float | None:
    """``value`` as a float when it is a finite number (not a bool, not an integer beyond any float), else None:
    what arrives in JSON or from a middleware is anybody's."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        value = float(value)
    except OverflowError:
        return None
    return value if math.isfinite(value) else None


def did_you_mean(name: str, known) -> str:
    """`` (did you mean 'x'?)`` for the known name closest to a mistyped ``name``, or ``""``."""
    import difflib

    close = difflib.get_close_matches(str(name), list(known), n=1)
    return f" (did you mean '{close[0]}'?)" if close else ""


def known_keys(doc: dict, known: tuple, where: str) -> None:
    """A key a config does not have is a typo whose value would be ignored without a word: ConfigError."""
    from nao_skin.errors import ConfigError

    for key in doc:
        if key not in known:
            raise ConfigError(f"{where}: unknown key '{key}'{did_you_mean(key, known)}; it takes {', '.join(known)}")


# the rules most settings need (Rule is frozen: these are constants)
POSITIVE = Rule(float, low=0.0, low_open=True)        # a length or tolerance
NON_NEGATIVE = Rule(float, low=0.0)
# a ROS timer counts its period in 64-bit nanoseconds (a rate of 1e-300 Hz overflows it); a day is the
# longest period that makes sense for a node, 1 kHz more than a Python callback keeps up with
SECONDS = Rule(float, low=0.0, low_open=True, high=86400.0)
SECONDS_OR_ZERO = Rule(float, low=0.0, high=86400.0)
RATE = Rule(float, low=1e-5, high=1000.0)             # Hz
AT_LEAST_ONE = Rule(int, low=1)                       # a count of things that must happen at least once
WHOLE = Rule(int, low=0)                              # a count or seed that may be 0
PORT = Rule(int, low=1, high=65535)
YARP_PORT = Rule(str, pattern=r"/\S+", why="a YARP port name: '/' and no spaces, e.g. /skinManager/skin_events:o")
YARP_PORT_OR_NONE = Rule(str, pattern=r"(/\S+)?", why="empty (no port) or a YARP port name: '/' and no spaces, e.g."
                                                      " /nao/skin/torso_comp")
JOINT_NAMES = Rule(tuple, pattern=r"[A-Za-z][A-Za-z0-9_]*", why="distinct joint names as NAOqi spells them (e.g."
                                                                " HeadYaw), at least one")
_OCTET = r"(?:25[0-5]|2[0-4][0-9]|1[0-9][0-9]|[1-9]?[0-9])"
_LABEL = r"[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
# an IPv4 address, or a host name whose last label is not all digits (999.1.1.1 is neither); no port: nao_port
HOST = Rule(str, pattern=rf"{_OCTET}(?:\.{_OCTET}){{3}}|(?:{_LABEL}\.)*(?=[A-Za-z0-9-]*[A-Za-z])(?:{_LABEL})",
            why="an IPv4 address or a host name, e.g. 192.168.1.10 or nao.local (the port is nao_port)")
