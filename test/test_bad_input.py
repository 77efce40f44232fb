"""Mistakes get one line and exit 2, checked before any data is read; every command sees the same skin.

Through the real command line (``nao_skin.cli.main`` in-process, or ``python -m
nao_skin.cli`` where the whole process matters), on real files: the shared real
recording and its layouts, and simulated touches written in the thesis' format.
"""
import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from thesis_format import write_thesis_file  # noqa: E402

from nao_skin.calibration.options import OPTION_FIELDS, CalibrationOptions, set_items
from nao_skin.cli import build_parser
from nao_skin.cli import main as cli_main
from nao_skin.errors import ConfigError, DataError
from nao_skin.formats.bag import read_touches
from nao_skin.formats.legacy import read_legacy
from nao_skin.model.skin import SkinCalibration, load_skin
from nao_skin.paths import config_dir, default_skin_config, package_dir
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate

BENCH_CHEAP = ["bench", "--quick", "--only", "hard", "--seeds", "1", "--presets", "ideal"]


def one_line(capsys) -> str:
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1, err
    return err[0]


@pytest.fixture(scope="module")
def skin():
    return load_skin()


@pytest.fixture(scope="module")
def thesis_touches(skin):
    """Twelve simulated left hand-torso touches (the simulator stands in for the robot)."""
    params = load_params("default", {"pairs": [["l_hand", "torso"]], "n_touches": 12})
    return simulate(skin, params, seed=2).touches


# ------------------------------------------------------------------------------ options
@pytest.mark.parametrize("args, says", [
    (["--test-fraction", "2"], "--test-fraction 2.0: expected a number in [0, 1)"),
    (["--test-fraction", "1"], "leaves no touch to train on"),
    (["--set", "test_fraction=abc"], "--set test_fraction=abc: expected a number"),
    (["--seed", "-1"], "--seed -1: expected a whole number in [0, 4294967295]"),
    (["--gate-mm", "nan"], "--gate-mm nan: expected a number in [0, 10000]"),
    # a float literal beyond 2**53 passed as a whole number: 1e22 rounds ran for ever
    (["--set", "rounds=1.0e+22"], "--set rounds=1.0e+22: expected a whole number in [1, 100]"),
    (["--set", "max_iterations=100000"], "--set max_iterations=100000: expected a whole number in [1, 10000]"),
    (["--set", "estimate_fabric=false", "--set", "fabric_thickness=99999999999999999999999"],
     "expected a number in [0, 0.01]"),
    (["--set", "patch_bounds=[0.003]"], "--set patch_bounds=[0.003]: expected 2 numbers in [1e-06, 10]"),
    # a bound of 1e-300 overflowed the prior's weight (a traceback)
    (["--set", "triangle_bounds=[1e-300, 1e-300]"], "--set triangle_bounds=[1e-300, 1e-300]: expected 2 numbers in"
                                                   " [1e-06, 10]"),
    (["--set", "bounded=1"], "--set bounded=1: expected true or false"),
    (["--set", "joint_levels=[mount, wrist]"], "expected a list of mount, patch, triangle"),
    (["--set", "lateral_weight=0.3"], "unknown calibration option 'lateral_weight'"),
    (["--set", "fabric_bounds=[0.003, 0.001]"], "lower bound is above the upper one"),
    (["--test-fraction", "x"], "argument --test-fraction: invalid float value: 'x'"),
    (["--splits", "0"], "--splits 0: expected a whole number from 1 to 100"),
    (["--splits", "3", "--set", "test_fraction=0"], "--splits 3: with test_fraction 0 no touch is held out"),
    (["--splits", "100000000000"], "--splits 100000000000: expected a whole number from 1 to 100"),   # had run out of memory
    # had failed after the first calibration, on a seed the user never gave
    (["--seed", "4294967295", "--splits", "2"], "--splits 2: the splits take seeds 4294967295..4294967296, beyond the"
                                                " largest seed 4294967295; give a smaller --seed"),
    (["--set", f"patch_bounds=[{10 ** 400}, 0.1]"], "expected 2 numbers in [1e-06, 10]"),   # beyond any float
    (["--set", "seed=1", "--set", "seed=2"], "--set seed=2: option seed is already given by --set seed=1; give it once"),
    (["--seed", "1", "--set", "seed=2"], "--set seed=2: option seed is already given by --seed 1"),
    (["--free", "--set", "bounded=true"], "--set bounded=true: option bounded is already given by --free"),
    (["--bounded", "--set", "bounded=false"], "--set bounded=false: option bounded is already given by --bounded"),
    (["--bounded", "--free"], "argument --free: not allowed with argument --bounded"),
    (["--no-first-guess", "--set", "initial_guess=rigid-fit"], "option initial_guess is already given by --no-first-guess"),
])
def test_a_wrong_option_is_one_line_before_any_data_is_read(tmp_path, capsys, args, says):
    # the input is broken: had it been read first, the line would be about the input
    broken = tmp_path / "broken.txt"
    broken.write_text("{'0': [{0: {'cop': [0, 0,")
    assert cli_main(["calibrate", str(broken), "--out", str(tmp_path / "out"), *args]) == 2
    line = one_line(capsys)
    assert says in line and "broken.txt" not in line, line
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("argv, says", [
    (["calibrate", "in.txt", "--out", "o1", "--out", "o2"],
     "nao-skin calibrate: error: argument --out: given twice (--out o1 and --out o2); give it once"),
    (["calibrate", "in.txt", "--out", "o", "--strategy", "sequential", "--strategy", "all-at-once"],
     "argument --strategy: given twice (--strategy sequential and --strategy all-at-once); give it once"),
    (["stats", "in.txt", "--skin", "a.yaml", "--skin", "b.yaml"], "argument --skin: given twice"),
    (["stats", "in.txt", "--skin", ""], "nao-skin stats: error: argument --skin: an empty value"),
    (["calibrate", "in.txt", "--out", "o", "--prior", " "], "argument --prior: an empty value"),
    (["stats", ""], "nao-skin stats: error: argument input: an empty value"),
    (["stats", "a.txt", "b.txt"], "nao-skin stats: error: unrecognized arguments: b.txt (see nao-skin stats --help)"),
], ids=["out-twice", "strategy-twice", "skin-twice", "empty-skin", "blank-prior", "empty-input", "extra-input"])
def test_an_option_given_twice_or_empty_is_a_mistake_not_the_last_or_the_default(tmp_path, capsys, monkeypatch,
                                                                                argv, says):
    """``--out a --out b`` wrote b alone, ``--skin ""`` read the default skin config, both with exit 0; an
    input too many was said as the top command's mistake."""
    monkeypatch.chdir(tmp_path)
    assert cli_main(argv) == 2
    assert says in one_line(capsys)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("argv, says", [
    (["stats", "bad\x1b[31mname.txt"], "nao-skin stats: error: bad\\x1b[31mname.txt: "),
    (["stats", "a.txt", "\x1b[2J"], "unrecognized arguments: \\x1b[2J (see nao-skin stats --help)"),
    (["calibrate", "a.txt", "--out", "o", "--strategy", "\x07\x9b"], "argument --strategy: invalid choice: '\\x07\\x9b'"),
], ids=["input", "extra", "choice"])
def test_a_control_character_in_an_input_is_shown_escaped_not_sent_to_the_terminal(tmp_path, capsys, monkeypatch,
                                                                                  argv, says):
    """A file name with an escape sequence was echoed raw in the error line: the terminal recoloured or
    cleared itself instead of showing which input was wrong."""
    monkeypatch.chdir(tmp_path)
    assert cli_main(argv) == 2
    line = one_line(capsys)
    assert says in line
    assert not any(ch in line for ch in "\x1b\x07\x9b")

def test_an_input_without_a_usable_touch_is_one_line_with_its_summary(tmp_path, capsys, thesis_touches, skin):
    """calibrate printed the input's summary and then the error holding it again; import's error gave no
    reason at all."""
    touches = thesis_touches.subset(np.arange(thesis_touches.n_touches))
    touches.joints[:, touches.joint_names.index("LShoulderPitch")] = np.inf
    path = tmp_path / "no_angles.txt"
    write_thesis_file(path, touches, skin)
    n = touches.n_touches
    summary = f"{path}: 0 touches loaded of {n} touches read; skipped: {n} bad joint angle"
    assert cli_main(["calibrate", str(path), "--out", str(tmp_path / "out"), "--quiet", "--no-plots"]) == 2
    assert one_line(capsys) == f"nao-skin calibrate: error: {path}: no usable touch in the input ({summary})"
    assert cli_main(["import", str(path), "-o", str(tmp_path / "bag")]) == 2
    captured = capsys.readouterr()
    assert captured.err.strip().splitlines()[-1] == (f"nao-skin import: error: {path}: no usable touch, nothing"
                                                     f" written ({summary})")
    assert summary not in captured.out and "joint 'LShoulderPitch' is not a finite angle" in captured.out
    assert not (tmp_path / "out").exists() and not (tmp_path / "bag").exists()


