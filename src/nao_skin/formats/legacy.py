"""The thesis' own dataset text format (§3.5.1): one Python dict literal ``{key: [skinContacts, joints]}``.

``key`` is a touch index ("0", "1", ...) or a timestamp; ``skinContacts`` maps a
skinManager contactId to a dict with ``cop``, ``geoCenter``, ``normal``,
``skinPart``, ``taxelInfo`` ({"slot": [x, y, z, nx, ny, nz]}) and ``force``,
``moment``, ``averagePressure`` (possibly None); ``joints`` maps NAOqi joint
names to radians. The file is parsed with :mod:`ast` (never ``eval``), and
each touch is evaluated on its own, so one bad touch is skipped with a
one-line reason while the rest of the file still loads. A file whose text is
damaged (a garbage line, cut short by a full disk or a killed recorder) is
read touch by touch from each touch's key on (:func:`_salvaged_entries`):
every complete touch before and after the damage is kept, and one line says
which lines were lost.
"""
from __future__ import annotations

import ast
import json
import math
import re
from pathlib import Path
from typing import Mapping

import numpy as np

from nao_skin.errors import DataError
from nao_skin.model.robot import MAX_JOINT_LIMIT
from nao_skin.model.skin import INTEGER_TEXT, SkinModel
from nao_skin.model.taxel_file import MAX_COORDINATE
from nao_skin.paths import read_text
from nao_skin.touch.datasets import LoadReport
from nao_skin.touch.touches import TouchSet


class _SkipTouch(DataError):
    """A touch that cannot be used; ``reason`` is the short key it is counted under."""

    def __init__(self, reason: str, message: str, part: str | None = None):
        super().__init__(message)
        self.reason = reason
        self.part = part        # set when the part's layout lacks a named slot


def _vector3(value, where: str) -> np.ndarray:
    """A recorded [x, y, z] or None (-> NaN)."""
    if value is None:
        return np.full(3, np.nan)
    try:
        out = np.array([float(v) for v in value], dtype=float)
    except (TypeError, ValueError, OverflowError):      # OverflowError: an integer beyond any float
        raise _SkipTouch("malformed field", f"{where}: expected 3 numbers or None, got {value!r}") from None
    if out.shape != (3,):
        raise _SkipTouch("malformed field", f"{where}: expected 3 numbers or None, got {len(out)}")
    if np.nanmax(np.abs(out), initial=0.0) > MAX_COORDINATE:      # NaN: not recorded, as None
        raise _SkipTouch("malformed field", f"{where}: {value!r} lies beyond {MAX_COORDINATE:g} m of its"
                                            f" part's frame (metres)")
    return out


def _key_number(key) -> float | None:
    """The key as a time (or an index), or None when it is a name. Python's ``float`` reads '1_0' as 10, which
    would make it the key '10' twice; 'nan' or a 400-digit number is no time either (an import would refuse
    it as a bag stamp)."""
    if isinstance(key, bool) or (isinstance(key, str) and "_" in key):
        return None
    try:
        number = float(key)
    except (TypeError, ValueError, OverflowError):
        return None
    return number if math.isfinite(number) else None


def _numeric(key) -> bool:
    """Whether the key is a time (or an index) rather than a name: its stamp is the number."""
    return _key_number(key) is not None


def _stamp_of(key, row: int) -> float:
    number = _key_number(key)
    return float(row) if number is None else number      # neither an index nor a timestamp: file order


class _Touch:
    """One parsed touch, before it joins the flat arrays."""

    __slots__ = ("key", "stamp", "joints", "contacts")

    def __init__(self, key, stamp, joints, contacts):
        self.key, self.stamp, self.joints, self.contacts = key, stamp, joints, contacts


