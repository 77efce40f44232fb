"""One record session per ROS domain and namespace on this machine.

Two sessions on one ``ROS_DOMAIN_ID`` hear each other: each recorder takes
the other robot's skin and joint states for its own, each calibrate node
answers the other's requests, and both bags mix the two robots beyond
repair. So ``nao-skin record`` and ``record.launch.py`` claim the domain
(with the session's namespace: two robots in two namespaces hear only their own
topics) before any node starts: an exclusive ``flock`` on
``/tmp/nao_skin_ros_domain_<id>.lock``, held as long as the claiming process
runs. The kernel releases it when that process ends in any way (a
``kill -9`` too), so a claim never outlives its session and two sessions
starting at once cannot both get it. The file stays (it names the last
claimant's pid, for the refusal's line); it is in ``/tmp`` whatever
``TMPDIR`` says, so that every shell of the machine sees the same one.
Sessions on two machines share a domain only with
``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``; there the recorder says when a
second publisher feeds one of its skin topics.
"""
from __future__ import annotations

import fcntl
import os
from pathlib import Path

from nao_skin.errors import ConfigError, os_reason

LOCK_DIR = Path("/tmp")
DOMAIN_IDS = range(0, 233)       # what rmw accepts on Linux (ports 7400 + 250 * id must stay below 65536)


def domain_id(environ=os.environ) -> int:
    """The ROS domain this process's nodes join: ``ROS_DOMAIN_ID``, 0 when unset or empty (as rcl reads it)."""
    text = environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    if not text.isascii() or not text.isdigit() or int(text) not in DOMAIN_IDS:
        raise ConfigError(f"ROS_DOMAIN_ID={text!r}: expected a whole number from {DOMAIN_IDS.start} to"
                          f" {DOMAIN_IDS.stop - 1}")
    return int(text)


def lock_path(domain: int, lock_dir: Path | None = None, namespace: str = "/") -> Path:
    """The lock of a domain's session outside a namespace, or in ``namespace`` (``/nao2``: ``..._nao2.lock``)."""
    within = "_".join(p for p in namespace.split("/") if p)
    name = f"nao_skin_ros_domain_{domain}{f'_ns_{within}' if within else ''}.lock"
    return (LOCK_DIR if lock_dir is None else Path(lock_dir)) / name


class DomainClaim:
    """This process's claim on a ROS domain (:func:`claim_domain`): held while the object lives or until
    :meth:`release`; ``fd`` None: the lock file could not be opened, the domain is not claimed."""

    def __init__(self, path: Path, domain: int, fd: int | None, problem: str | None = None):
        self.path, self.domain, self.fd, self.problem = path, domain, fd, problem

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)        # closing the descriptor releases the flock
            self.fd = None

    def __del__(self, close=os.close):    # bound now: at interpreter exit the module's names may be gone
        if self.fd is not None:
            try:
                close(self.fd)
            except OSError:
                pass


def claim_domain(domain: int | None = None, lock_dir: Path | None = None, namespace: str = "/",
                 spelling: str = "command") -> DomainClaim:
    """Claim ``domain`` (default :func:`domain_id`) for this process's record session, or raise
    :class:`~nao_skin.errors.ConfigError` naming the session that holds it. When the lock file cannot be
    opened at all (``/tmp`` not writable) the session goes on unclaimed: the returned claim's ``problem``
    says why, for the caller to say. ``spelling``: how the refusal says to start the session elsewhere, as its
    user started it (``command``: nao-skin record, ``launch``: record.launch.py)."""
    domain = domain_id() if domain is None else domain
    path = lock_path(domain, lock_dir, namespace)
    where = f"ROS_DOMAIN_ID {domain}" + (f" in namespace {namespace}" if namespace != "/" else "")
    try:
        fd = _open(path)
    except OSError as exc:
        return DomainClaim(path, domain, None, f"cannot claim {where} ({path}: {os_reason(exc)}):"
                                               f" a second session there would not be refused")
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = _holder(fd)
        start = "ros2 launch nao_skin record.launch.py" if spelling == "launch" else "nao-skin record"
        os.close(fd)
        raise ConfigError(
            f"another nao-skin session{f' (pid {holder})' if holder else ''} runs on {where} on"
            f" this machine: the two would record each other's touches; stop it first, or give each robot its own"
            f" domain (e.g. ROS_DOMAIN_ID={_free_neighbour(domain, lock_dir)} {start} ...) or namespace"
            f" ({start} {'namespace:=' if spelling == 'launch' else '--namespace '}/nao2)") from None
    try:                              # the pid, for the line another session is refused with
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    except OSError:                   # another user's file, read only to us: the flock alone is the claim
        pass
    return DomainClaim(path, domain, fd)


def _open(path: Path) -> int:
    """The lock file's descriptor, the file made if need be, writable by every user (sticky /tmp keeps it
    from being removed by others; the next session, whoever runs it, writes its pid there)."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o666)
    except PermissionError:           # another user's file that is not writable to us: flock needs no write
        # non-blocking: a FIFO planted there (/tmp is everybody's) would wait for a writer for ever
        return os.open(path, os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW | os.O_NONBLOCK)
    try:
        if os.fstat(fd).st_uid == os.getuid():
            os.fchmod(fd, 0o666)      # the umask took write access from the others
    except OSError:
        pass
    return fd


def _holder(fd: int) -> int | None:
    try:
        text = os.pread(fd, 32, 0).decode("ascii").strip()
    except (OSError, UnicodeDecodeError):
        return None
    return int(text) if text.isdigit() else None


def _free_neighbour(domain: int, lock_dir: Path | None) -> int:
    """A domain near ``domain`` that no running session holds (a suggestion in the refusal)."""
    for other in list(range(domain + 1, DOMAIN_IDS.stop)) + list(range(DOMAIN_IDS.start, domain)):
        try:
            fd = os.open(lock_path(other, lock_dir), os.O_RDONLY | os.O_CLOEXEC | os.O_NOFOLLOW | os.O_NONBLOCK)
        except OSError:               # no session ever claimed it here
            return other
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            return other
        except BlockingIOError:
            continue
        finally:
            os.close(fd)
    return domain
