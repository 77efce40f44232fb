"""The thesis' own dataset text format (§3.5.1): one Python dict literal ``{key: [skinContacts, joints]}``.

``key`` is a touch index ("0", "1", ...) or a timestamp; ``skinContacts`` maps a
skinManager contactId to a dict with ``cop``, ``geoCenter``, ``normal``,
``skinPart``, ``taxelInfo`` ({"slot": [x, y, z, nx, ny, nz]}) and ``force``,
``moment``, ``averagePressure`` (possibly None); ``joints`` maps NAOqi joint
names to radians. The file is parsed with :mod:`ast` (never ``eval``), and
each touch is evaluated on its own, so one bad touch is skipped with a
one-line reason while the rest of the file still loads.
"""
from __future__ import annotations

import ast
import math
from pathlib import Path
from typing import Mapping

import numpy as np

from .datasets import LoadReport
from .errors import DataError
from .robot import RobotModel
from .skin import SkinModel, build_part
from .taxel_file import read_taxel_file
from .touches import TouchSet

DEFAULT_CHAINS = {"r_hand": "r_arm", "l_hand": "l_arm", "torso": None, "head": "head"}


def skin_model_for(taxel_files: Mapping[str, str | Path], robot: RobotModel,
                   chains: Mapping[str, str | None] | None = None) -> SkinModel:
    """A skin model from a recording's own taxel files (patches = triangle // 16, the Nao convention)."""
    chains = dict(DEFAULT_CHAINS, **(chains or {}))
    parts = {}
    for name, path in taxel_files.items():
        if name not in chains:
            raise DataError(f"{path}: skin part '{name}' has no known chain (give one for it)")
        chain = chains[name]
        parts[name] = build_part(name, chain, robot.end_frame(chain), read_taxel_file(path), None, str(path))
    return SkinModel(robot, parts, source=", ".join(str(p) for p in taxel_files.values()))


