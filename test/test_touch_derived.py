"""What calibration derives from a touch set is kept with that touch set: computed once, never another set's."""
import numpy as np

from nao_skin.calibration.pairing import chain_end_poses, robot_joints
from nao_skin.model.skin import load_skin
from nao_skin.sim.simulate import simulate


def test_derived_results_belong_to_their_touch_set_and_its_owners():
    skin = load_skin()
    touches = simulate(skin, {"n_touches": 4}, seed=1).touches
    calls = []
    first = touches.derived(("k",), lambda: calls.append(1) or np.arange(3), (skin,))
    again = touches.derived(("k",), lambda: calls.append(1) or np.arange(3), (skin,))
    assert first is again and len(calls) == 1
    other_skin = load_skin()
    touches.derived(("k",), lambda: calls.append(1) or np.arange(3), (other_skin,))
    assert len(calls) == 2                                  # another skin object: computed anew
    copy = touches.subset(np.arange(touches.n_touches))
    copy.derived(("k",), lambda: calls.append(1) or np.arange(3), (other_skin,))
    assert len(calls) == 3                                  # another touch set: its own results


def test_forward_kinematics_is_computed_once_per_touch_set_and_chain():
    skin = load_skin()
    touches = simulate(skin, {"n_touches": 4}, seed=1).touches
    poses = chain_end_poses(touches, skin, "l_hand")
    assert chain_end_poses(touches, skin, "l_hand") is poses
    np.testing.assert_allclose(poses, skin.robot.fk(skin.parts["l_hand"].chain, robot_joints(touches, skin)))
    reversed_columns = touches.subset(np.arange(touches.n_touches))
    reversed_columns.joint_names = tuple(reversed(touches.joint_names))
    reversed_columns.joints = touches.joints[:, ::-1].copy()
    np.testing.assert_allclose(chain_end_poses(reversed_columns, skin, "l_hand"), poses)
