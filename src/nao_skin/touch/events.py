"""Self-touch events from separate joint and skin streams, the same code live and offline.

Joint states and skin samples arrive separately, at their own rates. A
*touch* is a moment when two or more skin parts are active together (their
latest non-empty samples within ``skin_tolerance`` of each other); its stamp
is the skin stamp that completed it and its joint angles are linearly
interpolated to that stamp from the two joint states that bracket it.

Rules (each drop is counted in ``counts`` under its reason, never guessed):

* an event waits ``skin_tolerance`` for the other parts' samples of the same
  moment, then waits for a joint state at or after its stamp;
* both bracketing joint states must lie within ``joint_tolerance`` of the
  stamp ("stale joints" otherwise); a joint state may name only some joints
  (or give NaN for some): a joint those leave out is interpolated from the
  nearest states that have it, within ``joint_tolerance`` on both sides, and a
  joint needed by a touching part's chain that none gives drops the event
  ("missing joint");
* a continuous press is one touch per *distinct activation pattern*: while
  every part of a combination stays pressed (no empty sample, no silence
  longer than ``release_gap``), a new touch is emitted only when the set of
  activated taxels changed, and at most once per ``min_interval``. A release
  and a new press always give a new touch;
* a moment dropped for want of joint states (stale, or none yet: a joint
  stream that stalled or started late) does not end its press's chances: the
  press's next moment ``min_interval`` later is tried again, however its
  pattern stands, so a press held through a gap in the joint states is
  recorded once the joints are back. The drop is counted once per press, and
  taken back when a later moment of the press is recorded.

A *fingertip touch* is a moment when one part fires that a fingertip of the scene presses (the skin
config's ``fingertip_touch``): it waits ``skin_tolerance`` for another part as a self-touch's moment does,
and becomes a touch when a fingertip pressed it: said by the recording (a touch bag's fingertip message at its
stamp, :meth:`EventDetector.add_fingertip`), or judged live from the joint angles (``judge``, e.g.
:class:`~nao_skin.touch.fingertip.FingertipJudge`: a fingertip is where the contact is). A part that fires while
no fingertip is near is dropped ("no fingertip near": an experimenter's hand); one that fires while another part
is pressed is part of that part's self-touch, not a fingertip's.

Touch bags (one sample per part and one joint state per touch, all at the
touch stamp) are read with :data:`TOUCH_BAG_CONFIG`: zero tolerances and
every stamp a new press, so each stored touch comes back exactly once.

Per message the work is a few dict/list operations and one bisect
(no numpy on the skin path except building the emitted record).
"""
from __future__ import annotations

import bisect
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from nao_skin.model.robot import MAX_JOINT_LIMIT
from nao_skin.touch.touches import TouchSet

MAX_NOTES = 50            # one-line drop explanations kept (counts are always complete)
MAX_PENDING = 1000        # events waiting for joints before the oldest is dropped
RECOVERED = "joints late, press recorded later"     # a count of presses kept, like "touches": no drop
NOT_DROPS = ("touches", "continued press", RECOVERED)


@dataclass(frozen=True)
class EventConfig:
    # s: samples of different parts this close belong to one moment. At least half the skin
    # frame period (parts are sampled with their own phase), below a full period (20 ms at 50 Hz)
    # so that consecutive frames stay separate moments.
    skin_tolerance: float = 0.015
    joint_tolerance: float = 0.1    # s: max distance of each bracketing joint state from the skin stamp
    min_interval: float = 0.2       # s: during one continuous press, at most one touch per this interval
    release_gap: float = 0.1        # s: a part silent this long counts as released
    joint_history: float = 5.0      # s of joint states kept for interpolation


LIVE_CONFIG = EventConfig()
TOUCH_BAG_CONFIG = EventConfig(skin_tolerance=0.0, joint_tolerance=0.0, min_interval=0.0, release_gap=0.0)


@dataclass
class ContactRecord:
    part: int                       # index into the detector's part names
    contact_id: int                 # skinManager contactId, -1 if none
    cop: np.ndarray                 # (3,) recorded COP, part local frame (NaN unknown)
    slots: np.ndarray               # (n,) int
    pressures: np.ndarray           # (n,) float (NaN unknown)


@dataclass
class TouchRecord:
    stamp: float
    joints: np.ndarray              # (J,) radians, detector joint order
    contacts: list = field(default_factory=list)
    fingertip: str | None = None    # the fingertip that pressed it (a fingertip touch), None: a self-touch