class _SkipTouch(DataError):
    """A touch that cannot be used; ``reason`` is the short key it is counted under."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


def _vector3(value, where: str) -> np.ndarray:
    """A recorded [x, y, z] or None (-> NaN)."""
    if value is None:
        return np.full(3, np.nan)
    try:
        out = np.array([float(v) for v in value], dtype=float)
    except (TypeError, ValueError):
        raise _SkipTouch("malformed field", f"{where}: expected 3 numbers or None, got {value!r}") from None
    if out.shape != (3,):
        raise _SkipTouch("malformed field", f"{where}: expected 3 numbers or None, got {len(out)}")
    return out


def _stamp_of(key, row: int) -> float:
    try:
        return float(key)
    except (TypeError, ValueError):
        return float(row)      # neither an index nor a timestamp: file order


class _Touch:
    """One parsed touch, before it joins the flat arrays."""

    __slots__ = ("key", "stamp", "joints", "contacts")

    def __init__(self, key, stamp, joints, contacts):
        self.key, self.stamp, self.joints, self.contacts = key, stamp, joints, contacts


def _parse_touch(value, key: str, where: str, skin: SkinModel, joint_index: Mapping[str, int],
                 part_index: Mapping[str, int]):
    """Validate one ``[skinContacts, joints]`` entry; raise DataError naming the field."""
    if not isinstance(value, (list, tuple)) or len(value) != 2 or not isinstance(value[0], dict) \
            or not isinstance(value[1], dict):
        raise _SkipTouch("malformed touch", f"{where}: expected [skinContacts dict, joints dict]")
    contacts_in, joints_in = value
    contacts = []
    for cid, contact in contacts_in.items():
        cwhere = f"{where}: contact {cid!r}"
        if not isinstance(contact, dict):
            raise _SkipTouch("malformed touch", f"{cwhere}: expected a dict")
        part = contact.get("skinPart")
        if part not in skin.parts:
            raise _SkipTouch("unknown skin part", f"{cwhere}: field 'skinPart': unknown skin part {part!r}"
                            f" (configured: {', '.join(skin.parts)})")
        info = contact.get("taxelInfo")
        if not isinstance(info, dict) or not info:
            raise _SkipTouch("empty contact", f"{cwhere}: field 'taxelInfo': no activated taxel listed")
        sp = skin.parts[part]
        slots = []
        for s in info:
            try:
                slot = int(s)
            except (TypeError, ValueError):
                raise _SkipTouch("bad taxel slot", f"{cwhere}: field 'taxelInfo': slot {s!r} is not an integer") from None
            if not 0 <= slot < sp.n_slots:
                raise _SkipTouch("bad taxel slot", f"{cwhere}: field 'taxelInfo': slot {slot} out of range 0..{sp.n_slots - 1}"
                                f" of part '{part}'")
            if not sp.present[slot]:
                raise _SkipTouch("bad taxel slot", f"{cwhere}: field 'taxelInfo': slot {slot} is not a taxel of the"
                                f" '{part}' layout ({sp.source})")
            slots.append(slot)
        pressure = contact.get("averagePressure")
        try:
            pressure = np.nan if pressure is None else float(pressure)
        except (TypeError, ValueError):
            raise _SkipTouch("malformed field", f"{cwhere}: field 'averagePressure': not a number ({pressure!r})") from None
        cop = _vector3(contact.get("cop"), f"{cwhere}: field 'cop'")
        try:
            contact_id = int(cid)
        except (TypeError, ValueError):
            contact_id = -1
        contacts.append((part_index[part], contact_id, cop, np.array(slots, dtype=int), pressure))
    if not contacts:
        raise _SkipTouch("empty contact", f"{where}: no skin contact")
    joints = np.full(len(joint_index), np.nan)
    for name, angle in joints_in.items():
        idx = joint_index.get(name)
        if idx is None:
            continue                     # a joint the model does not use (e.g. legs)
        try:
            joints[idx] = np.nan if angle is None else float(angle)
        except (TypeError, ValueError):
            raise _SkipTouch("bad joint angle", f"{where}: joint '{name}': not a number ({angle!r})") from None
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
_last_parse: dict = {}     # one entry: (path, mtime, size) -> entries of the last big file parsed
_CACHE_MIN_BYTES = 1 << 20  # small files parse in milliseconds: not worth keeping


def _literal_entries(path: Path) -> list:
    """``(line, key, value)`` per top-level entry; a value that is no literal is ``_NOT_A_LITERAL``.

    Parsing a recording (5 MB: ~3 s of AST building) dominates reading it, so
    the entries of the last big file are kept: reading the same unchanged file
    again (stats, then calibrate, in one process) does not parse it twice.
    Entries are never modified by the reader.
    """
    try:
        st = path.stat()
        cache_key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
        if cache_key in _last_parse:
            return _last_parse[cache_key]
        text = path.read_text()
    except OSError as exc:
        raise DataError(f"{path}: cannot read legacy dataset ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: not a text file ({exc.reason} at byte {exc.start})") from None
    try:
        tree = ast.parse(text, filename=str(path), mode="eval")
    except SyntaxError as exc:
        raise DataError(f"{path}:{exc.lineno}: Python syntax error ({exc.msg});"
                        f" a legacy dataset is one dict literal") from None
    except (ValueError, MemoryError, RecursionError) as exc:
        raise DataError(f"{path}: cannot parse as a Python literal ({exc})") from None
    if not isinstance(tree.body, ast.Dict):
        raise DataError(f"{path}:{tree.body.lineno}: expected one dict literal {{key: [skinContacts, joints]}},"
                        f" found {type(tree.body).__name__}")
    entries = []
    for key_node, value_node in zip(tree.body.keys, tree.body.values):
        try:                     # each entry on its own: one bad touch does not lose the others
            key = ast.literal_eval(key_node) if key_node is not None else None
        except ValueError:
            key = None
        try:
            value = ast.literal_eval(value_node)
        except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
            value = _NOT_A_LITERAL
        entries.append((getattr(value_node, "lineno", "?"), key, value))
    if st.st_size >= _CACHE_MIN_BYTES:
        _last_parse.clear()
        _last_parse[cache_key] = entries
    return entries


def read_legacy(path: str | Path, skin: SkinModel) -> tuple:
    """Read a legacy dataset: ``(TouchSet, LoadReport)``.

    Touch order is the file's. Stamps are ``float(key)`` (an index key is its
    own number of seconds); ``keys`` keep the original strings. Activation
    pressures are the contact's ``averagePressure`` (NaN when None), the
    recorded ``cop`` becomes ``contact_cop``. A syntax error in the file is a
    :class:`DataError` naming file and line; a bad touch is skipped and counted.
    """
    path = Path(path)
    entries = _literal_entries(path)
    report = LoadReport(str(path))
    robot = skin.robot
    part_names = tuple(skin.parts)
    part_index = {n: i for i, n in enumerate(part_names)}
    joint_index = robot.joint_index
    parsed = []
    for row, (line, key, value) in enumerate(entries):
        report.n_read += 1
        where = f"{path}:{line}: touch {key!r}"
        if not isinstance(key, (str, int, float)):
            report.skip("malformed touch", f"{path}:{line}: touch #{row}: key is not a string or number")
            continue
        if value is _NOT_A_LITERAL:
            report.skip("not a literal", f"{where}: not a Python literal (only dicts, lists, numbers,"
                                         f" strings, None are allowed)")
            continue
        try:
            joints, contacts = _parse_touch(value, str(key), where, skin, joint_index, part_index)
        except _SkipTouch as exc:
            report.skip(exc.reason, str(exc))
            continue
        parsed.append(_Touch(str(key), _stamp_of(key, row), joints, contacts))
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
