"""A live recording (BagWriter(live=True), as the pairing recorder writes it) read while it is written and
after its writer was killed with SIGKILL, for both storages.

The writer is a real process: it writes simulated touches, flushes after the
first ``FLUSHED``, writes the rest without a flush and waits. Read then, the
bag says it is still open (pid of the writer) and holds exactly the flushed
touches; after ``kill -9`` it says the recorder died, and still holds them.
A sqlite3 bag's metadata.yaml is written only on close, so these touches
are read from the .db3 itself (before: "0 touches loaded of 0 messages
read", exit 0). Also: a sqlite3 writer whose open transaction has reached
the file (locked while it lives, a hot journal once killed), and a writer
without the lock (an older recorder) seen through ``nao-skin stats``.
"""
from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from nao_skin.formats.bag import LIVE_CONFIG, read_touches
from nao_skin.formats.salvage import LOCK_FILE
from nao_skin.model.skin import load_skin
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate

pytestmark = pytest.mark.slow   # every test starts a bag writer process and kills it (~5 s together)

ROOT = Path(__file__).resolve().parents[1]
SEED, PER_PAIR, FLUSHED = 4, 8, 12

WRITER = r"""
import sys, time
import numpy as np
from nao_skin.formats.bag import BagWriter
from nao_skin.model.skin import load_skin
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate
from recorded_touches import write_recorded

path, storage, mode, seed, per_pair, flushed = sys.argv[1], sys.argv[2], sys.argv[3], *map(int, sys.argv[4:7])
skin = load_skin()
touches = simulate(skin, load_params("default", {"n_touches": per_pair}), seed).touches
bag = BagWriter(path, storage, kind="touches", live=mode != "no-lock")
bag.__enter__()
if mode == "spill":        # a one-page cache: the open transaction reaches the file before any commit
    bag._writer.storage.conn.execute("PRAGMA cache_size=1")
order = np.argsort(touches.stamps, kind="stable")
write_recorded(bag, skin, touches, order[:flushed])
bag.flush()
print("flushed", flush=True)
write_recorded(bag, skin, touches, order[flushed:])
print("written", flush=True)
time.sleep(600)
"""


@pytest.fixture(scope="module")
def played():
    skin = load_skin()
    touches = simulate(skin, load_params("default", {"n_touches": PER_PAIR}), SEED).touches
    order = np.argsort(touches.stamps, kind="stable")
    return skin, touches.subset(order)


class Writer:
    """The writer process; started, it has written everything and flushed the first FLUSHED touches."""

    def __init__(self, bag: Path, storage: str, mode: str = "live"):
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT / "test"),
                                                             os.environ.get("PYTHONPATH", "")]))
        self.popen = subprocess.Popen([sys.executable, "-c", WRITER, str(bag), storage, mode, str(SEED),
                                       str(PER_PAIR), str(FLUSHED)], env=env, stdout=subprocess.PIPE, text=True)
        lines = [self.popen.stdout.readline().strip() for _ in range(2)]
        assert lines == ["flushed", "written"], f"writer: {lines}, exit {self.popen.poll()}"

    def kill(self) -> None:
        self.popen.send_signal(signal.SIGKILL)
        self.popen.wait(timeout=10)
        assert self.popen.returncode == -signal.SIGKILL

    def stop(self) -> None:
        if self.popen.poll() is None:
            self.kill()
        self.popen.stdout.close()


def killed_recording(bag: Path, storage: str, mode: str = "live") -> None:
    """A recording at ``bag`` whose writer was killed (SIGKILL) after its first FLUSHED touches were flushed."""
    writer = Writer(bag, storage, mode)
    try:
        writer.kill()
    finally:
        writer.stop()


