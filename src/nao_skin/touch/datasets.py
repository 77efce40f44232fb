"""Touch data sets as a whole: what loading skipped, exact duplicates, train/test split."""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph

from nao_skin.touch.touches import TouchSet

MAX_LISTED_MESSAGES = 20     # a report prints this many skip reasons in full, then counts


@dataclass
class LoadReport:
    """What a reader did with its input: touches read, kept, and every skip with its one-line reason.

    ``skipped`` counts by short reason key (e.g. ``"missing joint"``); ``messages``
    holds the one-line explanations naming file, touch and field.
    """

    source: str
    n_read: int = 0
    n_loaded: int = 0
    skipped: Counter = field(default_factory=Counter)
    messages: list = field(default_factory=list)
    unit: str = "touches"          # what n_read counts: touches (text formats) or messages (bags)
    unknown_slots: Counter = field(default_factory=Counter)   # per part: skipped for slots not in its layout
    notes: list = field(default_factory=list)      # what was kept but is worth a look (one line each)
    # what the input is, said with its summary and never as a warning: a recording of the simulated robot, one
    # still being recorded (a record session's calibrate node reads its own, open, on every update and request)
    info: list = field(default_factory=list)

    @property
    def n_skipped(self) -> int:
        return int(sum(self.skipped.values()))

    def skip(self, reason: str, message: str, count: int = 1, part: str | None = None) -> None:
        """Count a skip; ``part``: the skin part whose layout lacks the named slot (reason 'bad taxel slot')."""
        self.skipped[reason] += count
        self.messages.append(" ".join(str(message).split()))
        if part is not None:
            self.unknown_slots[part] += count

    def merge(self, other: "LoadReport") -> None:
        self.skipped.update(other.skipped)
        self.unknown_slots.update(other.unknown_slots)
        self.notes.extend(other.notes)
        self.info.extend(other.info)
        self.messages.extend(other.messages)

    def summary(self) -> str:
        """One line: read / loaded / skipped by reason."""
        why = ", ".join(f"{n} {reason}" for reason, n in sorted(self.skipped.items()))
        return (f"{self.source}: {self.n_loaded} touches loaded of {self.n_read} {self.unit} read"
                + (f"; skipped: {why}" if why else ""))

    def lines(self, limit: int = MAX_LISTED_MESSAGES) -> list:
        """Summary, what the input is, the notes, then the first ``limit`` skip messages (and how many more)."""
        out = [self.summary()] + self.info + self.notes + self.messages[:limit]
        if len(self.messages) > limit:
            out.append(f"... and {len(self.messages) - limit} more")
        return out


def _touch_signatures(touches: TouchSet) -> np.ndarray:
    """(N, L) int64 rows that are equal exactly when two touches have the same angles, part/slot sets and
    fingertip."""
    n = touches.n_touches
    joints = np.where(np.isnan(touches.joints), np.inf, touches.joints + 0.0)  # -0.0 == 0.0, NaN == NaN
    joint_bits = np.ascontiguousarray(joints, dtype=np.float64).view(np.int64)
    # one code per activated taxel; a taxel listed twice (two contacts) counts once
    code = touches.act_part.astype(np.int64) * (1 << 32) + touches.act_slot.astype(np.int64)
    pairs = np.unique(np.stack([touches.act_touch.astype(np.int64), code], axis=1), axis=0)
    counts = np.bincount(pairs[:, 0], minlength=n)
    width = int(counts.max()) if n and len(pairs) else 0
    padded = np.full((n, width), -1, dtype=np.int64)
    start = np.cumsum(counts) - counts
    padded[pairs[:, 0], np.arange(len(pairs)) - start[pairs[:, 0]]] = pairs[:, 1]
    return np.concatenate([joint_bits, touches.fingertip_of_touch[:, None].astype(np.int64), counts[:, None], padded],
                          axis=1)


def duplicate_mask(touches: TouchSet) -> np.ndarray:
    """(N,) bool: True for a touch that exactly repeats an earlier one (same angles, same part/slot sets)."""
    if touches.n_touches == 0:
        return np.zeros(0, dtype=bool)
    _, first = np.unique(_touch_signatures(touches), axis=0, return_index=True)
    mask = np.ones(touches.n_touches, dtype=bool)
    mask[first] = False
    return mask


def repeats_of(touches: TouchSet, earlier: TouchSet) -> int:
    """How many of ``touches`` exactly repeat a touch of ``earlier`` (same angles, same part/slot sets): a
    simulated robot playing the seed of an earlier sitting again repeats every one of its touches."""
    if touches.n_touches == 0 or earlier.n_touches == 0:
        return 0
    _, ids = np.unique(_touch_signatures(TouchSet.concatenate([earlier, touches])), axis=0, return_inverse=True)
    ids = np.asarray(ids).reshape(-1)
    return int(np.isin(ids[earlier.n_touches:], ids[:earlier.n_touches]).sum())


