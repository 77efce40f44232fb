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

import os
from dataclasses import dataclass, replace
from pathlib import Path

from nao_skin.errors import DataError, one_line
from nao_skin.paths import DANGLING_LINK, not_a_file, read_text, safe_load

LOCK_FILE = "recording.lock"          # in a live bag's directory while its writer has it open
# in a rescued copy's metadata (custom_data): the bag it was copied from, its directory moved while recording
RESCUED_FROM_KEY = "nao_skin.rescued_from"
STORAGE_SUFFIXES = (".mcap", ".db3")
# a storage file read whole into memory (an mcap whose bag does not open): a touch bag of 4000 touches is 12 MB
MAX_SALVAGE_BYTES = 1 << 30


def check_storage_files(path: Path) -> None:
    """Every storage file of a bag (the bag's own file, or the .mcap and .db3 files in its directory) and its
    metadata.yaml is a regular file: a FIFO would wait for a writer forever, ``/dev/zero`` never ends."""
    path = Path(path)
    files = [path] if not path.is_dir() else sorted(p for p in path.iterdir() if p.suffix in STORAGE_SUFFIXES)
    if path.is_dir() and (path / "metadata.yaml").exists():   # rosbags reads it, before anything of ours could
        files.append(path / "metadata.yaml")
    for file in files:
        try:
            kind = not_a_file(file.stat().st_mode)
        except FileNotFoundError:
            kind = DANGLING_LINK if file.is_symlink() else None
        except OSError as exc:
            raise DataError(f"{file}: cannot read ({exc.strerror})") from None
        if kind:
            what = "metadata" if file.name == "metadata.yaml" else "storage"
            raise DataError(f"{file}: cannot read the bag's {what} (it is {kind}, not a regular file)")


METADATA_LIMIT = 64 << 20     # bytes: a bag's metadata.yaml lists files and topics, a few kB
LOCK_LIMIT = 1 << 16          # bytes: a lock names a process, a host and a start time


def bag_metadata(path: Path):
    """The ``rosbag2_bagfile_information`` of a bag directory's metadata.yaml, read as every text input is
    (a regular file, bounded: :func:`nao_skin.paths.read_text`); DataError (an OSError too), YAMLError,
    KeyError or TypeError when it cannot be read, is no YAML or no rosbag2 metadata."""
    return safe_load(read_text(Path(path) / "metadata.yaml", "as rosbag2 metadata",
                               limit=METADATA_LIMIT))["rosbag2_bagfile_information"]


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
        info = json.loads(read_text(lock, limit=LOCK_LIMIT))     # a FIFO put there would wait, /dev/zero not end
        pid, host, start = int(info["pid"]), str(info["host"]), info.get("start")
    except (ValueError, KeyError, TypeError, RecursionError):    # DataError (a ValueError): it does not read
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
@dataclass
class Tail:
    """What a storage file holds after a cursor, for a reader that follows a recording as it grows.

    ``committed``: complete messages, in the order a whole read gives them, that later writes cannot change;
    ``provisional``: what the file holds beyond them now (the complete messages of an mcap chunk still being
    written, and ``(None, how the file ends, None)`` where it breaks off), read again next time;
    ``cursor``: where the next read resumes (None: from the start); ``restarted``: this read could not resume
    from the cursor it was given (another file under the name, or one rewritten), so ``committed`` starts
    from the beginning of the file.
    """

    committed: list
    provisional: list
    cursor: object
    restarted: bool = False


