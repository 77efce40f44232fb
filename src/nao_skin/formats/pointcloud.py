"""The nao_skin topics: their names, and the PointCloud2 layouts of the skin topics, as numpy.

Topics (standard message types only; metres, radians, REP-103 frames):

* ``/joint_states`` - sensor_msgs/msg/JointState, NAOqi joint names.
* ``/skin/<part>/taxels`` - sensor_msgs/msg/PointCloud2, one point per activated
  taxel: ``x y z`` float32 (nominal taxel position in the part's chain-end
  frame, as the taxel file gives it; ``header.frame_id`` = that frame),
  ``slot`` uint32, ``pressure`` float32 (NaN unknown), ``contact`` int32
  (skinManager contactId, -1 none). An empty cloud means "nothing pressed on
  this part now".
* ``/skin/<part>/contacts`` - sensor_msgs/msg/PointCloud2, one point per
  skinManager contact: ``x y z`` COP, ``nx ny nz`` normal, ``gx gy gz``
  geometric centre, ``fx fy fz`` force, ``mx my mz`` moment, ``pressure``
  average pressure (float32, NaN unknown), ``contact`` int32 id. Same stamp
  as the taxels message of that sample.
* ``/nao_skin/fingertip_touch`` - geometry_msgs/msg/PointStamped, in a touch bag: the touch at its stamp was
  a fingertip's (only one skin part fires); ``header.frame_id`` names the fingertip (a fingertip of the robot
  config, also the TF frame at its contact sphere's centre), ``point`` the sphere's centre in it (zero).

Clouds are encoded from and decoded to numpy structured arrays in one copy,
never point by point. Encoding and decoding work on plain attributes, so the
same code serves rosbags messages (bags) and rclpy messages (nodes); readers
accept any field order, padding, row padding and byte order, and need only
the fields they use.
"""
from __future__ import annotations

import re

import numpy as np

from nao_skin.errors import DataError
from nao_skin.model.skin import SkinPart

JOINT_STATES_TOPIC = "/joint_states"
FINGERTIP_TOUCH_TOPIC = "/nao_skin/fingertip_touch"
_SKIN_TOPIC = re.compile(r"^/skin/([^/]+)/(taxels|contacts)$")

TAXEL_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("slot", "<u4"),
                        ("pressure", "<f4"), ("contact", "<i4")])
CONTACT_DTYPE = np.dtype([(n, "<f4") for n in ("x", "y", "z", "nx", "ny", "nz", "gx", "gy", "gz",
                                                 "fx", "fy", "fz", "mx", "my", "mz", "pressure")]
                         + [("contact", "<i4")])
# sensor_msgs/PointField datatype codes (INT8 .. FLOAT64) of the numpy types
_POINT_FIELD_CODE = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}
_CODE_TYPE = {v: k for k, v in _POINT_FIELD_CODE.items()}


def taxels_topic(part: str) -> str:
    return f"/skin/{part}/taxels"


def contacts_topic(part: str) -> str:
    return f"/skin/{part}/contacts"


def skin_topic(topic: str) -> tuple | None:
    """``(part, "taxels" or "contacts")`` of a skin topic; None for any other topic."""
    m = _SKIN_TOPIC.match(topic)
    return None if m is None else m.groups()


# ---------------------------------------------------------------------- points
def taxels_array(slots, positions, pressures=None, contacts=None) -> np.ndarray:
    """Structured taxel points from per-taxel arrays (pressure NaN and contact -1 by default)."""
    slots = np.asarray(slots, dtype=np.int64).reshape(-1)
    out = np.zeros(len(slots), TAXEL_DTYPE)
    pos = np.asarray(positions, dtype=float).reshape(-1, 3)
    out["x"], out["y"], out["z"] = pos[:, 0], pos[:, 1], pos[:, 2]
    out["slot"] = slots
    out["pressure"] = np.nan if pressures is None else np.asarray(pressures, dtype=float)
    out["contact"] = -1 if contacts is None else np.asarray(contacts, dtype=np.int64)
    return out


def contacts_array(contact_ids, cop, normal=None, geo_center=None, force=None, moment=None,
                   pressure=None) -> np.ndarray:
    """Structured contact points; missing vectors are NaN (unknown), not zero."""
    ids = np.asarray(contact_ids, dtype=np.int64).reshape(-1)
    out = np.zeros(len(ids), CONTACT_DTYPE)
    for prefix, values in (("", cop), ("n", normal), ("g", geo_center), ("f", force), ("m", moment)):
        vals = np.full((len(ids), 3), np.nan) if values is None else np.asarray(values, dtype=float).reshape(-1, 3)
        out[prefix + "x"], out[prefix + "y"], out[prefix + "z"] = vals[:, 0], vals[:, 1], vals[:, 2]
    out["pressure"] = np.nan if pressure is None else np.asarray(pressure, dtype=float)
    out["contact"] = ids
    return out


