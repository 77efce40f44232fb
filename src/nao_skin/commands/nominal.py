"""``nao-skin nominal``: the nominal (zero-correction) calibration of a skin config.

The committed ``config/calibration_nominal.yaml`` (the URDF's default skin
frames) is this command's output for ``config/nao_skin.yaml``; a test checks
that it is not stale.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

from nao_skin.commands import add_skin_arguments, skin_config_file, skin_from_args, write_output

NAME = "nominal"
HELP = "write the nominal (zero-correction) calibration YAML of a skin config"


REGENERATE = "regenerate with: nao-skin nominal"


def add_arguments(parser) -> None:
    add_skin_arguments(parser)
    parser.add_argument("--out", default=None,
                        help="output calibration YAML (default: stdout)")


def nominal_calibration_text(skin, skin_config: Path) -> str:
    """The YAML text ``SkinCalibration.save`` writes for zero corrections of every part of ``skin`` (read from
    ``skin_config``)."""
    # The comment names the config by file name only, so the text does not depend on the checkout's path.
    comment = f"nominal calibration (all corrections zero) of {Path(skin_config).name}; {REGENERATE} --out <this file>"
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "calibration.yaml"
        skin.zero_calibration().save(path, skin, comment=comment)
        return path.read_text()


def run(args) -> int:
    from nao_skin.model.skin import CALIBRATION_HEADER

    skin_config = skin_config_file(args)
    skin = skin_from_args(args)
    # what this command writes and no other: a calibration from touches holds the same header
    write_output(nominal_calibration_text(skin, skin_config), args.out,
                 inputs=[skin_config, *skin.source_files()], mark=(CALIBRATION_HEADER, REGENERATE))
    return 0
