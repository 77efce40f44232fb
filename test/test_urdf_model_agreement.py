"""The expanded URDF (real xacro, real files) and the Python model describe the same frames.

For random joint configurations within the limits, every DH frame and every
skin mount/patch/triangle frame, computed by walking the URDF's joints from
``torso``, equals the model's pose within 1e-9 m and 1e-9 rad, for the
nominal calibration and for one with large random corrections.
"""
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from nao_skin import cli
from nao_skin.errors import ConfigError
from nao_skin.model.robot import RobotModel
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.model.urdf import UrdfModel, check_calibration_origins, default_xacro, expand_xacro, rotation_angle
from nao_skin.paths import config_dir, default_skin_config

TOL_M = 1e-9
TOL_RAD = 1e-9
NOMINAL = config_dir() / "calibration_nominal.yaml"
BAG = Path(__file__).resolve().parents[1] / "bags" / "sim_default" / "touches"


@pytest.fixture(scope="module")
def skin():
    return SkinModel.from_yaml(default_skin_config())


@pytest.fixture(scope="module")
def nominal_urdf():
    return UrdfModel.from_string(expand_xacro(), "nominal URDF")


def random_q(robot, n, seed):
    lo, hi = robot.limits.T
    return np.random.default_rng(seed).uniform(lo, hi, size=(n, len(lo)))


def random_calibration(skin, seed):
    """A few mm everywhere, up to ~2.5 rad on the mounts (the real hand mount is ~160 degrees off)."""
    rng = np.random.default_rng(seed)
    calib = skin.zero_calibration()
    for corr in calib.parts.values():
        axis = rng.normal(size=3)
        corr.mount[:] = np.r_[rng.uniform(-0.005, 0.005, 3), rng.uniform(1.5, 2.5) * axis / np.linalg.norm(axis)]
        corr.patches[:] = np.c_[rng.uniform(-0.004, 0.004, corr.patches[:, :3].shape),
                                rng.uniform(-0.2, 0.2, corr.patches[:, 3:].shape)]
        corr.triangles[:] = np.c_[rng.uniform(-0.003, 0.003, corr.triangles[:, :3].shape),
                                  rng.uniform(-0.2, 0.2, corr.triangles[:, 3:].shape)]
    return calib


def model_frames(skin, q, calib):
    """Every frame name -> (N, 4, 4) pose in the torso frame, from the Python model."""
    robot = skin.robot
    out = {}
    for chain in robot.chains.values():
        frames = robot.fk_frames(chain.name, q)
        out.update({name: frames[:, k] for k, name in enumerate(chain.frames)})
    for name, part in skin.parts.items():
        end = robot.fk(part.chain, q)[:, None]
        mount, patches, triangles = part.frame_poses(calib.parts[name] if calib else None)
        out[part.mount_frame] = end[:, 0] @ mount
        for i, pid in enumerate(part.patch_ids):
            out[part.patch_frame(pid)] = end[:, 0] @ patches[i]
        for i, tid in enumerate(part.triangle_ids):
            out[part.triangle_frame(tid)] = end[:, 0] @ triangles[i]
    return out


def assert_agree(urdf, model_poses, q, joint_names):
    urdf_poses = urdf.link_poses({name: q[:, i] for i, name in enumerate(joint_names)})
    worst_m, worst_rad = 0.0, 0.0
    for frame, expected in model_poses.items():
        got = urdf_poses[frame]
        worst_m = max(worst_m, np.abs(got[:, :3, 3] - expected[:, :3, 3]).max())
        worst_rad = max(worst_rad, rotation_angle(got[:, :3, :3], expected[:, :3, :3]).max())
    assert worst_m <= TOL_M, f"worst translation difference {worst_m:.3g} m"
    assert worst_rad <= TOL_RAD, f"worst rotation difference {worst_rad:.3g} rad"
    return worst_m, worst_rad


# ---------------------------------------------------------------------- agreement
def test_nominal_urdf_agrees_with_the_model(skin, nominal_urdf):
    urdf = nominal_urdf
    assert urdf.root == "torso"
    q = random_q(skin.robot, 60, seed=10)
    frames = model_frames(skin, q, None)
    # the URDF has exactly these frames: body DH frames and skin frames, no taxels, nothing else
    assert set(urdf.links) == set(frames) | {"torso"}
    assert_agree(urdf, frames, q, skin.robot.joint_names)


def test_corrected_urdf_agrees_with_the_model(skin, tmp_path):
    calib = random_calibration(skin, seed=11)
    path = tmp_path / "calibration.yaml"
    calib.save(path, skin)
    urdf = UrdfModel.from_string(expand_xacro(path), str(path))
    q = random_q(skin.robot, 60, seed=12)
    assert_agree(urdf, model_frames(skin, q, calib), q, skin.robot.joint_names)
    # the corrections are large enough that agreeing with the nominal model would be impossible
    nominal = model_frames(skin, q, None)
    moved = urdf.link_poses({n: q[:, i] for i, n in enumerate(skin.robot.joint_names)})["l_hand_skin_mount"]
    assert rotation_angle(moved[:, :3, :3], nominal["l_hand_skin_mount"][:, :3, :3]).min() > 1.0


