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

from dataclasses import dataclass

import numpy as np

from nao_skin.errors import ConfigError
from nao_skin.model.skin import SkinModel
from nao_skin.touch.contacts import contact_geometry
from nao_skin.touch.touches import TouchSet


@dataclass
class PartSample:
    """One part's skin data during one press."""

    slots: np.ndarray          # (n,) activated slots
    positions: np.ndarray      # (n, 3) nominal positions (what a skin driver sends)
    pressures: np.ndarray      # (n,)
    contact_ids: np.ndarray    # (n,) skinManager contact id of each taxel
    contact_list: np.ndarray   # (k,) ids of the part's contacts with an id (>= 0)
    cop: np.ndarray            # (k, 3) recorded COPs
    normal: np.ndarray         # (k, 3)
    geo_center: np.ndarray     # (k, 3)
    pressure: np.ndarray       # (k,) mean pressure of each contact


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
        geom = contact_geometry(touches, skin, None)
        act_part = touches.act_part
        act_touch = touches.act_touch
        act_cid = touches.contact_id[touches.act_contact]
        # per touch and part, prepared once: playing is then only lookups
        self.samples: list = []
        a_order = np.lexsort((act_part, act_touch))
        a_bounds = np.searchsorted(act_touch[a_order], np.arange(n + 1))
        c_order = np.lexsort((touches.contact_part, touches.contact_touch))
        c_bounds = np.searchsorted(touches.contact_touch[c_order], np.arange(n + 1))
        for t in range(n):
            acts = a_order[a_bounds[t]:a_bounds[t + 1]]
            cons = c_order[c_bounds[t]:c_bounds[t + 1]]
            per_part = {}
            for p in np.unique(act_part[acts]):
                name = touches.part_names[p]
                if name not in skin.parts:
                    continue
                a = acts[act_part[acts] == p]
                c = cons[(touches.contact_part[cons] == p) & (touches.contact_id[cons] >= 0)]
                slots = touches.act_slot[a]
                c_pressure = np.array([np.nanmean(touches.act_pressure[touches.act_contact == ci])
                                       if np.any(np.isfinite(touches.act_pressure[touches.act_contact == ci]))
                                       else np.nan for ci in c])
                per_part[name] = PartSample(slots, skin.parts[name].positions[slots], touches.act_pressure[a],
                                            act_cid[a], touches.contact_id[c], touches.contact_cop[c],
                                            geom.normal[c], geom.geo_center[c], c_pressure)
            self.samples.append(per_part)

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
