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
import pkgutil
import signal
import sys
import time

from nao_skin import commands
from nao_skin.errors import NaoSkinError, end_at_once_on_ctrl_c, os_reason


class _Parser(argparse.ArgumentParser):
    """argparse, but a mistake on the command line is one line (and exit 2), as every other mistake."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


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
        args = parser.parse_args(argv)
    except SystemExit as exc:            # --help, or a mistake already said in one line
        return int(exc.code or 0)
    finally:
        signal.signal(signal.SIGINT, previous)          # a command stops on KeyboardInterrupt
    args.started = started
    func = getattr(args, "func", None)
    if func is None:
        parser.print_help()
        return 0 if args.command is None else 2
    try:
        return int(func(args) or 0)
    except NaoSkinError as exc:
        print(f"nao-skin {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"nao-skin {args.command}: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:     # the machine, not the input (a full disk, a permission): outputs are written
        # whole or not at all, earlier ones stay; a failed write to an open stream (standard output
        # redirected to a full disk, a closed pipe) carries no file name: every named output says its own
        where = f"{exc.filename}: {os_reason(exc)}" if exc.filename else f"cannot write the output ({os_reason(exc)})"
        print(f"nao-skin {args.command}: error: {where}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
