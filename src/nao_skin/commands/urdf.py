"""``nao-skin urdf``: the expanded URDF (body + skin frames) for a calibration file."""
from __future__ import annotations

import argparse
from pathlib import Path

from nao_skin.commands import add_skin_arguments, config_files, skin_from_args, write_output

NAME = "urdf"
HELP = "expand urdf/nao_skin.urdf.xacro for a calibration YAML and write the URDF"


def add_arguments(parser) -> None:
    parser.add_argument("--calibration", type=Path, default=None,
                        help="calibration YAML (default: the package's config/calibration_nominal.yaml)")
    # the skin the calibration belongs to, to check it: a calibration made with --taxels is checked
    # against the same layouts (the skin config's own would refuse it)
    add_skin_arguments(parser)
    parser.add_argument("--skin-config", dest="skin", default=None, help=argparse.SUPPRESS)   # --skin's old name
    parser.add_argument("--out", type=Path, default=None, help="output URDF file (default: stdout)")


def run(args) -> int:
    from nao_skin.model.urdf import check_calibration_origins, default_xacro, expand_xacro
    from nao_skin.paths import default_skin_config

    skin_config = args.skin or default_skin_config()
    skin = skin_from_args(args)
    calibration = args.calibration or Path(skin_config).parent / "calibration_nominal.yaml"
    # A bad or hand-edited calibration fails here with one line, not deep inside xacro.
    check_calibration_origins(calibration, skin)
    robot_config = Path(skin.robot.source)
    text = expand_xacro(calibration, robot_config=robot_config if robot_config.is_file() else None)
    # xacro's banner names the file it expanded: what tells an earlier output from somebody's own URDF
    write_output(text, args.out, inputs=[calibration, skin_config, *config_files(skin)], mark=default_xacro().name)
    return 0
