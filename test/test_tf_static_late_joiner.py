"""/tf_static latching over real DDS (rmw_fastrtps_cpp), no ROS install needed.

A publisher made with nao_skin.nodes.static_tf publishes a TFMessage before
any subscriber exists; a subscriber created afterwards with the same QoS
(RELIABLE + TRANSIENT_LOCAL, depth 1) must still get it. After a second
publish, a third late subscriber must only get the second message.

Each node lives in its own rclpy context (its own DDS participant), on a
ROS domain id derived from the pid, with discovery restricted to localhost.
"""
import math
import os
import time

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from tf2_msgs.msg import TFMessage

from nao_skin.nodes.static_tf import latched_tf_static_publisher, rotation_to_quaternion, to_transform_stamped
from nao_skin.nodes.topics import LATCHED, TF_STATIC_TOPIC

WAIT_S = 10.0


def rot_z(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def homogeneous(rot, trans):
    t = np.eye(4)
    t[:3, :3] = rot
    t[:3, 3] = trans
    return t


# 90 deg about z, and 180 deg about x (the numerically delicate case).
T_A = homogeneous(rot_z(math.pi / 2), [0.1, -0.2, 0.3])
Q_A = (0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5))
T_B = homogeneous(np.diag([1.0, -1.0, -1.0]), [1.5, 2.5, -3.5])
Q_B = (1.0, 0.0, 0.0, 0.0)
T_C = homogeneous(np.eye(3), [0.0, 0.0, 0.7])
Q_C = (0.0, 0.0, 0.0, 1.0)


class Ros:
    """Owns rclpy contexts/nodes/executors made by a test; tears them down."""

    def __init__(self, domain_id):
        self.domain_id = domain_id
        self._items = []  # (context, executor, node)

    def node(self, name):
        ctx = Context()
        rclpy.init(context=ctx, domain_id=self.domain_id)
        executor = None
        node = None
        try:
            node = Node(name, context=ctx)
            executor = SingleThreadedExecutor(context=ctx)
            executor.add_node(node)
        except BaseException:
            if node is not None:
                node.destroy_node()
            ctx.try_shutdown()
            raise
        self._items.append((ctx, executor, node))
        return node, executor

    def close(self):
        while self._items:
            ctx, executor, node = self._items.pop()
            try:
                executor.shutdown(timeout_sec=1.0)
            finally:
                try:
                    node.destroy_node()
                finally:
                    ctx.try_shutdown()


@pytest.fixture
def ros(monkeypatch):
    # Unique-ish domain per test run to avoid cross-talk with other runs;
    # keep DDS discovery on this machine.
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.delenv('ROS_STATIC_PEERS', raising=False)
    monkeypatch.setenv('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    domain_id = 1 + os.getpid() % 100
    r = Ros(domain_id)
    try:
        yield r
    finally:
        r.close()


def subscribe(ros, name):
    node, executor = ros.node(name)
    received = []
    node.create_subscription(TFMessage, TF_STATIC_TOPIC, received.append, LATCHED)
    return executor, received


def spin_until(executor, predicate, timeout=WAIT_S):
    deadline = time.monotonic() + timeout
    while not predicate() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    return predicate()


def spin_for(executor, duration):
    deadline = time.monotonic() + duration
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)


def assert_transform(ts, parent, child, mat, quat):
    assert ts.header.frame_id == parent
    assert ts.child_frame_id == child
    tr = ts.transform.translation
    np.testing.assert_allclose([tr.x, tr.y, tr.z], mat[:3, 3], atol=1e-12)
    q = ts.transform.rotation
    np.testing.assert_allclose([q.x, q.y, q.z, q.w], quat, atol=1e-9)


def test_to_transform_stamped_numbers():
    ts = to_transform_stamped('base_link', 'skin_a', T_A, 12.25)
    assert_transform(ts, 'base_link', 'skin_a', T_A, Q_A)
    assert (ts.header.stamp.sec, ts.header.stamp.nanosec) == (12, 250_000_000)
    assert_transform(to_transform_stamped('a', 'b', T_B, None), 'a', 'b', T_B, Q_B)


def test_rotation_to_quaternion_roundtrip():
    rng = np.random.default_rng(0)
    for _ in range(200):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = rng.uniform(0.0, math.pi)
        half = angle / 2.0
        q_ref = np.append(axis * math.sin(half), math.cos(half))
        x, y, z, w = q_ref
        rot = np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ])
        q = rotation_to_quaternion(rot)
        assert q[3] >= 0.0
        np.testing.assert_allclose(q, q_ref, atol=1e-9)
    with pytest.raises(ValueError):
        rotation_to_quaternion(np.diag([1.0, 1.0, -1.0]))  # reflection
    with pytest.raises(ValueError):
        to_transform_stamped('a', 'b', np.zeros((3, 3)), None)


@pytest.mark.middleware   # DDS participants in this process
def test_tf_static_late_joiner_gets_latched_message(ros):
    pub_node, _ = ros.node('nao_skin_tf_static_pub')
    pub = latched_tf_static_publisher(pub_node)
    assert pub.qos_profile.durability == LATCHED.durability
    stamp = pub_node.get_clock().now().to_msg()

    first = TFMessage(transforms=[
        to_transform_stamped('base_link', 'skin_patch_a', T_A, stamp),
        to_transform_stamped('base_link', 'skin_patch_b', T_B, stamp),
    ])
    pub.publish(first)

    # Subscriber created only AFTER the publish: it must get the latched message.
    exec1, got1 = subscribe(ros, 'late_sub_1')
    assert spin_until(exec1, lambda: len(got1) >= 1), 'late subscriber got no /tf_static'
    spin_for(exec1, 0.5)  # give a (wrong) duplicate a chance to show up
    assert len(got1) == 1
    msg = got1[0]
    assert [t.child_frame_id for t in msg.transforms] == ['skin_patch_a', 'skin_patch_b']
    assert_transform(msg.transforms[0], 'base_link', 'skin_patch_a', T_A, Q_A)
    assert_transform(msg.transforms[1], 'base_link', 'skin_patch_b', T_B, Q_B)
    assert msg.transforms[0].header.stamp == stamp

    # Second publish replaces the latched message (depth 1).
    second = TFMessage(transforms=[
        to_transform_stamped('torso', 'skin_patch_c', T_C, stamp),
    ])
    pub.publish(second)
    assert spin_until(exec1, lambda: len(got1) >= 2), 'live subscriber missed 2nd message'
    assert [t.child_frame_id for t in got1[1].transforms] == ['skin_patch_c']

    exec3, got3 = subscribe(ros, 'late_sub_3')
    assert spin_until(exec3, lambda: len(got3) >= 1), 'third late subscriber got nothing'
    spin_for(exec3, 0.5)
    assert len(got3) == 1
    assert [t.child_frame_id for t in got3[0].transforms] == ['skin_patch_c']
    assert_transform(got3[0].transforms[0], 'torso', 'skin_patch_c', T_C, Q_C)
