"""yarp_skin_bridge against a real ``yarpserver`` on loopback and real YARP writer ports.

The test starts its own yarpserver (config in a tmp dir), opens writer
ports named like skinManager's, and sends skinContactList bottles (the
skinDynLib wire layout) with envelopes, a compensated taxel vector, and a
malformed bottle. The bridge runs as its own process and publishes over
real DDS. Checked: per-part messages with the right taxels, positions,
pressures, contact ids and envelope stamps; the malformed bottle counted and
skipped; the writer port vanishing and coming back.
"""
from __future__ import annotations

import json
import time

import numpy as np
import pytest

yarp = pytest.importorskip("yarp", exc_type=ImportError)   # absent, or its compiled part unloadable
from robot_body import free_port, open_writer, send, yarpserver_exe  # noqa: E402
from ros_harness import Listener, Proc, node_process, ros_env, unique_domain_id  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from nao_skin.formats.pointcloud import decode_cloud, xyz  # noqa: E402
from nao_skin.formats.skinmanager import SkinEvents, format_skin_events  # noqa: E402
from nao_skin.model.skin import load_skin  # noqa: E402
from nao_skin.nodes.messages import stamp_from_msg  # noqa: E402

pytestmark = pytest.mark.middleware   # a real yarpserver and the yarp_skin_bridge node, over DDS

EVENTS = "/fake/skinManager/skin_events:o"
COMP = "/fake/skin/l_hand_comp:o"
LOCAL = "/test/bridge"
IDS = {"l_hand": 1, "r_hand": 4, "torso": 7, "head": 5}


def events_for(skin, contacts):
    """SkinEvents from ``[(part, contact id, slots, pressure)]`` with COPs from the nominal layout."""
    k = len(contacts)
    cop = np.zeros((k, 3))
    t_contact, t_id = [], []
    for i, (part, _, slots, _) in enumerate(contacts):
        cop[i] = skin.parts[part].positions[slots].mean(axis=0)
        t_contact += [i] * len(slots)
        t_id += list(slots)
    ids = np.array([c[1] for c in contacts])
    sp = np.array([IDS[c[0]] for c in contacts])
    return SkinEvents(sp, ids, np.full(k, 1), np.full(k, 6), cop, np.tile([0.0, 0.0, 1.5], (k, 1)),
                      np.zeros((k, 3)), cop + 1e-3, np.tile([0.0, 0.0, 1.0], (k, 1)),
                      np.array([c[3] for c in contacts], float), np.array(t_contact), np.array(t_id))


