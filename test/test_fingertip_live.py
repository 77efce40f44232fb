"""Fingertip scenes live (issue 61, the node suite): the simulated robot's fingertip touches and stray presses, the
scenes of a record session, the fingertip in the heat-map and the guidance for fingertip scenes.

Pure parts first (no ROS), then a whole ``nao-skin record --robot sim --scene r_finger-torso`` session over DDS:
its bag holds every fingertip touch the simulated robot made and none of its stray presses (recomputed here from
the same seed: the simulator's ground truth), it calibrates live, and the bag reads in ``rosbags`` with the
fingertip marks.
"""
from __future__ import annotations

import json
import signal
import subprocess
import sys

import numpy as np
import pytest

from nao_skin.errors import ConfigError
from nao_skin.guidance.capture import fingertip_targets, guidance, targets_from_json
from nao_skin.live.heatmap import fingertip_spheres
from nao_skin.model.skin import load_skin
from nao_skin.session.params import sim_overrides
from nao_skin.session.record import record_session
from nao_skin.sim.params import load_params
from nao_skin.sim.play import STRAY_MIN_DISTANCE, live_touches
from nao_skin.sim.simulate import simulate
from nao_skin.touch.fingertip import FingertipJudge

SCENE = ("r_finger", "torso")


@pytest.fixture(scope="module")
def skin():
    return load_skin()


def fingertip_params(skin, per_pair: int, scenes=("r_finger-torso",)):
    """The simulation parameters sim_robot plays for ``pairs`` of its parameter (``scene:=`` sets them)."""
    return load_params("default", sim_overrides(per_pair, list(scenes), skin.parts, tuple(skin.robot.fingertips)))


def activation_slots(touches, k: int, part: str) -> np.ndarray:
    a = np.flatnonzero((touches.act_touch == k) & (touches.act_part == touches.part_index(part)))
    return touches.act_slot[a]


# ---------------------------------------------------------------------------- the simulated robot's presses
def test_stray_presses_fire_the_part_with_no_fingertip_near_and_the_judge_drops_only_them(skin):
    seed = 2
    played = live_touches(skin, fingertip_params(skin, 20), seed)
    touches, stray = played.touches, played.touches.labels["stray"]
    sim = simulate(skin, fingertip_params(skin, 20), seed).touches
    # per fingertip touch at the experimenter's rate; the simulator's own touches played in their order
    originals = np.sum(sim.labels["duplicate_of"] < 0)
    assert stray.sum() + played.pairs["stray"]["given_up"] == round(played.params.scaled("experimenter_hand") * originals)
    assert stray.sum() >= 2 and played.pairs["stray"]["touches"] == stray.sum()
    np.testing.assert_array_equal(touches.joints[~stray], sim.joints)
    assert list(touches.fingertip_of_touch[stray]) == [-1] * stray.sum()
    # ground truth: every fingertip at least STRAY_MIN_DISTANCE from the spot a stray press fired
    body = skin.with_kinematics(played.truth)
    centre, radius = played.truth.fingertip_sphere(skin.robot, "r_finger")
    tip = np.einsum("nij,j->ni", body.robot.fk("r_arm", touches.joints[stray])[:, :3, :3], centre) \
        + body.robot.fk("r_arm", touches.joints[stray])[:, :3, 3]
    assert np.all(np.linalg.norm(tip - touches.labels["contact_point"][stray], axis=1) - radius >= STRAY_MIN_DISTANCE)
    # the recorder's judge (nominal calibration, its default gate) takes every fingertip touch, no stray press
    judge = FingertipJudge(skin, [SCENE])
    said = [judge("torso", activation_slots(touches, k, "torso"), touches.joints[k]) for k in range(touches.n_touches)]
    own = ~stray & ~touches.labels["non_self_contact"]
    assert [said[k] for k in np.flatnonzero(own)] == ["r_finger"] * own.sum()
    assert [said[k] for k in np.flatnonzero(stray)] == [None] * stray.sum()


def test_a_session_without_fingertip_scenes_plays_exactly_the_simulators_touches(skin):
    params = load_params("default", sim_overrides(3, [""]))
    played, sim = live_touches(skin, params, 7).touches, simulate(skin, params, 7).touches
    assert not played.labels["stray"].any() and played.n_touches == sim.n_touches
    for field in ("joints", "act_slot", "act_pressure", "contact_cop", "stamps"):
        np.testing.assert_array_equal(getattr(played, field), getattr(sim, field))


