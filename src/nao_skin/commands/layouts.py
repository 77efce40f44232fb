"""``nao-skin layouts DIR``: write the project's default taxel layouts (deterministic)."""
from __future__ import annotations

NAME = "layouts"
HELP = "write the default Nao taxel layouts (skinManager position files) to a directory"


def add_arguments(parser) -> None:
    parser.add_argument("directory", help="output directory, e.g. config/layouts")


def run(args) -> int:
    from nao_skin.model.layouts import write_default_layouts

    for path in write_default_layouts(args.directory):
        print(path)
    return 0
