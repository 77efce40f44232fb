"""One exception type whose message is a single line naming the input at fault."""
from __future__ import annotations

import os
import signal
import unicodedata
from collections.abc import Callable


class NaoSkinError(ValueError):
    """Bad input: the message is one line that names the file/touch/field and the problem."""

    def __init__(self, message: str):
        super().__init__(printable(" ".join(str(message).split())))


def printable(text: str) -> str:
    """``text`` with its control characters (an escape sequence in a file name, a byte that is not UTF-8)
    written as Python writes them in a string literal, so that a line naming an input shows that input
    and cannot move the cursor, recolour or clear the terminal it is read on."""
    return "".join(ch.encode("unicode_escape", "backslashreplace").decode("ascii")
                   if unicodedata.category(ch) in ("Cc", "Cs") else ch for ch in text)


class ConfigError(NaoSkinError):
    """A robot, skin or calibration configuration file is wrong."""


class DataError(NaoSkinError):
    """A recording, taxel file or message is wrong."""


class OutputError(NaoSkinError):
    """An output cannot be written (a full disk, no permission, a folder gone): what was written before stays."""


class OutputTaken(OutputError):
    """The place an output was to take was taken meanwhile (another process wrote there): it stays as it is."""


class DiskFull(OutputError):
    """The disk, a quota or a file size limit is full: with space freed the same output goes on."""


class BagMoved(OutputError):
    """A live bag's directory was removed, moved or replaced while it was written; the message says where
    its touches are now."""


class TooFewTouches(DataError):
    """The touches cannot determine what is asked yet: more touches will (a live update waits for them)."""


def os_reason(exc: OSError) -> str:
    """An OSError's reason without its errno and file name, e.g. 'No space left on device'."""
    return exc.strerror or str(exc) or type(exc).__name__


def one_line(exc: BaseException, limit: int = 300) -> str:
    """Any exception as one line for a report or a log: its type and message, whitespace collapsed."""
    return " ".join(f"{type(exc).__name__}: {exc}".split())[:limit]


def end_at_once_on_ctrl_c(prog: str):
    """Until the program installs its own SIGINT handling, a Ctrl-C ends the process at once with one line
    (``<prog>: interrupted while starting``) and exit code 130. Returns the handler to put back once
    started: the one it replaced, or, when it replaces its own (a console script installs it before
    importing the module whose ``main`` installs it again), the one that was there before the first.

    Starting means importing rclpy, numpy and scipy, a second or more. Python's own KeyboardInterrupt
    would surface there as a traceback from inside an import, or, inside a C extension's, as an
    ImportError around it. Nothing is held yet, so nothing is lost; ``os._exit``, because even a
    SystemExit would surface inside the import.
    """
    line = f"{prog}: interrupted while starting\n".encode()

    def interrupted(signum, frame):      # noqa: ARG001 - signal handler signature
        os.write(2, line)
        os._exit(130)

    previous = signal.getsignal(signal.SIGINT)
    interrupted.started_handler = getattr(previous, "started_handler", previous)
    signal.signal(signal.SIGINT, interrupted)
    return interrupted.started_handler


class InterruptOnce:
    """The SIGINT handler of a program run as its own process, which its own stop handling puts back once
    started: the first Ctrl-C raises KeyboardInterrupt where the program is, so its ``except`` and
    ``finally`` clauses remove what is half written; a later one is ignored, so it cannot break into that
    clean-up or into the line saying so; and none raises once :meth:`finish` is called. Python's own
    handler raises at every Ctrl-C, also between the program's return and the end of the process, where
    nothing catches it (a traceback)."""

    def __init__(self):
        self.armed = True

    def __call__(self, signum, frame):      # noqa: ARG002 - signal handler signature
        if self.armed:
            self.armed = False
            raise KeyboardInterrupt

    def finish(self) -> None:
        self.armed = False


def run_program(prog: str, main: Callable[[], int]) -> int:
    """``main()``'s exit code, run as the whole process: Ctrl-C ends it at once while it starts
    (:func:`end_at_once_on_ctrl_c`, until ``main`` puts back the handler that returns), then raises once
    (:class:`InterruptOnce`); the stop signals are ignored once it returns. A stop its own handling did not
    catch (it came before the program started its own, or as it returned, its outputs written) is one line."""
    interrupt = InterruptOnce()
    signal.signal(signal.SIGINT, interrupt)
    end_at_once_on_ctrl_c(prog)
    try:
        code = main()
        interrupt.finish()
    except Terminated as exc:
        interrupt.finish()
        os.write(2, f"{prog}: terminated ({signal.Signals(exc.signum).name})\n".encode())
        code = 128 + exc.signum
    except KeyboardInterrupt:     # it disarmed itself raising this: no second one comes
        os.write(2, f"{prog}: interrupted\n".encode())
        code = 130
    ignore_stop_signals()
    return code


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, a session manager, a CI timeout) or SIGHUP (the terminal closed) raised where the
    program is, as a Ctrl-C is: the same ``except KeyboardInterrupt`` and ``finally`` clauses remove what is
    half written and keep what was there before. Python's default for either ends the process without
    running them. ``signum``: which one."""

    def __init__(self, signum: int = signal.SIGTERM):
        super().__init__(signum)
        self.signum = signum


TERMINATING = tuple(getattr(signal, s) for s in ("SIGTERM", "SIGHUP") if hasattr(signal, s))
# what stops a command, record or a node: Ctrl-C, kill, the terminal closed
STOP_SIGNALS = (signal.SIGINT, *TERMINATING)


def stop_on_term_or_hangup() -> dict:
    """Make SIGTERM and SIGHUP raise :class:`Terminated` in the main thread; returns ``{signal: the handler it
    replaced}``."""

    def terminated(signum, frame):      # noqa: ARG001 - signal handler signature
        raise Terminated(signum)

    return {s: signal.signal(s, terminated) for s in TERMINATING}


def ignore_stop_signals() -> None:
    """The program's work is done and written: a stop signal has nothing left to stop. Ignored, not left
    to Python: CPython's exit puts every handler it installed back to the default before the process
    ends, and a Ctrl-C or ``kill`` arriving then ended it by the signal (exit -2 or -15, no line), which
    a caller counts as interrupted (and output still buffered was lost)."""
    for s in STOP_SIGNALS:
        signal.signal(s, signal.SIG_IGN)
