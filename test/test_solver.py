"""Solver core: analytic Jacobian equals finite differences (point and normal rows); a known correction is recovered."""
import warnings

import numpy as np
import pytest

from nao_skin import se3
from nao_skin.calibration.layout import ParameterLayout
from nao_skin.calibration.pairing import KIND_NORMAL, Pairing
from nao_skin.calibration.residuals import ResidualModel
from nao_skin.calibration.solver import SolveOptions, solve
from nao_skin.model.skin import load_skin


@pytest.fixture(scope="module")
def skin():
    return load_skin()


def _random_rows(skin, n, rng, normal_rows=0):
    """Residual rows 'mean of 3 hand taxels - mean of 2 torso taxels' (COP-like rows), then
    ``normal_rows`` rows 'mean hand normal + mean torso normal' (the solver's normal rows)."""
    hand, torso = skin.parts["l_hand"].slots, skin.parts["torso"].slots
    rows, parts, slots, weights = [], [], [], []
    for m in range(n + normal_rows):
        sign = 1 if m >= n else -1
        for s in rng.choice(hand, 3, replace=False):
            rows.append(m), parts.append(0), slots.append(s), weights.append(1 / 3)
        for s in rng.choice(torso, 2, replace=False):
            rows.append(m), parts.append(1), slots.append(s), weights.append(sign / 2)
    kind = np.r_[np.zeros(n, np.int8), np.full(normal_rows, KIND_NORMAL, np.int8)]
    m = n + normal_rows
    return Pairing(row_touch=np.r_[np.arange(n), np.arange(normal_rows) % n], row_kind=kind,
                   row_parts=np.tile([0, 1], (m, 1)), term_row=np.array(rows), term_part=np.array(parts),
                   term_slot=np.array(slots), term_weight=np.array(weights), distance=np.zeros(m))


def test_right_jacobian_matches_definition():
    rng = np.random.default_rng(1)
    for phi in [np.zeros(3), rng.normal(0, 0.3, 3), np.array([0.0, 2.8, 0.3])]:
        eps = 1e-6
        jr = se3.right_jacobian(phi)
        for i in range(3):
            d = np.zeros(3)
            d[i] = eps
            # R(phi + d) = R(phi) Exp(J_r d) to first order
            lhs = se3.rotvec_to_matrix(phi).T @ se3.rotvec_to_matrix(phi + d)
            got = se3.matrix_to_rotvec(lhs) / eps
            np.testing.assert_allclose(got, jr[:, i], atol=1e-5)


