"""Legacy dataset import (thesis §3.5.1 text format), deduplication and the train/test split.

The real recording is read in place (never copied into the repo; see real_data.py);
bad-input cases are small files written to tmp_path.
"""

import numpy as np
import pytest

from nao_skin.errors import DataError
from nao_skin.formats.legacy import _ast_entries, _json_entries, read_legacy
from nao_skin.model.taxel_file import read_taxel_file
from nao_skin.touch.datasets import deduplicate, duplicate_mask, pose_groups, pose_weights, split


@pytest.fixture(scope="module")
def real(real_loaded):
    return real_loaded


@pytest.fixture(scope="module")
def skin(default_skin):
    return default_skin


JOINTS = {"HeadYaw": 0.1, "HeadPitch": -0.2, "LShoulderPitch": 0.5, "LShoulderRoll": 0.3, "LElbowYaw": -1.0,
          "LElbowRoll": -1.0, "LWristYaw": 0.2, "RShoulderPitch": 0.6, "RShoulderRoll": -0.3, "RElbowYaw": 1.0,
          "RElbowRoll": 1.0, "RWristYaw": -0.2}


def contact(part, slots, cop=(0.01, 0.02, 0.03)):
    return {"cop": list(cop), "force": None, "normal": [0.0, 0.0, 1.0], "skinPart": part, "linkNumber": 6,
            "moment": None, "averagePressure": None, "geoCenter": list(cop), "bodyPartId": "x",
            "taxelInfo": {str(s): [0.0] * 6 for s in slots}}


def touch(hand_slots=(0, 1, 2), torso_slots=(0, 1), joints=None):
    return [{0: contact("l_hand", hand_slots), 1: contact("torso", torso_slots)}, dict(joints or JOINTS)]


def write(tmp_path, data, name="data.txt"):
    """One key per line, as the recorder's pretty-printed dicts: lines name the touch."""
    path = tmp_path / name
    body = ",\n".join(f" {k!r}: {v!r}" if not isinstance(v, str) else f" {k!r}: {v}" for k, v in data.items())
    path.write_text("{\n" + body + "\n}\n")
    return path


# ---------------------------------------------------------------------- the real recording
def test_real_file_imports_all_touches(real, real_skin):
    touches, report = real
    assert touches.n_touches == 810 and report.n_loaded == 810 and report.n_skipped == 0
    assert touches.keys[:3] == ["0", "1", "2"]
    np.testing.assert_array_equal(touches.stamps[:3], [0.0, 1.0, 2.0])
    assert set(touches.part_names) == {"l_hand", "torso"}
    # every touch has both parts, every activation a present taxel of its layout
    assert touches.parts_of_touch().all()
    for p, name in enumerate(touches.part_names):
        sel = touches.act_part == p
        assert real_skin.parts[name].present[touches.act_slot[sel]].all()
    assert np.isnan(touches.act_pressure).all()        # averagePressure is None in this file
    assert np.isfinite(touches.joints).all()


def test_real_file_taxel_info_matches_the_taxel_files(real, real_dir):
    """The recorder's taxelInfo rows are exactly the taxel file rows (checked once here, then ignored)."""
    import ast

    text = (real_dir / "l_hand_torso.legacy.txt").read_text()
    first = text[: text.index("'1': [")].rstrip().rstrip(",") + "}"
    contacts, _ = ast.literal_eval(first)["0"]
    files = {n: read_taxel_file(real_dir / f"{n}.taxels.txt") for n in ("l_hand", "torso")}
    for c in contacts.values():
        tf = files[c["skinPart"]]
        for slot, row in c["taxelInfo"].items():
            np.testing.assert_allclose(row, np.r_[tf.positions[int(slot)], tf.normals[int(slot)]], atol=1e-9)


