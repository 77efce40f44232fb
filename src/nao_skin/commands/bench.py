"""``nao-skin bench``: speed against error of calibration strategies, and the simulator's hard cases.

Writes ``bench_results.md`` (the tables), ``speed_vs_error.png`` and
``bench_results.json`` (every row) into ``--out`` and prints the tables.
``--out`` must be new, empty, or an earlier bench's output (then with
``--force``); see :mod:`nao_skin.outdir`. The sections are written as each is
done into ``OUT.incomplete`` beside it, which becomes ``--out`` when the run is
whole: a run stopped or failed leaves ``--out`` as it was.
"""
from __future__ import annotations

import json
import os
import shutil
import sys
import time
from pathlib import Path

from nao_skin.commands import add_output_arguments, written_here
from nao_skin.paths import REAL_DATA_VARIABLE

NAME = "bench"
REAL_LEFT_OUT = (f"real section left out: no --real PATH, and {REAL_DATA_VARIABLE} (a directory holding the real"
                 f" recording and its layouts) is not set")
HELP = "benchmark calibration strategies (seconds against error) and the simulator's hard cases"

SECTIONS = ("speed", "real", "hard", "live", "kinematics", "fingertip", "scenes")
# what runs without --only: the kinematics, fingertip and scenes sections (seeds x sizes x calibrations) are asked for by name
DEFAULT_SECTIONS = ("speed", "real", "hard", "live")
# where the project keeps the tables `--readme` fills (between its BENCH markers), from the repository root
RESULTS_DOC = "docs/results.md"
LISTING = "<outlier listing>"      # long: written to the file, not printed
OUTPUTS = ("bench_results.md", "bench_results.json", "speed_vs_error.png")
QUICK = {"repeat": 1, "seeds": 2, "sweep": (50, 200), "sim_touches": 400, "hard_pairs": "l_hand-torso",
         "hard_touches": 150, "live_sizes": (400,), "live_repeat": 1}


def add_arguments(parser) -> None:
    parser.add_argument("--readme", metavar="FILE", nargs="?", const=RESULTS_DOC,
                        help=f"also put the tables into this file's results blocks and the plot beside it (the"
                             f" project's: {RESULTS_DOC}, also what --readme alone writes)")
    add_output_arguments(parser, "bench")
    parser.add_argument("--quick", action="store_true",
                        help=f"smoke run: {QUICK['repeat']} repetition, {QUICK['seeds']} seeds, sweep "
                             f"{'/'.join(map(str, QUICK['sweep']))} touches, {QUICK['sim_touches']} simulated touches,"
                             f" hard cases on {QUICK['hard_pairs']} with {QUICK['hard_touches']} touches")
    parser.add_argument("--only", action="append", choices=SECTIONS, default=[],
                        help="run only this section (repeatable): speed = bundled simulated recording, "
                             "real = the --real recordings (or $NAO_SKIN_REAL_DATA's), hard = simulator hard cases,"
                             " live = one live update (warm-started) at 1000 and 4000 touches of the simulated"
                             " recording, kinematics = presets calibrated with kinematics off / on / auto, fingertip ="
                             " the real fingertip recordings ($NAO_SKIN_REAL_FINGERTIP, else real_fingertip beside"
                             " $NAO_SKIN_REAL_DATA) and the simulator's fingertip scenes, alone and mixed with"
                             " self-touches, scenes = the three real recordings each predicted from the other two and"
                             " the scenes-kinematic preset, every scene together against alone (the last three only"
                             " when asked for)")
    parser.add_argument("--repeat", type=int, help="timed repetitions per strategy, median quoted (default 3)")
    parser.add_argument("--seeds", type=int, help="seeds per hard-case preset (default 20)")
    parser.add_argument("--sim", help="simulated recording with truth_calibration.yaml (default: bags/sim_default)")
    parser.add_argument("--sim-pairs", default="all",
                        help="part pairs of the simulated recording to calibrate, comma separated (e.g."
                             " l_hand-torso), or 'all' (default)")
    parser.add_argument("--sim-touches", type=int, default=1200,
                        help="random touches of the simulated recording to use, 0 = all (default 1200 of its ~4000:"
                             " all of them take ~35 s a calibration on 2 cores, x 3 repetitions x 12 strategies)")
    parser.add_argument("--real", action="append", default=[], metavar="PATH",
                        help="a real recording (legacy .txt or bag); repeatable. Without it the real section reads"
                             " the directory $NAO_SKIN_REAL_DATA names (l_hand_torso.legacy.txt with its layouts"
                             " l_hand.taxels.txt and torso.taxels.txt), and is left out, said, when that is unset")
    parser.add_argument("--taxels", action="append", default=[], metavar="PART=FILE",
                        help="taxel file of a part of the --real recordings; repeatable")
    parser.add_argument("--skin", help="skin config YAML for the --real recordings (default: the package's)")
    parser.add_argument("--presets", help="hard-case and kinematics presets, comma separated (default: all; the"
                                          " kinematics section adds kinematic-error)")
    parser.add_argument("--hard-pairs", default="all",
                        help="pairs simulated for the hard cases, comma separated (default: all four thesis pairs)")
    parser.add_argument("--hard-touches", type=int, help="touches per pair of the hard cases (default: the preset's)")
    parser.add_argument("--jobs", type=int, default=1,
                        help="worker processes for the hard cases (their times are not part of the result)")
    parser.add_argument("--strict", action="store_true", help="exit 1 when a row failed or a target is not met")


