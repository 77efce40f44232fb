"""SE(3) as plain functions on numpy arrays.

Poses are 4x4 homogeneous matrices (batched as ``(..., 4, 4)``); small pose
corrections are 6-vectors ``[tx, ty, tz, rx, ry, rz]``: a translation in
metres and a rotation vector in radians (axis * angle), never Euler angles.
A correction ``delta`` applied to a frame ``T`` gives ``T @ pose_matrix(delta)``:
it is expressed in the frame's own axes, so bounds on its components mean
"along / about this frame's axes".
"""
from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation

_EPS = 1e-12


def vector_norms(v: np.ndarray) -> np.ndarray:
    """Euclidean norms of (N, 3) vectors (2-3x faster than np.linalg.norm(axis=1) on the hot paths)."""
    return np.sqrt(np.einsum("ij,ij->i", v, v))


def skew(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrices ``[v]x`` for ``(..., 3)`` vectors."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def so3_series(rotvec: np.ndarray):
    """``sin(t)/t``, ``(1 - cos t)/t^2``, ``(t - sin t)/t^3`` for ``t = |rotvec|``, shaped ``(..., 1, 1)``.

    The coefficients of Rodrigues' formula and of the SO(3) Jacobians; Taylor
    terms near zero keep them exact where the closed forms divide by ~0.
    """
    rotvec = np.asarray(rotvec, dtype=float)
    theta2 = np.sum(rotvec * rotvec, axis=-1)[..., None, None]
    small = theta2 < 1e-8
    t = np.where(small, 1.0, np.sqrt(theta2))
    sin_t = np.sin(t)
    a = np.where(small, 1.0 - theta2 / 6.0, sin_t / t)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(t)) / (t * t))
    c = np.where(small, 1.0 / 6.0 - theta2 / 120.0, (t - sin_t) / (t * t * t))
    return a, b, c


def rotvec_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues' formula, batched: I + a [r]x + b [r]x^2."""
    a, b, _ = so3_series(rotvec)
    k = skew(rotvec)
    return np.broadcast_to(np.eye(3), k.shape) + a * k + b * (k @ k)


def right_jacobian(rotvec: np.ndarray) -> np.ndarray:
    """Right Jacobian of SO(3): R(r + d) = R(r) Exp(J_r(r) d) to first order; I - b [r]x + c [r]x^2."""
    _, b, c = so3_series(rotvec)
    k = skew(rotvec)
    return np.broadcast_to(np.eye(3), k.shape) - b * k + c * (k @ k)


