"""Skin model: nominal frames reproduce the layouts, corrections move taxels as geometry says,
calibration files round-trip, bad configs fail in one line naming the file and the problem.

Expected motions are computed from the layout files alone (centroids, normals),
not from the model's frames, so a wrong frame convention makes them fail.
"""

import numpy as np
import pytest
import yaml

from nao_skin import se3
from nao_skin.errors import ConfigError, DataError
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.model.taxel_file import SLOTS_PER_TRIANGLE, read_taxel_file
from nao_skin.paths import config_dir, default_skin_config


@pytest.fixture(scope="module")
def skin():
    return SkinModel.from_yaml(default_skin_config())


def layout(skin, part):
    spec = yaml.safe_load(default_skin_config().read_text())["parts"][part]
    return read_taxel_file(default_skin_config().parent / spec["taxel_file"])


def random_q(skin, n, seed):
    lo, hi = skin.robot.limits.T
    return np.random.default_rng(seed).uniform(lo, hi, size=(n, len(lo)))


def random_calibration(skin, seed, mount_angle=2.5):
    rng = np.random.default_rng(seed)
    calib = skin.zero_calibration()
    for corr in calib.parts.values():
        axis = rng.normal(size=3)
        corr.mount[:] = np.r_[rng.uniform(-0.005, 0.005, 3), mount_angle * axis / np.linalg.norm(axis)]
        corr.patches[:] = np.c_[rng.uniform(-0.004, 0.004, corr.patches[:, :3].shape),
                                rng.uniform(-0.1, 0.1, corr.patches[:, 3:].shape)]
        corr.triangles[:] = np.c_[rng.uniform(-0.003, 0.003, corr.triangles[:, :3].shape),
                                  rng.uniform(-0.1, 0.1, corr.triangles[:, 3:].shape)]
    return calib


# ---------------------------------------------------------------------- nominal
@pytest.mark.parametrize("part", ["r_hand", "l_hand", "torso", "head"])
def test_nominal_corrections_reproduce_the_layout(skin, part):
    p = skin.part(part)
    taxels = layout(skin, part)
    pos, nor = p.taxel_positions(p.zero_correction())
    present = taxels.present
    np.testing.assert_array_equal(p.present, present)
    np.testing.assert_allclose(pos[present], taxels.positions[present], atol=1e-15)
    np.testing.assert_allclose(nor[present], taxels.normals[present], atol=1e-15)
    assert np.all(np.isnan(pos[~present]))


