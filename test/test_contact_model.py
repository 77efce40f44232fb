"""The contact model (nao_skin.calibration.contact): surface rows, and the fired-taxel prediction that judges a
calibration without closest pairs (report.json's ``fired_*``; ``bench-bound --rows``)."""
import json

import numpy as np
import pytest

from nao_skin.calibration.engine import CalibrationOptions, calibrate
from nao_skin.calibration.evaluation import firing_prediction
from nao_skin.calibration.pairing import KIND_COP, KIND_COP_SKIN, KIND_SURFACE
from nao_skin.calibration.rows import pair_touches
from nao_skin.cli import main as cli_main
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate
from nao_skin.touch.datasets import deduplicate
from test_plane_rows import _model, ideal_sim, skin  # noqa: F401 - the same ideal scene and its fixtures

PAIRS = [("r_hand", "torso"), ("l_hand", "torso"), ("r_hand", "head"), ("l_hand", "head")]


def test_surface_rows_put_the_fired_taxels_on_the_other_skin_at_the_fabric(skin, ideal_sim):
    touches, truth = ideal_sim.touches, ideal_sim.truth
    fabric = load_params("ideal").fabric_thickness
    pairing = pair_touches(touches, skin, truth, ("cop", "surface"))
    surface = pairing.row_kind == KIND_SURFACE
    # a row per activated taxel with the other part's skin beside it: most of them, both ways
    assert 0.5 * len(touches.act_slot) < surface.sum() <= len(touches.act_slot)
    assert np.all(np.isnan(pairing.row_normal[~surface]))
    np.testing.assert_allclose(np.linalg.norm(pairing.row_normal[surface], axis=1), 1.0)
    # side A (the hand) first: the terms of every row are one taxel of each part, A's weight positive
    names = touches.part_names
    assert all(names[a].endswith("hand") and not names[b].endswith("hand") for a, b in pairing.row_parts[surface])
    model = _model(skin, touches, pairing, truth, fabric)
    r = model.residuals(truth)
    np.testing.assert_allclose(np.cross(r[surface], pairing.row_normal[surface]), 0.0, atol=1e-12)
    along = np.einsum("ij,ij->i", r[surface], pairing.row_normal[surface])
    # where both skins are flat the row is exact at the truth: most rows vanish, whatever the lattices' offset
    assert np.mean(np.abs(along) < 1e-6) > 0.4
    # the rows are signed along the touched part's outward normal: thicker fabric (both skins lifted
    # 0.5 mm more towards each other) is 1 mm of penetration
    # (a row is weighted: a touch's rows of one direction weigh as one row)
    weight = np.zeros(pairing.n_rows)
    positive = pairing.term_weight > 0
    weight[pairing.term_row[positive]] = pairing.term_weight[positive]
    thicker = np.einsum("ij,ij->i", model.residuals(truth, fabric + 0.0005)[surface], pairing.row_normal[surface])
    assert np.median((thicker - along) / weight[surface]) == pytest.approx(-0.001, abs=5e-5)
    # a closest COP pair is millimetres long at the same truth (two different fired areas)
    assert np.median(np.linalg.norm(r[pairing.row_kind == KIND_COP], axis=1)) > 5e-4


def test_cops_over_the_other_skin_leave_out_the_taxels_past_its_edge(skin, ideal_sim):
    touches, truth = ideal_sim.touches, ideal_sim.truth
    pairing = pair_touches(touches, skin, truth, ("cop", "cop_skin"))
    whole, on_skin = pairing.row_kind == KIND_COP, pairing.row_kind == KIND_COP_SKIN
    assert np.array_equal(np.unique(pairing.row_touch[on_skin]), np.unique(pairing.row_touch[whole]))
    terms = {}
    for kind in (KIND_COP, KIND_COP_SKIN):
        rows = np.flatnonzero(pairing.row_kind == kind)
        for row in rows:
            t = np.flatnonzero(pairing.term_row == row)
            w = pairing.term_weight[t]
            # each side's weights sum to one: a COP
            assert w[w > 0].sum() == pytest.approx(1.0) and w[w < 0].sum() == pytest.approx(-1.0)
            terms[kind, pairing.row_touch[row]] = set(zip(pairing.term_part[t], pairing.term_slot[t]))
    # the same two contacts, fewer of their taxels: those the other part's skin is not beside are left out
    left_out = 0
    for touch in np.unique(pairing.row_touch[on_skin]):
        assert terms[KIND_COP_SKIN, touch] <= terms[KIND_COP, touch]
        left_out += len(terms[KIND_COP, touch] - terms[KIND_COP_SKIN, touch])
    assert left_out > 0
    # and the two COPs of a touch lie closer at the truth than the whole contacts' do
    r = np.linalg.norm(_model(skin, touches, pairing, truth, 0.001).residuals(truth), axis=1)
    assert np.median(r[on_skin]) < 0.9 * np.median(r[whole])


