"""Forward kinematics of the DH robot model (config/nao_h25.yaml).

Known poses are checked against geometry worked out by hand from the Nao's
dimensions (shoulder 98 mm beside and 100 mm above the torso origin, upper arm
105 mm, neck 126.5 mm), batches against an independent per-pose product of
elementary DH matrices built straight from the YAML rows.
"""
import math
import re

import numpy as np
import pytest
import yaml

from nao_skin.errors import ConfigError
from nao_skin.model.robot import RobotModel, parse_angle
from nao_skin.paths import config_dir

ROBOT_YAML = config_dir() / "nao_h25.yaml"


@pytest.fixture(scope="module")
def robot():
    return RobotModel.from_yaml(ROBOT_YAML)


def pose(robot, **angles):
    q = np.zeros((1, len(robot.joint_names)))
    for name, value in angles.items():
        q[0, robot.joint_index[name]] = value
    return q


def random_q(robot, n, seed):
    lo, hi = robot.limits.T
    return np.random.default_rng(seed).uniform(lo, hi, size=(n, len(lo)))


def rot_z(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def rot_x(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def trans(x, y, z):
    out = np.eye(4)
    out[:3, 3] = (x, y, z)
    return out


def reference_fk(rows, joint_values):
    """Rz(offset+q) Tz(d) Tx(a) Rx(alpha), multiplied row by row for one pose, from raw YAML rows."""
    out = np.eye(4)
    for row in rows:
        q = joint_values[row["joint"]] if row["joint"] else 0.0
        a, d = float(row["a"]), float(row["d"])
        alpha, offset = parse_angle(row["alpha"], "test"), parse_angle(row["offset"], "test")
        out = out @ rot_z(offset + q) @ trans(0, 0, d) @ trans(a, 0, 0) @ rot_x(alpha)
    return out


# ---------------------------------------------------------------------- known poses
@pytest.mark.parametrize("chain, side", [("l_arm", 1.0), ("r_arm", -1.0)])
def test_zero_pose_wrist_is_one_upper_arm_ahead_of_the_shoulder(robot, chain, side):
    end = robot.fk(chain, pose(robot))[0]
    np.testing.assert_allclose(end[:3, 3], [0.105, side * 0.098, 0.1], atol=1e-12)
    # the forearm (-y of the hand frame) points forward (+x of the torso) with the arm stretched out
    np.testing.assert_allclose(-end[:3, 1], [1.0, 0.0, 0.0], atol=1e-12)


def test_shoulder_pitch_of_90_degrees_points_the_arm_down(robot):
    end = robot.fk("l_arm", pose(robot, LShoulderPitch=math.pi / 2))[0]
    np.testing.assert_allclose(end[:3, 3], [0.0, 0.098, 0.1 - 0.105], atol=1e-12)


def test_shoulder_roll_swings_the_arm_sideways_about_the_shoulder(robot):
    roll = 1.0
    left = robot.fk("l_arm", pose(robot, LShoulderRoll=roll))[0]
    right = robot.fk("r_arm", pose(robot, RShoulderRoll=-roll))[0]
    np.testing.assert_allclose(left[:3, 3], [0.105 * math.cos(roll), 0.098 + 0.105 * math.sin(roll), 0.1], atol=1e-12)
    # the right arm mirrors the left one in the sagittal plane
    np.testing.assert_allclose(right[:3, 3], left[:3, 3] * [1, -1, 1], atol=1e-12)


def test_elbow_roll_turns_the_forearm_towards_the_body_midline(robot):
    bend = -1.0  # left elbow flexion is negative on the Nao
    end = robot.fk("l_arm", pose(robot, LElbowRoll=bend))[0]
    np.testing.assert_allclose(end[:3, 3], [0.105, 0.098, 0.1], atol=1e-12)  # the hand frame sits at the elbow
    np.testing.assert_allclose(-end[:3, 1], [math.cos(bend), math.sin(bend), 0.0], atol=1e-12)


def test_head_yaw_and_pitch_turn_the_face(robot):
    zero = robot.fk("head", pose(robot))[0]
    np.testing.assert_allclose(zero[:3, 3], [0.0, 0.0, 0.1265], atol=1e-12)
    np.testing.assert_allclose(zero[:3, 2], [1, 0, 0], atol=1e-12)   # head z: the face, forward at rest
    np.testing.assert_allclose(zero[:3, 0], [0, 0, 1], atol=1e-12)   # head x: up at rest
    left = robot.fk("head", pose(robot, HeadYaw=math.pi / 2))[0]
    np.testing.assert_allclose(left[:3, 2], [0, 1, 0], atol=1e-12)
    down = robot.fk("head", pose(robot, HeadPitch=0.5))[0]
    np.testing.assert_allclose(down[:3, 2], [math.cos(0.5), 0, -math.sin(0.5)], atol=1e-12)
    np.testing.assert_allclose(down[:3, 3], zero[:3, 3], atol=1e-12)


def test_base_chain_is_the_identity(robot):
    q = random_q(robot, 3, seed=0)
    np.testing.assert_array_equal(robot.fk(None, q), np.broadcast_to(np.eye(4), (3, 4, 4)))
    assert robot.end_frame(None) == "torso"


# ---------------------------------------------------------------------- batches
@pytest.mark.parametrize("chain", ["head", "l_arm", "r_arm"])
def test_batch_equals_independent_per_pose_product(robot, chain):
    rows = yaml.safe_load(ROBOT_YAML.read_text())["chains"][chain]
    q = random_q(robot, 40, seed=1)
    batch = robot.fk(chain, q)
    assert batch.shape == (40, 4, 4)
    for n in range(len(q)):
        values = dict(zip(robot.joint_names, q[n]))
        np.testing.assert_allclose(batch[n], reference_fk(rows, values), atol=1e-12)
        np.testing.assert_allclose(batch[n], robot.fk(chain, q[n])[0], atol=1e-15)


@pytest.mark.parametrize("chain", ["head", "l_arm", "r_arm"])
def test_every_frame_is_a_rigid_transform(robot, chain):
    frames = robot.fk_frames(chain, random_q(robot, 200, seed=2))
    rot = frames[..., :3, :3]
    np.testing.assert_allclose(np.swapaxes(rot, -1, -2) @ rot, np.broadcast_to(np.eye(3), rot.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-12)
    np.testing.assert_array_equal(frames[..., 3, :], np.broadcast_to([0, 0, 0, 1.0], frames.shape[:-2] + (4,)))
    np.testing.assert_allclose(frames[:, -1], robot.fk(chain, random_q(robot, 200, seed=2)), atol=0)


def test_joint_columns_follow_joint_names(robot):
    # moving one joint of the left arm moves only the left arm
    q = pose(robot, LElbowYaw=0.7, RShoulderPitch=0.0)
    np.testing.assert_allclose(robot.fk("r_arm", q), robot.fk("r_arm", pose(robot)), atol=0)
    assert not np.allclose(robot.fk("l_arm", pose(robot, LShoulderPitch=0.7)), robot.fk("l_arm", pose(robot)))
    assert robot.chain_joint_names("l_arm") == ["LShoulderPitch", "LShoulderRoll", "LElbowYaw", "LElbowRoll", "LWristYaw"]


def test_unknown_chain_is_a_config_error(robot):
    with pytest.raises(ConfigError, match="unknown chain 'l_leg'"):
        robot.fk("l_leg", pose(robot))


# ---------------------------------------------------------------------- config errors
def write_robot(tmp_path, mutate):
    doc = yaml.safe_load(ROBOT_YAML.read_text())
    mutate(doc)
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_chain_naming_an_unknown_joint_fails_naming_file_and_joint(tmp_path):
    path = write_robot(tmp_path, lambda d: d["chains"]["l_arm"][3].update(joint="LElbowYawn"))
    with pytest.raises(ConfigError) as err:
        RobotModel.from_yaml(path)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith(f"{path}: chain 'l_arm' row 3: unknown joint 'LElbowYawn'")


@pytest.mark.parametrize("mutate, expected", [
    (lambda d: d["joints"].update(HeadYaw=[1.0]), "joint 'HeadYaw' limits must be [lower, upper]"),
    (lambda d: d["joints"].update(HeadYaw=[1.0, -1.0]), "joint 'HeadYaw' lower limit 1.0 is not below upper -1.0"),
    # finite, but the pose search's draw between them overflowed (a traceback in simulate)
    (lambda d: d["joints"].update(HeadYaw=[-1e308, 1e308]), "joint 'HeadYaw' limits [-1e+308, 1e+308] reach beyond"
                                                            " two turns (|limit| <= 12.57 rad)"),
    (lambda d: d["chains"]["head"][1].update(alpha="half a turn"), "chain 'head' row 1 alpha: cannot read 'half a turn' as an angle"),
    (lambda d: d["chains"]["head"][0].pop("d"), "chain 'head' row 0: missing d"),
    (lambda d: d["chains"]["r_arm"][0].update(frame="l_shoulder_base"),
     "chain 'r_arm' row 0: frame 'l_shoulder_base' is also chain 'l_arm' row 0's"),
    (lambda d: d["chains"]["head"][0].update(frame="torso"), "chain 'head' row 0: frame 'torso' is also the base frame"),
    (lambda d: d.pop("chains"), "a robot config needs 'joints' and 'chains' mappings"),
    (lambda d: d.update(chains=["head"]), "a robot config needs 'joints' and 'chains' mappings"),
    (lambda d: d.update(joints=["HeadYaw"]), "a robot config needs 'joints' and 'chains' mappings"),
    (lambda d: d.update(links=[1]), "'links' must be a mapping of link name to {chain, row, param}"),
    (lambda d: d["links"]["LElbowOffsetY"].update(row="two"),
     "link 'LElbowOffsetY' needs chain, row (a whole number) and param (a or d)"),
    (lambda d: d["joints"].update(HeadYaw=[float("nan"), 1.0]), "joint 'HeadYaw': nan is not a finite number"),
    (lambda d: d["joints"].update(HeadYaw=[float("-inf"), 1.0]), "joint 'HeadYaw': -inf is not a finite number"),
    (lambda d: d["chains"]["l_arm"][1].update(d=float("nan")), "chain 'l_arm' row 1 d: nan is not a finite number"),
    (lambda d: d["chains"]["l_arm"][1].update(d=1e300), "chain 'l_arm' row 1 d: 1e+300 m is beyond 10 m"),
    (lambda d: d["chains"]["l_arm"][1].update(joint=["LShoulderPitch"]),
     "chain 'l_arm' row 1: unknown joint '['LShoulderPitch']'"),
    # frames become TF frame ids and URDF link names: a number, a space or markup made a URDF nothing reads
    (lambda d: d["chains"]["head"][1].update(frame=5), "chain 'head' row 1 frame: 5 is not a frame name"),
    (lambda d: d["chains"]["head"][1].update(frame="head link"),
     "chain 'head' row 1 frame: 'head link' is not a frame name"),
    (lambda d: d["chains"]["head"][1].update(frame='head<&"'), "chain 'head' row 1 frame: 'head<&\"' is not a frame name"),
    (lambda d: d.update(base_frame=[1]), "base_frame: [1] is not a frame name"),
    (lambda d: d.update(name=None), "name: None is not a robot name"),
    # a key the config does not have was ignored: a misspelt 'links' dropped every link without a word
    (lambda d: d.update(linkz=d.pop("links")), "unknown key 'linkz' (did you mean 'links'?)"),
    (lambda d: d["chains"]["head"][1].update(foo=1), "chain 'head' row 1: unknown key 'foo'"),
    (lambda d: d["links"]["LElbowOffsetY"].update(sign=-1), "link 'LElbowOffsetY': unknown key 'sign'"),
    # the simulator's body: a misspelt joint would rest at 0 without a word
    (lambda d: d["body"]["rest_posture"].update(HeadYow=[0, 0.1]), "body: rest_posture: HeadYow: not a joint of"),
    (lambda d: d["body"]["rest_posture"].update(HeadYaw=[0, -0.1]), "body: rest_posture: HeadYaw: expected [mean,"),
    (lambda d: d["body"]["rest_posture"].update(HeadYaw=0.3), "body: rest_posture: HeadYaw: expected [mean, spread]"),
    (lambda d: d["body"].update(box=[[0.1, -0.1], [0, 0], [0, 0]]), "body: box: expected [[low, high]] metres"),
    (lambda d: d["body"].update(box=[[-0.1, 0.1]]), "body: box: expected [[low, high]] metres"),
    (lambda d: d["body"].update(hand_end=[0, float("nan"), 0]), "body: hand_end: nan is not a finite number"),
    (lambda d: d["body"].update(hand_end=[0, 1e9, 0]), "body: hand_end: expected [x, y, z] metres"),
    (lambda d: d["body"].update(rest=1), "body: unknown key 'rest'"),
    (lambda d: d["body"].update(rest_posture=False), "body: rest_posture: expected a mapping of joint names"),
], ids=["one-limit", "limits-swapped", "limits-beyond-two-turns", "angle-words", "missing-d", "frame-twice", "frame-is-base", "no-chains", "chains-list", "joints-list",
        "links-list", "link-row-word", "nan-limit", "infinite-limit", "nan-length", "huge-length", "joint-list",
        "frame-number", "frame-space", "frame-markup", "base-frame-list", "name-null", "top-key", "row-key",
        "link-key", "rest-unknown-joint", "rest-negative-spread", "rest-number", "box-swapped", "box-one-axis",
        "hand-end-nan", "hand-end-huge", "body-key", "rest-false"])
def test_malformed_robot_config_fails_with_one_line(tmp_path, mutate, expected):
    path = write_robot(tmp_path, mutate)
    with pytest.raises(ConfigError) as err:
        RobotModel.from_yaml(path)
    assert str(err.value).startswith(f"{path}: {expected}")
    assert "\n" not in str(err.value)


def test_a_frame_name_may_carry_a_tf_prefix(tmp_path):
    path = write_robot(tmp_path, lambda d: d["chains"]["head"][1].update(frame="nao1/head_link"))
    assert "nao1/head_link" in RobotModel.from_yaml(path).chains["head"].frames


def test_angle_strings(robot):
    assert parse_angle("-pi/2", "x") == -math.pi / 2
    assert parse_angle("2*pi/3", "x") == 2 * math.pi / 3
    assert parse_angle("pi", "x") == math.pi
    assert parse_angle("0.25", "x") == 0.25
    for text in ("pi/0", "pi/0.0", ".pi"):     # a division by zero and a bare dot were tracebacks
        with pytest.raises(ConfigError, match=f"x: cannot read '{re.escape(text)}' as an angle"):
            parse_angle(text, "x")
    np.testing.assert_allclose(robot.limits[robot.joint_index["LElbowRoll"]], [-1.5446, -0.0349])
