"""``nao-skin bench-capture``: touches needed until every part is calibrated well, random against guided capture.

See :mod:`nao_skin.bench.capture` for the loop. Writes ``capture_results.md``
(the tables), ``capture_results.json`` (every run with its trace),
``capture.png`` and ``honesty.png`` (the live status's predicted error
against the true one, every update) into ``--out`` and prints the tables. ``--out`` must be new,
empty, or an earlier bench-capture output (then with ``--force``); see
:mod:`nao_skin.formats.outdir`.
"""
from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

from nao_skin.commands import add_output_arguments

NAME = "bench-capture"
HELP = ("benchmark guided capture: touches until every part's true taxel error meets the target, random vs guided"
        " (and an oracle's split over the pairs)")
OUTPUTS = ("capture_results.md", "capture_results.json", "capture.png", "honesty.png")


def add_arguments(parser) -> None:
    add_output_arguments(parser, "bench-capture")
    parser.add_argument("--seeds", type=int, default=None, help="seeds (default 10; --quick: 2)")
    parser.add_argument("--first-seed", type=int, default=0, help="first seed (default 0)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: 2 seeds, cap 400 touches, target median 1.0 mm / p95 2.0 mm")
    parser.add_argument("--start", type=int, help="random touches before the first calibration (default 60)")
    parser.add_argument("--batch", type=int, help="touches per batch (default 25, the calibrate node's"
                                                  " live_every_touches)")
    parser.add_argument("--cap", type=int, help="give up at this many touches (default 1500)")
    parser.add_argument("--median-mm", type=float, help="every part's true taxel error median at most (default 0.5)")
    parser.add_argument("--p95-mm", type=float, help="every part's true taxel error p95 at most (default 1.5)")
    parser.add_argument("--cold", action="store_true",
                        help="calibrate from nominal after every batch (default: warm-started from the last one)")
    parser.add_argument("--until-done", action="store_true",
                        help="after the target, go on until the live status calls every part done (or the cap):"
                             " when 'done' comes and how far from the truth the parts are then")
    parser.add_argument("--to-cap", action="store_true",
                        help="go on to the cap whatever is met: when the target was met for good (against when"
                             " the status said done), and the prediction's honesty over every touch count")
    parser.add_argument("--done-margin", type=float,
                        help="the live status's 'done' margin to replay (default: the calibrate node's"
                             " live_done_margin)")
    parser.add_argument("--strategies", default="random,guided,oracle",
                        help="comma-separated, of random, guided, oracle (default: all three; oracle splits random"
                             " touches over the pairs by the true error: an upper bound, not a capture policy)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (runs are independent)")
    parser.add_argument("--autonomous", action="store_true",
                        help="instead: the robot's autonomous fingertip capture on the torso against a random manual"
                             " session of it (nao_skin.bench.autonomous): coverage, press depth, robot time; --cap"
                             " (default 400) and --touches (default 250) apply")
    parser.add_argument("--touches", type=int, default=250, help="--autonomous: presses the figures are taken at")
    parser.add_argument("--set", action="append", default=[], metavar="OPTION=VALUE",
                        help="a calibration option of every update (YAML value), e.g. --set pairs=cop+plane;"
                             " repeatable, as nao-skin calibrate takes it")


_HOW = {True: "as the live calibrate node updates: warm-started, from scratch whenever the touches doubled",
        False: "from nominal each time"}


def run_autonomous(args) -> int:
    from nao_skin.bench import autonomous as bench
    from nao_skin.errors import DataError
    from nao_skin.formats.outdir import CAPTURE_BENCHMARK, check_output_dir, clear_for_writing
    from nao_skin.model.skin import load_skin
    from nao_skin.plain import jsonable

    setup = bench.AutonomousSetup(touches=args.touches, cap=args.cap if args.cap is not None else 400)
    seeds = args.seeds if args.seeds is not None else 10
    if seeds < 1 or args.first_seed < 0 or setup.touches < 1 or setup.cap < setup.touches:
        raise DataError(f"--seeds {seeds}, --first-seed {args.first_seed}, --touches {setup.touches}, --cap"
                        f" {setup.cap}: expected at least one seed from 0 and 1 <= touches <= cap")
    check_output_dir(args.out, CAPTURE_BENCHMARK, force=args.force)
    t0, skin, rows = time.perf_counter(), load_skin(), []
    for seed in range(args.first_seed, args.first_seed + seeds):
        rows.append(bench.run_seed(skin, seed, setup))
        print(f"seed {seed}: {json.dumps(jsonable(rows[-1]))}", flush=True)
    summary = bench.summary(rows, setup)
    out = Path(args.out)
    clear_for_writing(out, NAME, CAPTURE_BENCHMARK, AUTONOMOUS_OUTPUTS)
    argv = sys.argv[2:] + ([] if "--force" in sys.argv[2:] else ["--force"])
    text = "\n".join([f"# nao-skin bench-capture --autonomous", "", f"Command: `nao-skin bench-capture {' '.join(argv)}`",
                      "", bench.__doc__.split("\n\n", 1)[1].strip(), "", bench.table(rows), "",
                      f"Summary: `{json.dumps(jsonable(summary))}`", "",
                      f"Wall time: {time.perf_counter() - t0:.0f} s.", ""])
    (out / "autonomous_results.md").write_text(text)
    (out / "autonomous_results.json").write_text(json.dumps(jsonable({"setup": setup.__dict__, "rows": rows,
                                                                      "summary": summary}), indent=1) + "\n")
    print(text)
    return 0