@dataclass
class _Sample:
    stamp: float
    slots: tuple
    pressures: tuple
    contact_ids: tuple
    summary: Mapping | None
    press_start: float


@dataclass
class _Candidate:
    stamp: float
    samples: dict                   # part index -> _Sample
    press: tuple = ()               # (part combination, press starts): which press this moment is of


class EventDetector:
    """Incremental touch detection. Feed messages in (roughly) time order (the recorder and the stream-bag
    reader put them in it: :class:`~nao_skin.touch.inorder.InOrder`); collect emitted touches."""

    def __init__(self, part_names: Sequence[str], joint_names: Sequence[str],
                 needed_joints: Mapping[str, Sequence[str]] | None = None, config: EventConfig = LIVE_CONFIG,
                 fingertips: Mapping[str, Sequence[str]] | None = None, judge=None):
        """``needed_joints``: per part and per fingertip, the joints its chain needs; ``fingertips``: per
        fingertip, the parts it presses (their one-part moments are fingertip touches when a fingertip pressed
        them); ``judge(part, slots, q)``: the fingertip pressing a part's moment live, None when none is near (no
        judge: only a recording's fingertip messages say so)."""
        self.part_names = tuple(part_names)
        self.joint_names = tuple(joint_names)
        self.config = config
        fingertips = dict(fingertips or {})
        self.fingertip_names = tuple(fingertips)
        self._pressed_alone = {self.part_names.index(p) for parts in fingertips.values() for p in parts
                               if p in self.part_names}
        self._judge = judge
        self._markers: dict = {}              # stamp -> fingertip a recording says pressed the moment there
        self._part_index = {n: i for i, n in enumerate(self.part_names)}
        self._joint_index = {n: i for i, n in enumerate(self.joint_names)}
        needed_joints = needed_joints or {}
        self._needed = [tuple(self._joint_index[j] for j in needed_joints.get(p, ()) if j in self._joint_index)
                        for p in self.part_names]
        self._needed_names = [tuple(needed_joints.get(p, ())) for p in self.part_names]
        self._tip_needed = {f: [(self._joint_index[j], j) for j in needed_joints.get(f, ()) if j in self._joint_index]
                            for f in self.fingertip_names}
        self._columns_cache: dict = {}
        self._joint_stamps: list = []
        self._joint_values: list = []
        self._trimmed_until = float("-inf")   # the latest joint stamp let go of (older than joint_history)
        self._latest: dict = {}               # part index -> _Sample (latest non-empty) or None (released)
        self._open: _Candidate | None = None
        self._pending: deque = deque()        # finalised candidates waiting for a later joint state
        self._last_emit: dict = {}            # part combination -> (stamp, pattern, press)
        self._retrying: dict = {}             # part combination -> (press, drop reason): a moment lacked joints
        self._summaries: dict = {}            # (part, stamp) -> contacts summary arriving before its taxels
        self._behind: dict = {}               # part index -> stamp of the last sample ignored as stamped far back
        self._part_stamp: dict = {}           # part index -> latest stamp of its samples (released ones too)
        self.counts: Counter = Counter()
        self.notes: list = []
        self.n_pressed = 0                    # skin samples with a taxel on: what a reader says when none paired

    @classmethod
    def for_skin(cls, skin, config: EventConfig = LIVE_CONFIG, judge=None) -> "EventDetector":
        """A detector for the parts, joints and fingertip scenes of a :class:`~nao_skin.model.skin.SkinModel`
        (``judge``: a :class:`~nao_skin.touch.fingertip.FingertipJudge` of the session's scenes)."""
        robot = skin.robot
        needed = {n: robot.chain_joint_names(p.chain) if p.chain else [] for n, p in skin.parts.items()}
        fingertips: dict = {}
        # the scenes a live judge takes fingertip touches of, or (reading a bag) every scene a recording may name
        for tip, part in (judge.pairs if judge is not None else skin.fingertip_touch.pairs()):
            fingertips.setdefault(tip, []).append(part)
            needed[tip] = robot.chain_joint_names(robot.fingertip(tip).chain)
        return cls(tuple(skin.parts), tuple(robot.joint_names), needed, config, fingertips, judge)

    # ------------------------------------------------------------------ bookkeeping
    def drops(self) -> dict:
        """``{reason: count}`` of what was dropped (``counts`` without the touches and presses kept)."""
        return {k: v for k, v in self.counts.items() if k not in NOT_DROPS}

    def _drop(self, reason: str, note: str) -> None:
        self.counts[reason] += 1
        if len(self.notes) < MAX_NOTES:
            self.notes.append(note)

    # ------------------------------------------------------------------ input
    def add_joint_state(self, stamp: float, names: Sequence[str], positions: Sequence[float]) -> list:
        """A JointState (NAOqi names, radians). Returns the touches this completes."""
        key = tuple(names)
        cols = self._columns_cache.get(key)
        if cols is None:
            pairs = [(i, self._joint_index[n]) for i, n in enumerate(names) if n in self._joint_index]
            cols = (np.array([p[0] for p in pairs], dtype=int), np.array([p[1] for p in pairs], dtype=int))
            self._columns_cache[key] = cols
        values = np.full(len(self.joint_names), np.nan)
        positions = np.asarray(positions, dtype=float)
        if len(positions) != len(names):
            self._drop("malformed joint state", f"joint state at {stamp:.6f}: {len(names)} names but"
                                                f" {len(positions)} positions")
            return []
        values[cols[1]] = positions[cols[0]]
        # no measurement, as a joint not reported: inf (FK would warn on it), and what no joint reaches (beyond
        # two turns: a broken encoder word, not an angle)
        values[np.abs(values) > MAX_JOINT_LIMIT] = np.nan
        stamp = float(stamp)
        stamps = self._joint_stamps
        n = self._confirmed()
        if n < len(stamps) and stamps[n - 1] <= stamp < stamps[-1] - self.config.joint_history:
            # the stream goes on where it was: the state that jumped ahead of it was mis-stamped
            self._drop("joint state stamped ahead", f"joint state at {stamps[-1]:.6f}: {stamps[-1] - stamps[n - 1]:.3f}"
                                                    f" s ahead of the joint states before and after it; ignored")
            del stamps[-1], self._joint_values[-1]
        if not stamps or stamp >= stamps[-1]:
            stamps.append(stamp)
            self._joint_values.append(values)
        else:                                  # late message: keep the buffer sorted
            i = bisect.bisect_right(stamps, stamp)
            stamps.insert(i, stamp)
            self._joint_values.insert(i, values)
        # a state far ahead of the one before waits for the next to confirm it before it ages the others out
        horizon = stamps[self._confirmed() - 1] - self.config.joint_history
        if stamps[0] < horizon:
            cut = bisect.bisect_left(stamps, horizon)
            cut = min(cut, len(stamps) - 2) if len(stamps) > 2 else 0
            if cut > 0:
                self._trimmed_until = max(self._trimmed_until, stamps[cut - 1])
                del stamps[:cut], self._joint_values[:cut]
        return self._resolve_pending(final=False)

    def _confirmed(self) -> int:
        """How many joint states count: all but the latest when it lies more than ``joint_history`` ahead of
        the one before (one mis-stamped message would otherwise age out every real one and drop every touch
        after it as out of order); the next state confirms it or shows it was mis-stamped."""
        stamps = self._joint_stamps
        if len(stamps) >= 2 and stamps[-1] - stamps[-2] > self.config.joint_history:
            return len(stamps) - 1
        return len(stamps)

    def add_fingertip(self, stamp: float, name: str) -> list:
        """A recording's word that the moment at ``stamp`` was pressed by fingertip ``name`` (a touch bag's
        fingertip message)."""
        if name not in self.fingertip_names:
            self._drop("unknown fingertip", f"fingertip message at {stamp:.6f}: fingertip '{name}' presses no part of"
                                            f" this skin config (fingertips: {', '.join(self.fingertip_names) or 'none'})")
            return []
        self._markers[float(stamp)] = name
        if len(self._markers) > MAX_PENDING:      # never matched: never pile up
            self._markers.pop(next(iter(self._markers)))
        return []

    def add_contacts(self, stamp: float, part: str, contact_ids: Sequence[int], cops: np.ndarray) -> list:
        """skinManager contacts of one skin sample (the ``/skin/<part>/contacts`` message).

        Attached to the taxel sample of the same part and stamp, whichever arrives first.
        """
        p = self._part_index.get(part)
        if p is None:
            self._drop("unknown skin part", f"contacts at {stamp:.6f}: skin part '{part}' is not configured"
                                            f" ({', '.join(self.part_names)})")
            return []
        summary = {int(c): np.asarray(cop, dtype=float) for c, cop in zip(contact_ids, cops)}
        stamp = float(stamp)
        for sample in (self._latest.get(p), self._open.samples.get(p) if self._open else None):
            if sample is not None and sample.stamp == stamp:
                sample.summary = summary
                return []
        self._summaries[(p, stamp)] = summary
        if len(self._summaries) > 64:        # unmatched summaries never pile up
            self._summaries.pop(next(iter(self._summaries)))
        return []

    def add_skin(self, stamp: float, part: str, slots: Sequence[int], pressures: Sequence[float] | None = None,
                 contact_ids: Sequence[int] | None = None, contacts_summary: Mapping | None = None) -> list:
        """One skin sample of one part: its activated taxel slots (empty = released). Returns completed touches."""
        p = self._part_index.get(part)
        if p is None:
            self._drop("unknown skin part", f"skin sample at {stamp:.6f}: skin part '{part}' is not configured"
                                            f" ({', '.join(self.part_names)})")
            return []
        stamp = float(stamp)
        cfg = self.config
        prev = self._latest.get(p)
        latest = self._part_stamp.get(p)
        if latest is not None and stamp < latest - cfg.joint_history:
            # one sample stamped far back (an unset or foreign clock; older than the joint states kept, so no
            # touch anyway) must not end the part's press: the next real one would count as a new press, one
            # more touch each time; a clock that really went back is followed from its second sample on
            behind, self._behind[p] = self._behind.get(p), stamp
            if behind is None or not 0.0 < stamp - behind <= cfg.joint_history:
                self._drop("skin stamped behind", f"skin sample of '{part}' at {stamp:.6f}: {latest - stamp:.3f} s"
                                                  f" before the part's latest (stamps out of order?); ignored")
                return []
        self._behind.pop(p, None)
        self._part_stamp[p] = stamp if latest is None or stamp < latest - cfg.joint_history else max(latest, stamp)
        out = self._close_open(stamp)
        if len(slots) == 0:
            self._latest[p] = None
            return out + self._resolve_pending(final=False)
        self.n_pressed += 1
        n = len(slots)
        pressures = tuple(pressures) if pressures is not None else (float("nan"),) * n
        contact_ids = tuple(int(c) for c in contact_ids) if contact_ids is not None else (-1,) * n
        summary = contacts_summary if contacts_summary is not None else self._summaries.pop((p, stamp), None)
        new_press = prev is None or stamp - prev.stamp > cfg.release_gap or stamp < prev.stamp
        sample = _Sample(stamp, tuple(int(s) for s in slots), pressures, contact_ids, summary,
                         stamp if new_press else prev.press_start)
        self._latest[p] = sample
        cand = self._open
        if cand is not None and abs(stamp - cand.stamp) <= cfg.skin_tolerance:
            cand.samples.setdefault(p, sample)           # the first sample of a part in a moment counts
        else:
            together = {q: s for q, s in self._latest.items()
                        if s is not None and q != p and abs(stamp - s.stamp) <= cfg.skin_tolerance}
            # a part a fingertip presses may be a touch alone, where a judge or the recording can say whose
            if together or (p in self._pressed_alone and (self._judge is not None or stamp in self._markers)):
                together[p] = sample
                self._open = _Candidate(stamp, together)
        return out + self._resolve_pending(final=False)

    def flush(self) -> list:
        """End of input: finalise the open moment and resolve or drop what waits for joints."""
        out = self._close_open(None)
        return out + self._resolve_pending(final=True)

    # ------------------------------------------------------------------ moments -> touches
    def _close_open(self, now: float | None) -> list:
        cand = self._open
        # a sample from well before the open moment (stamps out of order) closes it as a later one would:
        # replaced unclosed, the moment's touch would be lost without a word
        if cand is None or (now is not None and abs(now - cand.stamp) <= self.config.skin_tolerance):
            return []
        self._open = None
        combo = tuple(sorted(cand.samples))
        pattern = tuple((q, tuple(sorted(set(cand.samples[q].slots)))) for q in combo)
        press = tuple(cand.samples[q].press_start for q in combo)
        last = self._last_emit.get(combo)
        if last is not None and last[2] == press and (
                last[1] == pattern or cand.stamp - last[0] < self.config.min_interval):
            self.counts["continued press"] += 1     # the same touch still held: not a new one
            return []
        self._last_emit[combo] = (cand.stamp, pattern, press)
        cand.press = (combo, press)
        self._pending.append(cand)
        if len(self._pending) > MAX_PENDING:
            old = self._pending.popleft()
            self._drop("no joint state", f"touch at {old.stamp:.6f}: no joint state arrived for it")
        return self._resolve_pending(final=False)

    def _resolve_pending(self, final: bool) -> list:
        out = []
        stamps = self._joint_stamps
        # at the end of the input no later joint state can show the latest one mis-stamped: it counts (a touch
        # bag holds joint states at its touches only, so its last touch's came seconds after the one before)
        n = len(stamps) if final else self._confirmed()
        while self._pending:
            cand = self._pending[0]
            t = cand.stamp
            after = bisect.bisect_left(stamps, t, 0, n)
            if after == n:
                if not final:
                    break                          # wait for a joint state at or after t
                self._pending.popleft()
                self._drop("no joint state after", f"touch at {t:.6f}: no joint state at or after it")
                continue
            self._pending.popleft()
            before = after if stamps[after] == t else after - 1
            tol = self.config.joint_tolerance
            if before < 0:
                if t < self._trimmed_until:
                    self._drop("stamp out of order", f"touch at {t:.6f}: {stamps[-1] - t:.3f} s before the latest"
                                                     f" joint state, older than the {self.config.joint_history} s"
                                                     f" of joint states kept (stamps out of order?)")
                else:
                    self._joints_missing(cand, "no joint state before",
                                         f"touch at {t:.6f}: no joint state at or before it")
                continue
            if t - stamps[before] > tol or stamps[after] - t > tol:
                self._joints_missing(cand, "stale joints", f"touch at {t:.6f}: bracketing joint states at"
                                                           f" {stamps[before]:.6f} and {stamps[after]:.6f} are more"
                                                           f" than {tol} s away")
                continue
            q0, q1 = self._joint_values[before], self._joint_values[after]
            span = stamps[after] - stamps[before]
            q = q0 if span <= 0 else q0 + (q1 - q0) * ((t - stamps[before]) / span)
            if np.isnan(q).any():
                q = self._per_joint(t, q)
            record = self._record(cand, q)
            if record is not None:
                out.append(record)
                self._recovered(cand)
        return out

    def _joints_missing(self, cand: _Candidate, reason: str, note: str) -> None:
        """A moment without joint states around it: dropped (counted once per press), and its press tried
        again at its next moment ``min_interval`` on, whatever its pattern (the pattern was never recorded)."""
        combo, press = cand.press
        if self._retrying.get(combo, (None,))[0] != press:
            self._drop(reason, f"{note}; its press is tried again at its next moment")
            self._retrying[combo] = (press, reason)
        last = self._last_emit.get(combo)
        if last is not None and last[0] == cand.stamp and last[2] == press:    # no later moment of it is on its way
            self._last_emit[combo] = (last[0], None, press)

    def _recovered(self, cand: _Candidate) -> None:
        """A press whose earlier moment lacked joint states is recorded after all: that drop is taken back."""
        combo, press = cand.press
        retry = self._retrying.get(combo)
        if retry is not None and retry[0] == press:
            del self._retrying[combo]
            self.counts[retry[1]] -= 1
            if self.counts[retry[1]] <= 0:
                del self.counts[retry[1]]
            self.counts[RECOVERED] += 1

    def _per_joint(self, t: float, q: np.ndarray) -> np.ndarray:
        """``q`` with each joint the bracketing states left NaN interpolated from the nearest states that
        have it, within ``joint_tolerance`` on both sides: joint states naming only some joints (a second
        driver publishing the head's) or NaN for some arrive between the full ones."""
        tol = self.config.joint_tolerance
        lo = bisect.bisect_left(self._joint_stamps, t - tol)
        hi = bisect.bisect_right(self._joint_stamps, t + tol)
        stamps = np.array(self._joint_stamps[lo:hi])
        values = np.array(self._joint_values[lo:hi])
        q = q.copy()
        for col in np.flatnonzero(np.isnan(q)):
            has = np.isfinite(values[:, col])
            before = np.flatnonzero(has & (stamps <= t))
            after = np.flatnonzero(has & (stamps >= t))
            if len(before) and len(after):
                b, a = before[-1], after[0]
                span = stamps[a] - stamps[b]
                w = 0.0 if span <= 0 else (t - stamps[b]) / span
                q[col] = values[b, col] + (values[a, col] - values[b, col]) * w
        return q

    def _fingertip_of(self, cand: _Candidate, q: np.ndarray) -> str | None:
        """The fingertip that pressed a one-part moment, or None (dropped and counted where a judge said none
        was near; a part pressed while another is, is part of that one's self-touch)."""
        named = self._markers.pop(cand.stamp, None)
        if named is not None:
            return named
        if self._judge is None:
            return None
        (p, sample), = cand.samples.items()
        gap = self.config.release_gap
        if any(s is not None and q_ != p and abs(s.stamp - cand.stamp) <= gap for q_, s in self._latest.items()):
            return None
        tip = self._judge(self.part_names[p], sample.slots, q)
        if tip is None:
            self._drop("no fingertip near", f"touch at {cand.stamp:.6f}: part '{self.part_names[p]}' fired alone and"
                                            f" no fingertip was near it (an experimenter's hand?)")
        return tip

    def _record(self, cand: _Candidate, q: np.ndarray) -> TouchRecord | None:
        fingertip = None
        if len(cand.samples) == 1:
            fingertip = self._fingertip_of(cand, q)
            if fingertip is None:
                return None
            for col, name in self._tip_needed[fingertip]:
                if not np.isfinite(q[col]):
                    self._drop("missing joint", f"touch at {cand.stamp:.6f}: joint '{name}' needed by fingertip"
                                                f" '{fingertip}' is missing or not finite ({q[col]})")
                    return None
        for p in sorted(cand.samples):
            for col, name in zip(self._needed[p], self._needed_names[p]):
                if not np.isfinite(q[col]):
                    self._drop("missing joint", f"touch at {cand.stamp:.6f}: joint '{name}' needed by part"
                                                f" '{self.part_names[p]}' is missing or not finite ({q[col]})")
                    return None
        contacts = []
        for p in sorted(cand.samples):
            s = cand.samples[p]
            slots = np.array(s.slots, dtype=int)
            pressures = np.array(s.pressures, dtype=float)
            ids = np.array(s.contact_ids, dtype=int)
            for cid in dict.fromkeys(s.contact_ids):     # contact ids in order of appearance
                sel = ids == cid
                cop = s.summary.get(cid) if s.summary is not None and cid >= 0 else None
                cop = np.full(3, np.nan) if cop is None else np.asarray(cop, dtype=float)
                contacts.append(ContactRecord(p, cid, cop, slots[sel], pressures[sel]))
        self.counts["touches"] += 1
        return TouchRecord(cand.stamp, q.copy(), contacts, fingertip)


