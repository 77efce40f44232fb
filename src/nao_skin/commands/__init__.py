"""One module per ``nao-skin`` command (see :mod:`nao_skin.cli`)."""
from __future__ import annotations

import sys
import time
from pathlib import Path


def wall_seconds(args) -> float:
    """Seconds since the command started (``cli.main`` stamps ``args.started``): what a user waited."""
    return time.perf_counter() - getattr(args, "started", time.perf_counter())


def write_output(text: str, out: Path | None) -> None:
    """``text`` to ``out`` (its folder made, its path printed), or to stdout when ``out`` is None."""
    if out is None:
        sys.stdout.write(text)
        return
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(out)


def add_skin_arguments(parser) -> None:
    """The options that say which skin layout the data belongs to: the same in every command."""
    parser.add_argument("--skin", default=None, metavar="YAML",
                        help="skin config YAML (default: the package's config/nao_skin.yaml)")
    parser.add_argument("--taxels", action="append", default=[], metavar="PART=FILE",
                        help="skinManager taxel file of a part (e.g. the recording's own, l_hand=l_hand.taxels.txt);"
                             " it replaces that part's layout in the skin config; repeatable")
    parser.add_argument("--robot", default=None, metavar="YAML",
                        help="robot config YAML (default: the one the skin config names, config/nao_h25.yaml)")


def skin_from_args(args):
    """The skin model of ``--skin``, ``--taxels`` and ``--robot`` (:func:`nao_skin.model.skin.load_skin`)."""
    from nao_skin.model.skin import load_skin, parse_taxel_files

    return load_skin(getattr(args, "skin", None), parse_taxel_files(getattr(args, "taxels", None) or []),
                     getattr(args, "robot", None))