def _pairs(text: str, option: str, simulated: bool = False):
    """``--sim-pairs`` / ``--hard-pairs``: None for 'all', else the pairs, each a pair of the package's skin
    (``simulated``: one the simulator can make touch)."""
    from nao_skin.errors import DataError
    from nao_skin.model.skin import load_skin, parse_pairs

    if text == "all":
        return None
    pairs = list(parse_pairs(text.split(","), sorted(load_skin().parts), where=option))
    if not pairs:             # '' or ',' would otherwise mean every pair: not what was typed
        raise DataError(f"{option} {text!r}: expected HAND-PART pairs, comma separated (e.g. l_hand-torso), or 'all'")
    if simulated:             # every simulated case would fail, one row at a time
        from nao_skin.errors import ConfigError
        from nao_skin.sim.params import check_pairs

        try:
            check_pairs(pairs, load_skin())
        except ConfigError as exc:
            raise DataError(f"{option} {text!r}: {exc}") from None
    return pairs


def _check_counts(args) -> None:
    """The numbers of touches and workers, before anything runs: a bad one would only fail rows, silently."""
    from nao_skin.bench.pool import MAX_JOBS
    from nao_skin.errors import DataError
    from nao_skin.sim.params import MAX_TOUCHES_PER_PAIR

    if args.sim_touches < 0:
        raise DataError(f"--sim-touches {args.sim_touches}: expected a whole number >= 0 (0: all)")
    if args.hard_touches is not None and not 1 <= args.hard_touches <= MAX_TOUCHES_PER_PAIR:
        raise DataError(f"--hard-touches {args.hard_touches}: expected a whole number in 1..{MAX_TOUCHES_PER_PAIR}")
    if not 1 <= args.jobs <= MAX_JOBS:
        raise DataError(f"--jobs {args.jobs}: expected a whole number from 1 to {MAX_JOBS}")


def readme_text(readme: Path) -> str:
    """The README whose results section the bench fills; one line when it cannot be, checked before the run."""
    from nao_skin.errors import DataError
    from nao_skin.paths import read_text

    text = read_text(readme, name=f"--readme {readme}")
    if README_START not in text or README_END not in text:
        raise DataError(f"{readme}: no '{README_START}' ... '{README_END}' section to fill")
    return text


def _check_readme_run(readme: Path, sections: set, real: bool) -> None:
    """What ``--readme`` may replace: a block only with every section it holds (the main block: speed, real,
    hard, live; the kinematics block, when the README has one: kinematics), and the plot beside it only when
    an earlier bench wrote it; else one line before the run (a partial run dropped the other sections)."""
    from nao_skin.errors import DataError
    from nao_skin.paths import not_a_file

    text = readme_text(readme)
    main = sections & set(DEFAULT_SECTIONS)
    # the kinematics go to a block of their own when the README has one, else into the main block
    writes_main = bool(main) or ("kinematics" in sections and README_KIN_START not in text)
    missing = sorted(set(DEFAULT_SECTIONS) - main) + ([] if real or "real" not in main else
                                                      [f"real (no --real, {REAL_DATA_VARIABLE} unset)"])
    if writes_main and missing:
        raise DataError(f"--readme {readme}: its results section holds every section ({', '.join(DEFAULT_SECTIONS)});"
                        f" this run has no {', '.join(missing)}, whose figures would be lost: run them all, or"
                        f" leave out --readme")
    plot = readme.parent / README_PLOT
    if writes_main and (plot.exists() or plot.is_symlink()):
        kind = not_a_file(plot.stat().st_mode) if plot.exists() else "a symbolic link that leads nowhere"
        if kind or not written_here(plot, ("Matplotlib",)):     # the tag matplotlib writes into a PNG
            raise DataError(f"--readme {readme}: {plot} exists and is no plot of an earlier bench; nothing is written"
                            f" over somebody's file: move it first")


