"""The robot's two middleware ends, real, for tests: a libqi session serving an ALMotion-shaped service, and a
``yarpserver`` with skinManager-shaped writer ports.

What answers on them is a MOCK of the robot's body (nothing else here is): :class:`PlayedNao` plays a
:class:`~nao_skin.live.playback.Playback` as NAOqi's sensed joint angles and as skinManager's skin events.
Run as a script it is the robot of a test session, a process of its own (YARP keeps one name server per
process): ``python test/robot_body.py --seed S --qi-port P --events PORT --go FILE`` serves both ends, the arm
at rest and the skin released, prints ``ready``, plays :func:`played_touches` once FILE exists, prints
``done`` and exits. Importing this module needs neither ``qi`` nor ``yarp``; the functions that use one import
it.
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import sys
import threading
import time
from pathlib import Path

import numpy as np
import yaml

from nao_skin.formats.pointcloud import xyz
from nao_skin.formats.skinmanager import SkinEvents, format_skin_events
from nao_skin.live.playback import Playback
from nao_skin.model.skin import SkinModel, load_skin
from nao_skin.sim.simulate import simulate
from nao_skin.touch.datasets import deduplicate
from nao_skin.touch.touches import TouchSet

# skinManager's skinPart ids, as the bridge reads them (config/bridges.yaml: the thesis' Nao)
PART_IDS = dict(yaml.safe_load((Path(__file__).resolve().parents[1] / "config" / "bridges.yaml").read_text())
                ["/**/yarp_skin_bridge"]["ros__parameters"]["part_ids"])
# presses held still 0.4 s either side, as an operator holds the arm: NAOqi, polled at 50 Hz, stamps an angle
# when its answer arrives, and on a loaded machine that can come late
PLAY = {"period": 1.5, "press": 0.3, "hold": 0.4, "lead_in": 0.5}


def played_touches(skin: SkinModel, seed: int, per_pair: int = 5) -> TouchSet:
    """The touches the robot of a test session makes: simulated, a hand on the torso and the other on the head."""
    sim = simulate(skin, {"pairs": [["l_hand", "torso"], ["r_hand", "head"]], "n_touches": per_pair}, seed=seed)
    return deduplicate(sim.touches)[0]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve_motion(port: int, motion):
    """A libqi session listening on loopback ``port`` that serves ``motion`` as ALMotion."""
    import qi

    session = qi.Session()
    session.listenStandalone(f"tcp://127.0.0.1:{port}")
    session.registerService("ALMotion", motion)
    return session


def yarpserver_exe() -> str:
    import pytest

    cand = Path(sys.executable).parent / "yarpserver"
    exe = str(cand) if cand.exists() else shutil.which("yarpserver")
    if not exe:
        pytest.fail("yarpserver not installed: run docker/setup_venv.sh --with-yarp (make test does)")
    return exe


def yarp_env(conf: Path) -> dict:
    """YARP's configuration in ``conf`` (the yarpserver started there writes its address to yarp.conf)."""
    conf.mkdir(parents=True, exist_ok=True)
    return {"YARP_CONFIG_HOME": str(conf), "YARP_CONF": str(conf), "YARP_DATA_HOME": str(conf)}


def open_writer(name: str):
    import yarp

    port = yarp.BufferedPortBottle()
    assert port.open(name), f"cannot open YARP port {name}"
    return port


def send(port, text: str, count: int, t: float) -> None:
    """One bottle, enveloped with ``(count, t)`` as skinManager stamps what it writes."""
    import yarp

    b = port.prepare()
    b.clear()
    b.fromString(text)
    port.setEnvelope(yarp.Stamp(count, t))
    port.write(True)      # strict: back-to-back bottles are all delivered