def test_no_command_is_a_usage_mistake_and_help_is_not(capsys):
    """``nao-skin`` alone says what is missing, as argparse says any other mistake; ``--help`` is no mistake."""
    assert cli_main([]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.splitlines()[0].startswith("usage: nao-skin")
    assert captured.err.splitlines()[-1] == "nao-skin: error: a command is required (nao-skin --help lists them)"
    assert cli_main(["--help"]) == 0
    assert "calibrate" in capsys.readouterr().out


def test_a_number_in_exponent_notation_is_a_number(tmp_path, capsys):
    """YAML 1.1 reads '1e-3' as a string: '--set f_scale=1e-3' was refused as "expected a number"."""
    broken = tmp_path / "broken.txt"
    broken.write_text("{'0': [{0: {'cop': [0, 0,")
    args = ["--set", "f_scale=1e-3", "--set", "patch_bounds=[3E-3, 1e-1]", "--set", "condition_limit=1e8"]
    assert cli_main(["calibrate", str(broken), "--out", str(tmp_path / "out"), *args]) == 2
    assert "broken.txt" in one_line(capsys)      # the options passed: the line is about the input
    options = CalibrationOptions()
    set_items(options, args[1::2])
    assert (options.f_scale, options.patch_bounds, options.condition_limit) == (1e-3, (3e-3, 0.1), 1e8)


def test_every_option_has_a_rule_and_help_and_takes_an_integer_for_a_float():
    options = CalibrationOptions()
    options.validate()
    for name, spec in OPTION_FIELDS.items():
        assert spec.metadata["help"].strip(), name
        if isinstance(spec.default, float):
            whole = next(v for v in (int(spec.default), int(spec.default) + 1, 0)
                         if not _refused(spec.metadata["rule"], float(v)))
            options.set(name, whole)
            assert isinstance(getattr(options, name), float) and getattr(options, name) == whole, name


def test_options_read_back_from_a_report_are_the_options_and_checked_by_the_same_rules():
    """One way from a mapping to options (a report's, a node's parameters, a bench's overrides): JSON lists come
    back as the tuples they were, and a value out of range names its input."""
    import json

    options = CalibrationOptions(closing_levels=("patch", "triangle"), f_scale=0.003, kinematics="auto")
    assert CalibrationOptions.from_mapping(json.loads(json.dumps(options.as_mapping()))) == options
    with pytest.raises(DataError, match=r"^parameter f_scale:=-1: expected a number"):
        CalibrationOptions.from_mapping({"f_scale": -1}, where="parameter {name}:={value!r}")
    with pytest.raises(DataError, match="unknown calibration option 'fscale'"):
        CalibrationOptions.from_mapping({"fscale": 1e-3})
    with pytest.raises(DataError, match="fabric_bounds.*lower bound is above"):     # checked together too
        CalibrationOptions.from_mapping({"fabric_bounds": [0.003, 0.001]})


def _refused(rule, value) -> bool:
    try:
        rule.check("x", value)
    except DataError:
        return True
    return False


def test_the_command_offers_every_value_the_engine_takes():
    args = build_parser().parse_args(["calibrate", "x.txt", "--out", "o", "--pairs", "cop+taxel5"])
    from nao_skin.commands.calibrate import build_options

    assert build_options(args).pairs == "cop+taxel5"


def test_every_option_of_every_command_has_a_help_text():
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    missing = [f"{name} {a.option_strings or a.dest}" for name, p in sub.choices.items() for a in p._actions
               if not isinstance(a, argparse._HelpAction) and not (a.help or "").strip()]
    assert not missing


# ------------------------------------------------------------------------------ angles
def test_a_nan_joint_angle_is_named_as_a_non_finite_angle(tmp_path, skin, thesis_touches):
    touches = thesis_touches.subset(np.arange(thesis_touches.n_touches))
    touches.joints[3, touches.joint_names.index("LElbowRoll")] = np.nan     # a driver's NaN, printed as `nan`
    path = tmp_path / "with_nan.txt"
    write_thesis_file(path, touches, skin)
    assert "nan" in path.read_text()
    loaded, report = read_legacy(path, skin)
    assert loaded.n_touches == touches.n_touches - 1
    assert dict(report.skipped) == {"bad joint angle": 1}
    assert "joint 'LElbowRoll' is not a finite angle" in report.messages[0], report.messages


def test_a_boolean_joint_angle_is_no_angle(tmp_path, skin, thesis_touches):
    path = tmp_path / "with_bool.txt"
    write_thesis_file(path, thesis_touches, skin)
    text = path.read_text()
    at = text.index("'LElbowRoll': ") + len("'LElbowRoll': ")
    end = min(i for i in (text.find(",", at), text.find("}", at)) if i >= 0)
    path.write_text(text[:at] + "True" + text[end:])            # float(True) was taken as 1 rad
    loaded, report = read_legacy(path, skin)
    assert loaded.n_touches == thesis_touches.n_touches - 1
    assert dict(report.skipped) == {"bad joint angle": 1}
    assert "joint 'LElbowRoll': not a number (True)" in report.messages[0], report.messages


def test_angles_outside_the_joint_limits_are_kept_counted_and_named(tmp_path, capsys, skin, thesis_touches):
    touches = thesis_touches.subset(np.arange(thesis_touches.n_touches))
    j = touches.joint_names.index("LElbowRoll")
    low, high = skin.robot.limits[skin.robot.joint_index["LElbowRoll"]]
    touches.joints[[1, 4], j] = high + 0.05
    path = tmp_path / "past_limits.txt"
    write_thesis_file(path, touches, skin)
    assert cli_main(["stats", str(path), "--json"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out.splitlines()[-1])["touches"] == touches.n_touches        # kept
    note = [line for line in out.err.splitlines() if "outside the robot config's limits" in line]
    assert len(note) == 1 and "2 of 12 touches" in note[0] and "LElbowRoll" in note[0] and "kept" in note[0]


def test_an_angle_an_encoder_count_past_a_limit_is_at_it(tmp_path, capsys, skin, thesis_touches):
    """A joint at its hard stop reads a count past the documented limit: no note for that, one for a real excess."""
    from nao_skin.model.robot import JOINT_LIMIT_TOLERANCE

    touches = thesis_touches.subset(np.arange(thesis_touches.n_touches))
    j = touches.joint_names.index("LElbowRoll")
    low, high = skin.robot.limits[skin.robot.joint_index["LElbowRoll"]]
    touches.joints[[0, 2, 3], j] = high + 0.5 * JOINT_LIMIT_TOLERANCE     # a count past it: at the stop
    touches.joints[[5], j] = low - 2 * JOINT_LIMIT_TOLERANCE              # past it
    path = tmp_path / "at_the_stops.txt"
    write_thesis_file(path, touches, skin)
    assert cli_main(["stats", str(path), "--json"]) == 0
    note = [line for line in capsys.readouterr().err.splitlines() if "outside the robot config's limits" in line]
    assert len(note) == 1 and "1 of 12 touches" in note[0] and f"{2 * JOINT_LIMIT_TOLERANCE:.4g} rad past" in note[0]
    touches.joints[5, j] = low
    write_thesis_file(path, touches, skin)
    assert cli_main(["stats", str(path), "--json"]) == 0
    assert "outside the robot config's limits" not in capsys.readouterr().err


def test_the_real_recording_is_noted_only_for_its_real_excesses(capsys, real_recording, real_taxels, real):
    """A third of the real recording's touches were said to be outside the limits, mostly for 0.00007 rad (the
    wrists at their stops); the note now counts only the touches past them by more than an encoder count."""
    from nao_skin.formats.inputs import joint_limit_note
    from nao_skin.model.robot import JOINT_LIMIT_TOLERANCE

    robot = load_skin().robot
    cols = [i for i, n in enumerate(real.joint_names) if n in robot.joint_index]
    limits = robot.limits[[robot.joint_index[real.joint_names[i]] for i in cols]]
    with np.errstate(invalid="ignore"):
        past = np.nan_to_num(np.fmax(limits[:, 0] - real.joints[:, cols], real.joints[:, cols] - limits[:, 1]),
                             nan=-1.0).max(axis=1)
    beyond = int((past > JOINT_LIMIT_TOLERANCE).sum())
    assert 0 < beyond < int((past > 0).sum()), (beyond, int((past > 0).sum()))     # both kinds are in it
    assert cli_main(["stats", str(real_recording), *real_taxels]) == 0
    note = [line for line in capsys.readouterr().out.splitlines() if "outside the robot config's limits" in line]
    assert len(note) == 1 and f": {beyond} of {real.n_touches} touches" in note[0], note
    assert joint_limit_note(real.subset(np.flatnonzero(past <= JOINT_LIMIT_TOLERANCE)), robot, "x") is None


def test_a_note_given_to_the_summary_is_not_logged_again(tmp_path, skin, thesis_touches):
    """calibrate logs to stdout and summarises to stderr: a note on both would be printed twice."""
    from nao_skin.formats.inputs import load_touches

    touches = thesis_touches.subset(np.arange(thesis_touches.n_touches))
    touches.joints[[1, 4], touches.joint_names.index("LElbowRoll")] = 10.0
    path = tmp_path / "past_limits.txt"
    write_thesis_file(path, touches, skin)
    logged, summarised = [], []
    load_touches([path], skin, log=logged.append, summary=summarised.append)
    said = [line for line in logged + summarised if "outside the robot config's limits" in line]
    assert len(said) == 1 and said[0] in summarised, (logged, summarised)
    assert any("touches loaded" in line for line in logged)


def test_an_absurd_angle_is_named_in_a_short_line(tmp_path, capsys, skin, thesis_touches):
    touches = thesis_touches.subset(np.arange(thesis_touches.n_touches))
    touches.joints[1, touches.joint_names.index("LElbowRoll")] = 1e300      # finite, but no joint's angle
    touches.joints[2, touches.joint_names.index("LElbowRoll")] = -1.6       # past the limit: kept as measured
    path = tmp_path / "absurd.txt"
    write_thesis_file(path, touches, skin)
    assert cli_main(["stats", str(path), "--json"]) == 0
    err = capsys.readouterr().err.splitlines()
    skipped = [line for line in err if "joint 'LElbowRoll' = 1e+300 rad, beyond two turns" in line]
    assert len(skipped) == 1 and len(skipped[0]) < 400, err
    note = [line for line in err if "outside the robot config's limits" in line]
    assert len(note) == 1 and "LElbowRoll = -1.6 rad" in note[0] and len(note[0]) < 400, note


# ------------------------------------------------------------------------------ one skin model
@pytest.fixture(scope="module")
def real_calibration(tmp_path_factory, real_recording, real_taxels):
    """The real recording calibrated with its own layouts, through the command."""
    out = tmp_path_factory.mktemp("real") / "cal"
    run = subprocess.run([sys.executable, "-m", "nao_skin.cli", "calibrate", str(real_recording), *real_taxels,
                          "--out", str(out), "--quiet", "--no-plots"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    return out, run


@pytest.mark.slow   # real_calibration: the real recording calibrated by the command
def test_stats_evaluates_a_calibration_with_the_layouts_it_was_made_with(capsys, real_calibration, real_recording,
                                                                         real_taxels):
    out, _ = real_calibration
    report = json.loads((out / "report.json").read_text())
    assert cli_main(["stats", str(real_recording), *real_taxels, "--calibration", str(out / "calibration.yaml"),
                     "--json"]) == 0
    stats = json.loads(capsys.readouterr().out.splitlines()[-1])
    n_train, n_test = report["final"]["train"]["n_touches"], report["final"]["test"]["n_touches"]
    cop = (report["final"]["train"]["cop_mean_mm"] * n_train + report["final"]["test"]["cop_mean_mm"] * n_test) \
        / (n_train + n_test)
    # stats pairs every touch (duplicates too): the same skin gives the split's figures within a few %
    assert stats["cop_mean_mm"] == pytest.approx(cop, rel=0.05)


@pytest.mark.slow   # real_calibration: the real recording calibrated by the command
def test_another_layout_refuses_the_calibration_in_one_line(capsys, real_calibration, real_recording):
    out, _ = real_calibration
    assert cli_main(["stats", str(real_recording), "--calibration", str(out / "calibration.yaml")]) == 2
    line = one_line(capsys)
    assert "calibrated on the layout l_hand.taxels.txt" in line and "--taxels l_hand=" in line, line
    doc = (out / "calibration.yaml").read_text()
    assert "file: l_hand.taxels.txt" in doc and "sha256:" in doc


@pytest.mark.slow   # real_calibration: the real recording calibrated by the command
def test_urdf_takes_the_layouts_a_calibration_was_made_with(tmp_path, capsys, real_calibration, real_taxels):
    """urdf told a user to give the same layout with --taxels, which it did not have."""
    out, _ = real_calibration
    calibration = str(out / "calibration.yaml")
    assert cli_main(["urdf", "--calibration", calibration, "--out", str(tmp_path / "a.urdf")]) == 2
    assert "--taxels l_hand=" in one_line(capsys)
    assert cli_main(["urdf", "--calibration", calibration, *real_taxels, "--out", str(tmp_path / "b.urdf")]) == 0
    assert "l_hand_skin_mount" in (tmp_path / "b.urdf").read_text()


@pytest.mark.slow   # real_calibration: the real recording calibrated by the command
def test_calibrate_prints_the_engine_time_and_the_whole_command_time(real_calibration):
    _, run = real_calibration
    line = run.stdout.strip().splitlines()[-1]
    engine = float(line.split("(engine ")[1].split(" s")[0])
    whole = float(line.split("whole command ")[1].split(" s")[0])
    assert 0 < engine <= whole + 0.05


def test_a_layout_is_the_same_whatever_file_holds_it(tmp_path, real_dir):
    skin = load_skin()
    part = skin.parts["torso"]
    part.write_taxel_file(tmp_path / "torso_copy.txt")        # the same taxels, another file and format
    again = load_skin(taxel_files={"torso": tmp_path / "torso_copy.txt"})
    assert again.parts["torso"].layout_sha256 == part.layout_sha256
    calib = skin.zero_calibration()
    calib.save(tmp_path / "c.yaml", skin)
    SkinCalibration.load(tmp_path / "c.yaml", again)            # same layout: accepted
    real = load_skin(taxel_files={"torso": real_dir / "torso.taxels.txt"})
    with pytest.raises(ConfigError, match="part 'torso' was calibrated on the layout torso.txt"):
        SkinCalibration.load(tmp_path / "c.yaml", real)
    # a layout record that is no record: the check it is there for was skipped without a word
    import yaml

    doc = yaml.safe_load((tmp_path / "c.yaml").read_text())
    for broken in ("x", {"file": "torso.txt"}, {"file": "torso.txt", "sha256": 7}):
        doc["parts"]["torso"]["layout"] = broken
        (tmp_path / "bad.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
        with pytest.raises(ConfigError, match=r"bad.yaml: part 'torso': 'layout' must be a mapping with 'file' and"
                                              r" 'sha256'"):
            SkinCalibration.load(tmp_path / "bad.yaml", skin)


def test_a_calibration_hanging_off_another_base_frame_is_refused(tmp_path):
    skin = load_skin()
    skin.zero_calibration().save(tmp_path / "c.yaml", skin)
    text = (tmp_path / "c.yaml").read_text()
    (tmp_path / "c.yaml").write_text(text.replace("base_frame: torso", "base_frame: head"))
    with pytest.raises(ConfigError, match="c.yaml: its frames hang off base frame 'head'; the robot config's is"
                                          " 'torso'"):
        SkinCalibration.load(tmp_path / "c.yaml", skin)


def test_a_calibration_applies_only_to_the_chain_description_it_was_made_on(tmp_path):
    """A robot config of the same name with another DH row took a calibration made on the real one."""
    skin = load_skin()
    skin.zero_calibration().save(tmp_path / "c.yaml", skin)
    config = (config_dir() / "nao_h25.yaml").read_text()
    renamed = config.replace("frame: l_wrist_link", "frame: l_wrist")          # the same arm, another frame name
    assert renamed != config
    tilted = config.replace("offset: pi,    frame: l_wrist_link", "offset: 3.15,  frame: l_wrist_link")
    assert tilted != config
    for text, name in ((renamed, "renamed"), (tilted, "tilted")):
        (tmp_path / f"{name}.yaml").write_text(text)
        other = load_skin(robot_config=tmp_path / f"{name}.yaml")
        assert other.robot.name == skin.robot.name
        with pytest.raises(ConfigError, match=r"part 'l_hand' was calibrated on another description of chain 'l_arm'"
                                              rf" \(sha256 [0-9a-f]{{12}}\) than the robot config's .*{name}.yaml"):
            SkinCalibration.load(tmp_path / "c.yaml", other)
    # "pi" written out: the same description
    (tmp_path / "same.yaml").write_text(config.replace("offset: pi,    frame: l_wrist_link",
                                                       f"offset: {math.pi!r}, frame: l_wrist_link"))
    SkinCalibration.load(tmp_path / "c.yaml", load_skin(robot_config=tmp_path / "same.yaml"))


def test_an_unknown_part_in_taxels_is_one_line(capsys, tmp_path, real_recording, real_dir):
    assert cli_main(["stats", str(real_recording), "--taxels", f"l_arm={real_dir / 'l_hand.taxels.txt'}"]) == 2
    assert "unknown skin part 'l_arm'" in one_line(capsys)
    assert cli_main(["stats", str(real_recording), "--taxels", f"l_hand={tmp_path / 'none.txt'}"]) == 2
    assert "none.txt: no such file" in one_line(capsys)
    assert cli_main(["stats", str(real_recording), "--taxels", f"l_hand={tmp_path}"]) == 2
    assert f"{tmp_path} is a directory, not a taxel file" in one_line(capsys)
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    assert cli_main(["stats", str(real_recording), "--taxels", f"l_hand={tmp_path / 'loop'}"]) == 2
    assert "loop: a symbolic link that leads nowhere (a loop or a missing target)" in one_line(capsys)
    os.mkfifo(tmp_path / "fifo")         # it was "no such file"
    assert cli_main(["stats", str(real_recording), "--taxels", f"l_hand={tmp_path / 'fifo'}"]) == 2
    assert "fifo: not a regular file" in one_line(capsys)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_bag_whose_storage_file_is_no_regular_file_is_one_line(tmp_path, capsys, skin, storage):
    """A bag's storage file that is a FIFO waited for a writer for ever (SIGTERM did not stop it), one that is
    /dev/zero grew to 23 GB; a huge storage file read from itself (its bag does not open) ended in a
    MemoryError traceback."""
    from nao_skin.formats.bag import write_touch_bag
    from nao_skin.sim.simulate import simulate

    bag = tmp_path / "bag"
    write_touch_bag(bag, simulate(skin, {"n_touches": 3}, seed=2).touches, skin, storage=storage)
    (file,) = [p for p in bag.iterdir() if p.suffix in (".mcap", ".db3")]
    kept = tmp_path / "kept"
    file.rename(kept)
    os.mkfifo(tmp_path / "fifo")
    for target, kind in ((tmp_path / "fifo", "a FIFO"), (Path("/dev/zero"), "a character device")):
        file.symlink_to(target)
        assert cli_main(["stats", str(bag)]) == 2
        assert one_line(capsys) == (f"nao-skin stats: error: {file}: cannot read the bag's storage (it is {kind},"
                                    f" not a regular file)")
        file.unlink()
    os.mkfifo(tmp_path / "alone.mcap")
    assert cli_main(["stats", str(tmp_path / "alone.mcap")]) == 2
    assert "alone.mcap: cannot read the bag's storage (it is a FIFO, not a regular file)" in one_line(capsys)
    if storage == "mcap":       # read from the file itself when its bag does not open: at most 1 GiB of it
        kept.rename(file)
        with open(file, "r+b") as f:
            f.truncate((1 << 30) + 1)     # sparse: no gigabyte written
        assert cli_main(["stats", str(bag)]) == 2
        assert "is larger than 1 GiB and its bag does not open" in one_line(capsys)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_bag_whose_metadata_yaml_is_no_regular_file_is_one_line(tmp_path, capsys, skin, storage):
    """A FIFO named metadata.yaml waited for a writer for ever (the storage files were checked, it was not),
    and so did every reader of the bag: stats, check, calibrate (an adversarial review, 2026-11-28)."""
    from nao_skin.formats.bag import write_touch_bag

    bag = tmp_path / "bag"
    write_touch_bag(bag, simulate(skin, {"n_touches": 3}, seed=2).touches, skin, storage=storage)
    (bag / "metadata.yaml").rename(tmp_path / "kept.yaml")
    os.mkfifo(tmp_path / "fifo")
    for target, kind in ((tmp_path / "fifo", "a FIFO"), (Path("/dev/zero"), "a character device")):
        (bag / "metadata.yaml").symlink_to(target)
        assert cli_main(["stats", str(bag)]) == 2
        assert one_line(capsys) == (f"nao-skin stats: error: {bag / 'metadata.yaml'}: cannot read the bag's"
                                    f" metadata (it is {kind}, not a regular file)")
        (bag / "metadata.yaml").unlink()
    (tmp_path / "kept.yaml").rename(bag / "metadata.yaml")
    assert cli_main(["stats", str(bag)]) == 0


def test_a_ground_truth_beside_a_recording_that_is_no_regular_file_is_a_note(tmp_path, capsys):
    """The simulator's truth_calibration.yaml is never asked for: as a FIFO it hung stats, check and calibrate
    (it was read whole to compare it with the other inputs' even when there was one input), as a directory it
    refused the recording. Now a note says no true error is reported, and the recording is read."""
    out = tmp_path / "sim"
    assert cli_main(["simulate", "--seed", "1", "--touches-per-pair", "3", "--out", str(out)]) == 0
    truth = out / "truth_calibration.yaml"
    truth.unlink()
    os.mkfifo(tmp_path / "fifo")
    for make, kind in ((lambda: truth.symlink_to(tmp_path / "fifo"), "a FIFO"),
                       (lambda: truth.symlink_to("/dev/zero"), "a character device"),
                       (lambda: truth.mkdir(), "a directory")):
        make()
        capsys.readouterr()
        assert cli_main(["stats", str(out), "--json"]) == 0
        said = capsys.readouterr()
        assert (f"{truth}: cannot read as the simulator's ground truth (it is {kind}, not a regular file): no true"
                f" taxel error is reported") in said.out + said.err
        assert json.loads(said.out.splitlines()[-1])["touches"] > 0
        truth.rmdir() if truth.is_dir() and not truth.is_symlink() else truth.unlink()


def test_an_output_marker_that_is_no_regular_file_is_not_ours(tmp_path, capsys):
    """A FIFO in place of an output's .nao_skin_output hung calibrate and simulate, --force or not (the marker
    was read as it was), JSON nested 100000 deep there was a RecursionError traceback. Now it is no marker of
    ours, and the directory one nao-skin did not write."""
    out = tmp_path / "out"
    assert cli_main(["simulate", "--seed", "1", "--touches-per-pair", "2", "--out", str(out)]) == 0
    marker = out / ".nao_skin_output"
    for make in (os.mkfifo, lambda path: path.write_text("[" * 100_000)):    # JSON too deep: a RecursionError
        marker.unlink()
        make(marker)
        before = sorted(p.name for p in out.iterdir())
        for force in ([], ["--force"]):
            capsys.readouterr()
            assert cli_main(["simulate", "--seed", "1", "--touches-per-pair", "2", "--out", str(out), *force]) == 2
            assert f"--out {out}: is a non-empty directory nao-skin did not write" in one_line(capsys)
        assert sorted(p.name for p in out.iterdir()) == before


def test_stats_reads_a_simulator_output_directory(tmp_path, capsys):
    assert cli_main(["simulate", "--preset", "default", "--seed", "1", "--touches-per-pair", "2",
                     "--out", str(tmp_path / "session")]) == 0
    capsys.readouterr()
    assert cli_main(["stats", str(tmp_path / "session"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["touches"] > 0


def test_a_ground_truth_beside_the_inputs_is_used_only_where_it_describes_them(tmp_path, capsys):
    """The simulator's truth_calibration.yaml is found beside its recording, never asked for: another robot
    config refused the recording itself ("made for robot 'nao_h25'", naming a file the user never gave), and
    two simulations calibrated together were judged against the first one's truth (8.6 mm, exit 0)."""
    from nao_skin.formats.inputs import load_touches

    for seed in (1, 2):
        assert cli_main(["simulate", "--seed", str(seed), "--touches-per-pair", "2", "--out",
                         str(tmp_path / f"sim{seed}")]) == 0
    capsys.readouterr()
    skin, notes = load_skin(), []
    _, _, truth = load_touches([str(tmp_path / "sim1")], skin, log=lambda line: None)
    assert truth is not None
    _, _, truth = load_touches([str(tmp_path / "sim1"), str(tmp_path / "sim2")], skin, log=notes.append)
    assert truth is None and any("the inputs carry different ground truths" in n for n in notes), notes
    manufacturer = load_skin(robot_config=package_dir() / "config" / "nao_h25_manufacturer.yaml")
    touches, _, truth = load_touches([str(tmp_path / "sim1")], manufacturer, log=notes.append)
    assert truth is None and touches.n_touches > 0
    assert "the simulator's ground truth does not fit this skin" in notes[-1], notes
    assert cli_main(["stats", str(tmp_path / "sim1"), "--robot", str(package_dir() / "config" /
                                                                   "nao_h25_manufacturer.yaml")]) == 0


@pytest.mark.parametrize("command", [["calibrate", "--out", "OUT"], ["stats"], ["import", "-o", "OUT"],
                                     ["demo", "--out", "OUT", "--input"]])
def test_missing_and_empty_inputs_get_the_same_line_in_every_command(tmp_path, capsys, command):
    (tmp_path / "empty").mkdir()
    for given, says in ((tmp_path / "missing.txt", "no such file or directory"),
                        (tmp_path / "empty", "empty directory")):
        argv = [*[str(tmp_path / "o") if a == "OUT" else a for a in command], str(given)] if command[0] == "demo" \
            else [command[0], str(given), *[str(tmp_path / "o") if a == "OUT" else a for a in command[1:]]]
        assert cli_main(argv) == 2
        assert one_line(capsys) == f"nao-skin {command[0]}: error: {given}: {says}" + (
            "; expected a rosbag2 recording, a simulator output directory or a legacy .txt data set"
            if says == "empty directory" else "")


def test_one_recording_named_twice_is_refused_before_its_touches_count_twice(tmp_path, capsys, real_recording):
    shutil.copy(real_recording, tmp_path / "touches.txt")
    (tmp_path / "link.txt").symlink_to(tmp_path / "touches.txt")
    for again in (str(tmp_path / "touches.txt"), str(tmp_path / "." / "touches.txt"), str(tmp_path / "link.txt")):
        assert cli_main(["calibrate", str(tmp_path / "touches.txt"), again, "--out", str(tmp_path / "o")]) == 2
        assert one_line(capsys) == (f"nao-skin calibrate: error: {again}: the same recording as the input"
                                    f" {tmp_path / 'touches.txt'}; give each input once (its touches would count twice)")
    bag = package_dir() / "bags" / "sim_default"
    assert cli_main(["calibrate", str(bag), str(bag / "touches" / "touches.bag.db3"),
                     "--out", str(tmp_path / "o")]) == 2
    assert "the same recording as the input" in one_line(capsys)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", [["calibrate", "BROKEN"], ["simulate", "--touches-per-pair", "2"],
                                     [*BENCH_CHEAP], ["demo", "--input", "BROKEN"], ["bench-capture", "--quick"]])
def test_an_out_nothing_can_be_written_in_is_refused_before_any_work(tmp_path, capsys, command):
    broken = tmp_path / "broken.txt"              # had it been read first, the line would be about it
    broken.write_text("{'0': [{0: {'cop': [0, 0,")
    out = "/proc/nao_skin_out"                    # no directory can be made there, even by root
    assert cli_main([str(broken) if a == "BROKEN" else a for a in command] + ["--out", out]) == 2
    assert one_line(capsys) == f"nao-skin {command[0]}: error: --out {out}: cannot write in /proc" \
                               f" (No such file or directory); choose another place"


def test_simulate_refuses_a_negative_seed_in_one_line(tmp_path, capsys):
    assert cli_main(["simulate", "--seed", "-1", "--out", str(tmp_path / "sim")]) == 2
    assert one_line(capsys) == "nao-skin simulate: error: --seed -1: expected a whole number >= 0"
    assert not (tmp_path / "sim").exists()


@pytest.mark.parametrize("output, says", [
    ("/proc/nao_skin_bag", "/proc/nao_skin_bag: cannot write the bag (No such file or directory)"),
    ("notes.txt/bag", "notes.txt is a file, not a directory"),
], ids=["proc", "below-a-file"])
def test_import_to_a_place_no_bag_can_be_written_is_one_line(tmp_path, capsys, monkeypatch, output, says,
                                                             real_recording, real_taxels):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("mine\n")
    assert cli_main(["import", str(real_recording), "-o", output, *real_taxels]) == 2
    line = one_line(capsys)
    assert line.startswith("nao-skin import: error: ") and says in line, line
    assert (tmp_path / "notes.txt").read_text() == "mine\n"


def test_import_refuses_a_stamp_no_bag_can_hold_and_leaves_no_half_bag(tmp_path, capsys, skin, thesis_touches):
    touches = thesis_touches.subset(np.arange(thesis_touches.n_touches))
    touches.stamps[5] = 3e9     # a timestamp key beyond what a ROS header's int32 seconds hold (was a struct.error)
    legacy = tmp_path / "far_future.txt"
    write_thesis_file(legacy, touches, skin)
    assert cli_main(["import", str(legacy), "-o", str(tmp_path / "bag")]) == 2
    line = one_line(capsys)
    # the input is named, where the stamp is to be corrected (it named the bag that was not written)
    assert line.startswith(f"nao-skin import: error: {legacy}: touch '3000000000") and \
        line.endswith("': stamp 3000000000.0 is not a time between 0 and 2147483647 s (a ROS message header holds"
                      " int32 seconds: up to January 2038)"), line
    assert not (tmp_path / "bag").exists()


KILLED_MID_WRITE = """
import os, signal, sys
from nao_skin.cli import main
from nao_skin.formats import bag
write, written = bag.BagWriter.write_touch, []
def write_then_die(self, *args):
    write(self, *args)
    written.append(1)
    if len(written) == 100:         # kill -9 (a power cut) half-way through the touches: no clean-up runs
        os.kill(os.getpid(), signal.SIGKILL)
bag.BagWriter.write_touch = write_then_die
sys.exit(main(sys.argv[1:]))
"""


def test_an_import_killed_half_way_leaves_no_half_bag_and_the_next_run_cleans_up(tmp_path, real_recording,
                                                                                  real_taxels):
    """kill -9 during the write left half a bag at -o, which read as a recorder's crash and made a rerun refuse."""
    argv = ["import", str(real_recording), "-o", "bag", "--storage", "mcap", *real_taxels]
    run = subprocess.run([sys.executable, "-c", KILLED_MID_WRITE, *argv], cwd=tmp_path, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == -9, run.stderr
    assert not (tmp_path / "bag").exists()
    (left,) = tmp_path.glob(".bag.*")            # what the killed run wrote, hidden beside -o
    assert cli_main(["import", str(real_recording), "-o", str(tmp_path / "bag"), "--storage", "mcap",
                     *real_taxels]) == 0
    assert not left.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["bag"]
    touches, report = read_touches(tmp_path / "bag",
                                   load_skin(taxel_files=dict(t.split("=") for t in real_taxels[1::2])))
    assert touches.n_touches == 810 and report.n_skipped == 0


def test_a_legacy_cop_metres_away_skips_its_touch(tmp_path, skin, thesis_touches):
    path = tmp_path / "far_cop.txt"
    write_thesis_file(path, thesis_touches, skin)
    # the first touch's first COP 1e308 m away: inf as a float32 in a bag, overflow in every sum of squares
    path.write_text(re.sub(r"'cop': \[[^]]*\]", "'cop': [1e308, 1e308, 1e308]", path.read_text(), count=1))
    loaded, report = read_legacy(path, skin)
    assert loaded.n_touches == thesis_touches.n_touches - 1 and dict(report.skipped) == {"malformed field": 1}
    assert "field 'cop': [1e+308, 1e+308, 1e+308] lies beyond 10 m of its part's frame" in report.messages[0]


@pytest.mark.parametrize("command, inputs", [
    (["nominal", "--skin-config", "cfg/nao_skin.yaml"], ["cfg/nao_skin.yaml", "cfg/nao_h25.yaml", "cfg/layouts/head.txt"]),
    (["urdf", "--skin-config", "cfg/nao_skin.yaml", "--calibration", "cfg/calibration_nominal.yaml"],
     ["cfg/calibration_nominal.yaml", "cfg/nao_skin.yaml", "cfg/nao_h25.yaml"]),
], ids=["nominal", "urdf"])
def test_a_file_output_never_replaces_an_input_and_needs_a_writable_place(tmp_path, capsys, monkeypatch,
                                                                         command, inputs):
    monkeypatch.chdir(tmp_path)
    shutil.copytree(package_dir() / "config", tmp_path / "cfg")
    (tmp_path / "notes.txt").write_text("mine\n")
    before = {p: p.read_bytes() for p in (tmp_path / "cfg").rglob("*") if p.is_file()}
    for out in inputs:
        assert cli_main([*command, "--out", out]) == 2
        assert one_line(capsys) == (f"nao-skin {command[0]}: error: --out {out}: is the input {out};"
                                    f" writing there would replace it, choose another file")
    for out, says in (("cfg", "is a directory; give a file name"),
                      ("notes.txt/out.yaml", f"{tmp_path / 'notes.txt'} is a file, not a directory"),
                      ("/proc/nao_skin/out.yaml", "cannot write (No such file or directory)")):
        assert cli_main([*command, "--out", out]) == 2
        assert one_line(capsys).startswith(f"nao-skin {command[0]}: error: --out {out}: {says}")
    assert {p: p.read_bytes() for p in (tmp_path / "cfg").rglob("*") if p.is_file()} == before
    assert (tmp_path / "notes.txt").read_text() == "mine\n"
    assert cli_main([*command, "--out", "new/out.yaml"]) == 0          # a new file is fine, an earlier one too
    assert cli_main([*command, "--out", "new/out.yaml"]) == 0
    assert sorted(p.name for p in (tmp_path / "new").iterdir()) == ["out.yaml"]     # no temporary left over


def test_layouts_that_cannot_be_written_leave_no_folder_behind(tmp_path, capsys, monkeypatch):
    """A full disk while the layouts are written (here a stand-in: the write raises ENOSPC, as on a full
    tmpfs) left the folders the run had made, empty."""
    import errno

    from nao_skin.formats import outdir

    def full(path, data, read_only_too=False):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(outdir, "replace_file", full)
    (tmp_path / "mine").mkdir()
    assert cli_main(["layouts", str(tmp_path / "mine" / "new" / "layouts")]) == 2
    assert one_line(capsys).endswith("cannot write (No space left on device); choose another place")
    assert list((tmp_path / "mine").iterdir()) == []        # the user's folder stays, what the run made is gone


def test_layouts_never_replace_a_robots_own_layout_without_force(tmp_path, capsys, real_dir):
    own = tmp_path / "layouts" / "l_hand.txt"
    own.parent.mkdir()
    shutil.copy(real_dir / "l_hand.taxels.txt", own)
    assert cli_main(["layouts", str(own.parent)]) == 2
    assert one_line(capsys) == (f"nao-skin layouts: error: layouts {own.parent}: {own} differs from the default"
                                f" layout; nothing written (pass --force to replace it, or choose another directory)")
    assert own.read_bytes() == (real_dir / "l_hand.taxels.txt").read_bytes() and len(list(own.parent.iterdir())) == 1
    assert cli_main(["layouts", str(own.parent), "--force"]) == 0
    assert cli_main(["layouts", str(own.parent)]) == 0                  # the defaults again: the same bytes
    capsys.readouterr()
    assert cli_main(["layouts", str(tmp_path / "layouts" / "head.txt")]) == 2
    assert "head.txt is a file, not a directory" in one_line(capsys)
    # --force replaces a link under a layout's name, never the file it points to outside the directory
    elsewhere = tmp_path / "precious.txt"
    elsewhere.write_text("the user's own file\n")
    linked = tmp_path / "linked"
    linked.mkdir()
    (linked / "l_hand.txt").symlink_to(elsewhere)
    assert cli_main(["layouts", str(linked), "--force"]) == 0
    assert elsewhere.read_text() == "the user's own file\n"
    assert not (linked / "l_hand.txt").is_symlink() and (linked / "l_hand.txt").read_bytes() == own.read_bytes()
    # a folder under a layout's name: nothing written, not the layouts before it (r_hand.txt had been)
    blocked = tmp_path / "blocked"
    (blocked / "l_hand.txt").mkdir(parents=True)
    assert cli_main(["layouts", str(blocked), "--force"]) == 2
    assert one_line(capsys) == (f"nao-skin layouts: error: layouts {blocked}: {blocked / 'l_hand.txt'} is a directory,"
                                f" not a regular file; nothing written; choose another place")
    assert [p.name for p in blocked.iterdir()] == ["l_hand.txt"]


@pytest.mark.parametrize("args, says", [
    (["--presets", ""], "argument --presets: an empty value; give one, or leave the option out for its default"),
    (["--hard-pairs", "l_hand-torso,l_hand-torso"], "--hard-pairs 'l_hand-torso' is given twice"),
    # '' and ',' had meant every pair; a pair the simulator cannot make touch had failed every case, row by row
    (["--hard-pairs", ""], "argument --hard-pairs: an empty value"),
    (["--hard-pairs", ","], "--hard-pairs ',': expected HAND-PART pairs"),
    (["--hard-pairs", "torso-head"], "--hard-pairs 'torso-head': the simulator cannot make torso-head touch"),
    (["--hard-pairs", "l_hand-elbow"], "--hard-pairs 'l_hand-elbow': expected HAND-PART of two skin parts"),
    (["--only", "speed", "--sim-pairs", ""], "argument --sim-pairs: an empty value"),
    (["--only", "speed", "--sim-pairs", "foo-bar"], "--sim-pairs 'foo-bar': expected HAND-PART of two skin parts"),
    (["--hard-touches", "-3"], "--hard-touches -3: expected a whole number in 1..100000"),
    (["--hard-touches", str(10 ** 12)], "--hard-touches 1000000000000: expected a whole number in 1..100000"),
    (["--jobs", "-2"], "--jobs -2: expected a whole number from 1 to 64"),
    (["--jobs", "100000"], "--jobs 100000: expected a whole number from 1 to 64"),
    (["--sim-touches", "-1"], "--sim-touches -1: expected a whole number >= 0 (0: all)"),
    (["--readme", "missing.md"], "--readme missing.md: cannot read (No such file or directory)"),
    (["--skin", "broken.txt"], "broken.txt: not valid YAML"),          # read although no --real uses it
    (["--readme", "binary.md"], "--readme binary.md: cannot read (not a text file: invalid start byte at byte 0)"),
    (["--only", "real", "--real", "broken.txt", "--real", "broken.txt"],
     "broken.txt: the same recording as the input broken.txt; give each input once"),
])
def test_bench_arguments_are_checked_before_anything_runs(tmp_path, capsys, monkeypatch, args, says):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "broken.txt").write_text("{'0': [{0: {'cop': [0, 0,")
    (tmp_path / "binary.md").write_bytes(b"\xff\xfe")
    assert cli_main([*BENCH_CHEAP, *args, "--out", "b"]) == 2
    assert one_line(capsys).startswith(f"nao-skin bench: error: {says}")
    assert not (tmp_path / "b").exists()


def test_the_bench_takes_the_real_recording_from_an_argument_or_the_variable_else_says_so(tmp_path, capsys,
                                                                                          monkeypatch):
    """The real recording is no part of the repository: --only real without --real or $NAO_SKIN_REAL_DATA, or
    with the variable naming a directory that lacks a file of it, is one line before anything runs."""
    monkeypatch.delenv("NAO_SKIN_REAL_DATA", raising=False)
    assert cli_main(["bench", "--only", "real", "--out", str(tmp_path / "b")]) == 2
    assert one_line(capsys) == ("nao-skin bench: error: --only real needs a real recording: --real PATH (with --taxels"
                                " PART=FILE of its layouts), or NAO_SKIN_REAL_DATA=DIR holding l_hand_torso.legacy.txt,"
                                " l_hand.taxels.txt, torso.taxels.txt")
    half = tmp_path / "half"
    half.mkdir()
    (half / "l_hand_torso.legacy.txt").write_text("{}\n")
    monkeypatch.setenv("NAO_SKIN_REAL_DATA", str(half))
    for sections in (["--only", "real"], ["--quick"]):          # every section, the real one among them
        assert cli_main(["bench", *sections, "--out", str(tmp_path / "b")]) == 2
        assert one_line(capsys) == (f"nao-skin bench: error: NAO_SKIN_REAL_DATA={half}: no l_hand.taxels.txt,"
                                    f" torso.taxels.txt there (expected a directory holding l_hand_torso.legacy.txt,"
                                    f" l_hand.taxels.txt, torso.taxels.txt); set it to one, or give --real PATH")
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize("args, says", [
    (["--median-mm", "nan"], "--median-mm nan: must be a finite number above 0"),
    (["--p95-mm", "inf"], "--p95-mm inf: must be a finite number above 0"),
    (["--first-seed", "-1"], "--first-seed -1: expected a whole number >= 0"),
    (["--done-margin", "0"], "--done-margin 0.0: must be a finite number above 0"),
    (["--until-done", "--cold"], "--until-done: the live status follows warm-started updates; not with --cold"),
    (["--start", "500", "--cap", "80"], "--start 500: more random touches than the cap of 80"),
    (["--strategies", "random,random"], "--strategies 'random,random': expected some of random, guided, oracle,"
                                        " each once"),
    (["--jobs", "0"], "--jobs 0: expected a whole number from 1 to 64"),
    (["--jobs", "65"], "--jobs 65: expected a whole number from 1 to 64"),
    (["--set", "pairs=nope"], "--set pairs=nope: expected one of cop, taxel, both"),
    (["--set", "seed=1", "--set", "seed=2"], "--set seed=2: option seed is already given by --set seed=1; give it once"),
])
def test_bench_capture_arguments_are_checked_before_anything_runs(tmp_path, capsys, args, says):
    assert cli_main(["bench-capture", "--quick", *args, "--out", str(tmp_path / "b")]) == 2
    assert one_line(capsys).startswith(f"nao-skin bench-capture: error: {says}")
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize("real", ["missing.txt", "broken.txt"])
def test_a_broken_bench_input_never_costs_an_earlier_benchmark(tmp_path, capsys, monkeypatch, real):
    from nao_skin.formats.outdir import BENCHMARK, write_marker

    monkeypatch.chdir(tmp_path)
    (tmp_path / "broken.txt").write_text("{'0': [{0: {'cop': [0, 0,")
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "bench_results.md").write_text("last week's figures\n")
    write_marker(tmp_path / "b", "bench", BENCHMARK)
    before = sorted(p.name for p in (tmp_path / "b").iterdir())
    assert cli_main(["bench", "--only", "real", "--real", real, "--out", "b", "--force"]) == 2
    assert real in one_line(capsys)
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == before
    assert (tmp_path / "b" / "bench_results.md").read_text() == "last week's figures\n"


@pytest.mark.parametrize("args, says", [
    (["--bag", "existing"], "bag {tmp}/existing: exists already; a bag is never overwritten, name a new one"),
    (["--bag", "existing/inner"], "bag {tmp}/existing/inner: lies inside the bag {tmp}/existing; a bag is never written"
                                  " into another, choose a place outside it"),
    (["--bag", "notes.txt/bag"], "bag {tmp}/notes.txt/bag: {tmp}/notes.txt is a file, not a directory"),
    (["--bag", "/proc/nao_skin_bag"], "bag /proc/nao_skin_bag: cannot write in /proc (No such file or directory)"),
    (["--calibration", "notes.txt"], "notes.txt: a calibration needs a 'parts' mapping"),
    # both have 'robot:' and 'parts:': it was refused as made for robot 'nao_h25.yaml'
    (["--calibration", str(package_dir() / "config" / "nao_skin.yaml")],
     f"{package_dir() / 'config' / 'nao_skin.yaml'}: is a skin config (it has 'self_touch:'), not a calibration"),
    (["--calibration", "missing.yaml"], "missing.yaml: cannot read calibration (No such file or directory)"),
    (["--taxels", "l_hand=binary.txt"], "{tmp}/binary.txt: cannot read taxel file (not a text file"),
    (["--bag", "a\nb"], "bag '{tmp}/a\\nb': holds a control character (a newline, a tab), which a ROS parameter"
                        " does not carry as it is"),
    (["--param", "calibrate.out_dir=x\ty"], "calibrate.out_dir 'x\\ty': holds a control character"),
    # the recorder wrote one bag while the calibrate node followed another: every live update failed, exit 0
    (["--param", "pairing_recorder.bag_path=other"], "--param pairing_recorder.bag_path: the session's bag is set"
                                                      " once, for the recorder and the calibrate node together"),
    (["--param", "calibrate.recording=other"], "--param calibrate.recording: the session's bag is set once"),
    (["--param", "calibrate.out_dir="], "--param calibrate.out_dir='': the session's calibration needs a directory"),
    (["--duration", "-5"], "--duration -5.0: expected seconds >= 0 (0: until Ctrl-C)"),
    (["--duration", "nan"], "--duration nan: expected seconds >= 0 (0: until Ctrl-C)"),
    # the simulated robot (the default) ignored the real robot's address without a word
    # named as given here, not in the launch file's spelling (nao_ip:=...; an adversarial review, 2026-11-28)
    (["--nao-ip", "10.0.0.9"], "--nao-ip 10.0.0.9: only --robot nao reads it (--robot sim, the default, simulates"),
    (["--no-naoqi"], "--no-naoqi: only --robot nao reads it"),
    (["--robot", "nao", "--no-naoqi", "--nao-ip", "10.0.0.2"], "--nao-ip 10.0.0.2: only naoqi_bridge reads it, and"
                                                             " --no-naoqi leaves it out"),
    (["--robot", "nao", "--guided"], "--guided: only the simulated robot (--robot sim) follows the guidance"),
])
def test_record_refuses_what_a_node_would_die_of_before_any_starts(tmp_path, capsys, monkeypatch, args, says):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "existing").mkdir()
    (tmp_path / "existing" / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")    # a bag
    (tmp_path / "notes.txt").write_text("mine\n")
    (tmp_path / "binary.txt").write_bytes(b"\xff\xfe")
    argv = ["record", "--print", *args]
    assert cli_main(argv if "--bag" in args else [*argv, "--bag", "new_bag"]) == 2
    assert one_line(capsys).startswith("nao-skin record: error: " + says.format(tmp=tmp_path))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["binary.txt", "existing", "notes.txt"]


def test_a_command_run_from_a_removed_directory_says_so(tmp_path, capsys, monkeypatch):
    """It said "cannot write the output (No such file or directory)", naming neither bag nor directory."""
    gone = tmp_path / "gone"
    gone.mkdir()
    monkeypatch.chdir(gone)
    gone.rmdir()
    assert cli_main(["record", "--print"]) == 2
    assert one_line(capsys) == ("nao-skin record: error: the current directory no longer exists (removed while this"
                                " shell was in it); cd to one that does, or give absolute paths")


@pytest.mark.parametrize("args, says", [
    (["--seconds", "nan"], "--seconds nan: expected seconds above 0, at most 86400"),
    (["--seconds", "-1"], "--seconds -1.0: expected seconds above 0, at most 86400"),
    (["--seconds", "1e12"], "--seconds 1000000000000.0: expected seconds above 0, at most 86400"),
    (["--touch-period", "0"], "--touch-period 0.0: expected seconds above 0, at most 86400"),
    # the simulated robot refused it at its start, and the benchmark printed a window of zeros, exit 0
    (["--touch-period", "1e-6"], "--touch-period: press_duration 5e-07 s + 2 x hold 0.05 s must be shorter than"
                                 " touch_period 1e-06 s (and press_duration > 0)"),
    (["--update-every", "0"], "--update-every 0: expected a whole number >= 1"),
    (["--record-stops", "-1"], "--record-stops -1: expected a whole number from 0 to 1000"),
    (["--domain", "500"], "--domain 500: expected a ROS domain id in 0..232"),
    (["--update-input", "missing.bag"], "missing.bag: no such file or directory"),
])
def test_bench_live_arguments_are_checked_before_any_node_starts(tmp_path, capsys, monkeypatch, args, says):
    monkeypatch.setenv("TMPDIR", str(tmp_path))          # its temporary directory would be made here
    monkeypatch.chdir(tmp_path)
    assert cli_main(["bench-live", *args]) == 2
    assert one_line(capsys) == f"nao-skin bench-live: error: {says}"
    assert list(tmp_path.iterdir()) == []


def test_bench_live_reads_its_update_input_before_any_node_starts(tmp_path, capsys, monkeypatch):
    """A file with no touches made every live update fail, and the benchmark ended with exit 0."""
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    (tmp_path / "junk.txt").write_bytes(b"\xff\xfe\x00junk")
    assert cli_main(["bench-live", "--update-input", str(tmp_path / "junk.txt")]) == 2
    line = one_line(capsys)
    assert line.startswith(f"nao-skin bench-live: error: {tmp_path / 'junk.txt'}: cannot read"), line
    assert [p.name for p in tmp_path.iterdir()] == ["junk.txt"]


@pytest.mark.parametrize("argv, says", [
    (["stats", "a" * 300 + ".txt"], "{a}.txt: cannot read (File name too long)"),
    (["stats", "loop"], "loop: cannot read (Too many levels of symbolic links)"),
    (["calibrate", "BROKEN", "--out", "b" * 300], "--out {b}: File name too long; choose another place"),
    (["calibrate", "BROKEN", "--out", "new/" + "b" * 250], "--out new/{b250}: the name bbbbbbbbbbbbbbbbbbbb... is"
                                                          " longer than 239 bytes; choose a shorter one"),
    (["calibrate", "BROKEN", "--out", "loop"], "--out loop: Too many levels of symbolic links; choose another place"),
], ids=["input-name-too-long", "input-symlink-loop", "out-name-too-long", "out-folder-name-too-long",
        "out-symlink-loop"])
def test_paths_the_file_system_cannot_take_are_one_line(tmp_path, capsys, monkeypatch, argv, says):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "broken.txt").write_text("{'0': [{0: {'cop': [0, 0,")
    (tmp_path / "loop").symlink_to("loop2")
    (tmp_path / "loop2").symlink_to("loop")
    assert cli_main(["broken.txt" if a == "BROKEN" else a for a in argv]) == 2
    assert one_line(capsys) == f"nao-skin {argv[0]}: error: " + says.format(a="a" * 300, b="b" * 300, b250="b" * 250)


def test_a_removed_current_directory_is_one_line(tmp_path, capsys, monkeypatch):
    gone = tmp_path / "gone"
    gone.mkdir()
    monkeypatch.chdir(gone)
    gone.rmdir()
    assert cli_main(["calibrate", str(package_dir() / "bags" / "sim_default"), "--out", "out"]) == 2
    assert one_line(capsys) == ("nao-skin calibrate: error: --out out: the current directory no longer exists;"
                                " change to an existing one")


def test_quiet_still_says_what_was_skipped_and_which_layout_to_pass(tmp_path, real_recording):
    """The real recording under the packaged layouts: most touches name slots those layouts lack."""
    run = subprocess.run([sys.executable, "-m", "nao_skin.cli", "calibrate", str(real_recording), "--quiet",
                          "--no-plots", "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=300)
    skipped = [line for line in run.stderr.splitlines() if "skipped: 634 bad taxel slot" in line]
    assert len(skipped) == 1, run.stderr
    assert any("--taxels l_hand=FILE" in line for line in run.stderr.splitlines()), run.stderr
    assert any("--taxels torso=FILE" in line for line in run.stderr.splitlines()), run.stderr


@pytest.mark.parametrize("parts", ["l_hand,knee", "l_hand,l_hand", "l_hand,", " ,"])
def test_unknown_parts_are_refused_by_stats_pairs(capsys, tmp_path, parts, real_taxels):
    broken = tmp_path / "broken.txt"                # told before the touches are read
    broken.write_text("{'0': [{0: {'cop': [0, 0,")
    assert cli_main(["stats", str(broken), *real_taxels, "--parts", parts]) == 2
    assert one_line(capsys) == (f"nao-skin stats: error: --parts {parts!r}: expected two different skin parts A,B of"
                                f" r_hand, l_hand, torso, head")


def test_stats_of_a_pair_the_recording_lacks_is_one_line_and_its_json_is_json(capsys, real_recording, real_taxels):
    # every figure was NaN with exit 0, and '--json' printed a bare NaN no JSON reader takes
    assert cli_main(["stats", str(real_recording), *real_taxels, "--parts", "r_hand,head"]) == 2
    assert one_line(capsys) == (f"nao-skin stats: error: {real_recording}: no touch of the parts r_hand and head"
                                f" together (pairs touching: l_hand+torso)")
    assert cli_main(["stats", str(real_recording), *real_taxels, "--parts", "torso,l_hand", "--json"]) == 0
    out = json.loads(capsys.readouterr().out, parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))
    assert out["pairs"]["l_hand+torso"] > 0


def test_a_layout_replaces_a_configured_part_and_never_adds_one(tmp_path, real_dir):
    """``--taxels`` gives a part of the skin config its own layout; a part the config lacks is refused, not added
    on a chain its name suggests (a Nao default another robot's config never asked for)."""
    merged = load_skin(taxel_files={"l_hand": real_dir / "l_hand.taxels.txt"})
    assert set(merged.parts) == {"r_hand", "l_hand", "torso", "head"}
    assert merged.parts["l_hand"].layout_sha256 != load_skin().parts["l_hand"].layout_sha256
    config = yaml.safe_load(default_skin_config().read_text())
    del config["parts"]["head"]
    config["self_touch"]["touched"] = ["torso"]
    config["fingertip_touch"]["touched"] = ["torso", "l_hand", "r_hand"]
    for part in config["parts"].values():
        part["taxel_file"] = str(default_skin_config().parent / part["taxel_file"])
    config["robot"] = str(default_skin_config().parent / config["robot"])
    headless = tmp_path / "headless.yaml"
    headless.write_text(yaml.safe_dump(config))       # its parts in key order: l_hand, r_hand, torso
    with pytest.raises(ConfigError, match=r"--taxels head=.*: unknown skin part 'head' \(configured in .*headless"
                                          r"\.yaml: l_hand, r_hand, torso\)"):
        load_skin(headless, taxel_files={"head": real_dir / "l_hand.taxels.txt"})
    # a node's parameter is named as such, not as the command line's --taxels
    from nao_skin.session.params import skin_from_params

    with pytest.raises(ConfigError, match=r"^parameter taxels foo=.*: unknown skin part 'foo'"):
        skin_from_params({"skin_config": "", "taxels": [f"foo={real_dir / 'l_hand.taxels.txt'}"]})


def test_nodes_build_the_skin_as_the_commands_do(real_dir):
    from nao_skin.session.params import skin_from_params

    skin = skin_from_params({"skin_config": "", "taxels": ["", f"l_hand={real_dir / 'l_hand.taxels.txt'}"]})
    same = load_skin(taxel_files={"l_hand": real_dir / "l_hand.taxels.txt"})
    assert {n: p.layout_sha256 for n, p in skin.parts.items()} == {n: p.layout_sha256 for n, p in same.parts.items()}
    with pytest.raises(ConfigError, match="parameter taxels 'l_hand': expected PART=FILE"):
        skin_from_params({"skin_config": "", "taxels": ["l_hand"]})


def test_a_key_given_twice_in_a_config_is_one_line_naming_both_lines(tmp_path, capsys, real_recording, real_taxels):
    """YAML keeps the second of two equal keys without a word: a hand edit above a forgotten line lost."""
    robot = (package_dir() / "config" / "nao_h25.yaml").read_text().splitlines()
    first = next(i for i, line in enumerate(robot) if re.match(r"^[a-z_]+:", line))
    doubled = tmp_path / "robot.yaml"
    doubled.write_text("\n".join(robot + [robot[first]]) + "\n")
    assert cli_main(["stats", str(real_recording), "--robot", str(doubled), *real_taxels]) == 2
    key = robot[first].split(":")[0]
    assert one_line(capsys) == (f"nao-skin stats: error: {doubled}: key '{key}' given twice"
                                f" (lines {first + 1} and {len(robot) + 1}); give it once")
    # a key merged in with '<<' may be given again: that is YAML's own override
    from nao_skin.paths import read_yaml

    merged = tmp_path / "merged.yaml"
    merged.write_text("base: &base {a: 1, b: 2}\nthis:\n  <<: *base\n  a: 3\n")
    assert read_yaml(merged, "test")["this"] == {"a": 3, "b": 2}


@pytest.mark.parametrize("argv", [["nominal", "--skin-config", "deep.yaml"], ["urdf", "--calibration", "deep.yaml"],
                                  ["simulate", "--params", "deep.yaml", "--out", "o"],
                                  ["stats", str(package_dir() / "bags" / "sim_default"), "--robot", "deep.yaml"],
                                  ["nominal", "--skin-config", "block.yaml"]],
                         ids=["skin", "calibration", "params", "robot", "block"])
def test_yaml_nested_without_end_is_one_line_not_a_crash(tmp_path, capsys, monkeypatch, argv):
    """50000 levels of '[' ended the process by a segfault in libyaml's parser (exit 139, no line); the
    same in block style (indentation) would too."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "deep.yaml").write_text("[" * 50000 + "]" * 50000 + "\n")
    (tmp_path / "block.yaml").write_text("".join("  " * i + "a:\n" for i in range(300)) + "  " * 300 + "b: 1\n")
    assert cli_main(argv) == 2
    name = next(a for a in argv if a.endswith(".yaml"))
    assert one_line(capsys) == f"nao-skin {argv[0]}: error: {name}: not valid YAML (nested deeper than 100 levels)"
    assert not (tmp_path / "o").exists()


def test_a_bag_whose_metadata_nests_without_end_is_read_from_its_storage_file(tmp_path, capsys):
    """A metadata.yaml of 500 nested '[' raised RecursionError from the YAML parser (a traceback, exit 1); it
    is unreadable metadata, which a closed bag's storage file holds a copy of."""
    bag = tmp_path / "touches"
    shutil.copytree(package_dir() / "bags" / "sim_default" / "touches", bag)
    (bag / "metadata.yaml").write_text("[" * 500 + "]" * 500 + "\n")
    assert cli_main(["stats", str(bag), "--json"]) == 0
    out = capsys.readouterr()
    assert "its metadata.yaml is unreadable (not YAML: nested deeper than 100 levels)" in out.out + out.err
    assert "nothing lost" in out.out + out.err


def test_a_robot_config_without_a_chain_says_which_chain_is_missing(tmp_path, capsys, real_recording, real_taxels):
    """A robot file without the left arm had said its elbow-offset link was malformed; then, with the link
    gone too, the skin's left hand names the chain the robot lacks."""
    robot = (package_dir() / "config" / "nao_h25.yaml").read_text()
    no_arm = robot[:robot.index("  l_arm:")] + robot[robot.index("  r_arm:"):]
    path = tmp_path / "robot.yaml"
    path.write_text(no_arm)
    assert cli_main(["stats", str(real_recording), "--robot", str(path), *real_taxels]) == 2
    assert one_line(capsys) == (f"nao-skin stats: error: {path}: link 'LElbowOffsetY' is on chain 'l_arm', which"
                                f" the file does not describe (chains: head, r_arm)")
    no_link = "\n".join(line for line in no_arm.splitlines() if not line.startswith("  LElbowOffsetY:"))
    path.write_text(no_link)
    assert cli_main(["stats", str(real_recording), "--robot", str(path), *real_taxels]) == 2
    assert one_line(capsys) == (f"nao-skin stats: error: {path}: fingertip 'l_finger': chain 'l_arm' is not a chain"
                                f" of this robot (chains: head, r_arm)")
    path.write_text("\n".join(line for line in no_link.splitlines() if not line.startswith("  l_finger:")))
    assert cli_main(["stats", str(real_recording), "--robot", str(path), *real_taxels]) == 2
    assert "part 'l_hand': unknown chain 'l_arm' (robot has head, r_arm)" in one_line(capsys)


@pytest.mark.parametrize("stdout", ["buffered", "unbuffered"])
@pytest.mark.parametrize("argv", [["--help"], ["stats", "--help"]], ids=["top", "command"])
def test_help_on_a_full_disk_is_one_line_not_exit_0(argv, stdout):
    """argparse drops a failed write of its help text: ``nao-skin --help > /dev/full`` printed nothing and
    exited 0 (PYTHONUNBUFFERED), or exited 120 with Python's own message at exit."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    if stdout == "unbuffered":
        env["PYTHONUNBUFFERED"] = "1"
    with open("/dev/full", "w") as full:
        run = subprocess.run([sys.executable, "-m", "nao_skin.cli", *argv], stdout=full, stderr=subprocess.PIPE,
                             text=True, timeout=300, env=env)
    assert (run.returncode, run.stderr) == (2, "nao-skin: error: cannot write to standard output"
                                               " (No space left on device)\n")


def test_standard_output_on_a_full_disk_is_one_line():
    """``nao-skin stats ... > file`` on a full disk: the failed write has no file name to say, so the line
    says it was the output; exit 2, no traceback."""
    with open("/dev/full", "w") as full:
        bundled = package_dir() / "bags" / "sim_default"
        run = subprocess.run([sys.executable, "-m", "nao_skin.cli", "stats", str(bundled), "--json"],
                             stdout=full, stderr=subprocess.PIPE, text=True, timeout=300)
    assert run.returncode == 2, run.stderr
    assert "Traceback" not in run.stderr
    assert run.stderr.strip().splitlines()[-1] == ("nao-skin stats: error: cannot write to standard output"
                                                   " (No space left on device)")


def test_a_closed_standard_output_is_one_line_before_anything_runs(tmp_path):
    """Started with standard output closed (``>&-``): a result printed there would be lost unseen."""
    for argv in (["stats", str(package_dir() / "bags" / "sim_default"), "--json"], ["nominal"]):
        run = subprocess.run([sys.executable, "-m", "nao_skin.cli", *argv], stderr=subprocess.PIPE, text=True,
                             timeout=300, preexec_fn=lambda: os.close(1))
        assert run.returncode == 2, run.stderr
        assert run.stderr.strip().splitlines() == [f"nao-skin {argv[0]}: error: standard output is closed;"
                                                   f" redirect it (e.g. > /dev/null)"]


def test_calibrate_help_gives_every_option_its_default_and_meaning(capsys):
    """The --set names alone told nobody what they do: the help lists each from the options table."""
    assert cli_main(["calibrate", "--help"]) == 0
    text = capsys.readouterr().out
    for name, spec in OPTION_FIELDS.items():
        assert f"\n  {name} (default " in text, name
    assert "  f_scale (default 0.002): " in text


@pytest.mark.parametrize("item, says", [
    # YAML 1.1 read yes, true and ON as a switch, and a switch as 'on': a choice takes its own words
    ("kinematics=yes", "--set kinematics=yes: expected one of off, on, auto"),
    ("kinematics=true", "--set kinematics=true: expected one of off, on, auto"),
    ("kinematics=ON", "--set kinematics=ON: expected one of off, on, auto"),
    ("kinematics=", "--set kinematics=: expected one of off, on, auto"),
    # yes was a switch where 1 was refused: a switch takes true or false
    ("estimate_fabric=yes", "--set estimate_fabric=yes: expected true or false"),
    ("estimate_fabric=True", "--set estimate_fabric=True: expected true or false"),
    ("bounded=on", "--set bounded=on: expected true or false"),
    ("strategy=sequential\u00a0x", "expected one of sequential, all-at-once"),
    # a level listed twice was stored twice (its stage run twice)
    ("closing_levels=[mount,mount]", "--set closing_levels=[mount,mount]: expected a list of mount, patch, triangle,"
                                     " each at most once"),
    ("levels=[patch, triangle, patch]", "each at most once"),
])
def test_a_set_value_is_read_by_its_options_rule(tmp_path, capsys, item, says):
    broken = tmp_path / "broken.txt"
    broken.write_text("{'0': [{0: {'cop': [0, 0,")
    assert cli_main(["calibrate", str(broken), "--out", str(tmp_path / "out"), "--set", item]) == 2
    line = one_line(capsys)
    assert says in line and "broken.txt" not in line, line


def test_a_set_value_in_its_options_words_is_taken():
    options = CalibrationOptions()
    set_items(options, ["kinematics=on", "estimate_fabric=false", "bounded= true", "closing_levels=[]",
                        "normal_levels=[mount, patch]", "max_touches=null", "strategy=all-at-once"])
    assert (options.kinematics, options.estimate_fabric, options.bounded, options.closing_levels,
            options.normal_levels, options.max_touches, options.strategy) == (
        "on", False, True, (), ("mount", "patch"), None, "all-at-once")


@pytest.mark.parametrize("item, says", [
    # the empty value had been echoed as '=None', and taken for no value rather than said
    ("sim_robot.touches_per_pair=", "--param sim_robot.touches_per_pair=: an empty value; give an integer, or leave"
                                    " it out for the node's default 20"),
    ("sim_robot.touches_per_pair= ", "--param sim_robot.touches_per_pair= : an empty value"),
    ("sim_robot.touches_per_pair=~", "--param sim_robot.touches_per_pair=~: expected an integer like 20"),
])
def test_record_says_a_param_value_as_given(capsys, item, says):
    assert cli_main(["record", "--print", "--param", item]) == 2
    line = one_line(capsys)
    assert line.startswith("nao-skin record: error: ") and says in line, line
