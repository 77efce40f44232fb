"""The press model (nao_skin.touch.press, nao_skin.calibration.press): what a COP row is expected to be at the
true skin, the rows fitted minus it, and the option that calibrates with it (``press_model``)."""
from functools import partial

import numpy as np
import pytest

from nao_skin.calibration.engine import CalibrationOptions, calibrate
from nao_skin.calibration.evaluation import truth_error
from nao_skin.calibration.layout import ParameterLayout
from nao_skin.calibration.pairing import KIND_COP, KIND_COP_SKIN, RowRules, chain_end_poses, robot_joints
from nao_skin.calibration.rows import pair_touches
from nao_skin.calibration.press import expected_cop_difference, press_offsets
from nao_skin.calibration.residuals import ResidualModel
from nao_skin.errors import DataError
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate
from nao_skin.touch.datasets import deduplicate
from nao_skin.touch.press import PressModel
from test_plane_rows import ideal_sim, skin  # noqa: F401 - the same ideal scene and its fixtures


def _residuals(skin, touches, pairing, calib, fabric):
    return ResidualModel(skin, partial(chain_end_poses, touches, skin), pairing, touches.part_names,
                         ParameterLayout(skin, touches.part_names), calib, fabric=fabric).residuals(calib)


def test_the_press_model_expects_most_of_a_cop_row_at_the_true_skin(skin, ideal_sim):
    """No noise: at the true skin a COP row is a millimetre long (two parts sample the pressed spot at their own
    taxels); the press model, knowing only the calibration, the two COPs and which taxels other contacts of the
    touch fired, predicts a good part of it."""
    touches, truth = ideal_sim.touches, ideal_sim.truth
    fabric = load_params("ideal").fabric_thickness
    press = press_offsets(touches, skin, truth, fabric, touches.part_names)
    assert set(press) == {("r_hand", "torso"), ("l_hand", "torso"), ("r_hand", "head"), ("l_hand", "head")}
    raw = _residuals(skin, touches, pair_touches(touches, skin, truth, ("cop_skin",)), truth, fabric)
    fitted = _residuals(skin, touches, pair_touches(touches, skin, truth, ("cop_skin",), rules=RowRules(press=press)), truth, fabric)
    row = np.median(np.linalg.norm(raw, axis=1))
    assert row > 5e-4
    # measured: 1.02 mm, 0.55 mm less the expectation (0.73 mm without leaving out what other contacts fired)
    assert np.median(np.linalg.norm(fitted, axis=1)) < 0.65 * row


def test_a_row_carries_its_touchs_expectation_and_its_residual_is_less_by_it(skin, ideal_sim):
    touches, truth = ideal_sim.touches, ideal_sim.truth
    fabric = load_params("ideal").fabric_thickness
    rng = np.random.default_rng(0)
    press = {pair: rng.normal(0.0, 1e-3, (touches.n_touches, 3)) for pair in
             [("r_hand", "torso"), ("l_hand", "torso"), ("r_hand", "head"), ("l_hand", "head")]}
    press[("r_hand", "torso")][:] = np.nan        # a pair without expectations: its rows are fitted as they are
    plain = pair_touches(touches, skin, truth, ("cop", "cop_skin"))
    pairing = pair_touches(touches, skin, truth, ("cop", "cop_skin"), rules=RowRules(press=press))
    assert plain.row_offset is None
    names = touches.part_names
    for i in range(pairing.n_rows):
        pair = (names[pairing.row_parts[i, 0]], names[pairing.row_parts[i, 1]])
        expected = (np.nan_to_num(press[pair][pairing.row_touch[i]]) if pairing.row_kind[i] == KIND_COP_SKIN
                    else np.zeros(3))
        np.testing.assert_array_equal(pairing.row_offset[i], expected)
    assert np.any(pairing.row_kind == KIND_COP) and not np.any(pairing.row_offset[pairing.row_kind == KIND_COP])
    np.testing.assert_allclose(_residuals(skin, touches, pairing, truth, fabric),
                               _residuals(skin, touches, plain, truth, fabric) - pairing.row_offset, atol=1e-15)


