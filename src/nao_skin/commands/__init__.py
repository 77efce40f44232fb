"""One module per ``nao-skin`` command (see :mod:`nao_skin.cli`)."""
from __future__ import annotations

import sys
from pathlib import Path


def write_output(text: str, out: Path | None) -> None:
    """``text`` to ``out`` (its folder made, its path printed), or to stdout when ``out`` is None."""
    if out is None:
        sys.stdout.write(text)
        return
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(out)
