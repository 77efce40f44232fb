"""``nao-skin check INPUT... --calibration CAL``: does a calibration still fit the skin?"""
from __future__ import annotations

import json
import shlex
import sys

from nao_skin.commands import add_skin_arguments, skin_from_args, wall_seconds

NAME = "check"
HELP = ("judge a calibration by a new recording: which skin parts still fit it and which have moved"
        " (exit 0: every part checked fits, 1: a part moved, 2: bad input or no part could be judged)")

MAX_TOLERANCE_MM = 50.0     # beyond, no part of a Nao's skin could be said to have moved


def add_arguments(parser) -> None:
    from nao_skin.calibration.options import DEFAULT_TOLERANCE_MM, OPTION_FIELDS

    parser.add_argument("inputs", nargs="+", metavar="INPUT",
                        help="new touches: rosbag2 recordings, simulator output folders or legacy .txt data sets")
    parser.add_argument("--calibration", required=True, metavar="YAML", help="the calibration.yaml to judge")
    parser.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE_MM, metavar="MM",
                        help="a part has moved when a refit from the new touches carries its taxels at least this"
                             f" far (median, mm) and brings its held-out touches closer (default {DEFAULT_TOLERANCE_MM:g})")
    high = 1000.0 * OPTION_FIELDS["fabric_bounds"].default[1]
    parser.add_argument("--fabric", type=float, default=None, metavar="MM",
                        help=f"fabric thickness to measure at, 0 to {high:g} mm (default: the calibration's estimate;"
                             f" for a calibration without one, its report.json's, else the one that brings the new"
                             f" training touches closest under it)")
    parser.add_argument("--seed", type=int, default=None,
                        help=f"seed of the train/test split of the new touches (default {OPTION_FIELDS['seed'].default})")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    add_skin_arguments(parser)


def run(args) -> int:
    import math

    from nao_skin.calibration.check import FITS, MOVED, NOT_CALIBRATED, NOT_CHECKED, check_calibration
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
    fabric, report = args.fabric, None
    if fabric is None and calibration.fabric_thickness is None:     # written before calibrations kept it
        fabric, report = _report_fabric(args.calibration, options)
    notes = []
    loaded = load_inputs(args.inputs, skin, summary=notes.append)
    notes[:0] = loaded.load_report.info        # what the inputs are (simulated, still being recorded): said too
    try:
        result = check_calibration(loaded.touches, skin, calibration, args.tolerance, fabric, options)
    except DataError as exc:     # too few touches to judge anything: the line names the recordings
        raise type(exc)(f"{', '.join(map(str, args.inputs))}: {exc}") from None
    moved = result.moved
    fabric_from = ("--fabric" if args.fabric is not None else str(report) if report is not None
                   else result.fabric_from)
    judged = [name for name, p in result.parts.items() if p.verdict in (FITS, MOVED)]
    # the words for what was not judged, for the last line (a part the recording never touched is no news)
    unjudged = {verdict: [n for n, p in result.parts.items() if p.verdict == verdict and p.pairs]
                for verdict in (NOT_CHECKED, NOT_CALIBRATED)}
    if args.json:
        for line in notes:
            print(line, file=sys.stderr)
        print(json.dumps(jsonable({"inputs": [str(p) for p in args.inputs], "calibration": args.calibration,
                                   "touches": loaded.touches.n_touches, "duplicates_removed": loaded.n_duplicates,
                                   **result.as_dict(), "fabric_from": fabric_from, "judged": judged})))
    else:
        for line in notes:
            print(line)
        words = {"--fabric": "from --fabric", "calibration": "the calibration's",
                 "estimated": "the one that brings the new touches closest under the calibration (it holds no fabric"
                              " estimate: a move along a part's normal is partly taken for fabric)",
                 "configured": "the configured"}
        said = words.get(fabric_from, f"from {fabric_from}")
        print(f"{args.calibration} against {loaded.touches.n_touches} touches of {', '.join(map(str, args.inputs))}"
              f" ({result.refit.train.n_touches} to refit the mounts from it, {result.refit.test.n_touches} held out;"
              f" fabric {result.fabric_mm:.2f} mm, {said}; {wall_seconds(args):.1f} s)")
        for name, part in result.parts.items():
            print(f"{name}: {part.verdict}: {part.reason}")
    if moved:
        if not args.json:
            print(f"moved: {', '.join(moved)}. Recalibrate: {_recalibrate(args)}")
        return 1
    if not judged:      # nothing fits or moved: no verdict for a script to take as a pass
        raise DataError(f"{', '.join(map(str, args.inputs))}: no part of {args.calibration} could be judged"
                        + "".join(f"; {v}: {', '.join(n)}" for v, n in unjudged.items() if n)
                        + " (record more touches of every pair: each part's line above says what it lacks)")
    if not args.json:
        rest = "".join(f"; {v}: {', '.join(n)}" for v, n in unjudged.items() if n)
        print(f"every part checked fits the calibration ({', '.join(judged)}{rest})")
    return 0


def _recalibrate(args) -> str:
    """The ways to recalibrate, with the skin this check read (its taxel files, skin and robot config)."""
    q = shlex.quote
    taxels = "".join(f" --taxels {q(item)}" for item in args.taxels or [])
    skin = (f" --skin {q(args.skin)}" if args.skin else "") + (f" --robot {q(args.robot)}" if args.robot else "")
    inputs = " ".join(q(str(p)) for p in args.inputs)
    calibrate = (f"calibrate these touches from it (nao-skin calibrate {inputs} --prior {q(args.calibration)}{skin}"
                 f"{taxels} --out DIR)")
    if args.skin or args.robot:     # a record session reads the package's skin config, with its robot
        return calibrate
    return (f"record touches of every pair, starting from the calibration (on the robot: nao-skin record --robot nao"
            f" --calibration {q(args.calibration)}{taxels}), or {calibrate}")


def _report_fabric(calibration: str, options) -> tuple:
    """``(mm, report path)`` from the report.json beside a calibration written before calibrations kept their
    fabric estimate (beside the file a link leads to); ``(None, None)`` where there is no usable one. A report
    that cannot be read is no reason to stop: the check then estimates the fabric, and says so."""
    import math
    from pathlib import Path

    from nao_skin.errors import DataError
    from nao_skin.paths import read_text

    report = Path(calibration).resolve().with_name("report.json")
    try:
        value = json.loads(read_text(report, "as a report"))["fabric_thickness_mm"]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return None, None
        value = float(value)
    except (DataError, ValueError, KeyError, TypeError, OverflowError, RecursionError):
        return None, None
    if math.isfinite(value) and 0.0 <= value <= 1000.0 * options.fabric_bounds[1]:
        return value, report
    return None, None