def test_skin_bridge(tmp_path, monkeypatch):
    conf = tmp_path / "yarpconf"
    conf.mkdir()
    yenv = {"YARP_CONFIG_HOME": conf, "YARP_CONF": conf, "YARP_DATA_HOME": conf}
    for k, v in yenv.items():
        monkeypatch.setenv(k, str(v))
    domain = unique_domain_id()
    skin = load_skin()
    server = bridge = listener = receiving = None
    writers = []
    try:
        server = Proc([yarpserver_exe(), "--ip", "127.0.0.1", "--socket", str(free_port())],
                      ros_env(domain, **yenv), tmp_path, "yarpserver")
        listener = Listener(domain)
        assert listener.spin_until(lambda: (conf / "yarp.conf").exists(), procs=[server])
        yarp.Network.init()
        assert listener.spin_until(lambda: yarp.Network.checkNetwork(0.5), procs=[server]), "yarpserver not up"
        events_port = open_writer(EVENTS)
        comp_port = open_writer(COMP)
        writers = [events_port, comp_port]

        taxels = {p: listener.subscribe(PointCloud2, f"/skin/{p}/taxels") for p in IDS}
        contacts = {p: listener.subscribe(PointCloud2, f"/skin/{p}/contacts") for p in IDS}
        status = listener.subscribe(String, "/skin/bridge_status", keep=lambda m: json.loads(m.data))
        params = {"events_port": EVENTS, "local_prefix": LOCAL, "compensated_ports.l_hand": COMP,
                  "reconnect_period": 0.3, "status_period": 0.2}
        params.update({f"part_ids.{p}": i for p, i in IDS.items()})
        bridge = node_process("yarp_skin_bridge", params, ros_env(domain, **yenv), tmp_path)
        connected = lambda: (yarp.Network.isConnected(EVENTS, f"{LOCAL}/skin_events:i", True)  # noqa: E731
                             and yarp.Network.isConnected(COMP, f"{LOCAL}/l_hand_comp:i", True))
        assert listener.spin_until(connected, procs=[bridge, server]), "bridge did not connect to the writers"
        # DDS discovery of the bridge's publishers, then the first bottle
        assert listener.spin_until(lambda: len(status) > 0, procs=[bridge])

        # 1. a contact list touching torso (two contacts) and the right hand
        torso, hand = skin.parts["torso"], skin.parts["r_hand"]
        t_slots_a, t_slots_b, h_slots = torso.slots[:4], torso.slots[40:43], hand.slots[10:15]
        ev = events_for(skin, [("torso", 3, t_slots_a, 12.5), ("r_hand", 8, h_slots, 30.0),
                               ("torso", 4, t_slots_b, 7.0)])
        send(events_port, format_skin_events(ev), 1, 1000.25)
        stamped = lambda lst, t: [m for m in lst if abs(stamp_from_msg(m.header.stamp) - t) < 1e-6]  # noqa: E731
        assert listener.spin_until(lambda: all(stamped(taxels[p], 1000.25) for p in ("torso", "r_hand", "head"))
                                   and all(stamped(contacts[p], 1000.25) for p in IDS), procs=[bridge])
        tor = decode_cloud(stamped(taxels["torso"], 1000.25)[0], "torso")
        np.testing.assert_array_equal(tor["slot"], np.r_[t_slots_a, t_slots_b])
        np.testing.assert_array_equal(tor["contact"], [3] * 4 + [4] * 3)
        np.testing.assert_allclose(tor["pressure"], [12.5] * 4 + [7.0] * 3)
        np.testing.assert_allclose(xyz(tor), torso.positions[tor["slot"]], atol=1e-6)
        assert stamped(taxels["torso"], 1000.25)[0].header.frame_id == torso.parent_frame
        rh = decode_cloud(stamped(taxels["r_hand"], 1000.25)[0], "r_hand")
        np.testing.assert_array_equal(rh["slot"], h_slots)
        assert stamped(taxels["r_hand"], 1000.25)[0].header.frame_id == hand.parent_frame
        assert len(decode_cloud(stamped(taxels["head"], 1000.25)[0], "head")) == 0  # released
        tc = decode_cloud(stamped(contacts["torso"], 1000.25)[0], "torso")
        np.testing.assert_array_equal(tc["contact"], [3, 4])
        np.testing.assert_allclose(xyz(tc), ev.cop[[0, 2]], atol=1e-6)
        np.testing.assert_allclose(xyz(tc, "g"), ev.geo_center[[0, 2]], atol=1e-6)
        np.testing.assert_allclose(xyz(tc, "n"), ev.normal[[0, 2]], atol=1e-6)
        np.testing.assert_allclose(tc["fz"], [1.5, 1.5])
        np.testing.assert_allclose(tc["pressure"], [12.5, 7.0])
        # l_hand takes its taxels from the compensated port: none from the contact list
        assert not stamped(taxels["l_hand"], 1000.25)
        assert len(decode_cloud(stamped(contacts["l_hand"], 1000.25)[0], "l")) == 0

        # 2. a malformed bottle (a contact with only two items), then a good one: skipped, counted, alive
        send(events_port, "((1 2 3 7) (0.1 0.2 0.3))", 2, 1000.5)
        ev2 = events_for(skin, [("head", 9, skin.parts["head"].slots[:3], 5.0)])
        send(events_port, format_skin_events(ev2), 3, 1000.75)
        assert listener.spin_until(lambda: stamped(taxels["head"], 1000.75), procs=[bridge])
        assert listener.spin_until(lambda: status[-1]["counts"].get("malformed") == 1, procs=[bridge])
        assert not stamped(taxels["torso"], 1000.5), "a malformed bottle produced messages"
        hd = decode_cloud(stamped(taxels["head"], 1000.75)[0], "head")
        np.testing.assert_array_equal(hd["slot"], skin.parts["head"].slots[:3])

        # 3. compensated taxels of the left hand: values above the threshold, contact -1
        lh = skin.parts["l_hand"]
        values = np.zeros(lh.n_slots)
        active = lh.slots[[0, 5, 20]]
        values[active] = [3.0, 100.0, 255.0]
        send(comp_port, " ".join(f"{v:g}" for v in values), 1, 2000.5)
        assert listener.spin_until(lambda: stamped(taxels["l_hand"], 2000.5), procs=[bridge])
        lt = decode_cloud(stamped(taxels["l_hand"], 2000.5)[0], "l_hand")
        np.testing.assert_array_equal(lt["slot"], active)
        np.testing.assert_allclose(lt["pressure"], [3.0, 100.0, 255.0])
        np.testing.assert_array_equal(lt["contact"], [-1, -1, -1])

        # 4. skinManager goes away and comes back under the same port name
        events_port.close()
        writers.remove(events_port)
        assert listener.spin_until(lambda: status and status[-1]["connected"][EVENTS] is False, procs=[bridge])
        events_port = open_writer(EVENTS)
        writers.append(events_port)
        assert listener.spin_until(lambda: status[-1]["connected"][EVENTS] is True, procs=[bridge])
        send(events_port, format_skin_events(ev2), 4, 3000.0)
        assert listener.spin_until(lambda: stamped(taxels["head"], 3000.0), procs=[bridge]), "no data after reconnect"
        assert status[-1]["counts"]["outages"] == 1

        # 5. envelope times no stamp holds (NaN, infinite, past int32 seconds): each bottle skipped and counted,
        # the next one bridged (the first of them ended the bridge's reading thread: nothing was bridged after it)
        malformed = status[-1]["counts"]["malformed"]
        for count, bad in enumerate((float("nan"), float("inf"), 3e9), start=5):
            send(events_port, format_skin_events(ev2), count, bad)
        send(events_port, format_skin_events(ev2), 8, 3000.5)
        assert listener.spin_until(lambda: stamped(taxels["head"], 3000.5), procs=[bridge]), "bridge stopped reading"
        assert listener.spin_until(lambda: status[-1]["counts"]["malformed"] == malformed + 3, procs=[bridge])
        assert all(m.header.stamp.sec >= 0 for m in taxels["head"])

        # 6. the name server forgets both ports while their connection goes on (a restarted yarpserver knows
        # neither): the bottles still arrive, and the bridge does not call the link lost (it said 'connection
        # lost' and 'connected: false' for the rest of a rehearsal while every bottle was bridged)
        outages = status[-1]["counts"]["outages"]
        yarp.Network.unregisterName(EVENTS)
        yarp.Network.unregisterName(f"{LOCAL}/skin_events:i")
        for count in range(20):         # 2 s of bottles: several of the bridge's checks (every 0.3 s)
            send(events_port, format_skin_events(ev2), 100 + count, 3000.6 + 0.01 * count)
            listener.spin_for(0.1)
        assert listener.spin_until(lambda: stamped(taxels["head"], 3000.79), procs=[bridge])
        assert status[-1]["connected"][EVENTS] is True and status[-1]["counts"]["outages"] == outages, status[-1]

        # 7. the name server forgets the bridge's port (a restarted yarpserver): the bridge registers it again,
        # and skinManager, coming back, connects and is bridged
        events_port.close()
        writers.remove(events_port)
        assert listener.spin_until(lambda: status[-1]["connected"][EVENTS] is False, procs=[bridge])
        yarp.Network.unregisterName(f"{LOCAL}/skin_events:i")    # the bridge's next check registers it again
        events_port = open_writer(EVENTS)
        writers.append(events_port)
        assert listener.spin_until(lambda: status[-1]["connected"][EVENTS] is True, procs=[bridge]), \
            bridge.stderr()[-2000:]
        send(events_port, format_skin_events(ev2), 9, 3001.0)
        assert listener.spin_until(lambda: stamped(taxels["head"], 3001.0), procs=[bridge]), "no data after re-register"
        assert status[-1]["counts"]["registered again"] >= 1

        # 8. stamp:=receive (skinManager's host on another clock): a second bridge on the same port stamps
        # what it reads with this machine's clock, the first still with the envelope's
        receiving = node_process("yarp_skin_bridge", {**params, "local_prefix": LOCAL + "_receive",
                                                      "stamp": "receive"},
                                 ros_env(domain, **yenv), tmp_path, "yarp_skin_bridge_receive")
        assert listener.spin_until(lambda: yarp.Network.isConnected(EVENTS, f"{LOCAL}_receive/skin_events:i", True),
                                   procs=[receiving]), "the second bridge did not connect"
        sent = time.time()
        now_stamped = lambda: [m for m in taxels["head"] if abs(stamp_from_msg(m.header.stamp) - sent) < 60]  # noqa: E731
        for count in range(10, 200):  # again until both arrive: the second bridge's publishers are discovered late
            send(events_port, format_skin_events(ev2), count, 4000.0)
            if listener.spin_until(lambda: stamped(taxels["head"], 4000.0) and now_stamped(), timeout=0.3,
                                   procs=[bridge, receiving]):
                break
        assert stamped(taxels["head"], 4000.0) and now_stamped(), "envelope and receive stamps"
        assert receiving.stop() == 0, receiving.stderr()[-2000:]
        assert "ignored parameters" not in receiving.stderr(), receiving.stderr()[-2000:]
    finally:
        for w in writers:
            w.close()
        if listener is not None:
            listener.close()
        if receiving is not None:
            receiving.stop()
        code = bridge.stop() if bridge is not None else 0
        if server is not None:
            server.stop()
        yarp.Network.fini()
    assert code == 0, bridge.stderr()[-3000:]
    assert "skipped:" in bridge.stderr() and "contact 0" in bridge.stderr()


def test_two_parts_on_one_skin_part_id_are_refused_in_one_line(tmp_path):
    """One skinPart id feeds one part: mapping two parts to it dropped one without a word."""
    node = node_process("yarp_skin_bridge", {"part_ids.head": 7, "part_ids.torso": 7},
                        ros_env(unique_domain_id()), tmp_path)
    try:
        node.popen.wait(timeout=60)
    finally:
        code = node.stop()
    assert code == 2 and "Traceback" not in node.stderr()
    assert "error: parameter part_ids: torso and head both have skinPart id 7" in node.stderr().splitlines(), \
        node.stderr()[-2000:]
