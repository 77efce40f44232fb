"""Command line entry point: ``nao-skin <command> ...``.

Each module in :mod:`nao_skin.commands` is one command: it defines ``NAME``,
``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``. Modules are
found at start-up, so adding a command never edits this file. Errors of bad
input (:class:`nao_skin.errors.NaoSkinError`) end the command with their one
line on stderr and exit code 2.
"""
from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import signal
import sys
import time

from nao_skin import commands
from nao_skin.errors import (NaoSkinError, Terminated, end_at_once_on_ctrl_c, os_reason, printable, run_program,
                             stop_on_term_or_hangup)


class _StoreOnce(argparse.Action):
    """argparse's ``store``, but an option given twice is a mistake (the last would win unseen: two
    ``--out`` write one of them) and so is an empty value (a path of ``""`` would be read as not given,
    or as the current directory)."""

    GIVEN = "_options_given"     # kept on the namespace while parsing, removed by :func:`main`

    def __call__(self, parser, namespace, values, option_string=None):
        name = option_string or self.metavar or self.dest
        for value in values if isinstance(values, list) else [values]:
            if isinstance(value, str) and not value.strip():
                parser.error(f"argument {name}: an empty value" + ("; give one, or leave the option out for its"
                                                                   " default" if option_string and not self.required
                                                                   else "; give one" if option_string else ""))
        if option_string is not None:
            given = namespace.__dict__.setdefault(self.GIVEN, {})
            if self.dest in given:
                parser.error(f"argument {option_string}: given twice ({given[self.dest]}"
                             f" {_shown(getattr(namespace, self.dest))} and {option_string} {_shown(values)});"
                             f" give it once")
            given[self.dest] = option_string
        setattr(namespace, self.dest, values)


def _shown(value) -> str:
    return " ".join(map(str, value)) if isinstance(value, list) else str(value)


class _Parser(argparse.ArgumentParser):
    """argparse, but a mistake on the command line is one line (and exit 2), as every other mistake."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.register("action", None, _StoreOnce)
        self.register("action", "store", _StoreOnce)

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {printable(message)} (see {self.prog} --help)\n")

    def _print_message(self, message, file=None):
        # argparse drops a failed write, so help on a full disk would print nothing and exit 0. Standard
        # output's failure is said (on standard error); standard error's has nowhere to be said.
        if message and file is sys.stdout:
            file.write(message)
            file.flush()
        else:
            super()._print_message(message, file)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="nao-skin", description="Self-touch calibration of the Nao's artificial skin.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(func=module.run)
    return parser


def main(argv=None) -> int:
    started = time.perf_counter()
    previous = end_at_once_on_ctrl_c("nao-skin")     # while the commands' modules import
    try:
        parser = build_parser()
        args, extra = parser.parse_known_args(argv)
    except SystemExit as exc:            # --help, or a mistake already said in one line
        return int(exc.code or 0)
    except OSError as exc:               # the help text not written (_Parser._print_message)
        print(f"nao-skin: error: cannot write to standard output ({os_reason(exc)})", file=sys.stderr)
        # what it still buffers fails again at Python's own flush at exit, with a second message
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - until exit
        return 2
    finally:
        signal.signal(signal.SIGINT, previous)          # a command stops on KeyboardInterrupt
    vars(args).pop(_StoreOnce.GIVEN, None)
    if extra:    # said by the command's own parser, whose help lists what it takes
        prog = f"nao-skin {args.command}" if args.command else "nao-skin"
        extra = printable(" ".join(extra))
        print(f"{prog}: error: unrecognized arguments: {extra} (see {prog} --help)", file=sys.stderr)
        return 2
    args.started = started
    func = getattr(args, "func", None)
    if func is None:     # no command is a usage mistake, said as argparse says its own
        parser.print_usage(sys.stderr)
        print("nao-skin: error: a command is required (nao-skin --help lists them)", file=sys.stderr)
        return 2
    if sys.stdout is None:      # started with it closed (>&-): what a command prints would be lost unseen
        print(f"nao-skin {args.command}: error: standard output is closed; redirect it (e.g. > /dev/null)",
              file=sys.stderr)
        return 2
    previous_term = stop_on_term_or_hangup()   # as a Ctrl-C does: its outputs whole or not at all
    stdout = sys.stdout = _WatchedStream(sys.stdout)
    try:
        return int(func(args) or 0)
    except NaoSkinError as exc:
        print(f"nao-skin {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except Terminated as exc:
        print(f"nao-skin {args.command}: terminated ({signal.Signals(exc.signum).name})", file=sys.stderr)
        return 128 + exc.signum
    except KeyboardInterrupt:
        print(f"nao-skin {args.command}: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:     # the machine, not the input (a full disk, a permission): outputs are written
        # whole or not at all, earlier ones stay; a failed write to an open stream carries no file name
        if exc.filename:
            where = f"{exc.filename}: {os_reason(exc)}"
        elif stdout.failed:
            where = f"cannot write to standard output ({os_reason(exc)})"
        elif not _cwd_exists():   # a relative path cannot be resolved: the error names no file
            where = ("the current directory no longer exists (removed while this shell was in it); cd to one"
                     " that does, or give absolute paths")
        else:
            where = f"cannot write the output ({os_reason(exc)})"
        print(f"nao-skin {args.command}: error: {printable(where)}", file=sys.stderr)
        return 2
    finally:
        for signum, handler in previous_term.items():
            signal.signal(signum, handler)
        # a stream that failed once fails again at Python's own flush at exit, with a second message
        sys.stdout = open(os.devnull, "w") if stdout.failed else stdout.stream  # noqa: SIM115 - until exit


def _cwd_exists() -> bool:
    try:
        os.getcwd()
    except FileNotFoundError:
        return False
    return True


class _WatchedStream:
    """Standard output, remembering whether a write to it failed: such an OSError names no file, and the
    line should say it was standard output (redirected to a full disk, a pipe closed early)."""

    def __init__(self, stream):
        self.stream = stream
        self.failed = False

    def write(self, text):
        try:
            return self.stream.write(text)
        except OSError:
            self.failed = True
            raise

    def flush(self):
        try:
            return self.stream.flush()
        except OSError:
            self.failed = True
            raise

    def __getattr__(self, name):
        return getattr(self.stream, name)


def console() -> int:
    """``nao-skin`` as its own process (``python -m nao_skin.cli``; the console script is
    :func:`nao_skin.entry.nao_skin`): :func:`main`, then a Ctrl-C while Python exits leaves the command's
    exit code as it is."""
    return run_program("nao-skin", main)


if __name__ == "__main__":
    sys.exit(console())
