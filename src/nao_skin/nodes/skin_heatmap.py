"""skin_heatmap: live coverage heat-map of the skin for RViz (visualization_msgs/MarkerArray).

Every taxel of every part is a sphere, coloured by how often it has been
activated in this session and, when it continues earlier sittings
(``earlier_recordings``), in their touches (:mod:`nao_skin.live.heatmap`: grey = never, then a
viridis-like log scale), currently pressed taxels red. One SPHERE_LIST marker
per triangle, in the triangle's own frame (``<part>_skin_triangle_<t>``,
namespace = part, id = triangle number, points in slot order), so the
positions follow the current calibration through TF without this node
knowing it. A colour-bar legend (namespace ``legend``) sits next to the torso. Each fingertip of the session's
``fingertip_scenes`` is an orange sphere (namespace ``fingertip``): its contact sphere, the calibration's
(``calibration``, else the robot config's), in its arm's end frame, so TF moves it with the joint states and
it shows where the fingertip presses.
Published at ``rate`` Hz (default 10).

Guided capture on ``/nao_skin/guidance/markers`` (MarkerArray, latched,
republished when the guidance or a part's state changes): each target
triangle of ``/nao_skin/guidance`` outlined in magenta in its own frame
(namespace ``guidance``, id = rank) with a label (rank, part, triangle, the
pair to press with, why); and per part its live calibration state from
``/nao_skin/calibration/status`` (collecting / converging / done) as a text
over its mount (namespace ``state``).
"""
from __future__ import annotations

import json
import time

import numpy as np
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import ColorRGBA, String
from visualization_msgs.msg import Marker, MarkerArray

from nao_skin.errors import DataError
from nao_skin.formats.inputs import load_touches
from nao_skin.formats.pointcloud import read_taxels, taxels_topic
from nao_skin.guidance.capture import targets_from_json
from nao_skin.live.diagnostics import RateWindow, count_check, rate_check
from nao_skin.live.heatmap import (FINGERTIP_COLOUR, GUIDANCE_COLOUR, SCALE_LEVELS, ActivationCounts,
                                   fingertip_spheres, palette, triangle_outline, triangle_slots)
from nao_skin.nodes.diagnostics import publish_diagnostics
from nao_skin.nodes.runtime import declare, run_node
from nao_skin.nodes.topics import (GUIDANCE_MARKERS_TOPIC, GUIDANCE_TOPIC, HEATMAP_TOPIC, LATCHED, MAX_SKIPPED_SAID,
                                   STATUS_TOPIC, STREAM_DEPTH, frame_prefix, relative)
from nao_skin.model.skin import SkinCalibration
from nao_skin.session.params import SKIN_HEATMAP, fingertip_scenes, skin_from_params
from nao_skin.touch.datasets import deduplicate

STATE_COLOURS = {"collecting": (0.6, 0.6, 0.6, 1.0), "converging": (1.0, 0.8, 0.2, 1.0), "done": (0.2, 1.0, 0.4, 1.0)}
UNREACHED_ALPHA = 0.35   # a guidance target no pose reaches, drawn faint
LEGEND_NS = "legend"
LEGEND_HEIGHT = 0.12      # m: height of the colour bar

