"""Which parts to fit against which: the thesis' multi-session plan, from the pairs in the data."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from nao_skin.errors import TooFewTouches
from nao_skin.model.skin import SelfTouch, pair_label, part_rank
from nao_skin.touch.datasets import pose_groups
from nao_skin.touch.touches import TouchSet

if TYPE_CHECKING:   # only for annotations: calibrate imports this module
    from nao_skin.calibration.options import CalibrationOptions

@dataclass
class Step:
    """Fit ``targets`` against touches with ``references`` (fixed unless simultaneous)."""

    targets: tuple
    references: tuple

    @property
    def name(self) -> str:
        return "+".join(self.targets) + (" from " + "+".join(self.references) if self.references else "")

def pair_counts(touches: TouchSet) -> dict:
    """``{frozenset(part names): touches where both fire}`` of every pair that fires together at least once."""
    fired = touches.parts_of_touch()
    names = touches.part_names
    out = {}
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            n = int(np.sum(fired[:, i] & fired[:, j]))
            if n:
                out[frozenset((names[i], names[j]))] = n
    return out


def pair_poses(touches: TouchSet) -> dict:
    """``{frozenset(part names): distinct poses}`` of the touches where both fire: what pins a mount. A press
    held still is recorded as several touches at one pose (:func:`~nao_skin.touch.datasets.pose_groups`);
    thirty such touches at three poses determine a mount no better than three."""
    fired = touches.parts_of_touch()
    groups = pose_groups(touches)
    names = touches.part_names
    out = {}
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            both = fired[:, i] & fired[:, j]
            if np.any(both):
                out[frozenset((names[i], names[j]))] = len(np.unique(groups[both]))
    return out


def too_few(n_touches: int, n_poses: int, need: int) -> str:
    """The words for touches that cannot pin a mount: ``need`` poses at least."""
    at = f" at {n_poses} poses (a press held still is one pose)" if n_poses < n_touches else ""
    return (f"{n_touches} training touch{'' if n_touches == 1 else 'es'}{at}; a mount needs at least {need}"
            f"{' poses' if at else ''}")


def touching_pairs(touches: TouchSet) -> set:
    """Pairs of part names that fire together in at least one touch."""
    return set(pair_counts(touches))


def left_out_pairs(touches: TouchSet, options: "CalibrationOptions") -> list:
    """The pairs too few poses connect to calibrate from (yet): ``[(pair name, touches, poses)]``."""
    poses = pair_poses(touches)
    counts = sorted(pair_counts(touches).items(), key=lambda kv: sorted(kv[0], key=part_rank))
    return [(pair_label(p), n, poses[p]) for p, n in counts
            if poses[p] < options.min_mount_touches]


def pairs_outside_roles(touches: TouchSet, options: "CalibrationOptions", roles: SelfTouch) -> list:
    """Names of the pairs the plan calibrates from (enough poses) that the skin config's ``self_touch`` does
    not name: fitted one from the other, without the plan's order (a config or a recording of another robot?)."""
    named = {frozenset(pair) for pair in roles.pairs()}
    poses = pair_poses(touches)
    return sorted((pair_label(p) for p in pair_counts(touches) if p not in named
                   and poses[p] >= options.min_mount_touches), key=lambda name: [part_rank(n) for n in name.split("+")])


def plan_steps(touches: TouchSet, options: "CalibrationOptions", roles: SelfTouch) -> list:
    """The multi-session plan the thesis found best, restricted to the pairs the data supports.

    ``roles`` (the skin's :class:`~nao_skin.model.skin.SelfTouch`): which parts touch and which are
    touched. A pair with touches at fewer than ``min_mount_touches`` poses is left out (its parts
    stay at their prior unless another pair calibrates them): partial is fine.
    """
    counts = pair_counts(touches)
    if not counts:
        raise TooFewTouches("no touch has two skin parts active together: nothing to calibrate from")
    poses = pair_poses(touches)
    pairs = {p for p in counts if poses[p] >= options.min_mount_touches}
    if not pairs:
        pair = max(counts, key=lambda p: (poses[p], counts[p]))
        need = options.min_mount_touches
        raise TooFewTouches(f"parts {' and '.join(sorted(pair, key=part_rank))} together: "
                            f"{too_few(counts[pair], poses[pair], need)} (about"
                            f" {int(np.ceil(need / (1 - options.test_fraction)))} before the"
                            f" {int(options.test_fraction * 100)} % test split)")
    present = sorted({p for pair in pairs for p in pair}, key=part_rank)
    if options.reference == "simultaneous":
        return [Step(tuple(present), ())]
    steps = []
    calibrated = set()
    for hand in roles.touching:             # hands from the torso (or, lacking it, from the head)
        for body in roles.touched:
            if frozenset((hand, body)) in pairs:
                steps.append(Step((hand,), (body,)))
                calibrated.add(hand)
                break
    for body in roles.touched:              # then torso and head from the calibrated hands
        refs = tuple(h for h in roles.touching if h in calibrated and frozenset((h, body)) in pairs)
        if refs and not any(s.targets == (body,) for s in steps):
            steps.append(Step((body,), refs))
    for pair in sorted(pairs, key=lambda p: sorted(map(part_rank, p))):   # anything else (e.g. two hands):
        # fit the second from the first
        a, b = sorted(pair, key=part_rank)
        if not any(set(s.targets) | set(s.references) >= {a, b} for s in steps):
            steps.append(Step((b,), (a,)))
    return steps
