"""``nao-skin calibrate INPUT... --out DIR``: calibrate the skin from recorded self-touch."""
from __future__ import annotations

import sys
from pathlib import Path

NAME = "calibrate"
HELP = "calibrate skin mounts, patches and triangles from self-touch recordings (bags or legacy .txt)"


def add_arguments(parser) -> None:
    from ..calibrate import CalibrationOptions

    d = CalibrationOptions()
    parser.add_argument("inputs", nargs="+", metavar="INPUT", help="rosbag2 recordings or legacy .txt data sets")
    parser.add_argument("--out", required=True, help="output directory (replaced when the run succeeds)")
    parser.add_argument("--skin", help="skin config YAML (default: the package's config/nao_skin.yaml)")
    parser.add_argument("--taxels", action="append", default=[], metavar="PART=FILE",
                        help="use this skinManager taxel file for a part (e.g. from the recording); repeatable")
    parser.add_argument("--prior", help="start from this calibration.yaml instead of the nominal skin")
    parser.add_argument("--truth", help="ground-truth calibration (simulation) to report true taxel errors")
    parser.add_argument("--strategy", choices=["sequential", "all-at-once"], default=d.strategy)
    parser.add_argument("--reference", choices=["fixed", "simultaneous"], default=d.reference)
    parser.add_argument("--pairs", choices=["cop", "taxel", "both", "taxel5"], default=d.pairs,
                        help="which paired points enter the residuals of patch and triangle stages")
    parser.add_argument("--free", action="store_true", help="no bounds on patch and triangle corrections")
    parser.add_argument("--loss", choices=["huber", "linear"], default=d.loss)
    parser.add_argument("--jacobian", choices=["analytic", "2-point"], default=d.jacobian)
    parser.add_argument("--no-first-guess", action="store_true", help="skip the closed-form mount fit")
    parser.add_argument("--gate-mm", type=float, default=d.gate_mm, help="set aside touches farther than this after the mount fit (0: off)")
    parser.add_argument("--test-fraction", type=float, default=d.test_fraction)
    parser.add_argument("--seed", type=int, default=d.seed, help="seed of the train/test split")
    parser.add_argument("--set", action="append", default=[], metavar="OPTION=VALUE",
                        help="any field of CalibrationOptions, e.g. --set lateral_weight=0.3; repeatable")
    parser.add_argument("--no-plots", action="store_true")
    parser.add_argument("--quiet", action="store_true", help="print only the final line")


def build_options(args):
    from ..calibrate import CalibrationOptions

    options = CalibrationOptions(strategy=args.strategy, reference=args.reference, pairs=args.pairs,
                                 bounded=not args.free, loss=args.loss, jacobian=args.jacobian,
                                 initial_guess="none" if args.no_first_guess else "rigid-fit",
                                 gate_mm=args.gate_mm, test_fraction=args.test_fraction, seed=args.seed)
    return apply_settings(options, args.set)


def apply_settings(options, settings):
    """``KEY=VALUE`` strings onto a CalibrationOptions, typed like the field's default."""
    import dataclasses

    import yaml

    from ..errors import DataError

    fields = {f.name for f in dataclasses.fields(options)}
    for item in settings:
        key, sep, raw = item.partition("=")
        if not sep or key not in fields:
            raise DataError(f"--set {item!r}: expected OPTION=VALUE with OPTION one of {', '.join(sorted(fields))}")
        value = yaml.safe_load(raw)
        current = getattr(options, key)
        if isinstance(current, bool) and not isinstance(value, bool):
            raise DataError(f"--set {item!r}: {key} takes true or false")
        if isinstance(current, float) and isinstance(value, int):
            value = float(value)
        if isinstance(current, tuple) and isinstance(value, list):
            value = tuple(value)
        setattr(options, key, value)
    options.validate()
    return options


def load_skin(args):
    from ..config import default_skin_config
    from ..errors import DataError
    from ..legacy import skin_model_for
    from ..skin import SkinModel

    skin = SkinModel.from_yaml(args.skin or default_skin_config())
    if args.taxels:
        files = {}
        for item in args.taxels:
            part, sep, path = item.partition("=")
            if not sep:
                raise DataError(f"--taxels {item!r}: expected PART=FILE")
            files[part] = path
        override = skin_model_for(files, skin.robot)
        skin.parts.update(override.parts)
    return skin


def run(args) -> int:
    from ..calibrate import calibrate
    from ..datasets import deduplicate
    from ..inputs import load_touches
    from ..report import write_outputs
    from ..skin import SkinCalibration

    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, flush=True))
    skin = load_skin(args)
    touches, load_report, truth = load_touches(args.inputs, skin, log=log)
    touches, n_dup = deduplicate(touches)
    log(f"{touches.n_touches} touches after removing {n_dup} exact duplicates")
    prior = SkinCalibration.load(args.prior, skin) if args.prior else None
    if args.truth:
        truth = SkinCalibration.load(args.truth, skin)
    result = calibrate(touches, skin, build_options(args), prior=prior, truth=truth, progress=log)
    result.report["input"] = {"files": [str(p) for p in args.inputs], "touches_read": load_report.n_read,
                              "touches_loaded": load_report.n_loaded, "skipped": dict(load_report.skipped),
                              "duplicates_removed": n_dup}
    out = write_outputs(result, skin, args.out, prior=prior, plots=not args.no_plots)
    final = result.report["final"]

    def train_test(key):
        return " / ".join(f"{final[split].get(key, float('nan')):.2f}" for split in ("train", "test"))

    line = (f"calibrated {', '.join(result.report['plan'])} in {result.report['total_seconds']:.2f} s: "
            f"closest COP {train_test('cop_mean_mm')} mm, closest taxel {train_test('taxel_mean_mm')} mm"
            f" (selected contacts' {train_test('contact_taxel_mean_mm')} mm) (train / test)")
    if "truth_taxel_error_mm" in final:
        t = final["truth_taxel_error_mm"]["all"]
        line += f"; true taxel error median {t['median']:.2f} mm, p95 {t['p95']:.2f} mm"
    print(line + f" -> {Path(out)}", file=sys.stdout)
    return 0
