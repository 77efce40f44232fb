"""``nao-skin import LEGACY -o BAG --taxels l_hand=FILE --taxels torso=FILE``: a thesis dataset to a touch bag."""
from __future__ import annotations

from pathlib import Path

NAME = "import"
HELP = "convert a legacy self-touch dataset (thesis dict-literal text) plus the parts' taxel files into a touch bag"


def add_skin_arguments(parser) -> None:
    """Options that say which skin layout the data belongs to (shared with ``stats``)."""
    parser.add_argument("--taxels", action="append", default=[], metavar="PART=FILE",
                        help="taxel file of a skin part (skinManager part name, e.g. l_hand=positions/left_hand.txt);"
                             " repeat per part. Without it the skin config is used")
    parser.add_argument("--skin", default=None, help="skin config YAML (default: the packaged config/nao_skin.yaml)")
    parser.add_argument("--robot", default=None, help="robot config YAML for --taxels (default: config/nao_h25.yaml)")


def skin_from_args(args):
    """The SkinModel named by ``--taxels`` (with ``--robot``) or ``--skin``."""
    from ..config import config_dir, default_skin_config
    from ..errors import ConfigError
    from ..legacy import skin_model_for
    from ..robot import RobotModel
    from ..skin import SkinModel

    if not args.taxels:
        return SkinModel.from_yaml(args.skin or default_skin_config())
    files = {}
    for item in args.taxels:
        part, sep, path = item.partition("=")
        if not sep or not part or not path:
            raise ConfigError(f"--taxels {item!r}: expected PART=FILE, e.g. l_hand=l_hand.taxels.txt")
        files[part] = Path(path)
    robot = RobotModel.from_yaml(args.robot or config_dir() / "nao_h25.yaml")
    return skin_model_for(files, robot)


def add_arguments(parser) -> None:
    parser.add_argument("legacy", help="legacy dataset file: one Python dict literal {key: [skinContacts, joints]}")
    parser.add_argument("-o", "--output", required=True, help="bag directory to create (never overwritten)")
    parser.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3", help="rosbag2 storage plugin")
    parser.add_argument("--dedup", action="store_true", help="drop exact duplicate touches before writing")
    add_skin_arguments(parser)


def run(args) -> int:
    from ..bagio import write_touch_bag
    from ..datasets import deduplicate
    from ..errors import DataError
    from ..legacy import read_legacy

    skin = skin_from_args(args)
    touches, report = read_legacy(args.legacy, skin)
    for line in report.lines():
        print(line)
    if touches.n_touches == 0:
        raise DataError(f"{args.legacy}: no usable touch, nothing written")
    if args.dedup:
        touches, removed = deduplicate(touches)
        print(f"exact duplicates removed: {removed}")
    write_touch_bag(args.output, touches, skin, storage=args.storage)
    print(f"wrote {touches.n_touches} touches to {args.output} ({args.storage})")
    return 0