def _key_integer(key) -> int | float | None:
    """A slot or contact id given as a dict key: an int, or a string of ASCII digits (the JSON path quotes
    number keys); ``inf`` for an infinite float (no int holds it); None for anything else (a bool, 1.5,
    '²': no slot, though ``int()`` takes them)."""
    if isinstance(key, int) and not isinstance(key, bool):
        return key
    if isinstance(key, str) and INTEGER_TEXT.fullmatch(key.strip()):
        return int(key)
    if isinstance(key, float) and not math.isfinite(key):
        return math.inf
    return None


def _parse_touch(value, where: str, skin: SkinModel, joint_index: Mapping[str, int], part_index: Mapping[str, int]):
    """Validate one ``[skinContacts, joints]`` entry; raise DataError naming the field."""
    if not isinstance(value, (list, tuple)) or len(value) != 2 or not isinstance(value[0], dict) \
            or not isinstance(value[1], dict):
        raise _SkipTouch("malformed touch", f"{where}: expected [skinContacts dict, joints dict]")
    contacts_in, joints_in = value
    contacts = []
    for cid, contact in contacts_in.items():
        cwhere = f"{where}: contact {cid}"
        if not isinstance(contact, dict):
            raise _SkipTouch("malformed touch", f"{cwhere}: expected a dict")
        part = contact.get("skinPart")
        if not isinstance(part, str) or part not in skin.parts:
            raise _SkipTouch("unknown skin part", f"{cwhere}: field 'skinPart': unknown skin part {part!r}"
                            f" (configured: {', '.join(skin.parts)})")
        info = contact.get("taxelInfo")
        if not isinstance(info, dict) or not info:
            raise _SkipTouch("empty contact", f"{cwhere}: field 'taxelInfo': no activated taxel listed")
        sp = skin.parts[part]
        numbers = [_key_integer(s) for s in info]
        for s, number in zip(info, numbers):
            if number is None:
                raise _SkipTouch("bad taxel slot", f"{cwhere}: field 'taxelInfo': slot {s!r} is not an integer")
            if abs(number) >= 2 ** 63:      # beyond int64 (or infinite): out of range like any other
                raise _SkipTouch("bad taxel slot", f"{cwhere}: field 'taxelInfo': slot {s} out of range"
                                 f" 0..{len(sp.present) - 1} of part '{part}'", part)
        slots = np.array(numbers, dtype=int)
        outside = (slots < 0) | (slots >= len(sp.present))
        if outside.any():
            raise _SkipTouch("bad taxel slot", f"{cwhere}: field 'taxelInfo': slot {slots[outside][0]} out of range"
                            f" 0..{len(sp.present) - 1} of part '{part}'", part)
        absent = ~sp.present[slots]
        if absent.any():
            raise _SkipTouch("bad taxel slot", f"{cwhere}: field 'taxelInfo': slot {slots[absent][0]} is not a taxel"
                            f" of the '{part}' layout ({sp.layout_file})", part)
        pressure = contact.get("averagePressure")
        try:
            pressure = np.nan if pressure is None else float(pressure)
        except (TypeError, ValueError, OverflowError):
            raise _SkipTouch("malformed field", f"{cwhere}: field 'averagePressure': not a number ({pressure!r})") from None
        cop = _vector3(contact.get("cop"), f"{cwhere}: field 'cop'")
        contact_id = _key_integer(cid)      # skinManager's contactId, -1: none usable
        contact_id = contact_id if contact_id is not None and 0 <= contact_id < 2 ** 31 else -1
        contacts.append((part_index[part], contact_id, cop, slots, pressure))
    if not contacts:
        raise _SkipTouch("empty contact", f"{where}: no skin contact")
    joints = np.full(len(joint_index), np.nan)
    for name, angle in joints_in.items():
        idx = joint_index.get(name)
        if idx is None:
            continue                     # a joint the model does not use (e.g. legs)
        try:
            if isinstance(angle, (bool, str)):     # float(True) is 1.0 rad, float('0.5') a text read as one
                raise TypeError
            joints[idx] = np.nan if angle is None or math.isinf(float(angle)) else float(angle)   # inf: not measured
        except (TypeError, ValueError):
            raise _SkipTouch("bad joint angle", f"{where}: joint '{name}': not a number ({angle!r})") from None
        except OverflowError:           # an integer beyond any float
            raise _SkipTouch("bad joint angle", f"{where}: joint '{name}' is not a finite angle"
                             f" ({str(angle)[:20]}..., {len(str(angle))} digits)") from None
        if abs(joints[idx]) > MAX_JOINT_LIMIT:    # no joint of an arm or a head turns that far: not an angle
            raise _SkipTouch("bad joint angle", f"{where}: joint '{name}' = {float(angle):.4g} rad, beyond two"
                             f" turns (|angle| <= {MAX_JOINT_LIMIT:.2f} rad)")
    robot = skin.robot
    for p in sorted({c[0] for c in contacts}):
        part = skin.parts[list(part_index)[p]]
        for name in robot.chain_joint_names(part.chain) if part.chain else ():
            if name not in joints_in:
                raise _SkipTouch("missing joint", f"{where}: joint '{name}' is missing (needed by part '{part.name}')")
            if not math.isfinite(joints[joint_index[name]]):
                raise _SkipTouch("bad joint angle", f"{where}: joint '{name}' is not a finite angle ({joints_in[name]!r})")
    return joints, contacts