class UnclosedBag:
    """A bag rosbags cannot open (or opens empty), read from its one storage file; :func:`unclosed_sqlite`,
    :func:`cut_mcap` and :func:`provisional_mcap` find one. Subclasses say how the file is read and what the
    report says was lost."""

    def __init__(self, path: Path, file: Path):
        self.path, self.file = path, file
        # before the file is read: a recorder closing the bag meanwhile still counts as open (a storage
        # file named itself: the lock of the folder it is in)
        self.lock = recording_lock(path if path.is_dir() else path.parent)
        self.custom_data: dict = {}     # the bag's custom metadata, where the storage file holds a copy of it
        self.rescued_from = _rescued_from(path if path.is_dir() else path.parent)

    def since(self, cursor) -> "Tail":
        """The messages written after ``cursor`` (None: from the start), see :class:`Tail`."""
        raise NotImplementedError

    def _lost_without_lock(self, n_msgs: int, ends: str) -> tuple:
        raise NotImplementedError

    def _read_until_death(self, n_msgs: int, ends: str) -> str:
        raise NotImplementedError

    def lost(self, n_msgs: int, ends: str) -> tuple | None:
        """``(reason, report line)`` when messages are lost for good; None while the recording may go on.

        ``ends``: how the messages ended (the ``why`` of the last ``(None, why, None)``).
        """
        if self.lock is None and self.rescued_from is not None and ends == "ends cleanly":
            return None             # a copy made while its recorder held the file: everything written to then
        if self.lock is None:
            return self._lost_without_lock(n_msgs, ends)
        if self.lock.state == "died":
            return ("truncated bag", f"{self.path}: {self.lock.who} died before closing the bag;"
                                     f" {self._read_until_death(n_msgs, ends)}")
        return None

    def note(self, n_msgs: int, n_touches: int) -> str | None:
        """The report note of a bag read from its storage file that lost nothing (so far): a rescued copy, or a
        recording whose recorder cannot be told running or dead (an open one is :meth:`info`); None otherwise."""
        lock = self.lock
        if lock is None and self.rescued_from is not None and self.lost(n_msgs, "ends cleanly") is None:
            return (f"{self.path}: the copy of {self.rescued_from} its recorder made when that bag's directory was"
                    f" removed, moved or replaced while recording: {n_msgs} messages of {self.file.name},"
                    f" {n_touches} touches, every one written until then")
        if lock is None or lock.state in ("died", "open"):
            return None
        read = f"read {n_msgs} messages of {self.file.name} written so far: {n_touches} touches"
        if lock.pid is None:
            return (f"{self.path}: {LOCK_FILE} is unreadable: the recording may still be open or its recorder died;"
                    f" {read}")
        return (f"{self.path}: {LOCK_FILE} names pid {lock.pid} on host {lock.host}, which cannot be checked from"
                f" here: the recording is open if that recorder still runs, else it died; {read}")

    def info(self, n_msgs: int, n_touches: int) -> str | None:
        """What a recording read while its recorder (running) still writes it is: what was written so far. No
        warning (:attr:`~nao_skin.touch.datasets.LoadReport.info`): a record session's own calibrations read their
        open recording, as expected; None when it is not one."""
        lock = self.lock
        if lock is None or lock.state != "open":
            return None
        return (f"{self.path}: the recording is still open (being recorded by pid {lock.pid} on {lock.host}); read"
                f" {n_msgs} messages of {self.file.name} written so far: {n_touches} touches")


def _rescued_from(directory: Path) -> str | None:
    """The bag a rescued copy (``<bag>.rescued``) was copied from, as its metadata.yaml says; None for any
    other bag."""
    try:
        info = bag_metadata(directory)
        origin = (info.get("custom_data") or {}).get(RESCUED_FROM_KEY)
    except Exception:  # noqa: BLE001 - no or unreadable metadata: not a rescued copy
        return None
    return origin if isinstance(origin, str) else None


