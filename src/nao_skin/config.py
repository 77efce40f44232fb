"""Where the packaged configuration lives, in a source tree, a venv or a ROS install."""
from __future__ import annotations

import os
from pathlib import Path


def read_yaml(path: str | Path, what: str):
    """The YAML document in ``path``; one-line ConfigError naming the file when unreadable."""
    import yaml

    from .errors import ConfigError

    path = Path(path)
    try:
        return yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read {what} ({exc.strerror})") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None


def config_dir() -> Path:
    """``config/`` of the package: $NAO_SKIN_CONFIG, the source tree, or the ROS share dir."""
    env = os.environ.get("NAO_SKIN_CONFIG")
    if env:
        return Path(env)
    here = Path(__file__).resolve()
    source_tree = here.parents[2] / "config"
    if (source_tree / "nao_skin.yaml").exists():
        return source_tree
    try:  # installed by colcon: share/nao_skin/config
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("nao_skin")) / "config"
    except Exception:  # noqa: BLE001 - any failure means "not installed the ROS way"
        return source_tree


def default_skin_config() -> Path:
    return config_dir() / "nao_skin.yaml"


def load_default_skin():
    from .skin import SkinModel

    return SkinModel.from_yaml(default_skin_config())