def test_a_taxel_file_that_is_not_the_recordings_is_said(real, real_skin, capsys, real_dir):
    """skinManager computed each recorded COP from its own taxel file: with that file the COPs lie among
    their taxels; with another part's file (swapped by mistake) centimetres off, and the calibration would fit
    taxels that are not where the skin reported its touches."""
    from nao_skin import cli
    from nao_skin.formats.inputs import cop_layout_notes

    touches, _ = real
    assert cop_layout_notes(touches, real_skin, "rec") == []
    legacy = str(real_dir / "l_hand_torso.legacy.txt")
    swapped = ["--taxels", f"l_hand={real_dir / 'torso.taxels.txt'}", "--taxels",
               f"torso={real_dir / 'l_hand.taxels.txt'}"]
    assert cli.main(["stats", legacy, *swapped]) == 0
    said = capsys.readouterr()
    err = said.out + said.err
    for part, other in (("l_hand", "torso"), ("torso", "l_hand")):
        assert (f"{legacy}: part '{part}': the recorded contact COPs lie a median") in err
        assert (f"mm from the taxels they name in {real_dir / f'{other}.taxels.txt'} (a few mm with the layout"
                f" skinManager used): is that this robot's taxel file of this part?") in err


def test_real_file_has_25_exact_duplicates(real):
    touches, _ = real
    unique, removed = deduplicate(touches)
    assert removed == 25 and unique.n_touches == 785
    # a duplicate really repeats an earlier touch: same angles and same taxels
    dup = np.flatnonzero(duplicate_mask(touches))
    def taxels(t):
        sel = touches.act_touch == t
        return set(zip(touches.act_part[sel].tolist(), touches.act_slot[sel].tolist()))

    for d in dup:
        same_angles = np.flatnonzero((touches.joints == touches.joints[d]).all(axis=1))
        assert any(e < d and taxels(e) == taxels(d) for e in same_angles)


# ---------------------------------------------------------------------- dedup and split on small sets
def test_deduplicate_needs_same_angles_and_same_taxels(tmp_path, skin):
    other_angles = dict(JOINTS, LWristYaw=0.25)
    data = {"0": touch(), "1": touch(), "2": touch(joints=other_angles), "3": touch(hand_slots=(0, 1, 3)),
            "4": touch(hand_slots=(2, 1, 0))}
    touches, _ = read_legacy(write(tmp_path, data), skin)
    unique, removed = deduplicate(touches)
    assert removed == 2                     # "1" repeats "0", and "4" lists the same taxels in another order
    assert unique.keys == ["0", "2", "3"]


def test_split_is_reproducible_and_disjoint(tmp_path, skin):
    data = {str(i): touch(joints=dict(JOINTS, LWristYaw=0.01 * i)) for i in range(20)}
    touches, _ = read_legacy(write(tmp_path, data), skin)
    train, test = split(touches, 0.3, seed=7)
    train2, test2 = split(touches, 0.3, seed=7)
    assert test.n_touches == 6 and train.n_touches == 14
    assert train.keys == train2.keys and test.keys == test2.keys
    assert not set(train.keys) & set(test.keys)
    assert split(touches, 0.3, seed=8)[1].keys != test.keys


def test_touches_of_one_pose_stay_on_one_side_of_the_split(tmp_path, skin):
    """A press held still is recorded as several touches (another contact sample each, the same joint angles up
    to encoder jitter): a random split put some in training and some in the test set, which then measured
    poses the calibration was fitted to."""
    data = {}
    for pose in range(6):          # 6 presses of 4 samples each, angles jittered by < 0.1 deg
        for k in range(4):
            data[f"{pose}.{k}"] = touch(hand_slots=(k, k + 1), joints=dict(
                JOINTS, LShoulderPitch=0.1 * pose + 0.001 * k, LElbowRoll=-1.0 - 0.0005 * k))
    for i in range(12):            # and 12 touches each at a pose of its own
        data[f"single.{i}"] = touch(joints=dict(JOINTS, LWristYaw=0.05 * i, LShoulderPitch=1.5))
    touches, _ = read_legacy(write(tmp_path, data), skin)
    groups = pose_groups(touches)
    assert len(set(groups)) == 6 + 12
    for pose in range(6):
        assert len({groups[touches.keys.index(f"{pose}.{k}")] for k in range(4)}) == 1
    for seed in range(20):
        train, test = split(touches, 0.3, seed, groups)
        assert sorted(train.keys + test.keys) == sorted(touches.keys)
        presses = {key.split(".")[0] for key in test.keys if not key.startswith("single")}
        assert not presses & {key.split(".")[0] for key in train.keys}
        assert abs(test.n_touches - round(0.3 * touches.n_touches)) <= 2    # whole groups of 4 come that close
    # each touch a pose of its own: the same split as without groups
    singles = touches.subset(np.flatnonzero([k.startswith("single") for k in touches.keys]))
    assert split(singles, 0.3, 5, pose_groups(singles))[1].keys == split(singles, 0.3, 5)[1].keys


