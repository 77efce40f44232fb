"""The real left hand-torso recording, read in place and never copied into the repository: the directory
``$NAO_SKIN_REAL_DATA`` names, else ``../shared/data/real_selftouch`` beside this checkout (as CI lays it out).

Tests take it through the ``real_dir`` fixture (conftest.py, :func:`require`): without it they skip with one
line saying what is missing and how to point them at it; under ``CI=true`` that is a failure, so CI never
passes without having run them. Everything else in the suite runs without the recording."""
import os
from pathlib import Path

from nao_skin.paths import REAL_DATA_FILES as FILES
from nao_skin.paths import REAL_DATA_VARIABLE as VARIABLE
from nao_skin.paths import REAL_LAYOUTS as LAYOUTS
from nao_skin.paths import REAL_RECORDING as RECORDING
from nao_skin.paths import real_data_missing

__all__ = ["FILES", "LAYOUTS", "RECORDING", "VARIABLE", "missing_line", "require", "require_fingertip", "taxel_args",
           "where"]


def where() -> Path:
    """Where the recording is looked for: the variable when it is set (a wrong one is said, never passed over for
    another place), else beside the checkout."""
    named = os.environ.get(VARIABLE)
    return Path(named) if named else Path(__file__).resolve().parents[2] / "shared" / "data" / "real_selftouch"


def missing_line(directory: Path):
    """None when ``directory`` holds every file of the recording, else the one line that says what is missing."""
    lacking = real_data_missing(directory)
    if not lacking:
        return None
    looked = f"{VARIABLE}={directory}" if os.environ.get(VARIABLE) else f"{VARIABLE} unset, looked in {directory}"
    return f"real recording missing ({', '.join(lacking)}; {looked}): set {VARIABLE}=DIR holding {', '.join(FILES)}"


def require_fingertip() -> Path:
    """The directory of the real fingertip recordings (``$NAO_SKIN_REAL_FINGERTIP``, else ``real_fingertip`` beside
    the self-touch recording's); else the test skips, or fails under ``CI=true``."""
    from nao_skin.paths import REAL_FINGERTIP, REAL_FINGERTIP_VARIABLE

    named = os.environ.get(REAL_FINGERTIP_VARIABLE)
    directory = Path(named) if named else where().parent / "real_fingertip"
    lacking = [name for name in REAL_FINGERTIP if not (directory / name).is_file()]
    if lacking:
        skip_outside_ci(f"real fingertip recordings missing ({', '.join(lacking)} in {directory}): set"
                        f" {REAL_FINGERTIP_VARIABLE}=DIR holding {', '.join(REAL_FINGERTIP)}")
    return directory


def in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() == "true"


def require() -> Path:
    """The recording's directory; else the test skips, or fails under ``CI=true``."""
    directory = where()
    line = missing_line(directory)
    if line is None:
        return directory
    skip_outside_ci(line)


def skip_outside_ci(line: str, module_level: bool = False) -> None:
    """Skip with ``line`` where what the tests need is missing; under ``CI=true`` fail with it instead, so CI
    never leaves them out (the real recording here, the real launch system in real_launch.py)."""
    import pytest

    if in_ci():
        pytest.fail(f"{line} (CI=true: these tests must run)", pytrace=False)
    pytest.skip(line, allow_module_level=module_level)


def taxel_args(directory: Path) -> list:
    """``--taxels PART=FILE`` for each layout of the recording, as the commands take them."""
    return [arg for part, name in LAYOUTS.items() for arg in ("--taxels", f"{part}={directory / name}")]
