"""The unknowns of a solve as one vector: a 6-vector correction ``[t, rotvec]`` per mount, patch and triangle
of every part being calibrated, the fabric thickness, the kinematic corrections a stage estimates
(joint-angle offsets and link lengths of the robot config, :meth:`RobotModel.corrected`) and the corrections of
the fingertips' contact spheres (centre x, y, z and radius, m)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nao_skin.calibration.kinds import LEVELS  # noqa: F401 - where the engine's modules read it
from nao_skin.model.skin import SkinCalibration, SkinModel

KINEMATICS = "kinematics"   # the level of a stage that frees kinematic corrections

COMPONENTS = ("tx", "ty", "tz", "rx", "ry", "rz")   # of a 6-vector correction, as reports name them
FINGERTIP_COMPONENTS = ("x", "y", "z", "radius")    # of a fingertip sphere's correction
FINGERTIPS = "fingertips"   # how a fingertip's columns are named (fingertips/<name>/<component>)


@dataclass
class ParameterLayout:
    """Column layout of the correction vector over the parts being calibrated.

    Per part: mount (6), then its patches (6 each), then its triangles (6 each),
    in the order of ``SkinPart.patch_ids`` / ``triangle_ids``.
    """

    skin: SkinModel
    part_names: tuple
    kinematic_names: tuple = ()                   # joint / link names of the robot config, after the fabric
    fingertip_names: tuple = ()                   # fingertips of the robot config, 4 columns each, after those
    offsets: dict = field(default_factory=dict)   # part -> (mount col, patch col, triangle col, end)

    def __post_init__(self):
        col = 0
        for name in self.part_names:
            part = self.skin.parts[name]
            m = col
            p = m + 6
            t = p + 6 * len(part.patch_ids)
            end = t + 6 * len(part.triangle_ids)
            self.offsets[name] = (m, p, t, end)
            col = end
        # last column: the fabric thickness over the taxels (m), shared by every part
        self.fabric_col = col
        self.kinematic_cols = {name: col + 1 + i for i, name in enumerate(self.kinematic_names)}
        first = col + 1 + len(self.kinematic_names)
        self.fingertip_cols = {name: first + 4 * i for i, name in enumerate(self.fingertip_names)}
        self.size = first + 4 * len(self.fingertip_names)

    def block_columns(self, part: str, level: str, rows: np.ndarray) -> np.ndarray:
        """First column of each block (``rows`` index patches/triangles; ignored for mounts)."""
        m, p, t, _ = self.offsets[part]
        if level == "mount":
            return np.full(np.shape(rows), m)
        return (p if level == "patch" else t) + 6 * np.asarray(rows)

    def describe(self, col: int) -> str:
        if col == self.fabric_col:
            return "fabric_thickness"
        for name, first in self.fingertip_cols.items():
            if first <= col < first + 4:
                return f"{FINGERTIPS}/{name}/{FINGERTIP_COMPONENTS[col - first]}"
        if col > self.fabric_col:
            return f"{KINEMATICS}/{self.kinematic_names[col - self.fabric_col - 1]}"
        for name, (m, p, t, end) in self.offsets.items():
            if m <= col < end:
                part = self.skin.parts[name]
                comp = COMPONENTS[(col - m) % 6]
                if col < p:
                    return f"{name}/mount/{comp}"
                if col < t:
                    return f"{name}/patch_{int(part.patch_ids[(col - p) // 6])}/{comp}"
                return f"{name}/triangle_{int(part.triangle_ids[(col - t) // 6])}/{comp}"
        raise IndexError(col)

    def to_vector(self, calib: SkinCalibration, fabric: float = 0.0) -> np.ndarray:
        x = np.zeros(self.size)
        x[self.fabric_col] = fabric
        for name, col in self.kinematic_cols.items():
            x[col] = calib.kinematics.get(name, 0.0)
        for name, col in self.fingertip_cols.items():
            x[col:col + 4] = calib.fingertips.get(name, np.zeros(4))
        for name, (m, p, t, end) in self.offsets.items():
            corr = calib.parts[name]
            x[m:p] = corr.mount
            x[p:t] = corr.patches.ravel()
            x[t:end] = corr.triangles.ravel()
        return x

    def to_calibration(self, x: np.ndarray, base: SkinCalibration) -> SkinCalibration:
        out = base.copy()
        for name, (m, p, t, end) in self.offsets.items():
            corr = out.parts[name]
            corr.mount = x[m:p].copy()
            corr.patches = x[p:t].reshape(-1, 6).copy()
            corr.triangles = x[t:end].reshape(-1, 6).copy()
        for name, col in self.kinematic_cols.items():
            out.kinematics[name] = float(x[col])
        for name, col in self.fingertip_cols.items():
            out.fingertips[name] = x[col:col + 4].copy()
        return out