# ---------------------------------------------------------------------- sqlite3: metadata.yaml lists no messages
class _UnclosedSqlite(UnclosedBag):
    def __init__(self, path: Path, file: Path, reason: str, why: str, unless_closed: str = ""):
        super().__init__(path, file)
        self.reason, self.why, self.unless_closed = reason, why, unless_closed
        # a bag closed by rosbag2 (Iron on) or rosbags keeps a copy of its metadata in the file: with it, a lost
        # or broken metadata.yaml costs nothing, and the file's message count says whether all is there (not
        # looked for while a recorder holds the bag: it writes the copy on close, and is not to be waited for)
        stored = stored_metadata(file) if self.lock is None else None
        self.stored_count = None
        if stored is not None:
            self.custom_data = stored.get("custom_data") or {}
            count = stored.get("message_count")
            if isinstance(count, int) and count == _sqlite_count(file):
                self.stored_count = count

    def lost(self, n_msgs: int, ends: str) -> tuple | None:
        return None if self.stored_count is not None and self.lock is None else super().lost(n_msgs, ends)

    def note(self, n_msgs: int, n_touches: int) -> str | None:
        if self.stored_count is not None and self.lock is None:
            return (f"{self.path}: {self.why}; the bag was closed and {self.file.name} holds its metadata too:"
                    f" read all {self.stored_count} messages it lists from it directly, nothing lost")
        return super().note(n_msgs, n_touches)

    def since(self, cursor) -> Tail:
        """``cursor``: ``(id, timestamp)`` of the last row read. A recorder appends rows in time order; when
        that row is gone or changed (another file under the name) or an older row came after it (another
        writer), the file is read from its start, so the order stays that of a whole read."""
        if cursor is not None:
            rows = _sqlite_messages(self.path, self.file, cursor[0] - 1)
            if rows and rows[0][:2] == cursor:
                rows = rows[1:]
                return Tail([r[2:] for r in rows], [], rows[-1][:2] if rows else cursor)
        rows = _sqlite_messages(self.path, self.file)
        return Tail([r[2:] for r in rows], [], rows[-1][:2] if rows else None, restarted=cursor is not None)

    def _lost_without_lock(self, n_msgs: int, ends: str) -> tuple:
        return self.reason, (f"{self.path}: {self.why}{self.unless_closed}; read {n_msgs} messages from"
                             f" {self.file.name} directly")

    def _read_until_death(self, n_msgs: int, ends: str) -> str:
        return (f"read {n_msgs} messages from {self.file.name} directly, up to its last flush;"
                " anything after that is lost")


def unclosed_sqlite(path: Path) -> UnclosedBag | None:
    """A sqlite3 bag whose metadata.yaml does not list its messages (never closed); None for any other bag."""
    files = sorted(path.glob("*.db3")) if path.is_dir() else []
    if len(files) != 1:
        return None
    why = metadata_yaml_problem(path)
    if why is not None:
        return _UnclosedSqlite(path, _only_storage(path, files[0], why), "no metadata", why)
    if not _lists_no_messages(path):
        return None
    return _UnclosedSqlite(path, files[0], "truncated bag", "metadata.yaml lists no messages",
                           " (the recorder did not close the bag; anything after its last commit is lost)")


def cut_sqlite(path: Path, open_error: Exception) -> UnclosedBag | None:
    """The bag's one sqlite3 file, read directly when its metadata.yaml reads but does not open (another
    version, a storage file or plugin it does not have): as an mcap bag's is (:func:`cut_mcap`). None when
    the folder holds no single sqlite3 file."""
    files = sorted(path.glob("*.db3")) if path.is_dir() else []
    if len(files) != 1:
        return None
    why = f"its metadata.yaml does not open ({one_line(open_error)})"
    return _UnclosedSqlite(path, _only_storage(path, files[0], why), "no metadata", why)


def _lists_no_messages(path: Path) -> bool:
    """The bag directory's (readable) metadata.yaml lists no messages: BagWriter's provisional one, written
    at open, lists neither files nor topics; the real one, written on close, both."""
    info = bag_metadata(path)
    return isinstance(info, dict) and not (info.get("files") or info.get("topics_with_message_count"))


def listed_message_count(path: Path) -> int | None:
    """How many messages the bag directory's metadata.yaml lists (a closed bag's); None when it lists none or
    does not read."""
    try:
        info = bag_metadata(path)
        count = info["message_count"]
    except Exception:  # noqa: BLE001 - unreadable in any way: no count to go by
        return None
    return count if isinstance(count, int) and not isinstance(count, bool) and count > 0 else None


