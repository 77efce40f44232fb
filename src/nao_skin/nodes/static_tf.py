"""Thin rclpy helpers to publish latched static transforms on ``/tf_static``.

``tf2_ros.StaticTransformBroadcaster`` does the same in a real ROS install;
these helpers only need rclpy + tf2_msgs + geometry_msgs, so they also work
in the pip venv (docker/setup_venv.sh), where tf2_ros is not available.

Usage::

    pub = latched_tf_static_publisher(node)
    stamp = node.get_clock().now().to_msg()
    pub.publish(TFMessage(transforms=[
        to_transform_stamped('base_link', 'skin_patch_0', T, stamp)]))

Note: like tf2_ros' broadcaster, a latched publisher keeps only its LAST
message (depth 1), so publish all static transforms of a node in one
TFMessage.
"""
import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import TransformStamped
from tf2_msgs.msg import TFMessage

from nao_skin import se3
from nao_skin.nodes.messages import stamp_to_msg
from nao_skin.nodes.topics import LATCHED, TF_STATIC_TOPIC


def latched_tf_static_publisher(node, topic=TF_STATIC_TOPIC):
    """Create a latched ``tf2_msgs/TFMessage`` publisher on ``/tf_static``."""
    return node.create_publisher(TFMessage, topic, LATCHED)


def rotation_to_quaternion(rot):
    """3x3 rotation matrix -> unit quaternion ``(x, y, z, w)`` (ROS order) with ``w >= 0``.

    The input is first projected onto the nearest proper rotation (SVD), so
    matrices with small numerical drift are accepted; singular matrices and
    reflections raise ValueError. The conversion is :func:`nao_skin.se3.matrix_to_quaternion`.
    """
    r = np.asarray(rot, dtype=float)
    if r.shape != (3, 3) or not np.all(np.isfinite(r)):
        raise ValueError(f'expected a finite 3x3 rotation matrix, got {r!r}')
    u, s, vt = np.linalg.svd(r)
    if s[-1] <= 1e-9 * max(s[0], 1e-300):
        raise ValueError(f'rotation matrix is singular: {r!r}')
    if np.linalg.det(u @ vt) < 0:
        raise ValueError(f'matrix is a reflection, not a rotation: {r!r}')
    return se3.matrix_to_quaternion(u @ vt)


def _to_time_msg(stamp):
    if stamp is None:
        return Time()
    if hasattr(stamp, 'to_msg'):  # rclpy.time.Time
        return stamp.to_msg()
    if isinstance(stamp, (int, float)):
        return stamp_to_msg(stamp)
    return stamp  # builtin_interfaces/Time


def to_transform_stamped(parent, child, matrix, stamp):
    """4x4 homogeneous ``parent_T_child`` -> ``geometry_msgs/TransformStamped``.

    ``stamp`` may be a ``builtin_interfaces/Time``, an ``rclpy.time.Time``,
    seconds as a number, or ``None`` (zero time, fine for static transforms).
    """
    t = np.asarray(matrix, dtype=float)
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        raise ValueError(f'expected a finite 4x4 homogeneous matrix, got {t!r}')
    if not np.allclose(t[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise ValueError(f'last row of a homogeneous matrix must be [0 0 0 1]: {t!r}')
    if not parent or not child:
        raise ValueError('parent and child frame ids must be non-empty')
    q = rotation_to_quaternion(t[:3, :3])

    msg = TransformStamped()
    msg.header.stamp = _to_time_msg(stamp)
    msg.header.frame_id = str(parent)
    msg.child_frame_id = str(child)
    tr = msg.transform.translation
    tr.x, tr.y, tr.z = (float(v) for v in t[:3, 3])
    rq = msg.transform.rotation
    rq.x, rq.y, rq.z, rq.w = (float(v) for v in q)
    return msg
