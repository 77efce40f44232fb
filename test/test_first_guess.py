"""The closed-form first guess of a mount: rigid fit with surface normals."""
import numpy as np

from nao_skin import se3
from nao_skin.calibration.first_guess import rigid_mount_guess
from nao_skin.model.skin import load_skin
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate
from nao_skin.touch.datasets import deduplicate, split


def _rotation_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(se3.matrix_to_rotvec(a[:3, :3].T @ b[:3, :3]))))


def test_rigid_fit_with_normals_fixes_the_rotation_about_a_line_of_points():
    """Points on one line leave the rotation about that line free; normals pin it."""
    rng = np.random.default_rng(0)
    truth = se3.pose_matrix(np.array([0.01, -0.02, 0.03, 0.4, -2.5, 0.9]))
    src = np.zeros((40, 3))
    src[:, 0] = rng.uniform(-0.03, 0.03, 40)                  # all on the x axis
    normals = np.tile([0.0, 0.0, 1.0], (40, 1)) + rng.normal(0, 0.02, (40, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    dst = se3.transform_points(truth, src) + rng.normal(0, 0.0005, (40, 3))
    dst_n = se3.rotate_vectors(truth, normals)
    without = se3.rigid_fit(src, dst)
    with_normals = se3.rigid_fit(src, dst, None, normals, dst_n, 0.01 ** 2)
    assert _rotation_error_deg(without, truth) > 20.0         # the degenerate case is real
    assert _rotation_error_deg(with_normals, truth) < 3.0
    np.testing.assert_allclose(se3.transform_points(with_normals, src), dst, atol=0.003)


def test_rigid_fit_without_directions_is_unchanged_by_zero_weight():
    rng = np.random.default_rng(1)
    src = rng.normal(0, 0.03, (30, 3))
    truth = se3.pose_matrix(np.array([0.02, 0.0, -0.01, 1.0, 0.5, -0.3]))
    dst = se3.transform_points(truth, src)
    dirs = rng.normal(size=(30, 3))
    np.testing.assert_allclose(se3.rigid_fit(src, dst), truth, atol=1e-9)
    np.testing.assert_allclose(se3.rigid_fit(src, dst, None, dirs, -dirs, 0.0), truth, atol=1e-9)


def test_first_guess_of_a_hand_on_a_band_of_contacts():
    """planar-poses, seed 4: every contact on one band; points alone put the left hand
    mount 53 degrees off, the contact normals bring it within a few degrees."""
    skin = load_skin()
    sim = simulate(skin, load_params("planar-poses", {"pairs": [["l_hand", "torso"]]}), 4)
    touches, _ = deduplicate(sim.touches)
    train, _ = split(touches, 0.3, 0)
    guess = rigid_mount_guess(train, skin, skin.zero_calibration(), "l_hand", ("torso",))
    truth = sim.truth.parts["l_hand"].mount
    assert _rotation_error_deg(se3.pose_matrix(guess), se3.pose_matrix(truth)) < 10.0
    assert np.linalg.norm(guess[:3] - truth[:3]) < 0.015
