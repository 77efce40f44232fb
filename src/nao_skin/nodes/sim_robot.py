"""sim_robot: the simulated robot live, on the same topics as the real bridges.

Runs the simulator (:func:`nao_skin.sim.play.live_touches`: ``simulate``'s touches of the pairs and fingertip
scenes played, seeded, so a test can recompute exactly what was played, and among fingertip touches the
experimenter's stray presses, a part firing with no fingertip near) and plays its touches with
:class:`nao_skin.live.playback.Playback`: ``/joint_states`` at ``joint_rate`` Hz,
``/skin/<part>/taxels`` and ``/skin/<part>/contacts`` for every part at
``skin_rate`` Hz (empty clouds = released, as the YARP bridge sends), one
press per touch. Every message of a playback is stamped on its timeline (the
clock at its start plus the tick's time), not when the thread got to send it:
a stall of the machine delays messages but never opens a gap between the
samples of one press, which a detector would rightly take for a release and
a second press (a touch recorded twice). Publishes ``/sim_robot/status``
(std_msgs/String, JSON: touches ``played`` of ``total``, stray presses among them ``strays``, ``done`` once every
touch is played, ``stopped`` when the node was stopped before: its last status
says so) once per second.

With ``wait_for_subscribers: N`` the play starts only when every skin taxels
topic has N subscribers and the other topics at least one, and each of them
acknowledged the released state published then (bounded by ``wait_timeout``),
so nothing played is lost to DDS discovery.

``guided: true`` follows the guidance instead of playing a set made in
advance (:class:`nao_skin.sim.capture.CaptureSim`, the same truth for the
seed): ``guided_start`` random touches, then batches of ``guided_batch``
touches aimed at the top targets of the latest ``/nao_skin/guidance``
(random when there is none yet), through the simulator's pose solver, until
``touches_per_pair`` x pairs touches are played.
"""
from __future__ import annotations

import json
import threading
import time

from rclpy._rclpy_pybind11 import RCLError
from rclpy.duration import Duration
from rclpy.node import Node
from sensor_msgs.msg import JointState, PointCloud2
from std_msgs.msg import String

from nao_skin.errors import DataError
from nao_skin.formats.pointcloud import JOINT_STATES_TOPIC, contacts_array, contacts_topic, taxels_array, taxels_topic
from nao_skin.guidance.capture import targets_from_json
from nao_skin.live.diagnostics import Check, RateWindow, rate_check
from nao_skin.live.playback import Playback
from nao_skin.nodes.messages import cloud_from_array, joint_state_msg
from nao_skin.nodes.diagnostics import publish_diagnostics
from nao_skin.nodes.runtime import declare, run_node
from nao_skin.nodes.topics import GUIDANCE_TOPIC, LATCHED, SIM_STATUS_TOPIC, STREAM_DEPTH, frame_prefix, relative
from nao_skin.session.params import SIM_ROBOT, check_sim_robot
from nao_skin.sim.capture import Aim, CaptureSim
from nao_skin.sim.play import live_touches


