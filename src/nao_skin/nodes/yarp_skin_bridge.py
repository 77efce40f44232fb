"""yarp_skin_bridge: skinManager's YARP output as ROS skin messages, per skin part.

Opens local YARP ports, connects them to skinManager's skin events port
(skinContactList bottles) and, optionally per part, to a compensated taxel
port (one value per taxel). Publishes per part, stamped with the YARP
envelope time (the receive time when a writer sends no envelope, or with
``stamp:=receive`` when skinManager's host keeps another clock than the one
stamping ``/joint_states``: the recorder warns when they differ):

* ``/skin/<part>/contacts``: the part's contacts of every contact list (empty
  when the part has none: "released");
* ``/skin/<part>/taxels``: the taxels of those contacts, or, when the part has
  a compensated port configured, the taxels above ``compensated_threshold``
  on that port (contact -1: the pipeline clusters them).

skinManager's numeric skin part ids map to our part names by configuration
(``part_ids.<part>``): iCub and the Nao build of skinDynLib differ. A
malformed bottle (its envelope time too) is counted, logged (first few) and
skipped; the bridge goes on with the next. Vanished ports are reconnected
every ``reconnect_period`` s, logged once per outage; a name server that
forgot the bridge's own port (restarted) gets it registered again.
Counters go to ``/skin/bridge_status`` (std_msgs/String, JSON) every second.
"""
from __future__ import annotations

import json
import os
import threading
import time
from collections import Counter

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String

from nao_skin.errors import ConfigError, DataError, one_line
from nao_skin.formats.pointcloud import contacts_array, contacts_topic, taxels_array, taxels_topic
from nao_skin.formats.skinmanager import activated_taxels, parse_skin_events, parts_by_id
from nao_skin.live.diagnostics import ERROR, OK, Check, count_check
from nao_skin.live.reconnect import Backoff
from nao_skin.nodes.messages import cloud_from_array, stamp_to_msg
from nao_skin.nodes.diagnostics import publish_diagnostics
from nao_skin.nodes.runtime import declare, run_node
from nao_skin.nodes.topics import BRIDGE_STATUS_TOPIC, STREAM_DEPTH, frame_prefix, relative
from nao_skin.session.params import YARP_SKIN_BRIDGE, changeable_params, per_part_params, skin_from_params
from nao_skin.session.record import YARP_HINT

MAX_LOGGED_ERRORS = 5


