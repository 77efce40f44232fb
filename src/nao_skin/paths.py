"""Where the package's data lives (source tree, venv or ROS install), and reading its YAML files."""
from __future__ import annotations

import os
import re
from pathlib import Path


MAX_TEXT_BYTES = 1 << 30   # a text input larger than this is not one of ours (a recording of 810 touches: 5 MB)


DANGLING_LINK = "a symbolic link that leads nowhere (a loop or a missing target)"   # Path.exists() False, is_symlink()


def not_a_file(mode: int) -> str | None:
    """What a path of this ``st_mode`` is when it is not a regular file ("a directory", "a FIFO", ...), else None."""
    import stat

    if stat.S_ISREG(mode):
        return None
    kinds = ((stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
             (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket"))
    return next((text for test, text in kinds if test(mode)), "not a regular file")


def identity(path: str | Path) -> tuple | None:
    """(device, inode) of what ``path`` names now, None when nothing: the same name may come to hold
    another directory or file (moved, removed, replaced)."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino


def free_sibling(path: str | Path, suffix: str) -> str:
    """``<path><suffix>``, or ``<path><suffix>2``, 3, ...: the first that names nothing yet (a place beside
    ``path`` for what must not replace anything)."""
    for n in range(1, 100_000):
        candidate = f"{path}{suffix}{n if n > 1 else ''}"
        if not os.path.lexists(candidate):
            return candidate
    raise FileExistsError(f"{path}{suffix}: every name up to {path}{suffix}99999 is taken")


def read_text(path: str | Path, what: str = "", error: type | None = None, name: str | None = None,
              limit: int = MAX_TEXT_BYTES) -> str:
    """The text of ``path``; one line naming it (``name``, default the path) and ``what`` it was read as when it
    cannot be read or is no text (a bag or another binary file given for a text one), as ``error`` (DataError),
    whose ``reason`` is the part in brackets. Only a regular file is read, and at most ``limit`` bytes:
    ``/dev/zero`` never ends, a FIFO waits."""
    from nao_skin.errors import DataError

    error = error or DataError
    what = f" {what}" if what else ""
    name = str(path) if name is None else name

    def unreadable(reason: str) -> Exception:
        exc = error(f"{name}: cannot read{what} ({reason})")
        exc.reason = reason
        return exc

    try:
        kind = not_a_file(os.stat(path).st_mode)
        if kind:
            raise unreadable(f"it is {kind}, not a regular file")
        with open(path, "rb") as f:
            data = f.read(limit + 1)
        if len(data) > limit:
            size = f"{limit >> 30} GiB" if limit >= 1 << 30 else f"{limit >> 20} MiB"
            raise unreadable(f"larger than {size}: is it the right file?")
        # UTF-8 whatever the locale; a byte-order mark (as Windows editors write it) is not part of the text
        return data.decode("utf-8-sig")
    except OSError as exc:
        raise unreadable(exc.strerror) from None
    except UnicodeDecodeError as exc:
        raise unreadable(f"not a text file: {exc.reason} at byte {exc.start}") from None


def read_yaml(path: str | Path, what: str):
    """The YAML document in ``path``; one-line ConfigError naming the file when unreadable, or when a
    mapping gives a key twice (YAML would keep the second silently: a hand edit lost without a word)."""
    import yaml

    from nao_skin.errors import ConfigError

    path = Path(path)
    text = read_text(path, what, ConfigError)
    try:
        return _load_unique_keys(text)
    except _DuplicateKey as exc:
        raise ConfigError(f"{path}: {exc}; give it once") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None


class _DuplicateKey(Exception):
    pass


def _unique_key_loader():
    """A safe YAML loader (the C one when built) that refuses a mapping giving a key twice (keys it
    merges in with ``<<`` may be given again: that is how YAML overrides them)."""
    import yaml

    base = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

    class UniqueKeyLoader(base):
        def construct_mapping(self, node, deep=False):
            seen: dict = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":   # '<<: *base' then a key of base: an override
                    continue
                key = self.construct_object(key_node, deep=True)
                if not isinstance(key, (str, int, float, bool)):   # the base constructor judges the rest
                    continue
                line = key_node.start_mark.line + 1
                if key in seen:
                    raise _DuplicateKey(f"key '{key}' given twice (lines {seen[key]} and {line})")
                seen[key] = line
            return super().construct_mapping(node, deep)

    # YAML 1.1 reads '1e-3' as a string (it wants '1.0e-3'); people and YAML 1.2 (rcl) write it as a number
    UniqueKeyLoader.add_implicit_resolver("tag:yaml.org,2002:float", _EXPONENT_FLOAT, list("-+0123456789."))
    return UniqueKeyLoader


_EXPONENT_FLOAT = re.compile(r"^[-+]?([0-9]+(\.[0-9]*)?|\.[0-9]+)[eE][-+]?[0-9]+$")


def parse_yaml(text: str):
    """YAML text read as the config files are (:func:`read_yaml`); ``yaml.YAMLError`` when it is not YAML,
    nests deeper than :data:`MAX_YAML_DEPTH` or a mapping gives a key twice."""
    import yaml

    try:
        return _load_unique_keys(text)
    except _DuplicateKey as exc:
        raise yaml.YAMLError(str(exc)) from None


def _load_unique_keys(text: str):
    import yaml

    check_yaml_depth(text)
    return yaml.load(text, Loader=_unique_key_loader())


def safe_load(text: str):
    """``yaml.safe_load`` (the C loader when built) of text nobody vouches for (a bag's metadata), with
    the depth check of :func:`parse_yaml`; ``yaml.YAMLError`` when it is not YAML."""
    import yaml

    check_yaml_depth(text)
    return yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))


# Deeper nesting than any config of this project: libyaml's C parser recurses without a limit (50000 levels
# of '[' end the process by a segfault) and PyYAML's own in Python (500 raise RecursionError)
MAX_YAML_DEPTH = 100


def check_yaml_depth(text: str) -> None:
    """``yaml.YAMLError`` when ``text`` nests flow collections (``[``, ``{``) or block ones (indentation,
    ``- - -``) deeper than :data:`MAX_YAML_DEPTH`; brackets inside quoted strings count too."""
    import yaml

    depth = deepest = 0
    if text.count("[") + text.count("{") > MAX_YAML_DEPTH:
        for bracket in re.findall(r"[\[\]{}]", text):
            depth = depth + 1 if bracket in "[{" else max(depth - 1, 0)
            deepest = max(deepest, depth)
    if deepest > MAX_YAML_DEPTH or re.search(rf"^(?:[ \t]|-[ \t]){{{2 * MAX_YAML_DEPTH},}}", text, re.MULTILINE):
        error = yaml.YAMLError(f"nested deeper than {MAX_YAML_DEPTH} levels")
        error.problem = str(error)
        raise error


def yaml_value(text: str):
    """A value given on the command line (``--set f_scale=1e-3``, ``--param NODE.NAME=[1, 2]``), read as the
    config files are; text that is not YAML stays the text."""
    import yaml

    try:
        return parse_yaml(text)
    except yaml.YAMLError:
        return text


def package_dir() -> Path:
    """The package's data root (config/, urdf/, bags/): the source tree, or share/nao_skin when colcon installed it."""
    source_tree = Path(__file__).resolve().parents[2]
    if (source_tree / "config" / "nao_skin.yaml").exists():
        return source_tree
    return installed_share_dir("nao_skin") or source_tree


def installed_share_dir(package: str) -> Path | None:
    """``share/<package>`` of the first prefix on $AMENT_PREFIX_PATH whose ament index lists the package (what
    ament_index_python's get_package_share_directory finds, read here without a ROS import), or None."""
    for prefix in filter(None, os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)):
        if (Path(prefix) / "share" / "ament_index" / "resource_index" / "packages" / package).is_file():
            return Path(prefix) / "share" / package
    return None


# The real left hand-torso recording of the thesis is no part of the package (nor of the repository): a
# directory holding it and its two layouts is named by this variable, for the bench and the tests.
REAL_DATA_VARIABLE = "NAO_SKIN_REAL_DATA"
REAL_RECORDING = "l_hand_torso.legacy.txt"
REAL_LAYOUTS = {"l_hand": "l_hand.taxels.txt", "torso": "torso.taxels.txt"}
REAL_DATA_FILES = (REAL_RECORDING, *REAL_LAYOUTS.values())


def real_data_missing(directory: Path) -> list:
    """The files of the real recording ``directory`` does not hold (each a regular file), in REAL_DATA_FILES order."""
    return [name for name in REAL_DATA_FILES if not (Path(directory) / name).is_file()]


# The same robot's fingertip recordings (its right fingertip pressed on the torso and on the left hand, the thesis'
# text format), read with the self-touch recording's layouts: named by this variable, else the directory
# ``real_fingertip`` beside the self-touch recording's.
REAL_FINGERTIP_VARIABLE = "NAO_SKIN_REAL_FINGERTIP"
# recording -> (the fingertip that pressed, the part it pressed)
REAL_FINGERTIP = {"r_finger_torso.legacy.txt": ("r_finger", "torso"), "r_finger_l_hand.legacy.txt": ("r_finger", "l_hand")}


def config_dir() -> Path:
    """``config/`` of the package, or $NAO_SKIN_CONFIG."""
    env = os.environ.get("NAO_SKIN_CONFIG")
    return Path(env) if env else package_dir() / "config"


def urdf_dir() -> Path:
    return package_dir() / "urdf"


def default_skin_config() -> Path:
    return config_dir() / "nao_skin.yaml"
