"""``nao-skin check``: a calibration judged by new touches, part by part (calibration/check.py).

The simulator stands in for the robot's body: it records touches of a skin whose true placement it knows.
A skin part that moved after its calibration is a calibration whose frame of that part is off by the
move, which is what the check sees either way: the tests shift a mount in the calibration file.
"""
import json

import numpy as np
import pytest

from nao_skin.calibration.check import FITS, MOVED, NOT_CALIBRATED, NOT_CHECKED, check_calibration
from nao_skin.calibration.engine import CalibrationOptions, calibrate
from nao_skin.cli import main as cli_main
from nao_skin.formats.bag import write_touch_bag
from nao_skin.model.skin import SkinCalibration
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate
from nao_skin.touch.datasets import deduplicate



@pytest.fixture(scope="module")
def sittings(default_skin):
    """One simulated skin touched twice: 560 touches calibrate it, 240 others come later (all four pairs)."""
    touches, _ = deduplicate(simulate(default_skin, load_params("default", {"n_touches": 200}), seed=5).touches)
    order = np.random.default_rng(0).permutation(touches.n_touches)
    old, new = touches.subset(np.sort(order[:560])), touches.subset(np.sort(order[560:]))
    made = calibrate(old, default_skin, CalibrationOptions())
    return old, new, made.calibration, made.report.fabric_thickness_mm


def shifted(calibration, part: str, mm: float, axis: int = 0):
    """The calibration with ``part``'s mount translated by ``mm`` along one of its axes: the skin moved."""
    out = calibration.copy()
    out.parts[part].mount[axis] += mm / 1000.0
    return out


def test_new_touches_of_the_same_skin_fit_its_calibration(default_skin, sittings):
    old, new, calibration, fabric = sittings
    result = check_calibration(new, default_skin, calibration, fabric_mm=fabric)
    assert {name: p.verdict for name, p in result.parts.items()} == dict.fromkeys(default_skin.parts, FITS)
    assert result.moved == []
    for part in result.parts.values():
        assert part.moved_mm["median"] < 1.0 and part.held_out_cop_mm["touches"] >= 20


def test_a_hand_that_moved_is_named_and_the_other_parts_still_fit(default_skin, sittings):
    old, new, calibration, fabric = sittings
    result = check_calibration(new, default_skin, shifted(calibration, "l_hand", 4.0), fabric_mm=fabric)
    assert result.moved == ["l_hand"]
    l_hand = result.parts["l_hand"]
    assert 3.0 < l_hand.moved_mm["median"] < 5.0       # the refit finds about the move
    assert l_hand.held_out_cop_mm["gain_low"] > 0.1
    assert l_hand.pairs == ["l_hand+torso", "l_hand+head"]        # the pairs that touch, not every two parts
    assert "moved" not in " ".join(p.reason for n, p in result.parts.items() if n != "l_hand")
    # a smaller tolerance than the move changes nothing; a larger one keeps the part
    assert check_calibration(new, default_skin, shifted(calibration, "l_hand", 4.0), tolerance_mm=6.0,
                             fabric_mm=fabric).moved == []


def test_a_part_the_calibration_never_calibrated_is_said_so_not_called_moved(default_skin, sittings):
    old, new, calibration, fabric = sittings
    nominal = calibration.copy()
    nominal.parts["head"] = default_skin.parts["head"].zero_correction()
    result = check_calibration(new, default_skin, nominal, fabric_mm=fabric)
    assert result.parts["head"].verdict == NOT_CALIBRATED and "calibrate it" in result.parts["head"].reason
    assert result.moved == []


def test_few_held_out_touches_give_no_verdict(default_skin, sittings):
    """About 15 touches per pair: a 4 mm move leaves the refit 4-5 mm off, but 5 held-out touches cannot say
    whether that is the skin (with a normal quantile and no minimum, 2 touches once called an unmoved part
    moved)."""
    old, new, calibration, fabric = sittings
    few = new.subset(np.sort(np.random.default_rng(1).choice(new.n_touches, 60, replace=False)))
    result = check_calibration(few, default_skin, shifted(calibration, "l_hand", 4.0), fabric_mm=fabric)
    assert result.moved == []
    l_hand = result.parts["l_hand"]
    assert l_hand.verdict == NOT_CHECKED and l_hand.moved_mm["median"] > 3.0 and "record more" in l_hand.reason


