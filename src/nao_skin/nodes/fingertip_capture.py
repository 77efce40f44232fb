"""fingertip_capture: the robot presses its own fingertip on the torso, target after target, through NAOqi.

A thin adapter of :mod:`nao_skin.capture`: it connects to ALMotion over libqi (``tcp://<nao_ip>:<nao_port>``)
and hands the loop that proxy as its ``Motion`` (every call with ``naoqi_timeout``), the skin's
``/skin/<part>/taxels`` as its contacts and the age of ``/joint_states`` to its gate; the loop runs in a
thread of its own. Each planned approach is a marker on ``nao_skin/capture/markers`` (latched; ``dry_run``:
only those, nothing moves). ``~/stop`` (std_srvs/Trigger), Ctrl-C, a lost NAOqi, stale joint states and
late skin readings stop the capture: the arm retracts, goes to rest, and only then loses its stiffness. Every
abort is one log line and the diagnostics' status; ``nao_skin/capture/status`` (std_msgs/String JSON) says how far it got.
"""
from __future__ import annotations

import json
import threading
import time
from collections import deque

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import JointState, PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

from nao_skin.capture.loop import CaptureLoop
from nao_skin.capture.plan import Planner, TargetChooser
from nao_skin.capture.safety import STALE_HOLD, Abort, SafetyGate
from nao_skin.errors import NaoSkinError, one_line
from nao_skin.formats.pointcloud import JOINT_STATES_TOPIC, read_taxels, taxels_topic
from nao_skin.live.diagnostics import ERROR, OK, WARN, Check
from nao_skin.nodes.diagnostics import publish_diagnostics
from nao_skin.nodes.messages import header_stamp
from nao_skin.nodes.runtime import declare, run_node
from nao_skin.nodes.topics import LATCHED, STREAM_DEPTH, frame_prefix, relative
from nao_skin.session.params import FINGERTIP_CAPTURE, capture_setup

MARKERS_TOPIC = "nao_skin/capture/markers"
STATUS_TOPIC = "nao_skin/capture/status"
READINGS_KEPT = 500       # skin readings kept for the loop's questions (10 s of a part at 50 Hz)
JOINTS_WAIT = 10.0        # s the capture waits for the first joint states before it gives up
CLOSE_WAIT = 60.0         # s Ctrl-C waits for the arm to retract and reach its rest pose


class NaoqiMotion:
    """ALMotion over libqi, each call bounded by ``timeout`` (a robot gone mid-call raises, never hangs)."""

    def __init__(self, url: str, timeout: float):
        import qi

        self.session = qi.Session()
        self.session.connect(url)
        self.proxy = self.session.service("ALMotion")
        self.timeout_ms = max(1, int(timeout * 1000))

    def _call(self, name: str, *args):
        future = getattr(self.proxy, name)(*args, _async=True)
        try:
            return future.value(self.timeout_ms)
        except RuntimeError:
            if not future.isFinished():
                raise RuntimeError(f"no answer from ALMotion.{name} in {self.timeout_ms / 1000:g} s") from None
            raise

    def setStiffnesses(self, names, stiffnesses):  # noqa: N802 - NAOqi's names
        return self._call("setStiffnesses", list(names), float(stiffnesses))

    def angleInterpolationWithSpeed(self, names, angles, fraction):  # noqa: N802
        return self._call("angleInterpolationWithSpeed", list(names), [float(a) for a in angles], float(fraction))

    def getAngles(self, names, useSensors):  # noqa: N802
        return self._call("getAngles", list(names), bool(useSensors))

    def killTasksUsingResources(self, names):  # noqa: N802
        return self._call("killTasksUsingResources", list(names))

    def connected(self) -> bool:
        return bool(self.session.isConnected())

    def close(self) -> None:
        try:
            self.session.close()
        except Exception:  # noqa: BLE001 - a broken session may fail to close too; nothing to save
            pass


class WallClock:
    @staticmethod
    def now() -> float:
        return time.monotonic()

    @staticmethod
    def sleep(seconds: float) -> None:
        time.sleep(max(seconds, 0.0))