def test_the_contact_rows_calibrate_as_an_option(skin, ideal_sim):
    options = CalibrationOptions.from_mapping({"closing_pairs": "cop+surface"})
    result = calibrate(ideal_sim.touches, skin, options, truth=ideal_sim.truth)
    assert result.report.final["truth_taxel_error_mm"]["all"]["median"] < 1.0


def test_fired_taxels_are_predicted_best_by_the_true_skin(skin):
    sim = simulate(skin, load_params("default", {"n_touches": 40}), seed=2)
    touches, _ = deduplicate(sim.touches)
    truth = firing_prediction(touches, skin, sim.truth, PAIRS)
    nominal = firing_prediction(touches, skin, skin.zero_calibration(), PAIRS)
    # the torso 3 mm off sideways: still touching, but not where the hands' fired taxels say
    shifted = sim.truth.copy()
    shifted.parts["torso"].mount[1] += 0.003
    off = firing_prediction(touches, skin, shifted, PAIRS)
    for figures in (truth, nominal, off):
        assert set(figures) == {"fired_precision", "fired_recall", "fired_f1"}
    assert truth["fired_precision"] > 80 and 40 < truth["fired_recall"] < 90
    assert nominal["fired_f1"] < 10 < truth["fired_f1"] - 40
    assert off["fired_f1"] < truth["fired_f1"] - 2
    # no part pair of these touches: nothing predicted, nothing fired, said as not measured
    none = firing_prediction(touches, skin, sim.truth, [("l_hand", "r_hand")])
    assert all(np.isnan(v) for v in none.values())


def test_the_report_and_the_summary_line_carry_the_fired_taxel_figure(tmp_path, skin, capsys):
    sim_dir = tmp_path / "sim"
    assert cli_main(["simulate", "--preset", "default", "--seed", "1", "--touches-per-pair", "15",
                     "--out", str(sim_dir)]) == 0
    out = tmp_path / "cal"
    capsys.readouterr()
    assert cli_main(["calibrate", str(sim_dir), "--out", str(out)]) == 0
    said = capsys.readouterr().out
    report = json.loads((out / "report.json").read_text())
    for split in ("train", "test"):
        f = report["final"][split]
        assert 0 < f["fired_precision"] <= 100 and 0 < f["fired_recall"] <= 100
        assert min(f["fired_precision"], f["fired_recall"]) <= f["fired_f1"] <= max(f["fired_precision"],
                                                                                    f["fired_recall"])
    final = report["final"]
    assert f"fired taxels predicted F1 {final['train']['fired_f1']:.2f} / {final['test']['fired_f1']:.2f} %" in said
    md = (out / "report.md").read_text()
    assert "fired taxels predicted F1 (%)" in md and f"{final['test']['fired_f1']:.2f}" in md


def test_bench_bound_linearises_the_rows_it_is_given(tmp_path, capsys):
    out = tmp_path / "bound"
    assert cli_main(["bench-bound", "--seeds", "1", "--pool", "20", "--sizes", "20,40", "--rows", "cop+surface",
                     "--out", str(out)]) == 0
    assert "(rows: cop+surface)" in (out / "bound_results.md").read_text()
    capsys.readouterr()
    assert cli_main(["bench-bound", "--pool", "20", "--sizes", "20", "--rows", "surface",
                     "--out", str(tmp_path / "b2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("nao-skin bench-bound: error: --rows 'surface': expected one of"), err
    assert not (tmp_path / "b2").exists()
