"""A robot session end to end, as at the robot: ``nao-skin record --robot nao`` with every process it starts
for the Nao (naoqi_bridge, yarp_skin_bridge, pairing_recorder, skin_heatmap, calibrate) against a real libqi
session and a real ``yarpserver``; the touch bag it writes is then read back and summarised by ``stats``.

Only the robot's body is a MOCK (:class:`robot_body.PlayedNao`): simulated touches played as ALMotion's
sensed angles and as skinManager's skin events, on this machine's clock. Checked: every touch played is in the
bag once, with the joint angles NAOqi gave during its press and the taxels skinManager listed; the session
ends on Ctrl-C with exit 0 and the recorder's count; the bag says it was recorded from the robot, not the simulator.
"""
from __future__ import annotations

import json
import signal
import sys

import numpy as np
import pytest

pytest.importorskip("qi")
pytest.importorskip("yarp", exc_type=ImportError)   # absent, or its compiled part unloadable
from robot_body import PART_IDS, free_port, played_touches, yarp_env, yarpserver_exe  # noqa: E402
from ros_harness import ROOT, Listener, Proc, ros_env, unique_domain_id  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from nao_skin.formats.bag import read_touches  # noqa: E402
from nao_skin.formats.pointcloud import taxels_topic  # noqa: E402
from nao_skin.model.skin import load_skin  # noqa: E402
from nao_skin.nodes.topics import PROGRESS_TOPIC  # noqa: E402

pytestmark = pytest.mark.middleware   # libqi, yarpserver and the session's nodes over DDS

EVENTS = "/fake/skinManager/skin_events:o"


def test_a_robot_session_records_every_touch_the_robot_made(tmp_path):
    skin = load_skin()
    seed = 4
    touches = played_touches(skin, seed)
    env = ros_env(unique_domain_id(), **yarp_env(tmp_path / "yarp"))
    qi_port = free_port()
    bag, go = tmp_path / "touches", tmp_path / "go"
    server = robot = session = listener = None
    try:
        server = Proc([yarpserver_exe(), "--ip", "127.0.0.1", "--socket", str(free_port())], env, tmp_path,
                      "yarpserver")
        listener = Listener(int(env["ROS_DOMAIN_ID"]))
        assert listener.spin_until(lambda: (tmp_path / "yarp" / "yarp.conf").exists(), procs=[server])
        robot = Proc([sys.executable, str(ROOT / "test" / "robot_body.py"), "--seed", str(seed), "--qi-port",
                      str(qi_port), "--events", EVENTS, "--go", str(go)], env, tmp_path, "robot_body")
        assert listener.spin_until(lambda: "ready" in robot.stdout(), timeout=60, procs=[robot, server]), \
            robot.stderr()[-2000:]

        progress = listener.subscribe(String, PROGRESS_TOPIC, keep=lambda m: json.loads(m.data))
        session = Proc([sys.executable, "-m", "nao_skin.cli", "record", "--robot", "nao", "--nao-ip", "127.0.0.1",
                        "--param", f"naoqi_bridge.nao_port={qi_port}", "--events-port", EVENTS, "--bag", str(bag)],
                       env, tmp_path, "record")
        # the play starts once the recorder hears both of the robot's streams (DDS discovery, YARP connection)
        streams = {taxels_topic(p) for p in PART_IDS}
        assert listener.spin_until(lambda: progress and streams <= set(progress[-1]["clock_skew_s"]),
                                   timeout=90, procs=[session, server, robot]), session.stderr()[-3000:]
        go.touch()
        assert listener.spin_until(lambda: "done" in robot.stdout(), timeout=90, procs=[session, server]), \
            robot.stderr()[-2000:]
        listener.spin_for(1.0)
        code = session.stop(signal.SIGINT, timeout=60)
        err = session.stderr()
    finally:
        for proc in (session, robot):
            if proc is not None and proc.alive():
                proc.stop(signal.SIGKILL)
        if listener is not None:
            listener.close()
        if server is not None:
            server.stop()
    assert robot.stop() == 0, robot.stderr()[-2000:]
    assert code == 0, err[-3000:]
    assert "Traceback" not in err, err[-3000:]
    assert f"[pairing_recorder]: wrote 10 touches to {bag}: " in err, err[-2000:]

    back, report = read_touches(bag, skin)
    assert back.n_touches == touches.n_touches == 10 and report.n_skipped == 0
    assert not any("simulated" in n for n in report.info + report.notes), report.lines()
    index = [list(touches.joint_names).index(n) for n in back.joint_names]
    np.testing.assert_allclose(back.joints, touches.joints[:, index], atol=1e-9)     # played in index order
    for k in range(touches.n_touches):
        for part in PART_IDS:
            assert slots_of(back, k, part) == slots_of(touches, k, part), (k, part)

    stats = Proc([sys.executable, "-m", "nao_skin.cli", "stats", str(bag)], env, tmp_path, "stats")
    assert stats.popen.wait(timeout=120) == 0, stats.stderr()
    assert "simulated" not in stats.stdout() + stats.stderr()
    out = stats.stdout()
    assert "\ntouches: 10\n" in out and "'l_hand+torso': 5" in out and "'r_hand+head': 5" in out, out


def slots_of(touches, k: int, part: str) -> list:
    """The taxels of ``part`` activated in touch ``k``, sorted."""
    if part not in touches.part_names:
        return []
    mine = (touches.act_touch == k) & (touches.act_part == touches.part_index(part))
    return sorted(touches.act_slot[mine].tolist())
