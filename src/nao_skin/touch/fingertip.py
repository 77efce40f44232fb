"""Whose press it was, live: the fingertip of the scene that is where a part that fired alone was touched.

The recorder sees one part fire; the joint angles say where every fingertip of the robot is. Under the
calibration the node holds, the fired taxels fall into contacts (neighbours, as skinManager groups them), each
centred on the skin; a fingertip pressed the part when its contact sphere is within ``gate`` of one contact's
centre. An experimenter's hand fires the part where no fingertip is (centimetres off; pressing at the same time,
it is another contact); the nearest fingertip wins when two are near.
"""
from __future__ import annotations

import numpy as np

from nao_skin import se3
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch import DEFAULT_FINGERTIP_GATE, DEFAULT_MAX_NEIGHBOR_DIST
from nao_skin.touch.contacts import cluster_labels



class FingertipJudge:
    """``judge(part, slots, q) -> fingertip or None`` for :class:`~nao_skin.touch.events.EventDetector`."""

    def __init__(self, skin: SkinModel, pairs, calibration: SkinCalibration | None = None, gate: float = DEFAULT_FINGERTIP_GATE):
        """``pairs``: the ``(fingertip, part)`` scenes of the session (of the skin config's ``fingertip_touch``):
        only their fingertips are judged, and only on their parts."""
        calibration = calibration or skin.zero_calibration()
        self.robot = skin.with_kinematics(calibration).robot
        self.gate = float(gate)
        self.pairs = tuple(pairs)
        self._tips: dict = {}            # part -> [(fingertip, chain, centre, radius)]
        for tip, part in self.pairs:
            centre, radius = calibration.fingertip_sphere(skin.robot, tip)
            self._tips.setdefault(part, []).append((tip, self.robot.fingertip(tip).chain, centre, radius))
        self._taxels = {name: skin.parts[name].taxel_positions(calibration.parts.get(name), normals=False)
                        for name in self._tips}
        self._chains = {name: skin.parts[name].chain for name in self._tips}

    def distances(self, part: str, slots, q: np.ndarray) -> dict:
        """``{fingertip: m}``: how far each fingertip that presses ``part`` is from the fired taxels' centre, at the
        joint angles ``q`` (the robot config's order)."""
        if part not in self._tips or len(slots) == 0:
            return {}
        q = np.asarray(q, dtype=float)[None]
        local = self._taxels[part][list(slots)]
        labels = cluster_labels(local, np.zeros(len(local), int), DEFAULT_MAX_NEIGHBOR_DIST)
        centres = np.stack([local[labels == k].mean(axis=0) for k in range(labels.max() + 1)])
        contacts = se3.transform_points(self.robot.fk(self._chains[part], q)[0], centres)
        return {tip: float(np.min(np.linalg.norm(contacts - se3.transform_points(self.robot.fk(chain, q)[0], centre),
                                                 axis=1)) - radius)
                for tip, chain, centre, radius in self._tips[part]}

    def __call__(self, part: str, slots, q: np.ndarray) -> str | None:
        found = {tip: d for tip, d in self.distances(part, slots, q).items() if np.isfinite(d) and d <= self.gate}
        return min(found, key=found.get) if found else None
