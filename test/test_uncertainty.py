"""The predicted taxel error (nao_skin.calibration.uncertainty): at the estimate, in the report and calibration.yaml."""
import numpy as np
import pytest

from nao_skin.calibration.engine import calibrate
from nao_skin.calibration.options import CalibrationOptions
from nao_skin.calibration.report import markdown_report
from nao_skin.errors import ConfigError
from nao_skin.model.skin import SkinCalibration, load_skin
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate
from nao_skin.touch.datasets import deduplicate


@pytest.fixture(scope="module")
def skin():
    return load_skin()


@pytest.fixture(scope="module")
def result(skin):
    """300 simulated touches per pair (the four of the default preset), calibrated with the ground truth known."""
    sim = simulate(skin, load_params("default", {"n_touches": 300}), seed=1)
    touches, _ = deduplicate(sim.touches)
    return calibrate(touches, skin, CalibrationOptions(), truth=sim.truth)


def test_the_predicted_median_is_within_a_factor_of_two_of_the_true_one_for_every_calibrated_part(result):
    final = result.report.final
    predicted, true = final["predicted_taxel_error_mm"], final["truth_taxel_error_mm"]
    assert set(predicted) == {*result.report.parts, "all"}
    assert 0.2 < final["predicted_noise_mm"] < 3.0             # the paired taxels' residual noise
    for part in result.report.parts:
        ratio = predicted[part]["median"] / true[part]["median"]
        assert 0.5 <= ratio <= 2.0, (part, predicted[part], true[part])
        assert 0 < predicted[part]["median"] <= predicted[part]["p95"]


def test_the_prediction_is_in_the_report_and_calibration_yaml_and_older_files_still_load(result, skin, tmp_path):
    text = markdown_report(result.report.to_dict())
    assert "## Predicted taxel error (linearised posterior at the estimate)" in text
    part = result.report.parts[0]
    predicted = result.report.final["predicted_taxel_error_mm"][part]
    assert f"| {part} | {predicted['median']:.2f} | {predicted['p95']:.2f} |" in text
    path = tmp_path / "calibration.yaml"
    result.calibration.save(path, skin)
    loaded = SkinCalibration.load(path, skin)
    assert set(loaded.predicted_error_mm) == set(result.report.parts)
    assert loaded.predicted_error_mm[part] == pytest.approx(predicted, abs=1e-4)
    # a file without the key (older, or nominal) loads, with no prediction
    bare = result.calibration.copy()
    bare.predicted_error_mm = {}
    bare.save(path, skin)
    assert "predicted_taxel_error_mm" not in path.read_text()
    assert SkinCalibration.load(path, skin).predicted_error_mm == {}
    np.testing.assert_allclose(SkinCalibration.load(path, skin).parts[part].triangles,
                               result.calibration.parts[part].triangles, atol=1e-9)
    # a broken entry is said, naming the part
    result.calibration.save(path, skin)
    path.write_text(path.read_text().replace("      median: ", "      median: -", 1))
    with pytest.raises(ConfigError, match=rf"part '{part}': predicted_taxel_error_mm must be"):
        SkinCalibration.load(path, skin)


def touches_on_one_triangle(skin) -> tuple:
    """``(touches, first, more, target)``: 160 simulated touches of the left hand on the torso (seed 3); ``first``
    the indices of the first 60, ``more`` those and 25 later ones that all press ``target``, the hand triangle
    the first 60 pressed least (what a guidance target asks for). Here and over DDS (test_live_calibration)."""
    sim = simulate(skin, load_params("default", {"pairs": [["l_hand", "torso"]], "n_touches": 160}), seed=3)
    touches, _ = deduplicate(sim.touches)
    hand = skin.parts["l_hand"]
    on_hand = touches.act_part == touches.part_index("l_hand")
    pressed = [set(hand.triangle_ids[hand.slot_triangle[touches.act_slot[(touches.act_touch == t) & on_hand]]]
                   .tolist()) for t in range(touches.n_touches)]
    first = np.arange(60)
    later = {int(t): [i for i in range(60, touches.n_touches) if t in pressed[i]] for t in hand.triangle_ids}
    target = min((t for t in later if len(later[t]) >= 25), key=lambda t: sum(t in p for p in pressed[:60]))
    return touches, first, np.concatenate([first, later[target][:25]]), target