def touch_events(playback: Playback, k: int, part_ids: dict) -> SkinEvents:
    """The skinContactList skinManager sends while touch ``k`` of ``playback`` is pressed (-1: released)."""
    parts = playback.samples[k] if k >= 0 else {}
    skin_part, ids, cop, geo, normal, pressure, t_contact, t_id = [], [], [], [], [], [], [], []
    for name, (taxels, contacts) in parts.items():
        for row, cid in enumerate(contacts["contact"]):
            slots = taxels["slot"][taxels["contact"] == cid]
            assert len(slots), f"{name}: contact {cid} without taxels"
            t_contact += [len(ids)] * len(slots)
            t_id += slots.tolist()
            skin_part.append(part_ids[name])
            ids.append(int(cid))
            cop.append(xyz(contacts)[row])
            geo.append(xyz(contacts, "g")[row])
            normal.append(xyz(contacts, "n")[row])
            p = float(contacts["pressure"][row])
            pressure.append(p if np.isfinite(p) else 20.0)    # skinManager always sends one
        assert np.isin(taxels["contact"], contacts["contact"]).all(), f"{name}: a taxel of no contact"
    k3 = np.array(cop, float).reshape(-1, 3)
    n = len(ids)
    return SkinEvents(np.array(skin_part, int), np.array(ids, int), np.ones(n, int), np.full(n, 6), k3,
                      np.zeros((n, 3)), np.zeros((n, 3)), np.array(geo, float).reshape(-1, 3),
                      np.array(normal, float).reshape(-1, 3), np.array(pressure, float), np.array(t_contact, int),
                      np.array(t_id, int))


class PlayedNao:
    """MOCK of the robot's body: ``playback`` as ALMotion.getAngles answers it (sensed angles at the moment
    of the call, by NAOqi joint name) and as skinManager writes its skin events (a bottle every
    ``1 / skin_hz`` s, enveloped with this machine's clock, empty while nothing is pressed).

    Until :meth:`play`, the arm rests at the first touch's angles and nothing is pressed."""

    def __init__(self, playback: Playback, part_ids: dict, skin_hz: float = 50.0):
        self.playback = playback
        self.part_ids = dict(part_ids)
        self.period = 1.0 / skin_hz
        self.started: float | None = None
        self.calls = 0
        self._index = {name: i for i, name in enumerate(playback.joint_names)}
        self._events = [format_skin_events(touch_events(playback, k, part_ids)) for k in range(len(playback))]
        self._released = format_skin_events(touch_events(playback, -1, part_ids))
        self._stop = threading.Event()
        self._thread = None
        self.bottles = 0

    def now(self) -> float:
        """Time into the play (negative before it starts)."""
        return -1.0 if self.started is None else time.monotonic() - self.started

    def getAngles(self, names, useSensors):  # noqa: N802 - NAOqi's method name
        t = self.now()
        q = self.playback.joints_at(max(t, 0.0))
        self.calls += 1
        return [float(q[self._index[n]]) if n in self._index else 0.0 for n in names]

    def write_skin(self, port) -> None:
        """Write the skin events to ``port`` from a thread of its own until :meth:`close`."""
        def loop():
            while not self._stop.is_set():
                t = self.now()
                k = self.playback.touch_at(t) if t >= 0 else -1
                self.bottles += 1
                send(port, self._events[k] if k >= 0 else self._released, self.bottles, time.time())
                self._stop.wait(self.period)

        self._thread = threading.Thread(target=loop, daemon=True)
        self._thread.start()

    def play(self) -> None:
        self.started = time.monotonic()

    def done(self) -> bool:
        return self.now() > self.playback.duration

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)


def main(argv=None) -> int:
    import yarp

    args = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    args.add_argument("--seed", type=int, required=True)
    args.add_argument("--qi-port", type=int, required=True)
    args.add_argument("--events", required=True, help="skinManager's events port name to write")
    args.add_argument("--go", type=Path, required=True, help="play once this file exists")
    a = args.parse_args(argv)
    skin = load_skin()
    body = PlayedNao(Playback(played_touches(skin, a.seed), skin, **PLAY), PART_IDS)
    yarp.Network.init()
    deadline = time.monotonic() + 30
    while not yarp.Network.checkNetwork(0.5):
        assert time.monotonic() < deadline, "no yarpserver"
    port = open_writer(a.events)
    session = serve_motion(a.qi_port, body)
    try:
        body.write_skin(port)
        print("ready", flush=True)
        while not a.go.exists():
            time.sleep(0.01)
        body.play()
        while not body.done():
            time.sleep(0.05)
        print(f"done: {len(body.playback)} touches, {body.calls} getAngles calls, {body.bottles} bottles", flush=True)
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)     # the test's stop while it ends: let it end
        body.close()
        port.close()
        session.close()
        yarp.Network.fini()
    return 0


if __name__ == "__main__":
    code = main()
    # past main() only the interpreter's teardown is left: libqi's and YARP's threads destroyed there now and
    # then aborted the process (SIGABRT, "terminate called without an active exception") after it had played
    # every touch and said so; what it played is judged by its output, its own end by main()'s return
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
