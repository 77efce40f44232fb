"""Two robots on one ROS domain, each session in its own namespace, over real DDS: each records only its own
touches. The simulated robots stand in for the two robots' bodies; they touch with disjoint parts (the left
hand on the torso, the right hand on the head), so a touch of the other robot in a bag is seen by its parts.
"""
from __future__ import annotations

import json
import signal

import pytest
from ros_harness import Listener, Proc, ros_env, unique_domain_id
from test_record_session import record_cmd

pytest.importorskip("rclpy")
from std_msgs.msg import String  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402

from nao_skin.formats.bag import read_touches  # noqa: E402
from nao_skin.model.skin import load_skin  # noqa: E402
from nao_skin.nodes.topics import (LATCHED, PROGRESS_TOPIC, SIM_STATUS_TOPIC, STATUS_TOPIC,  # noqa: E402
                                   TF_STATIC_TOPIC)


def replace_depth(qos, depth: int):
    """``qos`` with another history depth (the rest as it is)."""
    from rclpy.qos import QoSProfile

    return QoSProfile(history=qos.history, depth=depth, reliability=qos.reliability, durability=qos.durability)

pytestmark = [pytest.mark.middleware, pytest.mark.slow]
ROBOTS = {"/nao1": ("l_hand-torso", {"l_hand", "torso"}), "/nao2": ("r_hand-head", {"r_hand", "head"})}
PER_PAIR = 6


def test_two_robots_in_two_namespaces_on_one_domain_record_only_their_own_touches(tmp_path):
    domain = unique_domain_id()
    listener = None
    sessions = {}
    codes = {}
    try:
        listener = Listener(domain)
        sims = {ns: listener.subscribe(String, f"{ns}/{SIM_STATUS_TOPIC}", keep=lambda m: json.loads(m.data))
                for ns in ROBOTS}
        progress = {ns: listener.subscribe(String, f"{ns}/{PROGRESS_TOPIC}", keep=lambda m: json.loads(m.data))
                    for ns in ROBOTS}
        statuses = {ns: listener.subscribe(String, f"{ns}/{STATUS_TOPIC}", qos=LATCHED,
                                           keep=lambda m: json.loads(m.data)) for ns in ROBOTS}
        # two writers' latched messages may land together: a reader history of 1 would keep only the later
        frames = listener.subscribe(TFMessage, TF_STATIC_TOPIC, qos=replace_depth(LATCHED, 10))
        for ns, (pair, _) in ROBOTS.items():
            argv = record_cmd(tmp_path / ns.strip("/"), seed=3, per_pair=PER_PAIR) + [
                "--namespace", ns, "--param", f"sim_robot.pairs=[{pair}]"]
            sessions[ns] = Proc(argv, ros_env(domain), tmp_path, ns.strip("/"))
        assert listener.spin_until(lambda: all(s and s[-1]["done"] for s in sims.values()), timeout=240,
                                   procs=list(sessions.values())), {ns: s[-1:] for ns, s in sims.items()}
        # each calibrate node publishes its skin frames, prefixed with its namespace, on the one /tf_static
        assert listener.spin_until(lambda: all(any(t.child_frame_id.startswith(f"{ns.strip('/')}/")
                                                   for m in frames for t in m.transforms) for ns in ROBOTS),
                                   timeout=60), sorted({t.child_frame_id for m in frames for t in m.transforms})[:5]
        assert all(statuses.values()), statuses
        # a recorder on a busy machine may still be reading what was played: stopped before it has, its last
        # touches had no joint state after them yet (2 of 6, with two other sessions on the machine); the bags
        # below say whether each got everything
        listener.spin_until(lambda: all(p and p[-1]["touches"] >= PER_PAIR for p in progress.values()), timeout=60,
                            procs=list(sessions.values()))
        for ns, session in sessions.items():
            codes[ns] = session.stop(signal.SIGINT, timeout=60)
    finally:
        if listener is not None:
            listener.close()
        for session in sessions.values():
            if session.alive():
                session.stop(signal.SIGKILL)
    skin = load_skin()
    for ns, (_, parts) in ROBOTS.items():
        err = sessions[ns].stderr()
        assert codes[ns] == 0 and "Traceback" not in err, err[-3000:]
        touches, _ = read_touches(tmp_path / ns.strip("/"), skin)
        fired = {touches.part_names[p] for p in set(touches.contact_part.tolist())}
        assert touches.n_touches == sims[ns][-1]["played"] == PER_PAIR, (ns, touches.n_touches, sims[ns][-1])
        assert fired == parts, (ns, fired)


