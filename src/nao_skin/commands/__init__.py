"""One module per ``nao-skin`` command (see :mod:`nao_skin.cli`)."""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path


def wall_seconds(args) -> float:
    """Seconds since the command started (``cli.main`` stamps ``args.started``): what a user waited."""
    return time.perf_counter() - getattr(args, "started", time.perf_counter())


def write_output(text: str, out: str | Path | None, inputs=(), mark: tuple = ()) -> None:
    """``text`` to ``out`` (its folder made, its path printed), or to stdout when ``out`` is None.

    ``out`` may be an existing file this command wrote before (e.g. config/calibration_nominal.yaml
    regenerated): one whose first lines hold every text of ``mark``, as ``text``'s do (what this command
    writes and no other: a calibration of ``nao-skin calibrate`` is no nominal calibration). Never one of
    ``inputs``, a directory, a link that leads nowhere, or anybody's own file; it is replaced whole or not
    at all (a temporary sibling renamed over it).
    """
    from nao_skin.errors import DataError
    from nao_skin.formats.outdir import replace_file
    from nao_skin.paths import DANGLING_LINK

    if out is None:
        sys.stdout.write(text)
        return
    if str(out).endswith(("/", os.sep)):
        raise DataError(f"--out {out}: names a directory; give a file name")
    out = Path(out)
    if out.is_dir():
        raise DataError(f"--out {out}: is a directory; give a file name")
    if out.is_symlink() and not out.exists():
        raise DataError(f"--out {out}: is {DANGLING_LINK}; choose another file")
    for item in inputs:
        if item and Path(item).exists() and out.exists() and os.path.samefile(item, out):
            raise DataError(f"--out {out}: is the input {item}; writing there would replace it, choose another file")
    if out.is_file() and not written_here(out, mark):
        raise DataError(f"--out {out}: exists and was not written by this command; nothing is written over"
                        f" somebody's file: choose another name, or remove it first")
    for parent in out.absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise DataError(f"--out {out}: {parent} is a file, not a directory; choose another place")
            break
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        replace_file(out, text)
    except OSError as exc:
        raise DataError(f"--out {out}: cannot write ({exc.strerror}); choose another place") from None
    print(out)


def written_here(path: Path, mark: tuple) -> bool:
    """Whether ``path`` is empty (e.g. made by mktemp) or its first lines hold every text of ``mark``
    (unreadable: not ours)."""
    try:
        with open(path, "rb") as f:
            head = f.read(1024)
    except OSError:
        return False
    return not head or (bool(mark) and all(m.encode() in head for m in mark))


def add_output_arguments(parser, command: str) -> None:
    """``--out`` (default ``out/<command>``) and ``--force`` of a benchmark writing its own output directory."""
    default = f"out/{command.replace('-', '_')}"
    parser.add_argument("--out", default=default,
                        help=f"output directory (default: {default}): new, empty, or an earlier {command} output"
                             f" (with --force)")
    parser.add_argument("--force", action="store_true",
                        help=f"replace the outputs of an earlier {command} in --out (never a file nao-skin did not"
                             f" write)")


def add_skin_arguments(parser) -> None:
    """The options that say which skin layout the data belongs to: the same in every command."""
    parser.add_argument("--skin", default=None, metavar="YAML",
                        help="skin config YAML (default: the package's config/nao_skin.yaml)")
    parser.add_argument("--taxels", action="append", default=[], metavar="PART=FILE",
                        help="skinManager taxel file of a part (e.g. the recording's own, l_hand=l_hand.taxels.txt);"
                             " it replaces that part's layout in the skin config (grouped by the config's patch"
                             " table where that places every triangle of the file, else 16 triangles per patch);"
                             " repeatable")
    parser.add_argument("--robot", default=None, metavar="YAML",
                        help="robot config YAML (default: the one the skin config names, config/nao_h25.yaml)")
    parser.add_argument("--skin-config", dest="skin", default=None, help=argparse.SUPPRESS)   # --skin's old name


def skin_config_file(args) -> Path:
    """The skin config ``--skin`` names, or the package's."""
    from nao_skin.paths import default_skin_config

    return Path(args.skin) if getattr(args, "skin", None) else default_skin_config()


def skin_from_args(args):
    """The skin model of ``--skin``, ``--taxels`` and ``--robot`` (:func:`nao_skin.model.skin.load_skin`)."""
    from nao_skin.model.skin import load_skin, parse_taxel_files

    return load_skin(getattr(args, "skin", None), parse_taxel_files(getattr(args, "taxels", None) or []),
                     getattr(args, "robot", None))