def _sim_input(args, quick: bool, say, keep: int | None = None):
    import numpy as np

    from nao_skin.bench.speed import BenchInput, restrict_pairs
    from nao_skin.errors import DataError
    from nao_skin.formats.inputs import load_touches
    from nao_skin.model.skin import load_skin
    from nao_skin.paths import package_dir
    from nao_skin.touch.datasets import deduplicate

    path = Path(args.sim) if args.sim else package_dir() / "bags" / "sim_default"
    skin = load_skin()
    touches, _, truth = load_touches([path], skin, log=say)
    if truth is None:
        raise DataError(f"{path}: no truth_calibration.yaml next to the recording; the speed matrix needs ground truth")
    touches, _ = deduplicate(touches)
    pairs = _pairs(args.sim_pairs, "--sim-pairs")
    label = "all pairs"
    if pairs:
        touches = restrict_pairs(touches, pairs)
        label = ", ".join(f"{a}-{b}" for a, b in pairs)
        if touches.n_touches == 0:
            raise DataError(f"{path}: no touch of the pairs {label}")
    keep = keep if keep is not None else QUICK["sim_touches"] if quick else args.sim_touches
    if keep and touches.n_touches > keep:
        touches = touches.subset(np.sort(np.random.default_rng(0).choice(touches.n_touches, keep, replace=False)))
    name = f"simulated {path.name} ({label}, {touches.n_touches}{' random' if keep else ''} touches, 70/30 split)"
    return BenchInput(name, touches, skin, truth)


def _real_from_environment(args, sections: set) -> Path | None:
    """Without ``--real``, the real section reads the recording in the directory $NAO_SKIN_REAL_DATA names (its
    layouts too, unless ``--taxels`` gives them): that directory, put into ``args``; None when the section
    does not run, has its ``--real`` or the variable is unset (then the section is left out, said by
    :data:`REAL_LEFT_OUT`). Asked for by name (``--only real``) without either, or the directory lacking a
    file, it is one line."""
    from nao_skin.errors import DataError
    from nao_skin.paths import REAL_DATA_FILES, REAL_LAYOUTS, REAL_RECORDING, real_data_missing

    if "real" not in sections or args.real:
        return None
    named = os.environ.get(REAL_DATA_VARIABLE)
    if not named:
        if "real" in args.only:
            raise DataError(f"--only real needs a real recording: --real PATH (with --taxels PART=FILE of its"
                            f" layouts), or {REAL_DATA_VARIABLE}=DIR holding {', '.join(REAL_DATA_FILES)}")
        return None
    directory = Path(named)
    lacking = real_data_missing(directory)
    if lacking:
        raise DataError(f"{REAL_DATA_VARIABLE}={named}: no {', '.join(lacking)} there (expected a directory holding"
                        f" {', '.join(REAL_DATA_FILES)}); set it to one, or give --real PATH")
    args.real = [str(directory / REAL_RECORDING)]
    if not args.taxels:
        args.taxels = [f"{part}={directory / name}" for part, name in REAL_LAYOUTS.items()]
    return directory


FINGERTIP_LEFT_OUT = (f"{REAL_DATA_VARIABLE} (the self-touch recording's directory, whose layouts they are read"
                      f" with) is unset, or neither $NAO_SKIN_REAL_FINGERTIP nor real_fingertip beside it holds them")


