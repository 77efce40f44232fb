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