class SkinReadings:
    """The skin messages as the loop asks for them: which parts fired after a moment, their slots, the highest
    pressure (thread-safe: the executor writes, the capture thread reads).

    A reading counts from when it was taken, not from when its message came: its stamp, placed on this
    process's monotonic clock by the least ``receipt - stamp`` seen so far (the transport's shortest delay and
    whatever offset the stamping clock has). :meth:`fired` first waits until the ``target`` part has a reading
    taken at or after the moment of the call, at most ``late_after`` s (the node's: ``stale_after`` plus the
    arm's hold, :data:`~nao_skin.capture.safety.STALE_HOLD`; beyond it the skin is late: an
    :class:`~nao_skin.capture.safety.Abort` of the session), or until ``stopping`` is set. On a loaded machine
    the skin's messages come a few steps of the approach late; read by their receipt, the press went on 4.5 mm
    past the first contact (the capture's end-to-end test on a loaded machine, 2026-12-08), where the options
    allow 1.9. The other parts are read as far as they came: a contact there aborts the touch a step later."""

    def __init__(self, target: str, late_after: float, stopping: threading.Event):
        self.target, self.late_after, self.stopping = target, float(late_after), stopping
        self._lock = threading.Condition()
        self._kept: deque = deque(maxlen=READINGS_KEPT)
        self._offset = np.inf          # least receipt - stamp (s)
        self._newest = -np.inf         # when the target's newest reading was taken (monotonic s)

    def add(self, part: str, stamp: float, slots: np.ndarray, pressures: np.ndarray) -> None:
        received = time.monotonic()
        with self._lock:
            self._offset = min(self._offset, received - stamp)
            taken = stamp + self._offset
            self._kept.append((taken, part, slots, pressures))
            if part == self.target:
                self._newest = max(self._newest, taken)
            self._lock.notify_all()

    def wake(self) -> None:
        """A stop was requested: a wait in :meth:`fired` ends now."""
        with self._lock:
            self._lock.notify_all()

    def fired(self, since: float) -> dict:
        until = time.monotonic()
        with self._lock:
            fresh = self._lock.wait_for(lambda: self._newest >= until or self.stopping.is_set(),
                                        timeout=self.late_after)
            if self.stopping.is_set():
                raise Abort("stop requested", session=True)
            if not fresh:
                raise Abort(f"skin readings late: none of {self.target} taken in the {self.late_after:g} s since"
                            f" the arm stopped (stale after {self.late_after:g} s)", session=True)
            kept = [r for r in self._kept if r[0] > since and len(r[2])]
        out = {}
        for _, part, slots, pressures in kept:
            had = out.get(part, (np.zeros(0, int), 0.0))
            peak = float(np.nanmax(pressures)) if np.isfinite(pressures).any() else 0.0
            out[part] = (np.union1d(had[0], slots), max(had[1], peak))
        return out


