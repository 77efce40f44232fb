"""Whether the real ROS 2 launch system (``launch``, ``launch_ros``) is installed, for the tests that run the
launch files under it. ``launch_ros`` is looked for, not ``launch``: the repository's own ``launch/``
folder (the launch files) passes for a namespace package named ``launch`` when the checkout is on the path."""
import importlib.util

from real_data import skip_outside_ci

WHY = ("the real ROS 2 launch system (launch, launch_ros) is not installed: docker/setup_venv.sh installs it from"
       " ../shared/wheels beside the checkout (or $NAO_SKIN_LAUNCH_WHEELS)")


def require_launch() -> None:
    """Skip the calling test module with one line where the launch system is missing; under ``CI=true`` fail."""
    if importlib.util.find_spec("launch_ros") is None:
        skip_outside_ci(WHY, module_level=True)
