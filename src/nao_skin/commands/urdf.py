"""``nao-skin urdf``: the expanded URDF (body + skin frames) for a calibration file."""
from __future__ import annotations

from pathlib import Path

from nao_skin.commands import config_files, write_output

NAME = "urdf"
HELP = "expand urdf/nao_skin.urdf.xacro for a calibration YAML and write the URDF"


def add_arguments(parser) -> None:
    parser.add_argument("--calibration", type=Path, default=None,
                        help="calibration YAML (default: the package's config/calibration_nominal.yaml)")
    parser.add_argument("--skin-config", type=Path, default=None,
                        help="skin config the calibration belongs to, used to check it"
                             " (default: the package's config/nao_skin.yaml)")
    parser.add_argument("--out", type=Path, default=None, help="output URDF file (default: stdout)")


def run(args) -> int:
    from nao_skin.model.skin import SkinModel
    from nao_skin.model.urdf import check_calibration_origins, expand_xacro
    from nao_skin.paths import default_skin_config

    skin_config = args.skin_config or default_skin_config()
    skin = SkinModel.from_yaml(skin_config)
    calibration = args.calibration or Path(skin_config).parent / "calibration_nominal.yaml"
    # A bad or hand-edited calibration fails here with one line, not deep inside xacro.
    check_calibration_origins(calibration, skin)
    robot_config = Path(skin.robot.source)
    text = expand_xacro(calibration, robot_config=robot_config if robot_config.is_file() else None)
    write_output(text, args.out, inputs=[calibration, skin_config, *config_files(skin)])
    return 0
