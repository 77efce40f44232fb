"""Point-to-plane rows (``pairs: cop+plane``): a taxel against the other side's closest taxel, along that
taxel's normal only, so the two lattices' tangential offset does not count."""
from functools import partial

import numpy as np
import pytest

import nao_skin.calibration.residuals as residuals_module
from nao_skin.calibration.engine import CalibrationOptions, calibrate
from nao_skin.calibration.layout import ParameterLayout
from nao_skin.calibration.pairing import KIND_PLANE_A, KIND_PLANE_B, KIND_TAXEL, PlaneRows, RowRules, chain_end_poses
from nao_skin.calibration.rows import pair_touches
from nao_skin.calibration.residuals import ResidualModel
from nao_skin.model.skin import load_skin
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate

KINDS = ("cop", "taxel", "plane_b", "plane_a")


@pytest.fixture(scope="module")
def skin():
    return load_skin()


@pytest.fixture(scope="module")
def ideal_sim(skin):
    """Every pair, no noise and no defects: the true skins meet at their fabric surfaces."""
    return simulate(skin, load_params("ideal", {"n_touches": 30}), seed=5)


def _model(skin, touches, pairing, calib, fabric):
    return ResidualModel(skin, partial(chain_end_poses, touches, skin), pairing, touches.part_names,
                         ParameterLayout(skin, touches.part_names), calib, fabric=fabric)


def test_plane_rows_vanish_at_the_truth_where_closest_taxels_do_not(skin, ideal_sim):
    touches, truth = ideal_sim.touches, ideal_sim.truth
    pairing = pair_touches(touches, skin, truth, KINDS, rules=RowRules(plane=PlaneRows("equal")))
    plane = np.isin(pairing.row_kind, (KIND_PLANE_B, KIND_PLANE_A))
    assert plane.sum() > 5 * np.sum(pairing.row_kind == KIND_TAXEL)      # a row per activated taxel, both ways
    assert np.all(np.isnan(pairing.row_normal[~plane]))
    np.testing.assert_allclose(np.linalg.norm(pairing.row_normal[plane], axis=1), 1.0)
    r = _model(skin, touches, pairing, truth, load_params("ideal").fabric_thickness).residuals(truth)
    # only the component along the normal is left
    np.testing.assert_allclose(np.cross(r[plane], pairing.row_normal[plane]), 0.0, atol=1e-12)
    dist = np.linalg.norm(r, axis=1)
    assert np.median(dist[plane]) < 1e-6
    assert np.median(dist[pairing.row_kind == KIND_TAXEL]) > 5e-4       # the lattices' tangential offset


@pytest.mark.parametrize("dense", [True, False])
@pytest.mark.parametrize("kinds", [KINDS, ("surface",)], ids=["plane", "surface"])
def test_projected_jacobian_is_the_derivative_with_the_normals_held(skin, ideal_sim, monkeypatch, dense, kinds):
    """ICP point-to-plane: the normals are fixed while a pairing is, so the Jacobian is the projected one (the
    contact model's surface rows too, nao_skin.calibration.contact)."""
    touches, truth = ideal_sim.touches, ideal_sim.truth
    if not dense:
        monkeypatch.setattr(residuals_module, "DENSE_LIMIT", 0)
    pairing = pair_touches(touches, skin, truth, kinds, parts=("l_hand", "torso"), rules=RowRules(plane=PlaneRows("pressure")))
    model = _model(skin, touches, pairing, truth, 0.001)
    layout = model.layout
    rng = np.random.default_rng(0)
    x0 = layout.to_vector(truth, 0.001)
    x0[:layout.fabric_col] += rng.normal(0.0, 0.005, layout.fabric_col)
    cols = np.concatenate([np.arange(0, layout.fabric_col, 37), [layout.fabric_col]])
    free_levels = {p: {"mount", "patch", "triangle"} for p in touches.part_names}
    jac = model.jacobian(layout.to_calibration(x0, truth), free_levels, cols)
    jac = jac.toarray() if hasattr(jac, "toarray") else jac
    base = model.residuals(layout.to_calibration(x0, truth), x0[layout.fabric_col]).ravel()
    for k, c in enumerate(cols):
        x = x0.copy()
        x[c] += 1e-7
        step = (model.residuals(layout.to_calibration(x, truth), x[layout.fabric_col]).ravel() - base) / 1e-7
        np.testing.assert_allclose(jac[:, k], step, atol=1e-6)


def test_point_to_plane_recovers_the_truth_at_least_as_well_as_the_whole_cops_alone(skin, ideal_sim):
    touches, truth = ideal_sim.touches, ideal_sim.truth
    default = calibrate(touches, skin, CalibrationOptions(pairs="cop"), truth=truth)
    options = CalibrationOptions()
    options.set("pairs", "cop+plane")
    plane = calibrate(touches, skin, options, truth=truth)
    errors = [r.report.final["truth_taxel_error_mm"]["all"] for r in (default, plane)]
    assert errors[1]["median"] <= errors[0]["median"], errors
    assert errors[1]["p95"] <= errors[0]["p95"], errors