def test_the_uncertainty_map_has_every_triangle_and_falls_where_touches_land(skin):
    """The map (final.predicted_triangle_error_mm, uncertainty.png, the calibrate node's markers): every triangle
    of each calibrated part, and a triangle the new touches press is surer after them than the others."""
    from nao_skin.calibration.uncertainty_map import colours, triangle_discs

    touches, first, more, target = touches_on_one_triangle(skin)
    hand = skin.parts["l_hand"]
    options = CalibrationOptions(test_fraction=0.0)
    before = calibrate(touches.subset(first), skin, options).report.final["predicted_triangle_error_mm"]
    after = calibrate(touches.subset(more), skin, options).report.final["predicted_triangle_error_mm"]
    assert set(before) == {"l_hand", "torso"}
    assert set(before["l_hand"]) == {int(t) for t in hand.triangle_ids}
    gain = {t: after["l_hand"][t] / before["l_hand"][t] for t in before["l_hand"]}
    assert gain[target] < 0.9 and gain[target] < np.median(list(gain.values())), (target, gain)
    # on the map's scale: white where sure, darker where not; one disc per triangle, above its taxels
    sure, unsure = colours([0.0, 5.0])
    assert sure[:3].min() > 0.9 and unsure[:3].max() < 0.5
    discs = triangle_discs(hand, after["l_hand"])
    assert [d[0] for d in discs] == [int(t) for t in hand.triangle_ids] and all(d[1][2] > 0 for d in discs)


def test_the_posterior_s_draws_average_to_the_predicted_figures_and_scatter_about_them(result):
    """Posterior.median_draws: each part's median taxel distance per draw of the posterior. Averaged over the
    draws the prediction gives (the same 64), they are the predicted medians; their scatter is what the truth
    of any one calibration may do about the prediction (bench-capture's "were each posterior exact")."""
    post = result.posterior
    predicted = result.report.final["predicted_taxel_error_mm"]
    parts = [p for p in predicted if p != "all"]
    draws = post.median_draws(parts, samples=64)
    for p in parts:
        assert np.mean(draws[p]) * 1e3 == pytest.approx(predicted[p]["median"], rel=1e-9)
    worst = np.max([draws[p] for p in parts], axis=0)
    assert 0.05 < np.std(worst) / np.mean(worst) < 0.3          # a real scatter, not a point, not a guess


def test_a_touch_s_variance_lowered_is_what_adding_its_rows_to_the_posterior_removes(result):
    """The guidance's criterion (Posterior.variance_lowered) against the posterior recomputed with the rows added:
    a touch's k rows of one contact, each of the rows' noise, taken off the summed variance of every taxel."""
    from nao_skin.calibration.uncertainty import INEFFICIENCY

    post = result.posterior
    assert post is not None and post.cov.shape == (len(post.free), len(post.free))
    assert post.rows_per_touch >= 1.0 and post.sigma == pytest.approx(result.report.final["predicted_noise_mm"] / 1e3)
    g = post.taxel_jacobian.toarray()
    hand, torso = post.taxels_of("r_hand")[20], post.taxels_of("torso")[100]
    rotation = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    row = rotation @ g[3 * hand:3 * hand + 3] - g[3 * torso:3 * torso + 3]
    noise = (INEFFICIENCY * post.sigma) ** 2 / post.rows_per_touch
    after = np.linalg.inv(np.linalg.inv(post.cov) + row.T @ row / noise)
    removed = np.trace(g @ post.cov @ g.T) - np.trace(g @ after @ g.T)
    assert post.variance_lowered(row) == pytest.approx(removed, rel=1e-6)
    assert post.variance_lowered(row) > post.variance_lowered(0.1 * row) > 0.0     # a row that says less


