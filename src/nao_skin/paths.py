"""Where the package's data lives (source tree, venv or ROS install), and reading its YAML files."""
from __future__ import annotations

import os
from pathlib import Path


def read_yaml(path: str | Path, what: str):
    """The YAML document in ``path``; one-line ConfigError naming the file when unreadable."""
    import yaml

    from nao_skin.errors import ConfigError

    path = Path(path)
    try:
        return yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read {what} ({exc.strerror})") from None
    except UnicodeDecodeError as exc:       # e.g. a bag or a binary file passed for a YAML one
        raise ConfigError(f"{path}: cannot read {what} (not a text file: {exc.reason} at byte {exc.start})") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None


def package_dir() -> Path:
    """The package's data root (config/, urdf/, bags/): the source tree, or share/nao_skin when colcon installed it."""
    source_tree = Path(__file__).resolve().parents[2]
    if (source_tree / "config" / "nao_skin.yaml").exists():
        return source_tree
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("nao_skin"))
    except Exception:  # noqa: BLE001 - any failure means "not installed the ROS way"
        return source_tree


def config_dir() -> Path:
    """``config/`` of the package, or $NAO_SKIN_CONFIG."""
    env = os.environ.get("NAO_SKIN_CONFIG")
    return Path(env) if env else package_dir() / "config"


def urdf_dir() -> Path:
    return package_dir() / "urdf"


def default_skin_config() -> Path:
    return config_dir() / "nao_skin.yaml"
