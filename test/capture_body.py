"""The robot's body for the capture's end-to-end test: a MOCK of the body only (nothing of the capture).

:class:`nao_skin.sim.body.SimBody` in real time, served as ``ALMotion`` behind a real libqi session
(:func:`qi_body`: libqi's multi-threaded object, so ``getAngles`` answers while a move runs, as NAOqi's
does), and its skin as skinManager and the YARP bridge would put it on ROS (:class:`SkinPublisher`:
``/skin/<part>/taxels`` and ``/skin/<part>/contacts`` at 50 Hz, the released parts empty; a press is one
skinManager contact, its COP the pressure-weighted centre of its taxels).
"""
from __future__ import annotations

import threading

import numpy as np

from nao_skin.formats.pointcloud import contacts_array, contacts_topic, taxels_array, taxels_topic
from nao_skin.sim.body import SimBody

SKIN_HZ = 50.0


def qi_body(*args, **kwargs) -> SimBody:
    """A real-time :class:`SimBody` whose methods libqi may call concurrently."""
    import qi

    cls = qi.multiThreaded()(type("QiSimBody", (SimBody,), {}))
    return cls(*args, realtime=True, **kwargs)


class SkinPublisher:
    """The body's skin on the ROS topics, from a thread of its own, on ``node`` (an rclpy node)."""

    def __init__(self, node, body: SimBody):
        from sensor_msgs.msg import PointCloud2

        from nao_skin.nodes.messages import cloud_from_array
        from nao_skin.nodes.topics import STREAM_DEPTH

        self.node, self.body, self.cloud = node, body, cloud_from_array
        self.parts = list(body.skin.parts)
        self.taxels = {p: node.create_publisher(PointCloud2, taxels_topic(p), STREAM_DEPTH) for p in self.parts}
        self.contacts = {p: node.create_publisher(PointCloud2, contacts_topic(p), STREAM_DEPTH) for p in self.parts}
        self.pressed = 0          # messages of the target part that fired
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        part = self.body.part
        sp = self.body.skin.parts[part]
        while not self._stop.wait(1.0 / SKIN_HZ):
            slots, pressure = self.body.skin_now()
            stamp = self.node.get_clock().now().to_msg()
            for name in self.parts:
                frame = self.body.skin.parts[name].parent_frame
                if name == part and len(slots):
                    self.pressed += 1
                    cid = np.full(len(slots), self.body.press_key)
                    pos = sp.positions[slots]
                    cop = (pressure[:, None] * pos).sum(axis=0) / pressure.sum()
                    taxels = taxels_array(slots, pos, pressure, cid)
                    contacts = contacts_array(cid[:1], cop[None], pressure=[pressure.mean()])
                else:
                    taxels, contacts = taxels_array([], []), contacts_array([], [])
                # contacts first: the recorder attaches them to the taxel sample of the same stamp
                self.contacts[name].publish(self.cloud(contacts, frame, stamp))
                self.taxels[name].publish(self.cloud(taxels, frame, stamp))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