AUTONOMOUS_OUTPUTS = ("autonomous_results.md", "autonomous_results.json")


def run(args) -> int:
    if args.autonomous:
        return run_autonomous(args)
    from dataclasses import replace

    from nao_skin.bench import capture as bench
    from nao_skin.bench.pool import MAX_JOBS
    from nao_skin.calibration.options import CalibrationOptions, set_items
    from nao_skin.errors import DataError
    from nao_skin.formats.outdir import CAPTURE_BENCHMARK, check_output_dir, clear_for_writing
    from nao_skin.model.skin import load_skin
    from nao_skin.plain import jsonable

    setup = bench.QUICK_SETUP if args.quick else bench.CaptureSetup()
    for name in ("start", "batch", "cap", "median_mm", "p95_mm", "done_margin"):
        value = getattr(args, name)
        if value is not None:
            if not 0 < value < math.inf:       # NaN or inf: a target never or always met, runs up to the cap
                raise DataError(f"--{name.replace('_', '-')} {value}: must be a finite number above 0")
            setup = replace(setup, **{name: value})
    if setup.start > setup.cap:
        raise DataError(f"--start {setup.start}: more random touches than the cap of {setup.cap}")
    if args.cold:
        if args.until_done:
            raise DataError("--until-done: the live status follows warm-started updates; not with --cold")
        setup = replace(setup, warm_start=False)
    setup = replace(setup, until_done=args.until_done, to_cap=args.to_cap)
    options = CalibrationOptions()
    given = set_items(options, args.set)
    options.validate()
    setup = replace(setup, options={name: getattr(options, name) for name in given})
    strategies = tuple(s.strip() for s in args.strategies.split(",") if s.strip())
    unknown = sorted(set(strategies) - set(bench.STRATEGIES))
    if unknown or not strategies or len(set(strategies)) < len(strategies):
        raise DataError(f"--strategies {args.strategies!r}: expected some of {', '.join(bench.STRATEGIES)},"
                        f" each once")
    seeds = args.seeds if args.seeds is not None else (2 if args.quick else 10)
    if seeds < 1:
        raise DataError(f"--seeds {seeds}: must be at least 1")
    if args.first_seed < 0:
        raise DataError(f"--first-seed {args.first_seed}: expected a whole number >= 0")
    if not 1 <= args.jobs <= MAX_JOBS:
        raise DataError(f"--jobs {args.jobs}: expected a whole number from 1 to {MAX_JOBS}")
    check_output_dir(args.out, CAPTURE_BENCHMARK, force=args.force)
    out = Path(args.out)
    say = lambda msg: print(msg, flush=True)  # noqa: E731
    t0 = time.perf_counter()
    seed_list = list(range(args.first_seed, args.first_seed + seeds))
    say(f"bench-capture: {len(seed_list)} seeds x {'/'.join(strategies)}, start {setup.start}, batch {setup.batch},"
        f" cap {setup.cap}, target median <= {setup.median_mm:g} mm and p95 <= {setup.p95_mm:g} mm in every part")
    rows = bench.capture_matrix(load_skin(), seed_list, setup, max(1, args.jobs), say, strategies)
    # an earlier output goes only now: a run stopped before keeps it
    clear_for_writing(out, NAME, CAPTURE_BENCHMARK, OUTPUTS)
    bench.plot(rows, setup, out / "capture.png")
    bench.plot_honesty(rows, out / "honesty.png")
    argv = sys.argv[2:] + ([] if "--force" in sys.argv[2:] else ["--force"])
    seconds = time.perf_counter() - t0
    md = [f"# nao-skin bench-capture{' (quick)' if args.quick else ''}", "",
          f"Command: `nao-skin bench-capture {' '.join(argv)}`", "",
          f"Touches (presses recorded, duplicates removed) until EVERY part's true taxel error has median <="
          f" {setup.median_mm:g} mm and p95 <= {setup.p95_mm:g} mm; random start of {setup.start} touches, then"
          f" batches of {setup.batch}, recalibrated after each"
          f" ({_HOW[setup.warm_start]}), cap"
          f" {setup.cap}. Random: uniform over the pairs and each part's reachable triangles. Guided: one touch aimed"
          f" at each of the guidance's top {setup.max_targets} targets a pose reaches, as the simulated robot"
          f" follows it; the rest of the batch and the missed aims random. Oracle: random"
          f" touches, each batch split over the pairs by how far each pair's worse part is from the target under"
          f" the true error (share ~ distance ** {bench.ORACLE_POWER}): what perfect knowledge of where the"
          f" error is would buy by sending touches there; no capture at the robot has that knowledge.", "",
          *([f"Calibration options changed from the default: "
             f"{', '.join(f'{k}={v}' for k, v in setup.options.items())}.", ""] if setup.options else []),
          bench.table(rows, setup), "", "![capture](capture.png)", "",
          "![the live status's predicted error against the truth](honesty.png)", "", f"Wall time: {seconds:.0f} s.", ""]
    text = "\n".join(md)
    (out / "capture_results.md").write_text(text)
    results = {"setup": bench.setup_dict(setup), "seeds": seed_list, "summary": bench.summary(rows, setup),
               "rows": rows, "seconds": seconds}
    (out / "capture_results.json").write_text(json.dumps(jsonable(results), indent=1) + "\n")
    print(text)
    print(f"-> {out / 'capture_results.md'}, {out / 'capture.png'}, {out / 'honesty.png'}")
    return 0