def test_the_samples_of_one_press_weigh_as_fewer_touches(tmp_path, skin):
    """The calibration weighs each touch n^-pose_weight (n touches at its pose), scaled to weigh as many
    touches in all; a set where every touch has a pose of its own is left as it is."""
    data = {f"press.{k}": touch(hand_slots=(k,), joints=dict(JOINTS, LElbowRoll=-1.0 - 0.0005 * k)) for k in range(4)}
    data.update({f"single.{i}": touch(joints=dict(JOINTS, LWristYaw=0.05 * i, LShoulderPitch=1.5)) for i in range(4)})
    touches, _ = read_legacy(write(tmp_path, data), skin)
    weights = pose_weights(touches, 0.5)
    press = np.array([key.startswith("press") for key in touches.keys])
    assert np.allclose(weights[press] / weights[~press], 0.5)     # 4 ** -0.5
    assert np.isclose(weights.mean(), 1.0)
    assert np.allclose(pose_weights(touches, 1.0)[press].sum(), pose_weights(touches, 1.0)[~press][0])
    assert pose_weights(touches, 0.0) is None
    assert pose_weights(touches.subset(np.flatnonzero(~press)), 0.5) is None


# ---------------------------------------------------------------------- keys
def test_timestamp_keys_become_stamps(tmp_path, skin):
    data = {"1589880000.25": touch(), "1589880000.5": touch(hand_slots=(3,))}
    touches, report = read_legacy(write(tmp_path, data), skin)
    assert report.n_loaded == 2
    np.testing.assert_allclose(touches.stamps, [1589880000.25, 1589880000.5])
    assert touches.keys == ["1589880000.25", "1589880000.5"]


@pytest.mark.parametrize("exact", [False, True], ids=["fast reader", "exact reader"])
def test_a_key_given_twice_keeps_the_first_touch_and_says_so(tmp_path, skin, exact):
    """A touch key given twice (a hand edit) loaded both under one stamp, and an import into a bag then
    kept one of them without a word."""
    path = tmp_path / "data.txt"
    path.write_text("{'0': %r,\n '1': %r,\n '0': %r}" % (touch(), touch(hand_slots=(3,)), touch(hand_slots=(4,))))
    touches, report = read_legacy(path, skin, exact=exact)
    assert report.n_loaded == 2 and touches.keys == ["0", "1"]
    assert report.skipped == {"key given twice": 1}
    assert report.messages == [f"{path}:3: touch '0': the key was given before, at line 1; the first is kept"]
    # one time written two ways: an import wrote both, and read back one ("wrote 39", then "38 loaded")
    path.write_text("{'5': %r,\n '6': %r,\n '5.0': %r}" % (touch(), touch(hand_slots=(3,)), touch(hand_slots=(4,))))
    touches, report = read_legacy(path, skin, exact=exact)
    assert report.n_loaded == 2 and touches.keys == ["5", "6"]
    assert report.messages == [f"{path}:3: touch '5.0': the key is the time of '5' at line 1 (one time, written two"
                               f" ways); the first is kept"]


