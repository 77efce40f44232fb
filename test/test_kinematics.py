"""The kinematics the touches can determine (issue 18, part 2).

The robot config with the manufacturer's link lengths (the elbow offset), the
simulator's true robot that differs from the config, kinematic unknowns in the
fit, and where their estimates go (report, calibration.yaml, URDF).
"""
from dataclasses import replace

import numpy as np
import pytest
import yaml

from nao_skin.calibration.engine import CalibrationOptions, calibrate
from nao_skin.calibration.evaluation import paired_gain
from nao_skin.errors import ConfigError
from nao_skin.model.robot import RobotModel
from nao_skin.model.skin import SkinCalibration
from nao_skin.paths import config_dir
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate, write_outputs
from nao_skin.touch.datasets import deduplicate

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


def test_corrected_robot_adds_joint_offsets_and_link_lengths():
    robot = RobotModel.from_yaml(THESIS)
    q = random_q(robot, 20, 5)
    moved = robot.corrected({"LElbowRoll": 0.03, "LElbowOffsetY": 0.015})
    shifted = q.copy()
    shifted[:, robot.joint_index["LElbowRoll"]] += 0.03
    maker = RobotModel.from_yaml(MANUFACTURER)
    np.testing.assert_allclose(moved.fk("l_arm", q), maker.fk("l_arm", shifted), atol=1e-12)
    np.testing.assert_allclose(moved.fk("r_arm", q), robot.fk("r_arm", q), atol=1e-15)
    assert robot.kinematic_names(["l_arm"]) == ["LShoulderPitch", "LShoulderRoll", "LElbowYaw", "LElbowRoll",
                                                "LWristYaw", "LElbowOffsetY"]
    with pytest.raises(ConfigError, match="neither a joint nor a named link"):
        robot.corrected({"LKnee": 0.1})


# ------------------------------------------------------------------------------ simulator
def small_params(preset, **overrides):
    return load_params(preset, {"n_touches": 3, "pairs": [["l_hand", "torso"]], **overrides})


def test_kinematic_error_preset_truth_differs_and_is_reproducible(skin, tmp_path):
    a = simulate(skin, small_params("kinematic-error"), seed=4)
    b = simulate(skin, small_params("kinematic-error"), seed=4)
    nominal = simulate(skin, small_params("default"), seed=4)
    kin = a.truth.kinematics
    assert kin == b.truth.kinematics
    assert np.array_equal(a.touches.joints, b.touches.joints)
    joints = [j for j in kin if j in skin.robot.joint_index]
    assert len(joints) == 12                                     # every arm and head joint
    assert all(0 < abs(v) <= np.radians(2.0) for v in (kin[j] for j in joints))
    assert kin["LElbowOffsetY"] == 0.015 and kin["RElbowOffsetY"] == -0.015
    assert nominal.truth.kinematics == {}
    # the skin's truth is drawn first from the same stream: the same as the config's robot's
    for name in skin.parts:
        np.testing.assert_array_equal(a.truth.parts[name].mount, nominal.truth.parts[name].mount)
    # another seed, other offsets
    assert simulate(skin, small_params("kinematic-error"), seed=5).truth.kinematics != kin
    # the truth goes into the recording's files; the config's robot leaves them as they were
    write_outputs(a, skin, tmp_path / "ke", preset="kinematic-error", with_bag=False)
    meta = yaml.safe_load((tmp_path / "ke" / "simulation.yaml").read_text())
    assert meta["params"]["joint_offset_deg"] == 2.0
    loaded = SkinCalibration.load(tmp_path / "ke" / "truth_calibration.yaml", skin)
    assert loaded.kinematics == pytest.approx(kin, abs=1e-10)
    write_outputs(nominal, skin, tmp_path / "nominal", preset="default", with_bag=False)
    assert "joint_offset_deg" not in (tmp_path / "nominal" / "simulation.yaml").read_text()
    assert "kinematics" not in (tmp_path / "nominal" / "truth_calibration.yaml").read_text()