class FingertipCapture(Node):
    def __init__(self, **kwargs):
        super().__init__("fingertip_capture", **kwargs)
        p = declare(self, FINGERTIP_CAPTURE)
        self.skin, calibration, tips, self.part, options = capture_setup(p)
        self.planners = [Planner(self.skin, calibration, tip, self.part, options) for tip in tips]
        self.chooser = TargetChooser(self.planners[0].points, self.planners[0].slots, arms=len(self.planners))
        self.url = f"tcp://{p['nao_ip']}:{int(p['nao_port'])}"
        self.timeout = float(p["naoqi_timeout"])
        self.dry_run, self.max_touches = bool(p["dry_run"]), int(p["max_touches"])
        self.frames = frame_prefix(self)
        self._joints_at: float | None = None
        self._stop = threading.Event()
        self.readings = SkinReadings(self.part, options.stale_after + STALE_HOLD, self._stop)
        self.motion: NaoqiMotion | None = None
        self.aborts: list = []             # (monotonic time, line)
        self.state = "starting"
        for part in self.skin.parts:
            self.create_subscription(PointCloud2, relative(taxels_topic(part)),
                                     lambda msg, part=part: self._on_taxels(part, msg), STREAM_DEPTH)
        self.create_subscription(JointState, relative(JOINT_STATES_TOPIC), self._on_joints, STREAM_DEPTH)
        self.markers_pub = self.create_publisher(MarkerArray, MARKERS_TOPIC, LATCHED)
        self.status_pub = self.create_publisher(String, STATUS_TOPIC, 10)
        self.markers: list = []
        self.create_service(Trigger, "~/stop", self._on_stop)
        self.create_timer(0.5, self._publish_status)
        publish_diagnostics(self, self._diagnostics, hardware_id=f"NAOqi {self.url}")
        self.gate = SafetyGate(options.stale_after, self._stop.is_set, self._joint_age, lost=self._lost,
                               sleep=WallClock.sleep)
        self.loop = CaptureLoop(self.planners, self.chooser, None, self.readings, self.gate, WallClock(),
                                log=self.get_logger().warning, on_abort=self._on_abort,
                                on_plan=self._on_plan)
        self._thread = threading.Thread(target=self._run, name="capture", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ inputs
    def _on_taxels(self, part: str, msg: PointCloud2) -> None:
        try:
            slots, pressures, _ = read_taxels(msg, self.skin.parts[part], f"{taxels_topic(part)}")
            stamp = header_stamp(msg, taxels_topic(part))
        except NaoSkinError:
            return          # the recorder says what is wrong with a skin message; here it fires nothing
        self.readings.add(part, stamp, slots, pressures)

    def _on_joints(self, msg: JointState) -> None:
        self._joints_at = time.monotonic()

    def _joint_age(self) -> float | None:
        return None if self._joints_at is None else time.monotonic() - self._joints_at

    def _lost(self) -> str | None:
        motion = self.motion
        return None if motion is None or motion.connected() else f"the session to {self.url} closed"

    def _on_stop(self, request, response):
        self.stop("stop requested (~/stop)")
        response.success = True
        response.message = "stopping: the arm retracts and goes to rest"
        return response

    def stop(self, why: str) -> None:
        if not self._stop.is_set():
            self.get_logger().info(why)
        self._stop.set()
        self.readings.wake()
        motion = self.motion
        if motion is not None:      # a move in progress ends where it is; the loop then retracts
            try:
                motion.killTasksUsingResources([n for p in self.planners for n in p.arm.names])
            except Exception as exc:  # noqa: BLE001 - NAOqi gone: the loop finds out and says so
                self.get_logger().warning(f"cannot stop the move: {one_line(exc)}")

    # ------------------------------------------------------------------ the capture
    def _run(self) -> None:
        if self.dry_run:
            self.state = "dry run"
            plans = self.loop.plan_only(self.max_touches)
            self.state = f"dry run: {len(plans)} approaches planned"
            self.get_logger().info(f"{self.state} (nao_skin/capture/markers); nothing moved")
            return
        try:
            self.motion = NaoqiMotion(self.url, self.timeout)
        except Exception as exc:  # noqa: BLE001 - libqi raises RuntimeError and others
            return self._on_abort(f"capture stopped: cannot connect to NAOqi at {self.url} ({one_line(exc)})")
        self.loop.motion = self.motion
        deadline = time.monotonic() + JOINTS_WAIT
        while self._joints_at is None and time.monotonic() < deadline and not self._stop.is_set():
            time.sleep(0.05)
        self.state = "capturing"
        self.get_logger().info(f"capturing {self.part} with the fingertips of"
                               f" {', '.join(p.arm.chain for p in self.planners)} through NAOqi at {self.url}")
        self.loop.run(self.max_touches)
        self.state = "stopped" if self.loop.stopped else "done"
        done = sum(r.outcome == "touched" for r in self.loop.results)
        self.get_logger().info(f"capture {self.state}: {done} touches; arm {self.loop.state}")

    def _on_abort(self, line: str) -> None:
        self.aborts.append((time.monotonic(), line))
        if line.startswith("capture stopped: cannot connect"):
            self.get_logger().error(line)
            self.state = "stopped"

    def _on_plan(self, plan) -> None:
        ends = self.loop.planner.fingertip(plan.path[[0, -1]])
        frame = self.frames + self.skin.robot.base_frame
        k = len(self.markers)
        arrow = Marker(ns="approach", id=k, type=Marker.ARROW, action=Marker.ADD)
        target = Marker(ns="target", id=k, type=Marker.SPHERE, action=Marker.ADD)
        for m in (arrow, target):
            m.header.frame_id = frame
            m.pose.orientation.w = 1.0
            m.color.a = 1.0
        from geometry_msgs.msg import Point

        arrow.points = [Point(x=float(a), y=float(b), z=float(c)) for a, b, c in ends]
        arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.002, 0.004, 0.004
        arrow.color.g = 1.0
        target.pose.position = Point(x=float(plan.point[0]), y=float(plan.point[1]), z=float(plan.point[2]))
        target.scale.x = target.scale.y = target.scale.z = 0.005
        target.color.r = 1.0
        self.markers += [arrow, target]
        self.markers_pub.publish(MarkerArray(markers=list(self.markers)))

    # ------------------------------------------------------------------ outputs
    def _status(self) -> dict:
        outcomes = [r.outcome for r in self.loop.results]
        return {"state": self.state, "arm": self.loop.state, "touched": outcomes.count("touched"),
                "unreachable": outcomes.count("unreachable"), "aborted": outcomes.count("aborted"),
                "taxels_fired": int(np.count_nonzero(self.chooser.fired)),
                "reachable_unreached": self.chooser.reachable_unreached(), "stopped": self.loop.stopped}

    def _publish_status(self) -> None:
        self.status_pub.publish(String(data=json.dumps(self._status())))

    def _diagnostics(self, now: float) -> list:
        """ERROR once the capture stopped for anything but a requested stop; WARN for 10 s after an aborted
        touch; each with its one line."""
        status = self._status()
        values = tuple((k, str(v)) for k, v in status.items())
        last = self.aborts[-1][1] if self.aborts else ""
        if status["state"] == "stopped" and not (self.loop.stopped or "").startswith("stop requested"):
            return [Check(ERROR, last or "capture stopped", values)]
        if self.aborts and now - self.aborts[-1][0] < 10.0:
            return [Check(WARN, last, values)]
        return [Check(OK, "", values)]

    def close(self) -> None:
        """Ctrl-C: stop, let the loop retract and lower the arm (it needs NAOqi only, not the executor)."""
        self.stop("stopping at Ctrl-C" + ("" if self.dry_run else ": the arm retracts and goes to rest"))
        self._thread.join(timeout=CLOSE_WAIT)
        if self._thread.is_alive():
            self.get_logger().error(f"the arm did not reach its rest pose in {CLOSE_WAIT:g} s; stiffness kept")
        self._publish_status()
        if self.motion is not None:
            self.motion.close()


def main(args=None) -> int:
    return run_node(FingertipCapture, args)


if __name__ == "__main__":
    raise SystemExit(main())
