"""The kinematics the touches can determine (issue 18, part 2).

The robot config with the manufacturer's link lengths (the elbow offset), the
simulator's true robot that differs from the config, kinematic unknowns in the
fit, and where their estimates go (report, calibration.yaml, URDF).
"""
import numpy as np
import pytest

from nao_skin.model.robot import RobotModel
from nao_skin.paths import config_dir

THESIS = config_dir() / "nao_h25.yaml"
MANUFACTURER = config_dir() / "nao_h25_manufacturer.yaml"


def random_q(robot, n, seed):
    lo, hi = robot.limits.T
    return np.random.default_rng(seed).uniform(lo, hi, size=(n, len(lo)))


@pytest.mark.parametrize("chain,side", [("l_arm", 1.0), ("r_arm", -1.0)])
def test_manufacturer_config_moves_the_elbow_out_by_15_mm(chain, side):
    """Arm stretched forward: the elbow and everything after it 15 mm further out (+y left, -y right);
    no frame turns, nothing before the elbow moves, at any pose only the elbow offset differs."""
    thesis, maker = RobotModel.from_yaml(THESIS), RobotModel.from_yaml(MANUFACTURER)
    q0 = np.zeros((1, len(thesis.joint_names)))
    a, b = thesis.fk_frames(chain, q0)[0], maker.fk_frames(chain, q0)[0]
    shift = b[:, :3, 3] - a[:, :3, 3]
    np.testing.assert_allclose(shift[:2], 0.0, atol=1e-12)          # torso -> shoulder: unchanged
    np.testing.assert_allclose(shift[2:], np.tile([0.0, side * 0.015, 0.0], (len(shift) - 2, 1)), atol=1e-12)
    np.testing.assert_allclose(b[:, :3, :3], a[:, :3, :3], atol=1e-12)
    # any pose: rotations equal, the wrist off by 15 mm along the shoulder-roll frame's lateral axis
    q = random_q(thesis, 50, 3)
    a, b = thesis.fk_frames(chain, q), maker.fk_frames(chain, q)
    np.testing.assert_allclose(b[..., :3, :3], a[..., :3, :3], atol=1e-12)
    np.testing.assert_allclose(b[:, -1, :3, 3] - a[:, -1, :3, 3], side * 0.015 * a[:, 2, :3, 0], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(b[:, -1, :3, 3] - a[:, -1, :3, 3], axis=1), 0.015, atol=1e-12)
    # the head chain is the same in both
    np.testing.assert_allclose(thesis.fk("head", q), maker.fk("head", q), atol=1e-15)