_NOT_A_LITERAL = object()
_NON_FINITE = {"nan": math.nan, "NaN": math.nan, "inf": math.inf, "Infinity": math.inf}
# Python names the recorder writes, as JSON spells them (outside strings only)
_JSON_NAMES = (("None", "null"), ("True", "true"), ("False", "false"), ("nan", "NaN"), ("inf", "Infinity"))
# a number right before ':' is a dict key (a skinManager contactId); JSON wants it quoted. Matched on the
# reversed text, where the pattern starts at the rare ':' instead of at every digit of every number.
_REVERSED_NUMBER_KEY = re.compile(r":(\s*)([0-9.]+-?)(?=\s*[{,])")
_SPACE = re.compile(r"\s*")


class _NonFiniteNames(ast.NodeTransformer):
    """``nan`` and ``inf`` as Python prints them (a driver's NaN angle) become float constants."""

    def visit_Name(self, node):
        if node.id in _NON_FINITE:
            return ast.copy_location(ast.Constant(_NON_FINITE[node.id]), node)
        return node


def _literal_with_non_finite(node):
    """The literal of ``node`` if its only non-literal names are nan/inf (then checked as angles), else a marker."""
    try:
        return ast.literal_eval(_NonFiniteNames().visit(node))
    except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
        return _NOT_A_LITERAL


def _literal_entries(path: Path, exact: bool = False) -> tuple:
    """``([(line, key, value)] per top-level entry, [damaged stretch])``; a value that is no literal is
    ``_NOT_A_LITERAL``.

    Files as the thesis' recorder writes them (Python's repr of a dict: no
    escapes, no tuples) take the fast path, read as JSON; anything else a
    Python literal allows, or a broken file, takes the exact path through
    :mod:`ast`, which names the line of each problem. Both give the same entries.
    A file that is no literal as a whole is read touch by touch (:func:`_salvaged_entries`).
    """
    text = read_text(path, "legacy dataset")
    entries = None if exact else _json_entries(text)
    if entries is not None:
        return entries, []
    try:
        return _ast_entries(text, path), []
    except _SyntaxDamage as whole:
        entries, damaged = _salvaged_entries(text)
        if not entries:          # no complete touch anywhere: the file's own syntax error says where
            raise DataError(str(whole)) from None
        return entries, damaged


