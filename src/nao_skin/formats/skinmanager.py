"""skinManager output as arrays: skin event bottles (skinContactList) and compensated taxel vectors.

A skinContactList travels as a YARP bottle holding one list per contact::

    ((contactId bodyPart linkNumber skinPart) (cop x y z) (force) (moment)
     (geoCenter) (normal) (taxelId ...) pressure)

(iCub skinDynLib ``skinContact::write``; positions in the skin part's link
frame, metres). ``skinPart`` is skinDynLib's numeric SkinPart enum, whose
meaning depends on the build (the Nao build reuses iCub slots, e.g. the head
on SKIN_RIGHT_FOREARM), so the id -> part name mapping is configuration.

The parser works on the bottle's text form (``Bottle.toString()``), which
keeps this module free of the YARP bindings and testable anywhere. Every
defect raises :class:`DataError` with one line naming the source (port) and
the contact; the bridge counts and skips such bottles.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from nao_skin.errors import ConfigError, DataError

_TOKEN = re.compile(r'\s*(?:(\()|(\))|("(?:[^"\\]|\\.)*")|([^\s()"]+))')
_CONTACT_FIELDS = ("ids", "cop", "force", "moment", "geoCenter", "normal", "taxels", "pressure")


def parse_bottle_text(text: str, where: str) -> list:
    """YARP bottle text to nested Python lists of ints/floats/strings (no eval)."""
    stack: list = [[]]
    pos = 0
    text = text.strip()
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None or m.end() == pos:
            raise DataError(f"{where}: cannot read bottle text at character {pos}")
        pos = m.end()
        open_, close, quoted, word = m.groups()
        if open_:
            stack.append([])
        elif close:
            if len(stack) == 1:
                raise DataError(f"{where}: unbalanced ')' at character {pos - 1}")
            done = stack.pop()
            stack[-1].append(done)
        elif quoted is not None:
            stack[-1].append(quoted[1:-1])
        elif word is not None:
            stack[-1].append(_number(word))
    if len(stack) != 1:
        raise DataError(f"{where}: unbalanced '(' in bottle text")
    return stack[0]


def _number(word: str):
    try:
        return int(word)
    except ValueError:
        pass
    try:
        return float(word)
    except ValueError:
        return word


@dataclass
class SkinEvents:
    """One skinContactList as flat arrays: K contacts, A activated taxels."""

    skin_part: np.ndarray      # (K,) int: skinDynLib SkinPart id
    contact_id: np.ndarray     # (K,) int
    body_part: np.ndarray      # (K,) int
    link: np.ndarray           # (K,) int
    cop: np.ndarray            # (K, 3)
    force: np.ndarray          # (K, 3)
    moment: np.ndarray         # (K, 3)
    geo_center: np.ndarray     # (K, 3)
    normal: np.ndarray         # (K, 3)
    pressure: np.ndarray       # (K,)
    taxel_contact: np.ndarray  # (A,) int: row of the contact each taxel belongs to
    taxel_id: np.ndarray       # (A,) int: taxel id (= slot on the part)

    @property
    def n_contacts(self) -> int:
        return len(self.contact_id)

    def of_part(self, skin_part_id: int) -> tuple:
        """(contact rows, taxel rows) of one skinDynLib part id."""
        rows = np.flatnonzero(self.skin_part == skin_part_id)
        taxels = np.flatnonzero(np.isin(self.taxel_contact, rows))
        return rows, taxels


MAX_CONTACT_ID = 2 ** 31 - 1                       # the int32 'contact' field of the taxel points
FLOAT32_MAX = float(np.finfo(np.float32).max)        # COPs, forces and pressures are published as float32


def _vector(value, n: int, where: str, what: str, kind=float) -> list:
    if not isinstance(value, list) or len(value) != n:
        got = f"{len(value)} values" if isinstance(value, list) else repr(value)
        raise DataError(f"{where}: {what} must be a list of {n} numbers, got {got}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or (kind is int and not isinstance(v, int)):
            raise DataError(f"{where}: {what} holds {v!r}, not {'an integer' if kind is int else 'a number'}")
        out.append(kind(v))
    return out


def contacts_from_lists(items: list, where: str, max_taxel_id: int = 1 << 16) -> SkinEvents:
    """Nested lists of a skinContactList (see :func:`parse_bottle_text`) to :class:`SkinEvents`."""
    if not isinstance(items, list):
        raise DataError(f"{where}: a skin event bottle must be a list of contacts")
    ids, vecs, pressure, t_contact, t_id = [], [], [], [], []
    for k, c in enumerate(items):
        here = f"{where}: contact {k}"
        if not isinstance(c, list) or len(c) != len(_CONTACT_FIELDS):
            n = len(c) if isinstance(c, list) else "no list"
            raise DataError(f"{here}: expected 8 items ({' '.join(_CONTACT_FIELDS)}), got {n}")
        head = _vector(c[0], 4, here, "(contactId bodyPart linkNumber skinPart)", int)
        if not 0 <= head[0] <= MAX_CONTACT_ID:     # stored as int32: 2**40 became 0, 10**23 "no contact"
            raise DataError(f"{here}: contactId {head[0]} is outside 0..{MAX_CONTACT_ID}")
        row = [_vector(c[i], 3, here, _CONTACT_FIELDS[i]) for i in range(1, 6)]
        taxels = c[6]
        if not isinstance(taxels, list):
            raise DataError(f"{here}: taxel ids must be a list, got {taxels!r}")
        taxels = _vector(taxels, len(taxels), here, "taxel ids", int)
        if any(t < 0 or t >= max_taxel_id for t in taxels):
            bad = next(t for t in taxels if t < 0 or t >= max_taxel_id)
            raise DataError(f"{here}: taxel id {bad} is outside 0..{max_taxel_id - 1}")
        p = c[7]
        if isinstance(p, bool) or not isinstance(p, (int, float)) or not abs(p) <= FLOAT32_MAX:
            raise DataError(f"{here}: pressure must be a finite number, got {p!r}")
        ids.append(head)
        vecs.append(row)
        pressure.append(float(p))
        t_contact += [k] * len(taxels)
        t_id += taxels
    head = np.array(ids, dtype=int).reshape(-1, 4)
    v = np.array(vecs, dtype=float).reshape(-1, 5, 3)
    fits = np.all(np.abs(v) <= FLOAT32_MAX, axis=(1, 2))     # published as float32: 1e300 would become inf
    if not np.all(fits):
        k = int(np.flatnonzero(~fits)[0])
        raise DataError(f"{where}: contact {k}: a COP/force/moment/geoCenter/normal value that is not a finite"
                        f" float32")
    return SkinEvents(head[:, 3], head[:, 0], head[:, 1], head[:, 2], v[:, 0], v[:, 1], v[:, 2], v[:, 3], v[:, 4],
                      np.array(pressure, dtype=float), np.array(t_contact, dtype=int), np.array(t_id, dtype=int))


def parse_skin_events(text: str, where: str, max_taxel_id: int = 1 << 16) -> SkinEvents:
    """``Bottle.toString()`` of a skinContactList to :class:`SkinEvents`."""
    return contacts_from_lists(parse_bottle_text(text, where), where, max_taxel_id)


def format_skin_events(events: SkinEvents) -> str:
    """The bottle text skinManager would send for ``events`` (for simulators and tests)."""
    out = []
    for k in range(events.n_contacts):
        taxels = events.taxel_id[events.taxel_contact == k]

        def vec(a):
            return "(" + " ".join(repr(float(x)) for x in a) + ")"

        out.append(f"(({events.contact_id[k]} {events.body_part[k]} {events.link[k]} {events.skin_part[k]}) "
                   f"{vec(events.cop[k])} {vec(events.force[k])} {vec(events.moment[k])} "
                   f"{vec(events.geo_center[k])} {vec(events.normal[k])} "
                   f"({' '.join(str(int(t)) for t in taxels)}) {float(events.pressure[k])!r})")
    return " ".join(out)


def activated_taxels(values, threshold: float, where: str, n_slots: int) -> tuple:
    """Compensated taxel vector (one value per slot, 0-255 or 0/100 binarised) to (slots, values) above threshold."""
    try:
        v = np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        raise DataError(f"{where}: compensated taxel values must be numbers") from None
    if len(v) > n_slots:
        raise DataError(f"{where}: {len(v)} taxel values, more than the part's {n_slots} slots")
    if not np.all(np.isfinite(v)):
        raise DataError(f"{where}: non-finite compensated taxel value at slot {int(np.flatnonzero(~np.isfinite(v))[0])}")
    slots = np.flatnonzero(v > threshold)
    return slots, v[slots]


def parts_by_id(ids_of_parts: Mapping, where: str) -> dict:
    """``{skinDynLib id: part name}`` from configuration's ``{part name: id}`` (-1: the part is not bridged).

    One id feeds one part: two parts on one id would leave one of them without a word.
    """
    out: dict = {}
    for name, pid in dict(ids_of_parts).items():
        if isinstance(pid, bool) or not isinstance(pid, int):
            raise ConfigError(f"{where}.{name}: skin part id {pid!r} is not an integer")
        if pid < 0:
            continue
        if pid in out:
            raise ConfigError(f"{where}: {out[pid]} and {name} both have skinPart id {pid}")
        out[pid] = str(name)
    return out