def test_urdf_joints_are_the_naoqi_joints_with_their_limits(skin, nominal_urdf):
    urdf = nominal_urdf
    robot = skin.robot
    assert sorted(urdf.moving_joint_names) == sorted(robot.joint_names)
    for name in robot.joint_names:
        joint = urdf.joints[name]
        assert joint.type == "revolute"
        np.testing.assert_allclose([joint.lower, joint.upper], robot.limits[robot.joint_index[name]], rtol=0, atol=0)
    fixed = [j for j in urdf.joints.values() if j.type == "fixed"]
    assert all(j.name == f"{j.child}_joint" for j in fixed)
    # skin frames hang off the chain end the model uses
    for part in skin.parts.values():
        assert urdf.joints[f"{part.mount_frame}_joint"].parent == part.parent_frame


def test_dh_rows_with_a_link_length_expand_to_exact_frames(tmp_path):
    """Rows with a != 0 need the two-joint form of the xacro; another robot config may have them."""
    doc = yaml.safe_load((config_dir() / "nao_h25.yaml").read_text())
    doc["chains"]["l_arm"][3]["a"] = 0.015          # driven row
    doc["chains"]["l_arm"][4]["a"] = -0.02
    doc["chains"]["head"][0].update(a=0.01, offset="pi/3", alpha=0.2)   # fixed row
    path = tmp_path / "robot_with_a.yaml"
    path.write_text(yaml.safe_dump(doc))
    robot = RobotModel.from_yaml(path)
    urdf = UrdfModel.from_string(expand_xacro(NOMINAL, robot_config=path), str(path))
    q = random_q(robot, 40, seed=13)
    frames = {}
    for chain in robot.chains.values():
        poses = robot.fk_frames(chain.name, q)
        frames.update({name: poses[:, k] for k, name in enumerate(chain.frames)})
    assert_agree(urdf, frames, q, robot.joint_names)


# ---------------------------------------------------------------------- nominal file and commands
def test_committed_nominal_calibration_is_what_the_command_writes(tmp_path):
    out = tmp_path / "calibration_nominal.yaml"
    assert cli.main(["nominal", "--skin-config", str(default_skin_config()), "--out", str(out)]) == 0
    assert out.read_text() == NOMINAL.read_text(), \
        "config/calibration_nominal.yaml is stale: run nao-skin nominal --out config/calibration_nominal.yaml"


def test_urdf_command_writes_the_expanded_urdf(tmp_path, skin):
    calib = random_calibration(skin, seed=14)
    cal_path = tmp_path / "calibration.yaml"
    calib.save(cal_path, skin)
    out = tmp_path / "nao.urdf"
    assert cli.main(["urdf", "--calibration", str(cal_path), "--out", str(out)]) == 0
    urdf = UrdfModel.from_file(out)
    q = random_q(skin.robot, 10, seed=15)
    assert_agree(urdf, model_frames(skin, q, calib), q, skin.robot.joint_names)


def test_xacro_command_line_expands_the_file_as_is(tmp_path, nominal_urdf):
    """`xacro urdf/nao_skin.urdf.xacro` from the venv, with its default (relative) config paths."""
    exe = Path(sys.executable).with_name("xacro")
    if not exe.exists():
        exe = shutil.which("xacro")
    if not exe:
        pytest.fail("no xacro executable next to this Python (docker/setup_venv.sh installs it)")
    xacro_file = default_xacro()
    done = subprocess.run([str(exe), str(xacro_file.relative_to(xacro_file.parents[1]))],
                          cwd=xacro_file.parents[1], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    from_cli = UrdfModel.from_string(done.stdout, "xacro CLI")
    from_api = nominal_urdf
    assert from_cli.links == from_api.links
    for name, joint in from_api.joints.items():
        np.testing.assert_array_equal(from_cli.joints[name].origin, joint.origin)


# ---------------------------------------------------------------------- bad calibration files
def test_an_origin_that_is_no_number_is_said_as_such(skin, tmp_path):
    """A NaN in an origin was said as 'origin is nan m / 0 rad off the pose its correction gives'."""
    doc = yaml.safe_load(NOMINAL.read_text())
    doc["parts"]["r_hand"]["mount"]["origin"]["xyz"][0] = float("nan")
    path = tmp_path / "nan.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError) as err:
        check_calibration_origins(path, skin)
    assert str(err.value).startswith(f"{path}: part 'r_hand' mount: origin.xyz and origin.rpy must be finite numbers"
                                     f" (the URDF and /tf read them), not [nan, "), str(err.value)


def test_origin_edited_by_hand_is_caught_naming_file_and_frame(skin, tmp_path):
    doc = yaml.safe_load(NOMINAL.read_text())
    tid = next(iter(doc["parts"]["head"]["triangles"]))
    doc["parts"]["head"]["triangles"][tid]["origin"]["xyz"][0] += 0.002
    path = tmp_path / "edited.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError) as err:
        check_calibration_origins(path, skin)
    line = f"{path}: part 'head' triangle {tid}: origin is 0.002 m / 0 rad off the pose its correction gives"
    assert str(err.value).startswith(line)
    assert cli.main(["urdf", "--calibration", str(path), "--out", str(tmp_path / "x.urdf")]) == 2
    assert not (tmp_path / "x.urdf").exists()
    # every command that reads a calibration: the model would use the correction, /tf the origin
    with pytest.raises(ConfigError, match=re.escape(line)):
        SkinCalibration.load(path, skin)
    for args in (["stats", str(BAG), "--calibration", str(path)],
                 ["calibrate", str(BAG), "--prior", str(path), "--out", str(tmp_path / "out")]):
        assert cli.main(args) == 2
    assert not (tmp_path / "out").exists()
    # an entry without an origin is a correction written by hand: taken as it is
    del doc["parts"]["head"]["triangles"][tid]["origin"]
    path.write_text(yaml.safe_dump(doc))
    SkinCalibration.load(path, skin)


def test_missing_frame_entry_is_caught(skin, tmp_path):
    doc = yaml.safe_load(NOMINAL.read_text())
    pid = next(iter(doc["parts"]["torso"]["patches"]))
    del doc["parts"]["torso"]["patches"][pid]
    path = tmp_path / "partial.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match="holds 108 frames and 0 kinematic corrections where its contents line"
                                          " says 109 and 0: the file was cut short or edited"):
        check_calibration_origins(path, skin)
    del doc["contents"]       # as a file written by hand, without the count: the URDF check still names the frame
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError) as err:
        check_calibration_origins(path, skin)
    assert str(err.value) == f"{path}: part 'torso' patch {pid}: missing (the URDF would lack frame 'torso_skin_patch_{pid}')"


