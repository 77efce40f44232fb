"""Output directories: which ones a command may write, and replacing one safely.

Every output directory nao-skin produces holds a marker file, ``.nao_skin_output``
(JSON: the command that wrote it, when, what kind of output it is and every
entry it wrote). A directory is only ever replaced when it carries the marker
AND holds nothing the marker does not list, so a file a user later put into an
output directory is never deleted, AND by an output of the same kind, so no
``--force`` turns a (simulated) recording into a calibration or a benchmark.
:func:`check_output_dir` is called before any data is loaded, so a
mistaken ``--out`` costs nothing; :func:`replace_dir` checks again at the end,
because a calibration can run for minutes while the user works in the directory.
"""
from __future__ import annotations

import errno
import json
import os
import re
import shutil
import signal
import stat
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path

from nao_skin.errors import STOP_SIGNALS, DataError, OutputTaken
from nao_skin.paths import read_text

MARKER = ".nao_skin_output"
MARKER_LIMIT = 16 << 20     # bytes: a marker lists the entries of one output, a few kB
FORMAT = "nao_skin/output/1"
# kinds of output
RECORDING = "recording"          # nao-skin simulate
CALIBRATION = "calibration"      # nao-skin calibrate, demo, the calibrate node
BENCHMARK = "benchmark"          # nao-skin bench
CAPTURE_BENCHMARK = "capture benchmark"   # nao-skin bench-capture
BOUND_BENCHMARK = "bound benchmark"       # nao-skin bench-bound
CHECK_BENCHMARK = "check benchmark"       # nao-skin bench-check
# outputs of earlier versions mark all three benches "benchmark": such a marker is read as the kind its command
# writes now, so that --force never lets one bench replace another's (hours of a bench for minutes of another)
_EARLIER_KINDS = {("benchmark", "nao-skin bench-capture"): CAPTURE_BENCHMARK,
                  ("benchmark", "nao-skin bench-bound"): BOUND_BENCHMARK}


