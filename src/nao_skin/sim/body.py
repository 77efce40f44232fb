"""A simulated robot BODY for the capture loop: ALMotion's calls move the true arm, the true skin fires.

It stands in for the robot's body only (NAOqi's motion and skinManager's skin), nothing of the capture: the
loop (:mod:`nao_skin.capture.loop`) drives it as it drives the robot, in the pure simulator directly and in
the end-to-end test behind a real libqi session (``test/capture_body.py``).

* **Motion.** ``angleInterpolationWithSpeed`` moves the arm's joints in a straight joint-space line at
  ``fraction`` of :data:`MAX_SPEED` (the slowest joint sets the time, as NAOqi's interpolation does), plus one
  motion cycle per call; it returns when the move is done, as NAOqi's blocking call does.
  ``killTasksUsingResources`` stops a move where it is. ``getAngles`` answers the angles at that moment.
  Every command and every stiffness change is logged for the tests.
* **Clock.** Virtual (``realtime=False``: a move or a wait advances the body's time at once; the pure
  simulator and the unit tests) or the wall clock (a move takes its time; the end-to-end test).
* **Skin.** The robot's true skin and fingertip (:func:`nao_skin.sim.simulate.true_robot` of the seed) fire
  by the simulator's own fingertip rule (:func:`nao_skin.sim.fingertip.fire_fingertip`) wherever the
  fingertip is: its spots and reach are drawn once per press (a new press once the fingertip has lifted
  :data:`LIFTED` off the skin), so a press's taxels do not flicker from one reading to the next.
* **Ground truth.** The fingertip's height over the true fabric surface (along the nearest facing taxel's
  normal), followed along every move; per press the deepest (``presses``: negative, below the surface), and
  for a press the skin was read firing, how far the fingertip went on along the true normal from where it
  first fired (``beyond``). A
  sphere landing between taxels fires late or not at all under the simulator's rule (nothing fires beyond
  the sphere's radius sideways), so the depth below the surface of such a press says more about that rule
  than about the capture: ``beyond`` is what the capture controls.
"""
from __future__ import annotations

import threading
import time

import numpy as np

from nao_skin import se3
from nao_skin.model.skin import SkinModel
from nao_skin.sim.contact import taxels_in_base
from nao_skin.sim.fingertip import fire_fingertip
from nao_skin.sim.params import SimParams, make_params
from nao_skin.sim.poses import PoseSet

MAX_SPEED = 7.0          # rad/s of every arm joint at fraction 1 (a Nao's arm joints turn about 7-9 rad/s)
CYCLE = 0.02             # s: one ALMotion cycle per interpolation call (its start and end)
LIFTED = 0.006           # m over the skin: beyond the press's reach, the next press is a new one
OVER_SKIN = 0.02         # m sideways from the nearest taxel within which a fingertip is over the skin
SAMPLES_PER_MM = 2       # ground-truth samples along a move, per mm of fingertip travel


class SimClock:
    """The body's clock: virtual (``sleep`` advances it) or the wall clock (``sleep`` waits, ``wake`` ends a
    wait early)."""

    def __init__(self, realtime: bool = False):
        self.realtime = realtime
        self._t = 0.0
        self._origin = time.monotonic()
        self._wake = threading.Event()

    def now(self) -> float:
        return time.monotonic() - self._origin if self.realtime else self._t

    def sleep(self, seconds: float) -> None:
        if seconds <= 0:
            return
        if self.realtime:
            self._wake.clear()
            self._wake.wait(seconds)
        else:
            self._t += seconds

    def wake(self) -> None:
        self._wake.set()


