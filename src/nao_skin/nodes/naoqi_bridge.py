"""naoqi_bridge: the robot's head and arm joint angles from NAOqi on ``/joint_states``.

Connects with libqi to ``tcp://<nao_ip>:<nao_port>``, calls ALMotion
``getAngles(names, True)`` (sensed angles) at ``rate`` Hz in its own thread
(a slow or dead robot never blocks the ROS executor) and publishes each read
as one JointState stamped when it was read. When the robot disappears the
bridge publishes nothing (never the last angles again), reconnects with
back-off and logs once per outage. Leave it out when another driver (e.g.
naoqi_driver2) already publishes ``/joint_states``.
"""
from __future__ import annotations

import threading
import time

from rclpy.node import Node
from sensor_msgs.msg import JointState

from nao_skin.errors import one_line
from nao_skin.formats.pointcloud import JOINT_STATES_TOPIC
from nao_skin.live.diagnostics import ERROR, Check, RateWindow, count_check, rate_check
from nao_skin.live.reconnect import Backoff
from nao_skin.model.robot import MAX_JOINT_LIMIT
from nao_skin.nodes.messages import joint_state_msg
from nao_skin.nodes.diagnostics import publish_diagnostics
from nao_skin.nodes.runtime import declare, run_node
from nao_skin.nodes.topics import STREAM_DEPTH, relative
from nao_skin.rules import finite_float
from nao_skin.session.params import NAOQI_BRIDGE, changeable_params, check_naoqi_bridge


class ReadTimeout(Exception):
    """getAngles did not answer in time (a hung robot or network): the link counts as gone."""


class MotionLink:
    """A libqi session to ALMotion; the caller closes it when the link is gone and reconnects."""

    def __init__(self, url: str):
        self.url = url
        self.session = None
        self.motion = None

    def connect(self) -> None:
        import qi

        session = qi.Session()
        session.connect(self.url)
        self.motion = session.service("ALMotion")
        self.session = session

    def close(self) -> None:
        session, self.session, self.motion = self.session, None, None
        if session is not None:
            try:
                session.close()
            except Exception:  # noqa: BLE001 - closing a broken session may fail too; nothing to save
                pass

    def connected(self) -> bool:
        session = self.session
        return session is not None and bool(session.isConnected())

    def read(self, names, use_sensors: bool, timeout: float):
        """ALMotion's reply as it is (the caller judges it); ReadTimeout after ``timeout`` s without one."""
        future = self.motion.getAngles(list(names), bool(use_sensors), _async=True)
        try:
            return future.value(max(1, int(timeout * 1000)))
        except RuntimeError:
            if not future.isFinished():
                raise ReadTimeout(f"no answer from ALMotion.getAngles in {timeout:g} s") from None
            raise