def test_none_pressure_force_moment_and_real_pressure(tmp_path, skin):
    t = touch()
    t[0][0]["averagePressure"] = 3.5
    touches, _ = read_legacy(write(tmp_path, {"0": t}), skin)
    hand = touches.act_part == touches.part_index("l_hand")
    np.testing.assert_array_equal(touches.act_pressure[hand], 3.5)
    assert np.isnan(touches.act_pressure[~hand]).all()
    np.testing.assert_allclose(touches.contact_cop[0], [0.01, 0.02, 0.03])


def test_a_byte_order_mark_is_not_part_of_the_text(tmp_path, skin):
    """A file saved by a Windows editor begins with a UTF-8 byte-order mark: it had been a 'syntax error'."""
    plain = write(tmp_path, {"0": touch(), "1": touch(hand_slots=(3,))})
    marked = tmp_path / "marked.txt"
    marked.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    a, report_a = read_legacy(plain, skin)
    b, report_b = read_legacy(marked, skin)
    assert report_b.n_loaded == report_a.n_loaded == 2 and b.keys == a.keys
    np.testing.assert_array_equal(b.act_slot, a.act_slot)


# ---------------------------------------------------------------------- bad input
def test_syntax_error_names_file_and_line(tmp_path, skin):
    """In the note that says what was lost when another touch is read, in the error when none is."""
    path = write(tmp_path, {"0": touch(), "1": "[{0: {'cop': [1, 2,}}, {}]"})
    touches, report = read_legacy(path, skin)
    assert touches.keys == ["0"] and len(report.notes) == 1
    assert report.notes[0].startswith(f"{path}: damaged text at line 3 (touch '1': unreadable text)")
    path = write(tmp_path, {"1": "[{0: {'cop': [1, 2,}}, {}]"})
    with pytest.raises(DataError) as err:
        read_legacy(path, skin)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg and f"{path}:2:" in msg and "syntax" in msg


def test_bad_touches_are_skipped_with_one_line_each(tmp_path, skin):
    bad_slot = touch(hand_slots=(0, 384))
    thermal = touch(torso_slots=(6,))                      # slot 6 is a thermal pad, not a taxel
    unknown_part = touch()
    unknown_part[0][1]["skinPart"] = "l_foot"
    missing = touch(joints={k: v for k, v in JOINTS.items() if k != "LElbowRoll"})
    none_angle = touch(joints=dict(JOINTS, LWristYaw=None))
    head_missing_ok = touch(joints={k: v for k, v in JOINTS.items() if not k.startswith("Head")})
    data = {"0": touch(), "1": bad_slot, "2": thermal, "3": unknown_part, "4": missing, "5": none_angle,
            "6": head_missing_ok, "7": "[{0: float('nan')}, {}]"}
    path = write(tmp_path, data)
    touches, report = read_legacy(path, skin)
    assert touches.keys == ["0", "6"]                      # head joints are not needed by l_hand/torso
    assert report.n_read == 8 and report.n_loaded == 2 and report.n_skipped == 6
    assert report.skipped == {"bad taxel slot": 2, "unknown skin part": 1, "missing joint": 1,
                              "bad joint angle": 1, "not a literal": 1}
    for m in report.messages:
        assert "\n" not in m and str(path) in m
    text = " | ".join(report.messages)
    assert "touch '1'" in text and "slot 384 out of range" in text
    assert "touch '2'" in text and "slot 6 is not a taxel" in text
    assert "touch '3'" in text and "'l_foot'" in text
    assert "touch '4'" in text and "joint 'LElbowRoll' is missing" in text
    assert "touch '5'" in text and "'LWristYaw'" in text
    assert "touch '7'" in text and "not a Python literal" in text
    # the line number points at the touch in the file
    assert f"{path}:3: touch '1'" in text