class SimBody:
    """MOCK of the robot's body (see the module docstring): the arms of ``fingertips`` (one name or several)
    over the part ``part``."""

    def __init__(self, skin: SkinModel, fingertips, part: str, params: SimParams | dict | None = None,
                 seed: int = 0, realtime: bool = False):
        from nao_skin.sim.simulate import true_robot

        self.fingertips = (fingertips,) if isinstance(fingertips, str) else tuple(fingertips)
        self.skin, self.part = skin, part
        self.p = make_params(params or {}) if not isinstance(params, SimParams) else params
        streams = np.random.SeedSequence(int(seed)).spawn(2)
        self.truth = true_robot(skin, self.p, [(f, part) for f in self.fingertips], np.random.default_rng(streams[0]))
        self.body = skin.with_kinematics(self.truth)
        self.seed = int(seed)
        robot = skin.robot
        self.index = {n: i for i, n in enumerate(robot.joint_names)}
        self.chains = [robot.fingertip(f).chain for f in self.fingertips]
        spheres = [self.truth.fingertip_sphere(robot, f) for f in self.fingertips]
        self.centres = [c for c, _ in spheres]
        self.radii = np.array([r for _, r in spheres])
        self.q = np.array([robot.body.rest_posture.get(n, (0.0, 0.0))[0] for n in robot.joint_names])
        self.q = np.clip(self.q, robot.limits[:, 0], robot.limits[:, 1])
        self.gap = float(self.p.fabric_thickness)
        self.clock = SimClock(realtime)
        self._lock = threading.Lock()
        self._move = None             # (t0, duration, q_from, q_to) of the move in progress
        pos, nor, self.slots = taxels_in_base(self.body, part, self.q[None], self.truth)
        self._taxels, self._normals = pos[0], nor[0]          # the part is on the base: fixed
        self.stiffness: dict = {}
        self.log: list = []           # ("command", t, names, angles, fraction) / ("stiffness", t, names, value, q)
        self.presses: list = []       # per press: the deepest height (m, negative: below the fabric surface)
        self.beyond: list = []        # per press that fired: how far (m) it went on beyond its first firing
        self.fired_presses: list = []  # per press: whether the skin fired in it
        self._press_min: float | None = None
        self._first_fire: tuple | None = None      # (centre, normal) of the fingertip at the press's first firing
        self._beyond = 0.0
        self.press_key = 0
        self.lost = False             # set by a test: every call raises as a vanished robot's proxy does

    # ------------------------------------------------------------------ ALMotion
    def _check(self, names) -> list:
        if self.lost:
            raise RuntimeError("ALMotion: connection lost")
        unknown = [n for n in names if n not in self.index]
        if unknown:
            raise RuntimeError(f"ALMotion: unknown joint(s) {', '.join(map(str, unknown))}")
        return [self.index[n] for n in names]

    def getAngles(self, names, useSensors):  # noqa: N802 - NAOqi's method name
        cols = self._check(list(names))
        q = self._now_q()
        return [float(q[c]) for c in cols]

    def setStiffnesses(self, names, stiffnesses):  # noqa: N802
        cols = self._check(list(names))
        value = float(stiffnesses)
        self.stiffness.update({c: value for c in cols})
        self.log.append(("stiffness", self.clock.now(), list(names), value, self._now_q().copy()))

    def angleInterpolationWithSpeed(self, names, angles, fraction):  # noqa: N802
        cols = self._check(list(names))
        fraction = float(fraction)
        if not 0.0 < fraction <= 1.0:
            raise RuntimeError(f"ALMotion: speed fraction {fraction} not in (0, 1]")
        target = self._now_q().copy()
        target[cols] = np.asarray(angles, float)
        self.log.append(("command", self.clock.now(), list(names), list(map(float, angles)), fraction))
        if any(self.stiffness.get(c, 0.0) <= 0.0 for c in cols):
            return          # a joint without stiffness does not move (NAOqi: the command is ignored)
        q0 = self._now_q().copy()
        duration = float(np.max(np.abs(target - q0))) / (fraction * MAX_SPEED) + CYCLE
        with self._lock:
            self._move = (self.clock.now(), duration, q0, target)
        self._follow(q0, target)
        self.clock.sleep(duration)
        self._settle()

    def killTasksUsingResources(self, names):  # noqa: N802
        self._check(list(names))
        self._settle(stop=True)
        self.clock.wake()

    # ------------------------------------------------------------------ state
    def _now_q(self) -> np.ndarray:
        with self._lock:
            if self._move is None:
                return self.q
            t0, duration, q0, q1 = self._move
            s = min(max((self.clock.now() - t0) / duration, 0.0), 1.0)
            return q0 + s * (q1 - q0)

    def _settle(self, stop: bool = False) -> None:
        """End the move: at its end, or (``stop``) where it is now."""
        q = self._now_q().copy()
        with self._lock:
            if self._move is not None:
                self.q = q if stop or self.clock.realtime else self._move[3].copy()
            self._move = None

    def sphere_centre(self, q: np.ndarray, tip=0) -> np.ndarray:
        """(N, 3) the true sphere's centre of fingertip ``tip`` (an index, or (N,) of them), base frame."""
        q = np.atleast_2d(q)
        tip = np.broadcast_to(np.asarray(tip, int), (len(q),))
        out = np.empty((len(q), 3))
        for k in np.unique(tip):        # one FK per arm (two at most)
            rows = tip == k
            out[rows] = se3.transform_points(self.body.robot.fk(self.chains[k], q[rows]), self.centres[k])
        return out

    def height(self, q: np.ndarray) -> tuple:
        """``(h, normal, tip)``: (N,) the height of the true fingertip nearest the skin over the true fabric
        surface, (N, 3) the normal there (of the nearest taxel that faces it) and (N,) which fingertip."""
        q = np.atleast_2d(q)
        per_tip = []
        for k in range(len(self.fingertips)):
            c = self.sphere_centre(q, k)
            rel = c[:, None] - self._taxels[None]
            up = np.einsum("nsk,sk->ns", rel, self._normals)
            d = np.where(up > -0.01, np.linalg.norm(rel, axis=2), np.inf)
            near = np.argmin(d, axis=1)
            rows = np.arange(len(c))
            lateral = np.linalg.norm(rel[rows, near] - up[rows, near, None] * self._normals[near], axis=1)
            # a fingertip not over the skin (the other arm at rest beside the body) is no height over it
            h = np.where(lateral <= OVER_SKIN, up[rows, near] - self.radii[k] - self.gap, np.inf)
            per_tip.append((h, self._normals[near]))
        h = np.stack([t[0] for t in per_tip])
        tip = np.argmin(h, axis=0)
        n = np.arange(len(q))
        return h[tip, n], np.stack([t[1] for t in per_tip])[tip, n], tip

    def _follow(self, q0: np.ndarray, q1: np.ndarray) -> None:
        """Ground truth along a move (sampled every half millimetre of the fingertip): each press's deepest
        height, and how far the true fingertip went on along the true normal since the press first fired."""
        way = max(float(np.linalg.norm(self.sphere_centre(q1, k)[0] - self.sphere_centre(q0, k)[0]))
                  for k in range(len(self.fingertips)))
        s = np.linspace(0.0, 1.0, max(int(way * 1000 * SAMPLES_PER_MM), 1) + 1)[:, None]
        q = q0 + s * (q1 - q0)
        heights, _, tips = self.height(q)
        centres = self.sphere_centre(q, tips)
        for h, c in zip(heights, centres):
            if h < LIFTED:
                self._press_min = h if self._press_min is None else min(self._press_min, h)
                if self._first_fire is not None:
                    at, normal = self._first_fire
                    self._beyond = max(self._beyond, float((at - c) @ normal))
            elif self._press_min is not None:
                self.presses.append(self._press_min)
                self.fired_presses.append(self._first_fire is not None)
                if self._first_fire is not None:
                    self.beyond.append(self._beyond)
                self._press_min, self._first_fire, self._beyond = None, None, 0.0
                self.press_key += 1

    def fired(self, since: float = -np.inf) -> dict:
        """``{part: (slots, max pressure)}`` the skin reads now (the ``Contacts`` of the capture loop: the skin
        is read continuously, so what it reads now is newer than any ``since``)."""
        slots, pressure = self.skin_now()
        return {self.part: (slots, float(pressure.max()))} if len(slots) else {}

    def skin_now(self) -> tuple:
        """(slots, pressures) of the part's taxels that fire at the arm's angles now."""
        q = self._now_q()[None]
        h, normal, tip = self.height(q)
        if h[0] >= LIFTED:
            return np.zeros(0, int), np.zeros(0)
        k = int(tip[0])
        c = self.sphere_centre(q, k)
        poses = PoseSet(q, c - self.radii[k] * normal, normal, np.array([self.gap]), np.array([-1]),
                        np.array([-1]), 1, 0)
        rng = np.random.default_rng([self.seed, self.press_key])
        _, slot, pressure, _ = fire_fingertip(self.body, self.truth, self.fingertips[k], self.part, poses, self.p,
                                              rng)
        # the press's first contact, as the skin reads it (a reading of a press already ended, the arm on its way
        # up while another thread reads the skin, starts none)
        if len(slot) and self._first_fire is None and self._press_min is not None:
            self._first_fire = (c[0], normal[0])
        return slot.astype(int), pressure

    def full(self, names, q_arm: np.ndarray) -> np.ndarray:
        """(N, J) the body's joint angles now with the joints ``names`` set to ``q_arm`` (N, V)."""
        q = np.repeat(self._now_q()[None], len(q_arm), axis=0)
        q[:, [self.index[n] for n in names]] = q_arm
        return q

    def record(self, q: np.ndarray, rng: np.random.Generator):
        """The touches the recorder would store of presses held at the true joint angles ``q`` (N, J) (each by
        the fingertip nearest the skin there): fired by the fingertip rule, with the simulator's recording
        defects (encoder noise, stray taxels, duplicates, the experimenter's hand), as
        :func:`~nao_skin.sim.simulate.simulate` records its own (a TouchSet, the fingertips' touches in turn)."""
        from nao_skin.sim.simulate import _assemble, _fingertip_activations

        height, normal, tips = self.height(q)
        per_tip = []
        for k, name in enumerate(self.fingertips):
            rows = np.flatnonzero(tips == k)
            if not len(rows):
                continue
            contact = self.sphere_centre(q[rows], k) - self.radii[k] * normal[rows]
            n = len(rows)
            poses = PoseSet(q[rows], contact, normal[rows], np.full(n, self.gap), np.full(n, -1), np.full(n, -1), n, 0)
            acts = _fingertip_activations(self.body, self.truth, name, self.part, poses, self.p, rng)
            per_tip.append((name, self.part, poses, acts))
        return _assemble(self.skin, per_tip, self.p, rng)

    def commands(self) -> np.ndarray:
        """(N, V) every commanded angle vector (the arm's joints), in order."""
        return np.array([angles for kind, _, _, angles, _ in self.log if kind == "command"])

    def arm_angles(self, names) -> np.ndarray:
        q = self._now_q()
        return np.array([q[self.index[n]] for n in names])