def test_expand_xacro_with_a_missing_or_broken_file_is_one_line(tmp_path):
    with pytest.raises(ConfigError, match=r"calibration file for the URDF does not exist$"):
        expand_xacro(tmp_path / "nothing.yaml")
    broken = tmp_path / "broken.yaml"
    broken.write_text("parts: {torso: {mount: {frame: x}}}\n")
    with pytest.raises(ConfigError) as err:
        expand_xacro(broken)
    assert str(err.value).startswith(f"{broken}: xacro expansion of nao_skin.urdf.xacro failed")
    assert "\n" not in str(err.value)


@pytest.mark.middleware   # ROS's URDF parser: check_urdf comes with the middleware (setup_venv.sh --with-yarp)
def test_urdfdom_parses_the_expanded_urdf(tmp_path):
    """urdfdom is the parser robot_state_publisher uses; its check_urdf comes with pip's cmeel-urdfdom."""
    exe = Path(sys.executable).with_name("check_urdf")
    exe = str(exe) if exe.exists() else shutil.which("check_urdf")
    if not exe:
        pytest.fail("check_urdf not installed: run docker/setup_venv.sh --with-yarp (make test does)")
    out = tmp_path / "nao.urdf"
    out.write_text(expand_xacro())
    done = subprocess.run([exe, str(out)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "root Link: torso has 4 child(ren)" in done.stdout   # 3 chains + the torso skin mount


def test_a_robot_frame_named_like_a_skin_frame_is_refused_not_written_twice(tmp_path):
    """A robot config whose frame is named like a frame the xacro makes for the skin (or for its own rows)
    gave a URDF with that link and its joint twice, exit 0, which every URDF reader refuses."""
    doc = yaml.safe_load((config_dir() / "nao_h25.yaml").read_text())
    doc["chains"]["head"][0]["frame"] = "torso_skin_patch_0"
    robot = tmp_path / "robot.yaml"
    robot.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError) as err:
        expand_xacro(robot_config=robot)
    assert str(err.value) == (f"{robot}: the URDF would define the link 'torso_skin_patch_0' twice: a frame or"
                              f" joint of the robot config is named like a skin frame or another generated name;"
                              f" rename it")


def test_a_kinematic_correction_in_exponent_notation_reaches_the_urdf(tmp_path, skin):
    """'2e-3' is a number to nao_skin (YAML 1.2) but text to the YAML the xacro loads: the urdf command failed
    inside xacro ("unsupported operand type(s) for +: 'int' and 'str'")."""
    calib = tmp_path / "calibration.yaml"
    text = (config_dir() / "calibration_nominal.yaml").read_text()
    doc = yaml.safe_load(text)
    doc["kinematics"] = {"HeadYaw": {"correction": 0.002, "unit": "rad"}}
    doc["contents"]["kinematics"] = 1
    calib.write_text(yaml.safe_dump(doc, sort_keys=False).replace("correction: 0.002", "correction: 2e-3"))
    assert "correction: 2e-3" in calib.read_text()
    urdf = UrdfModel.from_string(expand_xacro(calib))
    plain = UrdfModel.from_string(expand_xacro(config_dir() / "calibration_nominal.yaml"))
    moved = [j.name for j in urdf.joints.values() if not np.allclose(j.origin, plain.joints[j.name].origin)]
    assert moved == ["HeadYaw"], moved
    assert rotation_angle(plain.joints["HeadYaw"].origin[:3, :3], urdf.joints["HeadYaw"].origin[:3, :3]) == \
        pytest.approx(0.002)