def test_a_second_session_in_the_same_namespace_and_domain_is_refused(tmp_path):
    """The claim is per domain and namespace: the same namespace twice is the one mistake it stops."""
    domain = unique_domain_id()
    first = Proc(record_cmd(tmp_path / "first", seed=1, per_pair=2) + ["--namespace", "/nao1", "--duration", "60"],
                 ros_env(domain), tmp_path, "first")
    try:
        import time

        deadline = time.monotonic() + 120
        while "sim_robot" not in first.stderr() + first.stdout() and first.alive() and time.monotonic() < deadline:
            time.sleep(0.2)
        import subprocess

        second = subprocess.run(record_cmd(tmp_path / "second", seed=1, per_pair=2) + ["--namespace", "nao1"],
                                env=ros_env(domain), capture_output=True, text=True, timeout=120)
    finally:
        first.stop(signal.SIGINT, timeout=60)
    assert second.returncode == 2, second.stderr
    assert f"runs on ROS_DOMAIN_ID {domain} in namespace /nao1" in second.stderr, second.stderr
    assert not (tmp_path / "second").exists()


def test_each_node_s_diagnostics_name_carries_its_namespace(tmp_path):
    """Every namespace publishes on the one /diagnostics: two robots' nodes there were both "nao_skin: sim_robot"
    (and "simulated robot"), one row in rqt_robot_monitor. Each status is now named by the node's fully
    qualified name, as diagnostic_updater names them with use_fqn; the simulated robots are two pieces of
    hardware."""
    import sys

    from diagnostic_msgs.msg import DiagnosticArray

    from nao_skin.nodes.topics import DIAGNOSTICS_TOPIC

    domain = unique_domain_id()
    nodes = {"/nao1": "sim_robot", "/nao2": "sim_robot", "/": "skin_heatmap"}
    procs, listener = [], None
    try:
        listener = Listener(domain)
        seen = listener.subscribe(DiagnosticArray, DIAGNOSTICS_TOPIC,
                                  keep=lambda m: [(s.name, s.hardware_id) for s in m.status])
        for ns, node in nodes.items():
            argv = [sys.executable, "-m", f"nao_skin.nodes.{node}", "--ros-args", "-r", f"__ns:={ns}"]
            if node == "sim_robot":     # one touch: the robot's play is beside the point
                argv += ["-p", "touches_per_pair:=1", "-p", "pairs:=['l_hand-torso']"]
            procs.append(Proc(argv, ros_env(domain), tmp_path, f"{node}{ns.replace('/', '_')}"))
        want = {"nao_skin: /nao1/sim_robot": "simulated robot /nao1",
                "nao_skin: /nao2/sim_robot": "simulated robot /nao2", "nao_skin: /skin_heatmap": None}

        def named():
            return {name: hardware for statuses in seen for name, hardware in statuses}

        assert listener.spin_until(lambda: set(want) <= set(named()), timeout=90, procs=procs), sorted(named())
        got = named()
        assert all(got[name] == hardware for name, hardware in want.items() if hardware), got
        assert not [name for name in got if name.startswith("nao_skin: ") and not name.startswith("nao_skin: /")]
    finally:
        if listener is not None:
            listener.close()
        for proc in procs:
            proc.stop(signal.SIGINT, timeout=30)