def test_integers_beyond_any_float_or_int64_skip_their_touch(tmp_path, skin):
    huge = 10 ** 400                       # a Python literal may be any length; float() and int64 overflow
    slot = touch()
    slot[0][0]["taxelInfo"][str(huge)] = [0.0] * 6
    cop = touch()
    cop[0][0]["cop"] = [huge, 0, 0]
    pressure = touch()
    pressure[0][1]["averagePressure"] = huge
    angle = touch(joints=dict(JOINTS, LElbowRoll=huge))
    path = write(tmp_path, {"0": touch(), "1": slot, "2": cop, "3": pressure, "4": angle, huge: touch()})
    touches, report = read_legacy(path, skin)
    assert touches.keys == ["0", str(huge)] and touches.stamps[1] == 5.0     # an unusable key: file order
    assert report.skipped == {"bad taxel slot": 1, "malformed field": 2, "bad joint angle": 1}
    text = " | ".join(report.messages)
    assert f"touch '1': contact 0: field 'taxelInfo': slot {huge} out of range 0..383 of part 'l_hand'" in text
    assert "touch '2': contact 0: field 'cop': expected 3 numbers or None" in text
    assert "touch '3': contact 1: field 'averagePressure': not a number" in text
    assert "touch '4': joint 'LElbowRoll' is not a finite angle (10000000000000000000..., 401 digits)" in text


@pytest.mark.parametrize("exact", [False, True], ids=["fast", "exact"])
def test_a_contact_id_or_slot_no_integer_holds_skips_only_its_touch(tmp_path, skin, exact):
    """One contact id of 10**20 (beyond int64) or inf, or one slot key inf, ended the whole load of the
    recording in a traceback (OverflowError)."""
    huge_id, inf_id, inf_slot, bool_slot, half_slot = touch(), touch(), touch(), touch(), touch()
    huge_id[0][10 ** 20] = huge_id[0].pop(0)
    inf_id[0][float("inf")] = inf_id[0].pop(0)
    inf_slot[0][0]["taxelInfo"][float("inf")] = [0.0] * 6
    bool_slot[0][0]["taxelInfo"] = {True: [0.0] * 6}          # was read as slot 1
    half_slot[0][0]["taxelInfo"] = {1.5: [0.0] * 6}           # was read as slot 1
    path = write(tmp_path, {"0": huge_id, "1": inf_id, "2": inf_slot, "3": bool_slot, "4": half_slot, "5": touch()})
    touches, report = read_legacy(path, skin, exact=exact)
    assert touches.keys == ["0", "1", "5"] and report.skipped == {"bad taxel slot": 3}
    hand = touches.contact_part == touches.part_index("l_hand")
    assert touches.contact_id[hand & (touches.contact_touch < 2)].tolist() == [-1, -1]   # no usable id: none
    text = " | ".join(report.messages)
    assert "touch '2': contact 0: field 'taxelInfo': slot inf out of range 0..383 of part 'l_hand'" in text
    assert "touch '3': contact 0: field 'taxelInfo': slot True is not an integer" in text
    assert "touch '4': contact 0: field 'taxelInfo': slot 1.5 is not an integer" in text


def test_an_angle_written_as_text_skips_its_touch(tmp_path, skin):
    touches, report = read_legacy(write(tmp_path, {"0": touch(joints=dict(JOINTS, LElbowRoll="-1.0")),
                                                   "1": touch()}), skin)
    assert touches.keys == ["1"] and report.skipped == {"bad joint angle": 1}
    assert "touch '0': joint 'LElbowRoll': not a number ('-1.0')" in report.messages[0]


def test_a_key_with_an_underscore_is_a_name_not_a_number(tmp_path, skin):
    """Python's float() reads '1_0' as 10: the touch was dropped as the key '10' given twice."""
    touches, report = read_legacy(write(tmp_path, {"10": touch(), "1_0": touch()}), skin)
    assert touches.keys == ["10", "1_0"] and not report.skipped
    assert touches.stamps[0] == 10.0 and touches.stamps[1] == 1.0     # a name: its place in the file


