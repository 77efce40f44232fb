"""``nao-skin import LEGACY -o BAG --taxels l_hand=FILE --taxels torso=FILE``: a thesis dataset to a touch bag."""
from __future__ import annotations

import sys

from nao_skin.commands import add_skin_arguments, skin_from_args

NAME = "import"
HELP = "convert a legacy self-touch dataset (thesis dict-literal text) plus the parts' taxel files into a touch bag"


def add_arguments(parser) -> None:
    parser.add_argument("legacy", help="legacy dataset file (the thesis' text format: one dict literal"
                                       " {key: [skinContacts, joints]})")
    parser.add_argument("-o", "--output", required=True, help="bag directory to create (never overwritten)")
    parser.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3", help="rosbag2 storage plugin")
    parser.add_argument("--dedup", action="store_true", help="drop exact duplicate touches before writing")
    add_skin_arguments(parser)


def run(args) -> int:
    from nao_skin.errors import DataError
    from nao_skin.formats.bag import write_touch_bag
    from nao_skin.formats.inputs import check_inputs, layout_hints
    from nao_skin.formats.legacy import read_legacy
    from nao_skin.touch.datasets import deduplicate

    check_inputs([args.legacy])
    skin = skin_from_args(args)
    touches, report = read_legacy(args.legacy, skin)
    lines = report.lines()
    for line in lines if touches.n_touches else lines[1:]:     # else the error below carries the summary
        print(line)
    for hint in layout_hints(touches, report, skin):     # e.g. the recording's own taxel files to pass
        print(hint, file=sys.stderr)
    if touches.n_touches == 0:
        raise DataError(f"{args.legacy}: no usable touch, nothing written ({report.summary()})")
    if args.dedup:
        touches, removed = deduplicate(touches)
        print(f"exact duplicates removed: {removed}")
    write_touch_bag(args.output, touches, skin, storage=args.storage, source=args.legacy)
    print(f"wrote {touches.n_touches} touches to {args.output} ({args.storage})")
    return 0