def assert_first_touches(got, want, n):
    """``got`` is exactly the first ``n`` touches of ``want``: stamps, joints, activated (part, slot) sets."""
    assert got.n_touches == n
    np.testing.assert_allclose(got.stamps, want.stamps[:n], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(got.joints[:, [got.joint_names.index(j) for j in want.joint_names]],
                                  want.joints[:n])

    def activated(ts, t):
        a = np.flatnonzero(ts.act_touch == t)
        return sorted(zip(np.array(ts.part_names)[ts.act_part[a]].tolist(), ts.act_slot[a].tolist()))

    for t in range(n):
        assert activated(got, t) == activated(want, t), f"touch {t}: activated taxels differ"


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_live_recording_then_kill_9(played, tmp_path, storage):
    skin, want = played
    bag = tmp_path / "touches"
    writer = Writer(bag, storage)
    try:
        lock = json.loads((bag / LOCK_FILE).read_text())
        assert lock["pid"] == writer.popen.pid
        # read while the writer has the bag open: what was flushed, and it says the recording is open
        got, report = read_touches(bag, skin)
        assert_first_touches(got, want, FLUSHED)
        assert not report.skipped, report.lines()
        text = " | ".join(report.lines())
        assert f"still open (being recorded by pid {writer.popen.pid}" in text
        assert f"{FLUSHED} touches" in text and "damaged" not in text and "lost" not in text
        writer.kill()
    finally:
        writer.stop()
    # the writer died: the same touches, and the report says the recorder died (not "damaged")
    got, report = read_touches(bag, skin)
    assert_first_touches(got, want, FLUSHED)
    assert dict(report.skipped) == {"truncated bag": 1}
    line = [m for m in report.messages if "truncated" in m or "died" in m]
    assert len(line) == 1 and f"the recorder (pid {writer.popen.pid} on " in line[0]
    assert "died before closing the bag" in line[0] and "damaged" not in line[0] and "\n" not in line[0]
    assert str(bag) in line[0]
    assert report.n_loaded == FLUSHED and report.n_read > 0


def test_sqlite_writer_with_its_transaction_in_the_file(played, tmp_path):
    """The writer's transaction has reached the .db3: read while it holds the file locked, and after
    ``kill -9`` (hot journal), as rolled back to the last commit, the recording left untouched."""
    skin, want = played
    bag = tmp_path / "touches"
    writer = Writer(bag, "sqlite3", mode="spill")
    try:
        got, report = read_touches(bag, skin)
        assert_first_touches(got, want, FLUSHED)
        assert not report.skipped and "the recording is still open" in " | ".join(report.lines())
        writer.kill()
    finally:
        writer.stop()
    db, journal = bag / "touches.db3", bag / "touches.db3-journal"
    before = db.read_bytes(), journal.read_bytes()
    with pytest.raises(sqlite3.OperationalError, match="readonly"):     # precondition: a hot journal
        sqlite3.connect(f"{db.as_uri()}?mode=ro", uri=True).execute("SELECT count(*) FROM messages").fetchall()
    got, report = read_touches(bag, skin)
    assert_first_touches(got, want, FLUSHED)
    assert dict(report.skipped) == {"truncated bag": 1}
    assert (db.read_bytes(), journal.read_bytes()) == before        # the recording is left as it was


def test_stats_of_an_unclosed_sqlite_bag_without_lock(played, tmp_path):
    """A writer without the lock (older recorder): metadata.yaml incomplete; stats reads the .db3 directly."""
    skin, want = played
    bag = tmp_path / "touches"
    killed_recording(bag, "sqlite3", "no-lock")
    assert not (bag / LOCK_FILE).exists()
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["message_count"] == 0 and info["topics_with_message_count"] == []      # the provisional one
    got, report = read_touches(bag, skin)
    assert_first_touches(got, want, FLUSHED)
    line = [m for m in report.messages if "metadata.yaml lists no messages" in m]
    assert len(line) == 1 and "touches.db3 directly" in line[0] and "did not close the bag" in line[0]

    env = dict(os.environ, PYTHONPATH=str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""))
    run = subprocess.run([sys.executable, "-m", "nao_skin.cli", "stats", str(bag), "--json"], env=env,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout)["touches"] == FLUSHED


