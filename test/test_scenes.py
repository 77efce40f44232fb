"""One robot, every scene: each scene of the touches predicted from the others, and where the scenes place a part.

On the simulator's scenes-kinematic preset (the real recordings' three scenes: the left hand on the torso, the right
fingertip on the torso and on the left hand, on arms whose kinematics err differently)."""
from __future__ import annotations

import numpy as np
import pytest

from nao_skin.calibration.options import CalibrationOptions
from nao_skin.calibration.scenes import cross_scene, placement_spread, scene_labels, scenes_markdown, scenes_report
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate
from nao_skin.touch.datasets import deduplicate

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def three_scenes(default_skin):
    sim = simulate(default_skin, load_params("scenes-kinematic", {"n_touches": 120}), 1)
    touches, _ = deduplicate(sim.touches)
    return sim, touches


def test_each_touch_names_its_scene(three_scenes):
    sim, touches = three_scenes
    labels = scene_labels(touches)
    assert set(labels) == {"l_hand+torso", "r_finger-torso", "r_finger-l_hand"}
    expected = np.where(touches.labels["pair"] == "l_hand-torso", "l_hand+torso", touches.labels["pair"])
    assert np.array_equal(labels.astype(str), expected.astype(str))


def test_each_scene_is_predicted_from_the_others_and_the_spread_says_where_the_scenes_put_the_parts(three_scenes,
                                                                                                    default_skin):
    sim, touches = three_scenes
    predictions, results = cross_scene(touches, default_skin, CalibrationOptions())
    assert [p.scene for p in predictions] == ["l_hand+torso", "r_finger-l_hand", "r_finger-torso"]
    for p in predictions:                 # every part and the fingertip are placed by the others: no own unknowns
        assert p.predicted and not p.reason and not p.fitted
        assert set(p.ratios()) == ({"cop_mean_mm", "taxel_mean_mm"} if "+" in p.scene else {"fingertip_mean_mm"})
    assert set(results) == {"l_hand+torso", "r_finger-l_hand", "r_finger-torso", "all", "all but l_hand+torso",
                            "all but r_finger-l_hand", "all but r_finger-torso"}
    spread = placement_spread(default_skin, results)
    assert set(spread) == {"l_hand", "torso"} and set(spread["torso"]) == {
        "l_hand+torso", "r_finger-torso", "all but l_hand+torso", "all but r_finger-l_hand", "all but r_finger-torso"}
    text = "\n".join(scenes_markdown(scenes_report(predictions, spread)))
    assert "| r_finger-torso |" in text and "Placement spread" in text


def test_a_fingertip_no_other_scene_sees_is_fitted_for_its_prediction(three_scenes, default_skin):
    """Predicting the right fingertip on the torso from the left hand's self-touches alone: the fingertip's sphere
    belongs to that scene, and is fitted on its training split, every frame held where the others put it."""
    sim, touches = three_scenes
    labels = scene_labels(touches)
    keep = labels != "r_finger-l_hand"
    predictions, results = cross_scene(touches.subset(keep), default_skin, CalibrationOptions())
    tip = next(p for p in predictions if p.scene == "r_finger-torso")
    assert tip.fitted == ["the sphere of r_finger"]
    assert "r_finger" not in results["all but r_finger-torso"].calibration.fingertips
    assert 0 < tip.predicted["fingertip_mean_mm"] < 3 * tip.own["test"]["fingertip_mean_mm"]


def test_calibrate_cross_scene_writes_each_scene_s_prediction_in_report_json_and_md(three_scenes, default_skin,
                                                                                     tmp_path):
    """`nao-skin calibrate BAG --cross-scene`: report.json's ``scenes`` and report.md's section, from a real bag of
    the three scenes; the calibration written is every scene's together (the same as without the option)."""
    import json

    from nao_skin.cli import main as cli_main
    from nao_skin.formats.bag import write_touch_bag

    sim, touches = three_scenes
    bag = tmp_path / "scenes"
    write_touch_bag(bag, touches, default_skin)
    assert cli_main(["calibrate", str(bag), "--out", str(tmp_path / "with"), "--cross-scene", "--no-plots",
                     "--quiet"]) == 0
    assert cli_main(["calibrate", str(bag), "--out", str(tmp_path / "without"), "--no-plots", "--quiet"]) == 0
    report = json.loads((tmp_path / "with" / "report.json").read_text())
    assert [s["scene"] for s in report["scenes"]["scenes"]] == ["l_hand+torso", "r_finger-l_hand", "r_finger-torso"]
    assert all(s["predicted"] and s["ratio"] for s in report["scenes"]["scenes"])
    assert set(report["scenes"]["placement_spread_mm"]) == {"l_hand", "torso"}
    assert "## Each scene predicted from the others" in (tmp_path / "with" / "report.md").read_text()
    assert "scenes" not in json.loads((tmp_path / "without" / "report.json").read_text()) or \
        not json.loads((tmp_path / "without" / "report.json").read_text())["scenes"]
    assert (tmp_path / "with" / "calibration.yaml").read_text() == (tmp_path / "without" / "calibration.yaml").read_text()
