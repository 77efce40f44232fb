"""Bags rosbags cannot open, read from their storage file: recordings never closed, and cut mcap files.

A live recording (:class:`~nao_skin.formats.bag.BagWriter` with ``live``,
as the pairing recorder writes it) holds :data:`LOCK_FILE` naming its
writer while it is open. rosbags writes the message list of metadata.yaml
and the mcap summary only on close, so until then (or for good, when the
recorder died) the messages are read from the file itself: the rows a
sqlite3 file has committed, the complete records of an mcap file. The lock
tells a recording in progress from one whose recorder died; without a lock
a cut mcap file is damaged.

No decoding here: :class:`UnclosedBag` gives ``(topic, msgtype, data)`` and
the lines the load report needs; the bag reader feeds the messages.
"""
from __future__ import annotations

from pathlib import Path

from nao_skin.errors import DataError, one_line

LOCK_FILE = "recording.lock"          # in a live bag's directory while its writer has it open


# ---------------------------------------------------------------------- the lock of a live recording
class RecordingLock:
    """A bag's :data:`LOCK_FILE`: who writes it, and whether that process still runs."""

    def __init__(self, pid, host, state: str):
        self.pid, self.host, self.state = pid, host, state      # state: open, died or unknown

    @property
    def who(self) -> str:
        return f"the recorder (pid {self.pid} on {self.host})"


def write_lock(path: Path) -> None:
    """Name this process as the writer of the bag directory ``path``."""
    import json
    import os
    import socket

    info = {"pid": os.getpid(), "host": socket.gethostname(), "start": _process_start(os.getpid())}
    (path / LOCK_FILE).write_text(json.dumps(info) + "\n")