def test_true_body_poses_and_fires(skin):
    """The recorded joints put the true skin in contact on the true robot, not on the config's."""
    sim = simulate(skin, small_params("kinematic-error", noise_scale=0.0), seed=2)
    q = sim.touches.labels["joints_true"]
    contact = sim.touches.labels["contact_point"]
    hand = skin.parts["l_hand"].present
    true = skin.with_kinematics(sim.truth).taxels_in_base("l_hand", q, sim.truth)[:, hand]
    assert np.all(np.min(np.linalg.norm(true - contact[:, None], axis=2), axis=1) < 0.01)
    # on the config's robot the same joints put the same skin elsewhere (15 mm elbow, ~2 deg per joint)
    config = skin.taxels_in_base("l_hand", q, sim.truth)[:, hand]
    assert np.all(np.median(np.linalg.norm(config - true, axis=2), axis=1) > 0.005)


# ------------------------------------------------------------------------------ calibration
def test_calibration_yaml_round_trips_the_kinematic_section(skin, tmp_path):
    calib = skin.zero_calibration()
    calib.save(tmp_path / "plain.yaml", skin)
    assert "kinematics" not in (tmp_path / "plain.yaml").read_text()       # absent when off: old files unchanged
    calib.kinematics = {"LShoulderPitch": 0.0123, "LElbowOffsetY": 0.0151}
    calib.kinematics_std = {"LShoulderPitch": 0.0004, "LElbowOffsetY": 0.0002}
    calib.save(tmp_path / "kin.yaml", skin)
    doc = yaml.safe_load((tmp_path / "kin.yaml").read_text())
    assert doc["kinematics"]["LElbowOffsetY"] == {"correction": 0.0151, "unit": "m", "std": 0.0002}
    assert doc["kinematics"]["LShoulderPitch"]["unit"] == "rad"
    back = SkinCalibration.load(tmp_path / "kin.yaml", skin)
    assert back.kinematics == calib.kinematics and back.kinematics_std == calib.kinematics_std
    (tmp_path / "bad.yaml").write_text((tmp_path / "kin.yaml").read_text().replace("LShoulderPitch", "LKnee"))
    with pytest.raises(ConfigError, match="LKnee"):
        SkinCalibration.load(tmp_path / "bad.yaml", skin)


def test_kinematics_off_changes_nothing(real, real_skin):
    """The default (off) and an explicit off: no kinematic stage, no section, the same corrections."""
    default = calibrate(real, real_skin, CalibrationOptions(max_iterations=5, max_repairings=2))
    off = CalibrationOptions(max_iterations=5, max_repairings=2)
    off.set("kinematics", False)                                  # YAML 1.1 reads `off` as false
    assert off.kinematics == "off"
    explicit = calibrate(real, real_skin, off)
    assert default.report.kinematics == {} and default.calibration.kinematics == {}
    assert not any("kinematics" in s["name"] for s in default.report.stages)
    assert default.calibration.to_dict(real_skin) == explicit.calibration.to_dict(real_skin)


@pytest.fixture(scope="module")
def kinematic_run(skin):
    """The left hand on the torso and the head, every joint up to 2 deg off, no noise: calibrated with
    the kinematic unknowns."""
    sim = simulate(skin, load_params("kinematic-error", {"noise_scale": 0.0, "link_errors": {}, "n_touches": 150,
                                                         "pairs": [["l_hand", "torso"], ["l_hand", "head"]]}), 1)
    touches, _ = deduplicate(sim.touches)
    options = CalibrationOptions()
    options.set("kinematics", True)                               # YAML 1.1 reads `on` as true
    return sim, calibrate(touches, skin, options, truth=sim.truth)


