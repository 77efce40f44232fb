"""skinManager taxel position files: both forms round-trip, malformed files fail in one line.

Real files: the project's default layouts (header form) and the real Nao
layouts beside the real recording (plain form; see real_data.py), read in place.
"""
from pathlib import Path

import numpy as np
import pytest
from real_data import LAYOUTS  # noqa: E402

from nao_skin.errors import DataError
from nao_skin.model.taxel_file import MAX_TAXEL_FILE_BYTES, SLOTS_PER_TRIANGLE, read_taxel_file, write_taxel_file
from nao_skin.paths import config_dir

REAL_LAYOUTS = sorted(LAYOUTS.values())       # names: found in the test, where a missing recording skips
LAYOUT_FILES = sorted((config_dir() / "layouts").glob("*.txt"))


def assert_same(a, b):
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.normals, b.normals)
    np.testing.assert_array_equal(a.present, b.present)


@pytest.mark.parametrize("with_header", [True, False], ids=["header", "plain"])
@pytest.mark.parametrize("source", LAYOUT_FILES + REAL_LAYOUTS, ids=lambda p: Path(p).name)
def test_read_write_read_is_identical(tmp_path, request, source, with_header):
    if not isinstance(source, Path):
        source = request.getfixturevalue("real_dir") / source
    first = read_taxel_file(source)
    out = tmp_path / "copy.txt"
    write_taxel_file(out, first.positions, first.normals, first.present, "l_hand", with_header=with_header)
    second = read_taxel_file(out)
    assert_same(first, second)
    # and a second write is byte-identical: nothing drifts through repeated round trips
    again = tmp_path / "again.txt"
    write_taxel_file(again, second.positions, second.normals, second.present, "l_hand", with_header=with_header)
    assert again.read_text() == out.read_text()
    if with_header:
        assert second.name == "l_hand"
        assert second.header["spatial_sampling"] == "taxel"
    else:
        assert second.header == {}
        assert second.name == "copy"


def test_header_form_maps_unused_slots_and_thermal_pads(tmp_path):
    first = read_taxel_file(LAYOUT_FILES[0])
    out = tmp_path / "h.txt"
    write_taxel_file(out, first.positions, first.normals, first.present, "torso")
    repr_ids = np.array(read_taxel_file(out).header["taxel2Repr"].strip("() ").split(), dtype=int)
    k = np.arange(len(repr_ids)) % SLOTS_PER_TRIANGLE
    np.testing.assert_array_equal(repr_ids[first.present], np.flatnonzero(first.present))
    assert np.all(repr_ids[~first.present & ((k == 6) | (k == 10))] == -2)
    assert np.all(repr_ids[~first.present & (k != 6) & (k != 10)] == -1)


def test_real_layouts_have_the_documented_taxel_counts(real_dir):
    # real_selftouch/README.md: known slots: left hand 227 of 240 usable, torso 220 of 250 usable
    assert read_taxel_file(real_dir / "l_hand.taxels.txt").present.sum() == 227
    assert read_taxel_file(real_dir / "torso.taxels.txt").present.sum() == 220


def test_a_thermal_pad_or_an_empty_row_needs_no_normal(tmp_path):
    path = tmp_path / "pads.txt"
    rows = ["0.01 0.02 0.03 0 0 1"] * 12
    rows[6] = "0.01 0.02 0.03 0 0 0"          # a thermal pad's position without a normal
    rows[7] = "0 0 0 0 0 0"                    # no taxel
    path.write_text("\n".join(rows) + "\n")
    assert read_taxel_file(path).present.sum() == 9     # 12 less two pads and the empty row


def test_short_file_pads_missing_slots_with_zeros(tmp_path):
    path = tmp_path / "short.txt"
    path.write_text("0.01 0.02 0.03 0 0 1\n\n# a comment line\n0.04 0.05 0.06 0 0 1  // trailing comment\n"
                    + "0 0 0 0 0 0\n" * 10)               # one triangle, two of its taxels there
    taxels = read_taxel_file(path)
    assert taxels.positions.shape == (384, 3)
    np.testing.assert_array_equal(taxels.positions[:2], [[0.01, 0.02, 0.03], [0.04, 0.05, 0.06]])
    assert taxels.present.sum() == 2


def test_a_file_that_ends_inside_a_triangle_is_refused(tmp_path, real_dir):
    """A taxel file cut short (200 of its 384 rows, a copy interrupted) was read as a smaller skin: 38 of 60
    touches were then skipped as taxels the layout does not have, the cause unsaid."""
    whole = (real_dir / "l_hand.taxels.txt").read_text().splitlines(keepends=True)
    path = tmp_path / "cut.txt"
    path.write_text("".join(whole[:200]))
    with pytest.raises(DataError, match=r"cut.txt: 200 taxel rows, which ends inside triangle 16 \(12 rows per"
                                        r" triangle\): is the file cut short\?"):
        read_taxel_file(path)