class SimRobot(Node):
    def __init__(self, **kwargs):
        super().__init__("sim_robot", **kwargs)
        p = declare(self, SIM_ROBOT)
        self.skin, params = check_sim_robot(p)
        self.timing = (p["touch_period"], p["press_duration"], p["hold"])
        self.guided = bool(p["guided"])
        self.targets: list = []           # the latest guidance's targets, best first
        self.strays = 0                   # presses of a part with no fingertip near (an experimenter's hand)
        if self.guided:
            self.capture = CaptureSim(self.skin, params, int(p["seed"]))
            self.total = int(p["touches_per_pair"]) * len(self.capture.pairs)
            self.batch = (min(int(p["guided_start"]), self.total), int(p["guided_batch"]))
            self.aimed = 0                # touches aimed at a guidance target (the rest are random)
            self.playback = Playback(self.capture.random(self.batch[0]), self.skin, *self.timing)
            self.create_subscription(String, GUIDANCE_TOPIC, self._on_guidance, LATCHED)
            self.get_logger().info(f"guided: {self.batch[0]} random touches, then batches of {self.batch[1]} aimed"
                                   f" at the guidance, {self.total} in all (seed {p['seed']})")
        else:
            result = live_touches(self.skin, params, int(p["seed"]))
            self.playback = Playback(result.touches, self.skin, *self.timing)
            self.total = len(self.playback)
            self.strays = int(result.pairs.get("stray", {}).get("touches", 0))
            among = f", {self.strays} of them stray presses (no fingertip near)" if self.strays else ""
            self.get_logger().info(f"simulated {len(self.playback)} touches{among} (seed {p['seed']}); playing them,"
                                   f" one every {p['touch_period']:g} s")
        self.joint_period = 1.0 / float(p["joint_rate"])
        self.skin_every = max(1, round(float(p["joint_rate"]) / float(p["skin_rate"])))
        self.loop = bool(p["loop"])
        self.parts = list(self.skin.parts)
        self.joint_pub = self.create_publisher(JointState, relative(JOINT_STATES_TOPIC), STREAM_DEPTH)
        self.taxel_pub = {n: self.create_publisher(PointCloud2, relative(taxels_topic(n)), STREAM_DEPTH)
                          for n in self.parts}
        self.contact_pub = {n: self.create_publisher(PointCloud2, relative(contacts_topic(n)), STREAM_DEPTH)
                            for n in self.parts}
        self.status_pub = self.create_publisher(String, SIM_STATUS_TOPIC, 10)
        self.wait_for = int(p["wait_for_subscribers"])
        self.wait_timeout = float(p["wait_timeout"])
        self.played = 0
        self.done = False                 # every touch played (with loop: never)
        self.stopped = False              # stopped (Ctrl-C) before it was done
        self.published = 0                # joint states published
        self._joint_rate = RateWindow()
        self.frames = frame_prefix(self)
        self._empty = {n: (cloud_from_array(taxels_array([], []), self.frames + self.skin.parts[n].parent_frame, None),
                           cloud_from_array(contacts_array([], []), self.frames + self.skin.parts[n].parent_frame,
                                            None))
                       for n in self.parts}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._play, name="sim_play", daemon=True)
        self._thread.start()
        self.create_timer(1.0, self._publish_status)
        # two simulated robots (a session each, in its namespace) are two pieces of hardware
        robot = f"simulated robot {self.get_namespace()}".rstrip(" /")
        publish_diagnostics(self, self._diagnostics, hardware_id=robot)

    def _subscribers_ready(self) -> bool:
        if self.wait_for <= 0:
            return True
        return (all(pub.get_subscription_count() >= self.wait_for for pub in self.taxel_pub.values())
                and self.joint_pub.get_subscription_count() >= 1
                and all(pub.get_subscription_count() >= 1 for pub in self.contact_pub.values()))

    def _wait_for_subscribers(self) -> None:
        """Until every topic has its subscribers and each of them takes what is published (bounded).

        A publisher counts a subscriber as soon as it has discovered it, which can be before the
        subscriber has discovered the publisher; under load that gap outlasted the lead-in, and a
        subscriber that meets a volatile publisher late drops what it sent before (the recorder lost
        the first touch). So the released state is published once and every publisher waits until
        its subscribers acknowledged it: from then on each of them receives every message."""
        deadline = time.monotonic() + self.wait_timeout
        while not self._subscribers_ready() and time.monotonic() < deadline and not self._stop.is_set():
            self._stop.wait(0.05)
        if not self._subscribers_ready():
            self.get_logger().warning(f"playing although not every topic has {self.wait_for} subscribers")
            return
        if self.wait_for <= 0 or self.wait_timeout <= 0:
            return
        self._publish(0.0, 0)
        publishers = [self.joint_pub, *self.contact_pub.values(), *self.taxel_pub.values()]
        for pub in publishers:
            # in short waits (each holds the GIL): a node stopped meanwhile is not held up
            try:
                while not pub.wait_for_all_acked(Duration(seconds=0.02)):
                    if self._stop.is_set():
                        return
                    if time.monotonic() >= deadline:
                        self.get_logger().warning(f"playing although {pub.topic_name} was not acknowledged by"
                                                  f" every subscriber within wait_timeout {self.wait_timeout:g} s")
                        return
            except RCLError as exc:      # the middleware cannot tell: play, as without the wait
                self.get_logger().warning(f"playing without waiting for {pub.topic_name}'s subscribers: {exc}")
                return

    def _play(self) -> None:
        self._wait_for_subscribers()
        finished = False                  # the playback ran to its end (not stopped part-way)
        while not self._stop.is_set():
            finished = self._play_once()
            if self.guided and self.played < self.total:
                self.playback = Playback(self._next_batch(), self.skin, *self.timing)
                continue
            if not self.loop:
                break
        # a Ctrl-C part-way is no 'done': the last status says how many of the touches were played
        self.done = finished and not self.loop and (not self.guided or self.played >= self.total)
        self.stopped = not self.done
        self._publish_status()
        # keep the arm where it is: joint states go on, the skin is released
        tick = 0
        while not self._stop.wait(self.joint_period):
            self._publish(self.playback.duration, tick)
            tick += 1

    def _play_once(self) -> bool:
        """Play ``self.playback``; True when it ran to its end, False when the node was stopped part-way."""
        t0 = time.monotonic()
        start = self.get_clock().now()
        tick = 0
        last_touch = -1
        while not self._stop.is_set():
            t = tick * self.joint_period
            if t > self.playback.duration:
                return True
            delay = t0 + t - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)
            k = self._publish(t, tick, start + Duration(nanoseconds=round(t * 1e9)))
            if k > last_touch:
                last_touch = k
                self.played += 1
            tick += 1
        return False

    def _on_guidance(self, msg: String) -> None:
        try:
            self.targets, _ = targets_from_json(msg.data, self.skin)
        except DataError as exc:
            self.get_logger().warning(f"skipped a guidance message: {exc}")

    def _next_batch(self):
        """The next touches: aimed at the guidance's top targets (random while there is none)."""
        n = min(self.batch[1], self.total - self.played)
        pairs = set(self.capture.pairs)
        aims = [Aim(t["hand"], t["touched"], t["hand_triangle_id"], t["touched_triangle_id"])
                for t in self.targets if t["pose"] is not None and (t["hand"], t["touched"]) in pairs][:n]
        touches, aimed = self.capture.guided(aims, n)
        self.aimed += aimed
        if aims:
            missed = f" ({len(aims) - aimed} of {len(aims)} aims reached no firing press)" if aimed < len(aims) else ""
            how = f"{aimed} aimed at guidance targets{missed}, {n - aimed} random"
        else:
            how = ("random (no guidance yet)" if not self.targets
                   else f"random (none of the guidance's {len(self.targets)} targets has a pose for a pair played here)")
        self.get_logger().info(f"next {touches.n_touches} touches: {how}")
        return touches

    def _publish(self, t: float, tick: int, at=None) -> int:
        """The streams at playback time ``t``, stamped ``at`` (rclpy Time; now when None); the touch pressed."""
        stamp = (self.get_clock().now() if at is None else at).to_msg()
        self.joint_pub.publish(joint_state_msg(self.playback.joint_names, self.playback.joints_at(t), stamp))
        self.published += 1
        if tick % self.skin_every:
            return -1
        k = self.playback.touch_at(t)
        pressed = self.playback.samples[k] if k >= 0 else {}
        for name in self.parts:
            frame = self.frames + self.skin.parts[name].parent_frame
            if name in pressed:
                taxels, contacts = (cloud_from_array(points, frame, stamp) for points in pressed[name])
            else:
                taxels, contacts = self._empty[name]
                taxels.header.stamp = stamp
                contacts.header.stamp = stamp
            # contacts first: the recorder attaches them to the taxel sample of the same stamp
            self.contact_pub[name].publish(contacts)
            self.taxel_pub[name].publish(taxels)
        return k

    def _publish_status(self) -> None:
        status = {"played": self.played, "total": self.total, "strays": self.strays, "done": self.done}
        if self.stopped:
            status["stopped"] = True
        if self.guided:       # how the touches were chosen: aimed at the guidance, or random
            status.update(aimed=self.aimed, missed_aims=self.capture.missed)
        self.status_pub.publish(String(data=json.dumps(status)))

    def _diagnostics(self, now: float) -> list:
        """Joint states published against joint_rate (none while it waits for subscribers), touches played."""
        rate = self._joint_rate.rate(self.published, now)
        return [rate_check("joint states", rate if self.published else None, 1.0 / self.joint_period),
                Check(values=(("played", f"{self.played} of {self.total}"),
                             ("done", "yes" if self.done else "stopped" if self.stopped else "no")))]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        if not self._thread.is_alive():   # its last status (stopped, or done) reaches the subscribers
            try:
                self.status_pub.wait_for_all_acked(Duration(seconds=1.0))
            except RCLError:              # the middleware cannot tell: as without the wait
                pass


def main(args=None) -> int:
    return run_node(SimRobot, args, interruptible_start=True)   # simulating takes seconds and writes nothing


if __name__ == "__main__":
    raise SystemExit(main())