@pytest.mark.slow
def test_kinematics_on_recovers_the_simulated_joint_offsets(kinematic_run):
    sim, result = kinematic_run
    kin = result.report.kinematics
    assert kin["accepted"] and kin["mode"] == "on"
    est = kin["corrections"]
    # the joints the touches pin well (std < 0.1 deg) within 0.35 deg (the std is a lower bound: one
    # touch's rows share its pose; HeadYaw, std 0.08 deg, ends 0.31 deg off here, still settling when the
    # passes stop: 0.27 when every solve ran to convergence, where over six seeds of the bench's
    # kinematic-error preset the largest determined offset error was alike, 0.13 / 0.26 against 0.12 /
    # 0.24 deg median / worst with the inexact solves). The weakly determined ones, within 1 deg: with
    # ElbowYaw near 0, ShoulderRoll, ElbowRoll and the elbow offset are one direction to first order
    # (docs/method.md, "Kinematics"), and LShoulderRoll, std 0.19 deg, ends 0.82 deg off on this seed on one
    # machine and within 0.5 on another (the bench's worst over 20 seeds: 1.73 deg)
    for name, entry in est.items():
        if entry["unit"] == "rad":
            err = np.degrees(abs(entry["value"] - sim.truth.kinematics.get(name, 0.0)))
            assert err < (0.35 if np.degrees(entry["std"]) < 0.1 else 1.0), (name, err, entry)
    # the held-out touches come closer, and surely so (the lower end of the gain's 95 % interval above 0). How
    # much depends on the machine's numerics: the same code passed a lower end of 10 % in CI and gave 8 % (15 %
    # closer) in a venv made here later the same day (numpy 2.4.6, scipy 1.17.1)
    held_out = kin["test_taxel_surface_mm"]
    assert held_out["after"] < held_out["before"] and held_out["gain_low"] > 0.0, held_out
    assert {"LShoulderPitch", "LElbowYaw", "HeadYaw"} <= set(est)
    assert result.calibration.kinematics == {n: e["value"] for n, e in est.items()}
    # and the skin sits closer to the truth than a skin-only calibration of the same touches can
    assert result.report.final["truth_taxel_error_mm"]["l_hand"]["median"] < \
        result.report.before["truth_taxel_error_mm"]["l_hand"]["median"]


@pytest.mark.slow
def test_an_unobservable_offset_is_held_and_listed(kinematic_run):
    """A WristYaw offset and the hand mount turned about that axis are one direction: the offset is held
    (not the mount), at nominal, and the report says so; so is HeadPitch against the head mount."""
    _, result = kinematic_run
    kin = result.report.kinematics
    held = {h["name"]: h["reason"] for h in kin["held"]}
    assert {"LWristYaw", "HeadPitch"} <= set(held)
    assert "not determined" in held["LWristYaw"]
    assert "LWristYaw" not in kin["corrections"] and "LWristYaw" not in result.calibration.kinematics
    assert not any("mount" in h for h in result.report.held)


@pytest.mark.slow
def test_kinematics_auto_keeps_the_skin_only_calibration_when_the_robot_is_the_config(skin):
    """On touches of a robot that is the config (no kinematic error) the kinematic unknowns do not enter with
    auto: the held-out figure (closest taxel pairs at the fabric surfaces) gains too little, so the result is
    the skin-only calibration, unchanged, with every unknown listed as held and the figures; on keeps them."""
    sim = simulate(skin, load_params("default", {"n_touches": 120, "pairs": [["l_hand", "torso"]]}), 3)
    touches, _ = deduplicate(sim.touches)
    off = calibrate(touches, skin, CalibrationOptions(), truth=sim.truth)
    auto = calibrate(touches, skin, CalibrationOptions(kinematics="auto"), truth=sim.truth)
    kin = auto.report.kinematics
    assert not kin["accepted"] and kin["corrections"] == {} and auto.calibration.kinematics == {}
    figures = kin["test_taxel_surface_mm"]
    assert figures["gain_low"] < 0.1 and figures["gain_low"] < figures["gain"]
    assert figures["gain"] == pytest.approx(1 - figures["after"] / figures["before"])
    assert [h["name"] for h in kin["held"]] == skin.robot.kinematic_names(["l_arm"])
    assert all("fabric surfaces" in h["reason"] for h in kin["held"])
    assert auto.calibration.to_dict(skin) == off.calibration.to_dict(skin)
    assert auto.report.final["truth_taxel_error_mm"] == off.report.final["truth_taxel_error_mm"]
    on = calibrate(touches, skin, CalibrationOptions(kinematics="on"), truth=sim.truth)
    assert on.report.kinematics["accepted"] and on.calibration.kinematics
    assert on.report.kinematics["test_taxel_surface_mm"] == figures


