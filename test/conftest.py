"""Fixtures shared by the test files: the default skin and the shared real recording."""
import pytest
from real_data import REAL_DIR

from nao_skin.formats.legacy import read_legacy, skin_model_for
from nao_skin.model.robot import RobotModel
from nao_skin.model.skin import SkinModel
from nao_skin.paths import default_skin_config

ROBOT_YAML = default_skin_config().parent / "nao_h25.yaml"


@pytest.fixture(scope="session")
def real_skin():
    """The real recording's own layouts (read in place from shared/)."""
    robot = RobotModel.from_yaml(ROBOT_YAML)
    return skin_model_for({"l_hand": REAL_DIR / "l_hand.taxels.txt", "torso": REAL_DIR / "torso.taxels.txt"}, robot)


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