def matrix_to_rotvec(rot: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotvec_to_matrix`, batched, stable at 0 and pi."""
    rot = np.asarray(rot, dtype=float)
    # Quaternion route avoids the 1/sin(theta) blow-up near pi.
    quat = matrix_to_quaternion(rot)  # x, y, z, w with w >= 0
    xyz = quat[..., :3]
    w = quat[..., 3]
    s = np.linalg.norm(xyz, axis=-1)
    angle = 2.0 * np.arctan2(s, w)
    small = s < 1e-10
    scale = np.where(small, 2.0 / np.where(w == 0, 1.0, w), angle / np.where(small, 1.0, s))
    return xyz * scale[..., None]


def matrix_to_quaternion(rot: np.ndarray) -> np.ndarray:
    """Rotation matrices to unit quaternions ``(x, y, z, w)`` (the order of ROS and scipy) with ``w >= 0``.

    Not scipy's ``Rotation.from_matrix``: :func:`matrix_to_rotvec`, and through
    it the calibration's first guess, depend on the rounding of this formula.
    The other way round, use ``scipy.spatial.transform.Rotation.from_quat``.
    """
    rot = np.asarray(rot, dtype=float)
    m = rot.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    # Shepperd's method: pick the largest of w, x, y, z to divide by.
    cand = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    pick = np.argmax(cand, axis=1)
    q = np.empty((m.shape[0], 4))
    for case in range(4):
        sel = pick == case
        if not np.any(sel):
            continue
        r = m[sel]
        if case == 0:
            s = np.sqrt(1.0 + cand[sel, 0]) * 2.0
            q[sel] = np.stack([(r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s,
                               (r[:, 1, 0] - r[:, 0, 1]) / s, 0.25 * s], axis=1)
        elif case == 1:
            s = np.sqrt(1.0 + r[:, 0, 0] - r[:, 1, 1] - r[:, 2, 2]) * 2.0
            q[sel] = np.stack([0.25 * s, (r[:, 0, 1] + r[:, 1, 0]) / s,
                               (r[:, 0, 2] + r[:, 2, 0]) / s, (r[:, 2, 1] - r[:, 1, 2]) / s], axis=1)
        elif case == 2:
            s = np.sqrt(1.0 + r[:, 1, 1] - r[:, 0, 0] - r[:, 2, 2]) * 2.0
            q[sel] = np.stack([(r[:, 0, 1] + r[:, 1, 0]) / s, 0.25 * s,
                               (r[:, 1, 2] + r[:, 2, 1]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s], axis=1)
        else:
            s = np.sqrt(1.0 + r[:, 2, 2] - r[:, 0, 0] - r[:, 1, 1]) * 2.0
            q[sel] = np.stack([(r[:, 0, 2] + r[:, 2, 0]) / s, (r[:, 1, 2] + r[:, 2, 1]) / s,
                               0.25 * s, (r[:, 1, 0] - r[:, 0, 1]) / s], axis=1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1.0
    return q.reshape(rot.shape[:-2] + (4,))


def pose_matrix(delta: np.ndarray) -> np.ndarray:
    """6-vector(s) ``[t, rotvec]`` to homogeneous matrices."""
    delta = np.asarray(delta, dtype=float)
    out = np.zeros(delta.shape[:-1] + (4, 4))
    out[..., :3, :3] = rotvec_to_matrix(delta[..., 3:6])
    out[..., :3, 3] = delta[..., :3]
    out[..., 3, 3] = 1.0
    return out


def pose_vector(mat: np.ndarray) -> np.ndarray:
    """Homogeneous matrices to 6-vectors ``[t, rotvec]``."""
    mat = np.asarray(mat, dtype=float)
    return np.concatenate([mat[..., :3, 3], matrix_to_rotvec(mat[..., :3, :3])], axis=-1)


def invert(mat: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms, batched (R^T, -R^T t)."""
    mat = np.asarray(mat, dtype=float)
    out = np.zeros_like(mat)
    rt = np.swapaxes(mat[..., :3, :3], -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rt, mat[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def transform_points(mat: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply ``(..., 4, 4)`` transforms to ``(..., 3)`` points (broadcasting)."""
    mat = np.asarray(mat, dtype=float)
    points = np.asarray(points, dtype=float)
    return np.einsum("...ij,...j->...i", mat[..., :3, :3], points) + mat[..., :3, 3]


def rotate_vectors(mat: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """Apply only the rotation part of ``(..., 4, 4)`` transforms."""
    return np.einsum("...ij,...j->...i", np.asarray(mat, dtype=float)[..., :3, :3], vectors)


def split_coordinates(mat: np.ndarray) -> tuple:
    """``(R, t)`` of ``(n, 4, 4)`` transforms stored coordinate first, ``(3, 3, n)`` and ``(3, n)``: the
    layout :func:`transform_coordinates` reads. Always new arrays (never views of ``mat``)."""
    mat = np.asarray(mat, dtype=float)
    return np.array(mat[:, :3, :3].transpose(1, 2, 0), order="C"), np.array(mat[:, :3, 3].T, order="C")


def transform_coordinates(rot: np.ndarray, points: np.ndarray, trans: np.ndarray | None = None) -> np.ndarray:
    """``R_k p_k + t_k`` for n points stored coordinate first: ``rot`` (3, 3, n), ``points`` and ``trans``
    (3, n), the result (3, n); without ``trans`` a rotation of vectors.

    The same as :func:`transform_points` on ``(n, 4, 4)`` and ``(n, 3)``, as nine products of contiguous
    rows: about twice as fast as the einsum where the calibration transforms every term of every touch.
    """
    out = np.empty_like(points) if trans is None else np.array(trans, dtype=float)
    for i in range(3):
        row = rot[i, 0] * points[0]
        row += rot[i, 1] * points[1]
        row += rot[i, 2] * points[2]
        if trans is None:
            out[i] = row
        else:
            out[i] += row
    return out


def rpy_from_matrix(rot: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed axes X, Y, Z: R = Rz(y) Ry(p) Rx(r)), scipy's extrinsic ``"xyz"``.

    Only for writing URDF ``<origin rpy=...>``; computation never uses Euler angles. At pitch +-pi/2
    (gimbal lock) scipy sets yaw to 0 and puts the whole turn about Z into roll: the same rotation.
    """
    rot = np.asarray(rot, dtype=float)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock detected")
        rpy = Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_euler("xyz")
    return rpy.reshape(rot.shape[:-2] + (3,))


def matrix_from_rpy(rpy: np.ndarray) -> np.ndarray:
    """URDF roll-pitch-yaw to rotation matrices (R = Rz(yaw) Ry(pitch) Rx(roll)), scipy's extrinsic ``"xyz"``."""
    rpy = np.asarray(rpy, dtype=float)
    return Rotation.from_euler("xyz", rpy.reshape(-1, 3)).as_matrix().reshape(rpy.shape[:-1] + (3, 3))


def rigid_fit(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None,
              source_dirs: np.ndarray | None = None, target_dirs: np.ndarray | None = None,
              dir_weight: float = 0.0) -> np.ndarray:
    """Closed-form least-squares rigid transform T with ``T * source ~ target``.

    Kabsch/Umeyama without scale; ``source`` and ``target`` are ``(N, 3)``.
    Used as the first guess that makes a 160-degree mount error reachable.
    Optional unit direction pairs (``R @ source_dirs ~ target_dirs``, e.g.
    surface normals) enter the rotation with ``dir_weight`` (m^2 per pair, so
    that they compare with the points' spread): they fix the rotation about
    an axis that points alone leave free, e.g. when all points lie on a line.
    """
    src = np.asarray(source, dtype=float)
    dst = np.asarray(target, dtype=float)
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=float)
    w = w / max(w.sum(), _EPS)
    mu_s = w @ src
    mu_d = w @ dst
    cov = (dst - mu_d).T @ ((src - mu_s) * w[:, None])
    if dir_weight > 0 and source_dirs is not None and target_dirs is not None:
        cov = cov + dir_weight * (np.asarray(target_dirs, float).T @ (np.asarray(source_dirs, float) * w[:, None]))
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt))
    rot = u @ np.diag([1.0, 1.0, d]) @ vt
    out = np.eye(4)
    out[:3, :3] = rot
    out[:3, 3] = mu_d - rot @ mu_s
    return out
