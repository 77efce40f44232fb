"""``nao-skin layouts DIR``: write the project's default taxel layouts (deterministic)."""
from __future__ import annotations

NAME = "layouts"
HELP = "write the default Nao taxel layouts (skinManager position files) to a directory"


def add_arguments(parser) -> None:
    parser.add_argument("directory", help="output directory, e.g. config/layouts")
    parser.add_argument("--force", action="store_true",
                        help="replace files of the same names that differ from the default layouts (e.g. a robot's"
                             " own measured layout); without it they are kept and nothing is written")


def run(args) -> int:
    import tempfile
    from pathlib import Path

    from nao_skin.errors import DataError, os_reason
    from nao_skin.formats.outdir import replace_file
    from nao_skin.model.layouts import write_default_layouts
    from nao_skin.paths import DANGLING_LINK, not_a_file

    if not args.directory.strip():
        raise DataError("layouts '': expected a directory, e.g. config/layouts")
    directory = Path(args.directory)
    for place in (directory, *directory.absolute().parents):
        if place.is_symlink() and not place.exists():
            raise DataError(f"layouts {directory}: {place} is {DANGLING_LINK}; choose another place")
        if place.exists():
            if not place.is_dir():
                raise DataError(f"layouts {directory}: {place} is a file, not a directory; choose another place")
            break
    with tempfile.TemporaryDirectory() as tmp:
        try:
            fresh = write_default_layouts(tmp)
        except OSError as exc:       # the temporary directory's disk is full
            raise DataError(f"layouts {directory}: cannot write the layouts first into {tmp}"
                            f" ({os_reason(exc)})") from None
        targets = [directory / f.name for f in fresh]
        # regenerating config/layouts rewrites the same bytes; another file under a layout's name is someone's own
        differing = [t for f, t in zip(fresh, targets)
                     if (t.exists() or t.is_symlink()) and (not t.is_file() or t.read_bytes() != f.read_bytes())]
        # checked for every file before any is written: a failure half-way would leave some layouts replaced
        blocked = [t for t in targets if not t.is_symlink() and t.exists() and not t.is_file()]
        if blocked:
            raise DataError(f"layouts {directory}: {blocked[0]} is {not_a_file(blocked[0].stat().st_mode)}, not a"
                            f" regular file; nothing written; choose another place")
        if differing and not args.force:
            more = f" and {len(differing) - 1} more" if len(differing) > 1 else ""
            raise DataError(f"layouts {directory}: {differing[0]}{more} differs from the default layout; nothing"
                            f" written (pass --force to replace it, or choose another directory)")
        made = [place for place in (directory, *directory.absolute().parents) if not place.exists()]
        try:
            directory.mkdir(parents=True, exist_ok=True)
            for f, target in zip(fresh, targets):
                if target not in differing and target.exists():
                    continue              # the same bytes already (a read-only copy stays as it is)
                if target.is_symlink():   # --force replaces the link, never the file it points to elsewhere
                    target.unlink()
                # whole or not at all: a full disk keeps the old one; what differs is replaced on --force alone
                replace_file(target, f.read_bytes(), read_only_too=True)
        except OSError as exc:
            for place in made:            # the folders this run made, when nothing is left in them
                try:
                    place.rmdir()
                except OSError:
                    break
            raise DataError(f"layouts {directory}: cannot write ({exc.strerror}); choose another place") from None
    for target in targets:
        print(target)
    return 0