def write_marker(directory: str | Path, command: str, kind: str, entries=None, stamp: bool = True) -> Path:
    """Mark ``directory`` as a ``kind`` of output written by ``nao-skin COMMAND``.

    ``entries``: the relative paths this command writes there; default: every
    entry the directory holds now (call it on a directory only we have written,
    e.g. the temporary one before it is moved into place). ``stamp=False``
    leaves the time out, for outputs promised to be the same bytes each run.
    """
    directory = Path(directory)
    if entries is None:
        entries = [rel for rel, _ in _walk(directory)]
    info = {"format": FORMAT, "command": f"nao-skin {command}", "kind": kind}
    if stamp:
        info["written"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    info["entries"] = sorted(set(entries) - {MARKER})
    path = directory / MARKER
    path.write_text(json.dumps(info, indent=1) + "\n")
    return path


def read_marker(directory: str | Path) -> dict | None:
    """The marker of ``directory``, or None when it has none (or one we cannot read: not ours)."""
    path = Path(directory) / MARKER
    try:     # as every text input is read: a FIFO put there would wait, /dev/zero never end
        info = json.loads(read_text(path, limit=MARKER_LIMIT))
    except (ValueError, RecursionError):      # DataError too: not a regular file, too large, no text
        return None
    if (not isinstance(info, dict) or info.get("format") != FORMAT or not isinstance(info.get("entries"), list)
            or not isinstance(info.get("kind"), str)):
        return None
    info["kind"] = _EARLIER_KINDS.get((info["kind"], info.get("command")), info["kind"])
    return info


def check_output_dir(out: str | Path, kind: str, inputs=(), force: bool = False, label: str = "--out") -> Path:
    """Refuse (DataError, one line) an output directory that writing a ``kind`` would damage; returns it resolved.

    Refused: an existing file, or a path below one; the current directory or
    one containing it; an input (file or directory) or a directory containing
    one or inside one; a non-empty directory without our marker; a marked one
    holding anything the marker does not list or another kind of output (both
    even with ``force``); a marked one without ``force``. A missing or empty
    directory is fine.
    """
    given = Path(out)
    name = f"{label} {given}"
    try:
        os.getcwd()
    except FileNotFoundError:           # every relative path below means the directory that was removed
        raise DataError(f"{name}: the current directory no longer exists; change to an existing one") from None
    try:
        given.stat()
    except FileNotFoundError:
        pass
    except OSError as exc:              # a name too long, a loop of symlinks, no permission on a folder
        raise DataError(f"{name}: {exc.strerror}; choose another place") from None
    if given.exists() and not given.is_dir():
        raise DataError(f"{name}: is an existing file, not a directory; choose a directory")
    for parent in Path(os.path.abspath(given)).parents:
        if parent.exists():
            if not parent.is_dir():
                raise DataError(f"{name}: {parent} is a file, not a directory; choose another place")
            break
    # an earlier output a killed run had moved aside to swap goes back first: the check sees what is really there
    _remove_stale_staging(Path(os.path.realpath(given)))
    forms = _forms(given)
    for cwd in _forms(Path.cwd()):
        for o in forms:
            if o == cwd:
                raise DataError(f"{name}: is the current directory; writing there would replace everything in it,"
                                f" choose a new directory")
            if _inside(cwd, o):
                raise DataError(f"{name}: contains the current directory; choose a new directory")
    for item in inputs:
        if item is None or str(item) == "":
            continue
        what = f"the input {item}"
        for i in _forms(Path(item)):
            for o in forms:
                if o == i:
                    raise DataError(f"{name}: is {what}; writing there would replace it, choose another directory")
                if _inside(i, o):
                    raise DataError(f"{name}: contains {what}; writing there would replace it,"
                                    f" choose another directory")
                if _inside(o, i):
                    raise DataError(f"{name}: lies inside {what}; choose a directory outside the input")
    problem = _replace_problem(given, kind, force)
    if problem:
        raise DataError(f"{name}: {problem}")
    check_writable(Path(os.path.realpath(given)), name)
    _check_replaceable(Path(os.path.realpath(given)), name)
    return Path(os.path.realpath(given))


def check_writable(out: Path, name: str) -> None:
    """Refuse, before any work, a place where ``out`` or its temporary sibling cannot be made (below a file,
    read-only, /proc): otherwise the failure would come only at the end, after minutes of calibration."""
    out = Path(os.path.abspath(out))
    place = next(p for p in (out.parent, *out.parent.parents) if p.exists())
    if not place.is_dir():
        raise DataError(f"{name}: {place} is a file, not a directory; choose another place")
    try:
        longest = os.pathconf(place, "PC_NAME_MAX")
    except (OSError, ValueError):
        longest = 255
    # the folders still to be made (and the temporary sibling's longer name) only fail when written, at the end
    for part in out.relative_to(place).parts:
        if len(os.fsencode(part)) > longest - 16:
            raise DataError(f"{name}: the name {part[:20]}... is longer than {longest - 16} bytes; choose a shorter one")
    try:
        Path(tempfile.mkdtemp(prefix=f".{out.name}.probe.", dir=place)).rmdir()
    except OSError as exc:
        raise DataError(f"{name}: cannot write in {place} ({exc.strerror}); choose another place") from None


def _check_replaceable(out: Path, name: str) -> None:
    """Refuse, before any work, an earlier output that could not be moved aside and removed at the end.

    Moving a directory to another parent rewrites its ``..``, and removing an
    entry writes its folder: a read-only output directory (or folder in it)
    would otherwise fail only after the calibration, or leave its old copy behind.
    """
    if not out.is_dir() or not any(out.iterdir()):
        return
    for folder in [out] + [out / rel for rel, is_dir in _walk(out) if is_dir]:
        try:
            Path(tempfile.mkdtemp(prefix=".probe.", dir=folder)).rmdir()
        except OSError as exc:
            raise DataError(f"{name}: its earlier output cannot be replaced: cannot write in {folder}"
                            f" ({exc.strerror}); make it writable or choose another directory") from None


def replace_file(path: str | Path, data: str | bytes, read_only_too: bool = False) -> None:
    """Write ``path`` whole or not at all: a temporary sibling (mode 0o666 less the umask, or the mode of the
    file it replaces, as a plain write gives) renamed over it, so a failed write (a full disk, a signal)
    leaves the earlier file as it was.
    Raises the ``OSError``; the temporary file is gone then. A symlink's target is written, as a plain write
    would; anything else that is not a regular file (``/dev/null``, a FIFO) is refused, never replaced, and so
    is a read-only file unless ``read_only_too`` (a ``--force``)."""
    from nao_skin.paths import not_a_file

    path = Path(os.path.realpath(path))
    mode = path.stat().st_mode if path.exists() else None
    kind = not_a_file(mode) if mode is not None else None
    if kind:
        raise OSError(errno.EEXIST, f"it is {kind}, not a regular file")
    if mode is not None and not mode & 0o222 and not read_only_too:
        # somebody made it read-only, which a rename would not ask about (nor, for root, a plain write)
        raise OSError(errno.EACCES, "it is read-only; make it writable to replace it")
    temporary, made = path.with_name(f".{path.name}.{os.getpid()}.tmp"), False
    try:
        # O_EXCL: never another file under that name
        with os.fdopen(os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666),
                       "wb" if isinstance(data, bytes) else "w") as f:
            made = True
            if mode is not None:    # the file it replaces keeps its permissions, as a plain write keeps them
                os.chmod(f.fileno(), stat.S_IMODE(mode))
            f.write(data)
            f.flush()
            _sync(f.fileno())
        os.replace(temporary, path)
        _sync_path(path.parent)
    except BaseException:
        if made:
            temporary.unlink(missing_ok=True)
        raise


