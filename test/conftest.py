"""Fixtures shared by the test files: the default skin and the real recording (see real_data.py: it is not in
the repository; a test that asks for it skips without it, and fails under CI=true)."""
import os
import sys

# Two test workers share the two cores with the nodes their sessions start (those inherit this). numpy
# outside a calibration (which limits itself to one) runs OpenBLAS with a spinning thread per core, so one
# worker's simulation could take both cores from the other's nodes: one BLAS thread per process.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import pytest  # noqa: E402
import real_data  # noqa: E402

from nao_skin.formats.legacy import read_legacy  # noqa: E402
from nao_skin.model.skin import SkinModel, load_skin  # noqa: E402
from nao_skin.paths import default_skin_config  # noqa: E402


@pytest.fixture(scope="session")
def real_dir():
    """The directory holding the real recording and its two layouts, read in place."""
    return real_data.require()


@pytest.fixture(scope="session")
def real_fingertip_dir(real_dir):
    """The directory holding the real fingertip recordings (read with ``real_dir``'s layouts)."""
    return real_data.require_fingertip()


@pytest.fixture(scope="session")
def real_recording(real_dir):
    """The real left hand-torso recording (the thesis' text format)."""
    return real_dir / real_data.RECORDING


@pytest.fixture(scope="session")
def real_taxels(real_dir):
    """``--taxels PART=FILE`` of the real recording's two layouts, as the commands take them."""
    return real_data.taxel_args(real_dir)


@pytest.fixture(scope="session")
def real_skin(real_dir):
    """The recording's two parts with its own layouts, as the commands build them (``--taxels``), without the
    parts it never touched."""
    skin = load_skin(taxel_files={part: real_dir / name for part, name in real_data.LAYOUTS.items()})
    return SkinModel(skin.robot, {name: skin.parts[name] for name in ("l_hand", "torso")}, skin.source,
                     skin.self_touch)


@pytest.fixture(scope="session")
def real_loaded(real_recording, real_skin):
    """(TouchSet, LoadReport) of the real left hand-torso recording."""
    return read_legacy(real_recording, real_skin)


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


@pytest.fixture(autouse=True)
def _own_ros_domains():
    """The ROS domains a test claimed (ros_harness.unique_domain_id) stay its own until it and its fixtures
    have ended (an autouse fixture is set up first, so torn down last)."""
    yield
    harness = sys.modules.get("ros_harness")
    if harness is not None:
        harness.release_domains()