@pytest.mark.parametrize("angle", [1e300, -6282.0, 13.0])
def test_an_angle_beyond_two_turns_skips_its_touch(tmp_path, skin, angle):
    """1e300 rad in every touch was calibrated (exit 0), the only word a note on joint limits: no joint of an
    arm or a head turns that far, so it is no angle but a broken value."""
    path = write(tmp_path, {"0": touch(), "1": touch(joints=dict(JOINTS, LElbowRoll=angle))})
    touches, report = read_legacy(path, skin)
    assert touches.keys == ["0"] and report.skipped == {"bad joint angle": 1}
    assert (f"touch '1': joint 'LElbowRoll' = {angle:.4g} rad, beyond two turns (|angle| <= 12.57 rad)"
            in " | ".join(report.messages))


@pytest.mark.parametrize("text, problem", [
    ("", "empty file; a legacy dataset is one dict literal {key: [skinContacts, joints]}"),
    ("  \n\n", "empty file; a legacy dataset is one dict literal {key: [skinContacts, joints]}"),
    ("{'0': [{}, {}]}\x00", "Python syntax error (source code string cannot contain null bytes);"
                            " a legacy dataset is one dict literal"),
], ids=["empty", "blank", "nul-byte"])
def test_an_empty_or_binary_file_is_one_line_without_a_made_up_line_number(tmp_path, skin, text, problem):
    path = tmp_path / "data.txt"
    path.write_text(text)
    with pytest.raises(DataError) as err:
        read_legacy(path, skin)
    assert str(err.value) == f"{path}: {problem}"


def test_not_a_dict_and_missing_file(tmp_path, skin):
    path = tmp_path / "list.txt"
    path.write_text("[1, 2, 3]\n")
    with pytest.raises(DataError, match="one dict literal"):
        read_legacy(path, skin)
    with pytest.raises(DataError, match="cannot read"):
        read_legacy(tmp_path / "nope.txt", skin)


# ------------------------------------------------------------------------------ the fast reader
def _same(a, b) -> bool:
    """Equal values, NaN equal to NaN; dict keys compared as text (JSON keys are strings)."""
    if isinstance(a, dict):
        return isinstance(b, dict) and len(a) == len(b) and all(
            str(ka) == str(kb) and _same(va, vb) for (ka, va), (kb, vb) in zip(a.items(), b.items()))
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and np.isnan(a):
        return isinstance(b, float) and np.isnan(b)
    return a == b and type(a) is type(b)


def _same_entries(fast, exact) -> bool:
    return len(fast) == len(exact) and all(
        lf == le and str(kf) == str(ke) and _same(vf, ve) for (lf, kf, vf), (le, ke, ve) in zip(fast, exact))


@pytest.mark.slow   # reads the real recording twice, once with the slow exact reader
def test_the_fast_reader_reads_the_real_file_exactly_as_python_does(real_dir):
    text = (real_dir / "l_hand_torso.legacy.txt").read_text()
    fast = _json_entries(text)
    assert fast is not None, "the recorder's own output must take the fast path"
    assert _same_entries(fast, _ast_entries(text, real_dir / "l_hand_torso.legacy.txt"))


def test_the_fast_reader_takes_what_the_recorder_writes_and_leaves_the_rest_to_python(tmp_path, skin):
    names = touch(joints=dict(JOINTS, LWristYaw=float("nan"), RWristYaw=float("-inf")))
    names[0][-3] = names[0].pop(1)                              # a negative contactId
    names[0][0]["averagePressure"] = True
    plain = {"0": touch(), "1": names, "2.5": touch(), "3": "[{0: {'skinPart': 'l_hand', 'taxelInfo': {}}}, {}]"}
    path = write(tmp_path, plain)
    text = path.read_text()
    assert _json_entries(text) is not None and _same_entries(_json_entries(text), _ast_entries(text, path))
    # escapes, tuples, calls, a trailing comma: the exact reader, with the same touches and reasons
    for odd in ('"it\'s"', "(1, 2)", "float('nan')", "[1, 2,]"):
        data = dict(plain, **{"4": f"[{{0: {{'skinPart': {odd}}}}}, {{}}]"})
        path = write(tmp_path, data, name="odd.txt")
        assert _json_entries(path.read_text()) is None, odd
        touches, report = read_legacy(path, skin)
        assert touches.keys == ["0", "2.5"], odd
    touches, report = read_legacy(write(tmp_path, plain, name="plain.txt"), skin)
    assert touches.keys == ["0", "2.5"]
    assert report.skipped == {"bad joint angle": 1, "empty contact": 1}
    assert "joint 'LWristYaw' is not a finite angle (nan)" in " | ".join(report.messages)