def test_a_part_no_pair_of_the_new_touches_reaches_is_not_checked(default_skin, sittings):
    old, new, calibration, fabric = sittings
    fired = new.parts_of_touch()
    keep = ~fired[:, new.part_index("head")]
    result = check_calibration(new.subset(np.flatnonzero(keep)), default_skin, shifted(calibration, "head", 5.0),
                                fabric_mm=fabric)
    assert result.parts["head"].verdict == NOT_CHECKED
    assert result.moved == []        # the head's move is not seen without its touches, nor blamed on another part


def test_the_command_says_fits_then_names_the_moved_part_with_exit_1(tmp_path, capsys, default_skin, sittings):
    old, new, calibration, fabric = sittings
    write_touch_bag(tmp_path / "first", old, default_skin)
    write_touch_bag(tmp_path / "later", new, default_skin)
    assert cli_main(["calibrate", str(tmp_path / "first"), "--out", str(tmp_path / "cal"), "--quiet", "--no-plots"]) == 0
    capsys.readouterr()
    cal = tmp_path / "cal" / "calibration.yaml"
    before = {p: p.read_bytes() for p in (tmp_path / "cal").rglob("*") if p.is_file()}

    assert cli_main(["check", str(tmp_path / "later"), "--calibration", str(cal)]) == 0
    out = capsys.readouterr().out.splitlines()
    made = SkinCalibration.load(cal, default_skin)
    assert f"fabric {1000 * made.fabric_thickness:.2f} mm, the calibration's" in out[0], out[0]
    assert 0.8 < 1000 * made.fabric_thickness < 1.4            # the simulator's 1 mm, estimated
    assert [line.split(":")[:2] for line in out[1:5]] == [[p, " fits"] for p in default_skin.parts]
    assert out[-1] == "every part checked fits the calibration (r_hand, l_hand, torso, head)"

    (tmp_path / "moved").mkdir()
    shifted(calibration, "l_hand", 4.0).save(tmp_path / "moved" / "calibration.yaml", default_skin)
    fabric = json.loads((tmp_path / "cal" / "report.json").read_text())["fabric_thickness_mm"]
    assert cli_main(["check", str(tmp_path / "later"), "--calibration", str(tmp_path / "moved" / "calibration.yaml"),
                     "--fabric", f"{fabric}", "--json"]) == 1
    doc = json.loads(capsys.readouterr().out)
    assert doc["moved"] == ["l_hand"] and doc["fabric_from"] == "--fabric" and doc["fabric_mm"] == pytest.approx(fabric)
    assert doc["touches"] == new.n_touches and doc["split"]["train"] + doc["split"]["test"] == new.n_touches
    assert doc["parts"]["l_hand"]["verdict"] == MOVED and doc["parts"]["torso"]["verdict"] == FITS
    assert {p: p.read_bytes() for p in (tmp_path / "cal").rglob("*") if p.is_file()} == before   # only read


@pytest.fixture(scope="module")
def real_cal(tmp_path_factory, real_taxels, real_dir):
    """The real recording's own calibration (nao-skin calibrate), made once for the tests that read it."""
    out = tmp_path_factory.mktemp("real") / "cal"
    assert cli_main(["calibrate", str(real_dir / "l_hand_torso.legacy.txt"), *real_taxels, "--out", str(out),
                     "--quiet", "--no-plots"]) == 0
    return out


def test_one_pair_of_parts_on_the_real_recording(tmp_path, capsys, real_taxels, real_dir, real_cal):
    """Its own calibration fits it, judged at the fabric it was made with (the file holds it: at the
    configured 1 mm instead of the 0.05 mm that calibration estimated, the mounts move 2-4 mm to make up the
    difference and the check called both parts moved). A hand moved 5 mm, or the torso 3 mm along its normal,
    is seen, and the line says one pair cannot tell which of its two parts moved, and how to recalibrate
    with these taxel files."""
    from nao_skin.model.skin import SkinCalibration, load_skin

    recording = str(real_dir / "l_hand_torso.legacy.txt")
    capsys.readouterr()
    cal = real_cal / "calibration.yaml"
    skin = load_skin(taxel_files={"l_hand": real_dir / "l_hand.taxels.txt", "torso": real_dir / "torso.taxels.txt"})
    made = SkinCalibration.load(cal, skin)
    assert made.fabric_thickness == pytest.approx(
        json.loads((real_cal / "report.json").read_text())["fabric_thickness_mm"] / 1000.0, abs=1e-9)
    assert cli_main(["check", recording, *real_taxels, "--calibration", str(cal)]) == 0
    out = capsys.readouterr().out
    assert "the calibration's" in next(line for line in out.splitlines() if " held out; fabric " in line)
    assert "r_hand: not checked: no pair" in out and "head: not checked: no pair" in out
    assert "l_hand: fits" in out and "torso: fits" in out
    assert out.splitlines()[-1] == "every part checked fits the calibration (l_hand, torso)"
    # at another fabric the refit moves both parts past the tolerance to make up for it: never "fits" (moved,
    # or not checked when the held-out touches cannot tell the gain at 95 %)
    assert cli_main(["check", recording, *real_taxels, "--calibration", str(cal), "--fabric", "1"]) in (1, 2)
    out = capsys.readouterr().out
    for part in ("l_hand", "torso"):
        line = next(line for line in out.splitlines() if line.startswith(f"{part}: "))
        assert line.startswith((f"{part}: moved", f"{part}: not checked: the refit puts its taxels")), line
        assert "at least 1 mm" in line or "moved" in line, line

    for name, part, axis, mm in (("hand", "l_hand", 1, 5.0), ("torso", "torso", 0, -3.0)):
        moved = tmp_path / name
        moved.mkdir()
        shifted(made, part, mm, axis=axis).save(moved / "calibration.yaml", skin)
        assert cli_main(["check", recording, *real_taxels, "--calibration", str(moved / "calibration.yaml")]) == 1
        out = capsys.readouterr().out
        assert f"{part}: moved" in out, out
        assert (f"{'l_hand+torso'} is its only pair: whether it or the other part moved, touches of another pair"
                f" tell") in out
        assert f"--prior {moved / 'calibration.yaml'} {' '.join(real_taxels)} --out DIR" in out


