"""``nao-skin calibrate INPUT... --out DIR``: calibrate the skin from recorded self-touch."""
from __future__ import annotations

import argparse
import sys

from nao_skin.commands import add_skin_arguments, skin_from_args, wall_seconds

NAME = "calibrate"
HELP = "calibrate skin mounts, patches and triangles from self-touch and fingertip recordings (bags or legacy .txt)"


CHOICE_FLAGS = {"--strategy": "strategy", "--reference": "reference", "--pairs": "pairs", "--loss": "loss",
                "--jacobian": "jacobian"}
NUMBER_FLAGS = {"--gate-mm": ("gate_mm", float), "--test-fraction": ("test_fraction", float),
                "--seed": ("seed", int)}


def add_arguments(parser) -> None:
    from nao_skin.calibration.options import OPTION_FIELDS, options_help

    parser.add_argument("inputs", nargs="+", metavar="INPUT", help="rosbag2 recordings or legacy .txt data sets")
    parser.add_argument("--out", required=True,
                        help="output directory: new, empty, or an earlier nao-skin output (with --force);"
                             " written when the run succeeds")
    parser.add_argument("--force", action="store_true",
                        help="replace the outputs of an earlier run in --out (never a file nao-skin did not write)")
    add_skin_arguments(parser)
    parser.add_argument("--fingertip", action="append", default=[], metavar="[INPUT=]NAME",
                        help="the fingertip (robot config, e.g. r_finger) whose touches a text input holds (one skin"
                             " part fires per touch); NAME alone: every text input; repeatable")
    parser.add_argument("--prior", help="start from this calibration.yaml instead of the nominal skin")
    parser.add_argument("--truth", help="ground-truth calibration (simulation) to report true taxel errors")
    for flag, name in CHOICE_FLAGS.items():
        spec = OPTION_FIELDS[name]
        parser.add_argument(flag, choices=spec.metadata["rule"].choices, default=None,
                            help=f"{spec.metadata['help']} (default {spec.default})")
    for flag, (name, kind) in NUMBER_FLAGS.items():
        spec = OPTION_FIELDS[name]
        parser.add_argument(flag, type=kind, default=None, help=f"{spec.metadata['help']} (default {spec.default})")
    bounds = parser.add_mutually_exclusive_group()
    bounds.add_argument("--bounded", action="store_true",
                        help="bound patch and triangle corrections to the thesis' box (patch_bounds, triangle_bounds)")
    bounds.add_argument("--free", action="store_true",
                        help="no bounds on patch and triangle corrections, the Gaussian prior alone (the default)")
    parser.add_argument("--no-first-guess", action="store_true", help="skip the closed-form mount fit")
    parser.add_argument("--set", action="append", default=[], metavar="OPTION=VALUE",
                        help="any calibration option, e.g. --set normal_weight=0.01; repeatable (each option, its"
                             " default, meaning and how its value is written: below)")
    parser.epilog = options_help()
    parser.formatter_class = argparse.RawDescriptionHelpFormatter     # the epilog's lines as they are
    parser.add_argument("--splits", type=int, default=1, metavar="K",
                        help="also calibrate on K-1 more seeded train/test splits and report each figure's mean and"
                             " spread over the K (the calibration written is the first split's; default 1)")
    parser.add_argument("--cross-scene", action="store_true",
                        help="also predict each scene of the inputs (a self-touch pair, a fingertip scene) from the"
                             " others, and give each part's placement spread between scenes (report.json 'scenes')")
    parser.add_argument("--no-plots", action="store_true", help="do not draw the report's plots (faster)")
    parser.add_argument("--quiet", action="store_true",
                        help="print only the final line (and what loading skipped, if anything)")


def build_options(args):
    """The options of the flags and ``--set`` items, each checked by its rule before any data is read."""
    from nao_skin.calibration.options import CalibrationOptions, set_items, set_once

    options = CalibrationOptions()
    given: dict = {}
    flags = {**CHOICE_FLAGS, **{flag: name for flag, (name, _) in NUMBER_FLAGS.items()}}
    for flag, name in flags.items():
        value = getattr(args, flag[2:].replace("-", "_"))
        if value is not None:
            set_once(options, name, value, f"{flag} {value}", given)
    for flag in ("--bounded", "--free"):
        if getattr(args, flag[2:]):
            set_once(options, "bounded", flag == "--bounded", flag, given)
    if args.no_first_guess:
        set_once(options, "initial_guess", "none", "--no-first-guess", given)
    set_items(options, args.set, given)
    options.validate()
    return options


def run(args) -> int:
    from nao_skin.calibration.options import OPTION_FIELDS
    from nao_skin.calibration.pipeline import calibrate_recordings, summary_line
    from nao_skin.calibration.splits import MAX_SPLITS
    from nao_skin.formats.inputs import Inputs, parse_fingertips
    from nao_skin.model.skin import SkinCalibration

    from nao_skin.errors import DataError

    options = build_options(args)
    if not 1 <= args.splits <= MAX_SPLITS:
        raise DataError(f"--splits {args.splits}: expected a whole number from 1 to {MAX_SPLITS}")
    if args.splits > 1 and options.test_fraction == 0:      # K identical runs and a "nan ± nan" test figure
        raise DataError(f"--splits {args.splits}: with test_fraction 0 no touch is held out and every split is the"
                        f" same; give a test fraction or --splits 1")
    if options.seed + args.splits - 1 > OPTION_FIELDS["seed"].metadata["rule"].high:
        raise DataError(f"--splits {args.splits}: the splits take seeds {options.seed}.."
                        f"{options.seed + args.splits - 1}, beyond the largest seed"
                        f" {OPTION_FIELDS['seed'].metadata['rule'].high:.0f}; give a smaller --seed")
    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, flush=True))
    skin = skin_from_args(args)
    prior = SkinCalibration.load(args.prior, skin) if args.prior else None
    truth = SkinCalibration.load(args.truth, skin) if args.truth else None
    inputs = Inputs(tuple(args.inputs), parse_fingertips(args.fingertip, args.inputs))
    run = calibrate_recordings(inputs, skin, options, args.out, prior=prior, truth=truth, force=args.force,
                               plots=not args.no_plots, log=log, splits=args.splits, cross_scene=args.cross_scene,
                               protected=[args.skin, args.robot, args.prior, args.truth,
                                          *(item.partition("=")[2] for item in args.taxels)],
                               summary=lambda msg: print(msg, file=sys.stderr, flush=True))
    print(f"{summary_line(run.result)} -> {run.out_dir} (engine {run.result.report.total_seconds:.2f} s,"
          f" whole command {wall_seconds(args):.1f} s)")
    for line in run.result.report.warnings:     # written, but not as a success without a word (--quiet too)
        print(f"warning: {line}", file=sys.stderr, flush=True)
    return 0
