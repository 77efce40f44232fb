"""Which parts to fit against which: the thesis' multi-session plan, from the pairs in the data."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from nao_skin.errors import TooFewTouches
from nao_skin.model.skin import part_rank
from nao_skin.touch.touches import TouchSet

if TYPE_CHECKING:   # only for annotations: calibrate imports this module
    from nao_skin.calibration.options import CalibrationOptions

HANDS = ("r_hand", "l_hand")
REFERENCE_BODY = ("torso", "head")   # parts the hands touch; fitted from the calibrated hands


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


def touching_pairs(touches: TouchSet) -> set:
    """Pairs of part names that fire together in at least one touch."""
    return set(pair_counts(touches))


def left_out_pairs(touches: TouchSet, options: "CalibrationOptions") -> list:
    """The pairs too few touches connect to calibrate from (yet): ``[(pair name, touches)]``."""
    return [("+".join(sorted(p, key=part_rank)), n) for p, n in sorted(pair_counts(touches).items(),
                                                                      key=lambda kv: sorted(kv[0], key=part_rank))
            if n < options.min_mount_touches]


def plan_steps(touches: TouchSet, options: "CalibrationOptions") -> list:
    """The multi-session plan the thesis found best, restricted to the pairs the data supports.

    A pair with fewer than ``min_mount_touches`` touches is left out (its parts
    stay at their prior unless another pair calibrates them): partial is fine.
    """
    counts = pair_counts(touches)
    if not counts:
        raise TooFewTouches("no touch has two skin parts active together: nothing to calibrate from")
    pairs = {p for p, n in counts.items() if n >= options.min_mount_touches}
    if not pairs:
        pair, n = max(counts.items(), key=lambda kv: kv[1])
        need = options.min_mount_touches
        raise TooFewTouches(f"parts {' and '.join(sorted(pair, key=part_rank))}: {n} training touches together;"
                        f" calibrating a mount needs at least {need} (about"
                        f" {int(np.ceil(need / (1 - options.test_fraction)))} touches before the"
                        f" {int(options.test_fraction * 100)} % test split)")
    present = sorted({p for pair in pairs for p in pair}, key=part_rank)
    if options.reference == "simultaneous":
        return [Step(tuple(present), ())]
    steps = []
    calibrated = set()
    for hand in HANDS:                      # hands from the torso (or, lacking it, from the head)
        for body in REFERENCE_BODY:
            if frozenset((hand, body)) in pairs:
                steps.append(Step((hand,), (body,)))
                calibrated.add(hand)
                break
    for body in REFERENCE_BODY:             # then torso and head from the calibrated hands
        refs = tuple(h for h in HANDS if h in calibrated and frozenset((h, body)) in pairs)
        if refs and not any(s.targets == (body,) for s in steps):
            steps.append(Step((body,), refs))
    for pair in sorted(pairs, key=lambda p: sorted(map(part_rank, p))):   # anything else (e.g. two hands):
        # fit the second from the first
        a, b = sorted(pair, key=part_rank)
        if not any(set(s.targets) | set(s.references) >= {a, b} for s in steps):
            steps.append(Step((b,), (a,)))
    return steps
