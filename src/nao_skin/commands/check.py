"""``nao-skin check INPUT... --calibration CAL``: does a calibration still fit the skin?"""
from __future__ import annotations

import json
import shlex
import sys

from nao_skin.commands import add_skin_arguments, skin_from_args, wall_seconds

NAME = "check"
HELP = ("judge a calibration by a new recording: which skin parts still fit it and which have moved"
        " (exit 0: every part checked fits, 1: a part moved, 2: bad input)")

MAX_TOLERANCE_MM = 50.0     # beyond, no part of a Nao's skin could be said to have moved


def add_arguments(parser) -> None:
    from nao_skin.calibration.check import DEFAULT_TOLERANCE_MM
    from nao_skin.calibration.options import OPTION_FIELDS

    parser.add_argument("inputs", nargs="+", metavar="INPUT",
                        help="new touches: rosbag2 recordings, simulator output folders or legacy .txt data sets")
    parser.add_argument("--calibration", required=True, help="the calibration.yaml to judge")
    parser.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE_MM, metavar="MM",
                        help="a part has moved when a refit from the new touches carries its taxels at least this"
                             f" far (median, mm) and brings its held-out touches closer (default {DEFAULT_TOLERANCE_MM:g})")
    high = 1000.0 * OPTION_FIELDS["fabric_bounds"].default[1]
    parser.add_argument("--fabric", type=float, default=None, metavar="MM",
                        help=f"fabric thickness to measure at, 0 to {high:g} mm (default: the one that brings the"
                             f" new training touches closest under the calibration)")
    parser.add_argument("--seed", type=int, default=None,
                        help=f"seed of the train/test split of the new touches (default {OPTION_FIELDS['seed'].default})")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    add_skin_arguments(parser)


def run(args) -> int:
    import math

    from nao_skin.calibration.check import check_calibration
    from nao_skin.calibration.options import CalibrationOptions
    from nao_skin.calibration.pipeline import load_inputs
    from nao_skin.errors import DataError
    from nao_skin.formats.inputs import check_inputs
    from nao_skin.model.skin import SkinCalibration
    from nao_skin.plain import jsonable

    if not (math.isfinite(args.tolerance) and 0 < args.tolerance <= MAX_TOLERANCE_MM):
        raise DataError(f"--tolerance {args.tolerance:g}: expected millimetres above 0 and at most"
                        f" {MAX_TOLERANCE_MM:g}")
    options = CalibrationOptions()
    high = 1000.0 * options.fabric_bounds[1]
    if args.fabric is not None and not (math.isfinite(args.fabric) and 0 <= args.fabric <= high):
        raise DataError(f"--fabric {args.fabric:g}: expected millimetres from 0 to {high:g}")
    if args.seed is not None:
        options.set("seed", args.seed, where=f"--seed {args.seed}")
    check_inputs(args.inputs)
    skin = skin_from_args(args)
    calibration = SkinCalibration.load(args.calibration, skin)
    notes = []
    loaded = load_inputs(args.inputs, skin, summary=notes.append)
    try:
        result = check_calibration(loaded.touches, skin, calibration, args.tolerance, args.fabric, options)
    except DataError as exc:     # too few touches to judge anything: the line names the recordings
        raise type(exc)(f"{', '.join(map(str, args.inputs))}: {exc}") from None
    moved = result.moved
    fabric_from = "--fabric" if args.fabric is not None else "estimated"
    if args.json:
        for line in notes:
            print(line, file=sys.stderr)
        print(json.dumps(jsonable({"inputs": [str(p) for p in args.inputs], "calibration": args.calibration,
                                   "touches": loaded.touches.n_touches, "duplicates_removed": loaded.n_duplicates,
                                   "fabric_from": fabric_from, **result.as_dict()})))
        return 1 if moved else 0
    for line in notes:
        print(line)
    fabric = (f"fabric {result.fabric_mm:.2f} mm, " + ("from --fabric" if args.fabric is not None else
                                                       "the one that brings them closest under the calibration"))
    print(f"{args.calibration} against {loaded.touches.n_touches} touches of {', '.join(map(str, args.inputs))}"
          f" ({result.refit.train.n_touches} to refit the mounts from it, {result.refit.test.n_touches} held out;"
          f" {fabric}; {wall_seconds(args):.1f} s)")
    for name, part in result.parts.items():
        print(f"{name}: {part.verdict}: {part.reason}")
    if moved:
        print(f"moved: {', '.join(moved)}. Recalibrate: {_recalibrate(args)}")
        return 1
    print("every part checked fits the calibration")
    return 0


def _recalibrate(args) -> str:
    """The two ways to recalibrate, with the skin this check read (its taxel files, skin and robot config)."""
    q = shlex.quote
    taxels = "".join(f" --taxels {q(item)}" for item in args.taxels or [])
    skin = (f" --skin {q(args.skin)}" if args.skin else "") + (f" --robot {q(args.robot)}" if args.robot else "")
    inputs = " ".join(q(str(p)) for p in args.inputs)
    record = (f"record touches of every pair, starting from the calibration (on the robot: nao-skin record --robot nao"
              f" --calibration {q(args.calibration)}{taxels}")
    record += (", with the skin config naming that robot config)" if args.robot or args.skin else ")")
    return (f"{record}, or calibrate these touches from it (nao-skin calibrate {inputs} --prior {q(args.calibration)}"
            f"{skin}{taxels} --out DIR)")