def test_urdf_takes_the_kinematic_corrections(skin, tmp_path):
    """Joint offsets turn the joint origin about the joint axis, link corrections move it: the URDF's
    frames are the corrected robot's, the joint positions those the joints report."""
    from nao_skin.model.urdf import UrdfModel, expand_xacro

    calib = skin.zero_calibration()
    calib.kinematics = {"LShoulderRoll": 0.02, "LElbowRoll": -0.03, "HeadYaw": 0.01, "RElbowOffsetY": -0.015,
                        "LElbowOffsetY": 0.002}
    calib.save(tmp_path / "kin.yaml", skin)
    urdf = UrdfModel.from_string(expand_xacro(tmp_path / "kin.yaml"), "corrected URDF")
    nominal = UrdfModel.from_string(expand_xacro(), "nominal URDF")
    robot = skin.with_kinematics(calib).robot
    q = random_q(robot, 10, 8)
    positions = {name: q[:, i] for i, name in enumerate(robot.joint_names)}
    got, before = urdf.link_poses(positions), nominal.link_poses(positions)
    for chain in robot.chains.values():
        frames = robot.fk_frames(chain.name, q)
        for k, frame in enumerate(chain.frames):
            np.testing.assert_allclose(got[frame], frames[:, k], atol=1e-9)
    assert np.abs(got["l_elbow_roll_link"] - before["l_elbow_roll_link"]).max() > 1e-3
    # the LElbowRoll joint's origin is turned about its axis by the offset
    joint = urdf.joints["LElbowRoll"]
    turned = nominal.joints["LElbowRoll"].origin @ _axis_rotation(joint.axis, -0.03)
    np.testing.assert_allclose(joint.origin, turned, atol=1e-9)


def _axis_rotation(axis, angle):
    from nao_skin import se3

    out = np.eye(4)
    out[:3, :3] = se3.rotvec_to_matrix(np.asarray(axis) * angle)
    return out


def test_auto_keeps_the_skin_only_calibration_when_the_test_split_gains_too_little(real, real_skin):
    """kinematics=auto: the kinematic stage is undone unless the held-out figure improves by
    kinematics_min_gain; then the calibration is the skin-only one and every unknown is listed as held."""
    fast = dict(max_iterations=5, max_repairings=2)
    off = calibrate(real, real_skin, CalibrationOptions(**fast))
    auto = calibrate(real, real_skin, CalibrationOptions(**fast, kinematics="auto", kinematics_min_gain=0.99))
    kin = auto.report.kinematics
    assert kin["mode"] == "auto" and not kin["accepted"] and kin["corrections"] == {}
    assert [h["name"] for h in kin["held"]] == real_skin.robot.kinematic_names(["l_arm"])
    assert all("kinematics=auto" in h["reason"] for h in kin["held"])
    assert auto.calibration.kinematics == {}
    assert auto.calibration.to_dict(real_skin) == off.calibration.to_dict(real_skin)
    assert auto.report.final == off.report.final
    assert any("reverted" in s for s in auto.report.stages if s["name"].startswith("kinematics"))