def _json_entries(text: str) -> list | None:
    """The entries of a plain recorder file, through the C JSON decoder; None when it is not one."""
    if '"' in text or "\\" in text or "\x00" in text:
        return None                       # strings with escapes: the exact path
    parts = text.split("'")               # odd items: the strings' contents, even items: everything else
    if len(parts) % 2 == 0:
        return None
    code = "\x00".join(parts[0::2])
    for name, spelled in _JSON_NAMES:
        if name in code:
            code = code.replace(name, spelled)
    code = _REVERSED_NUMBER_KEY.sub(r':\1"\2"', code[::-1])[::-1]
    parts[0::2] = code.split("\x00")
    text = '"'.join(parts)                # same lines as the file: nothing added or removed a newline
    decoder = json.JSONDecoder()
    entries, line, counted = [], 1, 0
    try:
        i = _SPACE.match(text).end()
        if text[i] != "{":
            return None
        i = _SPACE.match(text, i + 1).end()
        while text[i] != "}":
            key, i = decoder.raw_decode(text, i)
            i = _SPACE.match(text, i).end()
            if text[i] != ":":
                return None
            i = _SPACE.match(text, i + 1).end()
            line += text.count("\n", counted, i)
            counted = i
            value, i = decoder.raw_decode(text, i)
            entries.append((line, key, value))
            i = _SPACE.match(text, i).end()
            if text[i] == ",":
                i = _SPACE.match(text, i + 1).end()
            elif text[i] != "}":
                return None
        if text[i + 1:].strip():
            return None
    except (ValueError, IndexError, RecursionError):
        return None
    return entries


def _ast_entries(text: str, path: Path) -> list:
    """The entries of any file Python's literal syntax accepts; one bad entry does not lose the others."""
    if not text.strip():
        raise DataError(f"{path}: empty file; a legacy dataset is one dict literal {{key: [skinContacts, joints]}}")
    try:
        tree = ast.parse(text, filename=str(path), mode="eval")
    except SyntaxError as exc:
        line = f":{exc.lineno}" if exc.lineno else ""       # none for e.g. a NUL byte
        raise _SyntaxDamage(f"{path}{line}: Python syntax error ({exc.msg});"
                            f" a legacy dataset is one dict literal") from None
    except (ValueError, MemoryError, RecursionError) as exc:
        raise DataError(f"{path}: cannot parse as a Python literal ({exc})") from None
    if not isinstance(tree.body, ast.Dict):
        raise DataError(f"{path}:{tree.body.lineno}: expected one dict literal {{key: [skinContacts, joints]}},"
                        f" found {type(tree.body).__name__}")
    entries = []
    for key_node, value_node in zip(tree.body.keys, tree.body.values):
        try:
            key = ast.literal_eval(key_node) if key_node is not None else None
        except ValueError:
            key = None
        try:
            value = ast.literal_eval(value_node)
        except ValueError:
            value = _literal_with_non_finite(value_node)
        except (TypeError, SyntaxError, MemoryError, RecursionError):
            value = _NOT_A_LITERAL
        entries.append((getattr(value_node, "lineno", "?"), key, value))
    return entries


class _SyntaxDamage(DataError):
    """The file is no Python literal as a whole (a garbage line, cut short)."""


# where a touch begins: its key (a quoted text or a number) at a line's start or after the '{' or ',' before
# it, then ': [' and the '{' of its skin contacts. Inside a touch no key is followed by '[{' (contact ids map
# to dicts, slots to lists of numbers), so the text after damage is found again at the next touch.
_TOUCH_START = re.compile(r"""(?:^|[{,])\s*('[^'\\\n]*'|"[^"\\\n]*"|[-+]?[0-9][0-9.eE+-]*)\s*:\s*\[\s*\{""",
                          re.MULTILINE)


class _Damage:
    """A stretch of a file's text that could not be read: its lines, what it was (a touch, text between two
    touches), why, and how many touches it cost."""

    def __init__(self, first: int, last: int, what: str, why: str, lost: int, final: bool = False):
        self.first, self.last, self.what, self.why, self.lost = first, last, what, why, lost
        self.final = final      # at the file's end: no touch follows it

    def __str__(self) -> str:
        lines = f"line {self.first}" if self.first >= self.last else f"lines {self.first}-{self.last}"
        return f"{lines} ({self.what}: {self.why})"