def xyz(points: np.ndarray, prefix: str = "") -> np.ndarray:
    """``(N, 3)`` float array of the ``<prefix>x <prefix>y <prefix>z`` fields."""
    return np.stack([points[prefix + "x"], points[prefix + "y"], points[prefix + "z"]], axis=1).astype(float)


# ---------------------------------------------------------------------- PointCloud2 <-> numpy
def point_fields(dtype: np.dtype) -> list:
    """``(name, offset, datatype, count)`` of each PointField for a little-endian structured dtype."""
    return [(name, int(dtype.fields[name][1]), _POINT_FIELD_CODE[dtype.fields[name][0].str[1:]], 1)
            for name in dtype.names]


def encode_cloud(points: np.ndarray) -> dict:
    """Every PointCloud2 attribute but the header for a dense, unorganised (height 1) cloud of ``points``.

    ``fields`` are ``(name, offset, datatype, count)`` tuples (:func:`point_fields`)
    and ``data`` the little-endian bytes: an adapter only makes its own PointField objects.
    """
    points = np.ascontiguousarray(points, dtype=points.dtype.newbyteorder("<"))
    step = points.dtype.itemsize
    return {"height": 1, "width": len(points), "fields": point_fields(points.dtype), "is_bigendian": False,
            "point_step": step, "row_step": step * len(points), "data": points.tobytes(), "is_dense": True}


def decode_cloud(msg, where: str) -> np.ndarray:
    """A PointCloud2's points as a structured array of its own fields, whatever their order, padding or byte order.

    ``msg``: a rosbags or rclpy PointCloud2 (only its attributes are read).
    Raises a one-line :class:`DataError` naming ``where`` when a field has a
    type PointCloud2 does not define, or the data does not hold the points.
    """
    byte_order = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for f in msg.fields:
        code = _CODE_TYPE.get(int(f.datatype))
        if code is None or int(f.count) != 1:
            raise DataError(f"{where}: field '{f.name}' has unsupported datatype {f.datatype} / count {f.count}")
        names.append(f.name)
        formats.append(byte_order + code)
        offsets.append(int(f.offset))
    width, height, step = int(msg.width), int(msg.height), int(msg.point_step)
    # rows may be padded; a row_step below a row's size is taken as no padding
    row_step = max(int(msg.row_step), width * step)
    try:
        dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
        buf = np.frombuffer(msg.data, dtype=np.uint8)
        if width <= 0 or height <= 0:    # no point, whatever row_step says (it must not size a padded copy)
            return np.zeros(0, dtype=dtype)
        size = (height - 1) * row_step + width * step
        if len(buf) < size:
            raise ValueError(f"{len(buf)} bytes for {height} rows of {width} points of {step}")
        if height > 1 and row_step != width * step:
            padded = np.zeros(height * row_step, np.uint8)
            padded[:size] = buf[:size]
            buf = padded.reshape(height, row_step)[:, :width * step].ravel()
        return np.frombuffer(buf, dtype=dtype, count=width * height)
    except (ValueError, TypeError) as exc:
        raise DataError(f"{where}: malformed point cloud ({exc})") from None


def cloud_field(cloud: np.ndarray, name: str, dtype, where: str, default=None) -> np.ndarray:
    """Field ``name`` of a decoded cloud as ``dtype``; ``default`` for every point when the cloud lacks it.

    Without a default a missing field is a :class:`DataError` naming ``where``.
    """
    if name in cloud.dtype.names:
        return cloud[name].astype(dtype)
    if default is None:
        raise DataError(f"{where}: PointCloud2 has no field '{name}' (has {', '.join(cloud.dtype.names) or 'none'})")
    return np.full(len(cloud), default, dtype=dtype)


# ---------------------------------------------------------------------- what a reader takes from the skin topics
class NoTime(DataError):
    """A message whose header stamp is no time; the message is skipped."""

    reason = "no header stamp"        # what a load report counts it under


# a message header's stamp (builtin_interfaces/Time) holds int32 seconds: the last is in January 2038
# (rosbag2's own int64 nanoseconds would reach 2262); beyond it the seconds wrap negative
LAST_STAMP = float(2 ** 31 - 1)


