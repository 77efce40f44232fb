"""rclpy messages of the nao_skin topics: building and reading them; no node, no I/O.

Topic names, point layouts and the PointCloud2 codec are
:mod:`nao_skin.formats.pointcloud` (the same for bags and nodes); this module
only turns them into and out of rclpy message objects.
"""
from __future__ import annotations

import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import JointState, PointCloud2, PointField

from nao_skin.errors import DataError
from nao_skin.formats.pointcloud import JOINT_STATES_TOPIC, LAST_STAMP, encode_cloud, header_seconds


# ---------------------------------------------------------------------- time
def stamp_to_msg(seconds: float, where: str = "time") -> Time:
    """Seconds (float, e.g. a YARP envelope time) to ``builtin_interfaces/Time``; DataError naming ``where`` for
    one no stamp holds (NaN, infinite, beyond int32 seconds either way; before 1970 is a time, the recorder
    judges it)."""
    if not -LAST_STAMP <= float(seconds) < LAST_STAMP:
        raise DataError(f"{where}: {float(seconds)!r} s is no time a ROS stamp holds (int32 seconds: up to"
                        f" January 2038)")
    ns = int(round(float(seconds) * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def stamp_from_msg(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def header_stamp(msg, where: str) -> float:
    """The message's header stamp in seconds; DataError for one that is no time or unset (:func:`header_seconds`)."""
    return header_seconds(msg.header.stamp, where, zero=False)


# ---------------------------------------------------------------------- PointCloud2
def cloud_from_array(points: np.ndarray, frame_id: str, stamp: Time | None) -> PointCloud2:
    """A dense, unorganised (height 1) PointCloud2 holding the structured array ``points``."""
    cloud = encode_cloud(points)
    msg = PointCloud2()
    msg.header.frame_id = frame_id
    if stamp is not None:
        msg.header.stamp = stamp
    msg.height, msg.width = cloud["height"], cloud["width"]
    msg.fields = [PointField(name=n, offset=o, datatype=d, count=k) for n, o, d, k in cloud["fields"]]
    msg.is_bigendian, msg.is_dense = cloud["is_bigendian"], cloud["is_dense"]
    msg.point_step, msg.row_step = cloud["point_step"], cloud["row_step"]
    msg.data = cloud["data"]
    return msg


# ---------------------------------------------------------------------- JointState
def joint_state_msg(names, positions, stamp: Time) -> JointState:
    msg = JointState()
    msg.header.stamp = stamp
    msg.name = list(names)
    msg.position = np.asarray(positions, dtype=float).tolist()
    return msg


def joint_state_arrays(msg: JointState, where: str = JOINT_STATES_TOPIC) -> tuple:
    """``(stamp seconds, names list, positions (J,) float)``; DataError if names and positions disagree
    or the stamp is no time (:func:`header_stamp`)."""
    names = list(msg.name)
    positions = np.asarray(msg.position, dtype=float)
    if len(names) != len(positions):
        raise DataError(f"{where}: JointState has {len(names)} names but {len(positions)} positions")
    return header_stamp(msg, where), names, positions