class SkinHeatmap(Node):
    def __init__(self, **kwargs):
        super().__init__("skin_heatmap", **kwargs)
        p = declare(self, SKIN_HEATMAP)
        self.skin = skin_from_params(p)
        self.counts = ActivationCounts({n: part.n_slots for n, part in self.skin.parts.items()})
        earlier = [path for path in p["earlier_recordings"] if path]
        if earlier:     # the capture's coverage so far, not this sitting's alone; a bad bag: one line, exit 2
            # as the calibration counts them: a touch recorded twice (an exact duplicate) is one press
            self.counts.add_touches(deduplicate(load_touches(earlier, self.skin, log=self.get_logger().debug)[0])[0])
        self.palette = [ColorRGBA(r=float(c[0]), g=float(c[1]), b=float(c[2]), a=float(c[3])) for c in palette()]
        d = float(p["taxel_diameter"])
        # Everything but the colours is fixed: build markers once, recolour them per update.
        self.markers = []          # (part, slots, marker)
        self.frames = frame_prefix(self)
        for name, part in self.skin.parts.items():
            for tid, slots in triangle_slots(part):
                m = Marker()
                m.header.frame_id = self.frames + part.triangle_frame(tid)
                m.ns, m.id, m.type, m.action = name, tid, Marker.SPHERE_LIST, Marker.ADD
                m.pose.orientation.w = 1.0
                m.scale.x = m.scale.y = m.scale.z = d
                m.frame_locked = True
                m.lifetime = Duration()
                m.points = [Point(x=float(v[0]), y=float(v[1]), z=float(v[2])) for v in part.taxel_local[slots]]
                self.markers.append((name, slots, m))
        self.legend = self._legend(np.asarray(p["legend_origin"], float), d)
        calibration = SkinCalibration.load(p["calibration"], self.skin) if p["calibration"] else None
        self.fingertips = [self._fingertip(i, tip, frame, centre, radius) for i, (tip, frame, centre, radius)
                           in enumerate(fingertip_spheres(self.skin, fingertip_scenes(p, self.skin), calibration))]
        self.publisher = self.create_publisher(MarkerArray, HEATMAP_TOPIC, 10)
        for n in self.skin.parts:
            self.create_subscription(PointCloud2, relative(taxels_topic(n)), lambda m, n=n: self._on_taxels(n, m),
                                     STREAM_DEPTH)
        self.errors = 0                   # skin samples skipped
        self.status_errors = 0            # status messages skipped
        self.published = 0
        self.create_timer(1.0 / float(p["rate"]), self._publish)
        self.rate = float(p["rate"])
        self.received = 0                 # skin samples read
        self._rates = (RateWindow(), RateWindow())
        publish_diagnostics(self, self._diagnostics)
        self.guidance_pub = self.create_publisher(MarkerArray, GUIDANCE_MARKERS_TOPIC, LATCHED)
        self.targets: list = []             # the guidance's targets, best first
        self.states: dict = {}              # part -> live calibration state
        self.create_subscription(String, GUIDANCE_TOPIC, self._on_guidance, LATCHED)
        self.create_subscription(String, STATUS_TOPIC, self._on_status, LATCHED)

    def _on_taxels(self, part: str, msg) -> None:
        try:
            slots, _, _ = read_taxels(msg, self.skin.parts[part], taxels_topic(part))
        except DataError as exc:
            self.errors += 1
            if self.errors <= MAX_SKIPPED_SAID:
                self.get_logger().warning(f"skipped: {exc}")
            return
        self.counts.update(part, slots, time.monotonic())
        self.received += 1

    def _on_guidance(self, msg: String) -> None:
        try:
            self.targets, skipped = targets_from_json(msg.data, self.skin)
        except DataError as exc:
            self.get_logger().warning(f"skipped a guidance message: {exc}")
            return
        if skipped:
            self.get_logger().warning(f"guidance: skipped {skipped} targets that are not this skin's triangles")
        self._publish_guidance()

    def _on_status(self, msg: String) -> None:
        try:
            status = json.loads(msg.data)
        except (ValueError, TypeError, RecursionError):
            status = None
        if isinstance(status, dict) and "parts" not in status:
            return                        # a status of no live update (a calibration published): no states
        states = status.get("parts") if isinstance(status, dict) else None
        if not isinstance(states, dict):
            self.status_errors += 1
            if self.status_errors <= MAX_SKIPPED_SAID:
                self.get_logger().warning(f"skipped a malformed {STATUS_TOPIC} message ({msg.data[:80]!r}: expected"
                                          f" JSON with a 'parts' mapping)")
            return
        states = {k: v for k, v in states.items() if k in self.skin.parts and isinstance(v, str)}
        if states != self.states:
            self.states = states
            self._publish_guidance()

    def _publish_guidance(self) -> None:
        """Targets outlined with their labels, and each part's state: one latched MarkerArray, replacing the last."""
        stamp = self.get_clock().now().to_msg()
        clear = Marker()
        clear.action = Marker.DELETEALL
        markers = [clear]
        colour = ColorRGBA(r=GUIDANCE_COLOUR[0], g=GUIDANCE_COLOUR[1], b=GUIDANCE_COLOUR[2], a=GUIDANCE_COLOUR[3])
        # a target no pose reaches under the current calibration: faint, and its label says so
        faint = ColorRGBA(r=GUIDANCE_COLOUR[0], g=GUIDANCE_COLOUR[1], b=GUIDANCE_COLOUR[2], a=UNREACHED_ALPHA)
        for rank, t in enumerate(self.targets, start=1):
            reached = t["pose"] is not None
            part = self.skin.parts[t["part"]]
            frame = part.triangle_frame(int(t["triangle_id"]))
            outline = triangle_outline(part, int(t["triangle_id"]))
            line = self._marker(frame, "guidance", rank, Marker.LINE_STRIP, stamp, colour if reached else faint)
            line.scale.x = 0.0015
            line.points = [Point(x=float(v[0]), y=float(v[1]), z=float(v[2])) for v in outline]
            label = self._marker(frame, "guidance_label", rank, Marker.TEXT_VIEW_FACING, stamp,
                                 colour if reached else faint)
            label.pose.position.z = 0.012
            label.scale.z = 0.008
            other = t["touched"] if t["part"] == t["hand"] else t["hand"]
            why = t.get("reason", "") + ("" if reached else "; no pose reaches it")
            label.text = f"{rank}: {t['part']} triangle {t['triangle_id']} with {other} ({why})"
            markers += [line, label]
        for i, (name, state) in enumerate(sorted(self.states.items())):
            part = self.skin.parts[name]
            c = STATE_COLOURS.get(state, (1.0, 1.0, 1.0, 1.0))
            text = self._marker(part.mount_frame, "state", i, Marker.TEXT_VIEW_FACING, stamp,
                                ColorRGBA(r=c[0], g=c[1], b=c[2], a=c[3]))
            text.pose.position.z = 0.03
            text.scale.z = 0.012
            text.text = f"{name}: {state}"
            markers.append(text)
        self.guidance_pub.publish(MarkerArray(markers=markers))

    def _marker(self, frame: str, ns: str, mid: int, kind: int, stamp, colour: ColorRGBA) -> Marker:
        m = Marker()
        m.header.frame_id = self.frames + frame
        if stamp is not None:
            m.header.stamp = stamp
        m.ns, m.id, m.type, m.action = ns, mid, kind, Marker.ADD
        m.pose.orientation.w = 1.0
        m.scale.x = m.scale.y = m.scale.z = 0.01
        m.color = colour
        m.frame_locked = True
        return m

    def _fingertip(self, mid: int, name: str, frame: str, centre: np.ndarray, radius: float) -> Marker:
        """A fingertip's contact sphere in its arm's end frame (TF moves it with the arm)."""
        c = FINGERTIP_COLOUR
        m = self._marker(frame, "fingertip", mid, Marker.SPHERE, None, ColorRGBA(r=c[0], g=c[1], b=c[2], a=c[3]))
        m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(v) for v in centre)
        m.scale.x = m.scale.y = m.scale.z = 2.0 * radius
        m.text = name
        return m

    def _legend(self, origin: np.ndarray, d: float) -> list:
        base = self.frames + self.skin.robot.base_frame
        bar = Marker()
        bar.header.frame_id = base
        bar.ns, bar.id, bar.type, bar.action = LEGEND_NS, 0, Marker.CUBE_LIST, Marker.ADD
        bar.pose.orientation.w = 1.0
        step = LEGEND_HEIGHT / SCALE_LEVELS          # one cube per colour level, stacked upwards
        bar.scale.x = bar.scale.y = 2 * d
        bar.scale.z = step
        bar.points = [Point(x=float(origin[0]), y=float(origin[1]), z=float(origin[2] + i * step))
                      for i in range(SCALE_LEVELS)]
        bar.colors = self.palette[:SCALE_LEVELS]
        texts = []
        for i, z in enumerate((origin[2] - 2 * d, origin[2] + SCALE_LEVELS * step + 2 * d)):
            t = Marker()
            t.header.frame_id = base
            t.ns, t.id, t.type, t.action = LEGEND_NS, 1 + i, Marker.TEXT_VIEW_FACING, Marker.ADD
            t.pose.position.x, t.pose.position.y, t.pose.position.z = float(origin[0]), float(origin[1]), float(z)
            t.pose.orientation.w = 1.0
            t.scale.z = 3 * d
            t.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
            texts.append(t)
        return [bar] + texts

    def _publish(self) -> None:
        stamp = self.get_clock().now().to_msg()
        self.counts.release_silent(time.monotonic())
        colours = {n: self.counts.colour_indices(n) for n in self.skin.parts}
        get = self.palette.__getitem__
        for name, slots, m in self.markers:
            m.header.stamp = stamp
            # palette objects shared by every taxel of a colour: map() in C, no message built per taxel
            m.colors = list(map(get, colours[name][slots].tolist()))
        self.legend[1].text = "0 activations (grey: never)"
        self.legend[2].text = f"{self.counts.max_count()} activations (red: pressed now)"
        for m in self.legend + self.fingertips:
            m.header.stamp = stamp
        self.publisher.publish(MarkerArray(markers=[m for _, _, m in self.markers] + self.legend + self.fingertips))
        self.published += 1


    def _diagnostics(self, now: float) -> list:
        """Marker updates against ``rate``, skin samples read, messages skipped."""
        return [rate_check("marker updates", self._rates[0].rate(self.published, now), self.rate),
                rate_check("skin samples", self._rates[1].rate(self.received, now), 0.0),
                count_check("skipped messages", self.errors + self.status_errors)]


def main(args=None) -> int:
    return run_node(SkinHeatmap, args)


if __name__ == "__main__":
    raise SystemExit(main())
