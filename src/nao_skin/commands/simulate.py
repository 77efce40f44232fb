"""``nao-skin simulate``: a simulated self-touch recording with its ground truth.

Writes ``DIR/touches`` (rosbag2 touch bag directory), ``DIR/truth_calibration.yaml``,
``DIR/truth_taxels/<part>.txt`` and ``DIR/simulation.yaml``. The same seed and
options give the same bytes on one machine and version (the bundled recording's
command and why today's touches differ from it: bags/README.md)::

    nao-skin simulate --preset default --seed 0 --touches-per-pair 1000 --out /tmp/sim_default

DIR must be new, empty, or the output of an earlier simulate run (then with
``--force``); see :mod:`nao_skin.outdir`.
"""
from __future__ import annotations

from pathlib import Path

from nao_skin.commands import add_skin_arguments, skin_config_file, skin_from_args

NAME = "simulate"
HELP = "simulate self-touch touches with a known true skin placement (bag + ground truth)"


def _shipped_presets() -> str:
    """The presets config/simulation.yaml defines, for the help text (the file is the one list)."""
    from nao_skin.errors import NaoSkinError
    from nao_skin.sim.params import preset_names

    try:
        return ", ".join(preset_names())
    except NaoSkinError:   # a broken package file is said where it is loaded, not in the help
        return "see the file"


def add_arguments(parser) -> None:
    parser.add_argument("--preset", default="default",
                        help=f"parameter preset of config/simulation.yaml or --params ({_shipped_presets()})")
    parser.add_argument("--seed", type=int, default=0, help="random seed (same seed, same bytes)")
    parser.add_argument("--touches-per-pair", type=int, default=None, metavar="N",
                        help="touches per hand/part pair (default: the preset's n_touches)")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="output directory: new, empty, or an earlier simulate output (with --force)")
    parser.add_argument("--params", default=None, metavar="YAML",
                        help="simulation parameters file (default: config/simulation.yaml)")
    add_skin_arguments(parser)
    parser.add_argument("--storage", default="sqlite3", choices=("sqlite3", "mcap"), help="rosbag2 storage")
    parser.add_argument("--force", action="store_true",
                        help="replace the outputs of an earlier run in DIR (never a file nao-skin did not write)")


def run(args) -> int:
    from nao_skin.errors import ConfigError
    from nao_skin.formats.bag import check_outside_bags
    from nao_skin.formats.outdir import RECORDING, as_checked, check_output_dir
    from nao_skin.sim.params import MAX_TOUCHES_PER_PAIR, check_pairs, default_params_file, load_params, pair_list
    from nao_skin.sim.simulate import BAG_NAME, simulate, write_outputs

    skin = skin_from_args(args)
    check_output_dir(args.out, RECORDING, inputs=(args.params, skin_config_file(args), *skin.source_files()),
                     force=args.force)
    checked = as_checked(args.out)       # what --force agreed to replace, nothing written there meanwhile
    # refused here, not after minutes of simulating (the bag's own check stays where it is written)
    check_outside_bags(Path(args.out) / BAG_NAME)
    if args.seed < 0:           # numpy's seed sequences take no negative entropy
        raise ConfigError(f"--seed {args.seed}: expected a whole number >= 0")
    overrides = {}
    if args.touches_per_pair is not None:
        if not 1 <= args.touches_per_pair <= MAX_TOUCHES_PER_PAIR:
            raise ConfigError(f"--touches-per-pair {args.touches_per_pair}: expected a whole number in"
                              f" 1..{MAX_TOUCHES_PER_PAIR}")
        overrides["n_touches"] = args.touches_per_pair
    params = load_params(args.preset, overrides, args.params)
    check_pairs(pair_list(params), skin, where=f"{args.params or default_params_file()}: preset '{args.preset}'")
    result = simulate(skin, params, args.seed)
    for path in write_outputs(result, skin, Path(args.out), preset=args.preset, storage=args.storage,
                              replacing=checked):
        print(path)
    for pair, info in result.pairs.items():
        print(f"{pair}: {info['recorded']} touches recorded ({info['touches']} poses, {info['duplicates']} duplicates,"
              f" {info['outliers']} outliers); {info['unreachable']} of {info['attempted']} target spots unreachable")
    return 0
