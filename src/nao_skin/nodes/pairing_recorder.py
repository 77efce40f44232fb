"""pairing_recorder: self-touch events from the live streams into a touch bag, with progress.

Subscribes to ``/joint_states`` and every part's ``/skin/<part>/taxels`` and
``/skin/<part>/contacts`` and hands them to a
:class:`~nao_skin.session.recording.TouchRecording`: the same
:class:`~nao_skin.touch.events.EventDetector` that reads bags offline, each
detected touch written to a *touch bag* as ``write_touch_bag`` does (one
JointState at the touch stamp and the touching parts' skin messages). Every
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

On ``/diagnostics`` (1 Hz): the joint states' rate as received against the least one touch detection needs
(``joint states needed (Hz)``: one state per ``joint_tolerance``; the robot's driver may send more), the skin
samples' rate, the last touch's age, and the free disk where the bag is written
(WARN below 1 GiB, ERROR below 100 MiB).
"""
from __future__ import annotations

import json
import os
import shutil
import time

from rclpy.node import Node
from sensor_msgs.msg import JointState, PointCloud2
from std_msgs.msg import String

from nao_skin.errors import DataError
from nao_skin.formats.bag import default_bag_name
from nao_skin.formats.pointcloud import JOINT_STATES_TOPIC, contacts_topic, read_contacts, read_taxels, taxels_topic
from nao_skin.live.diagnostics import Check, RateWindow, age_check, count_check, disk_check, rate_check
from nao_skin.nodes.messages import header_stamp, joint_state_arrays
from nao_skin.nodes.diagnostics import publish_diagnostics
from nao_skin.nodes.runtime import declare, run_node
from nao_skin.nodes.topics import PROGRESS_TOPIC, STREAM_DEPTH, relative
from nao_skin.model.skin import SkinCalibration
from nao_skin.session.params import PAIRING_RECORDER, fingertip_scenes, skin_from_params
from nao_skin.session.recording import TouchRecording
from nao_skin.touch.events import EventConfig
from nao_skin.touch.fingertip import FingertipJudge


