"""Live calibration's bookkeeping, pure: when an update is due, how far the taxels moved, which parts settled.

The calibrate node recalibrates in the background while touches arrive; these
decide when (every ``every_touches`` new touches, or ``period`` seconds after
the last update if any touch came since) and say, per part, whether more
touches still move it: ``collecting`` (not calibrated yet), ``converging``, or
``done`` (its taxels moved less than ``settle_mm`` in each of the last
``updates`` updates).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nao_skin.model.skin import SkinCalibration, SkinModel

@dataclass
class UpdateSchedule:
    every_touches: int = 25
    period: float = 10.0                  # s
    last_touches: int = 0                 # touches the last update started from
    last_time: float = -np.inf

    def due(self, touches: int, now: float) -> bool:
        new = touches - self.last_touches
        return new > 0 and (new >= self.every_touches or now - self.last_time >= self.period)

    def started(self, touches: int, now: float) -> None:
        self.last_touches, self.last_time = touches, now


def taxel_displacement_mm(skin: SkinModel, before: SkinCalibration, after: SkinCalibration, parts) -> dict:
    """``{part: largest distance one of its taxels moved, mm}`` between two calibrations (chain-end frame)."""
    out = {}
    for name in parts:
        part = skin.parts[name]
        a, _ = part.taxel_positions(before.parts.get(name))
        b, _ = part.taxel_positions(after.parts.get(name))
        d = np.linalg.norm((a - b)[part.present], axis=1)
        out[name] = 1000.0 * float(d.max()) if len(d) else 0.0
    return out


@dataclass
class Settling:
    """Per part: the displacement of each update it was calibrated in; its state from the last few."""

    settle_mm: float = 0.1
    updates: int = 3
    history: dict = field(default_factory=dict)     # part -> [mm per update]

    def add(self, displacement_mm: dict) -> None:
        for part, mm in displacement_mm.items():
            self.history.setdefault(part, []).append(float(mm))

    def states(self, parts) -> dict:
        out = {}
        for part in parts:
            moved = self.history.get(part, [])
            if not moved:
                out[part] = "collecting"
            elif len(moved) >= self.updates and max(moved[-self.updates:]) < self.settle_mm:
                out[part] = "done"
            else:
                out[part] = "converging"
        return out
