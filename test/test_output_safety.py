"""Output directories: a mistaken ``--out`` is one line and exit 2, and never costs a recording or a user's file.

Real processes throughout: the ``nao-skin`` CLI runs as a subprocess in a
scratch working directory, on a small recording the simulator writes once
(copied into each test). "Intact" means every byte of every file under the
working directory is what it was before the command.
"""
from __future__ import annotations

import glob
import hashlib
import json
import os
import resource
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from nao_skin.formats.outdir import MARKER
from nao_skin.paths import package_dir

pytestmark = pytest.mark.slow   # every test runs the nao-skin CLI as processes (~1-15 s each)

BENCH_CHEAP = ["bench", "--quick", "--only", "hard", "--seeds", "1", "--presets", "ideal"]   # ~1 s of work
BENCH_KINEMATICS_CHEAP = ["bench", "--quick", "--only", "kinematics", "--seeds", "1", "--presets", "ideal"]  # ~10 s


def nao_skin(*argv, cwd, env=None, timeout=600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "nao_skin.cli", *map(str, argv)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)


def refused(root: Path, argv: list, *words, cwd: Path | None = None) -> str:
    """Run ``nao-skin ARGV`` in ``cwd`` (default ``root``): nothing under ``root`` may change (checked first:
    a loss shows as such), and it must end with one error line (exit 2) holding every one of ``words``."""
    before = tree(root)
    run = nao_skin(*argv, cwd=cwd or root)
    assert tree(root) == before, (run.returncode, run.stderr[-2000:])
    command = argv[0]
    assert run.returncode == 2, (run.returncode, run.stdout[-2000:], run.stderr[-2000:])
    err = run.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith(f"nao-skin {command}: error: "), err
    for word in words:
        assert word in err, (word, err)
    return err


def ok(run: subprocess.CompletedProcess) -> subprocess.CompletedProcess:
    assert run.returncode == 0, (run.stdout[-2000:], run.stderr[-3000:])
    return run


def tree(root: Path) -> dict:
    """Every entry under ``root``: file -> sha256 of its bytes, directory -> 'dir', symlink -> its target."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            path = Path(dirpath) / name
            rel = str(path.relative_to(root))
            if path.is_symlink():
                out[rel] = "-> " + os.readlink(path)
            elif path.is_dir():
                out[rel] = "dir"
            else:
                out[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """A small simulated recording (touches + truth, 25 touches a pair: calibrates in ~1 s)."""
    base = tmp_path_factory.mktemp("recording")
    ok(nao_skin("simulate", "--seed", "0", "--touches-per-pair", "25", "--out", "session", cwd=base))
    return base / "session"


@pytest.fixture
def work(tmp_path, recording) -> Path:
    """A working directory holding a recording (``session/``) and a user's notes file."""
    shutil.copytree(recording, tmp_path / "session", symlinks=True)
    (tmp_path / "notes.txt").write_text("what I did on the robot today\n")
    return tmp_path


# ------------------------------------------------------------------------------ the working directory
@pytest.mark.parametrize("argv", [
    ["calibrate", "session", "--out", "."],
    ["calibrate", "session", "--out", ".", "--force"],
    ["simulate", "--touches-per-pair", "3", "--out", ".", "--force"],
    [*BENCH_CHEAP, "--out", "."],
    ["demo", "--input", "session", "--out", "."],
], ids=["calibrate", "calibrate-force", "simulate", "bench", "demo"])
def test_out_current_directory_is_refused_and_nothing_changes(work, argv):
    refused(work, argv, "--out .", "current directory")


def test_out_containing_the_current_directory_is_refused(work):
    (work / "sub").mkdir()
    refused(work, ["calibrate", "../session", "--out", ".."], "--out ..", "contains the current directory",
            cwd=work / "sub")


# ------------------------------------------------------------------------------ inputs
@pytest.mark.parametrize("inp, out, words", [
    ("session/touches", "session/touches", ["is the input session/touches"]),
    ("session/touches", "session", ["contains the input session/touches"]),
    ("session", "session", ["is the input session"]),
    ("session", "session/calibration", ["lies inside the input session"]),
    ("link/touches", "session", ["contains the input link/touches"]),    # through a symlink
], ids=["bag-is-out", "out-holds-bag", "dir-is-out", "out-inside-input", "symlinked-input"])
def test_calibrate_never_writes_over_or_into_its_input(work, inp, out, words):
    (work / "link").symlink_to("session")
    for force in ([], ["--force"]):
        refused(work, ["calibrate", inp, "--out", out, *force], f"--out {out}", *words)


def test_other_inputs_are_protected_too(work):
    shutil.copy(work / "session" / "truth_calibration.yaml", work / "prior.yaml")
    (work / "cfg").mkdir()
    shutil.copy(work / "session" / "truth_calibration.yaml", work / "cfg" / "truth.yaml")
    refused(work, ["calibrate", "session", "--prior", "prior.yaml", "--out", "prior.yaml"], "--out prior.yaml")
    for argv in (["calibrate", "session", "--truth", "cfg/truth.yaml"], ["simulate", "--params", "cfg/truth.yaml"],
                 [*BENCH_CHEAP, "--readme", "cfg/truth.yaml"]):
        refused(work, [*argv, "--out", "cfg"], "--out cfg", "contains the input cfg/truth.yaml")


def test_a_layout_named_only_inside_the_skin_config_is_protected_too(work):
    """A skin config whose l_hand layout lies in an earlier output: '--out that --force' overwrote the
    layout the run read (the new calibration then failed its own sha256 check)."""
    ok(nao_skin("calibrate", "session", "--out", "earlier", cwd=work))
    config = yaml.safe_load((package_dir() / "config" / "nao_skin.yaml").read_text())
    for name, part in config["parts"].items():      # every path relative to the copy's place
        part["taxel_file"] = str(package_dir() / "config" / part["taxel_file"])
    config["parts"]["l_hand"]["taxel_file"] = str(work / "earlier" / "taxels" / "l_hand.txt")
    if "robot" in config:
        config["robot"] = str(package_dir() / "config" / config["robot"])
    (work / "skin.yaml").write_text(yaml.safe_dump(config))
    refused(work, ["calibrate", "session", "--skin", "skin.yaml", "--out", "earlier", "--force"],
            "--out earlier", "contains the input", "earlier/taxels/l_hand.txt")


def test_out_is_checked_before_any_input_is_read(work):
    (work / "junk.txt").write_bytes(os.urandom(1 << 20))     # would be a data error of its own
    refused(work, ["calibrate", "junk.txt", "missing.bag", "--out", "notes.txt"], "--out notes.txt", "existing file")
    refused(work, ["simulate", "--params", "junk.txt", "--out", "."], "--out .")
    refused(work, ["bench", "--only", "real", "--real", "junk.txt", "--out", "."], "--out .")
    refused(work, ["demo", "--input", "junk.txt", "--out", "."], "--out .")


# ------------------------------------------------------------------------------ directories we did not write
def test_existing_file_as_out_is_refused(work):
    for force in ([], ["--force"]):
        refused(work, ["calibrate", "session", "--out", "notes.txt", *force], "--out notes.txt", "existing file")


