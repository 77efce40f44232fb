"""``nao-skin bench-bound``: what choosing the touches could buy at best, from the linearised bound.

See :mod:`nao_skin.bench.bound`. Per seed a simulated pool (default preset,
all four thesis pairs); for each size the predicted true taxel error of
random touches and of the greedy (A-optimal, truth-informed) choice, and how
many random touches reach the greedy choice's error. With ``--kinematics``
instead: what an efficient estimator reaches with the arm and head kinematics
free against the skin alone (:func:`~nao_skin.bench.bound.kinematic_bound_row`). Writes
``bound_results.md`` and ``bound_results.json`` into ``--out`` (new, empty, or
an earlier bench-bound output with ``--force``) and prints the table.
"""
from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

from nao_skin.commands import add_output_arguments

NAME = "bench-bound"
HELP = ("benchmark what any choice of touches could buy: linearised bound on the true taxel error, random against"
        " the best (greedy, truth-informed) choice; or what the kinematics free cost (--kinematics)")
OUTPUTS = ("bound_results.md", "bound_results.json")
# what the choice from a pool takes unless told (--pool, --sizes, --batch); --kinematics chooses nothing
CHOICE_DEFAULTS = {"pool": 1000, "sizes": "250,500,1000", "batch": 10}


def add_arguments(parser) -> None:
    add_output_arguments(parser, "bench-bound")
    parser.add_argument("--seeds", type=int, default=2, help="simulated robots (default 2)")
    parser.add_argument("--pool", type=int, default=None,
                        help="touches per pair in each robot's pool to choose from (default 1000: 4000 in all)")
    parser.add_argument("--sizes", default=None, help="touches chosen, comma-separated (default 250,500,1000)")
    parser.add_argument("--batch", type=int, default=None, help="touches the greedy choice adds at a time (default 10)")
    parser.add_argument("--kinematics", default=None, metavar="PER_PAIR",
                        help="instead: what an efficient estimator reaches with the arm and head kinematics free"
                             " (kinematic-error preset) against the skin alone (default preset), at these touches per"
                             " pair, comma-separated (e.g. 200,1000), each split 70/30 as a calibration splits it")
    parser.add_argument("--preset", default="default",
                        help="the simulator preset of the pools (default: default, all four thesis pairs; e.g."
                             " fingertip-torso for the fingertip's rows alone)")
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


def _per_pair(text: str) -> list:
    from nao_skin.errors import DataError
    from nao_skin.sim.params import MAX_TOUCHES_PER_PAIR

    try:    # an empty entry ('200,,1000') is a typo, not nothing
        counts = sorted({int(s) for s in text.split(",")})
    except ValueError:
        counts = []
    if not counts or counts[0] < 10 or counts[-1] > MAX_TOUCHES_PER_PAIR:
        raise DataError(f"--kinematics {text!r}: expected touches per pair from 10 to {MAX_TOUCHES_PER_PAIR},"
                        f" comma-separated")
    return counts


