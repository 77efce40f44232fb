"""``nao-skin stats INPUT``: what a touch data set holds and how far apart its touching points are."""
from __future__ import annotations

import json
import sys

from nao_skin.commands import add_skin_arguments, skin_from_args

NAME = "stats"
HELP = ("print touches, exact duplicates, per-part-pair and per-fingertip-scene counts and closest COP / taxel and"
        " fingertip distances of a touch bag or legacy dataset, under the nominal layout or a given calibration")


def add_arguments(parser) -> None:
    parser.add_argument("input", help="touch or stream bag, a simulator output directory, or a legacy dataset text file")
    parser.add_argument("--calibration", default=None, help="calibration YAML (default: nominal layout)")
    parser.add_argument("--parts", default=None, metavar="A,B", help="pair only these two parts, e.g. l_hand,torso")
    parser.add_argument("--fingertip", action="append", default=[], metavar="NAME",
                        help="the fingertip (robot config, e.g. r_finger) whose touches a text input holds (one skin"
                             " part fires per touch)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    add_skin_arguments(parser)


def run(args) -> int:
    import numpy as np

    from nao_skin.calibration.fingertip import fingertip_pairs
    from nao_skin.calibration.pairing import metrics
    from nao_skin.calibration.rows import fingertip_rows, pair_for_metrics
    from nao_skin.calibration.plan import pair_counts, scene_label
    from nao_skin.calibration.rows import concat_pairings
    from nao_skin.formats.inputs import Inputs, check_inputs, load_touches, parse_fingertips
    from nao_skin.model.skin import SkinCalibration, pair_label
    from nao_skin.plain import jsonable
    from nao_skin.touch.datasets import deduplicate

    check_inputs([args.input])
    skin = skin_from_args(args)
    parts = tuple(args.parts.split(",")) if args.parts is not None else None
    # before the touches are read: a typo costs nothing
    if parts is not None and (len(parts) != 2 or parts[0] == parts[1] or any(p not in skin.parts for p in parts)):
        from nao_skin.errors import ConfigError

        raise ConfigError(f"--parts {args.parts!r}: expected two different skin parts A,B of {', '.join(skin.parts)}")
    calib = SkinCalibration.load(args.calibration, skin) if args.calibration else None
    lines = []
    inputs = Inputs((args.input,), parse_fingertips(args.fingertip, [args.input]))
    touches, report, _ = load_touches(inputs, skin, log=lines.append)
    _, n_dup = deduplicate(touches)
    pairs_touching = {pair_label(pair): n for pair, n in pair_counts(touches).items()}
    scenes = {scene_label(*k): n for k, n in fingertip_pairs(touches).items()}
    if parts is not None and pair_label(parts) not in pairs_touching:
        from nao_skin.errors import DataError

        raise DataError(f"{args.input}: no touch of the parts {parts[0]} and {parts[1]} together"
                        f" (pairs touching: {', '.join(pairs_touching) or 'none'})")
    rows = [pair_for_metrics(touches, skin, calib, parts=parts)]
    if parts is None:
        rows += [fingertip_rows(touches, skin, calib, tip, part) for tip, part in fingertip_pairs(touches)]
    m = metrics(concat_pairings(rows))
    out = {"input": str(args.input), "touches": touches.n_touches, "exact_duplicates": n_dup,
           "skipped": dict(report.skipped), "self_touches": int(np.sum(touches.fingertip_of_touch < 0)),
           "fingertip_touches": int(np.sum(touches.fingertip_of_touch >= 0)), "pairs": pairs_touching,
           "fingertip_scenes": scenes,
           "contacts_per_touch": round(len(touches.contact_touch) / max(touches.n_touches, 1), 3),
           "taxels_per_touch": round(len(touches.act_slot) / max(touches.n_touches, 1), 3),
           "calibration": args.calibration or "nominal", **{k: (round(v, 3) if isinstance(v, float) else v)
                                                              for k, v in m.items()}}
    if args.json:           # what loading said goes beside the JSON, not into it
        for line in lines:
            print(line, file=sys.stderr)
        print(json.dumps(jsonable(out)))       # JSON has no NaN: a figure with no touch is null
        return 0
    for line in lines:
        print(line)
    for key, value in out.items():
        print(f"{key}: {value}")
    return 0