@pytest.mark.parametrize("argv", [
    ["calibrate", "session", "--out", "results"],
    ["calibrate", "session", "--out", "results", "--force"],
    ["simulate", "--touches-per-pair", "3", "--out", "results", "--force"],
    [*BENCH_CHEAP, "--out", "results"],
    ["demo", "--input", "session", "--out", "results"],
], ids=["calibrate", "calibrate-force", "simulate", "bench", "demo"])
def test_non_empty_directory_nao_skin_did_not_write_is_refused(work, argv):
    (work / "results").mkdir()
    (work / "results" / "thesis_figures.txt").write_text("mine\n")
    (work / "results" / "old").mkdir()
    refused(work, argv, "--out results", "did not write", "thesis_figures.txt")


def test_a_missing_or_empty_directory_is_fine(work):
    (work / "empty").mkdir()
    (work / "empty").chmod(0o750)
    ok(nao_skin("calibrate", "session", "--out", "empty", "--no-plots", "--quiet", cwd=work))
    ok(nao_skin("calibrate", "session", "--out", "new/deeper", "--no-plots", "--quiet", cwd=work))
    for out in ("empty", "new/deeper"):
        assert json.loads((work / out / MARKER).read_text())["command"] == "nao-skin calibrate"
        assert (work / out / "calibration.yaml").is_file()
    # the user's directory keeps its mode; a new one gets what mkdir gives (not the temporary's private 0700)
    assert (work / "empty").stat().st_mode & 0o777 == 0o750
    umask = os.umask(0o022)
    os.umask(umask)                     # the command inherited it
    assert (work / "new" / "deeper").stat().st_mode & 0o777 == 0o777 & ~umask


# ------------------------------------------------------------------------------ our own outputs
def test_own_output_is_replaced_only_with_force(work):
    ok(nao_skin("calibrate", "session", "--out", "cal", "--no-plots", "--quiet", cwd=work))
    first = tree(work)
    refused(work, ["calibrate", "session", "--out", "cal", "--seed", "1", "--no-plots", "--quiet"],
            "--out cal", "earlier nao-skin calibrate run", "--force")
    marker = json.loads((work / "cal" / MARKER).read_text())
    assert marker["command"] == "nao-skin calibrate" and marker["kind"] == "calibration" and marker["written"]
    assert {"calibration.yaml", "report.json", "taxels"} <= set(marker["entries"])
    ok(nao_skin("calibrate", "session", "--out", "cal", "--seed", "1", "--no-plots", "--quiet", "--force", cwd=work))
    second = tree(work)
    assert second["cal/report.json"] != first["cal/report.json"]      # seed 1: another split, another report
    assert {k: v for k, v in second.items() if not k.startswith("cal/")} == \
           {k: v for k, v in first.items() if not k.startswith("cal/")}
    assert sorted(p.name for p in work.iterdir()) == ["cal", "notes.txt", "session"]   # no temporary left over


def file_size_limit(size: int):
    """``preexec_fn``: the stand-in for a full disk. Past ``size`` bytes a write fails for real (EFBIG, "File
    too large") as one on a full disk does (ENOSPC: the same lines, seen on a small tmpfs)."""
    return lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))


@pytest.mark.parametrize("argv, limit, says", [
    (["calibrate", "session", "--out", "cal", "--seed", "1", "--no-plots", "--quiet", "--force"], 20_000,
     "nao-skin calibrate: error: cal: cannot write the calibration (File too large); an earlier output there is"
     " unchanged"),
    (["simulate", "--out", "sim", "--touches-per-pair", "50"], 20_000,
     "nao-skin simulate: error: sim: cannot write the simulated recording (File too large); nothing written"),
    # past the truth YAML (56 kB), in the bag: sqlite3 says "disk I/O error"
    (["simulate", "--out", "sim", "--touches-per-pair", "50"], 150_000,
     "nao-skin simulate: error: sim: cannot write the simulated recording (sim/touches: cannot write the bag (disk"
     " I/O error)); nothing written"),
])
def test_a_full_disk_is_one_line_and_leaves_what_was_there(work, argv, limit, says):
    ok(nao_skin("calibrate", "session", "--out", "cal", "--no-plots", "--quiet", cwd=work))
    before = tree(work)
    run = subprocess.run([sys.executable, "-m", "nao_skin.cli", *argv], cwd=work, capture_output=True, text=True,
                         timeout=600, preexec_fn=file_size_limit(limit))
    assert run.returncode == 2, (run.returncode, run.stderr[-2000:])
    assert run.stderr.strip().splitlines()[-1] == says, run.stderr[-2000:]
    assert "Traceback" not in run.stderr
    assert tree(work) == before           # the earlier calibration as it was, no half-written output or temporary


def without_file_privileges() -> list:
    """Command prefix under which permission bits bind: as root, ``setpriv`` drops the capabilities that
    override them (as an ordinary user, nothing is needed)."""
    if os.geteuid() != 0:
        return []
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: read-only directories cannot be made to bind")
    caps = "-dac_override,-dac_read_search,-fowner"
    return ["setpriv", "--bounding-set", caps, "--inh-caps", caps]


@pytest.mark.parametrize("read_only", [".", "taxels"])
def test_an_earlier_output_that_cannot_be_replaced_is_refused_before_the_work(work, read_only):
    """A read-only output directory (or folder in it) used to fail only after the calibration, leaving a
    ``.cal.old.*`` behind."""
    ok(nao_skin("calibrate", "session", "--out", "cal", "--no-plots", "--quiet", cwd=work))
    folder = work / "cal" / read_only
    folder.chmod(0o555)
    try:
        before = tree(work)
        run = subprocess.run([*without_file_privileges(), sys.executable, "-m", "nao_skin.cli", "calibrate",
                              "session", "--out", "cal", "--force", "--no-plots"], cwd=work, capture_output=True,
                             text=True, timeout=600)
        after = tree(work)
    finally:
        folder.chmod(0o755)
    assert run.returncode == 2, (run.returncode, run.stderr[-2000:])
    assert run.stdout == ""                                       # refused before any calibration ran
    assert run.stderr.strip() == (f"nao-skin calibrate: error: --out cal: its earlier output cannot be replaced:"
                                  f" cannot write in {folder.resolve()} (Permission denied); make it writable or"
                                  f" choose another directory"), run.stderr
    assert after == before


