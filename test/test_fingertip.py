"""Fingertip touches: a fingertip of the robot (no skin on it) pressed on a skin part, only that part fires.

From the robot config's fingertips and the skin config's scene, through the thesis' text format (``--fingertip``)
and touch bags (each fingertip touch marked), the simulator's fingertip scenes, the calibration's fingertip rows and
what a live detector takes for a fingertip's touch."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest
import yaml

from nao_skin.calibration.engine import calibrate
from nao_skin.calibration.options import CalibrationOptions
from nao_skin.cli import main as cli_main
from nao_skin.errors import ConfigError
from nao_skin.formats.bag import read_touches, write_touch_bag
from nao_skin.formats.inputs import Inputs, load_touches
from nao_skin.model.robot import RobotModel
from nao_skin.model.skin import SkinCalibration, load_skin
from nao_skin.paths import default_skin_config, package_dir
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate
from nao_skin.touch.datasets import deduplicate
from nao_skin.touch.events import EventDetector
from nao_skin.touch.fingertip import FingertipJudge

ROBOT = package_dir() / "config" / "nao_h25.yaml"


def last_line(capsys) -> str:
    """The line a refused command ends with (what loading read and skipped comes before it)."""
    return capsys.readouterr().err.strip().splitlines()[-1]


# ---------------------------------------------------------------------- fingertips as data
def test_the_robot_config_names_its_fingertips_and_the_skin_config_which_parts_they_press(default_skin):
    robot = default_skin.robot
    assert set(robot.fingertips) == {"r_finger", "l_finger"}
    assert robot.fingertips["r_finger"].chain == "r_arm" and robot.fingertips["r_finger"].radius > 0
    pairs = default_skin.fingertip_touch.pairs()
    assert ("r_finger", "torso") in pairs and ("r_finger", "l_hand") in pairs
    assert ("r_finger", "r_hand") not in pairs and ("l_finger", "l_hand") not in pairs     # never its own arm's skin


@pytest.mark.parametrize("entry, said", [
    ({"chain": "tail", "point": [0, 0, 0]}, "fingertip 'x': chain 'tail' is not a chain of this robot"),
    ({"chain": "r_arm", "point": [0, 0]}, "fingertip 'x': point: expected [x, y, z] metres"),
    ({"chain": "r_arm", "point": [0, 0, 0], "radius": -0.001}, "fingertip 'x': point within 10 m and radius 0 to 0.1 m"),
    ({"chain": "r_arm", "point": [0, 0, 0], "size": 1}, "fingertip 'x': unknown key 'size'"),
], ids=["chain", "point", "radius", "key"])
def test_a_bad_fingertip_in_the_robot_config_is_one_line(tmp_path, entry, said):
    doc = yaml.safe_load(ROBOT.read_text())
    doc["fingertips"] = {"x": entry}
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match=re.escape(said)):
        RobotModel.from_yaml(path)


def test_a_scene_naming_an_unknown_fingertip_or_part_is_one_line(tmp_path):
    doc = yaml.safe_load(default_skin_config().read_text())
    doc["robot"] = str(ROBOT)
    for part in doc["parts"].values():
        part["taxel_file"] = str(default_skin_config().parent / part["taxel_file"])
    for scene, said in (({"touching": ["thumb"], "touched": ["torso"]}, "touching: thumb is not a fingertip of"),
                        ({"touching": ["r_finger"], "touched": ["tail"]}, "touched: tail is not a part of this config")):
        doc["fingertip_touch"] = scene
        path = tmp_path / "skin.yaml"
        path.write_text(yaml.safe_dump(doc))
        with pytest.raises(ConfigError, match=re.escape(said)):
            load_skin(path)


def test_a_calibration_keeps_its_fingertips_and_refuses_an_edited_one(tmp_path, default_skin):
    calib = default_skin.zero_calibration()
    calib.fingertips["r_finger"] = np.array([0.001, -0.002, 0.003, 0.0005])
    calib.fingertips_std["r_finger"] = np.array([0.0001, 0.0001, 0.0002, 0.0003])
    path = tmp_path / "calibration.yaml"
    calib.save(path, default_skin)
    back = SkinCalibration.load(path, default_skin)
    assert np.allclose(back.fingertips["r_finger"], calib.fingertips["r_finger"])
    centre, radius = back.fingertip_sphere(default_skin.robot, "r_finger")
    assert np.allclose(centre, default_skin.robot.fingertips["r_finger"].point + [0.001, -0.002, 0.003])
    doc = yaml.safe_load(path.read_text())
    doc["fingertips"]["r_finger"]["radius"] = 0.5
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match="fingertips: 'r_finger': point/radius are not what the correction gives"):
        SkinCalibration.load(path, default_skin)


# ---------------------------------------------------------------------- the real recordings
@pytest.fixture(scope="module")
def torso_skin(real_dir):
    return load_skin(taxel_files={"torso": real_dir / "torso.taxels.txt"})


def test_a_fingertip_recording_reads_as_that_fingertips_touches_and_calibrates(tmp_path, real_dir, real_fingertip_dir,
                                                                             capsys):
    """``--fingertip r_finger``: every touch of the file a touch of the right fingertip; the calibration fits the
    torso and the fingertip's sphere, and reports the fingertip's distance on both splits."""
    src = real_fingertip_dir / "r_finger_torso.legacy.txt"
    out = tmp_path / "cal"
    assert cli_main(["calibrate", str(src), "--taxels", f"torso={real_dir / 'torso.taxels.txt'}", "--fingertip",
                     "r_finger", "--out", str(out), "--no-plots", "--quiet"]) == 0
    line = capsys.readouterr().out
    assert "calibrated torso from r_finger: fingertip to its contact" in line
    report = json.loads((out / "report.json").read_text())
    for split in ("train", "test"):
        assert report["final"][split]["fingertip_mean_mm"] < 4.0          # 12.6 mm before (the data's README)
    assert report["fingertips"]["r_finger"]["chain"] == "r_arm"
    assert "fingertips:" in (out / "calibration.yaml").read_text()


def test_a_fingertip_recording_without_its_fingertip_and_a_self_touch_one_with_one_are_one_line(
        tmp_path, real_dir, real_fingertip_dir, real_recording, real_taxels, capsys):
    src = real_fingertip_dir / "r_finger_torso.legacy.txt"
    taxels = ["--taxels", f"torso={real_dir / 'torso.taxels.txt'}"]
    assert cli_main(["calibrate", str(src), *taxels, "--out", str(tmp_path / "a"), "--quiet"]) == 2
    assert last_line(capsys).endswith("no touch has two skin parts active together: nothing to calibrate from; each"
                                     " fires one part, as a fingertip's touches do: name the fingertip that pressed"
                                     " them (--fingertip NAME)")
    assert cli_main(["calibrate", str(real_recording), *real_taxels, "--fingertip", "r_finger", "--out",
                     str(tmp_path / "b"), "--quiet"]) == 2
    assert "touches fire two skin parts (touch " in last_line(capsys)
    assert cli_main(["calibrate", str(src), *taxels, "--fingertip", "thumb", "--out", str(tmp_path / "c")]) == 2
    assert "unknown fingertip 'thumb' (fingertips: r_finger, l_finger)" in last_line(capsys)
    assert cli_main(["calibrate", str(src), *taxels, "--fingertip", "l_finger=r_finger", "--out",
                     str(tmp_path / "d")]) == 2
    assert "--fingertip 'l_finger=r_finger': l_finger is not among the inputs" in last_line(capsys)


def test_stats_counts_both_kinds_of_touch(real_dir, real_fingertip_dir, capsys):
    src = real_fingertip_dir / "r_finger_torso.legacy.txt"
    assert cli_main(["stats", str(src), "--taxels", f"torso={real_dir / 'torso.taxels.txt'}", "--fingertip",
                     "r_finger", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["self_touches"] == 0 and out["fingertip_touches"] == out["touches"] > 1000
    assert out["fingertip_scenes"] == {"r_finger-torso": out["touches"]} and out["fingertip_mean_mm"] > 5


def test_a_touch_bag_keeps_which_fingertip_pressed(tmp_path, torso_skin, real_fingertip_dir):
    src = real_fingertip_dir / "r_finger_torso.legacy.txt"
    touches, _, _ = load_touches(Inputs((str(src),), {str(src): "r_finger"}), torso_skin, log=lambda m: None)
    touches, _ = deduplicate(touches)
    for storage in ("sqlite3", "mcap"):
        bag = tmp_path / storage
        write_touch_bag(bag, touches, torso_skin, storage=storage)
        back, report = read_touches(bag, torso_skin)
        assert back.n_touches == touches.n_touches, report.lines()
        assert set(back.fingertips[i] for i in back.fingertip_of_touch) == {"r_finger"}
        assert np.array_equal(back.act_slot, touches.act_slot)


# ---------------------------------------------------------------------- simulator
@pytest.fixture(scope="module")
def fingertip_sim(default_skin):
    return simulate(default_skin, load_params("fingertip-torso", {"n_touches": 150}), seed=3)


def test_the_simulator_presses_a_fingertip_and_fires_the_touched_part_alone(fingertip_sim, default_skin):
    touches = fingertip_sim.touches
    assert touches.part_names == ("torso",) and touches.fingertips == ("r_finger",)
    assert np.all(touches.fingertip_of_touch == 0)
    assert set(fingertip_sim.truth.fingertips) == {"r_finger"}
    # the contact point on the fingertip's sphere moves with the approach: its direction in the arm's end frame
    q = touches.labels["joints_true"]
    end = default_skin.with_kinematics(fingertip_sim.truth).robot.fk("r_arm", q)
    normal_in_hand = np.einsum("nji,nj->ni", end[:, :3, :3], touches.labels["contact_normal"])
    assert np.degrees(np.arccos(np.clip(normal_in_hand @ normal_in_hand.mean(0) / np.linalg.norm(
        normal_in_hand.mean(0)), -1, 1))).max() > 20.0


@pytest.mark.slow
def test_a_fingertip_scene_alone_places_the_part_and_finds_the_fingertip(fingertip_sim, default_skin):
    result = calibrate(fingertip_sim.touches, default_skin, CalibrationOptions(), truth=fingertip_sim.truth)
    final = result.report.final
    assert result.report.parts == ["torso"]
    assert final["truth_taxel_error_mm"]["torso"]["median"] < 1.0          # 3-5 mm before
    assert final["truth_fingertip_error_mm"]["r_finger"]["centre"] < 1.5   # up to 8.7 mm before
    assert final["test"]["fingertip_median_mm"] < 2.0                   # its mean: with the experimenter's touches


# ---------------------------------------------------------------------- live: whose press it was
def test_a_detector_with_a_judge_takes_a_part_pressed_alone_under_a_fingertip_and_no_other(fingertip_sim, default_skin):
    """Played as streams, every touch the simulator pressed with the fingertip is a fingertip touch (with the
    experimenter's hand pressing elsewhere at once too); the same presses with the fingertip elsewhere are dropped
    and counted, never recorded, as the simulator's contacts that no fingertip made."""
    touches = fingertip_sim.touches
    made = ~touches.labels["non_self_contact"]
    judge = FingertipJudge(default_skin, [("r_finger", "torso")], fingertip_sim.truth)
    detector = EventDetector.for_skin(default_skin, judge=judge)
    records = []
    away = touches.joints.copy()      # the right arm hanging at rest, by the robot's side
    for joint, (mean, _) in default_skin.robot.body.rest_posture.items():
        if joint.startswith("R"):
            away[:, default_skin.robot.joint_index[joint]] = mean
    for t in range(touches.n_touches):
        for k, q in enumerate((touches.joints[t], away[t])):
            stamp = 10.0 * t + 5.0 * k
            slots = touches.act_slot[touches.act_touch == t].tolist()
            records += detector.add_joint_state(stamp - 0.01, default_skin.robot.joint_names, q)
            records += detector.add_skin(stamp, "torso", slots)
            records += detector.add_joint_state(stamp + 0.01, default_skin.robot.joint_names, q)
            records += detector.add_skin(stamp + 1.0, "torso", [])
    records += detector.flush()
    assert len(records) == made.sum() and {r.fingertip for r in records} == {"r_finger"}
    assert np.array_equal([r.stamp for r in records], 10.0 * np.flatnonzero(made))
    assert detector.drops()["no fingertip near"] == 2 * touches.n_touches - made.sum()