@pytest.mark.slow   # four short calibrations with the kinematic path
def test_splits_say_on_which_the_kinematics_were_kept(real, real_skin):
    """--splits K with kinematics=auto: each split decides on its own test touches; the spread says on how
    many it kept the kinematics and with which gain, and report.md lists them."""
    from nao_skin.calibration.report import markdown_report
    from nao_skin.calibration.splits import split_spread

    options = CalibrationOptions(max_iterations=5, max_repairings=2, kinematics="auto", kinematics_min_gain=0.0)
    first = calibrate(real, real_skin, options)
    spread = first.report.splits = split_spread(real, real_skin, options, 2, first=first)
    per_split = [s["kinematics"] for s in spread["per_seed"]]
    assert spread["kinematics_kept"] == sum(k["accepted"] for k in per_split)
    assert all(k["accepted"] == (k["gain_low"] >= 0.0) and k["gain_low"] < k["gain"] for k in per_split)
    md = markdown_report(first.report.to_dict())
    assert f"Kinematics kept on {spread['kinematics_kept']} of 2 splits; each split's held-out gain" in md
    assert "kinematics_kept" not in split_spread(real, real_skin, replace(options, kinematics="off"), 1)


def test_the_held_out_gain_counts_only_with_its_spread():
    """The same mean gain is a gain at 95 % confidence over many touches that agree, not over few that
    scatter; a touch measured once (NaN) does not count."""
    rng = np.random.default_rng(0)
    before = 2.0 + rng.random(200)
    steady = paired_gain(before, before * 0.8 + rng.normal(0, 0.05, 200), 1.645)
    assert steady["gain"] == pytest.approx(0.2, abs=0.01) and steady["gain_low"] > 0.18 and steady["touches"] == 200
    scattered = paired_gain(before[:20], before[:20] * 0.8 + rng.normal(0, 1.0, 20), 1.645)
    assert scattered["gain_low"] < scattered["gain"] - 0.1
    after = before * 0.9
    after[:50] = np.nan
    half = paired_gain(before, after, 1.645)
    assert half["touches"] == 150 and half["gain"] == pytest.approx(0.1)
    assert half["before"] == pytest.approx(before[50:].mean())
    assert np.isnan(paired_gain(before[:1], before[:1], 1.645)["gain_low"])


@pytest.mark.slow
def test_auto_does_not_keep_kinematics_on_a_gain_the_test_split_cannot_vouch_for(skin):
    """Few touches (the bench's few-touches preset, seed 16; 30 test touches), a robot that is the config:
    the kinematic path brought the test split 11 % closer, past the 10 % asked, and auto kept it while the
    true error grew from 0.97 to 1.25 mm. Over 30 touches that gain is not 10 % at 95 % confidence. (The rows
    of that run, ``pairs=cop`` and ``kinematics_pairs=both``: the default rows since 2026-11-29 gain 2 % there.)"""
    from nao_skin.bench.hard import HardCaseSetup, simulate_case

    setup = HardCaseSetup()
    sim, touches, _ = simulate_case(skin, "few-touches", 16, setup)
    auto = calibrate(touches, skin, replace(setup.options, kinematics="auto", kinematics_pairs="both", pairs="cop"),
                     truth=sim.truth)
    kin = auto.report.kinematics
    held_out = kin["test_taxel_surface_mm"]
    assert held_out["gain"] >= 0.1 > held_out["gain_low"], held_out
    assert not kin["accepted"] and auto.calibration.kinematics == {}
    assert all("at 95 % confidence" in h["reason"] for h in kin["held"])