class PairingRecorder(Node):
    def __init__(self, **kwargs):
        super().__init__("pairing_recorder", **kwargs)
        p = declare(self, PAIRING_RECORDER)
        self.skin = skin_from_params(p)
        config = EventConfig(skin_tolerance=p["skin_tolerance"], joint_tolerance=p["joint_tolerance"],
                             min_interval=p["min_interval"], release_gap=p["release_gap"])
        scenes = fingertip_scenes(p, self.skin)
        judge = None
        if scenes:
            calibration = SkinCalibration.load(p["calibration"], self.skin) if p["calibration"] else None
            judge = FingertipJudge(self.skin, scenes, calibration, p["fingertip_gate_mm"] / 1000.0)
        self.recording = TouchRecording(self.skin, config, p["bag_path"] or default_bag_name(), p["storage"],
                                        p["recorded_from"], [path for path in p["continues"] if path],
                                        p["sim_seed"] if p["sim_seed"] >= 0 else None, judge)
        self.get_logger().info(f"recording touches to {self.recording.bag_path}")
        self._crowded_said: set = set()
        self._started = time.monotonic()
        self.create_subscription(JointState, relative(JOINT_STATES_TOPIC), self._on_joints, STREAM_DEPTH)
        for n in self.skin.parts:
            self.create_subscription(PointCloud2, relative(taxels_topic(n)), lambda m, n=n: self._on_taxels(n, m),
                                     STREAM_DEPTH)
            self.create_subscription(PointCloud2, relative(contacts_topic(n)), lambda m, n=n: self._on_contacts(n, m),
                                     STREAM_DEPTH)
        self.progress_pub = self.create_publisher(String, PROGRESS_TOPIC, 10)
        self.create_timer(float(p["flush_period"]), lambda: self.recording.flush(self._now()))
        self.create_timer(float(p["progress_period"]), self._publish_progress)
        # the detector needs a joint state within joint_tolerance of each touch: at least that rate, whatever the
        # robot's driver sends (naoqi_bridge 50 Hz, the simulated robot 100 Hz: the recorder is not told which)
        self._joint_rate = 1.0 / p["joint_tolerance"] if p["joint_tolerance"] > 0 else 0.0
        self._rates = {"joint states": RateWindow(), "skin samples": RateWindow()}
        self._touches_seen, self._touch_at = 0, None
        publish_diagnostics(self, self._diagnostics)

    # ------------------------------------------------------------------ input (one callback group: serial)
    def _on_joints(self, msg) -> None:
        try:
            stamp, names, positions = joint_state_arrays(msg)
        except DataError as exc:
            return self._bad(exc)
        self.recording.joint_state(stamp, names, positions, self._now())

    def _on_taxels(self, part: str, msg) -> None:
        t0 = time.perf_counter()
        try:
            stamp = header_stamp(msg, taxels_topic(part))
            slots, pressures, contacts = read_taxels(msg, self.skin.parts[part], taxels_topic(part))
        except DataError as exc:
            return self._bad(exc)
        self.recording.taxels(part, stamp, slots, pressures, contacts, self._now())
        self.recording.skin_ms.append((time.perf_counter() - t0) * 1e3)

    def _on_contacts(self, part: str, msg) -> None:
        t0 = time.perf_counter()
        try:
            stamp = header_stamp(msg, contacts_topic(part))
            contact_ids, cops = read_contacts(msg, self.skin.parts[part], contacts_topic(part))
        except DataError as exc:
            return self._bad(exc)
        self.recording.contacts(part, stamp, contact_ids, cops, self._now())
        self.recording.skin_ms.append((time.perf_counter() - t0) * 1e3)

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _bad(self, exc: Exception) -> None:
        if self.recording.bad_message():
            self.get_logger().warning(f"skipped: {exc}")

    # ------------------------------------------------------------------ what the operator is told
    def _check_publishers(self) -> None:
        """Say once per skin topic when more than one publisher feeds it: one bridge (or simulated robot)
        publishes a part's skin, so a second is most likely another session on this ROS_DOMAIN_ID whose
        touches would be recorded as this robot's."""
        for part in self.skin.parts:
            for topic in (taxels_topic(part), contacts_topic(part)):
                if topic in self._crowded_said:
                    continue
                infos = self.get_publishers_info_by_topic(relative(topic))
                if len(infos) > 1:
                    self._crowded_said.add(topic)
                    nodes = sorted({f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos})
                    self.get_logger().warning(
                        f"{topic} has {len(infos)} publishers ({', '.join(nodes)}): is another session"
                        f" on this ROS_DOMAIN_ID ({os.environ.get('ROS_DOMAIN_ID') or 0})? Its touches would"
                        f" be recorded as this robot's: give each robot a ROS_DOMAIN_ID of its own")

    def _publish_progress(self) -> None:
        progress = self.recording.progress()
        for warning in (self.recording.clock_warnings(progress["clock_skew_s"])
                        + self.recording.silence_warnings(time.monotonic() - self._started)
                        + self.recording.outage_warnings()):
            self.get_logger().warning(warning)
        self._check_publishers()
        self.progress_pub.publish(String(data=json.dumps(progress, sort_keys=True)))

    def _diagnostics(self, now: float) -> list:
        """Joint states against the rate touch detection needs, skin samples, the last touch, bad messages and
        the free disk where the bag is written."""
        received = self.recording.received
        rates = {what: window.rate(received[what], now) for what, window in self._rates.items()}
        if self.recording.n_touches > self._touches_seen:
            self._touches_seen, self._touch_at = self.recording.n_touches, now
        try:
            usage = shutil.disk_usage(self.recording.bag_path if self.recording.bag_path.exists()
                                      else self.recording.bag_path.parent)
            disk = disk_check(str(self.recording.bag_path), usage.free, usage.total)
        except OSError as exc:
            disk = disk_check(str(self.recording.bag_path), None, None, error=str(exc))
        return [rate_check("joint states", rates["joint states"], self._joint_rate, needed="touch detection"),
                rate_check("skin samples", rates["skin samples"], 0.0),
                age_check("touch", None if self._touch_at is None else now - self._touch_at),
                count_check("bad messages", sum(self.recording.errors.values())),
                disk,
                Check(values=(("touches", str(self.recording.n_touches)), ("bag", str(self.recording.bag_path))))]

    def close(self) -> None:
        """End of the session: what waits is written and the bag closed."""
        said = self.recording.close()
        if said:
            self.get_logger().info(said)


def main(args=None) -> int:
    return run_node(PairingRecorder, args)


if __name__ == "__main__":
    raise SystemExit(main())