def test_a_readme_the_bench_cannot_write_whole_is_left_as_it_was(tmp_path):
    """``bench --readme``: the README is the user's; a write that fails part way (a full disk) must not leave
    it cut short. The run's own results, far smaller, are written."""
    readme = tmp_path / "README.md"
    readme.write_text("# my robot\n\n<!-- BENCH:START -->\nold results\n<!-- BENCH:END -->\n"
                      "<!-- BENCH:KINEMATICS:START -->\nold kinematics\n<!-- BENCH:KINEMATICS:END -->\n"
                      + "notes of the lab, line after line\n" * 6000)           # ~200 kB
    before = readme.read_bytes()
    run = subprocess.run([sys.executable, "-m", "nao_skin.cli", *BENCH_KINEMATICS_CHEAP, "--out", "bench", "--readme",
                          "README.md"], cwd=tmp_path, capture_output=True, text=True, timeout=600,
                         preexec_fn=file_size_limit(100_000))
    assert run.returncode == 2, (run.returncode, run.stderr[-2000:])
    assert "Traceback" not in run.stderr
    assert run.stderr.strip().splitlines()[-1] == (
        "nao-skin bench: error: --readme README.md: cannot write it or its plot README-speed-vs-error.png (File too"
        " large); what was not replaced is unchanged, the results are in bench")
    assert readme.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["README.md", "bench"]     # no temporary left
    assert (tmp_path / "bench" / "bench_results.md").is_file()


def test_a_bench_that_does_not_run_every_section_of_a_readme_block_leaves_the_readme(tmp_path, monkeypatch):
    """``bench --quick --only real --readme README.md`` replaced the whole results block with its one section:
    the speed table, the hard cases and the live update were gone (84 lines); a kinematics run with no block
    of its own went there too; and the plot beside the README replaced a file of that name."""
    readme = tmp_path / "README.md"
    readme.write_text("# my robot\n\n<!-- BENCH:START -->\nspeed, real, hard cases, live\n<!-- BENCH:END -->\n")
    (tmp_path / "README-speed-vs-error.png").write_text("my own picture\n")
    (tmp_path / "touches.txt").write_text("not read: the README is checked first\n")
    monkeypatch.delenv("NAO_SKIN_REAL_DATA", raising=False)     # else the real section reads the recording it names
    before = tree(tmp_path)
    for argv, says in ((BENCH_CHEAP, "this run has no live, real, speed, whose figures would be lost"),
                       (BENCH_KINEMATICS_CHEAP, "this run has no hard, live, real, speed"),
                       (["bench", "--quick", "--seeds", "1"],
                        "this run has no real (no --real, NAO_SKIN_REAL_DATA unset)"),
                       (["bench", "--quick", "--seeds", "1", "--real", "touches.txt"],
                        "README-speed-vs-error.png exists and is no plot of an earlier bench")):
        err = refused(tmp_path, [*argv, "--out", "bench", "--readme", "README.md"], says)
        assert err.startswith("nao-skin bench: error: --readme README.md: "), err
    assert tree(tmp_path) == before