def test_bench_kinematics_rows_say_which_goals_are_met():
    """The bench's summary and goal lines from rows (no calibration run here)."""
    from nao_skin.bench.kinematics import kinematics_goal_lines, kinematics_summary, kinematics_tables, offset_errors

    def row(preset, seed, mode, hand, torso, offset_err=float("nan")):
        parts = {"l_hand": {"median": hand, "p95": 2 * hand}, "torso": {"median": torso, "p95": 2 * torso}}
        return {"preset": preset, "seed": seed, "mode": mode, "status": "ok", "parts": ["l_hand", "torso"],
                "seconds": 1.0, "true_median_mm": (hand + torso) / 2, "true_p95_mm": 2 * max(hand, torso),
                "part_true_mm": parts, "accepted": mode != "off", "held": [], "recovered": {},
                "max_offset_error_deg": offset_err}
    rows = [row("kinematic-error", 0, "off", 12.0, 4.0), row("kinematic-error", 0, "on", 0.4, 0.3, 0.1),
            row("default", 0, "off", 0.4, 0.5), row("default", 0, "on", 0.45, 0.5, 0.3),
            row("default", 0, "auto", 0.4, 0.5)]
    lines = kinematics_goal_lines(rows)
    assert any(line.startswith("kinematic-error, off") and line.endswith("- met") for line in lines)
    assert any("in 1/1 seeds" in line and line.endswith("- met") for line in lines)
    assert any(line.startswith("default, on") and "0.025 mm" in line and line.endswith("NOT met") for line in lines)
    assert any(line.startswith("default, auto") and line.endswith("- met") for line in lines)
    summary = {(s["preset"], s["mode"]): s for s in kinematics_summary(rows)}
    assert summary[("default", "on")]["parts"]["l_hand"]["median"] == 0.45
    # 'where determined': only offsets whose std puts two of them within the goal count
    recovered = {"LShoulderPitch": {"value": 1.0, "true": 1.15, "std": 0.05, "unit": "rad"},
                 "LElbowRoll": {"value": 1.0, "true": 0.3, "std": 0.2, "unit": "rad"},
                 "LElbowOffsetY": {"value": 14.0, "true": 15.0, "std": 0.4, "unit": "m"}}
    rows[1].update(recovered=recovered, **offset_errors(recovered))
    lines = kinematics_goal_lines(rows)
    assert any("worst 0.70 deg over every estimate - NOT met" in line for line in lines)
    assert any("where determined" in line and "1 estimates): worst 0.15 deg - met" in line
               and "weakly determined: LElbowRoll (std 0.20-0.20 deg)" in line for line in lines)
    assert "| kinematic-error | on |" in kinematics_tables(rows)
    # the held-out gain auto decides on, its 95 % bound's range over the seeds, on the auto rows
    rows += [dict(row("default", 1, "auto", 0.4, 0.5), held_out_gain=0.05, held_out_gain_low=-0.012),
             dict(row("default", 2, "auto", 0.4, 0.5), held_out_gain=0.08, held_out_gain_low=0.034)]
    assert "| 3/3 | -1.2 to 3.4 |" in kinematics_tables(rows)


def test_a_scene_without_the_head_holds_the_shoulders_common_turn(skin):
    """Both arms' ShoulderPitch turn about one line, the shoulders' axis: turning them and the torso's skin about it
    changes no touch, so a scene of the arms and the torso has one offset its touches cannot give (the gauge); the
    head's HeadYaw turns about another line and ends it."""
    robot = skin.robot
    assert robot.rotation_gauge(["l_arm"]) == "LShoulderPitch"
    assert robot.rotation_gauge(["r_arm", "l_arm"]) == "LShoulderPitch"
    assert robot.rotation_gauge(["l_arm", "head"]) is None


@pytest.mark.slow
def test_the_scenes_together_find_the_skin_each_scene_alone_misplaces(skin):
    """The scenes-kinematic preset (the real recordings' three scenes, the arms' kinematics off differently): with
    the kinematics free, each scene alone fits itself and misplaces the torso by millimetres; the three together
    place every part within the goal, the gauge held (before it was held, the shoulders' common turn ran off with
    the torso: 7 mm on this seed)."""
    sim = simulate(skin, load_params("scenes-kinematic", {"n_touches": 250}), 0)
    touches, _ = deduplicate(sim.touches)
    options = CalibrationOptions(kinematics="on")
    together = calibrate(touches, skin, options, truth=sim.truth)
    error = together.report.final["truth_taxel_error_mm"]
    assert error["torso"]["median"] < 1.0 and error["l_hand"]["median"] < 1.0
    assert "LShoulderPitch" in [h["name"] for h in together.report.kinematics["held"]]
    alone = calibrate(touches.subset(touches.labels["pair"] == "r_finger-torso"), skin, options, truth=sim.truth)
    assert alone.report.final["truth_taxel_error_mm"]["torso"]["median"] > 2.0