def _fingertip_directory() -> Path | None:
    """The real fingertip recordings' directory: $NAO_SKIN_REAL_FINGERTIP, else ``real_fingertip`` beside the
    directory $NAO_SKIN_REAL_DATA names (whose layouts they are read with); None when that is unset or neither
    holds them."""
    from nao_skin.paths import REAL_FINGERTIP, REAL_FINGERTIP_VARIABLE

    if not os.environ.get(REAL_DATA_VARIABLE):
        return None
    named = Path(os.environ.get(REAL_FINGERTIP_VARIABLE) or Path(os.environ[REAL_DATA_VARIABLE]).parent / "real_fingertip")
    return named if all((named / name).is_file() for name in REAL_FINGERTIP) else None


def _real_layouts() -> dict:
    """The real recordings' layouts, part -> file, from $NAO_SKIN_REAL_DATA's directory (the fingertip recordings
    are read with the self-touch recording's)."""
    from nao_skin.paths import REAL_LAYOUTS

    return {part: Path(os.environ.get(REAL_DATA_VARIABLE, "")) / name for part, name in REAL_LAYOUTS.items()}


def _real_inputs(args, say, skin) -> list:
    from nao_skin.bench.speed import BenchInput
    from nao_skin.formats.inputs import load_touches
    from nao_skin.touch.datasets import deduplicate

    out = []
    for path in args.real:
        touches, _, truth = load_touches([path], skin, log=say)
        touches, n_dup = deduplicate(touches)
        out.append(BenchInput(f"real {Path(path).name} ({touches.n_touches} touches after {n_dup} duplicates,"
                              f" 70/30 split by pose, seed 0)", touches, skin, truth))
    return out