class YarpSkinBridge(Node):
    def __init__(self, **kwargs):
        super().__init__("yarp_skin_bridge", **kwargs)
        p = declare(self, YARP_SKIN_BRIDGE, changeable=lambda values: changeable_params("yarp_skin_bridge", values),
                    on_change=self._on_params)
        self.skin = skin_from_params(p)
        self._receive_stamps = p["stamp"] == "receive"
        parts = list(self.skin.parts)
        per_part = declare(self, per_part_params("yarp_skin_bridge", parts))
        ids = {key.split(".", 1)[1]: v for key, v in per_part.items() if key.startswith("part_ids.")}
        self.part_of_id = parts_by_id(ids, "parameter part_ids")
        self.comp_port_of = {key.split(".", 1)[1]: v for key, v in per_part.items()
                             if key.startswith("compensated_ports.") and v}
        self.threshold = float(p["compensated_threshold"])
        self.bridged = sorted(set(self.part_of_id.values()) | set(self.comp_port_of), key=parts.index)
        self.taxel_pub = {n: self.create_publisher(PointCloud2, relative(taxels_topic(n)), STREAM_DEPTH)
                          for n in self.bridged}
        self.contact_pub = {n: self.create_publisher(PointCloud2, relative(contacts_topic(n)), STREAM_DEPTH)
                            for n in self.bridged}
        self.status_pub = self.create_publisher(String, BRIDGE_STATUS_TOPIC, 10)
        self.frames = frame_prefix(self)
        self.counts: Counter = Counter()
        self._counts_lock = threading.Lock()    # the reading threads count, the status timer copies
        self._logged_errors = 0
        self._failures_said: set = set()          # kinds of unexpected error already logged
        self._stop = threading.Event()
        self.period = float(p["reconnect_period"])     # the links are checked, and retried, this often
        self._last_bottle: dict = {}                    # local port -> monotonic time of its last bottle

        # YARP's own lines are quiet unless the environment asks for them: without a name server it printed
        # two a second ('No connection to nameserver', 'try running: yarp detect'), 70 lines in a 25 s
        # outage, where this bridge says each outage and recovery once (YARP reads this as it loads)
        os.environ.setdefault("YARP_QUIET", "1")
        try:
            import yarp
        except ImportError as exc:      # started alone (ros2 run): the line record and the launch file give
            raise ConfigError(f"{YARP_HINT} (import yarp: {' '.join(str(exc).split())})") from None
        self.yarp = yarp
        yarp.Network.init()
        self.links = []      # (remote port, local port object, local name, handler, backoff)
        prefix = p["local_prefix"].rstrip("/")
        self._add_link(p["events_port"], f"{prefix}/skin_events:i", self._on_events)
        for part, remote in self.comp_port_of.items():
            self._add_link(remote, f"{prefix}/{part}_comp:i", lambda b, s, part=part: self._on_compensated(part, b, s))
        self._threads = [threading.Thread(target=self._read_loop, args=(link,), daemon=True, name=f"yarp {link[2]}")
                         for link in self.links]
        for t in self._threads:
            t.start()
        self._check_links()
        self.create_timer(float(p["reconnect_period"]), self._check_links)
        self.create_timer(float(p["status_period"]), self._publish_status)
        publish_diagnostics(self, self._diagnostics, hardware_id=f"YARP {p['events_port']}")

    def _on_params(self, changed: dict) -> None:
        """``compensated_threshold`` set while it runs: the next compensated vector is read with it."""
        self.threshold = float(changed["compensated_threshold"])
        self.get_logger().info(f"applied compensated_threshold:={self.threshold:g}")

    def _diagnostics(self, now: float) -> list:  # noqa: ARG002 - the counts are the bridge's own
        """ERROR while a YARP link is down (nothing of it is bridged), WARN for malformed or failed bottles."""
        with self._counts_lock:
            counts = dict(self.counts)
        down = [remote for remote, _, _, _, backoff in self.links if not backoff.connected]
        values = tuple((f"connected {remote}", "no" if remote in down else "yes") for remote, *_ in self.links) \
            + tuple((key, str(n)) for key, n in sorted(counts.items()))
        return [Check(ERROR if down else OK, f"not connected: {', '.join(down)}" if down else "", values),
                count_check("malformed bottles", counts.get("malformed", 0) + counts.get("failed bottles", 0))]

    # ------------------------------------------------------------------ YARP plumbing
    def _add_link(self, remote: str, local: str, handler) -> None:
        port = self.yarp.BufferedPortBottle()
        port.setStrict(True)                       # keep every bottle: a touch is never dropped for being late
        if not port.open(local):
            raise DataError(f"YARP port {local}: cannot open (is yarpserver running and reachable? is another"
                            f" program, a second bridge, using this name? then give this one another local_prefix)")
        self.links.append((remote, port, local, handler, Backoff(f"YARP {remote} -> {local}", self.period,
                                                                 self.period)))

    def _check_links(self) -> None:
        net = self.yarp.Network
        now = time.monotonic()
        log = self.get_logger()
        for remote, port, local, _, backoff in self.links:
            # bottles still arriving are a connection whatever the name server says: a restarted yarpserver
            # knows neither port, and the connection made before goes on
            flowing = now - self._last_bottle.get(local, -np.inf) < 2 * self.period
            if flowing or net.isConnected(remote, local, True):
                if not backoff.connected:
                    log.info(backoff.succeeded(now) or f"YARP {remote} -> {local}: connected")
                continue
            if backoff.connected:                  # it was up: the writer vanished
                self._count("outages")
                log.warning(backoff.failed(now, "connection lost"))
            if not backoff.due(now + 0.5 * self.period):    # due before the next check (the timer jitters)
                continue
            if net.connect(remote, local, "tcp", True) or (self._register_again(port, local)
                                                           and net.connect(remote, local, "tcp", True)):
                log.info(backoff.succeeded(now) or f"YARP {remote} -> {local}: connected")
            else:
                line = backoff.failed(now, "source port not available")
                if line:
                    log.warning(line)

    def _register_again(self, port, local: str) -> bool:
        """Register ``local`` again where the name server lost it (a restarted yarpserver forgets the ports
        opened before: no writer could connect to the bridge again); True when it did."""
        net = self.yarp.Network
        if net.queryName(local).isValid() or not net.registerContact(port.where()).isValid():
            return False
        self._count("registered again")
        self.get_logger().warning(f"YARP {local}: the name server had lost this port (yarpserver restarted?):"
                                  f" registered it again")
        return True

    def _read_loop(self, link) -> None:
        _, port, local, handler, _ = link
        envelope = self.yarp.Stamp()
        while not self._stop.is_set():
            bottle = port.read(True)
            if bottle is None or self._stop.is_set():
                continue
            self._last_bottle[local] = time.monotonic()
            if self._receive_stamps:
                stamp = time.time()
            elif port.getEnvelope(envelope) and envelope.isValid():
                stamp = envelope.getTime()
            else:
                self._count("no envelope")
                stamp = time.time()
            try:
                handler(bottle, stamp_to_msg(stamp, f"envelope time of a bottle on {local}"))
            except DataError as exc:
                self._count(f"malformed {local}")
                self._count("malformed")
                self._say_skipped(str(exc))
            except Exception as exc:     # noqa: BLE001 - one bottle must not end this thread: nothing would be bridged
                self._count("failed bottles")
                kind = type(exc).__name__
                if kind not in self._failures_said:  # each kind said once, whatever malformed bottles said before
                    self._failures_said.add(kind)
                    self.get_logger().error(f"a bottle on {local} failed ({kind}: {one_line(exc)}); skipped, the"
                                            f" bridge goes on (counted as 'failed bottles' in {BRIDGE_STATUS_TOPIC})")

    def _count(self, key: str, n: int = 1) -> int:
        with self._counts_lock:
            self.counts[key] += n
            return self.counts[key]

    def _say_skipped(self, what: str) -> None:
        if self._logged_errors < MAX_LOGGED_ERRORS:
            self._logged_errors += 1
            self.get_logger().warning(f"skipped: {what}")

    # ------------------------------------------------------------------ bottles -> messages
    def _on_events(self, bottle, msg_stamp) -> None:
        where = f"skin events bottle #{self._count('bottles')} on {self.links[0][0]}"
        events = parse_skin_events(bottle.toString(), where)
        unknown = set(np.unique(events.skin_part).tolist()) - set(self.part_of_id)
        if unknown:
            self._count("contacts of unmapped parts", int(np.isin(events.skin_part, list(unknown)).sum()))
        for pid, part in self.part_of_id.items():
            n_slots = self.skin.parts[part].n_slots
            rows, taxels = events.of_part(pid)
            bad = events.taxel_id[taxels] >= n_slots
            if bad.any():
                raise DataError(f"{where}: taxel id {int(events.taxel_id[taxels][bad][0])} is beyond the"
                                f" {n_slots} slots of part '{part}'")
        for pid, part in self.part_of_id.items():
            sp = self.skin.parts[part]
            rows, taxels = events.of_part(pid)
            contacts = contacts_array(events.contact_id[rows], events.cop[rows], events.normal[rows],
                                      events.geo_center[rows], events.force[rows], events.moment[rows],
                                      events.pressure[rows])
            self.contact_pub[part].publish(cloud_from_array(contacts, self.frames + sp.parent_frame, msg_stamp))
            if part in self.comp_port_of:
                continue
            slots = events.taxel_id[taxels]
            owner = events.taxel_contact[taxels]
            points = taxels_array(slots, sp.positions[slots], events.pressure[owner], events.contact_id[owner])
            self.taxel_pub[part].publish(cloud_from_array(points, self.frames + sp.parent_frame, msg_stamp))
            self._count(f"messages {part}")

    def _on_compensated(self, part: str, bottle, msg_stamp) -> None:
        sp = self.skin.parts[part]
        where = f"compensated taxels of '{part}' on {self.comp_port_of[part]}"
        try:   # one numpy parse of the whole vector, not a Python call per taxel
            values = np.array(bottle.toString().split(), dtype=float)
        except ValueError:
            raise DataError(f"{where}: not a vector of numbers") from None
        slots, vals = activated_taxels(values, self.threshold, where, sp.n_slots)
        points = taxels_array(slots, sp.positions[slots], vals)
        self.taxel_pub[part].publish(cloud_from_array(points, self.frames + sp.parent_frame, msg_stamp))
        self._count(f"messages {part}")

    def _publish_status(self) -> None:
        connected = {remote: backoff.connected for remote, _, _, _, backoff in self.links}
        with self._counts_lock:
            counts = dict(self.counts)
        self.status_pub.publish(String(data=json.dumps({"counts": counts, "connected": connected},
                                                       sort_keys=True)))

    def close(self) -> None:
        self._stop.set()
        for _, port, _, _, _ in self.links:
            port.interrupt()
        for t in self._threads:
            t.join(timeout=2.0)
        for _, port, _, _, _ in self.links:
            port.close()
        self.yarp.Network.fini()


def main(args=None) -> int:
    return run_node(YarpSkinBridge, args)


if __name__ == "__main__":
    raise SystemExit(main())