def test_a_broken_file_still_names_its_line_through_the_exact_reader(tmp_path, skin):
    """A broken touch costs that touch, said with its line; a file without one complete touch is one line."""
    path = write(tmp_path, {"0": touch(), "1": touch(), "2": "[{0: {'cop': [1, 2,}}, {}]"})
    assert _json_entries(path.read_text()) is None
    touches, report = read_legacy(path, skin)
    assert touches.keys == ["0", "1"] and report.skipped == {"damaged text": 1}
    assert report.notes == [f"{path}: damaged text at line 4 (touch '2': unreadable text): 1 touch lost there;"
                            f" every complete touch before it is read (each touch from its own key on)"]
    broken = tmp_path / "broken.txt"
    broken.write_text("{'0': [{0: {'cop': [0, 0,")
    with pytest.raises(DataError, match=f"{broken}:1: Python syntax error"):
        read_legacy(broken, skin)


def test_the_bench_compares_both_readers_on_the_same_file(tmp_path, skin):
    from nao_skin.bench.speed import legacy_read_times

    path = write(tmp_path, {"0": touch(), "1": touch(hand_slots=(0, 384)), "2": touch()})
    t = legacy_read_times(path, skin, repeat=1)
    assert t["same_touches"] and t["touches"] == 2 and t["exact_s"] > 0 and t["fast_s"] > 0


# ---------------------------------------------------------------------- damaged text
def _pretty(tmp_path, n: int, name="data.txt"):
    """``n`` touches as the recorder's pretty-printed file: each touch over several lines."""
    import pprint

    path = tmp_path / name
    path.write_text(pprint.pformat({str(k): touch() for k in range(n)}, width=60) + "\n")
    return path


def test_a_garbage_line_costs_the_touch_it_falls_in_and_the_file_reads_on(tmp_path, skin):
    """One garbage line had made the whole file a syntax error (0 touches): the touches before it and after it
    are read from their keys on; one note names the lines and the touch lost."""
    path = _pretty(tmp_path, 6)
    lines = path.read_text().split("\n")
    start = [i for i, line in enumerate(lines) if line.lstrip(" {").startswith("'3': [")][0]
    nxt = [i for i, line in enumerate(lines) if line.lstrip(" {").startswith("'4': [")][0]
    lines.insert(start + 2, "  @@ a garbage line ]] {{")
    path.write_text("\n".join(lines))
    touches, report = read_legacy(path, skin)
    assert touches.keys == ["0", "1", "2", "4", "5"]
    assert report.n_loaded == 5 and report.n_read == 6 and report.skipped == {"damaged text": 1}
    assert report.notes == [f"{path}: damaged text at lines {start + 1}-{nxt + 1} (touch '3': unreadable text): 1 touch"
                            f" lost there; every complete touch before and after it is read (each touch from its own"
                            f" key on)"]
    # between two touches it costs none
    lines.pop(start + 2)
    lines.insert(nxt, "  @@ a garbage line")
    path.write_text("\n".join(lines))
    touches, report = read_legacy(path, skin)
    assert touches.n_touches == 6 and not report.skipped
    assert report.notes[0].startswith(f"{path}: damaged text at line {nxt + 1} (after touch '3': unreadable text):"
                                      f" 0 touches lost there")