def _process_start(pid: int) -> str | None:
    """A running process's start time (Linux); None when it is gone or a zombie, or there is no /proc."""
    try:
        fields = Path(f"/proc/{int(pid)}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError, ValueError):
        return None
    return None if fields[0] in ("Z", "X") else fields[19]


def recording_lock(path: Path) -> RecordingLock | None:
    """The bag's lock, if its writer left one: it holds the bag open now (state open) or died without closing it."""
    import json
    import os
    import socket

    lock = path / LOCK_FILE if path.is_dir() else None
    if lock is None or not lock.exists():
        return None
    try:
        info = json.loads(lock.read_text())
        pid, host, start = int(info["pid"]), str(info["host"]), info.get("start")
    except (OSError, ValueError, KeyError, TypeError):
        return RecordingLock(None, None, "unknown")
    if host != socket.gethostname():
        return RecordingLock(pid, host, "unknown")
    if Path("/proc/self/stat").exists():
        # the start time tells the recorder from a later process that got its pid
        now = _process_start(pid)
        return RecordingLock(pid, host, "open" if now is not None and start in (None, now) else "died")
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return RecordingLock(pid, host, "died")
    except PermissionError:
        pass
    return RecordingLock(pid, host, "open")


# ---------------------------------------------------------------------- a bag read from its storage file
class UnclosedBag:
    """A bag rosbags cannot open, read from its one storage file; :func:`unclosed_sqlite` and :func:`cut_mcap`
    find one. Subclasses say how the file is read and what the report says was lost."""

    def __init__(self, path: Path, file: Path):
        self.path, self.file = path, file
        # before the file is read: a recorder closing the bag meanwhile still counts as open
        self.lock = recording_lock(path)

    def messages(self):
        """``(topic, msgtype, data)`` in file order; ``(None, how the file ends, None)`` ends a cut file."""
        raise NotImplementedError

    def _lost_without_lock(self, n_msgs: int, ends: str) -> tuple:
        raise NotImplementedError

    def _read_until_death(self, n_msgs: int, ends: str) -> str:
        raise NotImplementedError

    def lost(self, n_msgs: int, ends: str) -> tuple | None:
        """``(reason, report line)`` when messages are lost for good; None while the recording may go on.

        ``ends``: how the messages ended (the ``why`` of the last ``(None, why, None)``).
        """
        if self.lock is None:
            return self._lost_without_lock(n_msgs, ends)
        if self.lock.state == "died":
            return ("truncated bag", f"{self.path}: {self.lock.who} died before closing the bag;"
                                     f" {self._read_until_death(n_msgs, ends)}")
        return None

    def still_open(self, n_msgs: int, n_touches: int) -> str | None:
        """The report note of a recording read while (maybe) still being written; None when it is not one."""
        lock = self.lock
        if lock is None or lock.state == "died":
            return None
        read = f"read {n_msgs} messages of {self.file.name} written so far: {n_touches} touches"
        if lock.state == "open":
            return f"{self.path}: the recording is still open (being recorded by pid {lock.pid} on {lock.host}); {read}"
        if lock.pid is None:
            return (f"{self.path}: {LOCK_FILE} is unreadable: the recording may still be open or its recorder died;"
                    f" {read}")
        return (f"{self.path}: {LOCK_FILE} names pid {lock.pid} on host {lock.host}, which cannot be checked from"
                f" here: the recording is open if that recorder still runs, else it died; {read}")


# ---------------------------------------------------------------------- sqlite3: metadata.yaml lists no messages
class _UnclosedSqlite(UnclosedBag):
    def __init__(self, path: Path, file: Path, reason: str, why: str):
        super().__init__(path, file)
        self.reason, self.why = reason, why

    def messages(self) -> list:
        return _sqlite_messages(self.path, self.file)

    def _lost_without_lock(self, n_msgs: int, ends: str) -> tuple:
        return self.reason, f"{self.path}: {self.why}; read {n_msgs} messages from {self.file.name} directly"

    def _read_until_death(self, n_msgs: int, ends: str) -> str:
        return (f"read {n_msgs} messages from {self.file.name} directly, up to its last flush;"
                " anything after that is lost")


def unclosed_sqlite(path: Path) -> UnclosedBag | None:
    """A sqlite3 bag whose metadata.yaml does not list its messages (never closed); None for any other bag."""
    import yaml

    files = sorted(path.glob("*.db3")) if path.is_dir() else []
    if len(files) != 1:
        return None
    meta = path / "metadata.yaml"
    if not meta.exists():
        return _UnclosedSqlite(path, files[0], "no metadata", "it has no metadata.yaml")
    try:
        info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
        listed = bool(info.get("files") or info.get("topics_with_message_count"))
    except Exception as exc:  # noqa: BLE001 - yaml and a malformed layout raise assorted types
        return _UnclosedSqlite(path, files[0], "no metadata", f"its metadata.yaml is unreadable ({one_line(exc)})")
    # BagWriter's provisional metadata (written at open) lists neither; the real one, written on close, both
    if listed:
        return None
    return _UnclosedSqlite(path, files[0], "truncated bag", "metadata.yaml is incomplete (the recorder did not close"
                                                             " the bag; anything after its last commit is lost)")


def _sqlite_messages(path: Path, file: Path) -> list:
    """``(topic, msgtype, data)`` of every message committed to a rosbag2 sqlite3 file, in time order.

    Read-only, in one query: a live recorder's next commit waits at most that long.
    """
    import sqlite3
    from contextlib import closing

    query = ("SELECT t.name, t.type, m.data FROM messages AS m JOIN topics AS t ON m.topic_id = t.id"
             " ORDER BY m.timestamp, m.id")
    try:
        with closing(sqlite3.connect(f"{file.resolve().as_uri()}?mode=ro", uri=True, timeout=1.0)) as conn:
            return conn.execute(query).fetchall()
    except sqlite3.Error as exc:
        name = getattr(exc, "sqlite_errorname", "")
        if not (name in ("SQLITE_READONLY_ROLLBACK", "SQLITE_BUSY") or "readonly" in str(exc)
                or "locked" in str(exc)):
            raise DataError(f"{path}: cannot read {file.name} ({one_line(exc)})") from None
    # the writer's open transaction has reached the file (it holds the file locked, or died so): sqlite
    # must roll its journal back, which a read-only reader cannot; do it on a copy, leave the recording be
    return _sqlite_messages_of_copy(path, file, query)


def _sqlite_messages_of_copy(path: Path, file: Path, query: str, attempts: int = 5) -> list:
    import shutil
    import sqlite3
    import tempfile
    from contextlib import closing

    journal = file.with_name(file.name + "-journal")

    def state():
        return tuple((f.stat().st_size, f.stat().st_mtime_ns) if f.exists() else None for f in (file, journal))

    with tempfile.TemporaryDirectory(prefix="nao_skin_db3_") as tmp:
        copy = Path(tmp) / file.name
        for _ in range(attempts):
            before = state()
            try:
                shutil.copyfile(file, copy)
                if before[1] is not None:
                    shutil.copyfile(journal, copy.with_name(journal.name))
            except FileNotFoundError:       # the writer committed meanwhile (journal gone): again
                pass
            else:
                if state() == before:       # a live writer changed neither file while they were copied
                    break
            for f in Path(tmp).iterdir():
                f.unlink()
        else:
            raise DataError(f"{path}: {file.name} kept changing while it was read; read it again")
        try:
            with closing(sqlite3.connect(copy)) as conn:
                return conn.execute(query).fetchall()
        except sqlite3.Error as exc:
            raise DataError(f"{path}: cannot read {file.name} ({one_line(exc)})") from None


# ---------------------------------------------------------------------- mcap: a file without its summary
class _CutMcap(UnclosedBag):
    def __init__(self, path: Path, file: Path, open_error: Exception):
        super().__init__(path, file)
        self.open_error = open_error

    def messages(self):
        try:
            buf = self.file.read_bytes()
        except OSError as exc:
            raise DataError(f"{self.path}: cannot read {self.file.name} ({exc.strerror})") from None
        return _mcap_messages(buf)

    def _lost_without_lock(self, n_msgs: int, ends: str) -> tuple:
        return "truncated bag", (f"{self.path}: {self.file.name} is damaged ({one_line(self.open_error)});"
                                 f" read {n_msgs} messages up to where it {ends}, the rest is lost")

    def _read_until_death(self, n_msgs: int, ends: str) -> str:
        return f"read {n_msgs} messages of {self.file.name} (the file {ends}); anything after its last flush is lost"


def cut_mcap(path: Path, open_error: Exception) -> UnclosedBag | None:
    """The bag's one mcap file, which rosbags failed to open with ``open_error`` (in progress, recorder died,
    damage); None when the bag has no single mcap file."""
    files = sorted(path.glob("*.mcap")) if path.is_dir() else []
    return _CutMcap(path, files[0], open_error) if len(files) == 1 else None


def _mcap_messages(buf: bytes):
    """``(topic, msgtype, data)`` of an mcap file read front to back, stopping where it breaks off.

    A cut file lacks the footer and summary the normal reader needs, but its
    records are length-prefixed: every complete one before the cut is intact.
    Yields ``(None, error, None)`` once if the file ends inside a record.
    """
    u16 = lambda b, o: int.from_bytes(b[o:o + 2], "little")          # noqa: E731
    u32 = lambda b, o: int.from_bytes(b[o:o + 4], "little")          # noqa: E731
    u64 = lambda b, o: int.from_bytes(b[o:o + 8], "little")          # noqa: E731

    def string(b, o):
        n = u32(b, o)
        return b[o + 4:o + 4 + n].decode(), o + 4 + n

    schemas, channels = {}, {}

    def walk(b, pos, end, top):
        while pos < end:
            if pos + 9 > end:
                yield None, "ends inside a record header", None
                return
            op, length = b[pos], u64(b, pos + 1)
            start, stop = pos + 9, pos + 9 + length
            if stop > end:
                if op == 0x06 and top:        # a cut chunk: its complete inner records are still good
                    inner = start + 8 + 8 + 8 + 4
                    comp, inner = string(b, inner)
                    if comp == "":
                        yield from walk(b, inner + 8, end, False)
                yield None, f"ends inside a record at byte {pos} of {end}", None
                return
            if op == 0x03:
                sid = u16(b, start)
                name, _ = string(b, start + 2)
                schemas[sid] = name
            elif op == 0x04:
                cid, sid = u16(b, start), u16(b, start + 2)
                topic, _ = string(b, start + 4)
                channels[cid] = (topic, schemas.get(sid, ""))
            elif op == 0x05:
                channel = channels.get(u16(b, start))
                if channel is not None:
                    yield channel[0], channel[1], b[start + 22:stop]
            elif op == 0x06:
                inner = start + 8 + 8 + 8 + 4
                comp, inner = string(b, inner)
                if comp != "":
                    yield None, f"compressed chunk ({comp}) cannot be salvaged", None
                    return
                yield from walk(b, inner + 8, stop, False)
            pos = stop

    if not buf.startswith(b"\x89MCAP0\r\n"):
        yield None, "not an mcap file", None
        return
    yield from walk(buf, 8, len(buf), True)
