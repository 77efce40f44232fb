"""record.launch.py's scene:= (issue 61) on the real ROS 2 launch system: a bad scene ends the launch with one line
before any node starts (exit 1, as the other bad arguments), and a fingertip scene with a self-touch pair starts
the nodes with the parameters ``nao-skin record --scene`` gives them and records the simulated robot's fingertip
touches, marked, in its bag."""
from __future__ import annotations

import json
import signal

import pytest
from real_launch import require_launch

require_launch()
pytest.importorskip("rclpy")
from ros_harness import Listener, unique_domain_id  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from test_colcon import workspace  # noqa: E402,F401 - the workspace fixture
from test_launch import (WAIT_S, as_record_would, assert_started_as, output, ros2_launch,  # noqa: E402
                         stopped_once_written)
from test_launch_arguments import context_with, launch_file  # noqa: E402

from nao_skin.errors import ConfigError  # noqa: E402
from nao_skin.formats.bag import read_touches  # noqa: E402
from nao_skin.model.skin import load_skin  # noqa: E402

pytestmark = [pytest.mark.middleware, pytest.mark.slow]


@pytest.mark.parametrize("value", ["r_finger-legs", "r_hand-torso,z_finger-torso", "r_finger-r_hand"])
def test_record_launch_refuses_a_scene_it_cannot_record_in_one_line(value, tmp_path):
    module = launch_file("record.launch.py")
    defaults = {name: default for name, (default, _) in module.ARGUMENTS.items()}
    with pytest.raises(ConfigError) as refused:
        module._nodes(context_with(defaults, scene=value, bag=str(tmp_path / "bag")))
    assert str(refused.value).startswith("scene:=") and "\n" not in str(refused.value), refused.value
    assert not (tmp_path / "bag").exists()


def test_record_launch_with_a_bad_scene_ends_with_exit_1_before_any_node_starts(workspace, tmp_path):  # noqa: F811
    ws, _, _ = workspace
    launch = ros2_launch(ws, tmp_path, unique_domain_id(), "record.launch.py", "record_launch",
                         scene="r_finger-legs", bag=str(tmp_path / "bag"))
    try:
        code = launch.popen.wait(timeout=WAIT_S)
    finally:
        launch.stop(signal.SIGKILL)
    err = output(launch)
    assert code == 1 and "scene:= 'r_finger-legs': expected HAND-PART" in err, err[-3000:]
    assert "Traceback" not in err and "process started" not in err, err[-3000:]
    assert not (tmp_path / "bag").exists()


def test_record_launch_records_a_fingertip_scene_beside_a_self_touch_pair(workspace, tmp_path):  # noqa: F811
    ws, _, _ = workspace
    bag = tmp_path / "session"
    scene = "r_finger-torso,l_hand-torso"
    domain = unique_domain_id()
    listener = launch = None
    code = None
    try:
        listener = Listener(domain)
        progress = listener.subscribe(String, "/nao_skin/recorder/progress", keep=lambda m: json.loads(m.data))
        specs = as_record_would(robot="sim", bag_path=str(bag), scene=scene)
        launch = ros2_launch(ws, tmp_path, domain, "record.launch.py", "record_launch", bag=str(bag), scene=scene)
        both = lambda: progress and all(progress[-1]["pairs"].get(k, 0) >= 2  # noqa: E731
                                        for k in ("r_finger-torso", "l_hand+torso"))
        assert listener.spin_until(both, timeout=WAIT_S, procs=[launch]), (progress[-1:], output(launch)[-3000:])
        assert_started_as(listener, specs)
        code = launch.stop(signal.SIGINT, timeout=60)
    finally:
        if listener is not None:
            listener.close()
        if launch is not None and code is None:
            launch.stop(signal.SIGKILL)
    err = output(launch)
    assert code == 0 and "Traceback" not in err, err[-3000:]
    got, _ = read_touches(bag, load_skin())
    tips = got.fingertip_of_touch
    assert (tips >= 0).sum() >= 2 and (tips < 0).sum() >= 2, tips
    assert set(got.fingertips[t] for t in tips[tips >= 0]) == {"r_finger"}


@pytest.mark.parametrize("value,says", [("r_finger-torso.txt=r_finger", "is not among the inputs"),
                                        ("r_finger", "no text input to name it for")])
def test_calibrate_launch_refuses_a_fingertip_it_cannot_name_in_one_line(value, says):
    """calibrate.launch.py fingertip:= names the fingertip of the text inputs' touches; one a bag input cannot take,
    or naming a file that is not an input, is one line before the node starts."""
    module = launch_file("calibrate.launch.py")
    defaults = {name: "a.bag" if default is None else default for name, (default, _) in module.ARGUMENTS.items()}
    with pytest.raises(ConfigError) as refused:
        module._node(context_with(defaults, fingertip=value))
    assert str(refused.value).startswith(f"fingertip:={value}: ") and says in str(refused.value), refused.value
    assert "\n" not in str(refused.value)


def test_calibrate_launch_calibrates_a_fingertip_recording_named_by_its_fingertip(workspace, tmp_path,  # noqa: F811
                                                                                  real_dir, real_fingertip_dir):
    """The thesis' text format does not say which fingertip pressed: calibrate.launch.py refused such a file
    ("no touch has two skin parts active together"); fingertip:=r_finger reads it as the right fingertip's touches,
    as nao-skin calibrate --fingertip does, and the calibration places the fingertip."""
    import yaml

    ws, _, _ = workspace
    src = real_fingertip_dir / "r_finger_l_hand.legacy.txt"
    out = tmp_path / "out"
    launch = ros2_launch(ws, tmp_path, unique_domain_id(), "calibrate.launch.py", "calibrate_launch",
                         inputs=str(src), out_dir=str(out), taxels=f"'l_hand={real_dir / 'l_hand.taxels.txt'}'",
                         fingertip="r_finger")
    code = stopped_once_written(launch, out / "calibration.yaml")
    assert code == 0 and "Traceback" not in output(launch), output(launch)[-3000:]
    calibration = yaml.safe_load((out / "calibration.yaml").read_text())
    assert set(calibration["fingertips"]) == {"r_finger"}
    report = json.loads((out / "report.json").read_text())
    assert report["final"]["test"]["fingertip_mean_mm"] > 0