def test_a_closed_mcap_whose_metadata_was_never_written_reads_whole(played, tmp_path):
    """A recorder killed after its writer closed the mcap file but before metadata.yaml was rewritten (or
    whose disk filled then, or whose folder was renamed while it recorded) leaves the provisional
    metadata.yaml, which lists no messages: rosbags opens that bag and finds nothing in it (0 touches, and
    a user deletes an 'empty' recording). Every touch is in the file, and is read from it."""
    from nao_skin.formats.bag import write_touch_bag

    skin, want = played
    bag = tmp_path / "touches"
    write_touch_bag(bag, want, skin, storage="mcap")
    closed, _ = read_touches(bag, skin)
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    provisional = {**info, "message_count": 0, "topics_with_message_count": [], "files": [],
                   "duration": {"nanoseconds": 0}, "starting_time": {"nanoseconds_since_epoch": 0}}
    (bag / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": provisional}))
    for lock in (None, {"pid": 2 ** 22 + 12345, "host": os.uname().nodename, "start": "1"}):   # no recorder; a dead one
        if lock is not None:
            (bag / LOCK_FILE).write_text(json.dumps(lock) + "\n")
        got, report = read_touches(bag, skin)
        assert_first_touches(got, closed, closed.n_touches)
        assert got.n_touches == want.n_touches and not report.skipped, report.lines()
        note = " | ".join(report.notes)
        assert "metadata.yaml lists no messages" in note and "nothing lost" in note, note


def test_a_killed_mcap_named_by_its_file_or_without_metadata_reads_as_its_bag(played, tmp_path):
    """The cut mcap file of a killed recording, named itself, copied alone, or in its folder without
    metadata.yaml, gives the touches its bag gives (it was "cannot open as a rosbag2")."""
    import shutil

    skin, want = played
    bag = tmp_path / "touches"
    killed_recording(bag, "mcap")
    file = bag / "touches.mcap"
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(file, alone / file.name)
    bare = tmp_path / "bare"
    shutil.copytree(bag, bare)
    (bare / "metadata.yaml").unlink()
    for path in (bag, file):
        got, report = read_touches(path, skin)
        assert_first_touches(got, want, FLUSHED)
        assert dict(report.skipped) == {"truncated bag": 1}, (path, report.lines())
    # without its metadata.yaml nothing says it is a touch bag: read as a live stream, as the bag would be
    as_stream, _ = read_touches(bag, skin, LIVE_CONFIG)
    for path in (alone / file.name, alone, bare):
        got, report = read_touches(path, skin)
        assert_first_touches(got, as_stream, as_stream.n_touches)
        assert dict(report.skipped) == {"truncated bag": 1}, (path, report.lines())


@pytest.mark.parametrize("lock_kind", ["fifo", "dev_zero", "deep"])
def test_a_lock_that_does_not_read_leaves_the_touches_readable(played, tmp_path, lock_kind):
    """The recorder's lock as a FIFO waited for a writer for ever in every read of the unclosed bag (stats,
    check, calibrate, record --continue-from), /dev/zero grew without end, JSON nested 100000 deep raised a
    RecursionError (an adversarial review, 2026-11-28). Now such a lock is 'unreadable', as a garbled one is."""
    skin, want = played
    bag = tmp_path / "touches"
    killed_recording(bag, "mcap")
    lock = bag / LOCK_FILE
    lock.unlink()
    if lock_kind == "fifo":
        os.mkfifo(lock)
    elif lock_kind == "dev_zero":
        lock.symlink_to("/dev/zero")
    else:
        lock.write_text("[" * 100_000)
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""))
    run = subprocess.run([sys.executable, "-m", "nao_skin.cli", "stats", str(bag), "--json"], env=env,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr[-2000:]
    assert json.loads(run.stdout.splitlines()[-1])["touches"] == FLUSHED
    assert f"{LOCK_FILE} is unreadable" in run.stdout + run.stderr