def metadata_yaml_problem(path: Path) -> str | None:
    """What is wrong with the bag directory's metadata.yaml, in words ("it has no metadata.yaml", "its
    metadata.yaml is unreadable (not YAML from line 2: ...)"); None when it reads as rosbag2 metadata."""
    import yaml

    meta = path / "metadata.yaml"
    if not meta.exists():
        return "it has no metadata.yaml"
    try:
        bag_metadata(path).get("files")
    except DataError as exc:      # its text: not a regular file, too large, not UTF-8
        problem = getattr(exc, "reason", one_line(exc))
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = f"not YAML{f' from line {mark.line + 1}' if mark is not None else ''}: {getattr(exc, 'problem', '')}"
    except (KeyError, TypeError, AttributeError):
        problem = "not rosbag2 metadata: no 'rosbag2_bagfile_information' mapping"
    else:
        return None
    return f"its metadata.yaml is unreadable ({problem})"


def stored_metadata(file: Path) -> dict | None:
    """The rosbag2 metadata a closed storage file holds itself (rosbag2 from Iron on, and rosbags, write it on
    close: a sqlite3 file's ``metadata`` table, an mcap file's ``rosbag2`` metadata record); None when it holds
    none (never closed, an older writer) or it does not read. What metadata.yaml says, without it."""
    import yaml

    text = _sqlite_stored(file) if file.suffix == ".db3" else _mcap_stored(file) if file.suffix == ".mcap" else None
    try:
        info = safe_load(text) if text else None
    except yaml.YAMLError:
        return None
    if isinstance(info, dict) and isinstance(info.get("rosbag2_bagfile_information"), dict):
        info = info["rosbag2_bagfile_information"]
    return info if isinstance(info, dict) else None


def _sqlite_stored(file: Path) -> str | None:
    import sqlite3
    from contextlib import closing

    try:
        with closing(sqlite3.connect(f"{file.resolve().as_uri()}?mode=ro", uri=True, timeout=1.0)) as conn:
            row = conn.execute("SELECT metadata FROM metadata ORDER BY metadata_version DESC LIMIT 1").fetchone()
    except sqlite3.Error:
        return None
    return row[0] if row and isinstance(row[0], str) else None


def _mcap_stored(file: Path) -> str | None:
    """``serialized_metadata`` of the last ``rosbag2`` Metadata record (opcode 0x0C) in the file (None above
    :data:`MAX_SALVAGE_BYTES`: it is read whole)."""
    try:
        if file.stat().st_size > MAX_SALVAGE_BYTES:
            return None
        buf = file.read_bytes()
    except OSError:
        return None
    name = len(b"rosbag2").to_bytes(4, "little") + b"rosbag2"
    at = buf.rfind(name)
    while at >= 9:
        record, end = at - 9, at + _u64(buf, at - 8)
        if buf[record] == 0x0C and end <= len(buf):
            try:
                pos, size = at + len(name) + 4, _u32(buf, at + len(name))
                stop = min(pos + size, end)
                while pos < stop:
                    key, pos = _string(buf, pos)
                    value, pos = _string(buf, pos)
                    if key == "serialized_metadata":
                        return value
            except _DamagedRecord:
                pass
        at = buf.rfind(name, 0, at)
    return None


def _sqlite_count(file: Path) -> int | None:
    import sqlite3
    from contextlib import closing

    try:
        with closing(sqlite3.connect(f"{file.resolve().as_uri()}?mode=ro", uri=True, timeout=1.0)) as conn:
            return int(conn.execute("SELECT COUNT(*) FROM messages").fetchone()[0])
    except sqlite3.Error:
        return None


def _only_storage(path: Path, db3: Path, why: str) -> Path:
    """``db3``, the bag's storage file, when nothing else in the folder could be: without metadata to say which,
    reading the sqlite3 file beside an mcap one would silently leave the other's touches out."""
    mcap = sorted(path.glob("*.mcap"))
    if mcap:
        raise DataError(f"{path}: holds both {db3.name} and {mcap[0].name} and {why}, so nothing says which is the"
                        f" recording; move the other file out of the folder")
    return db3


