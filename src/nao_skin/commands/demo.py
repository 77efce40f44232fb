"""``nao-skin demo``: the main job on the bundled data, end to end.

Reads the bundled simulated recording (``bags/sim_default``: a rosbag2 touch
bag with its ground truth), calibrates all four skin parts with the default
(thesis) plan, writes the results where users apply them and a URDF with the
calibrated skin frames, and prints how far the skin was and is from the truth.
"""
from __future__ import annotations

from pathlib import Path

from nao_skin.commands import wall_seconds

NAME = "demo"
HELP = "calibrate the bundled simulated recording (bags/sim_default) and write out/demo"


def bundled_recording() -> Path:
    from nao_skin.paths import package_dir

    return package_dir() / "bags" / "sim_default"


def add_arguments(parser) -> None:
    parser.add_argument("--input", default=None, help="recording to calibrate (default: bags/sim_default)")
    parser.add_argument("--out", default="out/demo",
                        help="output directory (default: out/demo); an earlier demo's output there is replaced")
    parser.add_argument("--force", action="store_true",
                        help="replace another nao-skin command's outputs in --out (never a file nao-skin did not write)")
    parser.add_argument("--quiet", action="store_true", help="print only the summary lines")


def run(args) -> int:
    from nao_skin.calibration.options import CalibrationOptions
    from nao_skin.calibration.pipeline import calibrate_recordings, check_output
    from nao_skin.errors import DataError
    from nao_skin.formats.inputs import check_inputs
    from nao_skin.formats.outdir import read_marker
    from nao_skin.model.skin import load_skin
    from nao_skin.model.urdf import expand_xacro

    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, flush=True))
    source = Path(args.input) if args.input else bundled_recording()
    # the demo is meant to be run again and again: its own earlier output (marked) is replaced without --force
    force = args.force or (read_marker(args.out) or {}).get("command") == f"nao-skin {NAME}"
    check_output(args.out, [source], force=force)
    if args.input:
        check_inputs([source])             # the user's input: the line every command gives
    elif not source.exists():
        raise DataError(f"{source}: bundled recording not found (regenerate it: see bags/README.md)")
    log(f"reading {source}; calibrating (thesis plan + joint refinement)")
    run = calibrate_recordings([source], load_skin(), CalibrationOptions(), args.out, force=force, command=NAME,
                               extra=lambda d: (d / "nao_skin.urdf").write_text(expand_xacro(d / "calibration.yaml")),
                               log=log)
    result, out, truth = run.result, run.out_dir, "truth_taxel_error_mm" in run.result.report.final
    final, before = result.report.final, result.report.before
    print(f"closest COP pair:   {before['test']['cop_mean_mm']:.1f} mm before -> {final['test']['cop_mean_mm']:.2f} mm after (test set mean)")
    print(f"closest taxel pair: {before['test']['taxel_mean_mm']:.1f} mm before -> {final['test']['taxel_mean_mm']:.2f} mm after (test set mean)")
    if truth:
        tb, tf = before["truth_taxel_error_mm"], final["truth_taxel_error_mm"]
        for part in [p for p in tf if p != "all"] + ["all"]:
            print(f"true taxel error {part:>7}: median {tb[part]['median']:6.2f} -> {tf[part]['median']:.2f} mm,"
                  f" p95 {tb[part]['p95']:6.2f} -> {tf[part]['p95']:.2f} mm")
    print(f"engine {result.report.total_seconds:.1f} s, whole command {wall_seconds(args):.1f} s; results in {out}/ (calibration.yaml, taxels/, report.md, report.json, *.png, nao_skin.urdf)")
    return 0