def test_a_file_cut_short_keeps_every_complete_touch(tmp_path, skin):
    path = _pretty(tmp_path, 6)
    text = path.read_text()
    cut = text.index("'4': [") + 40
    path.write_text(text[:cut])
    touches, report = read_legacy(path, skin)
    assert touches.keys == ["0", "1", "2", "3"] and report.skipped == {"damaged text": 1}
    first, last = (text[:at].rstrip().count("\n") + 1 for at in (text.index("'4': [") + 1, cut))
    lines = f"line {first}" if first == last else f"lines {first}-{last}"
    assert report.notes == [f"{path}: damaged text at {lines} (touch '4': the file ends inside it (cut short?)):"
                            f" 1 touch lost there; every complete touch before it is read (each touch from its own"
                            f" key on)"]
    # cut right after a whole touch: nothing lost, the missing end said
    path.write_text(text[:text.index("'4': [")].rstrip().rstrip(","))
    touches, report = read_legacy(path, skin)
    assert touches.n_touches == 4 and not report.skipped
    assert "(the file's end: no closing '}' (cut short?)): 0 touches lost there" in report.notes[0]


def test_a_damaged_one_line_file_reads_on_after_the_damage(tmp_path, skin):
    """write_thesis_file's files are one line (Python's repr): the touches after the damage are found there too."""
    from thesis_format import write_thesis_file

    from nao_skin.sim.params import load_params
    from nao_skin.sim.simulate import simulate

    sim = simulate(skin, load_params("default", {"pairs": [["l_hand", "torso"]], "n_touches": 6}), seed=3).touches
    path = tmp_path / "one_line.txt"
    write_thesis_file(path, sim, skin)
    text = path.read_text()
    third = text.index(f"'{sim.stamps[2]:.6f}': [{{") + len(f"'{sim.stamps[2]:.6f}': [{{")
    path.write_text(text[:third] + "@@ garbage ]" + text[third:])
    touches, report = read_legacy(path, skin)
    assert touches.n_touches == sim.n_touches - 1 and report.skipped == {"damaged text": 1}
    assert f"{sim.stamps[2]:.6f}" not in touches.keys and f"{sim.stamps[3]:.6f}" in touches.keys
    assert f"damaged text at line 1 (touch '{sim.stamps[2]:.6f}': unreadable text)" in report.notes[0]



@pytest.mark.slow   # a calibration by the command
def test_stats_and_calibrate_take_a_damaged_file(tmp_path, skin, capsys):
    """A garbage line in the middle and a file cut short: both commands read every complete touch, say what was
    lost, and the calibration is written."""
    import json

    from thesis_format import write_thesis_file

    from nao_skin import cli
    from nao_skin.sim.params import load_params
    from nao_skin.sim.simulate import simulate

    sim = simulate(skin, load_params("default", {"pairs": [["l_hand", "torso"]], "n_touches": 150}), seed=4).touches
    path = tmp_path / "damaged.txt"
    write_thesis_file(path, sim, skin)
    text = path.read_text()
    middle = text.index(f"'{sim.stamps[70]:.6f}': [{{") + 40      # inside the touch's first contact
    path.write_text(text[:middle] + "\n@@ garbage ]]\n" + text[middle:len(text) - 300])
    written = len({f"{stamp:.6f}" for stamp in sim.stamps})    # touches at one printed stamp are one key
    loaded = written - 2          # the one the garbage falls in, the last one (cut)
    assert cli.main(["stats", str(path), "--json"]) == 0
    said = capsys.readouterr()
    assert json.loads(said.out)["touches"] == loaded
    assert (f"{path}: damaged text at lines 1-3 (touch '{sim.stamps[70]:.6f}': unreadable text); line 3 (touch"
            f" '{sim.stamps[-1]:.6f}': the file ends inside it (cut short?)): 2 touches lost there; every complete"
            f" touch before and after it is read") in said.err
    assert cli.main(["calibrate", str(path), "--out", str(tmp_path / "out"), "--quiet", "--no-plots"]) == 0
    said = capsys.readouterr()
    assert f"{path}: {loaded} touches loaded of {written} touches read; skipped: 2 damaged text" in said.err
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["input"]["touches_loaded"] == loaded