def _segment_entries(text: str, first_line: int) -> tuple:
    """``(entries, first unreadable line or None)`` of ``text``, a stretch of the file from a touch's key on
    line ``first_line`` to the next touch's. Text that does not parse is read up to the line its syntax error
    names: a garbage line after a complete touch costs no touch."""
    body = text.rstrip()
    entries = _stretch_entries(body)
    if entries is not None:
        return _shifted(entries, first_line), None
    try:
        ast.parse("{" + body + "}", mode="eval")
        return [], first_line          # parses, yet holds no touches
    except SyntaxError as exc:
        bad = exc.lineno or 1
    except (ValueError, MemoryError, RecursionError):
        return [], first_line
    before = "\n".join(body.split("\n")[:bad - 1]).rstrip()
    entries = _stretch_entries(before) if before else None
    if entries is None:
        return [], first_line
    return _shifted(entries, first_line), first_line + bad - 1


def _stretch_entries(body: str) -> list | None:
    """The entries of ``body``, text from a touch's key on, read as the whole file would be; None when it is
    not one."""
    literal = "{" + (body[:-1] if body.endswith(",") else body) + "}"
    entries = _json_entries(literal)
    if entries is not None:
        return entries
    try:
        return _ast_entries(literal, Path("-"))
    except DataError:
        return None


def _shifted(entries: list, first_line: int) -> list:
    return [(line + first_line - 1 if isinstance(line, int) else line, key, value) for line, key, value in entries]


def _salvaged_entries(text: str) -> tuple:
    """``(entries, [_Damage])`` of a file that is no literal as a whole: each stretch from one touch's key to
    the next read on its own, so a garbage line or a file cut short loses the touch it falls in, not the file."""
    starts = [(m.start(1), m.group(1)) for m in _TOUCH_START.finditer(text)]
    line_at, counted, line = [], 0, 1
    for pos, _ in starts:
        line += text.count("\n", counted, pos)
        counted = pos
        line_at.append(line)
    n_lines = len(text.rstrip().split("\n"))
    closed = text.rstrip().endswith("}")
    entries, damaged = [], []
    if starts and text[:starts[0][0]].strip().lstrip("\ufeff") != "{":
        damaged.append(_Damage(1, max(1, line_at[0] - 1), "before the first touch", "not the dict's opening '{'",
                               0))
    for k, (pos, key) in enumerate(starts):
        final = k + 1 == len(starts)
        segment = text[pos:starts[k + 1][0] if not final else len(text)].rstrip()
        if final and closed:
            segment = segment[:-1]
        got, bad = _segment_entries(segment, line_at[k])
        entries += got
        last = line_at[k] + segment.rstrip().count("\n")
        if bad is None:
            continue
        if got:         # the touch is whole; what follows it is not
            damaged.append(_Damage(bad, max(bad, last), f"after touch {key}", "unreadable text", 0, final))
        else:
            damaged.append(_Damage(line_at[k], max(line_at[k], last), f"touch {key}",
                                   "the file ends inside it (cut short?)" if final and not closed
                                   else "unreadable text", 1, final))
    if entries and not closed and not (damaged and damaged[-1].final):
        damaged.append(_Damage(n_lines, n_lines, "the file's end", "no closing '}' (cut short?)", 0, True))
    return entries, damaged