class NaoqiBridge(Node):
    def __init__(self, **kwargs):
        super().__init__("naoqi_bridge", **kwargs)
        p = declare(self, NAOQI_BRIDGE, changeable=lambda values: changeable_params("naoqi_bridge", values),
                    on_change=self._on_params)
        self.names = list(p["joint_names"])
        self.use_sensors = bool(p["use_sensors"])
        self.period = 1.0 / float(p["rate"])
        self.url = f"tcp://{p['nao_ip']}:{int(p['nao_port'])}"
        self.link = MotionLink(self.url)
        check_naoqi_bridge(p)
        self.backoff = Backoff(f"NAOqi at {self.url}", p["reconnect_min"], p["reconnect_max"])
        self.publisher = self.create_publisher(JointState, relative(JOINT_STATES_TOPIC), STREAM_DEPTH)
        self.read_timeout = float(p["read_timeout"])
        self.stats = {"published": 0, "bad_reads": 0, "outages": 0}
        self._logged_reasons: set = set()
        self._answered = False      # since the last connection
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="naoqi_poll", daemon=True)
        self._thread.start()
        self._rate = RateWindow()
        publish_diagnostics(self, self._diagnostics, hardware_id=f"NAOqi {self.url}")

    def _on_params(self, changed: dict) -> None:
        """``rate``, ``use_sensors`` and ``read_timeout`` set while it runs: the poll thread's next read takes them."""
        if "rate" in changed:
            self.period = 1.0 / float(changed["rate"])
        if "use_sensors" in changed:
            self.use_sensors = bool(changed["use_sensors"])
        if "read_timeout" in changed:
            self.read_timeout = float(changed["read_timeout"])
        self.get_logger().info("applied " + ", ".join(f"{k}:={v!r}" for k, v in sorted(changed.items())))

    def _diagnostics(self, now: float) -> list:
        """Joint states published against ``rate`` while NAOqi answers; ERROR while it does not."""
        rate = self._rate.rate(self.stats["published"], now)
        checks = [count_check("bad reads", self.stats["bad_reads"]),
                  Check(values=(("outages", str(self.stats["outages"])),))]
        if not self._answered:
            return [Check(ERROR, f"no answer from NAOqi at {self.url} (reconnecting)"), *checks]
        return [rate_check("joint states", rate, 1.0 / self.period), *checks]

    def _loop(self) -> None:
        next_tick = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if self.link.motion is None:
                if self.backoff.due(now):
                    self._try_connect(now)
                self._stop.wait(0.05 if self.link.motion is None else 0.0)
                next_tick = time.monotonic()
                continue
            self._read_once()
            next_tick += self.period
            delay = next_tick - time.monotonic()
            if delay < -self.period:           # fell behind (slow robot): do not burst to catch up
                next_tick = time.monotonic()
            elif delay > 0:
                self._stop.wait(delay)

    def _try_connect(self, now: float) -> None:
        try:
            self.link.connect()
        except Exception as exc:  # noqa: BLE001 - libqi raises RuntimeError and others; all mean "not now"
            self.link.close()
            line = self.backoff.failed(now, f"cannot connect ({one_line(exc)})")
            if line:
                self.get_logger().warning(line)
            return
        # the outage ends with the first answer, not the connection: a robot that accepts the session but
        # never answers (hung) is one outage, not one per reconnection
        self._answered = False

    def _confirm(self) -> None:
        """The robot answered a read: the link works (logs "connected" or the recovery once)."""
        if not self._answered:
            self._answered = True
            line = self.backoff.succeeded(time.monotonic())
            if line:
                self.get_logger().info(line)

    def _read_once(self) -> None:
        try:
            values = self.link.read(self.names, self.use_sensors, self.read_timeout)
        except Exception as exc:  # noqa: BLE001 - libqi raises RuntimeError and others
            # a robot that answers with an error (a joint name it does not know) is there: a bad read,
            # not an outage to reconnect from at every tick
            if not isinstance(exc, ReadTimeout) and self.link.connected():
                self._confirm()
                return self._bad_read("failed", f"ALMotion.getAngles failed ({one_line(exc)})")
            self.link.close()
            self.stats["outages"] += 1
            line = self.backoff.failed(time.monotonic(), f"lost ({one_line(exc)})")
            if line:
                self.get_logger().warning(line)
            return
        self._confirm()
        # Stamp when the angles were read, not when they are published.
        stamp = self.get_clock().now().to_msg()
        problem = self._reply_problem(values)
        if problem:
            return self._bad_read(problem[0], f"ALMotion.getAngles returned {problem[1]}")
        self.publisher.publish(joint_state_msg(self.names, list(values), stamp))
        self.stats["published"] += 1

    def _reply_problem(self, values) -> tuple | None:
        """``(kind, what)`` is wrong with a getAngles reply for ``self.names``, or None."""
        if not isinstance(values, (list, tuple)):
            return "type", f"{type(values).__name__}, not a list of {len(self.names)} angles"
        if len(values) != len(self.names):
            return "length", f"{len(values)} values for {len(self.names)} joints"
        for name, v in zip(self.names, values):
            angle = finite_float(v)
            if angle is None or abs(angle) > MAX_JOINT_LIMIT:
                return "angle", f"{v!r} for {name}, not a joint angle (finite, within two turns)"
        return None

    def _bad_read(self, kind: str, reason: str) -> None:
        """A read that gives no angles: counted, and the first of each kind logged."""
        self.stats["bad_reads"] += 1
        if kind not in self._logged_reasons:
            self._logged_reasons.add(kind)
            self.get_logger().warning(f"{reason}; such reads are skipped (joints {', '.join(self.names)})")

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.link.close()


def main(args=None) -> int:
    return run_node(NaoqiBridge, args)


if __name__ == "__main__":
    raise SystemExit(main())
