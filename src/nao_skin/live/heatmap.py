"""Activation coverage of the skin in a session: counts per taxel and their colours.

The thesis collected data watching which taxels had been touched at least
once (§3.3.3); here each taxel counts how many times it has been *activated*
(a press starts: off in the previous sample of its part, on in this one), so
a long press counts once and the map shows where more touches are needed.

Colours: never-activated taxels grey, activated ones on a perceptually
ordered scale (viridis-like, dark blue -> yellow) of ``log(1 + count)``
relative to the session's maximum, currently pressed taxels a highlight
colour. Colours are indices into a small fixed palette so that a ROS adapter
can reuse one ColorRGBA object per palette entry.
"""
from __future__ import annotations

import numpy as np

#: anchor colours of the scale (viridis at 0, 0.25, 0.5, 0.75, 1)
_SCALE_ANCHORS = np.array([[0.267, 0.005, 0.329], [0.229, 0.322, 0.546], [0.128, 0.567, 0.551],
                           [0.369, 0.789, 0.383], [0.993, 0.906, 0.144]])
SCALE_LEVELS = 64
NEVER_COLOUR = (0.55, 0.55, 0.55, 0.6)          # grey, a little transparent: still to be touched
PRESSED_COLOUR = (1.0, 0.1, 0.1, 1.0)           # red: touched right now
NEVER_INDEX = SCALE_LEVELS
PRESSED_INDEX = SCALE_LEVELS + 1


def palette() -> np.ndarray:
    """(SCALE_LEVELS + 2, 4) RGBA: the scale, then the never-touched and the pressed colours."""
    x = np.linspace(0.0, 1.0, SCALE_LEVELS)
    at = np.linspace(0.0, 1.0, len(_SCALE_ANCHORS))
    rgb = np.stack([np.interp(x, at, _SCALE_ANCHORS[:, c]) for c in range(3)], axis=1)
    scale = np.concatenate([rgb, np.ones((SCALE_LEVELS, 1))], axis=1)
    return np.vstack([scale, NEVER_COLOUR, PRESSED_COLOUR])


def colour_index(counts: np.ndarray, pressed: np.ndarray, max_count: int) -> np.ndarray:
    """Palette index per taxel: pressed first, then grey for 0, then the log scale of the count."""
    counts = np.asarray(counts)
    level = np.log1p(counts) / np.log1p(max(int(max_count), 1))
    idx = np.clip(np.rint(level * (SCALE_LEVELS - 1)), 0, SCALE_LEVELS - 1).astype(int)
    idx = np.where(counts > 0, idx, NEVER_INDEX)
    return np.where(pressed, PRESSED_INDEX, idx)


SILENT_RELEASE_S = 0.5    # a part whose skin stream is silent this long counts as released (it streams at ~50 Hz)


class ActivationCounts:
    """Per part: how often each slot has been activated, and what is pressed now."""

    def __init__(self, slots_per_part: dict):
        self.counts = {p: np.zeros(n, dtype=np.int64) for p, n in slots_per_part.items()}
        self.pressed = {p: np.zeros(n, dtype=bool) for p, n in slots_per_part.items()}
        self.heard = {p: -np.inf for p in slots_per_part}      # when each part's last sample came (s)

    def update(self, part: str, slots, when: float = 0.0) -> None:
        """One skin sample of ``part`` at time ``when`` (s): ``slots`` are active now (empty = released)."""
        self.heard[part] = when
        now = np.zeros_like(self.pressed[part])
        slots = np.asarray(slots, dtype=np.int64)
        slots = slots[(slots >= 0) & (slots < len(now))]
        now[slots] = True
        started = now & ~self.pressed[part]
        if started.any() or (now != self.pressed[part]).any():
            self.counts[part] += started
            self.pressed[part] = now

    def add_touches(self, touches) -> None:
        """Touches recorded before (an earlier sitting's bag): each activation one press of its taxel."""
        for index, name in enumerate(touches.part_names):
            counts = self.counts.get(name)
            if counts is None:
                continue
            slots = touches.act_slot[touches.act_part == index]
            np.add.at(counts, slots[(slots >= 0) & (slots < len(counts))], 1)

    def release_silent(self, when: float, gap: float = SILENT_RELEASE_S) -> None:
        """Parts silent for more than ``gap`` s at ``when`` are released: a skin stream pauses only when its
        source is gone (skinManager stopped, a bridge killed), which sends no released sample."""
        for part, heard in self.heard.items():
            if when - heard > gap and self.pressed[part].any():
                self.pressed[part][:] = False

    def max_count(self) -> int:
        return max((int(c.max()) for c in self.counts.values() if len(c)), default=0)

    def colour_indices(self, part: str) -> np.ndarray:
        return colour_index(self.counts[part], self.pressed[part], self.max_count())

    def coverage(self, part: str, present: np.ndarray) -> float:
        """Share of the part's present taxels activated at least once."""
        present = np.asarray(present, dtype=bool)
        return float((self.counts[part][present] > 0).sum() / max(present.sum(), 1))


def triangle_slots(part) -> list:
    """``[(triangle id, slots)]`` of a :class:`~nao_skin.skin.SkinPart`: the taxels of each triangle frame."""
    slots = part.slots
    rows = part.slot_triangle[slots]
    return [(int(tid), slots[rows == r]) for r, tid in enumerate(part.triangle_ids)]


GUIDANCE_COLOUR = (1.0, 0.0, 1.0, 1.0)          # magenta: on neither the scale, the grey nor the red


def triangle_outline(part, triangle_id: int, lift: float = 0.002) -> np.ndarray:
    """(K + 1, 3) closed outline around one triangle's taxels in the triangle's own frame, ``lift`` m above them
    (its x-y hull: taxel centres lie in the frame's x-y plane), so a marker drawn with it follows the frame."""
    from scipy.spatial import ConvexHull

    slots = dict(triangle_slots(part))[int(triangle_id)]
    xy = part.taxel_local[slots][:, :2]
    centre = xy.mean(axis=0)
    ring = xy[ConvexHull(xy).vertices]              # counter-clockwise
    ring = centre + 1.25 * (ring - centre)          # a little outside the taxel centres
    ring = np.vstack([ring, ring[:1]])
    return np.column_stack([ring, np.full(len(ring), lift)])


FINGERTIP_COLOUR = (1.0, 0.55, 0.0, 0.8)        # orange: the fingertip pressing, beside the skin's scale


def fingertip_spheres(skin, scenes, calibration=None) -> list:
    """``[(fingertip, frame, centre (3,), radius)]`` of the fingertips of the fingertip ``scenes`` (``(fingertip,
    part)``), each once: its contact sphere under ``calibration`` (None: the robot config's) in its chain's end
    frame, where TF (the joint states through robot_state_publisher) carries it with the arm, so a marker there
    shows where the fingertip presses without the node following the joints itself."""
    robot = skin.robot
    calibration = calibration if calibration is not None else skin.zero_calibration()
    out = []
    for tip in dict.fromkeys(tip for tip, _ in scenes):
        centre, radius = calibration.fingertip_sphere(robot, tip)
        out.append((tip, robot.chains[robot.fingertip(tip).chain].end_frame, np.asarray(centre, float), float(radius)))
    return out