def run(args) -> int:
    from nao_skin.bench import hard, kinematics, speed
    from nao_skin.commands import skin_from_args
    from nao_skin.errors import DataError
    from nao_skin.formats.inputs import check_inputs
    from nao_skin.formats.outdir import BENCHMARK, check_output_dir, clear_for_writing, replace_dir
    from nao_skin.model.skin import load_skin
    from nao_skin.paths import free_sibling, package_dir

    say = lambda msg: print(msg, flush=True)  # noqa: E731
    sections = set(args.only or DEFAULT_SECTIONS)
    real_dir = _real_from_environment(args, sections)
    repeat = args.repeat if args.repeat is not None else (QUICK["repeat"] if args.quick else 3)
    seeds = args.seeds if args.seeds is not None else (QUICK["seeds"] if args.quick else 20)
    sweep = QUICK["sweep"] if args.quick else speed.TOUCH_SWEEP
    if repeat < 1 or seeds < 1:
        raise DataError(f"--repeat {repeat} / --seeds {seeds}: both must be at least 1")
    _check_counts(args)
    named = [p.strip() for p in args.presets.split(",") if p.strip()] if args.presets is not None else None
    if named is not None and not named:        # '' would otherwise mean every preset: the longest run there is
        raise DataError(f"--presets {args.presets!r}: expected preset names, comma separated")
    presets = named or list(hard.HARD_PRESETS)
    kin_presets = named or list(kinematics.KINEMATIC_PRESETS)
    hard_pairs = QUICK["hard_pairs"] if args.quick and args.hard_pairs == "all" else args.hard_pairs
    if sections & {"hard", "kinematics"}:   # mistakes in the arguments are told before the output dir is touched
        from nao_skin.sim.params import preset_names

        unknown = sorted((set(presets) | set(kin_presets)) - set(preset_names()))
        if unknown:
            raise DataError(f"--presets: unknown preset(s) {', '.join(unknown)} (known: {', '.join(preset_names())})")
        _pairs(hard_pairs, "--hard-pairs", simulated=True)
    if "speed" in sections:
        _pairs(args.sim_pairs, "--sim-pairs")
    sim = (args.sim or package_dir() / "bags" / "sim_default") if sections & {"speed", "live"} else None
    check_output_dir(args.out, BENCHMARK, force=args.force,
                     inputs=[sim, *args.real, *(item.partition("=")[2] for item in args.taxels), args.skin,
                             args.readme])
    # every input is checked before the output directory is cleared: a typo must not cost an earlier benchmark
    if sim is not None:
        check_inputs([sim])
    real_skin = None
    if "real" in sections and args.real:
        check_inputs(args.real)
    if ("real" in sections and args.real) or args.skin or args.taxels:
        real_skin = skin_from_args(args)     # read even when no section uses it: a broken one is one line now
    if args.readme:
        _check_readme_run(Path(args.readme), sections, bool(args.real))
    # read before an earlier output is cleared: a recording that turns out broken must not cost it
    inputs = []
    if "speed" in sections:
        inputs.append(_sim_input(args, args.quick, say))
    if "real" in sections and args.real:
        inputs += _real_inputs(args, say, real_skin)
    out = Path(args.out)
    staging: list = []

    def results_dir() -> Path:
        """Where the sections are written as each is done: ``OUT.incomplete`` beside ``out``, made when the
        first result is ready. It replaces ``out`` once the run is whole; a run stopped or failed before
        leaves ``out`` as it was and the sections finished in ``OUT.incomplete``, marked so."""
        if not staging:
            staging.append(clear_for_writing(free_sibling(out, ".incomplete"), NAME, BENCHMARK, OUTPUTS))
        return staging[0]

    try:
        t_start = time.perf_counter()
        # with --force, the quoted command also runs again where its earlier output is
        argv = sys.argv[2:] + ([] if "--force" in sys.argv[2:] else ["--force"])
        md = [f"# nao-skin bench{' (quick)' if args.quick else ''}", "",
              f"Command: `nao-skin bench {' '.join(argv)}`", ""]
        if real_dir is not None:         # the directory is this machine's: the variable is what to set elsewhere
            md += [f"Real recording: `${REAL_DATA_VARIABLE}` ({Path(args.real[0]).name} with"
                   f" {', '.join(Path(t.partition('=')[2]).name for t in args.taxels)})", ""]
        elif "real" in sections and not args.real:
            say(REAL_LEFT_OUT)
            md += [REAL_LEFT_OUT[0].upper() + REAL_LEFT_OUT[1:] + ".", ""]
        results: dict = {"quick": args.quick, "repeat": repeat, "seeds": seeds}
        failures = 0
        listing = ""

        if inputs:
            variants = speed.strategy_variants(sweep)
            say(f"speed against error: {len(variants)} strategies x {len(inputs)} inputs x {repeat} repetitions"
                f" (interleaved; the finite-difference row runs once)")
            rows = speed.speed_matrix(inputs, variants, repeat, say)
            results["speed"] = rows
            md += ["## Speed against error", "",
                   f"Each strategy changes one option of the default; times are the median of {repeat} interleaved"
                   f" run(s) on this machine, in one process; the finite-difference row runs once (slow). Errors:"
                   f" simulated input: distance of every calibrated taxel from its true position; real input: mean"
                   f" closest pair per touch, all touches (explained: touches within the gate).", ""]
            md += ["Headline (default against finite differences, same problem):", ""]
            for inp in inputs:
                md.append("- " + speed.headline(rows, inp.name))
            md += ["", "Targets (default row):", ""] + ["- " + line for line in speed.target_lines(rows)]
            goals = speed.speed_goal_lines(rows)
            if goals:
                md += ["", "Speed goal of the accuracy issue (default row, median of the runs; not counted as a"
                           " failure):", ""] + ["- " + line for line in goals]
            for inp in inputs:
                md += ["", f"### {inp.name}", "", speed.speed_table(rows, inp.name)]
            speed.plot_speed_vs_error(rows, results_dir() / "speed_vs_error.png")
            md += ["", "![speed against error](speed_vs_error.png)", ""]
            for inp in (i for i in inputs if i.truth is None):
                say(f"{inp.name}: the default calibration over {speed.REAL_SPLITS} seeded splits")
                spread, lines = speed.real_split_lines(inp)
                results.setdefault("real_splits", {})[inp.name] = spread
                md += [f"### {inp.name}: over {spread['k']} seeded splits", "",
                       f"The default calibration on the splits of seeds {spread['seeds'][0]}..{spread['seeds'][-1]}"
                       f" ({int(100 * spread['test_fraction'])} % test each, {spread['kind']}): one split's figure moves"
                       f" with its seed by"
                       f" about the spread below.", "", *lines, ""]
                failures += any(line.startswith("Targets") and "NOT met" in line for line in lines)
            legacy = [p for p in args.real if str(p).endswith(".txt")] if "real" in sections else []
            if legacy:
                md += ["### Reading the thesis' text format", "",
                       f"Whole read, every touch parsed and checked (median of {repeat} interleaved runs): the exact"
                       f" reader (Python's ast, any file Python's literal syntax takes) against the fast one (the C JSON"
                       f" decoder, for the recorder's plain output; any other file falls back to the exact reader).", ""]
                for path in legacy:
                    t = speed.legacy_read_times(path, inputs[-1].skin, repeat)
                    results.setdefault("legacy_read", {})[str(path)] = t
                    md.append(f"- {Path(path).name} ({t['touches']} touches loaded): exact {t['exact_s']:.2f} s, fast"
                              f" {t['fast_s']:.3f} s (x{t['exact_s'] / t['fast_s']:.0f}); same touches and skip reasons:"
                              f" {'yes' if t['same_touches'] else 'NO'}")
                md.append("")
            _write(results_dir(), md, results, listing)      # kept even if a later section fails
            failures += sum(r["status"] != "ok" for r in rows) + sum("NOT met" in t for t in speed.target_lines(rows))

        if "hard" in sections:
            setup, scene = _hard_setup(args, hard_pairs)
            say(f"hard cases: {len(presets)} presets x {seeds} seeds on {scene}")
            rows = hard.hard_case_matrix(load_skin(), presets, range(seeds), setup, max(1, args.jobs), say)
            results["hard"] = rows
            md += ["## Hard cases", "",
                   f"Simulated in memory ({scene}, touches per pair: "
                   f"{setup.n_touches or 'the preset default'}), {seeds} seeds each, deduplicated, calibrated with the"
                   f" default options. Converged: final true median taxel error <= {hard.CONVERGED_MM:g} mm over the"
                   f" calibrated parts. Condition: Jacobi-scaled normal equations of the last stage. Injected outliers:"
                   f" touches labelled '{hard.INJECTED_OUTLIER_LABEL}' in the training split (the experimenter's hand"
                   f" and stray taxels leave the true contact in the touch). Held frames: what no stage estimated (a triangle"
                   f" with < 10 paired activations in every stage, a patch or mount direction the touches do not"
                   f" excite). Own correction worse than nominal: a held frame's taxels, every other frame at the truth,"
                   f" end farther from the truth with the frame's correction than with its held components at nominal"
                   f" (the frame was moved where the data says nothing). Absolute: the held frames' taxels under the"
                   f" whole calibration against the nominal skin, mean over runs, and how many frames end farther"
                   f" (information: they ride on their patch and mount, which the data determined).", "", hard.hard_case_tables(rows), "",
                   "Touches set aside in the outlier case (keys):", "", LISTING, ""]
            listing = hard.outlier_listing(rows) or "(none run)"
            summary = hard.hard_case_summary(rows)
            results["hard_summary"] = summary
            _write(results_dir(), md, results, listing)
            failures += sum(r["status"] != "ok" for r in rows) + sum(s["met"] != "yes" for s in summary)

        if "live" in sections:
            from nao_skin.bench import live

            sizes = QUICK["live_sizes"] if args.quick else live.LIVE_SIZES
            live_repeat = QUICK["live_repeat"] if args.quick else max(repeat, 5)
            inp = _sim_input(args, quick=False, say=say, keep=0)
            say(f"live update: {', '.join(map(str, sizes))} touches x {live_repeat} random subsets")
            timings = live.update_timings(inp.touches, inp.skin, inp.truth, sizes, repeat=live_repeat, say=say)
            results["live"] = [vars(t) for t in timings]
            target = live.update_target_line(timings)
            md += ["## One live update", "", live.__doc__.split("\n\n", 1)[1].replace("\n", " ").strip(), "",
                   f"Input: {inp.name}; {live.LIVE_STEP} new touches per update, {live_repeat} subsets per size.", "",
                   *live.update_table(timings), "", f"- {target}", ""]
            _write(results_dir(), md, results, listing)
            failures += "NOT met" in target

        if "fingertip" in sections:
            from nao_skin.bench import fingertip

            directory = _fingertip_directory()
            real = []
            if directory is not None:
                say(f"fingertip: the real fingertip recordings in {directory}, {fingertip.REAL_SPLITS} splits each")
                real = fingertip.real_rows(directory, _real_layouts(), say=say)
            else:
                md += [f"Real fingertip recordings left out: {FINGERTIP_LEFT_OUT}.", ""]
            say(f"fingertip: simulated, {seeds} seeds x {len(fingertip.SIM_SIZES)} sizes, alone and mixed")
            sim_rows = fingertip.sim_rows(load_skin(), range(seeds), say=say)
            mixed = fingertip.mixed_rows(load_skin(), range(seeds), say=say)
            results["fingertip"] = {"real": real, "sim": sim_rows, "mixed": mixed}
            md += ["## Fingertip scenes", "", fingertip.__doc__.split("\n\n", 1)[1].replace("\n", " ").strip(), "",
                   *fingertip.tables(real, sim_rows, mixed)]
            failures += sum(not r["met"] for r in real)
            _write(results_dir(), md, results, listing)

        if "scenes" in sections:
            from nao_skin.bench import scenes

            directory = _fingertip_directory()
            real = []
            if directory is not None:
                from nao_skin.paths import REAL_RECORDING

                say("scenes: the real self-touch and fingertip recordings, each predicted from the others")
                real = scenes.real_rows(Path(os.environ[REAL_DATA_VARIABLE]) / REAL_RECORDING, directory,
                                        _real_layouts(), say=say)
            else:
                md += [f"Real recordings left out: {FINGERTIP_LEFT_OUT}.", ""]
            say(f"scenes: simulated scenes-kinematic, {seeds} seeds")
            sim_rows = scenes.sim_rows(load_skin(), range(seeds), say=say)
            results["scenes"] = {"real": real, "sim": sim_rows}
            md += ["## Every scene at once", "", scenes.__doc__.split("\n\n", 1)[1].replace("\n", " ").strip(), "",
                   *scenes.tables(real, sim_rows)]
            failures += sum(not s["met"] for r in real for s in r["scenes"])
            _write(results_dir(), md, results, listing)

        if "kinematics" in sections:
            setup, scene = _hard_setup(args, hard_pairs)
            say(f"kinematics: {len(kin_presets)} presets x {seeds} seeds x {len(kinematics.KINEMATIC_MODES)} modes on {scene}")
            rows = kinematics.kinematics_matrix(load_skin(), kin_presets, range(seeds), setup, max(1, args.jobs), say)
            results["kinematics"] = rows
            results["kinematics_summary"] = kinematics.kinematics_summary(rows)
            goals = kinematics.kinematics_goal_lines(rows)
            md += ["## Kinematics", "",
                   f"Each preset and seed simulated once ({scene}, touches per pair: "
                   f"{setup.n_touches or 'the preset default'}), calibrated with kinematics off, on and auto"
                   f" (calibration option `kinematics`). True taxel error: every taxel of the calibrated parts; where"
                   f" the calibration or the truth corrects the kinematics, in the torso frame at the training"
                   f" touches' poses (calibrated skin on the calibrated robot against the true skin on the true"
                   f" robot), else in the chain-end frame. Seconds: the engine's. Held-out gain: how much closer"
                   f" the kinematic path brings the test split's closest taxel pairs (fabric surfaces); auto keeps it"
                   f" when that gain's one-sided 95 % bound over the test touches reaches kinematics_min_gain.", "",
                   "Goals:", "", *("- " + line for line in goals), "", kinematics.kinematics_tables(rows), ""]
            failures += sum(r["status"] != "ok" for r in rows) + sum("NOT met" in line for line in goals)
            _write(results_dir(), md, results, listing)

        results["seconds"] = time.perf_counter() - t_start
        md.append(f"Benchmark wall time: {results['seconds']:.0f} s.")
        text = _write(results_dir(), md, results, listing, complete=True)
        replace_dir(results_dir(), out)
        print(text.replace(LISTING, f"(in {out / 'bench_results.md'})"))
        print(f"-> {out / 'bench_results.md'}, {out / 'speed_vs_error.png'}" if inputs else f"-> {out / 'bench_results.md'}")
        if args.readme:
            update_readme(Path(args.readme), out)
            print(f"-> {args.readme} (results section and plot)")
        return 1 if (args.strict and failures) else 0
    except BaseException:
        if staging and any((staging[0] / name).exists() for name in OUTPUTS):
            say(f"the sections finished so far: {staging[0]} (incomplete; {out} is as it was)")
        elif staging:
            shutil.rmtree(staging[0], ignore_errors=True)
        raise


