"""The self-touch simulator: seeded bytes, realistic statistics, honest geometry, presets, bad input.

Real parts throughout: the packaged robot and skin configs, the real recording
(for the statistics; see real_data.py), real rosbag2 files written and read back.
The robot's body is the only thing simulated, which is the point of the module.
"""
from __future__ import annotations

import ast
import dataclasses
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import yaml
from real_data import LAYOUTS, RECORDING  # noqa: E402

from nao_skin.calibration.context import activation_positions
from nao_skin.cli import main as cli_main
from nao_skin.errors import ConfigError
from nao_skin.model.skin import SkinModel, load_skin
from nao_skin.sim.params import SimParams, default_params_file, load_params, make_params, preset_names
from nao_skin.sim.simulate import simulate
from nao_skin.touch.contacts import DEFAULT_MAX_NEIGHBOR_DIST


@pytest.fixture(scope="module")
def skin() -> SkinModel:
    return load_skin()


@pytest.fixture(scope="module")
def ideal(skin):
    """Every pair, no noise and no defects (preset 'ideal')."""
    return simulate(skin, load_params("ideal", {"n_touches": 12}), seed=2)


# ------------------------------------------------------------------------------ determinism
def _tree_bytes(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_gives_same_bytes(tmp_path, capsys):
    args = ["simulate", "--seed", "7", "--touches-per-pair", "6"]
    assert cli_main(args + ["--out", str(tmp_path / "a")]) == 0
    assert cli_main(args + ["--out", str(tmp_path / "b")]) == 0
    assert cli_main(["simulate", "--seed", "8", "--touches-per-pair", "6", "--out", str(tmp_path / "c")]) == 0
    a, b, c = (_tree_bytes(tmp_path / d) for d in "abc")
    assert set(a) >= {"touches/metadata.yaml", "truth_calibration.yaml", "simulation.yaml",
                      "truth_taxels/l_hand.txt", "truth_taxels/torso.txt"}
    assert any(name.startswith("touches/") and name != "touches/metadata.yaml" for name in a)
    assert a == b
    assert a["truth_calibration.yaml"] != c["truth_calibration.yaml"]
    # a second run into the same directory refuses to overwrite the bag, in one line
    assert cli_main(args + ["--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err.strip()
    assert "(simulation.yaml, touches, truth_" in err and "--force" in err and len(err.splitlines()) == 1


def test_bag_and_truth_files_read_back(tmp_path, skin):
    from nao_skin.formats.bag import read_touches
    from nao_skin.model.skin import SkinCalibration

    params = load_params("default", {"n_touches": 5, "pairs": [["l_hand", "torso"], ["r_hand", "head"]]})
    result = simulate(skin, params, seed=3)
    from nao_skin.sim.simulate import write_outputs

    write_outputs(result, skin, tmp_path)
    back, _ = read_touches(tmp_path / "touches", skin)
    ts = result.touches
    # a touch bag keeps every recorded touch (duplicates included) with its joints and taxels
    assert back.n_touches == ts.n_touches
    np.testing.assert_allclose(back.joints, ts.joints[np.argsort(ts.stamps, kind="stable")], atol=1e-12)
    assert len(back.act_slot) == len(ts.act_slot)
    truth = SkinCalibration.load(tmp_path / "truth_calibration.yaml", skin)
    for name in skin.parts:
        np.testing.assert_allclose(truth.parts[name].mount, result.truth.parts[name].mount, atol=1e-9)
        np.testing.assert_allclose(truth.parts[name].triangles, result.truth.parts[name].triangles, atol=1e-9)
    meta = yaml.safe_load((tmp_path / "simulation.yaml").read_text())
    assert meta["seed"] == 3 and meta["params"]["n_touches"] == 5


# ------------------------------------------------------------------------------ statistics
def _real_stats(real_dir: Path) -> dict:
    data = ast.literal_eval((real_dir / RECORDING).read_text())
    per_touch, per_contact, triangles = [], [], {"l_hand": set(), "torso": set()}
    for contacts, _joints in data.values():
        per_touch.append(len(contacts))
        for contact in contacts.values():
            per_contact.append(len(contact["taxelInfo"]))
            triangles[contact["skinPart"]].update(int(s) // 12 for s in contact["taxelInfo"])
    layout_tris = 0
    for name in LAYOUTS.values():
        rows = np.loadtxt(real_dir / name)
        layout_tris += len(np.unique(np.flatnonzero(np.any(rows != 0, axis=1)) // 12))
    return {"touches": len(per_touch), "contacts per touch": float(np.mean(per_touch)),
            "taxels per contact": float(np.mean(per_contact)),
            "share of triangles touched": sum(len(t) for t in triangles.values()) / layout_tris}


def _sim_stats(result, skin) -> dict:
    ts = result.touches
    touched = sum(len(np.unique(ts.act_slot[ts.act_part == i] // 12)) for i in range(len(ts.part_names)))
    total = sum(len(skin.parts[n].triangle_ids) for n in ts.part_names)
    return {"touches": ts.n_touches,
            "contacts per touch": float(np.mean(np.bincount(ts.contact_touch, minlength=ts.n_touches))),
            "taxels per contact": float(np.mean(np.bincount(ts.act_contact))),
            "share of triangles touched": touched / total}


@pytest.mark.slow   # simulates a full recording and loads the real one
def test_statistics_resemble_the_real_recording(skin, real_dir):
    # the same pair as the real file, with as many touches as a tenth of it would take to cover the skin
    result = simulate(skin, load_params("default", {"pairs": [["l_hand", "torso"]], "n_touches": 120}), seed=0)
    real, sim = _real_stats(real_dir), _sim_stats(result, skin)
    print(f"\n{'statistic':28s} {'real':>8s} {'simulated':>10s}")
    for key in real:
        print(f"{key:28s} {real[key]:8.2f} {sim[key]:10.2f}")
    for key in ("contacts per touch", "taxels per contact", "share of triangles touched"):
        assert 0.5 <= sim[key] / real[key] <= 2.0, (key, real[key], sim[key])


# ------------------------------------------------------------------------------ geometry
def _closest_pairs(result, skin, calib):
    """Per touch: the closest activated taxel pair between the two parts, as (distance, normal part)."""
    ts = result.touches
    pos = activation_positions(ts, skin, calib)
    normal = ts.labels["contact_normal"]
    dist, along = np.full(ts.n_touches, np.inf), np.full(ts.n_touches, np.inf)
    for t in range(ts.n_touches):       # a test-sized loop over touches, not over taxels
        sel = ts.act_touch == t
        parts = np.unique(ts.act_part[sel])
        assert len(parts) == 2, f"touch {t} fires {len(parts)} parts"
        a = pos[sel & (ts.act_part == parts[0])]
        b = pos[sel & (ts.act_part == parts[1])]
        d = a[:, None] - b[None]
        norm = np.linalg.norm(d, axis=2)
        i, j = np.unravel_index(np.argmin(norm), norm.shape)
        dist[t], along[t] = norm[i, j], abs(d[i, j] @ normal[t])
    return dist, along


def test_geometry_is_honest(ideal, skin):
    ts = ideal.touches
    gap = ts.labels["gap"]
    assert not ts.labels["outlier"].any() and (ts.labels["duplicate_of"] < 0).all()
    np.testing.assert_allclose(ts.joints, ts.labels["joints_true"])      # no encoder noise in 'ideal'
    dist, along = _closest_pairs(ideal, skin, ideal.truth)
    print(f"\ntruth: closest taxel pair {np.median(dist) * 1e3:.2f} mm median, {dist.max() * 1e3:.2f} mm max;"
          f" fabric gap {gap.mean() * 1e3:.2f} mm")
    # true skin: the touching taxels face each other across the fabric (never closer than it allows,
    # never further than one lattice half-step sideways plus the compliance)
    assert np.all(along <= gap + 0.0015)
    assert np.all(dist <= gap + 0.0035)
    assert np.all(dist >= 0.5 * gap)
    assert abs(np.median(dist) - np.median(gap)) < 0.0015
    nominal, _ = _closest_pairs(ideal, skin, None)
    print(f"nominal: closest taxel pair {np.median(nominal) * 1e3:.1f} mm median")
    assert np.median(nominal) > 0.01
    assert np.mean(nominal <= gap + 0.0035) < 0.2


def test_true_hand_mount_is_a_rotation_about_the_forearm(ideal, skin):
    for hand in ("l_hand", "r_hand"):
        mount = ideal.truth.parts[hand].mount
        assert np.degrees(np.linalg.norm(mount[3:])) == pytest.approx(160.0, abs=1e-6)
        # the skin stays on the hand: same distances from the forearm axis (hand frame y axis)
        part = skin.parts[hand]
        nominal, _ = part.taxel_positions(None)
        true, _ = ideal.true_taxels[hand]
        radius = lambda p: np.hypot(p[part.slots, 0], p[part.slots, 2])  # noqa: E731
        assert np.mean(np.abs(radius(true) - radius(nominal))) < 0.004
        # ... but far from where the layout says
        assert np.median(np.linalg.norm(true[part.slots] - nominal[part.slots], axis=1)) > 0.03


def test_touches_spread_over_both_skins(ideal, skin):
    ts = ideal.touches
    for name, info in ideal.pairs.items():
        hand, target = name.split("-")
        rows = np.flatnonzero(ts.labels["pair"] == name)
        assert info["touches"] == len(rows) == 12
        for part in (hand, target):
            sel = np.isin(ts.act_touch, rows) & (ts.act_part == ts.part_index(part))
            share = len(np.unique(ts.act_slot[sel] // 12)) / len(skin.parts[part].triangle_ids)
            assert share > 0.3, (name, part, share)


def test_joint_angles_within_limits(ideal, skin):
    lo, hi = skin.robot.limits.T
    q = ideal.touches.labels["joints_true"]
    assert np.all(q >= lo) and np.all(q <= hi)


# ------------------------------------------------------------------------------ defects and presets
def test_defects_are_labelled(skin):
    params = load_params("noisy", {"n_touches": 40, "pairs": [["r_hand", "torso"], ["l_hand", "head"]]})
    ts = simulate(skin, params, seed=5).touches
    dup = np.flatnonzero(ts.labels["duplicate_of"] >= 0)
    assert len(dup) > 0
    for row in dup:
        orig = ts.labels["duplicate_of"][row]
        np.testing.assert_array_equal(ts.joints[row], ts.joints[orig])
        np.testing.assert_array_equal(ts.act_slot[ts.act_touch == row], ts.act_slot[ts.act_touch == orig])
        assert ts.stamps[row] > ts.stamps[orig]
    exp = ts.labels["experimenter_hand"]
    assert exp.any() and np.all(ts.labels["outlier"][exp])
    # the experimenter's hand is an extra contact on the robot's hand, away from the self-contact
    hands = np.isin(np.array(ts.part_names)[ts.contact_part], ["r_hand", "l_hand"])
    per_touch = np.bincount(ts.contact_touch[hands], minlength=ts.n_touches)
    assert per_touch[exp].mean() > per_touch[~ts.labels["outlier"]].mean()
    noise = ts.joints - ts.labels["joints_true"]
    assert 0.5 * 0.006 < noise.std() < 2 * 0.006
    assert np.all(np.diff(ts.stamps) > 0)


@pytest.mark.parametrize("preset", [n for n in preset_names() if n != "default"])
def test_every_preset_runs(preset, skin):
    params = load_params(preset, {"n_touches": 6, "pairs": [["l_hand", "torso"], ["r_hand", "head"]]})
    result = simulate(skin, params, seed=1)
    ts = result.touches
    assert ts.n_touches >= 12
    assert np.all(ts.parts_of_touch().sum(axis=1) == 2)
    if preset == "cad-rotation":
        for name, corr in result.truth.parts.items():
            assert not corr.patches.any() and not corr.triangles.any()
            angle = np.degrees(np.linalg.norm(corr.mount[3:]))
            assert angle == pytest.approx(160.0) if name.endswith("hand") else angle == 0.0
    if preset == "perturb-5cm":
        for hand in ("l_hand", "r_hand"):
            np.testing.assert_allclose(result.truth.parts[hand].mount, [0, -0.05, 0, 0, 0, 0], atol=1e-12)
    if preset == "planar-poses":
        # all contacts of a part on one band: the contact points span a line, not an area
        torso = ts.labels["contact_point"][ts.labels["pair"] == "l_hand-torso"]
        spread = np.linalg.svd(torso - torso.mean(axis=0), compute_uv=False)
        assert spread[1] < 0.3 * spread[0]
    if preset == "noisy":
        assert params.scaled("joint_noise") == 2 * make_params({}).joint_noise


def test_few_touches_leave_triangles_under_ten_activations(skin):
    ts = simulate(skin, load_params("few-touches", {"pairs": [["l_hand", "torso"]]}), seed=0).touches
    part = ts.part_index("torso")
    per_triangle = Counter(ts.act_slot[ts.act_part == part] // 12)
    touches_per_triangle = Counter()
    for tri in per_triangle:
        touches_per_triangle[tri] = len(np.unique(ts.act_touch[(ts.act_part == part) & (ts.act_slot // 12 == tri)]))
    under = [t for t in skin.parts["torso"].triangle_ids if touches_per_triangle.get(int(t), 0) < 10]
    assert len(under) > len(skin.parts["torso"].triangle_ids) / 2


def test_outliers_20_has_a_fifth_non_self_contacts(skin):
    result = simulate(skin, load_params("outliers-20", {"n_touches": 60, "pairs": [["l_hand", "torso"]]}), seed=4)
    ts = result.touches
    off = ts.labels["non_self_contact"]
    assert 0.1 < off.mean() < 0.3
    # those touches are really off: under the true skin, the hand's taxels are far from the contact
    pos = activation_positions(ts, skin, result.truth)
    on_hand = ts.act_part == ts.part_index("l_hand")
    dist = np.linalg.norm(pos - ts.labels["contact_point"][ts.act_touch], axis=1)
    nearest = np.full(ts.n_touches, np.inf)
    np.minimum.at(nearest, ts.act_touch[on_hand], dist[on_hand])
    clean = ~ts.labels["outlier"]
    assert np.all(nearest[off] > 0.02)
    assert np.median(nearest[clean]) < 0.005


# ------------------------------------------------------------------------------ parameters
def test_every_default_is_defined_once_in_the_yaml():
    doc = yaml.safe_load(default_params_file().read_text())
    given = {f.name for f in dataclasses.fields(SimParams) if f.default is dataclasses.MISSING}
    assert set(doc["defaults"]) == given           # skinManager's contact distance is its own constant
    assert make_params({}).to_dict() == {**doc["defaults"], "cluster_distance": DEFAULT_MAX_NEIGHBOR_DIST}
    assert make_params({}) == load_params("default")
    assert {"cad-rotation", "perturb-5cm", "few-touches", "outliers-20", "planar-poses", "noisy"} <= set(doc["presets"])


@pytest.mark.parametrize("overrides, words", [
    ({"joint_noise": -0.01}, ["joint_noise", "negative"]),
    ({"missed_taxel": 1.5}, ["missed_taxel", "probability"]),
    ({"pairs": [["l_hand", "torso"], ["l_hand", "torso"]]}, ["twice"]),
    ({"n_touches": 0}, ["n_touches"]),
    ({"spot_size": [0.01, 0.005]}, ["spot_size"]),
    ({"jont_noise": 0.1}, ["unknown field", "jont_noise"]),
    ({"n_touches": 10 ** 12}, ["'n_touches' 1000000000000 is more than 100000 touches per pair"]),
    ({"hand_mount_offset": [float("nan"), 0, 0]}, ["hand_mount_offset", "[x, y, z] metres"]),
    ({"link_errors": {"LElbowOffsetY": 1e300}}, ["link_errors", "map link names to metres"]),
    ({"spot_radius": 1e300}, ["'spot_radius' must be a finite number of at most 1e+06"]),
    # the batched pose search asked for 12 GiB and ended in a traceback
    ({"pose_restarts": 100_000_000}, ["'pose_restarts' 100000000 is more than 1000"]),
    ({"pose_iterations": 10 ** 9}, ["'pose_iterations' 1000000000 is more than 10000"]),
    # had failed later, naming the temporary bag
    ({"start_stamp": -5}, ["'start_stamp' must be seconds since 1970 from 0 to 2000000000, got -5"]),
    ({"start_stamp": 2.2e9}, ["'start_stamp' must be seconds since 1970", "got 2200000000.0"]),   # past 2038's int32
    ({"start_stamp": 1e20}, ["'start_stamp' must be seconds since 1970", "got 1e+20"]),
    # each wrote a recording its own readers merged, lost touches of, or whose truth they refused
    ({"touch_interval": [0, 0]}, ["'touch_interval' must start at 0.001 s or more"]),
    ({"cluster_distance": 1000}, ["'cluster_distance' 1000 m is beyond 0.5 m"]),
    ({"patch_rotation": 150}, ["'patch_rotation' 150 rad is more than half a turn"]),
    ({"joint_offset_deg": 800}, ["'joint_offset_deg' 800 is more than 20.0 deg"]),
    ({"link_errors": {"LElbowOffsetY": 9.0}}, ["'link_errors' beyond 0.1 m"]),
    ({"start_stamp": float("nan")}, ["'start_stamp' must be seconds since 1970", "got nan"]),
    # a Python warning 'divide by zero' on stderr, and a recording
    ({"press_reach": [0, 0]}, ["'press_reach' must start above 0 m (a compliant fabric), got [0, 0]"]),
])
def test_bad_parameters_fail_in_one_line(overrides, words):
    with pytest.raises(ConfigError) as exc:
        make_params(overrides)
    message = str(exc.value)
    assert len(message.splitlines()) == 1
    for word in words:
        assert word in message


def test_another_robot_rests_and_keeps_out_of_its_own_body(tmp_path):
    """The rest posture and the torso box are the robot config's (``body``): a robot whose joints are named
    otherwise simulates with its own, and one without a body rests at 0 and poses without a torso box."""
    from nao_skin.paths import config_dir

    text = (config_dir() / "nao_h25.yaml").read_text()
    renamed = tmp_path / "other_robot.yaml"
    renamed.write_text(text.replace("HeadYaw", "NeckYaw"))
    other = load_skin(robot_config=renamed)
    assert "NeckYaw" in other.robot.body.rest_posture and other.robot.body.box is not None
    nao = simulate(load_skin(), {"n_touches": 3, "pairs": [["l_hand", "head"]]}, seed=2).touches
    ours = simulate(other, {"n_touches": 3, "pairs": [["l_hand", "head"]]}, seed=2).touches
    np.testing.assert_array_equal(ours.joints, nao.joints)          # the same robot under other names
    bodiless = tmp_path / "bodiless.yaml"
    bodiless.write_text(text[:text.index("\nbody:")] + "\n")
    bare = load_skin(robot_config=bodiless)
    assert bare.robot.body.rest_posture == {} and bare.robot.body.box is None
    assert simulate(bare, {"n_touches": 3, "pairs": [["l_hand", "torso"]]}, seed=2).touches.n_touches >= 3


@pytest.mark.parametrize("pair", [["torso", "head"], ["l_hand", "r_hand"]])
def test_a_pair_the_skin_config_does_not_make_touch_fails_in_one_line(skin, pair):
    """What touches what is the skin config's ``self_touch``: the simulator presses a touching part on a
    touched one, and says so before it simulates anything."""
    with pytest.raises(ConfigError, match=rf"^the simulator cannot make {pair[0]}-{pair[1]} touch \(it presses a"
                                          r" touching part, r_hand or l_hand, on a touched one, torso or head: the"
                                          r" skin config's self_touch\)$"):
        simulate(skin, {"pairs": [pair], "n_touches": 10}, seed=0)


def test_a_params_file_whose_pair_cannot_touch_is_named_and_nothing_written(tmp_path, capsys):
    params = tmp_path / "sim.yaml"
    params.write_text("defaults:\n  pairs: [[torso, head]]\npresets: {}\n")
    assert cli_main(["simulate", "--params", str(params), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"nao-skin simulate: error: {params}: preset 'default': the simulator cannot make torso-head touch (it"
        f" presses a touching part, r_hand or l_hand, on a touched one, torso or head: the skin config's self_touch)")
    assert not (tmp_path / "out").exists()


def test_unknown_preset_and_missing_part_fail_in_one_line(skin, capsys, tmp_path):
    with pytest.raises(ConfigError, match="unknown preset 'nope'.*cad-rotation"):
        load_params("nope")
    headless = SkinModel(skin.robot, {k: v for k, v in skin.parts.items() if k != "head"}, "headless.yaml",
                         skin.self_touch)
    with pytest.raises(ConfigError, match="r_hand-head: skin part 'head' is not in headless.yaml"):
        simulate(headless, {"n_touches": 2}, seed=0)
    assert cli_main(["simulate", "--preset", "nope", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "unknown preset 'nope'" in err and len(err.splitlines()) == 1
    assert cli_main(["simulate", "--touches-per-pair", "0", "--out", str(tmp_path)]) == 2
    assert cli_main(["simulate", "--touches-per-pair", str(10 ** 12), "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == \
        "nao-skin simulate: error: --touches-per-pair 1000000000000: expected a whole number in 1..100000"
    assert not any(tmp_path.iterdir())       # nothing written on bad input


@pytest.mark.parametrize("overrides", [{"spot_radius": 1000.0}, {"fabric_thickness": 1000.0}])
def test_parameters_no_touch_can_be_simulated_with_are_one_line(skin, overrides):
    with pytest.raises(ConfigError) as exc:
        simulate(skin, {"n_touches": 2, "pairs": [["l_hand", "torso"]], **overrides}, seed=0)
    assert str(exc.value).startswith("simulation parameters: no touch of l_hand-torso could be posed and fired (")


@pytest.mark.parametrize("text, says", [
    ("defaults: [1, 2]\n", "expected 'defaults:' and 'presets:' mappings"),
    ("presets: [1]\n", "expected 'defaults:' and 'presets:' mappings"),
    ("presets: {x: [1]}\n", "preset 'x': expected a mapping of parameter: value"),
    # a robot config given for the parameters was simulated with the built-in defaults, exit 0
    ("joints: {HeadYaw: [-2, 2]}\nchains: {}\n", "expected 'defaults:' and 'presets:' mappings"),
    ("defaults: {}\npresetz: {x: {}}\n", "unknown key 'presetz' (did you mean 'presets'?); it takes defaults, presets"),
    # a field misspelt in a preset that does not run, or under a preset 'default' that never runs, was not read
    ("defaults: {}\npresets: {x: {}, y: {bogus: 1}}\n", "preset 'y': unknown field(s) bogus"),
    ("defaults: {}\npresets: {x: {}, default: {n_touches: 3}}\n",
     "preset 'default': the defaults are 'defaults:'; put its fields there"),
    ("defaults: {n_touchez: 3}\npresets: {x: {}}\n", "defaults: unknown field(s) n_touchez"),
], ids=["defaults-list", "presets-list", "preset-list", "another-config", "unknown-key", "other-preset-field",
        "preset-default", "defaults-field"])
def test_a_parameters_file_of_the_wrong_shape_is_one_line(tmp_path, text, says):
    path = tmp_path / "simulation.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_params("x", path=path)
    assert str(exc.value) == f"{path}: {says}"


def test_a_preset_named_by_a_number_is_found_by_that_number(tmp_path):
    """YAML reads `5:` as the number 5: '--preset 5' said "unknown preset '5' (known: default, 5)"."""
    path = tmp_path / "simulation.yaml"
    path.write_text("defaults: {}\npresets: {5: {n_touches: 7}}\n")
    assert load_params("5", path=path).n_touches == 7
    path.write_text("defaults: {}\npresets: {5: {}, '5': {}}\n")
    with pytest.raises(ConfigError) as exc:
        load_params("5", path=path)
    assert str(exc.value) == f"{path}: preset '5' is given twice"


def test_dataclass_fields_are_documented_in_the_yaml():
    text = default_params_file().read_text()
    for f in dataclasses.fields(SimParams):
        assert f"  {f.name}:" in text or f"  # {f.name}:" in text, f.name


# ------------------------------------------------------------------------------ bundled recording
BUNDLE = Path(__file__).resolve().parents[1] / "bags" / "sim_default"


def test_bundled_recording_matches_the_simulator(skin, tmp_path):
    meta = yaml.safe_load((BUNDLE / "simulation.yaml").read_text())
    assert meta["seed"] == 0 and meta["preset"] == "default"
    assert meta["params"] == load_params("default", {"n_touches": 1000}).record()
    # the truth does not depend on the number of touches: regenerate it cheaply, byte for byte
    from nao_skin.sim.simulate import write_outputs

    write_outputs(simulate(skin, load_params("default", {"n_touches": 1}), seed=0), skin, tmp_path,
                  preset="default", with_bag=False)
    for name in ["truth_calibration.yaml"] + [f"truth_taxels/{p}.txt" for p in skin.parts]:
        assert (tmp_path / name).read_bytes() == (BUNDLE / name).read_bytes(), name
    bag_meta = yaml.safe_load((BUNDLE / "touches" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    joint_msgs = {t["topic_metadata"]["name"]: t["message_count"] for t in bag_meta["topics_with_message_count"]}
    recorded = sum(info["recorded"] for info in meta["pairs"].values())
    assert joint_msgs["/joint_states"] == recorded
    assert all(info["touches"] == 1000 for info in meta["pairs"].values())


def test_simulate_and_nominal_take_the_skin_as_every_command_does(tmp_path, real_dir):
    """--skin, --taxels and --robot in simulate and nominal too: a robot's own layouts are simulated (and their
    nominal calibration written) without a skin config of their own."""
    hand_layout = real_dir / LAYOUTS["l_hand"]
    assert cli_main(["simulate", "--taxels", f"l_hand={hand_layout}", "--touches-per-pair", "2",
                     "--params", str(tmp_path / "sim.yaml"), "--out", str(tmp_path / "sim")]) == 2    # no such file
    (tmp_path / "sim.yaml").write_text("defaults:\n  pairs: [[l_hand, torso]]\npresets: {}\n")
    assert cli_main(["simulate", "--taxels", f"l_hand={hand_layout}", "--touches-per-pair", "2",
                     "--params", str(tmp_path / "sim.yaml"), "--out", str(tmp_path / "sim")]) == 0
    meta = yaml.safe_load((tmp_path / "sim" / "simulation.yaml").read_text())
    assert meta["skin"] == f"nao_skin.yaml + {hand_layout.name}"
    own = load_skin(taxel_files={"l_hand": hand_layout})
    truth = (tmp_path / "sim" / "truth_taxels" / "l_hand.txt").read_text()
    assert truth.count("\n") >= len(own.parts["l_hand"].slots)
    assert cli_main(["nominal", "--taxels", f"l_hand={hand_layout}", "--out", str(tmp_path / "nominal.yaml")]) == 0
    nominal = yaml.safe_load((tmp_path / "nominal.yaml").read_text())
    ids = {int(t) for t in nominal["parts"]["l_hand"]["triangles"]}
    assert ids == {int(t) for t in own.parts["l_hand"].triangle_ids} != {int(t) for t in load_skin().parts["l_hand"].triangle_ids}
