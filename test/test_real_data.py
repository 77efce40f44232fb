"""The real recording is not in the repository: a test that needs it skips with one line saying what is missing
and how to point the tests at it, and under ``CI=true`` fails instead, so CI never passes without running it.

Real pytest runs of a real test of the suite, with ``NAO_SKIN_REAL_DATA`` naming an empty directory (a
recording beside the checkout must not stand in for the one the variable names)."""
import os
import subprocess
import sys
from pathlib import Path

import real_data

ROOT = Path(__file__).resolve().parents[1]
NEEDS_IT = "test/test_taxel_file.py::test_real_layouts_have_the_documented_taxel_counts"


def run_pytest(tmp_path: Path, ci: bool) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "CI"}
    env[real_data.VARIABLE] = str(tmp_path)
    if ci:
        env["CI"] = "true"
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider", NEEDS_IT],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)


def expected_line(tmp_path: Path) -> str:
    return (f"real recording missing (l_hand_torso.legacy.txt, l_hand.taxels.txt, torso.taxels.txt;"
            f" NAO_SKIN_REAL_DATA={tmp_path}): set NAO_SKIN_REAL_DATA=DIR holding l_hand_torso.legacy.txt,"
            f" l_hand.taxels.txt, torso.taxels.txt")


def test_a_missing_recording_skips_in_one_line(tmp_path):
    run = run_pytest(tmp_path, ci=False)
    assert run.returncode == 0, run.stdout + run.stderr
    said = [line for line in run.stdout.splitlines() if line.startswith("SKIPPED")]
    assert len(said) == 1 and said[0].endswith(": " + expected_line(tmp_path)), run.stdout
    assert "1 skipped" in run.stdout and "passed" not in run.stdout, run.stdout


def test_under_ci_a_missing_recording_is_a_failure_not_a_skip(tmp_path):
    run = run_pytest(tmp_path, ci=True)
    assert run.returncode == 1, run.stdout + run.stderr
    assert f"{expected_line(tmp_path)} (CI=true: these tests must run)" in run.stdout, run.stdout
    assert "skipped" not in run.stdout and "Traceback" not in run.stdout, run.stdout


def test_the_line_names_only_what_is_missing(tmp_path, monkeypatch):
    monkeypatch.setenv(real_data.VARIABLE, str(tmp_path))
    (tmp_path / "l_hand_torso.legacy.txt").write_text("{}\n")
    (tmp_path / "torso.taxels.txt").mkdir()                      # a directory of that name is no layout
    assert real_data.missing_line(tmp_path) == (
        f"real recording missing (l_hand.taxels.txt, torso.taxels.txt; NAO_SKIN_REAL_DATA={tmp_path}): set"
        f" NAO_SKIN_REAL_DATA=DIR holding l_hand_torso.legacy.txt, l_hand.taxels.txt, torso.taxels.txt")
    (tmp_path / "l_hand.taxels.txt").write_text("0\n")
    (tmp_path / "torso.taxels.txt").rmdir()
    (tmp_path / "torso.taxels.txt").write_text("0\n")
    assert real_data.missing_line(tmp_path) is None
    monkeypatch.delenv(real_data.VARIABLE)
    assert real_data.where() == ROOT.parent / "shared" / "data" / "real_selftouch"
    assert "NAO_SKIN_REAL_DATA unset, looked in" in real_data.missing_line(ROOT)