def _choice_table(rows: list, args, options, sizes: list) -> list:
    """Markdown lines of random against greedy choices from each seed's pool."""
    table = ["| seed | touches | random: worst part median / p95 mm | greedy: worst part median / p95 mm"
             " | random touches for greedy's median | random / greedy touches |",
             "|---|---|---|---|---|---|"]
    def cell(value, digits):    # NaN: random touches are interpolated between two sizes, and one was measured
        return f"{value:.{digits}f}" if math.isfinite(value) else "-"

    table += [f"| {r['seed']} | {r['touches']} | {r['random_median_mm']:.3f} / {r['random_p95_mm']:.3f}"
              f" | {r['greedy_median_mm']:.3f} / {r['greedy_p95_mm']:.3f} | {cell(r['random_touches_for_greedy'], 0)}"
              f" | {cell(r['ratio'], 2)} |" for r in rows]
    ratios = sorted(r["ratio"] for r in rows if math.isfinite(r["ratio"]))
    sigmas = ", ".join(f"{r['sigma_mm']:.2f}" for r in rows if r["touches"] == sizes[0])
    means = "; ".join(f"{n}: random {sum(r['random_median_mm'] for r in rows if r['touches'] == n) / args.seeds:.3f},"
                      f" greedy {sum(r['greedy_median_mm'] for r in rows if r['touches'] == n) / args.seeds:.3f}"
                      for n in sizes)
    return [f"Linearised Bayesian bound (see nao_skin.bench.bound): per seed a pool of {args.pool} simulated touches"
            f" per pair (default preset), paired at the truth (rows: {options.closing_pairs}); predicted RMS error per"
            f" taxel, worst part's median and p95 over its taxels; random: mean of 2 draws; greedy: {args.batch}"
            f" touches at a time, chosen with the true robot's Jacobian. Noise per coordinate (robust spread of the"
            f" residuals at the truth): {sigmas} mm.", "", *table, "",
            f"Worst part's median, mean over the seeds (mm): {means}.",
            f"Random / greedy touches for the same predicted error: {ratios[0]:.2f}-{ratios[-1]:.2f}"
            f" (median {ratios[len(ratios) // 2]:.2f})." if ratios else
            "Random / greedy touches for the same predicted error: not measured (random touches' error is"
            " interpolated between two sizes or more)."]


