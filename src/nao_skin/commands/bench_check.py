"""``nao-skin bench-check``: how well ``nao-skin check`` tells a skin part that moved from one that did not.

See :mod:`nao_skin.bench.check`. Writes ``check_results.md`` and ``check_results.json`` into ``--out`` (new,
empty, or an earlier bench-check output with ``--force``) and prints the table.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from nao_skin.commands import add_output_arguments

NAME = "bench-check"
HELP = ("benchmark nao-skin check: a part's mount shifted in a calibration of the simulated recording, checked"
        " with new touches of the same skin (moved part named, false alarms)")
OUTPUTS = ("check_results.md", "check_results.json")
MAX_MOVE_MM = 50.0


def add_arguments(parser) -> None:
    add_output_arguments(parser, "bench-check")
    parser.add_argument("--sim", help="simulated recording with truth_calibration.yaml (default: bags/sim_default)")
    parser.add_argument("--seeds", type=int, default=10, help="shuffles of the recording (default 10)")
    parser.add_argument("--reference", type=int, default=3000,
                        help="touches of each shuffle that make the calibration (default 3000)")
    parser.add_argument("--sizes", default="60,100,200,400",
                        help="new touches checked, comma-separated (default 60,100,200,400)")
    parser.add_argument("--moves", default="0,1.5,3", help="mm the part moved, comma-separated (default 0,1.5,3)")
    parser.add_argument("--part", default="l_hand", help="the skin part that moves (default l_hand)")


def _numbers(text: str, option: str, kind, low, high) -> list:
    from nao_skin.errors import DataError

    try:    # an empty entry ('60,,100') is a typo, not nothing
        values = sorted({kind(s) for s in text.split(",")})
    except ValueError:
        values = []
    if not values or not (low <= values[0] and values[-1] <= high):
        raise DataError(f"{option} {text!r}: expected numbers from {low:g} to {high:g}, comma-separated")
    return values


def run(args) -> int:
    from nao_skin.bench.check import check_rows, summary, summary_table
    from nao_skin.errors import DataError
    from nao_skin.formats.inputs import check_inputs, load_touches
    from nao_skin.formats.outdir import CHECK_BENCHMARK, check_output_dir, clear_for_writing
    from nao_skin.model.skin import load_skin
    from nao_skin.paths import package_dir
    from nao_skin.plain import jsonable
    from nao_skin.touch.datasets import deduplicate

    skin = load_skin()
    if args.part not in skin.parts:
        raise DataError(f"--part {args.part}: not a skin part ({', '.join(skin.parts)})")
    if not 1 <= args.seeds <= 1000:
        raise DataError(f"--seeds {args.seeds}: expected a whole number from 1 to 1000")
    if args.reference < 10:
        raise DataError(f"--reference {args.reference}: expected a whole number >= 10")
    sizes = _numbers(args.sizes, "--sizes", int, 10, 10**6)
    moves = _numbers(args.moves, "--moves", float, 0.0, MAX_MOVE_MM)
    sim = Path(args.sim) if args.sim else package_dir() / "bags" / "sim_default"
    check_output_dir(args.out, CHECK_BENCHMARK, force=args.force, inputs=[sim])
    check_inputs([sim])
    touches, _, truth = load_touches([sim], skin)
    if truth is None:
        raise DataError(f"{sim}: no truth_calibration.yaml next to the recording: not the simulator's")
    touches, _ = deduplicate(touches)
    if args.reference + sizes[-1] > touches.n_touches:
        raise DataError(f"--reference {args.reference} + --sizes up to {sizes[-1]}: more than the {touches.n_touches}"
                        f" touches of {sim}")
    out = Path(args.out)
    t0 = time.perf_counter()
    rows = check_rows(touches, skin, range(args.seeds), sizes, moves, args.part, args.reference,
                      say=lambda msg: print(msg, flush=True))
    seconds = time.perf_counter() - t0
    argv = sys.argv[2:] + ([] if "--force" in sys.argv[2:] else ["--force"])
    md = ["# nao-skin bench-check", "", f"Command: `nao-skin bench-check {' '.join(argv)}`", "",
          f"{sim.name}, {touches.n_touches} touches; per seed, {args.reference} of them (shuffled) make a calibration"
          f" with the default options, and `nao-skin check` judges it with each number of other touches of the same"
          f" skin, its {args.part}'s mount shifted in the calibration by each move (a direction drawn per seed; 0:"
          f" nothing moved), as the command runs it. Seconds: one check (the command also reads the recording), this machine.", "",
          *summary_table(rows), "", f"Wall time: {seconds:.0f} s.", ""]
    text = "\n".join(md)
    clear_for_writing(out, NAME, CHECK_BENCHMARK, OUTPUTS)      # an earlier output goes only now, when the new is ready
    (out / "check_results.md").write_text(text)
    (out / "check_results.json").write_text(json.dumps(jsonable({"rows": rows, "summary": summary(rows),
                                                                 "seconds": seconds}), indent=1) + "\n")
    print(text)
    print(f"-> {out / 'check_results.md'}")
    return 0