def touchset_from_records(records: Sequence[TouchRecord], part_names: Sequence[str],
                          joint_names: Sequence[str], keys: Sequence | None = None, fingertips: Sequence[str] = ()) -> TouchSet:
    """Flat arrays from emitted touches (keys default to the stamps printed with ns resolution; ``fingertips``:
    the detector's, the names a fingertip touch's ``fingertip`` is one of)."""
    if not records:
        return TouchSet.empty(part_names, joint_names)
    fingertips = tuple(fingertips)
    touch_fingertip = np.array([fingertips.index(r.fingertip) if r.fingertip is not None else -1 for r in records],
                               dtype=int)
    contacts = [(t, c) for t, r in enumerate(records) for c in r.contacts]
    n_act = np.array([len(c.slots) for _, c in contacts], dtype=int)
    return TouchSet(
        tuple(part_names), tuple(joint_names),
        np.array([r.stamp for r in records], dtype=float),
        list(keys) if keys is not None else [f"{r.stamp:.9f}" for r in records],
        np.stack([r.joints for r in records]),
        np.array([t for t, _ in contacts], dtype=int), np.array([c.part for _, c in contacts], dtype=int),
        np.array([c.contact_id for _, c in contacts], dtype=int),
        np.stack([c.cop for _, c in contacts]).reshape(-1, 3),
        np.repeat(np.arange(len(contacts)), n_act),
        np.concatenate([c.slots for _, c in contacts]).astype(int),
        np.concatenate([c.pressures for _, c in contacts]).astype(float),
        fingertips=fingertips, touch_fingertip=touch_fingertip if fingertips else None)
