"""A record session's recording, apart from ROS: the live streams' touches into a touch bag, and what the
operator is told of it.

:class:`TouchRecording` feeds joint states and skin samples to the same
:class:`~nao_skin.touch.events.EventDetector` that reads bags offline, writes
each detected touch to a touch bag as ``write_touch_bag`` does
(:func:`~nao_skin.formats.bag.detected_touch_messages`), makes it durable on
:meth:`~TouchRecording.flush`, and keeps the progress: touches per pair, the
share of each part's taxels in a recorded touch, what was dropped and why, the
time per skin message, and how far each skin stream's stamps lag the joint
states'. The pairing_recorder node only translates messages to it and its
progress and warnings to topics and the log.
"""
from __future__ import annotations

import json
from collections import Counter, deque
from pathlib import Path
from typing import NoReturn

import numpy as np

from nao_skin.errors import BagMoved, DiskFull, OutputError
from nao_skin.formats.bag import SIMULATED, BagWriter, detected_touch_messages
from nao_skin.formats.pointcloud import JOINT_STATES_TOPIC, contacts_topic, taxels_topic
from nao_skin.live.clocks import SKEW_LIMIT_S, ArrivalLags
from nao_skin.live.heatmap import ActivationCounts
from nao_skin.model.skin import SkinModel, pair_label, scene_label
from nao_skin.touch.events import EventConfig, EventDetector
from nao_skin.touch.inorder import WAIT_S, InOrder

MAX_LOGGED_ERRORS = 5        # bad messages said one by one (all are counted)
SILENCE_S = 10.0             # s without a joint state, or without any skin sample, before the operator is told
# s of the joint states' own stamps they may lack mid-session while skin samples go on (they come at 10-100 Hz).
# Judged on the stamps, in the order the merge (touch.inorder) lets them through, never on when they arrived: a
# recorder held up (a starved process, a stopped one) gets each topic's backlog seconds apart, its stamps whole
OUTAGE_S = 2.0

# what the recorder reads, and where to look when it never comes
SILENT_STREAMS = {
    "joint states": f"is anything publishing {JOINT_STATES_TOPIC}? (naoqi_bridge: is nao_ip the robot's, is NAOqi"
                    f" running; or the driver that replaces it)",
    "skin samples": "is anything publishing /skin/<part>/taxels? (yarp_skin_bridge: is yarpserver reachable"
                    " ('yarp detect'), skinManager running, events_port its skin events port, part_ids its parts)",
}
SIMULATED_SILENCE = ("is sim_robot running? It simulates its touches before it plays the first (all of them, about"
                     " 5 ms a touch: 12 s for 2400; guided: guided_start), so a large touches_per_pair starts late")
RECENT_SKIN_MESSAGES = 20000   # skin messages whose processing time the progress' percentiles cover