def _kinematic_table(rows: list, options) -> list:
    """Markdown lines of the bound with the kinematics free against the skin alone, per seed and count."""
    import numpy as np

    from nao_skin.bench.bound import KINEMATIC_PRESET, OFFSET_TOLERANCE, RATIO_GOAL
    from nao_skin.calibration.uncertainty import PREDICTION_POSES, SAMPLES

    link_tol, joint_tol = OFFSET_TOLERANCE["link_mm"], OFFSET_TOLERANCE["joint_deg"]
    table = ["| seed | touches per pair (training) | skin only, default preset mm | kinematics known / free mm"
             f" | free / skin only | links' std mm (within {link_tol:g} mm) | joint offsets' std deg, median / max"
             f" (within {joint_tol:g} deg) | held |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        links, joints = list(r["link_std_mm"].values()), list(r["joint_std_deg"].values())
        table.append(f"| {r['seed']} | {r['per_pair']} ({r['train_touches']}) | {r['skin_only_mm']:.3f}"
                     f" | {r['kinematics_known_mm']:.3f} / {r['kinematics_free_mm']:.3f} | {r['ratio']:.2f}"
                     f" | {', '.join(f'{v:.2f}' for v in links)} ({100 * r['links_within']:.0f} %)"
                     f" | {np.median(joints):.3f} / {max(joints):.3f} ({100 * r['joints_within']:.0f} %)"
                     f" | {', '.join(r['held']) or '-'} |")
    summary = []
    for n in sorted({r["per_pair"] for r in rows}):
        ratios = np.array([r["ratio"] for r in rows if r["per_pair"] == n])
        summary.append(f"{n} per pair: free / skin only median {np.median(ratios):.2f} ({ratios.min():.2f}-"
                       f"{ratios.max():.2f}), at most {RATIO_GOAL:g} in {int(np.sum(ratios <= RATIO_GOAL))} of {len(ratios)}")
    return [f"Linearised Bayesian bound with the kinematics free (see nao_skin.bench.bound, kinematic_bound_row): per"
            f" seed and count the default preset and {KINEMATIC_PRESET} simulated, the training split's touches"
            f" paired at the truth (rows: {options.closing_pairs}); in each of {SAMPLES} posterior draws the worst"
            f" part's median distance of its taxels from the truth, averaged, the taxels judged in the base frame at"
            f" {PREDICTION_POSES} of the training poses (as a calibration with kinematic corrections predicts its"
            f" error). Known: the skin's frames alone free; free: the joint offsets and links of every chain too"
            f" (what the frames stand for exactly is held, as the engine holds it). Within: the share of the free unknowns an efficient estimator brings"
            f" within the tolerance (its error normal with the std shown).", "", *table, "", "; ".join(summary) + "."]


def run(args) -> int:
    from nao_skin.bench.bound import bound_rows, kinematic_bound_row
    from nao_skin.errors import DataError
    from nao_skin.formats.outdir import BOUND_BENCHMARK, check_output_dir, clear_for_writing
    from nao_skin.model.skin import load_skin
    from nao_skin.plain import jsonable

    from nao_skin.sim.params import MAX_TOUCHES_PER_PAIR

    if args.kinematics is not None:
        given = [f"--{name}" for name in CHOICE_DEFAULTS if getattr(args, name) is not None]
        if given:
            raise DataError(f"--kinematics {args.kinematics!r} with {', '.join(given)}: those choose touches from a"
                            f" pool, and --kinematics chooses none (it simulates PER_PAIR touches per pair and takes"
                            f" the training split)")
    for name, value in CHOICE_DEFAULTS.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    for name, low in (("seeds", 1), ("pool", 10), ("batch", 1)):
        if getattr(args, name) < low:
            raise DataError(f"--{name} {getattr(args, name)}: expected a whole number >= {low}")
    if args.pool > MAX_TOUCHES_PER_PAIR:     # the simulator's limit, said of the option that asked for it
        raise DataError(f"--pool {args.pool}: expected at most {MAX_TOUCHES_PER_PAIR} touches per pair")
    from nao_skin.calibration.options import CalibrationOptions

    options = CalibrationOptions.from_mapping({} if args.rows is None else {"closing_pairs": args.rows},
                                              where="--rows {value!r}")
    skin = load_skin()
    from nao_skin.sim.params import pair_list, preset_names

    if args.preset not in preset_names():
        raise DataError(f"--preset {args.preset}: unknown preset (known: {', '.join(preset_names())})")
    if args.kinematics is not None:
        if args.preset != "default":
            raise DataError(f"--kinematics with --preset {args.preset}: it simulates its own presets (default and"
                            f" kinematic-error)")
        counts = _per_pair(args.kinematics)
    else:
        from nao_skin.sim.params import load_params

        sizes = _sizes(args.sizes, len(pair_list(load_params(args.preset))) * args.pool)
        if args.batch > sizes[0]:     # the greedy choice adds this many at a time: beyond a size it never stops at it
            raise DataError(f"--batch {args.batch}: expected a whole number from 1 to the smallest size, {sizes[0]}")
    check_output_dir(args.out, BOUND_BENCHMARK, force=args.force)
    out = Path(args.out)
    t0 = time.perf_counter()
    rows = []
    for seed in range(args.seeds):
        if args.kinematics is not None:
            for n in counts:
                print(f"bench-bound: seed {seed}: {n} touches per pair, kinematics known and free", flush=True)
                rows.append(kinematic_bound_row(skin, seed, n, options))
        else:
            print(f"bench-bound: seed {seed}: {args.pool} touches per pair, sizes {sizes}", flush=True)
            rows += bound_rows(skin, seed, args.pool, sizes, args.batch, options=options, preset=args.preset)
    argv = sys.argv[2:] + ([] if "--force" in sys.argv[2:] else ["--force"])
    seconds = time.perf_counter() - t0
    body = _kinematic_table(rows, options) if args.kinematics is not None else _choice_table(rows, args, options, sizes)
    md = ["# nao-skin bench-bound", "", f"Command: `nao-skin bench-bound {' '.join(argv)}`", "", *body, "",
          f"Wall time: {seconds:.0f} s.", ""]
    text = "\n".join(md)
    clear_for_writing(out, NAME, BOUND_BENCHMARK, OUTPUTS)       # an earlier output goes only now, when the new is ready
    (out / "bound_results.md").write_text(text)
    (out / "bound_results.json").write_text(json.dumps(jsonable({"rows": rows, "seconds": seconds}), indent=1) + "\n")
    print(text)
    print(f"-> {out / 'bound_results.md'}")
    return 0