def _sync(fd: int) -> None:
    """``os.fsync``, where the file system takes it (some FUSE and pipe-like files do not: nothing to do)."""
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):
            raise


def _sync_path(path: str | Path) -> None:
    """Put a file's data, or a directory's entries, on the disk (``fsync``); one we may not open for reading
    (a directory without read permission) is left to the system."""
    try:
        fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if os.path.isdir(path) else 0))
    except PermissionError:
        return
    try:
        _sync(fd)
    finally:
        os.close(fd)


def _sync_tree(root: Path) -> None:
    """Every regular file and directory under ``root`` (and ``root``) on the disk: a rename that publishes
    them must never reach the disk before they do (after a power cut, an empty file where the earlier
    output was)."""
    for folder, _, files in os.walk(root):
        for name in files:
            if stat.S_ISREG(os.lstat(os.path.join(folder, name)).st_mode):
                _sync_path(os.path.join(folder, name))
        _sync_path(folder)


def output_stamp(path: str | Path) -> tuple | None:
    """What tells one output from anything put at its path since (None: nothing there): (device, inode, its
    output marker's text, inode and change time). The inode alone does not: a directory removed and another
    made in its place may get the same one; the marker says when it was written and by which command. A
    directory without a marker: its change time (which a chmod changes too; an output marker does not)."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    try:
        # the marker's own inode and change time too: a run of the same command within the same second, in a
        # directory that got the same inode, writes the same marker text
        written = os.stat(Path(path) / MARKER)
        marker = (read_text(Path(path) / MARKER, limit=MARKER_LIMIT), written.st_ino, written.st_ctime_ns)
    except (OSError, ValueError):   # none, or (DataError) a FIFO that would wait, a device, no text: not ours
        marker = st.st_ctime_ns
    return st.st_dev, st.st_ino, marker


def as_checked(out: str | Path) -> tuple:
    """``replacing`` for :func:`replace_dir` that allows exactly what is at ``out`` now, when a command checks
    it: nothing (a free place) or that output (the one ``--force`` agreed to replace). Another output written
    there while the command runs is then never replaced."""
    return () if is_free(os.path.realpath(out)) else output_stamp(os.path.realpath(out))


def is_free(path: str | Path) -> bool:
    """Nothing there yet, or an empty directory: a place any output may take."""
    path = Path(path)
    return not os.path.lexists(path) or (path.is_dir() and not path.is_symlink() and not any(path.iterdir()))


def replace_dir(new: str | Path, out: str | Path, label: str = "output directory", replacing=None) -> Path:
    """Move the finished, marked directory ``new`` to ``out`` (same file system, e.g. a temporary sibling).

    An earlier output at ``out`` is renamed aside first, the new one moved in,
    then the old one removed, so at no moment is there neither. It is checked
    once more here: one holding a file we did not write, or another kind of
    output, is not replaced.

    ``replacing``: None, any earlier output those rules allow (the user asked for it, ``--force``); ``()``,
    none: ``out`` must still be free (:func:`is_free`); else the :func:`output_stamp` of the one output that
    may be replaced (a node's own last one; a free ``out`` may be taken too). Anything else found there,
    e.g. another process's output written to the same place meanwhile, raises :class:`OutputTaken` and
    stays as it is. Writers in one folder take turns (a lock on the folder): no two check and swap at once.
    """
    new, out = Path(new), Path(os.path.realpath(out))
    marker = read_marker(new)
    if marker is None:
        raise RuntimeError(f"{new}: has no output marker; write_marker first")   # a bug of the caller, not bad input
    taken = f"{label} {out}: another output was written there meanwhile; it is left as it is"
    with _folder_locked(out.parent):
        if replacing is not None and not _may_take(out, replacing):
            raise OutputTaken(taken)
        problem = _replace_problem(out, marker["kind"], force=True)
        if problem:      # e.g. a user's file put into the node's own output: with ``replacing``, left for beside it
            raise (OutputTaken if replacing is not None else DataError)(f"{label} {out}: {problem}")
        # the temporary directory is private (0700): the output gets the mode of the directory it replaces,
        # or the one a plain mkdir gives
        os.chmod(new, stat.S_IMODE(out.stat().st_mode) if out.is_dir() else 0o777 & ~_umask())
        _sync_tree(new)   # the new output whole on the disk before any rename: the earlier one stays till then
        if not out.exists() or (replacing is not None and is_free(out)):
            try:
                os.replace(new, out)  # onto nothing or an empty directory only: never onto one made meanwhile
            except OSError as exc:
                if replacing is None or exc.errno not in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR):
                    raise
                raise OutputTaken(taken) from None
            _sync_path(out.parent)
            return out
        with _stops_deferred():
            # named by this process: a kill between the two renames leaves it for the next writer to put back
            aside = Path(tempfile.mkdtemp(prefix=f".{out.name}.old.{os.getpid()}.", dir=out.parent))
            try:
                os.replace(out, aside / out.name)
            except BaseException:
                aside.rmdir()
                raise
            if replacing is not None and not _may_take(aside / out.name, replacing):
                # replaced by a writer that does not take turns, between the check and the move: it goes back
                os.replace(aside / out.name, out)
                aside.rmdir()
                raise OutputTaken(taken)
            try:
                os.replace(new, out)
            except BaseException:
                try:
                    os.replace(aside / out.name, out)
                except OSError:      # something took the place in between: the earlier output is kept aside
                    raise OutputTaken(f"{taken}; the earlier output there is kept at {aside / out.name}") from None
                aside.rmdir()
                raise
            _sync_path(out.parent)   # the swap on the disk before the earlier output goes
            shutil.rmtree(aside, ignore_errors=True)
    return out


def _may_take(out: Path, replacing) -> bool:
    """``out`` is free, or the one output ``replacing`` names (see :func:`replace_dir`)."""
    return is_free(out) or (replacing != () and output_stamp(out) == replacing)


@contextmanager
def _folder_locked(folder: Path):
    """An exclusive ``flock`` on ``folder`` while the block runs: nao-skin writers of one folder take turns.
    A folder that cannot be opened for it (no read permission) is written without."""
    import fcntl

    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError:
        yield
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


@contextmanager
def _stops_deferred():
    """A stop signal (Ctrl-C, kill) waits until the block is done, then reaches the handlers the command had:
    stopped inside it, a swap left the earlier output half deleted beside the new one. Only the main thread
    can change handlers; elsewhere (a node's worker) the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list = []
    before = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    for s in STOP_SIGNALS:
        signal.signal(s, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        for s, handler in before.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)
        for s in dict.fromkeys(caught):
            signal.raise_signal(s)


def staging_dir(out: str | Path) -> Path:
    """A new private directory beside ``out`` to write an output into before :func:`replace_dir` moves it
    there, named ``.<out>.<pid>.<random>``.

    A run killed outright (SIGKILL, a power cut) leaves its staging directory behind, where no one looks:
    each call first removes those of ``out`` whose process is gone. Only staging directories are: their
    name says whose they were, and they never held anything but the unfinished output of that run.
    """
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale_staging(out)
    return Path(tempfile.mkdtemp(prefix=f".{out.name}.{os.getpid()}.", dir=out.parent))


def _remove_stale_staging(out: Path) -> None:
    """What a run killed outright left beside ``out``: its staging directory is removed; an earlier output it had
    moved aside to swap (``.<out>.old.<pid>.<random>/<out>``) goes back to ``out`` when nothing took its place
    (killed between the two renames), else is removed (killed after the swap, before the removal)."""
    staged = re.compile(rf"\.{re.escape(out.name)}\.([0-9]{{1,10}})\.[a-z0-9_]{{8}}")
    aside = re.compile(rf"\.{re.escape(out.name)}\.old\.([0-9]{{1,10}})\.[a-z0-9_]{{8}}")
    try:
        siblings = list(os.scandir(out.parent))
    except OSError:
        return
    for entry in siblings:
        match = staged.fullmatch(entry.name) or aside.fullmatch(entry.name)
        if not match or not entry.is_dir(follow_symlinks=False) or _alive(int(match.group(1))):
            continue
        earlier = Path(entry.path) / out.name
        if match.re is aside and not os.path.lexists(out) and earlier.is_dir():
            try:
                os.replace(earlier, out)
            except OSError:
                continue          # left as it is: never removed while it may be the only copy
        shutil.rmtree(entry.path, ignore_errors=True)


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs (another user's too: PermissionError); a pid no process can have is not."""
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):
        return False
    except OSError:
        pass
    return True


def clear_for_writing(out: str | Path, command: str, kind: str, entries, label: str = "output directory") -> Path:
    """Make ``out`` an empty marked directory for a command that writes into it piece by piece.

    An earlier output there must pass :func:`check_output_dir` first (with its
    ``force``); here it is moved aside and removed, after the same last check
    as :func:`replace_dir`.
    """
    out = Path(os.path.realpath(out))
    fresh = staging_dir(out)
    try:
        write_marker(fresh, command, kind, entries=entries)
        replace_dir(fresh, out, label)
    except BaseException:
        shutil.rmtree(fresh, ignore_errors=True)
        raise
    return out


def _umask() -> int:
    """The process's umask, read without setting it where Linux says it (a node writes from a thread)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _replace_problem(out: Path, kind: str, force: bool) -> str | None:
    """Why ``out`` may not be replaced by a ``kind`` of output (with or without ``force``), or None when it may."""
    if not out.exists():
        return None
    if not out.is_dir():
        return "is an existing file, not a directory; choose a directory"
    top = sorted(p.name for p in out.iterdir())
    if not top:
        return None
    marker = read_marker(out)
    if marker is None:
        return (f"is a non-empty directory nao-skin did not write (it holds {_some(top)});"
                f" choose a new or empty directory")
    if marker["kind"] != kind:
        return (f"holds a {marker['kind']} written by {marker['command']}, not a {kind}; it is not replaced, even with"
                f" --force: choose another directory")
    ours = set(marker["entries"])
    foreign = [rel for rel, _ in _walk(out, prune=ours) if rel not in ours and rel != MARKER]
    if foreign:
        more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
        return (f"{out / foreign[0]}{more} was not written by {marker['command']}; it is not replaced, even with"
                f" --force: move it out of the directory first or choose another one")
    if not force:
        held = _some([t for t in top if t != MARKER]) or f"nothing but its {MARKER}"
        return f"holds the outputs of an earlier {marker['command']} run ({held}); pass --force to replace them"
    return None


def _walk(root: Path, prune=None):
    """``(relative path, is_dir)`` of every entry under ``root``, not following symlinks.

    With ``prune`` (a set of relative paths), directories not in it are not
    descended into: the directory itself is already the entry to name.
    """
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        base = Path(dirpath).relative_to(root)
        for d in sorted(dirnames):
            yield (base / d).as_posix(), True
        for f in sorted(filenames):
            yield (base / f).as_posix(), False
        if prune is not None:
            dirnames[:] = [d for d in dirnames if (base / d).as_posix() in prune]
        dirnames.sort()


def _forms(path: Path) -> set:
    """The path as written (absolute) and with every symlink resolved: either may be what a user means."""
    return {Path(os.path.abspath(path)), Path(os.path.realpath(path))}


def _inside(child: Path, parent: Path) -> bool:
    return child != parent and parent in child.parents


def _some(names: list, n: int = 4) -> str:
    return ", ".join(names[:n]) + (f", ... ({len(names)} entries)" if len(names) > n else "")
