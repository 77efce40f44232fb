"""Worker processes of the benchmarks: no more than there is work for, and stopped with their parent."""
from __future__ import annotations

import signal
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager

from nao_skin.errors import NaoSkinError

MAX_JOBS = 64       # worker processes a benchmark may be asked for (each holds a copy of the skin and the data)


def _parent_stops_me() -> None:
    """In a worker: a Ctrl-C (sent to the terminal's whole process group) is the parent's to handle, which
    kills the workers (below); each worker would otherwise print a traceback of its own."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextmanager
def worker_pool(jobs: int, tasks: int):
    """A process pool of ``min(jobs, tasks)`` workers. If the parent stops (Ctrl-C, SIGTERM, an error) the
    workers are killed rather than waited for: a case can run for minutes."""
    pool = ProcessPoolExecutor(max_workers=max(1, min(jobs, tasks)), initializer=_parent_stops_me)
    try:
        yield pool
    except BrokenProcessPool as exc:   # a worker killed (out of memory, a kill): the run cannot go on
        # waited for: left running, the executor's own thread prints a traceback on a closed pipe at exit
        _kill_workers(pool, wait=True)
        raise NaoSkinError(f"a worker process ended abruptly ({exc.__class__.__name__}: killed, or out of"
                           f" memory?); the benchmark stops, its earlier output is kept") from None
    except BaseException:
        _kill_workers(pool, wait=False)
        raise
    pool.shutdown()


def _kill_workers(pool: ProcessPoolExecutor, wait: bool) -> None:
    # the executor has no way to stop running work; its worker processes are the only handle
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.kill()
    pool.shutdown(wait=wait, cancel_futures=True)
