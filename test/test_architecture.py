"""The package's layers and its freedom from import circles, as `.importlinter` states them, checked by import-linter."""
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def lint_imports(config: Path) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).with_name("lint-imports")
    return subprocess.run([str(exe if exe.exists() else shutil.which("lint-imports")), "--config", str(config),
                           "--no-cache"], cwd=str(ROOT), capture_output=True, text=True, timeout=300)


def test_every_architecture_contract_is_kept():
    run = lint_imports(ROOT / ".importlinter")
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    assert "0 broken" in run.stdout


def test_the_check_sees_a_broken_layer(tmp_path):
    """The same tool on a contract today's code breaks (the engine uses the model): it must say so."""
    config = tmp_path / "inverted.ini"
    config.write_text("[importlinter]\nroot_package = nao_skin\n\n[importlinter:contract:inverted]\n"
                      "name = model above calibration\ntype = layers\nlayers =\n    nao_skin.model\n"
                      "    nao_skin.calibration\n")
    run = lint_imports(config)
    assert run.returncode != 0 and "BROKEN" in run.stdout


def test_the_core_finds_an_installed_share_directory_through_the_ament_index(tmp_path, monkeypatch):
    """What ament_index_python would answer, read without a ROS import: the first prefix whose index lists the
    package wins; a prefix without the marker (a share dir of the same name alone) does not count."""
    from nao_skin.paths import installed_share_dir

    unlisted, first, second = tmp_path / "unlisted", tmp_path / "first", tmp_path / "second"
    (unlisted / "share" / "nao_skin").mkdir(parents=True)
    for prefix in (first, second):
        index = prefix / "share" / "ament_index" / "resource_index" / "packages"
        index.mkdir(parents=True)
        (index / "nao_skin").write_text("")
    monkeypatch.setenv("AMENT_PREFIX_PATH", f"{unlisted}::{first}:{second}")
    assert installed_share_dir("nao_skin") == first / "share" / "nao_skin"
    assert installed_share_dir("other") is None
    monkeypatch.delenv("AMENT_PREFIX_PATH")
    assert installed_share_dir("nao_skin") is None


# what the help of every command may import: no numpy, scipy or engine (they took most of a second to load)
_HEAVY = ("numpy", "scipy", "rosbags", "nao_skin.calibration.engine", "nao_skin.calibration.pairing",
          "nao_skin.model.skin")


def _imported_by(argv: list) -> tuple:
    """(exit code, the heavy modules imported) of ``nao-skin ARGV`` in a fresh interpreter."""
    code = ("import contextlib, io, json, sys\n"
            "from nao_skin.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            f"    rc = main({argv!r})\n"
            f"print(json.dumps([rc, sorted(m for m in sys.modules if m.split('.')[0] in {_HEAVY!r}"
            f" or m in {_HEAVY!r})]))\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    rc, modules = __import__("json").loads(run.stdout.splitlines()[-1])
    return rc, modules


def test_the_help_imports_no_engine():
    """``nao-skin --help`` and each command's help read only the command modules and the options table: a
    command imports numpy, scipy and the engine when it runs."""
    from nao_skin.cli import build_parser

    commands = list(build_parser()._subparsers._group_actions[0].choices)
    assert "calibrate" in commands and "simulate" in commands
    for argv in (["--help"], *([name, "--help"] for name in commands)):
        assert _imported_by(argv) == (0, []), argv


def test_the_help_check_sees_an_import():
    """The same check on a command that runs (it loads a recording): the engine's modules are seen."""
    rc, modules = _imported_by(["stats", str(ROOT / "bags" / "sim_default")])
    assert rc == 0 and "numpy" in modules and "nao_skin.model.skin" in modules