# ---------------------------------------------------------------------------- scene:= / --scene
def test_scenes_set_the_robot_the_recorder_the_heatmap_and_the_guidance(tmp_path):
    specs = {s.name: s for s in record_session("sim", bag_path=str(tmp_path / "bag"),
                                               scene=["r_finger-torso, r_hand-torso"], spelling="command")}
    assert specs["sim_robot"].overrides["pairs"] == ["r_finger-torso", "r_hand-torso"]
    assert specs["calibrate"].overrides["guidance_pairs"] == ["r_finger-torso", "r_hand-torso"]
    assert specs["pairing_recorder"].overrides["fingertip_scenes"] == ["r_finger-torso"]
    assert specs["skin_heatmap"].overrides["fingertip_scenes"] == ["r_finger-torso"]
    real = {s.name: s for s in record_session("nao", bag_path=str(tmp_path / "bag2"), scene="l_finger-head",
                                              with_robot_state_publisher=False)}
    assert "sim_robot" not in real and real["pairing_recorder"].overrides["fingertip_scenes"] == ["l_finger-head"]
    plain = {s.name: s for s in record_session("sim", bag_path=str(tmp_path / "bag3"))}
    assert "pairs" not in plain["sim_robot"].overrides and "fingertip_scenes" not in plain["pairing_recorder"].overrides


@pytest.mark.parametrize("scene,says", [("r_finger-legs", "scene:= 'r_finger-legs': expected HAND-PART"),
                                        ("x_finger-torso", "scene:= 'x_finger-torso': expected HAND-PART"),
                                        ("r_finger-r_hand", "r_finger-r_hand"),
                                        ("torso-head", "torso-head")])
def test_a_scene_naming_an_unknown_part_or_fingertip_is_one_line(tmp_path, scene, says):
    with pytest.raises(ConfigError) as refused:
        record_session("sim", bag_path=str(tmp_path / "bag"), scene=scene)
    assert says in str(refused.value) and "\n" not in str(refused.value)
    assert not (tmp_path / "bag").exists()