class TouchRecording:
    """The touches of one session into the touch bag ``bag_path`` (a new directory, opened here)."""

    def __init__(self, skin: SkinModel, config: EventConfig, bag_path: str | Path, storage: str,
                 recorded_from: str = "", continues=(), sim_seed: int | None = None, judge=None):
        """``judge``: a :class:`~nao_skin.touch.fingertip.FingertipJudge` of the session's fingertip scenes (None:
        self-touches only)."""
        self.skin = skin
        self.detector = EventDetector.for_skin(skin, config, judge)
        self.in_order = InOrder()    # the streams to the detector in the order of their stamps
        self.parts = list(skin.parts)
        self.joint_names = list(skin.robot.joint_names)
        self.bag_path = Path(bag_path).expanduser().resolve()
        self.recorded_from = recorded_from
        self.bag = BagWriter(self.bag_path, storage, kind="touches", live=True, source=recorded_from,
                             continues=continues, sim_seed=sim_seed)
        self.bag.__enter__()
        self.n_touches = 0
        self.pairs: Counter = Counter()
        self.touched = ActivationCounts({n: skin.parts[n].n_slots for n in self.parts})     # in recorded touches
        self.errors: Counter = Counter()
        self._said_errors = 0
        self.skin_ms: deque = deque(maxlen=RECENT_SKIN_MESSAGES)     # processing time of recent skin messages
        self._dirty = False
        self.closed = False
        self._flushed = 0            # touches made durable by the last flush
        self.lags = ArrivalLags()    # do the skin and the joints share a clock?
        self._skew_said: set = set()
        self._skew_seen: dict = {}   # skin topic -> progress checks in a row it was beyond the limit
        self.received: Counter = Counter()    # joint states and skin samples read
        self._silence_said: set = set()
        # the joint states' gaps, on the stamps the merge lets through (the detector's order)
        self._joints_at: float | None = None    # stamp of the latest joint state (in time)
        self._skin_at: float | None = None      # ... and of the latest skin sample
        self._skin_in_gap: float | None = None  # the first skin sample since stamped past the joint state's reach
        self._gap_said: float | None = None     # the latest joint state's stamp when its gap was said as open
        self._resumed: list = []                # s of the gaps that closed since last said

    # ------------------------------------------------------------------ input
    def joint_state(self, stamp: float, names, positions, arrived: float) -> None:
        self.received["joint states"] += 1
        self.lags.add(JOINT_STATES_TOPIC, stamp, arrived)
        self._detect(self.in_order.push(JOINT_STATES_TOPIC, stamp, arrived,
                                        ("add_joint_state", (stamp, names, positions))))

    def taxels(self, part: str, stamp: float, slots, pressures, contacts, arrived: float) -> None:
        self.received["skin samples"] += 1
        self.lags.add(taxels_topic(part), stamp, arrived)
        self._detect(self.in_order.push(taxels_topic(part), stamp, arrived, (
            "add_skin", (stamp, part, slots.tolist(), pressures.tolist(), contacts.tolist()))))

    def contacts(self, part: str, stamp: float, contact_ids, cops, arrived: float) -> None:
        self._detect(self.in_order.push(contacts_topic(part), stamp, arrived,
                                        ("add_contacts", (stamp, part, contact_ids, cops))))

    def _detect(self, calls) -> None:
        """The detector's ``(method, arguments)`` calls the merge let through, in order; their touches written."""
        for method, args in calls:
            self._watch_gaps(method, args[0])
            self._write(getattr(self.detector, method)(*args))

    def _watch_gaps(self, method: str, stamp: float) -> None:
        """A gap of the joint states' stamps while skin samples go on, as the detector meets it: skin samples
        stamped where no joint state is within ``joint_tolerance`` (no arm pose for a touch then) before the next
        joint state, which comes :data:`OUTAGE_S` or more after the one before."""
        reach = self.detector.config.joint_tolerance
        if method == "add_skin":
            self._skin_at = stamp
            if self._joints_at is not None and self._skin_in_gap is None and stamp > self._joints_at + reach:
                self._skin_in_gap = stamp
        elif method == "add_joint_state":
            last = self._joints_at
            if last is not None and stamp - last >= OUTAGE_S and self._skin_in_gap is not None \
                    and self._skin_in_gap < stamp - reach:
                self._resumed.append(stamp - last)
            # the greatest, but a stream gone back by more than the detector keeps is followed (as the detector
            # does): one state stamped far ahead must not end the watch, one a little late must not open a gap
            if last is None or stamp > last or stamp < last - self.detector.config.joint_history:
                self._joints_at, self._skin_in_gap = stamp, None

    def bad_message(self) -> bool:
        """Count a message that could not be read; True while it is still to be said (the first few)."""
        self.errors["bad message"] += 1
        self._said_errors += 1
        return self._said_errors <= MAX_LOGGED_ERRORS

    # ------------------------------------------------------------------ output
    def _write(self, records) -> None:
        touches = detected_touch_messages(records, self.skin, self.detector.part_names, self.joint_names,
                                          self.bag_path, self.detector.fingertip_names)
        for stamp_ns, joint_names, joints, parts, fingertip in touches:
            if self.closed:
                return
            try:
                self.bag.write_touch(stamp_ns, joint_names, joints, parts, fingertip)
            except OutputError as exc:
                self._cannot_write(exc)
            for part, taxels, _ in parts:
                self.touched.update(part.name, taxels["slot"])
            names = [part.name for part, _, _ in parts]
            self.pairs[pair_label(names) if fingertip is None else scene_label(fingertip, names[0])] += 1
            self.n_touches += 1
            self._dirty = True

    def flush(self, now: float | None = None) -> None:
        """Make what was written durable: a recorder killed outright loses at most what came since. ``now`` (the
        clock of the ``arrived`` times): first detect in what waited its time for a quiet stream."""
        if now is not None and not self.closed:
            self._detect(self.in_order.ready(now))
        if self._dirty and not self.closed:
            try:
                self.bag.flush()
            except OutputError as exc:
                self._cannot_write(exc)
            self._dirty = False
            self._flushed = self.n_touches

    def _cannot_write(self, exc: OutputError) -> NoReturn:
        """The bag cannot take more (e.g. the disk is full): stop recording, leave the bag as it is.

        Closing it would write again; left open, with its lock, every reader takes it for a recording
        whose recorder died and reads it up to its last flush. The recorder ends (exit 2) and with it a
        record session, rather than let the operator go on touching for nothing.
        """
        self.closed = True
        if isinstance(exc, BagMoved):     # it says where the touches are now
            raise OutputError(f"{exc} after {self.n_touches} touches") from None
        then = "free some space, then record on" if isinstance(exc, DiskFull) else "once that is fixed, record on"
        raise OutputError(f"{exc} after {self.n_touches} touches; recording stopped. The bag keeps the"
                          f" {self._flushed} touches flushed before (maybe a few more) and nao-skin reads it as it"
                          f" is; {then} into a new bag") from None

    def close(self) -> str | None:
        """End of the session: resolve what waits, write it, close the bag (metadata); the line that says what
        the bag holds (None: closed before)."""
        if self.closed:
            return None
        self._detect(self.in_order.drain())
        self._write(self.detector.flush())
        self.closed = True
        try:
            self.bag.__exit__(None, None, None)
        except OutputError as exc:
            self._cannot_write(exc)
        silent = [what for what in SILENT_STREAMS if not self.received[what]]
        dropped = self.dropped()
        return (f"wrote {self.n_touches} touches to {self.bag_path}: {json.dumps(dict(self.pairs))}"
                + (f" (no {' and no '.join(silent)} ever arrived)" if silent else "")
                + (f"; not recorded: {json.dumps(dropped)}" if dropped else ""))

    def dropped(self) -> dict:
        """What the detector dropped, and the messages that could not be read, by reason."""
        return self.detector.drops() | dict(self.errors)

    # ------------------------------------------------------------------ what the operator is told
    def progress(self) -> dict:
        ms = np.array(self.skin_ms) if self.skin_ms else np.zeros(1)
        return {
            "bag": str(self.bag_path), "touches": self.n_touches, "pairs": dict(self.pairs),
            "coverage": {n: round(self.touched.coverage(n, self.skin.parts[n].present), 4) for n in self.parts},
            "dropped": self.dropped(),
            # per skin topic, s its stamps lag the joint states' (beyond a few ms: another clock)
            "clock_skew_s": {t: round(v, 4) for t, v in self.lags.skew(JOINT_STATES_TOPIC).items()},
            "skin_message_ms": {"n": len(self.skin_ms), "p50": round(float(np.percentile(ms, 50)), 4),
                                "p99": round(float(np.percentile(ms, 99)), 4), "max": round(float(ms.max()), 4)},
        }

    def clock_warnings(self, skew: dict) -> list:
        """What to say of a progress check's ``clock_skew_s``: once per skin stream whose stamps are on another
        clock than the joint states', beyond the limit at two checks in a row (one check's window can still
        hold a start-up queue)."""
        out = []
        for topic, s in skew.items():
            beyond = abs(s) > SKEW_LIMIT_S
            self._skew_seen[topic] = self._skew_seen.get(topic, 0) + 1 if beyond else 0
            if self._skew_seen[topic] >= 2 and topic not in self._skew_said:
                self._skew_said.add(topic)
                out.append(f"{topic} is stamped {abs(s):.2f} s {'behind' if s > 0 else 'ahead of'}"
                           f" {JOINT_STATES_TOPIC} for messages that arrive together: the skin's clock is not the"
                           f" joints' (skinManager on another host?), so every touch takes the arm pose of another"
                           f" moment. Synchronise the clocks (chrony/NTP), or start yarp_skin_bridge with"
                           f" stamp:=receive")
        return out

    def outage_warnings(self) -> list:
        """What to say when the joint states stop mid-session while skin samples go on: a touch pressed then
        has no arm pose and is lost, and the detector counts it only once the joint states are back. Judged on
        the stamps the merge let through (:data:`OUTAGE_S`), so said late: once the merge stops waiting for
        joint states (``touch.inorder.WAIT_S``) with skin samples :data:`OUTAGE_S` past the last one, and once
        when they are back (only that, when they came back before). A recorder held up, whose backlog comes
        topic after topic with whole stamps, says nothing; nor the other way round: a skin driver may send
        nothing while nothing is pressed."""
        out = [f"joint states again after {gap:.1f} s without (by their stamps): touches pressed in the gap are not"
               f" recorded (counted in 'dropped')" for gap in self._resumed]
        self._resumed.clear()
        last, skin = self._joints_at, self._skin_at
        if last is not None and skin is not None and skin - last >= OUTAGE_S and self._gap_said != last:
            self._gap_said = last
            out.append(f"no joint states for {skin - last:.0f} s of skin samples, and none came in the {WAIT_S:g} s"
                       f" the recorder waits for late ones: a touch pressed now has no arm pose and cannot be"
                       f" recorded; stop touching until they are back ({SILENT_STREAMS['joint states']})")
        return out

    def silence_warnings(self, elapsed: float) -> list:
        """What to say, once each, of a stream that sent nothing in the session's first ``elapsed`` s (at least
        :data:`SILENCE_S`): a robot session that records nothing would otherwise end with 'wrote 0 touches'."""
        out = []
        for what, hint in SILENT_STREAMS.items():
            if elapsed >= SILENCE_S and not self.received[what] and what not in self._silence_said:
                self._silence_said.add(what)
                if self.recorded_from == SIMULATED:  # the robot's bridges are not in this session
                    hint = SIMULATED_SILENCE
                out.append(f"no {what} in {elapsed:.0f} s: {hint}")
        return out

