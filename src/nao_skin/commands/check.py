"""``nao-skin check RECORDING... --calibration CAL``: does a calibration still fit the skin?"""
from __future__ import annotations

import json
import shlex
import sys

from nao_skin.commands import add_skin_arguments, skin_from_args, wall_seconds

NAME = "check"
HELP = ("judge a calibration by a new recording: which skin parts still fit it and which have moved"
        " (exit 0: all fit, 1: a part moved, 2: bad input)")

MAX_TOLERANCE_MM = 50.0     # beyond, no part of a Nao's skin could be said to have moved


def add_arguments(parser) -> None:
    from nao_skin.calibration.check import DEFAULT_TOLERANCE_MM

    parser.add_argument("inputs", nargs="+", metavar="RECORDING",
                        help="new touches: rosbag2 recordings, simulator output folders or legacy .txt data sets")
    parser.add_argument("--calibration", required=True, help="the calibration.yaml to judge")
    parser.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE_MM, metavar="MM",
                        help="a part has moved when a refit from the new touches carries its taxels at least this"
                             f" far (median, mm) and brings its held-out touches closer (default {DEFAULT_TOLERANCE_MM:g})")
    parser.add_argument("--fabric", type=float, default=None, metavar="MM",
                        help="fabric thickness the calibration was made with (default: fabric_thickness_mm of the"
                             " report.json beside it, else the calibration option's)")
    parser.add_argument("--seed", type=int, default=None,
                        help="seed of the train/test split of the new touches (default: the calibration option's)")
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
    if args.seed is not None:
        options.set("seed", args.seed, where=f"--seed {args.seed}")
    if args.fabric is not None:
        options.set("fabric_thickness", args.fabric / 1000.0, where=f"--fabric {args.fabric:g}")
    check_inputs(args.inputs)
    skin = skin_from_args(args)
    calibration = SkinCalibration.load(args.calibration, skin)
    fabric_mm, fabric_from = _fabric(args, options)
    notes = []
    loaded = load_inputs(args.inputs, skin, summary=notes.append)
    try:
        result = check_calibration(loaded.touches, skin, calibration, args.tolerance, fabric_mm, options)
    except DataError as exc:     # too few touches to judge anything: the line names the recordings
        raise type(exc)(f"{', '.join(map(str, args.inputs))}: {exc}") from None
    moved = result.moved
    if args.json:
        for line in notes:
            print(line, file=sys.stderr)
        print(json.dumps(jsonable({"inputs": [str(p) for p in args.inputs], "calibration": args.calibration,
                                   "touches": loaded.touches.n_touches, "fabric_from": fabric_from,
                                   **result.as_dict()})))
        return 1 if moved else 0
    for line in notes:
        print(line)
    print(f"{args.calibration} against {loaded.touches.n_touches} touches of {', '.join(map(str, args.inputs))}"
          f" ({result.refit.train.n_touches} to refit the mounts from it, {result.refit.test.n_touches} held out;"
          f" {wall_seconds(args):.1f} s); fabric {fabric_mm:.2f} mm, {fabric_from}")
    for name, part in result.parts.items():
        print(f"{name}: {part.verdict}: {part.reason}")
    if moved:
        inputs = " ".join(shlex.quote(str(p)) for p in args.inputs)
        print(f"moved: {', '.join(moved)}. Recalibrate: record touches of every pair with the last calibration as"
              f" the start (nao-skin record --calibration {shlex.quote(args.calibration)}), or calibrate these"
              f" touches from it (nao-skin calibrate {inputs} --prior {shlex.quote(args.calibration)} --out DIR)")
        return 1
    print("every part checked fits the calibration")
    return 0


def _fabric(args, options) -> tuple:
    """``(mm, where from)``: the fabric thickness the calibration was made with. A report beside it that
    cannot be read is no reason to stop: the configured thickness is used, and the line says so."""
    import json
    import math
    from pathlib import Path

    if args.fabric is not None:
        return args.fabric, "--fabric"
    report = Path(args.calibration).with_name("report.json")
    try:
        value = json.loads(report.read_text())["fabric_thickness_mm"]
        if not isinstance(value, bool) and math.isfinite(value) and 0 <= value <= 1000 * options.fabric_bounds[1]:
            return float(value), f"from {report}"
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return 1000.0 * options.fabric_thickness, (f"the calibration option's (no fabric estimate in {report}:"
                                               f" --fabric MM gives the one the calibration was made with)")