def test_urdf_rpy_is_fixed_axes_x_y_z_and_survives_gimbal_lock():
    """URDF's rpy: R = Rz(yaw) Ry(pitch) Rx(roll); a pitch of +-90 degrees still gives back the same rotation."""
    def about(axis, angle):
        return se3.rotvec_to_matrix(np.eye(3)[axis] * angle)

    rng = np.random.default_rng(3)
    rpy = np.r_[rng.uniform(-3, 3, (20, 3)) * [1, 0.5, 1], [[0.3, np.pi / 2, 0.2], [-1.0, -np.pi / 2, 2.0]]]
    expected = np.stack([about(2, y) @ about(1, p) @ about(0, r) for r, p, y in rpy])
    np.testing.assert_allclose(se3.matrix_from_rpy(rpy), expected, atol=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # no gimbal-lock warning reaches a user writing a URDF
        back = se3.rpy_from_matrix(expected)
    np.testing.assert_allclose(se3.matrix_from_rpy(back), expected, atol=1e-12)
    assert se3.rpy_from_matrix(np.eye(3)).shape == (3,)


def test_analytic_jacobian_equals_central_differences(skin):
    rng = np.random.default_rng(0)
    n = 15
    q = rng.uniform(skin.robot.limits[:, 0], skin.robot.limits[:, 1], (n, len(skin.robot.joint_names)))
    pairing = _random_rows(skin, n, rng, normal_rows=6)
    calib = skin.zero_calibration()
    for name in ("l_hand", "torso"):
        c = calib.parts[name]
        c.mount = rng.normal(0, 1.0, 6)          # large rotations included (~160 deg real mounts)
        c.patches = rng.normal(0, 0.05, c.patches.shape)
        c.triangles = rng.normal(0, 0.05, c.triangles.shape)
    layout = ParameterLayout(skin, ("l_hand", "torso"))
    model = ResidualModel(skin, lambda part: skin.chain_poses(part, q), pairing, ("l_hand", "torso"), layout, calib)
    x0 = layout.to_vector(calib, fabric=0.001)
    model.residuals(calib, 0.001)
    all_levels = {"mount", "patch", "triangle"}
    jac = model.jacobian(calib, {"l_hand": all_levels, "torso": all_levels})
    num = np.zeros_like(jac)
    for c in range(layout.size):
        h = 1e-6
        xp, xm = x0.copy(), x0.copy()
        xp[c] += h
        xm[c] -= h
        num[:, c] = (model.residuals(layout.to_calibration(xp, calib), xp[layout.fabric_col]).ravel()
                     - model.residuals(layout.to_calibration(xm, calib), xm[layout.fabric_col]).ravel()) / (2 * h)
    assert np.abs(jac - num).max() < 1e-7
    assert np.abs(jac).max() > 0.1


def test_solver_recovers_a_mount_correction(skin):
    """Rows built from a true hand mount: solving from the nominal mount finds it again."""
    rng = np.random.default_rng(3)
    n = 60
    q = rng.uniform(skin.robot.limits[:, 0], skin.robot.limits[:, 1], (n, len(skin.robot.joint_names)))
    hand = skin.parts["l_hand"]
    truth = skin.zero_calibration()
    truth.parts["l_hand"].mount = np.array([0.01, -0.005, 0.008, 0.2, -0.1, 0.15])
    # residual rows: true hand taxel position minus a fixed world point = that position;
    # here the 'reference' is a torso-less target: we pair each hand taxel with itself under the truth
    slots = rng.choice(hand.slots, n)
    target = skin.taxels_in_base("l_hand", q, truth, slots[:, None])[:, 0]
    # express targets as torso taxels is not possible; use a single-part model and subtract targets
    pairing = Pairing(row_touch=np.arange(n), row_kind=np.zeros(n, np.int8), row_parts=np.zeros((n, 2), int),
                      term_row=np.arange(n), term_part=np.zeros(n, int), term_slot=slots, term_weight=np.ones(n),
                      distance=np.zeros(n))
    layout = ParameterLayout(skin, ("l_hand",))
    model = ResidualModel(skin, lambda part: skin.chain_poses(part, q), pairing, ("l_hand",), layout, skin.zero_calibration())
    original = model.residuals

    def shifted(calib, fabric=None):
        return original(calib, fabric) - target
    model.residuals = shifted
    free = np.zeros(layout.size, bool)
    free[:6] = True
    res = solve(model, np.zeros(layout.size), free, np.full(layout.size, -np.inf), np.full(layout.size, np.inf),
                {"l_hand": {"mount"}}, SolveOptions(loss="linear"))
    np.testing.assert_allclose(res.x[:6], truth.parts["l_hand"].mount, atol=1e-6)
    assert res.converged


def test_sparse_and_dense_jacobians_agree(skin, monkeypatch):
    """Large stages keep the Jacobian sparse; it must equal the dense one."""
    import nao_skin.calibration.residuals as residuals

    rng = np.random.default_rng(5)
    n = 10
    q = rng.uniform(skin.robot.limits[:, 0], skin.robot.limits[:, 1], (n, len(skin.robot.joint_names)))
    pairing = _random_rows(skin, n, rng)
    calib = skin.zero_calibration()
    calib.parts["l_hand"].mount = rng.normal(0, 1.0, 6)
    layout = ParameterLayout(skin, ("l_hand", "torso"))
    model = ResidualModel(skin, lambda part: skin.chain_poses(part, q), pairing, ("l_hand", "torso"), layout, calib)
    levels = {"l_hand": {"mount", "patch", "triangle"}, "torso": {"patch"}}
    cols = np.arange(3, layout.size - 7)
    dense = model.jacobian(calib, levels, cols)
    monkeypatch.setattr(residuals, "DENSE_LIMIT", 0)
    sparse = model.jacobian(calib, levels, cols)
    assert residuals.scipy.sparse.issparse(sparse)
    np.testing.assert_allclose(sparse.toarray(), dense, atol=1e-15)
    np.testing.assert_allclose(residuals.gram(sparse), residuals.gram(dense), atol=1e-12)
