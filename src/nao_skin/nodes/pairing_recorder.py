"""pairing_recorder: self-touch events from the live streams into a touch bag, with progress.

Subscribes to ``/joint_states`` and every part's ``/skin/<part>/taxels`` and
``/skin/<part>/contacts``, feeds them to the same
:class:`~nao_skin.touch.events.EventDetector` that reads bags offline, and
writes each detected touch to a *touch bag* as ``write_touch_bag`` does
(:meth:`~nao_skin.formats.bag.BagWriter.write_touch`, mcap): one JointState
at the touch stamp and the touching parts' skin messages. Every
``flush_period`` s what was written is made durable, so a ``kill -9`` loses
at most the last period; SIGINT writes everything and closes the bag
properly.

Progress on ``/nao_skin/recorder/progress`` (std_msgs/String, JSON) every
``progress_period`` s: touches per pair (e.g. ``l_hand+torso``), the share of
each part's taxels in at least one recorded touch, dropped events by reason,
the processing time per skin message (p50/p99, ms), and per skin topic how far
its stamps lag the joint states' (``clock_skew_s``; beyond a quarter second the
two come from different clocks, and the node says so once). It also says once
per skin topic when a second publisher feeds it (another session on the same
ROS_DOMAIN_ID).
"""
from __future__ import annotations

import json
import os
import time
from collections import Counter, deque
from pathlib import Path
from typing import NoReturn

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import JointState, PointCloud2
from std_msgs.msg import String

from nao_skin.errors import BagMoved, DataError, DiskFull, OutputError
from nao_skin.formats.bag import BagWriter, default_bag_name, detected_touch_messages
from nao_skin.formats.pointcloud import JOINT_STATES_TOPIC, contacts_topic, read_contacts, read_taxels, taxels_topic
from nao_skin.live.clocks import SKEW_LIMIT_S, ArrivalLags
from nao_skin.live.heatmap import ActivationCounts
from nao_skin.model.skin import pair_label
from nao_skin.nodes.messages import header_stamp, joint_state_arrays
from nao_skin.nodes.runtime import declare, run_node
from nao_skin.nodes.topics import PROGRESS_TOPIC
from nao_skin.session.params import PAIRING_RECORDER, skin_from_params
from nao_skin.touch.events import EventConfig, EventDetector