def deduplicate(touches: TouchSet) -> tuple:
    """``(touches without exact repeats, n_removed)``; the first occurrence is kept, order preserved."""
    dup = duplicate_mask(touches)
    return touches.subset(~dup), int(dup.sum())


POSE_TOLERANCE = np.radians(0.5)    # joint angles this close: one pose (a press sampled again, encoder jitter)


def pose_groups(touches: TouchSet, tolerance: float = POSE_TOLERANCE) -> np.ndarray:
    """A group number per touch: touches whose every joint angle agrees within ``tolerance`` (rad), directly
    or through others, share one. A press held still is recorded as several touches (another contact
    sample each); the shared real recording has 324 of its 785 touches at the pose of another one."""
    if tolerance == POSE_TOLERANCE:    # the split and the plan's rules ask for the same: computed once per set
        return touches.derived(("pose groups",), lambda: _pose_groups(touches, tolerance))
    return _pose_groups(touches, tolerance)


def _pose_groups(touches: TouchSet, tolerance: float) -> np.ndarray:
    n = touches.n_touches
    if n == 0 or touches.joints.shape[1] == 0:
        return np.arange(n)
    q = np.where(np.isfinite(touches.joints), touches.joints, 1e9)    # a joint not reported: its own value
    # candidates: the touches within ``tolerance`` on the first joint (sorted), then every joint compared
    order = np.argsort(q[:, 0], kind="stable")
    first = q[order, 0]
    ahead = np.searchsorted(first, first + tolerance, side="right") - np.arange(n) - 1
    i = np.repeat(np.arange(n), ahead)
    j = i + 1 + np.arange(len(i)) - np.repeat(np.cumsum(ahead) - ahead, ahead)
    close = np.all(np.abs(q[order[i]] - q[order[j]]) <= tolerance, axis=1)
    links = scipy.sparse.coo_matrix((np.ones(int(close.sum())), (order[i[close]], order[j[close]])), shape=(n, n))
    groups = scipy.sparse.csgraph.connected_components(links, directed=False)[1]
    groups.setflags(write=False)     # shared by every caller (TouchSet.derived)
    return groups


def pose_weights(touches: TouchSet, exponent: float) -> np.ndarray | None:
    """A weight per touch, ``n ** -exponent`` with ``n`` the touches at its pose (:func:`pose_groups`),
    scaled to a mean of 1 so the touches weigh as much in all as before; None when every weight is 1.

    The samples of one held press share its pose error and its contact: counted as independent they
    pull the fit toward the poses held longest. 0 weighs every touch alike, 1 every pose alike.
    """
    if exponent == 0 or touches.n_touches == 0:
        return None
    groups = pose_groups(touches)
    size = np.bincount(groups)[groups]
    if np.all(size == 1):
        return None
    weight = size.astype(float) ** -exponent
    return weight / weight.mean()


def split(touches: TouchSet, test_fraction: float = 0.3, seed: int = 0, groups: np.ndarray | None = None) -> tuple:
    """``(train, test)``: a random permutation with ``seed`` (same seed, same split); rows keep their order.

    ``groups`` (e.g. :func:`pose_groups`): touches of one group fall on the same side, so the held-out figure
    never meets a pose it was trained on; the test side holds the share of touches closest to
    ``test_fraction`` whole groups give. Each touch its own group is the same split as none.
    """
    if not 0.0 <= test_fraction <= 1.0:
        raise ValueError(f"test_fraction must be within 0..1, got {test_fraction}")
    n = touches.n_touches
    n_test = int(round(test_fraction * n))
    groups = np.arange(n) if groups is None else np.asarray(groups)
    n_groups = int(groups.max()) + 1 if n else 0
    perm = np.random.default_rng(seed).permutation(n_groups)
    taken = np.cumsum(np.bincount(groups, minlength=n_groups)[perm])
    k = int(np.searchsorted(taken, n_test))         # the first k + 1 groups reach n_test touches
    if k < n_groups and n_test and taken[k] - n_test > n_test - (taken[k - 1] if k else 0):
        k -= 1                                        # one group fewer is closer to the share
    held = np.zeros(n_groups, bool)
    held[perm[:k + 1] if n_test else []] = True
    test = held[groups]
    return touches.subset(np.flatnonzero(~test)), touches.subset(np.flatnonzero(test))
