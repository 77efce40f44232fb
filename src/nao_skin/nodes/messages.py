"""ROS message <-> numpy translation for the nao_skin topics; no node, no I/O.

Topic layouts (standard types only):

* ``/joint_states`` ``sensor_msgs/JointState``: NAOqi joint names, radians.
* ``/skin/<part>/taxels`` ``sensor_msgs/PointCloud2``, one point per activated
  taxel: ``x y z`` float32 (nominal taxel position in the part's chain-end
  frame), ``slot`` uint32, ``pressure`` float32 (NaN unknown), ``contact``
  int32 (skinManager contactId, -1 none). An empty cloud means "nothing
  pressed on this part now".
* ``/skin/<part>/contacts`` ``sensor_msgs/PointCloud2``, one point per
  skinManager contact: ``x y z`` COP, ``nx ny nz`` normal, ``gx gy gz``
  geometric centre, ``fx fy fz`` force, ``mx my mz`` moment, ``pressure``
  float32, ``contact`` int32.

Clouds are built from and read into numpy structured arrays in one copy,
never point by point.
"""
from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import JointState, PointCloud2, PointField

from nao_skin.errors import DataError
from nao_skin.formats.bag import CONTACT_DTYPE, TAXEL_DTYPE  # the one definition of the point layouts

SKIN_TOPIC_PREFIX = "/skin"
JOINT_STATES_TOPIC = "/joint_states"


# sensor_msgs/PointField datatype codes <-> numpy little-endian types
_FIELD_CODE = {np.dtype("<i1"): PointField.INT8, np.dtype("<u1"): PointField.UINT8,
               np.dtype("<i2"): PointField.INT16, np.dtype("<u2"): PointField.UINT16,
               np.dtype("<i4"): PointField.INT32, np.dtype("<u4"): PointField.UINT32,
               np.dtype("<f4"): PointField.FLOAT32, np.dtype("<f8"): PointField.FLOAT64}
_CODE_FIELD = {v: k for k, v in _FIELD_CODE.items()}


def taxels_topic(part: str) -> str:
    return f"{SKIN_TOPIC_PREFIX}/{part}/taxels"


def contacts_topic(part: str) -> str:
    return f"{SKIN_TOPIC_PREFIX}/{part}/contacts"


# ---------------------------------------------------------------------- time
def stamp_to_msg(seconds: float) -> Time:
    """Seconds (float, e.g. a YARP envelope time) to ``builtin_interfaces/Time``."""
    ns = int(round(float(seconds) * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def stamp_from_msg(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


# ---------------------------------------------------------------------- PointCloud2
def cloud_from_array(points: np.ndarray, frame_id: str, stamp: Time | None) -> PointCloud2:
    """A dense, unorganised (height 1) PointCloud2 holding the structured array ``points``."""
    points = np.ascontiguousarray(points)
    fields = [PointField(name=name, offset=points.dtype.fields[name][1],
                         datatype=_FIELD_CODE[points.dtype.fields[name][0]], count=1)
              for name in points.dtype.names]
    msg = PointCloud2()
    msg.header.frame_id = frame_id
    if stamp is not None:
        msg.header.stamp = stamp
    msg.height = 1
    msg.width = len(points)
    msg.fields = fields
    msg.is_bigendian = False
    msg.point_step = points.dtype.itemsize
    msg.row_step = points.dtype.itemsize * len(points)
    msg.is_dense = True
    msg.data = points.tobytes()
    return msg


def array_from_cloud(msg: PointCloud2, dtype: np.dtype, where: str) -> np.ndarray:
    """The cloud's points as a structured array of ``dtype`` (fields found by name, any offsets).

    Raises :class:`DataError` naming ``where`` (the topic) when a field is
    missing, has another type, or the buffer does not hold width x height points.
    """
    if msg.is_bigendian:
        raise DataError(f"{where}: big-endian PointCloud2 is not supported")
    n = int(msg.width) * int(msg.height)
    by_name = {f.name: f for f in msg.fields}
    layout = {}
    for name in dtype.names:
        f = by_name.get(name)
        if f is None:
            raise DataError(f"{where}: PointCloud2 has no field '{name}' (has {', '.join(by_name) or 'none'})")
        if _CODE_FIELD.get(f.datatype) != dtype.fields[name][0]:
            raise DataError(f"{where}: field '{name}' has datatype {f.datatype}, expected {dtype.fields[name][0]}")
        layout[name] = (dtype.fields[name][0], f.offset)
    step = int(msg.point_step)
    if n and len(msg.data) < step * n:
        raise DataError(f"{where}: PointCloud2 data holds {len(msg.data)} bytes, {n} points of {step} need more")
    if n == 0:
        return np.zeros(0, dtype)
    view = np.dtype({"names": list(layout), "formats": [v[0] for v in layout.values()],
                     "offsets": [v[1] for v in layout.values()], "itemsize": step})
    if msg.row_step == step * msg.width:      # rows are contiguous: one buffer view
        raw = np.frombuffer(msg.data, dtype=view, count=n)
    else:                                     # padded rows: take each row's points
        buf = np.frombuffer(msg.data, dtype=np.uint8)
        rows = [np.frombuffer(buf[r * msg.row_step: r * msg.row_step + step * msg.width].tobytes(), dtype=view)
                for r in range(msg.height)]
        raw = np.concatenate(rows)
    out = np.empty(n, dtype)
    for name in dtype.names:
        out[name] = raw[name]
    return out


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

    def put(names, values):
        vals = np.full((len(ids), 3), np.nan) if values is None else np.asarray(values, dtype=float).reshape(-1, 3)
        for k, name in enumerate(names):
            out[name] = vals[:, k]

    put(("x", "y", "z"), cop)
    put(("nx", "ny", "nz"), normal)
    put(("gx", "gy", "gz"), geo_center)
    put(("fx", "fy", "fz"), force)
    put(("mx", "my", "mz"), moment)
    out["pressure"] = np.nan if pressure is None else np.asarray(pressure, dtype=float)
    out["contact"] = ids
    return out


def xyz(points: np.ndarray, prefix: str = "") -> np.ndarray:
    """``(N, 3)`` float array of the ``<prefix>x <prefix>y <prefix>z`` fields."""
    return np.stack([points[prefix + "x"], points[prefix + "y"], points[prefix + "z"]], axis=1).astype(float)


# ---------------------------------------------------------------------- JointState
def joint_state_msg(names, positions, stamp: Time) -> JointState:
    msg = JointState()
    msg.header.stamp = stamp
    msg.name = list(names)
    msg.position = np.asarray(positions, dtype=float).tolist()
    return msg


def joint_state_arrays(msg: JointState, where: str = JOINT_STATES_TOPIC) -> tuple:
    """``(stamp seconds, names list, positions (J,) float)``; DataError if names and positions disagree."""
    names = list(msg.name)
    positions = np.asarray(msg.position, dtype=float)
    if len(names) != len(positions):
        raise DataError(f"{where}: JointState has {len(names)} names but {len(positions)} positions")
    return stamp_from_msg(msg.header.stamp), names, positions
