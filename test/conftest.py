"""Fixtures shared by the test files: the default skin and the shared real recording."""
import pytest
from real_data import REAL_DIR

from nao_skin.formats.legacy import read_legacy
from nao_skin.model.skin import SkinModel, load_skin
from nao_skin.paths import default_skin_config


@pytest.fixture(scope="session")
def real_skin():
    """The recording's two parts with its own layouts (read in place from shared/), as the commands build them
    (``--taxels``), without the parts it never touched."""
    skin = load_skin(taxel_files={"l_hand": REAL_DIR / "l_hand.taxels.txt", "torso": REAL_DIR / "torso.taxels.txt"})
    return SkinModel(skin.robot, {name: skin.parts[name] for name in ("l_hand", "torso")}, skin.source,
                     skin.self_touch)


@pytest.fixture(scope="session")
def real_loaded(real_skin):
    """(TouchSet, LoadReport) of the real left hand-torso recording."""
    return read_legacy(REAL_DIR / "l_hand_torso.legacy.txt", real_skin)


@pytest.fixture(scope="session")
def default_skin():
    return SkinModel.from_yaml(default_skin_config())


@pytest.fixture(scope="session")
def real(real_loaded):
    """The real recording's touches (files that need the load report define their own)."""
    return real_loaded[0]


@pytest.fixture(scope="session")
def skin(default_skin):
    return default_skin
