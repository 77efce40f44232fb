"""A recorded or simulated TouchSet played back as live streams (pure: time is an argument).

Each touch becomes one *press*: the arm moves (joints linearly interpolated)
from the previous touch's angles to this touch's, holds them ``hold`` s
before, during and after the press, and for ``press`` s every skin sample
shows the touch's activations (between presses all parts are empty, i.e.
released). Presses start ``period`` s apart (never overlapping), so a live
event detector fed these streams finds each touch exactly once, with exactly
its joint angles.
"""
from __future__ import annotations

import numpy as np

from nao_skin.errors import ConfigError
from nao_skin.formats.bag import touch_parts
from nao_skin.model.skin import SkinModel
from nao_skin.touch.touches import TouchSet


def check_timing(period: float, press: float, hold: float, where: str = "playback") -> None:
    """Presses that never overlap: ``press + 2 hold < period`` (ConfigError naming ``where`` otherwise)."""
    if not (0 < press and 0 <= hold and press + 2 * hold < period):
        raise ConfigError(f"{where}: press_duration {press:g} s + 2 x hold {hold:g} s must be shorter than"
                          f" touch_period {period:g} s (and press_duration > 0)")


class Playback:
    def __init__(self, touches: TouchSet, skin: SkinModel, period: float = 1.0, press: float = 0.3,
                 hold: float = 0.1, lead_in: float = 0.5):
        check_timing(period, press, hold)
        self.touches = touches
        self.skin = skin
        self.joint_names = list(touches.joint_names)
        self.part_names = [p for p in touches.part_names if p in skin.parts]
        n = touches.n_touches
        self.start = lead_in + hold + period * np.arange(n)
        self.end = self.start + press
        self.hold = hold
        self.joints = touches.joints
        self.duration = (self.end[-1] + hold + lead_in) if n else lead_in
        # per touch, what each touching part's skin sends while pressed: prepared once, playing is then lookups
        self.samples: list = [{part.name: (taxels, contacts) for part, taxels, contacts in parts}
                              for parts in touch_parts(touches, skin)]

    def __len__(self) -> int:
        return self.touches.n_touches

    def touch_at(self, t: float) -> int:
        """Index of the touch pressed at ``t`` (time since the start), or -1."""
        k = int(np.searchsorted(self.start, t, side="right")) - 1
        return k if k >= 0 and t < self.end[k] else -1

    def joints_at(self, t: float) -> np.ndarray:
        """Joint angles at ``t``: held around each press, linear in between."""
        n = len(self)
        if n == 0:
            return np.zeros(len(self.joint_names))
        k = int(np.searchsorted(self.start - self.hold, t, side="right"))   # touches whose hold has begun
        if k == 0:
            return self.joints[0]
        prev = k - 1
        if t <= self.end[prev] + self.hold or k == n:
            return self.joints[prev]
        t0, t1 = self.end[prev] + self.hold, self.start[k] - self.hold
        w = (t - t0) / (t1 - t0)
        return self.joints[prev] + (self.joints[k] - self.joints[prev]) * w