def test_the_press_model_is_the_simulators_default_press():
    default = load_params("default")
    assert list(PressModel().spot_radius) == default.spot_size
    assert list(PressModel().reach) == default.press_reach


def test_calibrating_with_the_press_model_comes_closer_to_the_truth(skin):
    """The option on a simulated recording with the preset's noise: the same touches end closer to the true skin
    (measured over seeds 0-19 in docs/decisions.md, "The press model's expectation")."""
    sim = simulate(skin, load_params("default", {"n_touches": 250}), seed=0)
    touches, _ = deduplicate(sim.touches)
    worst = {}
    for mode in (False, True):
        result = calibrate(touches, skin, CalibrationOptions(test_fraction=0.0, press_model=mode), truth=sim.truth)
        if mode:
            assert any(s["name"].startswith("press model: ") for s in result.report.stages)
        error = truth_error(skin, result.calibration, sim.truth, result.report.parts)
        worst[mode] = max(error[p]["median"] for p in result.report.parts)
    # measured: 0.476 mm off, 0.420 mm with the press model
    assert worst[True] < 0.93 * worst[False]


def test_an_unknown_press_model_is_refused_in_one_line():
    with pytest.raises(DataError, match="press_model='sometimes'"):
        CalibrationOptions.from_mapping({"press_model": "sometimes"})


def test_the_kinematic_path_is_run_again_on_the_rows_less_their_expectation(skin):
    """kinematics=on: the press model's expectations are taken at the kinematic path's calibration (on the robot
    it describes) and the path runs again on them; the arm's unknowns come closer to the truth with the skin."""
    sim = simulate(skin, load_params("kinematic-error", {"n_touches": 200}), seed=1)
    touches, _ = deduplicate(sim.touches)
    worst = {}
    for mode in (False, True):
        result = calibrate(touches, skin, CalibrationOptions(kinematics="on", press_model=mode), truth=sim.truth)
        error = truth_error(skin, result.calibration, sim.truth, result.report.parts,
                            robot_joints(result.train, skin))
        worst[mode] = max(error[p]["median"] for p in result.report.parts)
    # measured: 1.253 mm off, 0.891 mm with the press model (seeds 0-5: 0.798 against 0.626 on average)
    assert worst[True] < 0.85 * worst[False]


def _flat_skins(fabric=0.001, pitch=0.005, offset=(0.002, 0.001)):
    """Two flat lattices facing each other across two fabrics at the origin: the hand above (normals down), the
    touched part below (normals up), the touched lattice offset sideways; one row."""
    g = np.arange(-6, 7) * pitch
    x, y = np.meshgrid(g, g)
    grid = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    hand = grid + [0.0, 0.0, 2.0 * fabric]
    touched = grid + [offset[0], offset[1], 0.0]
    down, up = np.tile([0.0, 0.0, -1.0], (len(grid), 1)), np.tile([0.0, 0.0, 1.0], (len(grid), 1))
    return (hand[None], down[None]), (touched[None], up[None])


def test_two_flat_skins_pressed_together_are_expected_to_meet_and_another_contacts_taxels_are_not_this_ones():
    hand, touched = _flat_skins()
    contact, normal = np.array([[0.0, 0.0, 0.001]]), np.array([[0.0, 0.0, 1.0]])
    both = expected_cop_difference(hand, touched, contact, normal, 0.001)
    # flat skins at the fabrics' gap: the lifted surfaces meet, and a spot centred between them is sampled
    # evenly by both lattices (within the lattices' offset)
    assert abs(both[0, 2]) < 1e-9
    assert np.linalg.norm(both[0, :2]) < 0.001
    # the hand's taxels on the +x side fired in another contact: the row's spot did not press them, its
    # expected COP on the hand lies on the -x side
    elsewhere = hand[0][0][:, 0] > 0.0
    moved = expected_cop_difference((*hand, elsewhere[None]), touched, contact, normal, 0.001)
    assert moved[0, 0] < both[0, 0] - 0.002
    # the hand held 1 mm off the touched skin by the calibration: the expectation is taken with the skins touching
    apart = expected_cop_difference((hand[0] + [0.0, 0.0, 0.001], hand[1]), touched, contact, normal, 0.001)
    np.testing.assert_allclose(apart, both, atol=1e-12)