def _sqlite_messages(path: Path, file: Path, after: int = 0) -> list:
    """``(id, timestamp, topic, msgtype, data)`` of every message committed to a rosbag2 sqlite3 file after row
    ``after``, in time order.

    Read-only, in one query: a live recorder's next commit waits at most that long.
    """
    import sqlite3
    from contextlib import closing

    query = ("SELECT m.id, m.timestamp, t.name, t.type, m.data FROM messages AS m JOIN topics AS t"
             f" ON m.topic_id = t.id WHERE m.id > {int(after)} ORDER BY m.timestamp, m.id")
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
MCAP_MAGIC = b"\x89MCAP0\r\n"
SIGNATURE = 64        # bytes before a resumed read's offset that must still be there (the same file grown)
OP_FOOTER, FOOTER_LENGTH = 0x02, 20     # summary start, summary offset start (u64 each), summary crc (u32)


class _CutMcap(UnclosedBag):
    def __init__(self, path: Path, file: Path, open_error: Exception | None, why: str | None = None):
        super().__init__(path, file)
        self.open_error = open_error
        self.why = why      # why the bag is read from its file, when it opens (see provisional_mcap)
        # the last read reached the footer and closing magic: the file is whole, only the bag around it
        # (metadata.yaml) failed to open
        self.whole = False
        if self.lock is None:    # a live recording has no copy yet (see _UnclosedSqlite), nor a whole file to read
            self.custom_data = (stored_metadata(file) or {}).get("custom_data") or {}

    def since(self, cursor) -> Tail:
        """``cursor``: ``(offset, the bytes before it, schemas, channels)`` after the last complete top-level
        record read; only the bytes after it are read again, once the ones before it are still there (else
        the file is another one under the name, read from its start)."""
        offset, before = (cursor[0], cursor[1]) if cursor is not None else (0, b"")
        try:
            with open(self.file, "rb") as f:
                # what is read: the bytes after the last read's end (a live recording's new ones), or all of them
                if os.fstat(f.fileno()).st_size - (offset - len(before)) > MAX_SALVAGE_BYTES:
                    why = one_line(self.open_error) if self.open_error else "never closed"
                    raise DataError(f"{self.path}: {self.file.name} is larger than {MAX_SALVAGE_BYTES >> 30} GiB"
                                    f" and its bag does not open ({why}): too large to read from the file itself")
                f.seek(offset - len(before))
                buf = f.read()
        except OSError as exc:
            raise DataError(f"{self.path}: cannot read {self.file.name} ({exc.strerror})") from None
        if cursor is not None and buf.startswith(before):
            schemas, channels = dict(cursor[2]), dict(cursor[3])
        elif cursor is not None:
            return replace(self.since(None), restarted=True)
        elif not buf.startswith(MCAP_MAGIC):
            return Tail([], [(None, "not an mcap file", None)], None)
        else:
            offset, before, schemas, channels = len(MCAP_MAGIC), MCAP_MAGIC, {}, {}
        whole = _closed_mcap(buf)
        body = buf[len(before):len(buf) - len(MCAP_MAGIC)] if whole else buf[len(before):]
        committed, provisional, used = _mcap_records(body, offset, schemas, channels)
        self.whole = whole and not provisional
        seen = buf[:len(before) + used][-SIGNATURE:]
        return Tail(committed, provisional, (offset + used, seen, schemas, channels))

    def _closed_whole(self) -> bool:
        """The file reached its footer and closing magic and no recorder holds it: every message is read
        (a recorder that died after its writer closed the file, while writing metadata.yaml, lost nothing)."""
        return self.whole and (self.lock is None or self.lock.state == "died")

    def _read_all_listed(self, n_msgs: int) -> bool:
        """Every message metadata.yaml lists was read and no recorder holds the bag: the file is damaged only
        after them (its summary and index, which the messages do not need)."""
        if self.lock is not None or self.whole:
            return False
        listed = listed_message_count(self.path)
        return listed is not None and 0 < listed <= n_msgs

    def lost(self, n_msgs: int, ends: str) -> tuple | None:
        return None if self._closed_whole() or self._read_all_listed(n_msgs) else super().lost(n_msgs, ends)

    def note(self, n_msgs: int, n_touches: int) -> str | None:
        if self._read_all_listed(n_msgs):
            damage = one_line(self.open_error) if self.open_error is not None else self.why
            return (f"{self.path}: {self.file.name} is damaged after its messages ({damage}); read all {n_msgs}"
                    f" messages its metadata.yaml lists, {n_touches} touches, nothing lost")
        if self._closed_whole():
            why = (self.why or (self.path.is_dir() and metadata_yaml_problem(self.path))
                   or f"the bag does not open ({one_line(self.open_error)})")
            died = f" (its recorder, pid {self.lock.pid}, died after closing it)" if self.lock is not None else ""
            return (f"{self.path}: {why}; read its {self.file.name} directly, whole to its end{died}: {n_msgs}"
                    f" messages, {n_touches} touches, nothing lost")
        return super().note(n_msgs, n_touches)

    def _lost_without_lock(self, n_msgs: int, ends: str) -> tuple:
        damage = one_line(self.open_error) if self.open_error is not None else self.why
        return "truncated bag", (f"{self.path}: {self.file.name} is damaged ({damage});"
                                 f" read {n_msgs} messages up to where it {ends}, the rest is lost")

    def _read_until_death(self, n_msgs: int, ends: str) -> str:
        return f"read {n_msgs} messages of {self.file.name} (the file {ends}); anything after its last flush is lost"


