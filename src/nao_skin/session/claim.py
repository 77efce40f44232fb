"""One record session per ROS domain on this machine.

Two sessions on one ``ROS_DOMAIN_ID`` hear each other: each recorder takes
the other robot's skin and joint states for its own, each calibrate node
answers the other's requests, and both bags mix the two robots beyond
repair. So ``nao-skin record`` and ``record.launch.py`` claim the domain
before any node starts: a lock file names the claiming process
(:func:`~nao_skin.formats.salvage.lock_text`), and while that process runs
another session on the domain is refused in one line. The lock of a session
that was killed names a process that is gone: the next session takes it
over. The files live in ``/tmp`` whatever ``TMPDIR`` says, so that every
shell of the machine sees them. Sessions on two machines share a domain
only with ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``; there the recorder says
when a second publisher feeds one of its skin topics.
"""
from __future__ import annotations

import os
from pathlib import Path

from nao_skin.errors import ConfigError
from nao_skin.formats.salvage import lock_text, read_lock

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


class DomainClaim:
    """This process's claim on a ROS domain (:func:`claim_domain`); :meth:`release` gives it up."""

    def __init__(self, path: Path, domain: int):
        self.path, self.domain = path, domain

    def release(self) -> None:
        """Remove the lock if it still names this process (never another session's)."""
        lock = read_lock(self.path) if self.path.exists() else None
        if lock is not None and lock.pid == os.getpid():
            self.path.unlink(missing_ok=True)


def claim_domain(domain: int | None = None, lock_dir: Path | None = None) -> DomainClaim:
    """Claim ``domain`` (default :func:`domain_id`) for this process's record session, or raise
    :class:`~nao_skin.errors.ConfigError` naming the session that holds it. ``lock_dir``: :data:`LOCK_DIR`."""
    domain = domain_id() if domain is None else domain
    lock_dir = LOCK_DIR if lock_dir is None else lock_dir
    path = Path(lock_dir) / f"nao_skin_ros_domain_{domain}.lock"
    mine = path.with_name(f".{path.name}.{os.getpid()}")
    try:
        mine.write_text(lock_text())
        try:
            os.link(mine, path)          # atomic: exactly one of two sessions starting at once gets it
        except FileExistsError:
            held = read_lock(path)
            if held.state == "open" and held.pid != os.getpid():
                raise ConfigError(
                    f"another nao-skin session (pid {held.pid}) runs on ROS_DOMAIN_ID {domain} on this machine:"
                    f" the two would record each other's touches; stop it first, or give each robot its own"
                    f" domain (e.g. ROS_DOMAIN_ID={_free_neighbour(domain, lock_dir)} nao-skin record ...)") from None
            os.replace(mine, path)       # its session is gone (killed): its lock is taken over
    except OSError as exc:
        raise ConfigError(f"cannot claim ROS_DOMAIN_ID {domain} for this session: {path}: "
                          f"{exc.strerror or exc}") from None
    finally:
        mine.unlink(missing_ok=True)
    held = read_lock(path)               # two sessions taking over one stale lock at once: the last one has it
    if held.pid != os.getpid():
        raise ConfigError(f"another nao-skin session (pid {held.pid}) claimed ROS_DOMAIN_ID {domain} on this"
                          f" machine just now; stop it first, or give each robot its own domain")
    return DomainClaim(path, domain)


def _free_neighbour(domain: int, lock_dir: Path) -> int:
    """A domain near ``domain`` that no running session holds (a suggestion in the refusal)."""
    for other in list(range(domain + 1, DOMAIN_IDS.stop)) + list(range(DOMAIN_IDS.start, domain)):
        path = Path(lock_dir) / f"nao_skin_ros_domain_{other}.lock"
        if not path.exists() or read_lock(path).state != "open":
            return other
    return domain