def header_file(rows):
    return "name torso\nspatial_sampling taxel\ntaxel2Repr ( 0 1 )\n[calibration]\n" + "".join(r + "\n" for r in rows)


GOOD = "0.01 0.02 0.03 0 0 1"


@pytest.mark.parametrize("text, line, problem", [
    (f"{GOOD}\n{GOOD}\n0.01 0.02 0.03 0 0\n", 3, "expected 6 numbers 'x y z nx ny nz', got 5"),
    (f"{GOOD}\n0.01 0.02 zero 0 0 1\n", 2, "not a number in '0.01 0.02 zero 0 0 1'"),
    ("nan 0.02 0.03 0 0 1\n", 1, "non-finite value in 'nan 0.02 0.03 0 0 1'"),
    (header_file([GOOD, GOOD, "1 2 3 4 5 6 7"]), 7, "expected 6 numbers 'x y z nx ny nz', got 7"),
    (f"{GOOD}\n1e300 0.02 0.03 0 0 1\n", 2, "a value beyond 10 in '1e300 0.02 0.03 0 0 1'; positions are metres"
     " in the part's frame and normals unit vectors"),
    (f"{GOOD}\n35.1 20.2 -4.0 0 0 1\n", 2, "a value beyond 10 in '35.1 20.2 -4.0 0 0 1'; positions are metres"
     " in the part's frame and normals unit vectors"),
    # a normal places the fabric surface and orients the triangle: (5, 5, 5) moved a calibration by 1 mm
    (f"{GOOD}\n0.01 0.02 0.03 5 5 5\n", 2, "the normal of slot 1 has length 8.66 in '0.01 0.02 0.03 5 5 5';"
     " normals are unit vectors"),
    (f"{GOOD}\n0.01 0.02 0.03 0 0 0\n", 2, "the normal of slot 1 has length 0 in '0.01 0.02 0.03 0 0 0';"
     " normals are unit vectors"),
    # Python's float() takes digit separators: no taxel file has them
    (f"{GOOD}\n0.073_54096 0.02 0.03 0 0 1\n", 2, "not a number in '0.073_54096 0.02 0.03 0 0 1'"),
    # its rows had been read as none ("no taxel rows found")
    ("[calibration]\n[calibration]\n" + f"{GOOD}\n" * 12, 2, "a second [calibration] section"),
], ids=["five-numbers", "not-a-number", "nan", "header-form-line-number", "huge", "millimetres", "long-normal",
        "zero-normal", "digit-separator", "calibration-twice"])
def test_malformed_row_names_file_and_line(tmp_path, text, line, problem):
    path = tmp_path / "bad_taxels.txt"
    path.write_text(text)
    with pytest.raises(DataError) as err:
        read_taxel_file(path)
    assert str(err.value) == f"{path}:{line}: {problem}"


@pytest.mark.parametrize("text, problem", [
    ("", "no taxel rows found"),
    ("# only a comment\n", "no taxel rows found"),
    (f"{GOOD}\n" * 385, ":385: taxel row 385, more than the 384 slots of a skin part"),
    # read no further than that: 1.5 million rows had been parsed first (14 s, 0.7 GB)
    (f"{GOOD}\n" * 200_000, ":385: taxel row 385, more than the 384 slots of a skin part"),
])
def test_malformed_file_names_file_and_problem(tmp_path, text, problem):
    path = tmp_path / "bad_taxels.txt"
    path.write_text(text)
    with pytest.raises(DataError) as err:
        read_taxel_file(path)
    assert str(err.value) == f"{path}{problem if problem.startswith(':') else ': ' + problem}"


def test_a_taxel_file_larger_than_any_layout_is_not_read(tmp_path):
    """A file of hundreds of megabytes (a recording given as a layout) was read whole first (4 GB of memory
    at 15 million rows); no layout comes near the limit."""
    path = tmp_path / "l_hand.taxels.txt"
    with open(path, "wb") as f:
        f.truncate(MAX_TAXEL_FILE_BYTES + 1)
    with pytest.raises(DataError) as err:
        read_taxel_file(path)
    assert str(err.value) == f"{path}: cannot read taxel file (larger than 16 MiB: is it the right file?)"


def test_a_binary_file_is_one_line(tmp_path):
    path = tmp_path / "l_hand.taxels.txt"
    path.write_bytes(b"\xff\xfe garbage\n")
    with pytest.raises(DataError) as err:
        read_taxel_file(path)
    assert str(err.value) == f"{path}: cannot read taxel file (not a text file: invalid start byte at byte 0)"


def test_missing_file_is_one_line(tmp_path):
    path = tmp_path / "nowhere.txt"
    with pytest.raises(DataError) as err:
        read_taxel_file(path)
    assert str(err.value) == f"{path}: cannot read taxel file (No such file or directory)"