def cut_mcap(path: Path, open_error: Exception) -> UnclosedBag | None:
    """The bag's one mcap file (``path`` itself when it is one), which rosbags failed to open with
    ``open_error`` (in progress, recorder died, damage); None when the bag has no single mcap file."""
    files = (sorted(path.glob("*.mcap")) if path.is_dir()
             else [path] if path.suffix == ".mcap" and path.is_file() else [])
    return _CutMcap(path, files[0], open_error) if len(files) == 1 else None


def provisional_mcap(path: Path) -> UnclosedBag | None:
    """An mcap bag whose metadata.yaml is still the provisional one (it lists no messages): its recorder
    was killed, or its disk filled, or the folder was renamed, before the metadata was written on close.
    rosbags opens such a bag and finds nothing in it; its mcap file holds every message written (the whole
    file, when the writer closed it). None for any other bag."""
    files = sorted(path.glob("*.mcap")) if path.is_dir() else []
    if len(files) != 1 or sorted(path.glob("*.db3")) or metadata_yaml_problem(path) is not None:
        return None
    if not _lists_no_messages(path):
        return None
    return _CutMcap(path, files[0], None, "its metadata.yaml lists no messages (the bag was not closed)")


def _closed_mcap(buf: bytes) -> bool:
    """Whether ``buf`` (the end of an mcap file) ends with a footer record and the closing magic, as a
    writer leaves the file when it closes it."""
    footer = 1 + 8 + FOOTER_LENGTH
    n = len(buf)
    return (n >= footer + len(MCAP_MAGIC) and buf.endswith(MCAP_MAGIC)
            and buf[n - len(MCAP_MAGIC) - footer] == OP_FOOTER
            and _u64(buf, n - len(MCAP_MAGIC) - footer + 1) == FOOTER_LENGTH)


def _u16(b, o):
    return int.from_bytes(b[o:o + 2], "little")


def _u32(b, o):
    return int.from_bytes(b[o:o + 4], "little")


def _u64(b, o):
    return int.from_bytes(b[o:o + 8], "little")