@pytest.mark.parametrize("argv, started, stop", [
    # the bundled 4000 touches: seconds of calibration after its first progress line
    (["calibrate", str(package_dir() / "bags" / "sim_default"), "--out", "cal", "--no-plots", "--force"],
     "first guess", signal.SIGTERM),
    # ~12 s of simulating after its handlers are in place, and no line until the end
    (["simulate", "--touches-per-pair", "1000", "--out", "cal", "--force"], None, signal.SIGTERM),
    # the terminal closed (an ssh session dropped): Python's default for SIGHUP skipped every cleanup too
    (["calibrate", str(package_dir() / "bags" / "sim_default"), "--out", "cal", "--no-plots", "--force"],
     "first guess", signal.SIGHUP),
], ids=["calibrate", "simulate", "calibrate-hangup"])
def test_a_kill_mid_run_keeps_the_earlier_output_and_leaves_nothing_half_written(work, argv, started, stop):
    """SIGTERM (kill, a job's timeout) or SIGHUP as Ctrl-C: one line, exit 128 + the signal, the earlier
    output and everything else as it was, no temporary directory left."""
    if argv[0] == "simulate":
        ok(nao_skin("simulate", "--touches-per-pair", "3", "--out", "cal", cwd=work))
    else:
        ok(nao_skin("calibrate", "session", "--out", "cal", "--no-plots", "--quiet", cwd=work))
    before = tree(work)
    proc = subprocess.Popen([sys.executable, "-u", "-m", "nao_skin.cli", *argv], cwd=work, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        if started:
            for line in proc.stdout:
                if started in line:
                    break
        else:
            _wait_until_it_catches(proc, stop)
        assert proc.poll() is None, "the command ended before the signal: give it more work"
        proc.send_signal(stop)
    finally:
        err = _ended(proc)
    assert proc.returncode == 128 + stop, (proc.returncode, err[-2000:])
    assert err.strip().splitlines()[-1] == f"nao-skin {argv[0]}: terminated ({stop.name})"
    assert tree(work) == before


def test_what_a_run_killed_outright_left_is_removed_by_the_next_run_and_nothing_else(work):
    """SIGKILL (or a power cut) skips every clean-up: the run's staging directory beside --out stayed, a hidden
    copy of a whole simulated recording each time. The next run to that --out removes those whose process
    is gone; a live process's, the aside copy of a swap and the user's own files stay."""
    dead = subprocess.Popen(["true"])
    dead.wait()                        # a pid no process has now
    left = work / f".cal.{dead.pid}.abcd_123"
    (left / "touches").mkdir(parents=True)
    (left / "touches" / "touches.db3").write_bytes(b"\0" * 4096)
    kept = [work / ".cal.1.zzzz9999", work / ".cal.old.abcdefgh", work / ".cal.notes"]
    for path in kept:
        path.mkdir()
    ok(nao_skin("simulate", "--touches-per-pair", "3", "--out", "cal", cwd=work))
    assert not left.exists() and all(path.is_dir() for path in kept)
    assert sorted(p.name for p in work.glob(".cal*")) == sorted(p.name for p in kept)
    # killed after the swap, before the earlier output moved aside was removed: removed by the next run
    swapped = work / f".cal.old.{dead.pid}.abcd_123"
    (swapped / "cal").mkdir(parents=True)
    ok(nao_skin("simulate", "--touches-per-pair", "3", "--out", "cal", "--force", cwd=work))
    assert not swapped.exists() and (work / "cal" / "touches").is_dir()


def test_an_earlier_output_a_kill_left_aside_mid_swap_goes_back_before_anything_else(work):
    """Killed between the swap's two renames (SIGKILL, or a node's worker thread ended with its process), the
    earlier output stayed in a hidden .<out>.old.* directory for good and <out> looked free: the next run
    wrote there, and the earlier output was never seen again. It goes back first now."""
    ok(nao_skin("simulate", "--touches-per-pair", "3", "--out", "cal", cwd=work))
    earlier = tree(work / "cal")
    dead = subprocess.Popen(["true"])
    dead.wait()
    aside = work / f".cal.old.{dead.pid}.abcd_123"
    aside.mkdir()
    (work / "cal").rename(aside / "cal")                 # where the kill left it
    run = nao_skin("simulate", "--touches-per-pair", "4", "--out", "cal", cwd=work)
    err = run.stderr.strip()
    assert run.returncode == 2 and len(err.splitlines()) == 1, (run.returncode, err)
    assert "holds the outputs of an earlier nao-skin simulate run" in err, err
    assert tree(work / "cal") == earlier and not aside.exists()


def _wait_until_it_catches(proc: subprocess.Popen, signum: int) -> None:
    """Until the process has a handler for ``signum`` (Linux: the caught-signals mask in /proc): the
    command's own handling, not a fixed sleep that a fast machine outran (the run was over at 4 s) and a
    busy one may not reach (still importing: the default action, no line)."""
    bit = 1 << (signum - 1)
    while proc.poll() is None:
        with open(f"/proc/{proc.pid}/status") as status:
            caught = next(int(line.split()[1], 16) for line in status if line.startswith("SigCgt:"))
        if caught & bit:
            return
        time.sleep(0.01)


def _ended(proc: subprocess.Popen) -> str:
    """The process's standard error once it has ended (killed if it has not within 2 minutes: a test's
    failure, never a process left behind)."""
    try:
        return proc.communicate(timeout=120)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def _children(pid: int) -> list:
    """pids of the live processes whose parent is ``pid`` (read from /proc)."""
    out = []
    for stat_file in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat_file.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            out.append(int(stat_file.parent.name))
    return out


@pytest.mark.parametrize("stop", ["kill a worker", "terminate the benchmark"])
def test_a_benchmark_with_workers_ends_in_one_line_and_leaves_no_worker(tmp_path, stop):
    """A worker killed (out of memory) had ended the run in a BrokenProcessPool traceback; a SIGTERM had
    left the workers running their cases to the end."""
    proc = subprocess.Popen([sys.executable, "-m", "nao_skin.cli", "bench-capture", "--quick", "--seeds", "1",
                             "--strategies", "random,guided", "--jobs", "2", "--out", "b"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while len(_children(proc.pid)) < 2 and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.1)
        workers = _children(proc.pid)
        assert len(workers) >= 2, "the workers did not start"
        time.sleep(1.0)                                  # at work on their cases
        if stop == "kill a worker":
            os.kill(workers[0], signal.SIGKILL)
        else:
            proc.send_signal(signal.SIGTERM)
    finally:
        err = _ended(proc)
    last = err.strip().splitlines()[-1]
    if stop == "kill a worker":
        assert proc.returncode == 2 and last.startswith("nao-skin bench-capture: error: a worker process ended"
                                                        " abruptly"), (proc.returncode, err[-2000:])
    else:
        assert proc.returncode == 143 and last == "nao-skin bench-capture: terminated (SIGTERM)", err[-2000:]
    assert "Traceback" not in err
    deadline = time.monotonic() + 10
    while any(map(_running, workers)) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [w for w in workers if _running(w)], "workers left running"
    assert not (tmp_path / "b").exists()


def _running(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


@pytest.mark.parametrize("foreign", ["notes.md", "taxels/my_layout.txt", "drafts/a.txt"])
def test_a_file_added_to_our_output_is_never_deleted(work, foreign):
    ok(nao_skin("calibrate", "session", "--out", "cal", "--no-plots", "--quiet", cwd=work))
    (work / "cal" / foreign).parent.mkdir(parents=True, exist_ok=True)
    (work / "cal" / foreign).write_text("a user's file\n")
    name = foreign.split("/")[0] if foreign.startswith("drafts") else foreign    # a foreign folder is named whole
    for force in ([], ["--force"]):
        refused(work, ["calibrate", "session", "--out", "cal", "--no-plots", "--quiet", *force],
                f"cal/{name}", "not written by nao-skin calibrate", "even with --force")


def test_a_recording_is_never_replaced_by_another_kind_of_output(work):
    shutil.copytree(work / "session", work / "session2", symlinks=True)    # a recording, not an input here
    ok(nao_skin("calibrate", "session", "--out", "cal", "--no-plots", "--quiet", cwd=work))
    for argv in (["calibrate", "session", "--out", "session2"],
                 ["calibrate", "session", "--out", "session2", "--force"],
                 [*BENCH_CHEAP, "--out", "session2", "--force"],
                 ["demo", "--input", "session", "--out", "session2", "--force"]):
        refused(work, argv, "--out session2", "recording", "nao-skin simulate", "even with --force")
    refused(work, ["simulate", "--touches-per-pair", "3", "--out", "cal", "--force"], "--out cal", "calibration")


# ------------------------------------------------------------------------------ simulate
def test_simulate_replaces_its_own_output_with_force_only(tmp_path):
    args = ["simulate", "--touches-per-pair", "3", "--out", "sim"]
    ok(nao_skin(*args, "--seed", "0", cwd=tmp_path))
    first = tree(tmp_path)
    refused(tmp_path, [*args, "--seed", "1"], "--out sim", "touches", "--force")
    assert json.loads((tmp_path / "sim" / MARKER).read_text())["kind"] == "recording"
    ok(nao_skin(*args, "--seed", "1", "--force", cwd=tmp_path))
    second = tree(tmp_path)
    assert second["sim/truth_calibration.yaml"] != first["sim/truth_calibration.yaml"]
    assert sorted(second) == sorted(first)                        # the same files, nothing left behind
    (tmp_path / "sim" / "truth_taxels" / "measured.txt").write_text("my own measurement\n")
    refused(tmp_path, [*args, "--seed", "2", "--force"], "sim/truth_taxels/measured.txt", "even with --force")


def test_bundled_recording_can_be_regenerated_in_place():
    # its committed marker lists exactly its files, so `simulate ... --out bags/sim_default --force` may replace it
    from nao_skin.formats.outdir import RECORDING, check_output_dir
    from nao_skin.paths import package_dir

    bundle = package_dir() / "bags" / "sim_default"
    assert json.loads((bundle / MARKER).read_text())["command"] == "nao-skin simulate"
    check_output_dir(bundle, RECORDING, force=True)


# ------------------------------------------------------------------------------ bench
def test_bench_replaces_its_own_output_with_force_only(tmp_path):
    ok(nao_skin(*BENCH_CHEAP, "--out", "b", cwd=tmp_path))
    first = tree(tmp_path)
    refused(tmp_path, [*BENCH_CHEAP, "--out", "b"], "--out b", "--force")
    assert json.loads((tmp_path / "b" / MARKER).read_text())["kind"] == "benchmark"
    command = [line for line in (tmp_path / "b" / "bench_results.md").read_text().splitlines()
               if line.startswith("Command:")]
    assert len(command) == 1 and "--force" in command[0]          # the quoted command runs again as it stands
    ok(nao_skin(*BENCH_CHEAP, "--out", "b", "--force", cwd=tmp_path))
    assert sorted(tree(tmp_path)) == sorted(first)
    (tmp_path / "b" / "notes.md").write_text("comparison with last week\n")
    refused(tmp_path, [*BENCH_CHEAP, "--out", "b", "--force"], "b/notes.md", "even with --force")


def test_a_bench_stopped_before_its_end_leaves_the_earlier_output_and_its_sections_beside_it(tmp_path):
    """A bench stopped after its first section had replaced an earlier whole output (--force) with that
    section alone, marked as a finished output: the later sections' results were gone and nothing said the
    new one was incomplete."""
    ok(nao_skin(*BENCH_CHEAP, "--out", "b", cwd=tmp_path))
    earlier = tree(tmp_path / "b")
    proc = subprocess.Popen([sys.executable, "-m", "nao_skin.cli", *BENCH_KINEMATICS_CHEAP, "--only", "hard",
                             "--out", "b", "--force"], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    partial = tmp_path / "b.incomplete"
    try:
        deadline = time.monotonic() + 120
        while not (partial / "bench_results.json").exists() and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.05)
        time.sleep(0.5)                # the hard cases written, the kinematics section at work
        proc.send_signal(signal.SIGTERM)
    finally:
        out, err = proc.communicate(timeout=120)
    assert proc.returncode == 143 and err.strip().splitlines() == ["nao-skin bench: terminated (SIGTERM)"], err
    assert out.strip().splitlines()[-1] == f"the sections finished so far: {partial} (incomplete; b is as it was)"
    assert tree(tmp_path / "b") == earlier
    text = (partial / "bench_results.md").read_text()
    assert "**Incomplete: the run was stopped or failed" in text and "## Hard cases" in text
    assert "## Kinematics" not in text
    assert json.loads((partial / "bench_results.json").read_text())["complete"] is False
    assert json.loads((partial / MARKER).read_text())["kind"] == "benchmark"
    # a whole run replaces the earlier output and leaves no incomplete one of its own
    ok(nao_skin(*BENCH_CHEAP, "--out", "b", "--force", cwd=tmp_path))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b", "b.incomplete"]
    assert json.loads((tmp_path / "b" / "bench_results.json").read_text())["complete"] is True
    assert "Incomplete" not in (tmp_path / "b" / "bench_results.md").read_text()


# ------------------------------------------------------------------------------ demo
def test_demo_twice_in_a_row_replaces_its_own_output(tmp_path):
    """`make demo` twice: the defaults (bundled recording -> out/demo), the second run replaces the first."""
    ok(nao_skin("demo", "--quiet", cwd=tmp_path))
    first = os.stat(tmp_path / "out" / "demo").st_ino
    ok(nao_skin("demo", "--quiet", cwd=tmp_path))
    assert os.stat(tmp_path / "out" / "demo").st_ino != first      # a new directory moved in (both existed at once)
    assert (tmp_path / "out" / "demo" / "nao_skin.urdf").is_file()
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["demo"]
    (tmp_path / "out" / "demo" / "notes.txt").write_text("mine\n")
    refused(tmp_path, ["demo", "--quiet"], "out/demo/notes.txt", "not written")
    assert json.loads((tmp_path / "out" / "demo" / MARKER).read_text())["command"] == "nao-skin demo"


def test_demo_replaces_another_command_output_only_with_force(work):
    ok(nao_skin("calibrate", "session", "--out", "cal", "--no-plots", "--quiet", cwd=work))
    refused(work, ["demo", "--input", "session", "--out", "cal", "--quiet"], "--out cal", "--force")
    ok(nao_skin("demo", "--input", "session", "--out", "cal", "--quiet", "--force", cwd=work))
    assert json.loads((work / "cal" / MARKER).read_text())["command"] == "nao-skin demo"


# ------------------------------------------------------------------------------ bench-live's temporary directory
def _bench_live_env(tmp: Path) -> dict:
    pytest.importorskip("rclpy")
    from ros_harness import ros_env, unique_domain_id

    tmp.mkdir(exist_ok=True)
    return ros_env(unique_domain_id(), TMPDIR=str(tmp))


def _domain(env) -> list:
    return ["--domain", env["ROS_DOMAIN_ID"]]


@pytest.mark.middleware   # starts ROS 2 nodes
def test_bench_live_removes_its_temporary_directory_unless_kept(tmp_path):
    env = _bench_live_env(tmp_path / "tmp")
    ok(nao_skin("bench-live", "--seconds", "0.5", *_domain(env), cwd=tmp_path, env=env, timeout=180))
    assert list((tmp_path / "tmp").iterdir()) == []
    run = ok(nao_skin("bench-live", "--seconds", "0.5", "--keep-temp", *_domain(env), cwd=tmp_path, env=env,
                      timeout=180))
    kept = list((tmp_path / "tmp").iterdir())
    assert len(kept) == 1 and kept[0].name.startswith("nao_skin_bench_") and str(kept[0]) in run.stderr
    assert (kept[0] / "pairing_recorder.err").is_file()


def _nodes_of_domain(domain: str) -> list:
    """pids of nao_skin node processes running on ROS domain ``domain`` (read from /proc)."""
    out = []
    for entry in Path("/proc").iterdir():
        try:
            cmd = (entry / "cmdline").read_bytes()
            env = (entry / "environ").read_bytes()
        except (OSError, ValueError):
            continue
        if b"nao_skin.nodes." in cmd and f"ROS_DOMAIN_ID={domain}\0".encode() in env + b"\0":
            out.append(int(entry.name))
    return out


@pytest.mark.middleware   # starts ROS 2 nodes
@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_bench_live_stops_its_nodes_and_removes_its_temporary_directory_when_stopped(tmp_path, stop):
    """Ctrl-C, or SIGTERM (a timeout, a cancelled job): a SIGTERM left four nodes running and the directory."""
    env = _bench_live_env(tmp_path / "tmp")
    # SIGINT as a terminal sends it (a shell's background job would start with it ignored)
    proc = subprocess.Popen([sys.executable, "-m", "nao_skin.cli", "bench-live", "--seconds", "60", *_domain(env)],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 60
        while not glob.glob(str(tmp_path / "tmp" / "nao_skin_bench_*" / "*.err")) and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.1)
        assert glob.glob(str(tmp_path / "tmp" / "nao_skin_bench_*")), "bench-live made no temporary directory"
        time.sleep(2.0)                                  # the nodes are up and writing into it
        assert len(_nodes_of_domain(env["ROS_DOMAIN_ID"])) == 4
        proc.send_signal(stop)
        out, err = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130 and err.strip() == "nao-skin bench-live: interrupted", (proc.returncode, err)
    assert list((tmp_path / "tmp").iterdir()) == []
    assert _nodes_of_domain(env["ROS_DOMAIN_ID"]) == []


# ------------------------------------------------------------------------------ the calibrate node
@pytest.mark.middleware   # starts ROS 2 nodes
def test_calibrate_node_refuses_an_out_dir_holding_its_input(work):
    """At start (calibrate_on_start), in one line and exit 2, as any bad parameter: the node used to log the
    error, then run on with nothing to do and exit 0."""
    pytest.importorskip("rclpy")
    from ros_harness import node_process, ros_env, unique_domain_id

    bag = work / "session" / "touches"
    (work / "logs").mkdir()
    before = tree(work / "session")
    node = node_process("calibrate", {"inputs": [str(bag)], "calibrate_on_start": True,
                                      "out_dir": str(work / "session")}, ros_env(unique_domain_id()), work / "logs")
    try:
        code = node.popen.wait(timeout=60)
    finally:
        node.stop()
    lines = [line for line in node.stderr().splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, lines
    assert f"out_dir {work / 'session'}" in lines[0] and "contains the input" in lines[0]
    assert tree(work / "session") == before


def test_a_file_out_replaces_no_device_or_fifo_and_writes_through_a_symlink(tmp_path):
    """``--out`` of a single file renamed a temporary over whatever was there: a device node (as root,
    ``--out /dev/null`` would have replaced the system's), a FIFO, a symlink itself."""
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    specials = {fifo: ("a FIFO", stat_kind(fifo))}
    try:    # a device node of our own (the null device's numbers), never the system's
        os.mknod(tmp_path / "null", 0o666 | stat.S_IFCHR, os.makedev(1, 3))
        specials[tmp_path / "null"] = ("a character device", stat_kind(tmp_path / "null"))
    except PermissionError:
        pass
    for path, (kind, mode) in specials.items():
        for command in ("nominal", "urdf"):
            run = nao_skin(command, "--out", path, cwd=tmp_path, timeout=120)
            err = run.stderr.strip()
            assert run.returncode == 2 and len(err.splitlines()) == 1, (run.returncode, err)
            assert f"--out {path}: cannot write (it is {kind}, not a regular file)" in err, err
            assert stat_kind(path) == mode
    target = tmp_path / "kept" / "calibration.yaml"
    target.parent.mkdir()
    ok(nao_skin("nominal", "--out", target, cwd=tmp_path))
    target.write_text(target.read_text().replace("nominal calibration", "an earlier one"))
    link = tmp_path / "link.yaml"
    link.symlink_to(target)
    ok(nao_skin("nominal", "--out", link, cwd=tmp_path))
    assert link.is_symlink() and "nominal calibration" in target.read_text()
    assert sorted(p.name for p in target.parent.iterdir()) == ["calibration.yaml"]     # no temporary left


def test_a_file_out_keeps_an_earlier_outputs_permissions_and_leaves_a_read_only_one(tmp_path):
    """``urdf --out`` renamed a new file over a read-only earlier one (mode 0444 became 0644): the rename asks
    no permission of the file, so a user's way of keeping it was lost."""
    out = tmp_path / "robot.urdf"
    ok(nao_skin("urdf", "--out", out, cwd=tmp_path))
    out.chmod(0o640)
    ok(nao_skin("urdf", "--out", out, cwd=tmp_path))
    assert stat.S_IMODE(out.stat().st_mode) == 0o640
    out.chmod(0o444)
    before = out.read_bytes()
    refused(tmp_path, ["urdf", "--out", out], f"--out {out}: cannot write (it is read-only; make it writable to"
                                              f" replace it)")
    assert out.read_bytes() == before and stat.S_IMODE(out.stat().st_mode) == 0o444


@pytest.mark.parametrize("command", ["nominal", "urdf"])
def test_a_file_out_replaces_only_what_the_command_wrote(tmp_path, command):
    """``nominal --out notes.txt`` and ``urdf --out my_robot.urdf`` replaced the user's file without a word."""
    mine = {"notes.txt": "precious\n", "robot.urdf": "<?xml version='1.0'?><robot name='mine'/>\n"}
    for name, text in mine.items():
        (tmp_path / name).write_text(text)
        run = nao_skin(command, "--out", name, cwd=tmp_path, timeout=120)
        assert run.returncode == 2 and run.stderr.strip() == (
            f"nao-skin {command}: error: --out {name}: exists and was not written by this command; nothing is"
            f" written over somebody's file: choose another name, or remove it first"), run.stderr
    (tmp_path / "loop_a").symlink_to(tmp_path / "loop_b")
    (tmp_path / "loop_b").symlink_to(tmp_path / "loop_a")
    run = nao_skin(command, "--out", "loop_a", cwd=tmp_path, timeout=120)
    assert run.returncode == 2 and "--out loop_a: is a symbolic link that leads nowhere" in run.stderr, run.stderr
    assert {name: (tmp_path / name).read_text() for name in mine} == mine
    assert (tmp_path / "loop_a").is_symlink() and (tmp_path / "loop_b").is_symlink()
    (tmp_path / "made_by_mktemp").write_text("")          # an empty file holds nothing to lose
    ok(nao_skin(command, "--out", "made_by_mktemp", cwd=tmp_path, timeout=120))
    first = (tmp_path / "made_by_mktemp").read_text()
    ok(nao_skin(command, "--out", "made_by_mktemp", cwd=tmp_path, timeout=120))   # its own earlier output
    assert (tmp_path / "made_by_mktemp").read_text() == first and first
    # a calibration from touches holds the calibration header (and names the xacro): it is no output of these,
    # and the other command's output is not this one's
    other = "urdf" if command == "nominal" else "nominal"
    ok(nao_skin(other, "--out", "other_output", cwd=tmp_path, timeout=120))
    (tmp_path / "calibrated.yaml").write_text((package_dir() / "config" / "calibration_nominal.yaml").read_text().replace(
        "nominal calibration (all corrections zero) of nao_skin.yaml; regenerate with: nao-skin nominal --out"
        " <this file>", "parts calibrated from touches: l_hand, torso"))
    for name in ("calibrated.yaml", "other_output"):
        before = (tmp_path / name).read_text()
        run = nao_skin(command, "--out", name, cwd=tmp_path, timeout=120)
        assert run.returncode == 2 and f"--out {name}: exists and was not written by this command" in run.stderr, \
            run.stderr
        assert (tmp_path / name).read_text() == before
    # a name ending in a slash is a directory to be: no file of that name is written
    run = nao_skin(command, "--out", "new_dir/", cwd=tmp_path, timeout=120)
    assert run.returncode == 2 and run.stderr.strip().endswith("--out new_dir/: names a directory; give a file name")
    assert not (tmp_path / "new_dir").exists()


def test_an_input_that_is_no_regular_file_is_one_line_not_a_hang_or_all_memory(work):
    """``--skin-config /dev/zero`` read until the kernel killed it (24 GB); a FIFO waited for ever."""
    fifo = work / "pipe"
    os.mkfifo(fifo)
    for path, kind in ((fifo, "a FIFO"), (Path("/dev/zero"), "a character device")):
        for argv in (["nominal", "--skin-config", path], ["stats", "session", "--calibration", path]):
            run = nao_skin(*argv, cwd=work, timeout=120)
            err = run.stderr.strip()
            assert run.returncode == 2 and len(err.splitlines()) == 1, (argv, run.returncode, err[-2000:])
            assert f"{path}: cannot read" in err and f"(it is {kind}, not a regular file)" in err, err


def stat_kind(path: Path) -> int:
    return stat.S_IFMT(os.lstat(path).st_mode)


def test_a_stop_signal_during_the_swap_waits_until_it_is_done(tmp_path, monkeypatch):
    """Ctrl-C while an earlier output was being removed left it half deleted beside the new one."""
    from nao_skin.formats import outdir

    old, new = tmp_path / "cal", tmp_path / ".cal.new"
    for d, text in ((old, "old"), (new, "new")):
        d.mkdir()
        (d / "calibration.yaml").write_text(text)
        outdir.write_marker(d, "calibrate", outdir.CALIBRATION)
    rmtree = shutil.rmtree

    def interrupted_rmtree(path, *args, **kwargs):      # Ctrl-C arrives while the old copy is removed
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.1)
        rmtree(path, *args, **kwargs)

    monkeypatch.setattr(outdir.shutil, "rmtree", interrupted_rmtree)
    # the handler a command has; a test run started as a background job without job control has SIGINT
    # ignored from its start (Python then installs none), and an ignored Ctrl-C reaches nothing
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):              # delivered, once the swap is whole
            outdir.replace_dir(new, old)
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal"]
    assert (old / "calibration.yaml").read_text() == "new"


def test_an_output_is_on_the_disk_before_it_replaces_the_earlier_one(tmp_path, monkeypatch):
    """A power cut just after the rename that swaps an output in had left, on the disk, the new names
    without their data: empty files where the earlier calibration was. Every file of the new output is
    fsync'd before any rename, the folder after it, and only then the earlier output removed. (A spy on
    the real ``os.fsync``: a power cut cannot run here.)"""
    from nao_skin.formats import outdir

    old, new = tmp_path / "cal", tmp_path / ".cal.new"
    for d, text in ((old, "old"), (new, "new")):
        (d / "taxels").mkdir(parents=True)
        (d / "calibration.yaml").write_text(text)
        (d / "taxels" / "l_hand.txt").write_text(text)
        outdir.write_marker(d, "calibrate", outdir.CALIBRATION)
    events = []
    fsync, replace, rmtree = os.fsync, os.replace, shutil.rmtree
    monkeypatch.setattr(outdir.os, "fsync", lambda fd: (events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}"))),
                                                        fsync(fd)))
    monkeypatch.setattr(outdir.os, "replace", lambda a, b: (events.append(("replace", str(a), str(b))),
                                                            replace(a, b)))
    monkeypatch.setattr(outdir.shutil, "rmtree", lambda p, **kw: (events.append(("rmtree", str(p))), rmtree(p, **kw)))
    outdir.replace_dir(new, old)
    assert (old / "calibration.yaml").read_text() == "new"
    first_rename = next(i for i, e in enumerate(events) if e[0] == "replace")
    synced_before = {e[1] for e in events[:first_rename] if e[0] == "fsync"}
    assert {str(new), *(str(new / p) for p in ("calibration.yaml", "taxels", "taxels/l_hand.txt", outdir.MARKER))} \
        <= synced_before, events
    swapped_in = events.index(("replace", str(new), str(old)))
    removed = next(i for i, e in enumerate(events) if e[0] == "rmtree")
    assert ("fsync", str(tmp_path)) in events[swapped_in:removed], events
    # a single file written whole the same way: its data, then its folder
    events.clear()
    outdir.replace_file(tmp_path / "note.yaml", "a: 1\n")
    renamed = next(i for i, e in enumerate(events) if e[0] == "replace")
    assert events[renamed - 1][0] == "fsync" and events[renamed - 1][1].endswith(".tmp")
    assert events[renamed + 1:] == [("fsync", str(tmp_path))]


def test_a_ctrl_c_in_a_program_s_clean_up_or_after_it_returned_is_no_traceback(tmp_path):
    """A program run as its own process (the console scripts, ``python -m nao_skin.cli``): the first Ctrl-C
    raises where the program is; a second one during its clean-up, or one as it returns, had raised again
    where nothing caught it (a traceback; CI saw one as ``nao-skin record --help`` exited). Here the
    program sends itself the signals at those two moments, so neither depends on timing."""
    script = tmp_path / "program.py"
    script.write_text(
        "import os, signal, sys\n"
        "from nao_skin.errors import end_at_once_on_ctrl_c, run_program\n"
        "def started():\n"                                   # as cli.main does once it has parsed its arguments
        "    signal.signal(signal.SIGINT, end_at_once_on_ctrl_c('prog'))\n"
        "def cleans_up():\n"
        "    started()\n"
        "    try:\n"
        "        os.kill(os.getpid(), signal.SIGINT)\n"       # the Ctrl-C: a KeyboardInterrupt here
        "        print('not reached')\n"
        "    finally:\n"
        "        os.kill(os.getpid(), signal.SIGINT)\n"       # again, while it cleans up: ignored
        "        print('cleaned up', flush=True)\n"
        "def finishes():\n"
        "    started()\n"
        "    print('written', flush=True)\n"
        "    return 0\n"
        "code = run_program('prog', cleans_up if sys.argv[1] == 'clean-up' else finishes)\n"
        "os.kill(os.getpid(), signal.SIGINT)\n"               # as Python exits: ignored
        "sys.exit(code)\n")
    cleaned = subprocess.run([sys.executable, str(script), "clean-up"], capture_output=True, text=True, timeout=60)
    assert (cleaned.returncode, cleaned.stdout, cleaned.stderr) == (130, "cleaned up\n", "prog: interrupted\n")
    finished = subprocess.run([sys.executable, str(script), "finish"], capture_output=True, text=True, timeout=60)
    assert (finished.returncode, finished.stdout, finished.stderr) == (0, "written\n", "")


def test_a_bench_never_replaces_another_bench_s_output_even_with_force(tmp_path):
    """bench-capture --force deleted the tables of an earlier `nao-skin bench` (hours of work for minutes of
    another), and back: the three benches marked their outputs alike. An output an earlier version of the
    same command marked so is still its own."""
    from nao_skin.errors import DataError
    from nao_skin.formats.outdir import BENCHMARK, CAPTURE_BENCHMARK, check_output_dir, write_marker

    bench = tmp_path / "bench"
    bench.mkdir()
    (bench / "bench_results.md").write_text("hours of figures\n")
    write_marker(bench, "bench", BENCHMARK)
    with pytest.raises(DataError) as err:
        check_output_dir(bench, CAPTURE_BENCHMARK, force=True)
    assert "holds a benchmark written by nao-skin bench, not a capture benchmark" in str(err.value)
    earlier = tmp_path / "capture"
    earlier.mkdir()
    (earlier / "capture.md").write_text("an earlier capture bench\n")
    write_marker(earlier, "bench-capture", BENCHMARK)            # as versions before 2026-11-27 marked it
    assert check_output_dir(earlier, CAPTURE_BENCHMARK, force=True) == earlier
    with pytest.raises(DataError):
        check_output_dir(earlier, BENCHMARK, force=True)


def test_setup_venv_replaces_only_a_venv(tmp_path):
    """VENV naming a directory of the user's (or a file) was removed with rm -rf and a venv made in its place."""
    script = Path(__file__).resolve().parents[1] / "docker" / "setup_venv.sh"
    mine = tmp_path / "thesis"
    mine.mkdir()
    (mine / "thesis.tex").write_text("precious\n")
    note = tmp_path / "note.txt"
    note.write_text("mine\n")
    for venv in (mine, note):
        run = subprocess.run(["bash", str(script)], env={**os.environ, "VENV": str(venv), "PIP_NO_INDEX": "1"},
                             capture_output=True, text=True, timeout=120)
        err = [x for x in run.stderr.splitlines() if x.strip()]
        assert run.returncode == 2 and len(err) == 1, run.stderr
        assert err[0] == (f"setup_venv: ERROR: VENV={venv} exists and is no Python venv (no pyvenv.cfg): not"
                          f" replacing it; remove it or set another VENV")
    assert (mine / "thesis.tex").read_text() == "precious\n" and note.read_text() == "mine\n"


def _marked_output(directory: Path, text: str, command: str = "calibrate (node)") -> Path:
    from nao_skin.formats import outdir

    directory.mkdir()
    (directory / "calibration.yaml").write_text(text)
    outdir.write_marker(directory, command, outdir.CALIBRATION)
    return directory


def test_a_writer_replaces_only_the_output_it_expects_never_one_written_there_meanwhile(tmp_path, monkeypatch):
    """Two calibrate nodes given one out_dir (two `ros2 run` in one directory: the default out_dir is relative)
    both found it free, both wrote there, and the second replaced the first's calibration without a word while
    both said they had written it. A writer now says what it may replace (nothing, or its own last output,
    by its stamp), checked again once the earlier output is moved aside."""
    from nao_skin.errors import OutputTaken
    from nao_skin.formats import outdir

    out = tmp_path / "nao_skin_calibration"
    first = _marked_output(tmp_path / ".first", "first")
    outdir.replace_dir(first, out, replacing=())                      # free: taken
    second = _marked_output(tmp_path / ".second", "second")
    with pytest.raises(OutputTaken, match="another output was written there meanwhile"):
        outdir.replace_dir(second, out, replacing=())                 # it was free when this writer looked
    assert (out / "calibration.yaml").read_text() == "first" and second.is_dir()

    own = outdir.output_stamp(out)
    outdir.replace_dir(second, out, replacing=own)                    # its own: replaced
    assert (out / "calibration.yaml").read_text() == "second"
    third = _marked_output(tmp_path / ".third", "third")
    with pytest.raises(OutputTaken):                                  # no longer the output it wrote
        outdir.replace_dir(third, out, replacing=own)
    assert (out / "calibration.yaml").read_text() == "second"

    # another writer's output lands between the check and the move aside: it goes back, whole
    mine = outdir.output_stamp(out)
    mkdtemp = outdir.tempfile.mkdtemp

    def another_writer_first(*args, **kwargs):
        shutil.rmtree(out)
        _marked_output(out, "another's", command="calibrate")
        return mkdtemp(*args, **kwargs)

    monkeypatch.setattr(outdir.tempfile, "mkdtemp", another_writer_first)
    with pytest.raises(OutputTaken):
        outdir.replace_dir(third, out, replacing=mine)
    assert (out / "calibration.yaml").read_text() == "another's"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".third", "nao_skin_calibration"]
    monkeypatch.setattr(outdir.tempfile, "mkdtemp", mkdtemp)

    # its own output removed meanwhile: the place is free, taken without a word
    own = outdir.output_stamp(out)
    shutil.rmtree(out)
    outdir.replace_dir(third, out, replacing=own)
    assert (out / "calibration.yaml").read_text() == "third"
    # a user's file put into the node's own output: left as it is, for the writer to go beside it
    (out / "mine.txt").write_text("the user's")
    fourth = _marked_output(tmp_path / ".fourth", "fourth")
    with pytest.raises(OutputTaken, match="mine.txt was not written by"):
        outdir.replace_dir(fourth, out, replacing=outdir.output_stamp(out))
    assert (out / "mine.txt").read_text() == "the user's" and (out / "calibration.yaml").read_text() == "third"


