"""The nodes of a session as child processes: started so that they never outlive the command that started them,
stopped so that the recorder closes its bag (``nao-skin record``, ``nao-skin bench-live``)."""
from __future__ import annotations

import os
import signal
import subprocess
import time
from typing import Callable

PR_SET_PDEATHSIG = 1           # linux/prctl.h


def die_with_parent(parent_pid: int):
    """``preexec_fn`` for a child: the kernel sends it SIGTERM when this process ends (Linux), or None.

    The parent-death signal fires when the thread that forked the child exits;
    children are started from the main thread, which lives as long as the command.
    """
    import ctypes

    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None                    # not Linux: the nodes' own parent watch stops them
    prctl.argtypes = [ctypes.c_int, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong, ctypes.c_ulong]
    prctl.restype = ctypes.c_int

    def preexec() -> None:
        prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        if os.getppid() != parent_pid:     # the parent died before the prctl: that signal will never come
            os.kill(os.getpid(), signal.SIGTERM)

    return preexec


def stop_all(procs, say: Callable[[str], None], timeout: float = 20.0) -> dict:
    """SIGTERM every child ``(name, Popen)`` (the recorder closes its bag), wait, then SIGKILL what is left;
    ``{name: exit code}``.

    A node stops on SIGTERM as on SIGINT once it runs; one still starting up
    (importing, no handler yet) ends by SIGTERM's default action, quietly and
    before it held any data: that counts as stopped (code 0), unlike a
    KeyboardInterrupt traceback in the middle of an import.
    """
    for _, p in procs:
        if p.poll() is None:
            try:
                os.killpg(p.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
    deadline = time.monotonic() + timeout
    codes = {}
    for name, p in procs:
        try:
            code = p.wait(timeout=max(0.1, deadline - time.monotonic()))
            codes[name] = 0 if code == -signal.SIGTERM else code
        except subprocess.TimeoutExpired:
            say(f"{name} did not stop after SIGTERM; killed")
            os.killpg(p.pid, signal.SIGKILL)
            codes[name] = p.wait()
    return codes
