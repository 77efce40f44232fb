"""The linearised bound of what choosing the touches could buy (nao_skin.bench.bound, nao-skin bench-bound)."""
import json

import numpy as np
import pytest

from nao_skin.bench.bound import bound_rows, random_touches_for
from nao_skin.cli import main as cli_main
from nao_skin.model.skin import load_skin


def test_random_touches_for_follows_the_power_law_between_the_sizes_measured():
    errors = {100: 1.0, 400: 0.5, 1600: 0.25}                 # error ~ N^-1/2
    assert random_touches_for(1 / np.sqrt(2), errors) == pytest.approx(200)
    assert random_touches_for(0.35, errors) == pytest.approx(400 * (0.5 / 0.35) ** 2)
    assert random_touches_for(0.125, errors) == pytest.approx(6400)        # beyond: the last two extrapolated
    assert np.isnan(random_touches_for(0.5, {100: 1.0}))
    assert np.isnan(random_touches_for(0.5, {100: 1.0, 200: 1.2}))         # not falling: no power law


@pytest.fixture(scope="module")
def rows():
    return bound_rows(load_skin(), seed=3, pool_per_pair=40, sizes=(30, 60, 120), batch=10)


def test_more_touches_predict_a_smaller_error_and_the_best_choice_beats_random_in_the_tail(rows):
    assert [r["touches"] for r in rows] == [30, 60, 120] and all(r["pool"] > 120 for r in rows)
    assert all(0.2 < r["sigma_mm"] < 3.0 for r in rows)              # the residual noise of paired taxels
    for key in ("random_median_mm", "random_p95_mm", "greedy_median_mm", "greedy_p95_mm"):
        values = [r[key] for r in rows]
        assert values == sorted(values, reverse=True), key
    # the greedy choice lowers the summed taxel variance, which the tail dominates once each pair has a few
    # touches; at 30 over four pairs which frames its first batches reach decides the tail, and the simulated
    # pool that decides it can turn on rounding (scipy's Rodrigues formula instead of ours: 3.14 against 2.96 mm)
    for r in rows[1:]:
        assert r["greedy_p95_mm"] <= 1.02 * r["random_p95_mm"], r
    assert rows[-1]["greedy_p95_mm"] < rows[-1]["random_p95_mm"]


def test_bench_bound_writes_its_table_and_refuses_sizes_beyond_the_pool(tmp_path, capsys):
    out = tmp_path / "bound"
    assert cli_main(["bench-bound", "--seeds", "1", "--pool", "20", "--sizes", "20,40", "--out", str(out)]) == 0
    result = json.loads((out / "bound_results.json").read_text())
    assert [r["touches"] for r in result["rows"]] == [20, 40]
    assert "| 0 | 40 |" in (out / "bound_results.md").read_text()
    # one size: no count of random touches to interpolate, said so rather than printed as nan
    assert cli_main(["bench-bound", "--seeds", "1", "--pool", "20", "--sizes", "40", "--out", str(out), "--force"]) == 0
    text = (out / "bound_results.md").read_text()
    assert "nan" not in text and "for the same predicted error: not measured" in text
    assert "Worst part's median, mean over the seeds (mm): 40: random " in text
    capsys.readouterr()
    assert cli_main(["bench-bound", "--pool", "20", "--sizes", "20,81", "--out", str(tmp_path / "b2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["nao-skin bench-bound: error: --sizes '20,81': expected whole numbers from 1 to the pool's 80"
                   " touches, comma-separated"]
    assert not (tmp_path / "b2").exists()
    # a typo's empty entry, and a batch beyond the smallest size, were taken and ran
    for args, says in ((["--pool", "20", "--sizes", "20,,40"], "--sizes '20,,40': expected whole numbers"),
                       (["--pool", "20", "--sizes", "20,40", "--batch", "100000"],
                        "--batch 100000: expected a whole number from 1 to the smallest size, 20"),
                       # said as the simulation parameters' fault, after a progress line
                       (["--pool", "1000000000", "--sizes", "40"],
                        "--pool 1000000000: expected at most 100000 touches per pair")):
        assert cli_main(["bench-bound", *args, "--out", str(tmp_path / "b3")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0], err
    assert not (tmp_path / "b3").exists()


def test_bench_bound_with_the_kinematics_free_holds_what_the_frames_stand_for_and_costs_accuracy(tmp_path, capsys):
    out = tmp_path / "kinematics"
    assert cli_main(["bench-bound", "--kinematics", "30", "--seeds", "1", "--out", str(out)]) == 0
    (row,) = json.loads((out / "bound_results.json").read_text())["rows"]
    # the last joint of each chain turns its part as the part's mount does: no information of its own
    assert sorted(row["held"]) == ["HeadPitch", "LWristYaw", "RWristYaw"]
    assert sorted(row["link_std_mm"]) == ["LElbowOffsetY", "RElbowOffsetY"]
    assert "LShoulderPitch" in row["joint_std_deg"] and "HeadYaw" in row["joint_std_deg"]
    # unknowns the touches must also tell apart: the frames' error grows (1.7x at 30 per pair, 1.3-1.4x at 200)
    assert row["kinematics_free_mm"] > 1.2 * row["kinematics_known_mm"]
    assert row["ratio"] == pytest.approx(row["kinematics_free_mm"] / row["skin_only_mm"])
    assert 0.0 < row["links_within"] < 1.0 and 0.0 < row["joints_within"] < 1.0
    assert "| 0 | 30 (" in (out / "bound_results.md").read_text()
    capsys.readouterr()
    for bad in ("5", "30,x", "200000"):
        assert cli_main(["bench-bound", "--kinematics", bad, "--out", str(tmp_path / "k2")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"--kinematics '{bad}': expected touches per pair from 10 to" in err[0], err
    assert cli_main(["bench-bound", "--kinematics", "30", "--sizes", "40", "--out", str(tmp_path / "k2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--kinematics '30' with --sizes: those choose touches from a pool" in err[0], err
    assert not (tmp_path / "k2").exists()