README_START, README_END = "<!-- BENCH:START -->", "<!-- BENCH:END -->"
# the kinematics section (a run of its own, about half an hour) has a block of its own when the README has one
README_KIN_START, README_KIN_END = "<!-- BENCH:KINEMATICS:START -->", "<!-- BENCH:KINEMATICS:END -->"
KINEMATICS_TITLE = "## Kinematics"
README_PLOT = "README-speed-vs-error.png"


def update_readme(readme: Path, out: Path) -> None:
    """Put the benchmark's tables between the README's markers and its plot beside the README.

    With a kinematics block in the README, the run's kinematics section goes there and the rest into
    the main block; a block the run has nothing for is left as it was."""
    from nao_skin.errors import OutputError, os_reason
    from nao_skin.formats.outdir import replace_file

    text = readme_text(readme)
    body = (out / "bench_results.md").read_text()
    body = body.split("\n", 1)[1].lstrip("\n")                       # drop the '# nao-skin bench' title
    # the README keeps the summaries; per-seed rows and touch keys stay in bench_results.md
    kept, skipping = [], False
    for line in body.splitlines():
        if line.startswith("| preset | seed |") or line.startswith("Touches set aside in the outlier case"):
            skipping = True
            kept.append(f"(Per-seed rows and the keys of the touches set aside: `{out / 'bench_results.md'}`.)")
        elif skipping and (line.startswith("Benchmark wall time") or line.startswith("## ")):
            skipping = False
        if not skipping:
            kept.append(line)
    body = "\n".join(line for i, line in enumerate(kept) if i == 0 or line != kept[i - 1])
    blocks = {README_START: body}
    if README_KIN_START in text and f"\n{KINEMATICS_TITLE}" in "\n" + body:
        head, _, kin = ("\n" + body).partition(f"\n{KINEMATICS_TITLE}")
        command = head.strip().splitlines()[0]          # the 'Command: ...' line, for both blocks
        kin_lines = (KINEMATICS_TITLE + kin).splitlines()
        wall = [line for line in kin_lines if line.startswith("Benchmark wall time")]
        kin_lines = [line for line in kin_lines if not line.startswith("Benchmark wall time")]
        blocks = {README_KIN_START: "\n".join([command, "", *kin_lines, *wall])}
        if "\n## " in head:                              # the run had other sections too
            blocks[README_START] = "\n".join([head.strip(), *wall])
    ends = {README_START: README_END, README_KIN_START: README_KIN_END}
    for start, block in blocks.items():
        block = ("\n" + block).replace("](speed_vs_error.png)", f"]({README_PLOT})").replace("\n## ", "\n### ")
        before, rest = text.split(start, 1)
        _, after = rest.split(ends[start], 1)
        text = f"{before}{start}\n{block.strip()}\n{ends[start]}{after}"
    # each whole or not at all: a README cut short by a full disk would lose what the user wrote in it
    plot = readme.parent / README_PLOT
    try:
        replace_file(readme, text)
        if README_START in blocks and (out / "speed_vs_error.png").exists():
            replace_file(plot, (out / "speed_vs_error.png").read_bytes())
    except OSError as exc:
        raise OutputError(f"--readme {readme}: cannot write it or its plot {plot.name} ({os_reason(exc)});"
                          f" what was not replaced is unchanged, the results are in {out}") from None


def _hard_setup(args, hard_pairs: str) -> tuple:
    """The simulated scene of the hard cases and the kinematics, and its words for the tables."""
    from nao_skin.bench.hard import HardCaseSetup

    setup = HardCaseSetup(pairs=_pairs(hard_pairs, "--hard-pairs"),
                          n_touches=args.hard_touches or (QUICK["hard_touches"] if args.quick else None))
    return setup, (", ".join(f"{a}-{b}" for a, b in setup.pairs) if setup.pairs else "all four thesis pairs")


INCOMPLETE = ("**Incomplete: the run was stopped or failed before its end (or is still running); the sections"
              " below are those it finished.**")


def _write(out: Path, md: list, results: dict, listing: str, complete: bool = False) -> str:
    from nao_skin.plain import jsonable

    text = "\n".join(md) + "\n"
    marked = text if complete else text.replace("\n\n", f"\n\n{INCOMPLETE}\n\n", 1)
    (out / "bench_results.md").write_text(marked.replace(LISTING, listing))
    (out / "bench_results.json").write_text(json.dumps(jsonable(dict(results, complete=complete),
                                                                skip_keys=("trace",)), indent=1) + "\n")
    return text