def test_a_calibration_written_before_it_kept_its_fabric(tmp_path, capsys, real_taxels, real_dir, real_cal):
    """Such a file is judged at its report's fabric (found beside the file a link leads to), else at the one
    the new touches imply; a report that cannot be read is no reason to stop."""
    recording = str(real_dir / "l_hand_torso.legacy.txt")
    capsys.readouterr()
    old = tmp_path / "old"
    old.mkdir()
    lines = (real_cal / "calibration.yaml").read_text().splitlines(keepends=True)
    at = next(i for i, line in enumerate(lines) if line.startswith("fabric_thickness:"))
    (old / "calibration.yaml").write_text("".join(lines[:at] + lines[at + 3:]))     # as files were before
    (old / "report.json").write_bytes((real_cal / "report.json").read_bytes())
    (tmp_path / "link.yaml").symlink_to(old / "calibration.yaml")
    assert cli_main(["check", recording, *real_taxels, "--calibration", str(tmp_path / "link.yaml"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["fabric_from"] == str(old / "report.json") and doc["fabric_mm"] < 0.2
    for broken in ('{"fabric_thickness_mm": 1' + "0" * 400 + "}", "[" * 100000 + "]" * 100000, "{", '{"x": 1}'):
        (old / "report.json").write_text(broken)
        assert cli_main(["check", recording, *real_taxels, "--calibration", str(old / "calibration.yaml"),
                         "--json"]) == 0
        doc = json.loads(capsys.readouterr().out)
        assert doc["fabric_from"] == "estimated" and doc["fabric_mm"] < 0.2
    (old / "report.json").unlink()
    assert cli_main(["check", recording, *real_taxels, "--calibration", str(old / "calibration.yaml")]) == 0
    assert "it holds no fabric estimate: a move along a part's normal is partly taken for fabric" in capsys.readouterr().out


def test_the_fabric_is_kept_in_the_calibration_file(tmp_path, default_skin, sittings):
    from nao_skin.errors import ConfigError
    from nao_skin.model.skin import SkinCalibration

    old, new, calibration, fabric = sittings
    assert calibration.fabric_thickness == pytest.approx(fabric / 1000.0)
    calibration.save(tmp_path / "c.yaml", default_skin)
    assert SkinCalibration.load(tmp_path / "c.yaml", default_skin).fabric_thickness == pytest.approx(fabric / 1000.0)
    text = (tmp_path / "c.yaml").read_text()
    for bad in ("value: -0.001", "value: .nan", "value: true", "value: 0.5", "unit: mm"):
        key = bad.split(":")[0]
        edited = "\n".join(f"  {bad}" if line.startswith(f"  {key}:") and i < text.index("parts:") else line
                           for i, line in zip(_offsets(text), text.splitlines()))
        (tmp_path / "bad.yaml").write_text(edited)
        with pytest.raises(ConfigError, match="fabric_thickness must be"):
            SkinCalibration.load(tmp_path / "bad.yaml", default_skin)
    nominal = default_skin.zero_calibration()
    nominal.save(tmp_path / "n.yaml", default_skin)
    assert "fabric_thickness" not in (tmp_path / "n.yaml").read_text()
    assert SkinCalibration.load(tmp_path / "n.yaml", default_skin).fabric_thickness is None


def _offsets(text: str) -> list:
    """The character offset where each line of ``text`` starts."""
    out, at = [], 0
    for line in text.splitlines(keepends=True):
        out.append(at)
        at += len(line)
    return out


def test_nothing_judged_is_no_pass(tmp_path, capsys, default_skin, sittings):
    """A calibration that holds every part at nominal judges nothing: one line, exit 2, never exit 0."""
    old, new, calibration, fabric = sittings
    write_touch_bag(tmp_path / "later", new, default_skin)
    default_skin.zero_calibration().save(tmp_path / "nominal.yaml", default_skin)
    assert cli_main(["check", str(tmp_path / "later"), "--calibration", str(tmp_path / "nominal.yaml")]) == 2
    out, err = capsys.readouterr()
    assert [line.split(":")[1] for line in out.splitlines()[1:5]] == [" not calibrated"] * 4
    err = [line for line in err.splitlines() if line.strip()]
    assert len(err) == 1 and "could be judged; not calibrated: r_hand, l_hand, torso, head (record more" in err[0], err


@pytest.mark.parametrize("args, says", [
    (["--tolerance", "0"], "--tolerance 0: expected millimetres above 0 and at most 50"),
    (["--tolerance", "nan"], "--tolerance nan: expected millimetres above 0"),
    (["--tolerance", "80"], "--tolerance 80: expected millimetres above 0 and at most 50"),
    (["--fabric", "20"], "--fabric 20: expected millimetres from 0 to 3"),
    (["--fabric", "-1"], "--fabric -1: expected millimetres from 0 to 3"),
    (["--fabric", "inf"], "--fabric inf: expected millimetres from 0 to 3"),
    (["--seed", "-3"], "--seed -3"),
])
def test_a_wrong_option_is_one_line_and_exit_2(tmp_path, capsys, args, says, real_taxels, real_dir):
    cal = tmp_path / "calibration.yaml"
    assert cli_main(["nominal", "--out", str(cal)]) == 0
    capsys.readouterr()
    assert cli_main(["check", str(real_dir / "l_hand_torso.legacy.txt"), *real_taxels, "--calibration", str(cal),
                     *args]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith("nao-skin check: error: ") and says in err[0], err


def test_a_calibration_that_is_no_file_or_no_calibration_is_one_line(tmp_path, capsys, real_taxels, real_dir):
    recording = str(real_dir / "l_hand_torso.legacy.txt")
    assert cli_main(["check", recording, *real_taxels, "--calibration", str(tmp_path / "gone.yaml")]) == 2
    assert str(tmp_path / "gone.yaml") in capsys.readouterr().err
    (tmp_path / "notes.yaml").write_text("just: notes\n")
    assert cli_main(["check", recording, *real_taxels, "--calibration", str(tmp_path / "notes.yaml")]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and str(tmp_path / "notes.yaml") in err[0]


def test_bench_check_counts_what_the_check_named(tmp_path, capsys):
    out = tmp_path / "bench"
    assert cli_main(["bench-check", "--seeds", "1", "--sizes", "200", "--moves", "0,4", "--reference", "1500",
                     "--out", str(out)]) == 0
    doc = json.loads((out / "check_results.json").read_text())
    rows = {r["move_mm"]: r for r in doc["rows"]}
    assert rows[0.0]["verdicts"] == dict.fromkeys(["r_hand", "l_hand", "torso", "head"], FITS)
    assert rows[4.0]["verdicts"]["l_hand"] == MOVED and 3.0 < rows[4.0]["moved_mm"]["l_hand"] < 5.0
    summary = {s["move_mm"]: s for s in doc["summary"]}
    assert summary[4.0]["found"] == 1 and summary[0.0]["found"] is None
    assert summary[0.0]["false_alarms"] == 0 and summary[0.0]["checks"] == 4
    assert summary[4.0]["checks"] == 3       # the parts that did not move
    assert "| 4 | 200 | 1 | 1 of 1 |" in (out / "check_results.md").read_text()
    capsys.readouterr()
    for args, says in ((["--moves", "0,,3"], "--moves '0,,3': expected numbers from 0 to 50"),
                       (["--sizes", "5"], "--sizes '5': expected numbers from 10"),
                       (["--part", "tail"], "--part tail: not a skin part"),
                       (["--reference", "3990"], "--reference 3990 + --sizes up to 400: more than the 4000")):
        assert cli_main(["bench-check", *args, "--out", str(tmp_path / "b2")]) == 2
        err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
        assert len(err) == 1 and says in err[0], err
        assert not (tmp_path / "b2").exists()
