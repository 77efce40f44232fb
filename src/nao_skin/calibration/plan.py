"""Which parts to fit against which: the thesis' multi-session plan, from the pairs in the data."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from nao_skin.errors import DataError
from nao_skin.model.skin import PART_NAMES
from nao_skin.touch.touches import TouchSet

if TYPE_CHECKING:   # only for annotations: calibrate imports this module
    from nao_skin.calibration.options import CalibrationOptions

HANDS = ("r_hand", "l_hand")
REFERENCE_BODY = ("torso", "head")   # parts the hands touch; fitted from the calibrated hands


def part_rank(name: str) -> int:
    """Order of parts everywhere: r_hand, l_hand, torso, head, then others."""
    return PART_NAMES.index(name) if name in PART_NAMES else 99


@dataclass
class Step:
    """Fit ``targets`` against touches with ``references`` (fixed unless simultaneous)."""

    targets: tuple
    references: tuple

    @property
    def name(self) -> str:
        return "+".join(self.targets) + (" from " + "+".join(self.references) if self.references else "")

def touching_pairs(touches: TouchSet) -> set:
    """Pairs of part names that fire together in at least one touch."""
    fired = touches.parts_of_touch()
    out = set()
    names = touches.part_names
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if np.any(fired[:, i] & fired[:, j]):
                out.add(frozenset((names[i], names[j])))
    return out

def plan_steps(touches: TouchSet, options: "CalibrationOptions") -> list:
    """The multi-session plan the thesis found best, restricted to the pairs in the data."""
    pairs = touching_pairs(touches)
    if not pairs:
        raise DataError("no touch has two skin parts active together: nothing to calibrate from")
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
    for pair in pairs:                      # anything else (e.g. two hands): fit the second from the first
        a, b = sorted(pair, key=part_rank)
        if not any(set(s.targets) | set(s.references) >= {a, b} for s in steps):
            steps.append(Step((b,), (a,)))
    return steps