def read_legacy(path: str | Path, skin: SkinModel, exact: bool = False) -> tuple:
    """Read a legacy dataset: ``(TouchSet, LoadReport)``.

    Touch order is the file's. Stamps are ``float(key)`` (an index key is its
    own number of seconds); ``keys`` keep the original strings. Activation
    pressures are the contact's ``averagePressure`` (NaN when None), the
    recorded ``cop`` becomes ``contact_cop``. A syntax error in the file is a
    :class:`DataError` naming file and line; a bad touch is skipped and counted.
    """
    path = Path(path)
    entries, damaged = _literal_entries(path, exact)
    report = LoadReport(str(path))
    if damaged:
        lost = sum(d.lost for d in damaged)
        report.n_read += lost
        if lost:        # counted in the summary; the note (said even by a quiet command) says where
            report.skipped["damaged text"] += lost
        after = " and after" if not all(d.final for d in damaged) else ""
        report.notes.append(f"{path}: damaged text at {'; '.join(map(str, damaged))}: {lost} touch"
                            f"{'' if lost == 1 else 'es'} lost there; every complete touch before{after} it is read"
                            f" (each touch from its own key on)")
    robot = skin.robot
    part_names = tuple(skin.parts)
    part_index = {n: i for i, n in enumerate(part_names)}
    joint_index = robot.joint_index
    parsed = []
    first_line: dict = {}        # key -> the line that gave it first
    first_stamp: dict = {}       # time of a numeric key -> (line, key) that gave it first
    for row, (line, key, value) in enumerate(entries):
        report.n_read += 1
        where = f"{path}:{line}: touch {key!r}"
        if not isinstance(key, (str, int, float)):
            report.skip("malformed touch", f"{path}:{line}: touch #{row}: key is not a string or number")
            continue
        if str(key) in first_line:
            # a key is a touch's time: two touches under one would be one in a bag (and one in Python)
            report.skip("key given twice", f"{where}: the key was given before, at line {first_line[str(key)]};"
                                           f" the first is kept")
            continue
        first_line[str(key)] = line
        stamp, numeric = _stamp_of(key, row), _numeric(key)
        if numeric and stamp in first_stamp:
            # '5' and '5.0' are one time: a bag would hold the two touches as one
            at, other = first_stamp[stamp]
            report.skip("key given twice", f"{where}: the key is the time of {other!r} at line {at} (one time,"
                                           f" written two ways); the first is kept")
            continue
        if numeric:
            first_stamp[stamp] = (line, key)
        if value is _NOT_A_LITERAL:
            report.skip("not a literal", f"{where}: not a Python literal (only dicts, lists, numbers,"
                                         f" strings, None are allowed)")
            continue
        try:
            joints, contacts = _parse_touch(value, where, skin, joint_index, part_index)
        except _SkipTouch as exc:
            report.skip(exc.reason, str(exc), part=exc.part)
            continue
        parsed.append(_Touch(str(key), stamp, joints, contacts))
    report.n_loaded = len(parsed)
    return _to_touchset(parsed, part_names, tuple(robot.joint_names)), report


def _to_touchset(parsed, part_names, joint_names) -> TouchSet:
    if not parsed:
        return TouchSet.empty(part_names, joint_names)
    contacts = [(t, *c) for t, touch in enumerate(parsed) for c in touch.contacts]
    n_act = np.array([len(c[4]) for c in contacts], dtype=int)
    act_contact = np.repeat(np.arange(len(contacts)), n_act)
    return TouchSet(
        part_names=part_names, joint_names=joint_names,
        stamps=np.array([t.stamp for t in parsed], dtype=float),
        keys=[t.key for t in parsed],
        joints=np.stack([t.joints for t in parsed]),
        contact_touch=np.array([c[0] for c in contacts], dtype=int),
        contact_part=np.array([c[1] for c in contacts], dtype=int),
        contact_id=np.array([c[2] for c in contacts], dtype=int),
        contact_cop=np.stack([c[3] for c in contacts]),
        act_contact=act_contact,
        act_slot=np.concatenate([c[4] for c in contacts]).astype(int),
        act_pressure=np.repeat(np.array([c[5] for c in contacts], dtype=float), n_act),
    )