def test_nao_skin_record_refuses_a_bad_scene_with_one_line_and_exit_2(tmp_path):
    done = subprocess.run([sys.executable, "-m", "nao_skin.cli", "record", "--print", "--bag", str(tmp_path / "b"),
                           "--scene", "r_finger-legs"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.strip().count("\n") == 0 and "--scene 'r_finger-legs'" in done.stderr, done.stderr


# ---------------------------------------------------------------------------- heat-map and guidance
def test_the_heatmap_places_the_fingertip_sphere_in_its_arms_end_frame(skin):
    (tip, frame, centre, radius), = fingertip_spheres(skin, [SCENE, ("r_finger", "head")])
    assert (tip, frame) == ("r_finger", skin.robot.chains["r_arm"].end_frame)
    np.testing.assert_array_equal(centre, skin.robot.fingertip("r_finger").point)
    calibration = skin.zero_calibration()
    calibration.fingertips["r_finger"] = np.array([0.001, -0.002, 0.003, 0.0005])
    (_, _, moved, bigger), = fingertip_spheres(skin, [SCENE], calibration)
    np.testing.assert_allclose(moved - centre, [0.001, -0.002, 0.003])
    assert bigger == pytest.approx(radius + 0.0005)


def test_guidance_for_a_fingertip_scene_points_at_the_taxels_no_touch_reached(skin):
    touches = simulate(skin, fingertip_params(skin, 12), 3).touches
    part = skin.parts["torso"]
    reached = set(touches.act_slot[touches.act_part == touches.part_index("torso")].tolist())
    unreached = {int(part.triangle_ids[part.slot_triangle[s]]) for s in part.slots if int(s) not in reached}
    targets = fingertip_targets(touches, skin, [SCENE])
    assert {t.triangle_id for t in targets} == unreached and unreached
    assert all(t.hand == "r_finger" and t.touched == "torso" and t.pose is None for t in targets)
    never = [int(t.reason.split()[0]) for t in targets]
    assert never == sorted(never, reverse=True)           # most unreached taxels first
    # the guidance puts them first and its readers (heat-map, sim_robot) take a fingertip as the presser
    advice = guidance(touches, skin, None, pairs=[SCENE, ("r_hand", "torso")], max_targets=3, poses=False)
    assert [t.hand for t in advice.targets] == ["r_finger"] * 3
    read, skipped = targets_from_json(json.dumps(advice.to_dict()), skin)
    assert skipped == 0 and [t["hand"] for t in read] == ["r_finger"] * 3
    # a triangle reached since is no target any more
    first = targets[0].triangle_id
    slots = part.slots[part.slot_triangle[part.slots] == list(part.triangle_ids).index(first)]
    more = touches.subset(np.arange(touches.n_touches))          # a copy: its arrays are its own
    rows = np.flatnonzero(more.act_part == more.part_index("torso"))
    more.act_slot[rows[:len(slots)]] = slots
    assert first not in {t.triangle_id for t in fingertip_targets(more, skin, [SCENE])}


# ---------------------------------------------------------------------------- a whole session over DDS
@pytest.mark.middleware
def test_a_simulated_fingertip_session_records_every_fingertip_touch_and_no_stray_press(tmp_path, skin):
    pytest.importorskip("rclpy")
    from ros_harness import Listener, Proc, ros_env, unique_domain_id
    from std_msgs.msg import String
    from test_record_session import FAST_PLAY, assert_same_touches
    from visualization_msgs.msg import MarkerArray

    from nao_skin.formats.bag import read_touches
    from nao_skin.nodes.topics import LATCHED, STATUS_TOPIC

    seed, per_pair = 2, 20
    played = live_touches(skin, fingertip_params(skin, per_pair), seed).touches
    stray = played.labels["stray"]
    made = ~stray & ~played.labels["non_self_contact"]     # the fingertip's own contact fired
    assert stray.sum() >= 2 and made.sum() >= 15
    bag = tmp_path / "touches"
    argv = [sys.executable, "-m", "nao_skin.cli", "record", "--robot", "sim", "--scene", "r_finger-torso",
            "--bag", str(bag), "--seed", str(seed), "--param", f"sim_robot.touches_per_pair={per_pair}",
            "--param", "calibrate.live_every_touches=10"]
    for k, v in FAST_PLAY.items():
        argv += ["--param", f"sim_robot.{k}={v}"]
    domain = unique_domain_id()
    listener = session = None
    code = None
    try:
        listener = Listener(domain)
        robot = listener.subscribe(String, "/sim_robot/status", keep=lambda m: json.loads(m.data))
        progress = listener.subscribe(String, "/nao_skin/recorder/progress", keep=lambda m: json.loads(m.data))
        status = listener.subscribe(String, STATUS_TOPIC, qos=LATCHED, keep=lambda m: json.loads(m.data))
        heat = listener.subscribe(MarkerArray, "/nao_skin/heatmap", qos=5)
        session = Proc(argv, ros_env(domain), tmp_path, "record")
        assert listener.spin_until(lambda: robot and robot[-1]["done"], timeout=240, procs=[session]), \
            (robot[-1:], session.stderr()[-3000:])
        assert robot[-1]["played"] == played.n_touches and robot[-1]["strays"] == stray.sum(), robot[-1]
        # every press the robot made counted by the recorder: taken, or dropped as no fingertip near
        assert listener.spin_until(lambda: progress and progress[-1]["touches"] == made.sum()
                                   and progress[-1]["dropped"].get("no fingertip near", 0) == stray.sum(),
                                   timeout=120, procs=[session]), progress[-1:]
        updated = lambda: [s for s in status if s.get("state") == "updated" and s.get("touches", 0) >= 10]  # noqa: E731
        assert listener.spin_until(updated, timeout=240, procs=[session]), (status[-2:], session.stderr()[-3000:])
        assert "torso" in updated()[-1]["parts"], updated()[-1]
        tips = [m for m in heat[-1].markers if m.ns == "fingertip"] if heat else []
        assert [(m.header.frame_id, m.text) for m in tips] == [(skin.robot.chains["r_arm"].end_frame, "r_finger")]
        np.testing.assert_allclose([tips[0].pose.position.x, tips[0].pose.position.y, tips[0].pose.position.z],
                                   skin.robot.fingertip("r_finger").point)
        code = session.stop(signal.SIGINT, timeout=60)
    finally:
        if listener is not None:
            listener.close()
        if session is not None and code is None:
            session.stop(signal.SIGKILL)
    assert code == 0, session.stderr()[-3000:]

    # the bag: exactly the fingertip touches the robot made, in order, none of the stray presses
    got, report = read_touches(bag, skin)
    assert not report.skipped, report.lines()
    assert_same_touches(got, played.subset(made))
    assert list(np.array(got.fingertips)[got.fingertip_of_touch]) == ["r_finger"] * got.n_touches

    # and it reads in rosbags, each fingertip touch marked at its stamp
    from rosbags.highlevel import AnyReader

    bag_dir = bag if (bag / "metadata.yaml").exists() else next(p.parent for p in bag.rglob("metadata.yaml"))
    with AnyReader([bag_dir]) as reader:
        marks = [c for c in reader.connections if c.topic == "/nao_skin/fingertip_touch"]
        msgs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=marks)]
        joints = [c for c in reader.connections if c.topic == "/joint_states"]
        stamps = [reader.deserialize(raw, c.msgtype).header.stamp for c, _, raw in reader.messages(connections=joints)]
    assert [m.header.frame_id for m in msgs] == ["r_finger"] * made.sum()
    assert [(m.header.stamp.sec, m.header.stamp.nanosec) for m in msgs] == [(s.sec, s.nanosec) for s in stamps]