def header_seconds(stamp, where: str, zero: bool = True) -> float:
    """A header's ``builtin_interfaces/Time`` in seconds; :class:`NoTime` for one that is no time: before
    1970, with nanoseconds beyond a second, or unset (0) unless ``zero`` allows it.

    A touch takes its stamp from the skin and its arm pose from the joint states at that stamp, so a
    live message without a real stamp cannot be placed: an unset one would end the press it falls into.
    In a bag, 0 can be a time (a thesis file's first touch, its key the index 0, imported).
    """
    sec, nanosec = int(stamp.sec), int(stamp.nanosec)
    if sec < 0 or (sec == 0 and nanosec == 0 and not zero) or not 0 <= nanosec < 1_000_000_000:
        what = ("not set" if sec == 0 and nanosec == 0 else "before 1970" if sec < 0
                else f"no time (nanosec {nanosec} is not below 1e9)")
        raise NoTime(f"{where}: header stamp {sec}.{nanosec:09d} s is {what}: the message cannot be placed in time")
    return sec + nanosec * 1e-9


class BadSlot(DataError):
    """A taxels message naming a slot its part's layout lacks; the sample is skipped."""

    reason = "bad taxel slot"         # what a load report counts it under

    def __init__(self, message: str, part: str):
        super().__init__(message)
        self.part = part


def read_taxels(msg, part: SkinPart, where: str) -> tuple:
    """``(slots, pressures, contact ids)`` of a ``/skin/<part>/taxels`` message: int64, float, int64 arrays.

    Only ``slot`` is required (pressure NaN and contact -1 otherwise); every
    slot must be a taxel of ``part``'s layout, else :class:`BadSlot`.
    """
    points = int(msg.width) * int(msg.height)
    if points > part.n_slots:     # each taxel once at most: more is no skin sample (2M points held a recorder 1.7 s)
        raise BadSlot(f"{where}: {points} points for part '{part.name}' of {part.n_slots} slots; sample skipped",
                      part.name)
    cloud = decode_cloud(msg, where)
    if "slot" in cloud.dtype.names and cloud.dtype["slot"].kind == "f":   # a producer's float field: whole
        slots = _whole_numbers(cloud["slot"].astype(float), "slot", where)  # numbers only (a NaN cast warns)
    else:
        slots = cloud_field(cloud, "slot", np.int64, where)     # required: raises when the cloud lacks it
    bad = (slots < 0) | (slots >= part.n_slots)
    if np.any(bad):
        raise BadSlot(f"{where}: field 'slot': slot {int(slots[bad][0])} out of range 0..{part.n_slots - 1}"
                      f" of part '{part.name}'; sample skipped", part.name)
    absent = ~part.present[slots]
    if np.any(absent):
        raise BadSlot(f"{where}: field 'slot': slot {int(slots[absent][0])} is not a taxel of the"
                      f" '{part.name}' layout ({part.layout_file}); sample skipped", part.name)
    return slots, cloud_field(cloud, "pressure", float, where, np.nan), _contact_ids(cloud, where, -1)


def _whole(values: np.ndarray) -> np.ndarray:
    """Which float ``values`` are whole numbers an int64 holds."""
    return np.isfinite(values) & (values == np.round(values)) & (np.abs(values) < 2.0 ** 62)


def _whole_numbers(values: np.ndarray, name: str, where: str) -> np.ndarray:
    """``values`` as int64; a :class:`DataError` naming ``where`` when one is not a whole number.

    A field declared float but written as integers reads as tiny or huge
    floats: truncating them would turn every slot into slot 0 without a word.
    """
    whole = _whole(values)
    if not np.all(whole):
        raise DataError(f"{where}: field '{name}': {float(values[~whole][0])!r} is not a whole number (is the"
                        f" field's datatype right?); sample skipped")
    return values.astype(np.int64)


def _contact_ids(cloud: np.ndarray, where: str, default=None) -> np.ndarray:
    """The ``contact`` field as int64; in a producer's float field a value that is no whole number (NaN) is -1,
    no skinManager contact (its taxels are then grouped by where they are): cast, NaN became contact 0 and
    joined every such taxel into one contact."""
    if "contact" in cloud.dtype.names and cloud.dtype["contact"].kind == "f":
        values = cloud["contact"].astype(float)
        ids = np.full(len(values), -1, dtype=np.int64)
        whole = _whole(values)
        ids[whole] = values[whole].astype(np.int64)
        return ids
    return cloud_field(cloud, "contact", np.int64, where, default)


def read_contacts(msg, part: SkinPart, where: str) -> tuple:
    """``(contact ids (K,), COPs (K, 3))`` of a ``/skin/<part>/contacts`` message; the other fields are not needed.
    A contact holds a taxel at least: more contacts than ``part`` has slots is no skin sample."""
    points = int(msg.width) * int(msg.height)
    if points > part.n_slots:     # such clouds stall a recorder (0.8 s a message at 2M points): touches lost
        raise DataError(f"{where}: {points} contacts for part '{part.name}' of {part.n_slots} slots; sample skipped")
    cloud = decode_cloud(msg, where)
    cop = np.stack([cloud_field(cloud, k, float, where) for k in ("x", "y", "z")], axis=1)
    return _contact_ids(cloud, where), cop