MAX_LOGGED_ERRORS = 5
class PairingRecorder(Node):
    def __init__(self, **kwargs):
        super().__init__("pairing_recorder", **kwargs)
        p = declare(self, PAIRING_RECORDER)
        self.skin = skin_from_params(p)
        config = EventConfig(skin_tolerance=p["skin_tolerance"], joint_tolerance=p["joint_tolerance"],
                             min_interval=p["min_interval"], release_gap=p["release_gap"])
        self.detector = EventDetector.for_skin(self.skin, config)
        self.parts = list(self.skin.parts)
        self.joint_names = list(self.skin.robot.joint_names)
        path = p["bag_path"] or default_bag_name()
        self.bag_path = Path(path).expanduser().resolve()
        self.bag = BagWriter(self.bag_path, p["storage"], kind="touches", live=True)
        self.bag.__enter__()
        self.get_logger().info(f"recording touches to {self.bag_path}")
        self.n_touches = 0
        self.pairs: Counter = Counter()
        self.touched = ActivationCounts({n: self.skin.parts[n].n_slots for n in self.parts})     # in recorded touches
        self.errors: Counter = Counter()
        self._logged = 0
        self.skin_ms: deque = deque(maxlen=20000)     # processing time of recent skin messages
        self._dirty = False
        self._closed = False
        self._flushed = 0            # touches made durable by the last flush
        self.lags = ArrivalLags()    # do the skin and the joints share a clock?
        self._skew_said: set = set()
        self._skew_seen: dict = {}   # skin topic -> progress checks in a row it was beyond the limit
        self._crowded_said: set = set()
        self.create_subscription(JointState, JOINT_STATES_TOPIC, self._on_joints, 200)
        for n in self.parts:
            self.create_subscription(PointCloud2, taxels_topic(n), lambda m, n=n: self._on_taxels(n, m), 200)
            self.create_subscription(PointCloud2, contacts_topic(n), lambda m, n=n: self._on_contacts(n, m), 200)
        self.progress_pub = self.create_publisher(String, PROGRESS_TOPIC, 10)
        self.create_timer(float(p["flush_period"]), self._flush)
        self.create_timer(float(p["progress_period"]), self._publish_progress)

    # ------------------------------------------------------------------ input (one callback group: serial)
    def _on_joints(self, msg) -> None:
        try:
            stamp, names, positions = joint_state_arrays(msg)
        except DataError as exc:
            return self._bad(exc)
        self.lags.add(JOINT_STATES_TOPIC, stamp, self._now())
        self._write(self.detector.add_joint_state(stamp, names, positions))

    def _on_taxels(self, part: str, msg) -> None:
        t0 = time.perf_counter()
        try:
            stamp = header_stamp(msg, taxels_topic(part))
            slots, pressures, contacts = read_taxels(msg, self.skin.parts[part], taxels_topic(part))
        except DataError as exc:
            return self._bad(exc)
        self.lags.add(taxels_topic(part), stamp, self._now())
        self._write(self.detector.add_skin(stamp, part, slots.tolist(), pressures.tolist(), contacts.tolist()))
        self.skin_ms.append((time.perf_counter() - t0) * 1e3)

    def _on_contacts(self, part: str, msg) -> None:
        t0 = time.perf_counter()
        try:
            stamp = header_stamp(msg, contacts_topic(part))
            contact_ids, cops = read_contacts(msg, self.skin.parts[part], contacts_topic(part))
        except DataError as exc:
            return self._bad(exc)
        self.detector.add_contacts(stamp, part, contact_ids, cops)
        self.skin_ms.append((time.perf_counter() - t0) * 1e3)

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _check_clocks(self, skew: dict) -> None:
        """Say once per skin stream when its stamps are on another clock than the joint states': beyond
        the limit at two progress checks in a row (one check's window can still hold a start-up queue)."""
        for topic, s in skew.items():
            beyond = abs(s) > SKEW_LIMIT_S
            self._skew_seen[topic] = self._skew_seen.get(topic, 0) + 1 if beyond else 0
            if self._skew_seen[topic] >= 2 and topic not in self._skew_said:
                self._skew_said.add(topic)
                self.get_logger().warning(
                    f"{topic} is stamped {abs(s):.2f} s {'behind' if s > 0 else 'ahead of'} {JOINT_STATES_TOPIC}"
                    f" for messages that arrive together: the skin's clock is not the joints' (skinManager on"
                    f" another host?), so every touch takes the arm pose of another moment. Synchronise the"
                    f" clocks (chrony/NTP), or start yarp_skin_bridge with stamp:=receive")

    def _check_publishers(self) -> None:
        """Say once per skin topic when more than one publisher feeds it: one bridge (or simulated robot)
        publishes a part's skin, so a second is most likely another session on this ROS_DOMAIN_ID whose
        touches would be recorded as this robot's."""
        for part in self.parts:
            for topic in (taxels_topic(part), contacts_topic(part)):
                if topic in self._crowded_said:
                    continue
                infos = self.get_publishers_info_by_topic(topic)
                if len(infos) > 1:
                    self._crowded_said.add(topic)
                    nodes = sorted({f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos})
                    self.get_logger().warning(
                        f"{topic} has {len(infos)} publishers ({', '.join(nodes)}): is another session"
                        f" on this ROS_DOMAIN_ID ({os.environ.get('ROS_DOMAIN_ID') or 0})? Its touches would"
                        f" be recorded as this robot's: give each robot a ROS_DOMAIN_ID of its own")

    def _bad(self, exc: Exception) -> None:
        self.errors["bad message"] += 1
        if self._logged < MAX_LOGGED_ERRORS:
            self._logged += 1
            self.get_logger().warning(f"skipped: {exc}")

    # ------------------------------------------------------------------ output
    def _write(self, records) -> None:
        touches = detected_touch_messages(records, self.skin, self.detector.part_names, self.joint_names,
                                          self.bag_path)
        for stamp_ns, joint_names, joints, parts in touches:
            if self._closed:
                return
            try:
                self.bag.write_touch(stamp_ns, joint_names, joints, parts)
            except OutputError as exc:
                self._cannot_write(exc)
            for part, taxels, _ in parts:
                self.touched.update(part.name, taxels["slot"])
            self.pairs[pair_label(part.name for part, _, _ in parts)] += 1
            self.n_touches += 1
            self._dirty = True

    def _flush(self) -> None:
        if self._dirty and not self._closed:
            try:
                self.bag.flush()
            except OutputError as exc:
                self._cannot_write(exc)
            self._dirty = False
            self._flushed = self.n_touches

    def _cannot_write(self, exc: OutputError) -> NoReturn:
        """The bag cannot take more (e.g. the disk is full): stop recording, leave the bag as it is.

        Closing it would write again; left open, with its lock, every reader takes it for a recording
        whose recorder died and reads it up to its last flush. The node ends (exit 2) and with it a
        record session, rather than let the operator go on touching for nothing.
        """
        self._closed = True
        if isinstance(exc, BagMoved):     # it says where the touches are now
            raise OutputError(f"{exc} after {self.n_touches} touches") from None
        then = "free some space, then record on" if isinstance(exc, DiskFull) else "once that is fixed, record on"
        raise OutputError(f"{exc} after {self.n_touches} touches; recording stopped. The bag keeps the"
                          f" {self._flushed} touches flushed before (maybe a few more) and nao-skin reads it as it"
                          f" is; {then} into a new bag") from None

    def progress(self) -> dict:
        ms = np.array(self.skin_ms) if self.skin_ms else np.zeros(1)
        drops = {k: v for k, v in self.detector.counts.items() if k not in ("touches", "continued press")}
        return {
            "bag": str(self.bag_path), "touches": self.n_touches, "pairs": dict(self.pairs),
            "coverage": {n: round(self.touched.coverage(n, self.skin.parts[n].present), 4) for n in self.parts},
            "dropped": drops | dict(self.errors),
            # per skin topic, s its stamps lag the joint states' (beyond a few ms: another clock)
            "clock_skew_s": {t: round(v, 4) for t, v in self.lags.skew(JOINT_STATES_TOPIC).items()},
            "skin_message_ms": {"n": len(self.skin_ms), "p50": round(float(np.percentile(ms, 50)), 4),
                                "p99": round(float(np.percentile(ms, 99)), 4), "max": round(float(ms.max()), 4)},
        }

    def _publish_progress(self) -> None:
        progress = self.progress()
        self._check_clocks(progress["clock_skew_s"])
        self._check_publishers()
        self.progress_pub.publish(String(data=json.dumps(progress, sort_keys=True)))

    def close(self) -> None:
        """End of the session: resolve what waits, write it, close the bag (metadata)."""
        if self._closed:
            return
        self._write(self.detector.flush())
        self._closed = True
        try:
            self.bag.__exit__(None, None, None)
        except OutputError as exc:
            self._cannot_write(exc)
        self.get_logger().info(f"wrote {self.n_touches} touches to {self.bag_path}: {json.dumps(dict(self.pairs))}")


def main(args=None) -> int:
    return run_node(PairingRecorder, args)


if __name__ == "__main__":
    raise SystemExit(main())
