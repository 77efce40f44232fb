"""``nao-skin bench-bound``: what choosing the touches could buy at best, from the linearised bound.

See :mod:`nao_skin.bench.bound`. Per seed a simulated pool (default preset,
all four thesis pairs); for each size the predicted true taxel error of
random touches and of the greedy (A-optimal, truth-informed) choice, and how
many random touches reach the greedy choice's error. Writes
``bound_results.md`` and ``bound_results.json`` into ``--out`` (new, empty, or
an earlier bench-bound output with ``--force``) and prints the table.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from nao_skin.commands import add_output_arguments

NAME = "bench-bound"
HELP = ("benchmark what any choice of touches could buy: linearised bound on the true taxel error, random against"
        " the best (greedy, truth-informed) choice")
OUTPUTS = ("bound_results.md", "bound_results.json")


def add_arguments(parser) -> None:
    add_output_arguments(parser, "bench-bound")
    parser.add_argument("--seeds", type=int, default=2, help="simulated robots (default 2)")
    parser.add_argument("--pool", type=int, default=1000,
                        help="touches per pair in each robot's pool to choose from (default 1000: 4000 in all)")
    parser.add_argument("--sizes", default="250,500,1000", help="touches chosen, comma-separated (default 250,500,1000)")
    parser.add_argument("--batch", type=int, default=10, help="touches the greedy choice adds at a time (default 10)")
    parser.add_argument("--rows", default=None,
                        help="the rows linearised, as the calibration option closing_pairs takes them (default: that"
                             " option's default; e.g. cop+surface for the contact model's rows beside the COP pairs)")


def _sizes(text: str, pool: int) -> list:
    from nao_skin.errors import DataError

    try:    # an empty entry ('250,,500') is a typo, not nothing
        sizes = sorted({int(s) for s in text.split(",")})
    except ValueError:
        sizes = []
    if not sizes or sizes[0] < 1 or sizes[-1] > pool:
        raise DataError(f"--sizes {text!r}: expected whole numbers from 1 to the pool's {pool} touches, comma-separated")
    return sizes


def run(args) -> int:
    from nao_skin.bench.bound import bound_rows
    from nao_skin.errors import DataError
    from nao_skin.formats.outdir import BOUND_BENCHMARK, check_output_dir, clear_for_writing
    from nao_skin.model.skin import load_skin
    from nao_skin.plain import jsonable

    from nao_skin.sim.params import MAX_TOUCHES_PER_PAIR

    for name, low in (("seeds", 1), ("pool", 10), ("batch", 1)):
        if getattr(args, name) < low:
            raise DataError(f"--{name} {getattr(args, name)}: expected a whole number >= {low}")
    if args.pool > MAX_TOUCHES_PER_PAIR:     # the simulator's limit, said of the option that asked for it
        raise DataError(f"--pool {args.pool}: expected at most {MAX_TOUCHES_PER_PAIR} touches per pair")
    from nao_skin.calibration.options import CalibrationOptions

    options = CalibrationOptions.from_mapping({} if args.rows is None else {"closing_pairs": args.rows},
                                              where="--rows {value!r}")
    skin = load_skin()
    sizes = _sizes(args.sizes, 4 * args.pool)
    if args.batch > sizes[0]:     # the greedy choice adds this many at a time: beyond a size it never stops at it
        raise DataError(f"--batch {args.batch}: expected a whole number from 1 to the smallest size, {sizes[0]}")
    check_output_dir(args.out, BOUND_BENCHMARK, force=args.force)
    out = Path(args.out)
    t0 = time.perf_counter()
    rows = []
    for seed in range(args.seeds):
        print(f"bench-bound: seed {seed}: {args.pool} touches per pair, sizes {sizes}", flush=True)
        rows += bound_rows(skin, seed, args.pool, sizes, args.batch, options=options)
    argv = sys.argv[2:] + ([] if "--force" in sys.argv[2:] else ["--force"])
    seconds = time.perf_counter() - t0
    table = ["| seed | touches | random: worst part median / p95 mm | greedy: worst part median / p95 mm"
             " | random touches for greedy's median | random / greedy touches |",
             "|---|---|---|---|---|---|"]
    table += [f"| {r['seed']} | {r['touches']} | {r['random_median_mm']:.3f} / {r['random_p95_mm']:.3f}"
              f" | {r['greedy_median_mm']:.3f} / {r['greedy_p95_mm']:.3f} | {r['random_touches_for_greedy']:.0f}"
              f" | {r['ratio']:.2f} |" for r in rows]
    ratios = [r["ratio"] for r in rows]
    sigmas = ", ".join(f"{r['sigma_mm']:.2f}" for r in rows if r["touches"] == sizes[0])
    md = ["# nao-skin bench-bound", "", f"Command: `nao-skin bench-bound {' '.join(argv)}`", "",
          f"Linearised Bayesian bound (see nao_skin.bench.bound): per seed a pool of {args.pool} simulated touches per"
          f" pair (default preset), paired at the truth (rows: {options.closing_pairs}); predicted RMS error per taxel, worst part's median and"
          f" p95 over its taxels; random: mean of 2 draws; greedy: {args.batch} touches at a time, chosen with the"
          f" true robot's Jacobian. Noise per coordinate (robust spread of the residuals at the truth):"
          f" {sigmas} mm.", "", *table, "",
          f"Random / greedy touches for the same predicted error: {min(ratios):.2f}-{max(ratios):.2f}"
          f" (median {float(sorted(ratios)[len(ratios) // 2]):.2f}).", "", f"Wall time: {seconds:.0f} s.", ""]
    text = "\n".join(md)
    clear_for_writing(out, NAME, BOUND_BENCHMARK, OUTPUTS)       # an earlier output goes only now, when the new is ready
    (out / "bound_results.md").write_text(text)
    (out / "bound_results.json").write_text(json.dumps(jsonable({"rows": rows, "seconds": seconds}), indent=1) + "\n")
    print(text)
    print(f"-> {out / 'bound_results.md'}")
    return 0