class _DamagedRecord(Exception):
    """A record whose bytes cannot be what the mcap format says (a text field that is not UTF-8)."""


def _string(b, o):
    n = _u32(b, o)
    try:
        return b[o + 4:o + 4 + n].decode(), o + 4 + n
    except UnicodeDecodeError:
        raise _DamagedRecord from None


def _chunk_compression(buf: bytes, start: int) -> tuple:
    """``(compression, offset of the records' length)`` of the chunk record whose fields begin at ``start``."""
    return _string(buf, start + 8 + 8 + 8 + 4)


def _mcap_records(buf: bytes, base: int, schemas: dict, channels: dict) -> tuple:
    """``(committed, provisional, bytes used)`` of the mcap records in ``buf``, the file from byte ``base``.

    A cut file lacks the footer and summary the normal reader needs, but its
    records are length-prefixed: every complete one before the cut is intact.
    ``committed``: the ``(topic, msgtype, data)`` of the complete top-level
    records, the first ``bytes used`` of ``buf``; ``provisional``: the
    complete messages of a chunk cut off at the end, then ``(None, how the
    file ends, None)`` where it breaks off (also a compressed chunk, which is
    not salvaged, or a damaged record: nothing after it is read). ``schemas``
    and ``channels`` (id -> name, id -> (topic, schema name)) are updated with
    the committed records' definitions.
    """
    committed, pos, end = [], 0, len(buf)
    while pos < end:
        if pos + 9 > end:
            return committed, [(None, "ends inside a record header", None)], pos
        op, length = buf[pos], _u64(buf, pos + 1)
        start, stop = pos + 9, pos + 9 + length
        damaged = f"has a damaged record at byte {base + pos}"
        if stop > end:
            provisional, ends = [], None
            if op == 0x06:         # a cut chunk: its complete inner records are still good
                try:
                    comp, inner = _chunk_compression(buf, start)
                except _DamagedRecord:
                    comp, ends = None, damaged
                if comp == "":
                    ends = _walk(buf, inner + 8, end, base, dict(schemas), dict(channels), provisional)
            ends = ends or f"ends inside a record at byte {base + pos} of {base + end}"
            return committed, provisional + [(None, ends, None)], pos
        if op == 0x06:
            try:
                comp, inner = _chunk_compression(buf, start)
            except _DamagedRecord:
                return committed, [(None, damaged, None)], pos
            if comp != "":
                return committed, [(None, f"compressed chunk ({comp}) cannot be salvaged", None)], pos
            messages = []
            ends = _walk(buf, inner + 8, stop, base, schemas, channels, messages)
            if ends is not None:
                return committed, messages + [(None, ends, None)], pos
            committed += messages
        else:
            ends = _walk(buf, pos, stop, base, schemas, channels, committed)
            if ends is not None:
                return committed, [(None, ends, None)], pos
        pos = stop
    return committed, [], pos


def _walk(buf: bytes, pos: int, end: int, base: int, schemas: dict, channels: dict, out: list) -> str | None:
    """Schema, channel and message records between ``pos`` and ``end`` (no chunks): messages appended to
    ``out``; how they break off, or None when every record is complete."""
    while pos < end:
        if pos + 9 > end:
            return "ends inside a record header"
        op, length = buf[pos], _u64(buf, pos + 1)
        start, stop = pos + 9, pos + 9 + length
        if stop > end:
            return f"ends inside a record at byte {base + pos} of {base + end}"
        try:
            if op == 0x03:
                schemas[_u16(buf, start)] = _string(buf, start + 2)[0]
            elif op == 0x04:
                cid, sid = _u16(buf, start), _u16(buf, start + 2)
                channels[cid] = (_string(buf, start + 4)[0], schemas.get(sid, ""))
        except _DamagedRecord:
            return f"has a damaged record at byte {base + pos}"
        if op == 0x05:
            channel = channels.get(_u16(buf, start))
            if channel is not None:
                out.append((channel[0], channel[1], buf[start + 22:stop]))
        pos = stop
    return None