def test_nominal_corrections_reproduce_the_real_layouts(tmp_path, real_dir):
    config = tmp_path / "real_skin.yaml"
    config.write_text(yaml.safe_dump({
        "robot": str(config_dir() / "nao_h25.yaml"),
        "parts": {"l_hand": {"chain": "l_arm", "taxel_file": str(real_dir / "l_hand.taxels.txt")},
                  "torso": {"chain": None, "taxel_file": str(real_dir / "torso.taxels.txt")}},
        "self_touch": {"touching": ["l_hand"], "touched": ["torso"]}}))
    skin = SkinModel.from_yaml(config)
    for part, name in (("l_hand", "l_hand.taxels.txt"), ("torso", "torso.taxels.txt")):
        taxels = read_taxel_file(real_dir / name)
        pos, nor = skin.part(part).taxel_positions()
        np.testing.assert_allclose(pos[taxels.present], taxels.positions[taxels.present], atol=1e-15)
        np.testing.assert_allclose(nor[taxels.present], taxels.normals[taxels.present], atol=1e-15)
        # real_selftouch/README.md: patch = triangle // 16 (the default when a config lists no patches)
        p = skin.part(part)
        np.testing.assert_array_equal(p.patch_ids[p.triangle_patch], p.triangle_ids // 16)


# ---------------------------------------------------------------------- known corrections
def test_mount_translation_shifts_every_taxel(skin):
    p = skin.part("l_hand")
    corr = p.zero_correction()
    corr.mount[:3] = [0.01, -0.02, 0.005]
    moved, normals = p.taxel_positions(corr)
    base, base_normals = p.taxel_positions()
    # the nominal mount has the chain end's axes, so the shift is the correction itself
    np.testing.assert_allclose(moved[p.slots] - base[p.slots], np.broadcast_to([0.01, -0.02, 0.005], (len(p.slots), 3)),
                               atol=1e-15)
    np.testing.assert_allclose(normals[p.slots], base_normals[p.slots], atol=1e-15)


def test_mount_rotation_turns_the_part_about_its_taxel_centroid(skin):
    p = skin.part("torso")
    taxels = layout(skin, "torso")
    pts = taxels.positions[taxels.present]
    centre = pts.mean(axis=0)
    angle = 2.8  # large, as the real hand mount error (~160 degrees)
    corr = p.zero_correction()
    corr.mount[3:] = [0.0, 0.0, angle]
    moved, normals = p.taxel_positions(corr)
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    np.testing.assert_allclose(moved[taxels.present], centre + (pts - centre) @ rot.T, atol=1e-14)
    np.testing.assert_allclose(normals[taxels.present], taxels.normals[taxels.present] @ rot.T, atol=1e-14)


def test_triangle_translation_along_its_normal_moves_only_that_triangle(skin):
    p = skin.part("head")
    taxels = layout(skin, "head")
    row = 5
    tri = p.triangle_ids[row]
    corr = p.zero_correction()
    corr.triangles[row, 2] = 0.001            # 1 mm along the triangle frame's z: its outward normal
    moved, _ = p.taxel_positions(corr)
    base, _ = p.taxel_positions()
    slots = np.arange(p.n_slots)
    mine = p.present & (slots // SLOTS_PER_TRIANGLE == tri)
    normal = taxels.normals[mine].mean(axis=0)
    normal /= np.linalg.norm(normal)
    np.testing.assert_allclose(moved[mine] - base[mine], np.broadcast_to(0.001 * normal, (mine.sum(), 3)), atol=1e-15)
    others = p.present & ~mine
    np.testing.assert_array_equal(moved[others], base[others])


def test_patch_rotation_turns_only_that_patch_about_its_centroid_and_normal(skin):
    p = skin.part("r_hand")
    taxels = layout(skin, "r_hand")
    spec = yaml.safe_load(default_skin_config().read_text())["parts"]["r_hand"]["patches"]
    row = 1
    tri_of_slot = np.arange(p.n_slots) // SLOTS_PER_TRIANGLE
    mine = p.present & np.isin(tri_of_slot, spec[int(p.patch_ids[row])])
    pts = taxels.positions[mine]
    centre = pts.mean(axis=0)
    axis = taxels.normals[mine].sum(axis=0)
    axis /= np.linalg.norm(axis)
    angle = 0.3
    corr = p.zero_correction()
    corr.patches[row, 3:] = [0.0, 0.0, angle]   # about the patch frame's z: its mean normal
    moved, _ = p.taxel_positions(corr)
    rot = se3.rotvec_to_matrix(angle * axis)
    np.testing.assert_allclose(moved[mine], centre + (pts - centre) @ rot.T, atol=1e-14)
    base, _ = p.taxel_positions()
    np.testing.assert_array_equal(moved[p.present & ~mine], base[p.present & ~mine])


# ---------------------------------------------------------------------- batches
@pytest.mark.parametrize("part", ["r_hand", "l_hand", "torso", "head"])
def test_taxels_in_base_batch_equals_per_pose(skin, part):
    calib = random_calibration(skin, seed=3)
    q = random_q(skin, 25, seed=4)
    p = skin.part(part)
    batch = skin.taxels_in_base(part, q, calib)
    assert batch.shape == (25, p.n_slots, 3)
    local, _ = p.taxel_positions(calib.parts[part])
    for n in range(len(q)):
        chain = skin.robot.fk(p.chain, q[n])[0]
        expected = local @ chain[:3, :3].T + chain[:3, 3]
        np.testing.assert_allclose(batch[n][p.slots], expected[p.slots], atol=1e-14)
    # one slot list per pose: the same numbers, picked per row
    slots = np.random.default_rng(5).choice(p.slots, size=(25, 7))
    picked = skin.taxels_in_base(part, q, calib, slots)
    assert picked.shape == (25, 7, 3)
    np.testing.assert_array_equal(picked, np.take_along_axis(batch, slots[..., None], axis=1))


# ---------------------------------------------------------------------- calibration files
def test_calibration_save_load_round_trip(skin, tmp_path):
    calib = random_calibration(skin, seed=6)
    path = tmp_path / "calibration.yaml"
    calib.save(path, skin, comment="test round trip\nsecond line")
    loaded = SkinCalibration.load(path, skin)
    assert set(loaded.parts) == set(calib.parts)
    for name, corr in calib.parts.items():
        got = loaded.parts[name]
        np.testing.assert_allclose(got.mount, corr.mount, atol=1e-10)      # written with 10 decimals
        np.testing.assert_allclose(got.patches, corr.patches, atol=1e-10)
        np.testing.assert_allclose(got.triangles, corr.triangles, atol=1e-10)
        np.testing.assert_allclose(skin.part(name).taxel_positions(got)[0], skin.part(name).taxel_positions(corr)[0],
                                   atol=1e-9)
    text = path.read_text()
    assert "# test round trip\n# second line\n" in text
    # what the URDF reads: the calibrated pose relative to the parent frame
    doc = yaml.safe_load(text)
    tri = doc["parts"]["head"]["triangles"][int(skin.part("head").triangle_ids[3])]
    p = skin.part("head")
    expected = p.triangle_nominal[3] @ se3.pose_matrix(calib.parts["head"].triangles[3])
    np.testing.assert_allclose(tri["origin"]["xyz"], expected[:3, 3], atol=1e-10)
    np.testing.assert_allclose(se3.matrix_from_rpy(np.array(tri["origin"]["rpy"])), expected[:3, :3], atol=1e-9)
    assert tri["parent"] == p.patch_frame(p.patch_ids[p.triangle_patch[3]])


def test_a_fit_wound_past_pi_is_written_as_the_same_rotation_and_loads_again(skin, tmp_path):
    """A fit may end with a rotation vector far past pi (the same rotation): its file must load again; a
    translation no skin frame has (a diverged fit) is not written at all."""
    calib = skin.zero_calibration()
    calib.parts["l_hand"].mount = np.array([0.01, 0.02, -0.03, -347.0, -343.3, -197.4])
    calib.parts["torso"].triangles[2, 3:] = [3.186, 0.0, 0.0]
    path = tmp_path / "calibration.yaml"
    calib.save(path, skin)
    loaded = SkinCalibration.load(path, skin)
    for name in ("l_hand", "torso"):
        np.testing.assert_allclose(skin.part(name).taxel_positions(loaded.parts[name])[0],
                                   skin.part(name).taxel_positions(calib.parts[name])[0], atol=1e-9)
    assert np.linalg.norm(loaded.parts["l_hand"].mount[3:]) <= np.pi
    np.testing.assert_allclose(loaded.parts["l_hand"].mount[:3], [0.01, 0.02, -0.03], atol=1e-10)
    calib.parts["torso"].mount[0] = 11.0
    with pytest.raises(DataError, match=r"^torso_skin_mount: correction .* is no skin frame's .* the fit diverged;"
                                        r" nothing written$"):
        calib.save(tmp_path / "diverged.yaml", skin)
    assert not (tmp_path / "diverged.yaml").exists()


def test_partial_calibration_file_leaves_the_rest_nominal(skin, tmp_path):
    path = tmp_path / "partial.yaml"
    path.write_text(yaml.safe_dump({"parts": {"torso": {"mount": {"correction": {
        "translation": [0.001, 0, 0], "rotation_vector": [0, 0, 0.1]}}}}}))
    calib = SkinCalibration.load(path, skin)
    np.testing.assert_array_equal(calib.parts["torso"].mount, [0.001, 0, 0, 0, 0, 0.1])
    assert not np.any(calib.parts["torso"].triangles)
    assert not np.any(calib.parts["head"].mount)


BAD_CORRECTION = ("part 'head' mount: correction must be 3 + 3 finite numbers, metres (at most 10) and radians"
                  " (at most 100)")


@pytest.mark.parametrize("parts, problem", [
    ({"l_foot": {}}, "unknown skin part 'l_foot' (configured: r_hand, l_hand, torso, head)"),
    ({"torso": {"patches": {7: {}}}}, "part 'torso' has no patch 7"),
    ({"torso": {"triangles": {14: {}}}}, "part 'torso' has no triangle 14"),
    ({"head": {"mount": {"correction": {"translation": [0, 0], "rotation_vector": [0, 0, 0]}}}}, BAD_CORRECTION),
    ({"head": {"mount": {"correction": {"translation": [0, 0, ".nan"], "rotation_vector": [0, 0, 0]}}}},
     BAD_CORRECTION),
    ({"head": {"mount": {"correction": {"translation": [1e300, 0, 0], "rotation_vector": [0, 0, 0]}}}},
     BAD_CORRECTION),
    ({"head": {"mount": {"correction": {"translation": [0, 0, 0], "rotation_vector": [0, 1e300, 0]}}}},
     BAD_CORRECTION),
    ({"head": {"mount": {"correction": {"translation": [0, 0, 0]}}}},
     "part 'head' mount: needs correction.translation and correction.rotation_vector"),
    # true was read as 1 m
    ({"head": {"mount": {"correction": {"translation": [True, False, False], "rotation_vector": [0, 0, 0]}}}},
     BAD_CORRECTION),
    # text where numbers belong: '0.1 m' was said as a missing key, "000" read as three zeros
    ({"head": {"mount": {"correction": {"translation": "0.1 m", "rotation_vector": [0, 0, 0]}}}}, BAD_CORRECTION),
    ({"head": {"mount": {"correction": {"translation": "000", "rotation_vector": [0, 0, 0]}}}}, BAD_CORRECTION),
    ({"head": None}, "part 'head': expected a mapping (layout, mount, patches, triangles)"),
    ({"head": 5}, "part 'head': expected a mapping (layout, mount, patches, triangles)"),
    ({"torso": {"patches": [1, 2]}}, "part 'torso': 'patches' must be a mapping"),
    ({"torso": {"patches": {"abc": {}}}}, "part 'torso' patch 'abc': expected a whole number"),
    ({"torso": {"patches": {0.5: {}}}}, "part 'torso' patch 0.5: expected a whole number"),
    ({"torso": {"triangles": {"x": {}}}}, "part 'torso' triangle 'x': expected a whole number"),
    ({"r_hand": {"chain": "l_arm"}}, "part 'r_hand' was calibrated on chain 'l_arm'; the skin config hangs it off"
                                     " 'r_arm'"),
    # str.lstrip('-').isdigit() passed these and int() then raised a traceback
    ({"torso": {"patches": {"--0": {}}}}, "part 'torso' patch '--0': expected a whole number"),
    ({"torso": {"triangles": {"\u00b2": {}}}}, "part 'torso' triangle '\u00b2': expected a whole number"),
    # one triangle under two spellings: the later one was taken without a word
    ({"torso": {"triangles": {0: {}, "0": {}}}}, "part 'torso' triangle 0 is given twice (as 0 and '0')"),
    # an integer beyond any float: OverflowError, a traceback
    ({"head": {"mount": {"correction": {"translation": [10 ** 400, 0, 0], "rotation_vector": [0, 0, 0]}}}},
     BAD_CORRECTION),
    # 2 + 4 numbers are 6 numbers, but not a translation and a rotation
    ({"head": {"mount": {"correction": {"translation": [0, 0], "rotation_vector": [0, 0, 0, 0]}}}},
     BAD_CORRECTION),
], ids=["unknown-part", "unknown-patch", "unknown-triangle", "two-numbers", "nan", "huge-translation",
        "huge-rotation", "no-rotation", "bool-translation", "text-translation", "digits-translation", "part-none", "part-number", "patches-list", "patch-word", "patch-half",
        "triangle-word", "other-chain", "patch-dashes", "triangle-superscript", "triangle-twice", "int-beyond-float",
        "two-plus-four"])
def test_malformed_calibration_fails_naming_file_and_entry(skin, tmp_path, parts, problem):
    path = tmp_path / "calibration.yaml"
    path.write_text(yaml.safe_dump({"parts": parts}).replace("'.nan'", ".nan"))
    with pytest.raises(ConfigError) as err:
        SkinCalibration.load(path, skin)
    assert str(err.value) == f"{path}: {problem}"


def test_a_calibration_of_another_robot_is_refused(skin, tmp_path):
    path = tmp_path / "calibration.yaml"
    path.write_text(yaml.safe_dump({"robot": "pepper", "parts": {}}))
    with pytest.raises(ConfigError) as err:
        SkinCalibration.load(path, skin)
    assert str(err.value) == (f"{path}: made for robot 'pepper'; the skin config's robot is 'nao_h25'"
                              f" ({skin.robot.source}): give the robot config it was made with (--robot FILE, or a"
                              f" skin config whose 'robot:' names it)")


BAD_KINEMATICS = "needs a finite numeric correction (at most 0.1 m) and, if given, a finite std >= 0"


@pytest.mark.parametrize("top, problem", [
    ({"kinematics": [1, 2]}, "calibration: 'kinematics' must be a mapping"),
    ({"kinematics": {"LElbowOffsetY": {"correction": ".nan"}}}, f"kinematics: 'LElbowOffsetY' {BAD_KINEMATICS}"),
    ({"kinematics": {"LElbowOffsetY": {"correction": 1e300}}}, f"kinematics: 'LElbowOffsetY' {BAD_KINEMATICS}"),
    ({"kinematics": {"LElbowOffsetY": {"correction": 0.001, "std": -1}}},
     f"kinematics: 'LElbowOffsetY' {BAD_KINEMATICS}"),
    # read as 1 m / as metres, and a 9 m elbow went into the URDF with exit 0
    ({"kinematics": {"LElbowOffsetY": {"correction": True}}}, f"kinematics: 'LElbowOffsetY' {BAD_KINEMATICS}"),
    ({"kinematics": {"LElbowOffsetY": {"correction": 9.0}}}, f"kinematics: 'LElbowOffsetY' {BAD_KINEMATICS}"),
    ({"kinematics": {"LElbowOffsetY": {"correction": 0.005, "unit": "mm"}}},
     "kinematics: 'LElbowOffsetY' is in m, not 'mm' (a link length)"),
    ({"kinematics": {"HeadYaw": {"correction": 0.6}}},
     "kinematics: 'HeadYaw' needs a finite numeric correction (at most 0.5 rad) and, if given, a finite std >= 0"),
    ({"format": "nao_skin/simulation/1"},
     "format 'nao_skin/simulation/1', not nao_skin/calibration/1: another kind of file or a newer nao_skin's"),
    ({"contents": {"frames": -1}}, "contents must be a mapping of frames and (optional) kinematics and fingertips,"
                                   " each a whole number >= 0"),
    ({"contents": {"frames": 1.5}}, "contents must be a mapping of frames and (optional) kinematics and fingertips,"
                                    " each a whole number >= 0"),
    ({"contents": 3}, "contents must be a mapping of frames and (optional) kinematics and fingertips, each a whole"
                      " number >= 0"),
    ({"contents": {"frames": 2}}, "holds 0 frames and 0 kinematic corrections where its contents line says 2 and"
                                  " 0: the file was cut short or edited; restore it, or after a deliberate edit"
                                  " correct that line"),
], ids=["kinematics-list", "kinematics-nan", "kinematics-huge", "negative-std", "kinematics-bool", "link-9m",
        "unit-mm", "joint-beyond", "other-format", "contents-negative",
        "contents-fraction", "contents-number", "contents-more"])
def test_malformed_calibration_beside_the_parts_fails_in_one_line(skin, tmp_path, top, problem):
    path = tmp_path / "calibration.yaml"
    path.write_text(yaml.safe_dump({"parts": {}, **top}).replace("'.nan'", ".nan"))
    with pytest.raises(ConfigError) as err:
        SkinCalibration.load(path, skin)
    assert str(err.value) == f"{path}: {problem}"


def test_a_calibration_cut_short_is_refused_never_read_as_another(skin, tmp_path):
    """A copy that stopped, or a full disk where someone copied the file: cut anywhere, the file either
    loads as the calibration it was (only the last entry's origin, which load() does not read, was cut)
    or is refused in one line; never as fewer corrections with the rest at nominal."""
    calib = random_calibration(skin, seed=8)
    calib.kinematics = {"LElbowOffsetY": 0.0012, "LShoulderRoll": -0.01}
    whole = tmp_path / "calibration.yaml"
    calib.save(whole, skin)
    text = whole.read_text()
    assert "contents:" in text.split("parts:")[0]          # the count comes ahead of what it counts
    ends = [i + 1 for i, c in enumerate(text) if c == "\n"][:-1]
    # line ends, and cuts in the middle of a line, in every part of the file (~200 cuts of its ~2300 lines)
    cuts = ends[::15] + [e - 7 for e in ends[3::47]]
    loaded_whole = refused = 0
    cut = tmp_path / "cut.yaml"
    for at in cuts:
        cut.write_text(text[:at])
        try:
            got = SkinCalibration.load(cut, skin)
        except ConfigError as err:
            assert "\n" not in str(err) and str(err).startswith(str(cut)), err
            refused += 1
            continue
        loaded_whole += 1
        assert got.kinematics == pytest.approx(calib.kinematics, abs=1e-10), at
        for name, corr in calib.parts.items():
            np.testing.assert_allclose(got.parts[name].triangles, corr.triangles, atol=1e-10, err_msg=str(at))
            np.testing.assert_allclose(got.parts[name].patches, corr.patches, atol=1e-10, err_msg=str(at))
            np.testing.assert_allclose(got.parts[name].mount, corr.mount, atol=1e-10, err_msg=str(at))
    assert refused > 0.95 * len(cuts)


def test_a_binary_file_given_as_calibration_is_one_line(skin, tmp_path):
    bag = tmp_path / "touches.bag.db3"
    bag.write_bytes(b"SQLite format 3\x00\xba\xff" * 8)      # what a bag's storage file begins with
    with pytest.raises(ConfigError) as err:
        SkinCalibration.load(bag, skin)
    assert str(err.value).startswith(f"{bag}: cannot read calibration (not a text file: ")


# ---------------------------------------------------------------------- config errors
def write_skin_config(tmp_path, mutate, robot_mutate=None):
    doc = yaml.safe_load(default_skin_config().read_text())
    for spec in doc["parts"].values():
        spec["taxel_file"] = str(default_skin_config().parent / spec["taxel_file"])
    robot = yaml.safe_load((config_dir() / "nao_h25.yaml").read_text())
    if robot_mutate:
        robot_mutate(robot)
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump(robot))
    doc["robot"] = "robot.yaml"
    mutate(doc)
    path = tmp_path / "skin.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_config_naming_an_unknown_joint_fails_naming_file_and_joint(tmp_path):
    path = write_skin_config(tmp_path, lambda d: None,
                             robot_mutate=lambda r: r["chains"]["head"][1].update(joint="NeckYaw"))
    with pytest.raises(ConfigError) as err:
        SkinModel.from_yaml(path)
    assert str(err.value) == (f"{tmp_path / 'robot.yaml'}: chain 'head' row 1: unknown joint 'NeckYaw'"
                              f" (not listed under 'joints')")


def test_triangle_listed_in_two_patches_fails_naming_file_part_and_patches(tmp_path):
    path = write_skin_config(tmp_path, lambda d: d["parts"]["torso"]["patches"][1].append(5))
    with pytest.raises(ConfigError) as err:
        SkinModel.from_yaml(path)
    assert str(err.value) == f"{path}: part 'torso': triangle 5 is listed in patch 0 and in patch 1"


@pytest.mark.parametrize("number", [10 ** 23, -3])
def test_a_patch_number_beyond_a_label_fails_naming_file_and_patch(tmp_path, number):
    """10**23 overflowed numpy (a traceback in every command); -3 made a frame 'torso_skin_patch_-3'."""
    path = write_skin_config(tmp_path, lambda d: d["parts"]["torso"]["patches"].update({number: [40]}))
    with pytest.raises(ConfigError) as err:
        SkinModel.from_yaml(path)
    assert str(err.value) == f"{path}: part 'torso': patch {number!r}: expected a whole number in 0..65535"


def test_malformed_taxel_file_fails_naming_the_taxel_file_and_line(tmp_path):
    bad = tmp_path / "head_bad.txt"
    lines = (config_dir() / "layouts" / "head.txt").read_text().splitlines()
    lines[9] = lines[9] + " 0.5"          # a seventh number on line 10 of the file
    bad.write_text("\n".join(lines) + "\n")
    path = write_skin_config(tmp_path, lambda d: d["parts"]["head"].update(taxel_file="head_bad.txt"))
    with pytest.raises(DataError) as err:
        SkinModel.from_yaml(path)
    assert str(err.value) == f"{bad}:10: expected 6 numbers 'x y z nx ny nz', got 7"


BAD_SLOTS = "expected a multiple of 12 (slot = 12 * triangle + k) in 12..12288"
BAD_MOUNT = "xyz and rotvec must be 3 finite numbers each, metres (at most 10) and radians (at most 100)"


@pytest.mark.parametrize("mutate, problem", [
    (lambda d: d["parts"]["head"].update(chain="neck"), "part 'head': unknown chain 'neck' (robot has head, l_arm, r_arm)"),
    (lambda d: d["parts"]["head"].pop("taxel_file"), "part 'head': needs 'taxel_file' and 'chain' (null for the base)"),
    (lambda d: d["parts"]["head"].pop("chain"), "part 'head': needs 'taxel_file' and 'chain' (null for the base)"),
    # a part name becomes frame and file names: '../../x' wrote taxels/../../x.txt outside the output
    (lambda d: d["parts"].update({"../../evil": d["parts"].pop("head")}),
     "part '../../evil': a part name is a letter, then letters, digits or '_'"),
    (lambda d: d["parts"].update({"r hand": d["parts"].pop("head")}),
     "part 'r hand': a part name is a letter, then letters, digits or '_'"),
    # a typo's value would be ignored without a word
    (lambda d: d["parts"]["head"].update(chian="head"),
     "part 'head': unknown key 'chian' (did you mean 'chain'?); it takes chain, taxel_file, slots, patches, mount"),
    (lambda d: d["parts"]["head"].update(mount={"xyz": [0, 0, 0], "rpy": [0, 0, 1]}),
     "part 'head': mount: unknown key 'rpy'; it takes xyz, rotvec"),
    (lambda d: d.update(robots="x.yaml"),
     "unknown key 'robots' (did you mean 'robot'?); it takes robot, parts, self_touch, fingertip_touch"),
    (lambda d: d["parts"]["torso"]["patches"][0].append(40), "part 'torso' patch 0: triangle 40 is not in 0..31"),
    # YAML's true is Python's 1: it was "triangle 1 is listed in patch 0 and in patch 0"
    (lambda d: d["parts"]["torso"]["patches"][0].__setitem__(0, True),
     "part 'torso' patch 0: triangle True is not in 0..31"),
    (lambda d: d["parts"]["torso"]["patches"][0].remove(3),
     "part 'torso': triangles [3] have taxels in the layout but are in no patch"),
    (lambda d: d.pop("parts"), "a skin config needs a 'parts' mapping with at least one part"),
    (lambda d: d.update(parts={}), "a skin config needs a 'parts' mapping with at least one part"),
    (lambda d: d.update(robot=["robot.yaml"]), "names no 'robot' config file"),
    # it read as the Nao's hands on its torso and head, whatever parts the config has
    (lambda d: d.pop("self_touch"), "names no 'self_touch' (which parts touch which, e.g. touching: [r_hand, l_hand],"
                                    " touched: [torso, head])"),
    (lambda d: d["parts"]["head"].update(taxel_file=None), "part 'head': needs 'taxel_file' and 'chain' (null for the base)"),
    (lambda d: d["parts"]["head"].update(chain=["head"]), "part 'head': unknown chain ['head'] (robot has head, l_arm, r_arm)"),
    (lambda d: d["parts"]["head"].update(slots=10 ** 10), "part 'head': slots 10000000000: " + BAD_SLOTS),
    (lambda d: d["parts"]["head"].update(slots=390), "part 'head': slots 390: " + BAD_SLOTS),
    (lambda d: d["parts"]["head"].update(slots="many"), "part 'head': slots 'many': " + BAD_SLOTS),
    (lambda d: d["parts"]["head"].update(patches=[0, 1]),
     "part 'head': 'patches' must map patch numbers to lists of triangles"),
    (lambda d: d["parts"]["head"].update(patches={"a": [0]}), "part 'head': patch 'a': expected a whole number"),
    (lambda d: d["parts"]["head"].update(patches={"--1": [0]}), "part 'head': patch '--1': expected a whole number"),
    (lambda d: d["parts"]["head"].update(patches={0: [0], "0": [1]}),
     "part 'head': patch 0 is given twice (as 0 and '0')"),
    (lambda d: d["parts"]["head"].update(mount=5), "part 'head': mount: expected {xyz: [x, y, z], rotvec: [rx, ry, rz]}"),
    (lambda d: d["parts"]["head"].update(mount={"xyz": [0, 0]}), "part 'head': mount: " + BAD_MOUNT),
    (lambda d: d["parts"]["head"].update(mount={"xyz": [float("nan"), 0, 0]}), "part 'head': mount: " + BAD_MOUNT),
    (lambda d: d["parts"]["head"].update(mount={"xyz": "abc"}), "part 'head': mount: " + BAD_MOUNT),
])
def test_bad_skin_config_fails_in_one_line(tmp_path, mutate, problem):
    path = write_skin_config(tmp_path, mutate)
    with pytest.raises(ConfigError) as err:
        SkinModel.from_yaml(path)
    assert str(err.value) == f"{path}: {problem}"


def test_taxels_of_a_part_keep_the_configs_patch_table_where_it_places_every_triangle(tmp_path, real_dir):
    """``--taxels PART=FILE`` replaces a part's layout, not the config's patch table: the very layout of the
    config, given again, was regrouped 16 triangles per patch, and a calibration's patch corrections landed
    on other triangles (closest COP 5.60 -> 5.81 mm with exit 0). A layout the table does not cover (a
    recording's own, with triangles the package's layout lacks) is grouped by the convention, as before."""
    from nao_skin.model.skin import load_skin

    doc = yaml.safe_load(default_skin_config().read_text())
    table = doc["parts"]["l_hand"]["patches"]
    doc["parts"]["l_hand"]["patches"] = {0: table[1], 1: table[0]}          # the two patches numbered the other way
    doc["robot"] = str(config_dir() / doc["robot"])
    for part in doc["parts"].values():
        part["taxel_file"] = str(config_dir() / part["taxel_file"])
    config = tmp_path / "swapped.yaml"
    config.write_text(yaml.safe_dump(doc))
    layout = doc["parts"]["l_hand"]["taxel_file"]

    def grouping(part):
        return {int(p): sorted(part.triangle_ids[part.triangle_patch == i].tolist()) for i, p in enumerate(part.patch_ids)}

    configured = load_skin(config).parts["l_hand"]
    given_again = load_skin(config, {"l_hand": layout}).parts["l_hand"]
    assert grouping(given_again) == grouping(configured) and grouping(configured)[1][0] == 0
    np.testing.assert_allclose(given_again.patch_nominal, configured.patch_nominal)
    assert given_again.layout_sha256 == configured.layout_sha256
    real = load_skin(config, {"l_hand": real_dir / "l_hand.taxels.txt"}).parts["l_hand"]
    assert grouping(real) == {p: [t for t in real.triangle_ids.tolist() if t // 16 == p] for p in (0, 1)}