def test_the_predicted_figures_are_those_of_a_distance_not_of_an_rms(skin):
    """distance_figures: independent isotropic taxel errors of RMS r have a median distance of 0.888 r and a 95th
    percentile of 1.614 r (the chi distribution with 3 degrees of freedom), not r."""
    import scipy.sparse

    from nao_skin.calibration.uncertainty import distance_figures

    n = 1000
    rms = 1e-3
    cov = np.eye(3 * n) * rms ** 2 / 3
    figures = distance_figures(cov, scipy.sparse.identity(3 * n, format="csr"), np.array(["torso"] * n), ["torso"])
    assert figures["torso"]["median"] == pytest.approx(0.888 * rms, rel=0.02)
    assert figures["torso"]["p95"] == pytest.approx(1.614 * rms, rel=0.03)
    assert figures["all"] == figures["torso"]


def test_the_posed_taxel_jacobian_moves_the_taxels_as_the_frames_and_the_kinematics_do(skin):
    """posed_taxel_jacobian: G dx is how far every taxel moves in the base frame at each pose when the unknowns
    move by dx (a mount, a patch, a joint offset and a link at once), to first order."""
    from nao_skin.calibration.layout import ParameterLayout
    from nao_skin.calibration.uncertainty import posed_taxel_jacobian, taxel_jacobian

    parts, kinematic = ("l_hand", "torso"), ("LElbowOffsetY", "LShoulderPitch", "LElbowYaw")
    sim = simulate(skin, load_params("kinematic-error", {"n_touches": 10}), seed=2)
    calib = sim.truth
    layout = ParameterLayout(skin, parts, kinematic)
    g, taxel_part = taxel_jacobian(skin, layout, calib)
    q = deduplicate(sim.touches)[0].joints[:5]
    posed, posed_part = posed_taxel_jacobian(skin, layout, calib, g, taxel_part, q)
    assert posed.shape == (3 * len(taxel_part) * len(q), layout.size)
    assert list(posed_part) == list(taxel_part) * len(q)
    dx = np.zeros(layout.size)
    m, p, _, _ = layout.offsets["l_hand"]
    dx[m:m + 6] = [2e-5, -1e-5, 3e-5, 1e-4, -2e-4, 1e-4]
    dx[p + 6:p + 12] = [1e-5, 1e-5, -2e-5, -1e-4, 1e-4, 2e-4]
    dx[[layout.kinematic_cols[n] for n in kinematic]] = [2e-5, 1e-4, -2e-4]
    x = layout.to_vector(calib)
    moved = layout.to_calibration(x + dx, calib)

    def where(c):
        on = skin.with_kinematics(c)
        return np.concatenate([on.taxels_in_base(n, q, c)[:, skin.parts[n].slots] for n in parts], axis=1)

    shift = (where(moved) - where(calib)).ravel()
    assert np.abs(posed @ dx - shift).max() < 0.01 * np.abs(shift).max()
    assert np.abs(shift).max() > 1e-5                           # the move is tens of micrometres, not rounding


def test_a_calibration_with_kinematic_corrections_counts_them_in_its_predicted_error(skin):
    """The kinematic unknowns a calibration estimated move its taxels where they are: the prediction counts them
    (the taxels' base-frame distance at the training poses, as the truth evaluation measures them); without them
    it was 0.65 times the true figure, with them 0.83 (median; kinematic-error preset, 200 touches per pair, seeds
    0-19)."""
    from nao_skin.calibration.uncertainty import predicted_error

    sim = simulate(skin, load_params("kinematic-error", {"n_touches": 60}), seed=3)
    touches, _ = deduplicate(sim.touches)
    options = CalibrationOptions.from_mapping({"kinematics": "on"})
    result = calibrate(touches, skin, options, truth=sim.truth)
    kin = result.report.kinematics
    estimated = tuple(kin["corrections"])
    assert kin["accepted"] and "LElbowOffsetY" in estimated
    parts = tuple(result.report.parts)
    calib = result.calibration

    def worst(kinematic):
        figures = predicted_error(skin, result.train, calib, calib.fabric_thickness, parts, parts, options,
                                  result.report.prior_sigma, kinematic=kinematic).figures
        return max(figures[p]["median"] for p in parts)

    with_them, without = worst(estimated), worst(())
    assert with_them > 1.1 * without
    reported = result.report.final["predicted_taxel_error_mm"]
    assert max(reported[p]["median"] for p in parts) > 1.1 * without     # the engine's prediction counts them
