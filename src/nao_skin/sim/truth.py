"""Ground truth of the simulator: where the skin really sits (corrections to the nominal layout)."""
from __future__ import annotations

import numpy as np

from nao_skin import se3
from nao_skin.model.skin import PartCorrection, SkinCalibration, SkinModel
from nao_skin.sim.params import SimParams


def random_vectors(rng: np.random.Generator, n: int, magnitude: float) -> np.ndarray:
    """``n`` 3-vectors in uniformly random directions with norms in [magnitude/2, magnitude]."""
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return v * (magnitude * rng.uniform(0.5, 1.0, size=(n, 1)))


def _tilted(axis: np.ndarray, tilt: float, rng: np.random.Generator) -> np.ndarray:
    """``axis`` tilted by ``tilt`` radians towards a random perpendicular direction."""
    perp = np.cross(axis, rng.normal(size=3))
    perp /= np.linalg.norm(perp)
    return np.cos(tilt) * axis + np.sin(tilt) * perp


def hand_mount_truth(skin: SkinModel, part: str, p: SimParams, rng: np.random.Generator) -> np.ndarray:
    """A CAD-style hand mount error: a rotation about (nearly) the forearm axis, plus shifts.

    The hand skin wraps the forearm, whose axis is the y axis of the hand's DH
    frame through its origin. Rotating about that line (not about the mount
    origin, which sits at the taxel centroid off the axis) keeps the skin on
    the hand, as on the real robot where the hands were ~160 deg off the CAD.
    """
    mount = skin.parts[part].mount_nominal
    to_mount = se3.invert(mount)
    axis_point = se3.transform_points(to_mount, np.zeros(3))          # forearm axis, mount coordinates
    axis_dir = se3.rotate_vectors(to_mount, np.array([0.0, 1.0, 0.0]))
    axis_point -= (axis_point @ axis_dir) * axis_dir                   # pivot level with the skin's centre
    axis = _tilted(axis_dir, np.radians(p.hand_mount_axis_tilt_deg), rng)
    sign = rng.choice([-1.0, 1.0])
    rot = se3.rotvec_to_matrix(axis * np.radians(p.hand_mount_rotation_deg) * sign)
    t = axis_point - rot @ axis_point                                  # rotation about the axis line
    t += axis_dir * p.hand_mount_shift * rng.choice([-1.0, 1.0])
    radial = np.cross(axis_dir, rng.normal(size=3))
    t += radial / np.linalg.norm(radial) * p.hand_mount_radial
    t += np.asarray(p.hand_mount_offset, dtype=float)
    return np.r_[t, se3.matrix_to_rotvec(rot)]


def draw_truth(skin: SkinModel, parts, p: SimParams, rng: np.random.Generator) -> SkinCalibration:
    """True corrections of the given parts (others stay nominal), drawn from the magnitudes of ``p``."""
    calib = skin.zero_calibration()
    for name in parts:
        part = skin.parts[name]
        if name in skin.self_touch.touching:
            mount = hand_mount_truth(skin, name, p, rng)
        else:
            mount = np.r_[random_vectors(rng, 1, p.body_mount_translation)[0],
                          random_vectors(rng, 1, p.body_mount_rotation)[0]]
        n_p, n_t = len(part.patch_ids), len(part.triangle_ids)
        patches = np.hstack([random_vectors(rng, n_p, p.patch_translation),
                             random_vectors(rng, n_p, p.patch_rotation)])
        triangles = np.hstack([random_vectors(rng, n_t, p.triangle_translation),
                               random_vectors(rng, n_t, p.triangle_rotation)])
        calib.parts[name] = PartCorrection(mount, patches, triangles)
    return calib


def draw_kinematics(skin: SkinModel, p: SimParams, rng: np.random.Generator) -> dict:
    """The true robot's kinematic corrections of the config (:meth:`RobotModel.corrected`): an angle offset
    per joint of the chains the skin hangs off (uniform within ``joint_offset_deg``), then ``link_errors``."""
    from nao_skin.errors import ConfigError

    out = {}
    if p.joint_offset_deg > 0:
        joints = skin.robot.kinematic_names(sorted({part.chain for part in skin.parts.values()
                                                     if part.chain is not None}))
        joints = [j for j in joints if j in skin.robot.joint_index]
        values = rng.uniform(-1.0, 1.0, size=len(joints)) * np.radians(p.joint_offset_deg)
        out.update(zip(joints, values.tolist()))
    for name, value in p.link_errors.items():
        if name not in skin.robot.links:
            raise ConfigError(f"simulation link_errors: '{name}' is not a named link of {skin.robot.source}"
                              f" (links: {', '.join(skin.robot.links) or 'none'})")
        out[str(name)] = float(value)
    return {k: v for k, v in out.items() if v != 0.0}