def test_a_calibration_whose_place_was_taken_meanwhile_goes_beside_it(tmp_path, monkeypatch):
    """write_outputs with ``beside``: the first free <out_dir><beside>, and the place it was meant for stays."""
    from nao_skin.calibration.report import write_outputs
    from nao_skin.errors import OutputTaken
    from nao_skin.model.skin import load_skin
    from nao_skin.sim.simulate import simulate
    from nao_skin.calibration.engine import calibrate
    from nao_skin.calibration.options import CalibrationOptions

    skin = load_skin()
    result = calibrate(simulate(skin, {"n_touches": 60, "pairs": [["l_hand", "torso"]]}, seed=3).touches, skin,
                       CalibrationOptions(levels=("mount",)))
    out = _marked_output(tmp_path / "cal", "another's", command="calibrate")
    with pytest.raises(OutputTaken):
        write_outputs(result, skin, out, plots=False, replacing=())
    wrote = write_outputs(result, skin, out, plots=False, replacing=(), beside=".new")
    assert wrote == tmp_path / "cal.new" and (wrote / "calibration.yaml").is_file()
    assert (out / "calibration.yaml").read_text() == "another's"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal", "cal.new"]
    # a place beside that is taken too: the next one beside the first, not one beside it (cal.new.new)
    wrote = write_outputs(result, skin, tmp_path / "cal.new", plots=False, replacing=(), beside=".new")
    assert wrote == tmp_path / "cal.new2"
    # every place tried taken as the output is moved there (a race each time, stood in for): one line naming
    # them, nothing written, nothing left behind
    from nao_skin.calibration import report

    def always_taken(new, out, label="output directory", replacing=None):
        raise OutputTaken(f"{out}: taken")

    monkeypatch.setattr(report, "replace_dir", always_taken)
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(OutputTaken, match=rf"{tmp_path}/cal: the places tried \({tmp_path}/cal, {tmp_path}/cal.new3,"
                                          rf" {tmp_path}/cal.new3, .*\) were taken meanwhile by other outputs"):
        write_outputs(result, skin, out, plots=False, replacing=(), beside=".new")
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("force", [False, True])
def test_a_command_never_replaces_an_output_written_while_it_ran(tmp_path, monkeypatch, force):
    """`nao-skin calibrate --out X` (with or without --force) replaced, at its end, a calibration another command
    had written to X while it ran, without --force and without a word: a live session's own calibration was
    lost that way. Only what the check at its start saw (nothing, or the output --force agreed to replace)
    is replaced; another output there goes on, this one goes beside it and says so."""
    from nao_skin.calibration import pipeline
    from nao_skin.model.skin import load_skin
    from nao_skin.sim.simulate import simulate

    from nao_skin.formats.bag import write_touch_bag

    skin = load_skin()
    bag = tmp_path / "touches"
    write_touch_bag(bag, simulate(skin, {"n_touches": 20, "pairs": [["l_hand", "torso"]]}, seed=2).touches, skin)
    out = tmp_path / "cal"
    if force:
        _marked_output(out, "the one --force replaces", command="calibrate")
    calibrate_inputs = pipeline.calibrate_inputs

    def another_writes_meanwhile(*args, **kwargs):
        got = calibrate_inputs(*args, **kwargs)
        shutil.rmtree(out, ignore_errors=True)
        _marked_output(out, "another command's", command="calibrate")
        return got

    monkeypatch.setattr(pipeline, "calibrate_inputs", another_writes_meanwhile)
    said = []
    run = pipeline.calibrate_recordings([bag], skin, pipeline.CalibrationOptions(), out, force=force, plots=False,
                                        summary=said.append)
    assert run.out_dir == tmp_path / "cal.new" and (run.out_dir / "report.json").is_file()
    assert (out / "calibration.yaml").read_text() == "another command's"
    assert said[-1] == f"{out}: another output was written there while this calibration ran and is left as it is;" \
                       f" this one goes to {tmp_path / 'cal.new'}"
