"""Robot kinematics as data: DH chains from YAML, forward kinematics batched over N poses."""
from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from nao_skin.errors import ConfigError
from nao_skin.paths import read_yaml
from nao_skin.rules import known_keys

# TF frame ids and URDF names: no spaces or markup, '/' only between names (a tf2 prefix like robot1/torso)
FRAME_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")
_ANGLE_RE = re.compile(r"^\s*([+-]?)\s*(\d*\.?\d*)\s*\*?\s*pi\s*(?:/\s*(\d+(?:\.\d*)?))?\s*$")


def parse_angle(value, where: str) -> float:
    """A number, or a string like ``"pi"``, ``"-pi/2"``, ``"2*pi/3"`` (no eval)."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return _finite(float(value), value, where)
    if isinstance(value, str):
        m = _ANGLE_RE.match(value)
        if m and m.group(2) != "." and (m.group(3) is None or float(m.group(3)) != 0.0):
            sign = -1.0 if m.group(1) == "-" else 1.0
            factor = float(m.group(2)) if m.group(2) else 1.0
            divisor = float(m.group(3)) if m.group(3) else 1.0
            return _finite(sign * factor * math.pi / divisor, value, where)
        try:
            return _finite(float(value), value, where)
        except ValueError:
            pass
    raise ConfigError(f"{where}: cannot read {value!r} as an angle (a number or e.g. 'pi/2')")


def _finite(number: float, value, where: str) -> float:
    # a NaN or infinite DH parameter or limit would turn every pose computed from it into NaN, silently
    if not math.isfinite(number):
        raise ConfigError(f"{where}: {value!r} is not a finite number")
    return number


# A Nao's links are centimetres long: a DH length beyond this is another unit or a broken file, and its
# products overflow to inf in forward kinematics.
MAX_LINK_LENGTH = 10.0


ROBOT_KEYS = ("name", "base_frame", "joints", "chains", "links", "body", "fingertips")
FINGERTIP_KEYS = ("chain", "point", "radius")
BODY_KEYS = ("rest_posture", "box", "hand_end")
DH_ROW_KEYS = ("joint", "a", "d", "alpha", "offset", "frame")
DH_PARAMS = ("a", "d")   # the DH columns a named link length may be (translations along x and z of a row)


@dataclass(frozen=True)
class Link:
    """A named link length of the robot config (NAOqi name, e.g. LElbowOffsetY): one DH translation of one row."""

    chain: str
    row: int
    param: str                      # "a" or "d"


def frame_name(value, where: str, what: str = "frame name") -> str:
    """``value`` if it is a name a TF frame and a URDF link can carry, else a one-line ConfigError."""
    if not isinstance(value, str) or not FRAME_NAME.match(value):
        raise ConfigError(f"{where}: {value!r} is not a {what} (letters, digits and '_', not starting with a"
                          f" digit; '/' between such names)")
    return value


@dataclass(frozen=True)
class Chain:
    """A serial chain of standard DH rows hanging off the base frame."""

    name: str
    dh: np.ndarray                  # (R, 4): a, d, alpha, offset
    joints: tuple                   # (R,) NAOqi joint name or None for a fixed row
    frames: tuple                   # (R,) frame name after each row

    @property
    def end_frame(self) -> str:
        return self.frames[-1]


MAX_JOINT_LIMIT = 4 * np.pi    # rad: a humanoid's joint turns less than this either way
# rad an angle may lie past a joint limit and still be at it: the Nao reads its joints with 12-bit magnetic rotary
# encoders, 2 pi / 4096 = 0.0015 rad a count, and a reading at a hard stop overshoots the documented limit (given to
# a tenth of a degree, 0.0017 rad) by up to a count; above one count, below two
JOINT_LIMIT_TOLERANCE = 0.002
MAX_FINGERTIP_RADIUS = 0.1     # m: a fingertip's contact sphere is centimetres across


@dataclass(frozen=True)
class Fingertip:
    """The end of an arm with no skin on it (a robot config's ``fingertips``): what presses a skin part in a
    fingertip touch, where only that part fires.

    Its contact is a sphere: ``point`` (3,) its centre in the chain's end frame (m), ``radius`` (m). The point
    of the fingertip that meets the skin moves over the sphere with the direction of approach, as on the real
    hand, which does not press with one point. A calibration estimates the centre and the radius where its
    fingertip touches determine them.
    """

    name: str
    chain: str
    point: np.ndarray
    radius: float


def _fingertip(name, spec, chains, where: str) -> Fingertip:
    if not isinstance(spec, dict) or "chain" not in spec or "point" not in spec:
        raise ConfigError(f"{where}: expected {{chain: an arm chain, point: [x, y, z] m in its end frame,"
                          f" radius: m}}")
    known_keys(spec, FINGERTIP_KEYS, where)
    if spec["chain"] not in chains:
        raise ConfigError(f"{where}: chain {spec['chain']!r} is not a chain of this robot (chains: {', '.join(chains)})")
    point = spec["point"]
    if not (isinstance(point, (list, tuple)) and len(point) == 3):
        raise ConfigError(f"{where}: point: expected [x, y, z] metres in the end frame of chain {spec['chain']}")
    point = np.array([parse_angle(v, f"{where}: point") for v in point])
    radius = parse_angle(spec.get("radius", 0.0), f"{where}: radius")
    if np.any(np.abs(point) > MAX_LINK_LENGTH) or not 0.0 <= radius <= MAX_FINGERTIP_RADIUS:
        raise ConfigError(f"{where}: point within {MAX_LINK_LENGTH:g} m and radius 0 to {MAX_FINGERTIP_RADIUS:g} m"
                          f" (metres)")
    return Fingertip(frame_name(name, where, "fingertip name"), str(spec["chain"]), point, float(radius))


@dataclass(frozen=True)
class Body:
    """The body the simulator poses (a robot config's ``body``): how the robot rests, ``{joint: (mean,
    spread)}`` rad (a joint not listed: 0 +- :data:`REST_SPREAD`), and the rough torso, a box of the base frame
    ``(3, 2)`` [low, high] (None: none), that an arm chain's end frame origin and ``hand_end`` (a point of
    that frame, m) keep out of."""

    rest_posture: dict
    box: np.ndarray | None = None
    hand_end: np.ndarray | None = None


REST_SPREAD = 0.1     # rad


def _body(spec, joints, where: str) -> Body:
    if not isinstance(spec, dict):
        raise ConfigError(f"{where}: expected a mapping of {', '.join(BODY_KEYS)}")
    known_keys(spec, BODY_KEYS, where)
    posture = spec.get("rest_posture")
    posture = {} if posture is None else posture        # false or 0 is no posture: refused below
    if not isinstance(posture, dict):
        raise ConfigError(f"{where}: rest_posture: expected a mapping of joint names to [mean, spread] radians")
    rest = {}
    for name, value in posture.items():
        at = f"{where}: rest_posture: {name}"
        if name not in joints:
            raise ConfigError(f"{at}: not a joint of this robot (joints: {', '.join(joints)})")
        if not (isinstance(value, (list, tuple)) and len(value) == 2):
            raise ConfigError(f"{at}: expected [mean, spread] radians")
        mean, spread = (parse_angle(v, at) for v in value)
        if abs(mean) > MAX_JOINT_LIMIT or not 0 <= spread <= MAX_JOINT_LIMIT:
            raise ConfigError(f"{at}: expected [mean, spread] radians, spread >= 0, within two turns")
        rest[str(name)] = (mean, spread)
    box = spec.get("box")
    if box is not None:
        if not (isinstance(box, (list, tuple)) and len(box) == 3 and all(
                isinstance(r, (list, tuple)) and len(r) == 2 for r in box)):
            raise ConfigError(f"{where}: box: expected [[low, high]] metres for x, y and z of the base frame")
        box = np.array([[parse_angle(v, f"{where}: box") for v in r] for r in box])
        if np.any(box[:, 0] > box[:, 1]) or np.any(np.abs(box) > MAX_LINK_LENGTH):
            raise ConfigError(f"{where}: box: expected [[low, high]] metres for x, y and z of the base frame")
    hand_end = spec.get("hand_end")
    if hand_end is not None:
        if not (isinstance(hand_end, (list, tuple)) and len(hand_end) == 3):
            raise ConfigError(f"{where}: hand_end: expected [x, y, z] metres in an arm chain's end frame")
        hand_end = np.array([parse_angle(v, f"{where}: hand_end") for v in hand_end])
        if np.any(np.abs(hand_end) > MAX_LINK_LENGTH):
            raise ConfigError(f"{where}: hand_end: expected [x, y, z] metres in an arm chain's end frame")
    return Body(rest, box, hand_end)


def _fingertips(spec, chains: dict, taken: set, path: Path) -> dict:
    """A robot config's ``fingertips``: ``{name: Fingertip}``, none named as a frame, chain or joint is."""
    if not isinstance(spec, dict):
        raise ConfigError(f"{path}: 'fingertips' must map fingertip names to {{chain, point, radius}}")
    out = {str(n): _fingertip(n, entry, chains, f"{path}: fingertip '{n}'") for n, entry in spec.items()}
    for n in out:
        if n in taken:
            raise ConfigError(f"{path}: fingertip '{n}' has the name of a frame, chain or joint of the robot")
    return out


def _links(spec: dict, path: Path) -> dict:
    """A robot config's ``links``: ``{name: Link}`` (checked against the chains by the model)."""
    links = {}
    for lname, entry in spec.items():
        if not isinstance(entry, dict) or not {"chain", "row", "param"} <= set(entry) \
                or not isinstance(entry["row"], int) or isinstance(entry["row"], bool):
            raise ConfigError(f"{path}: link '{lname}' needs chain, row (a whole number) and param (a or d)")
        known_keys(entry, ("chain", "row", "param"), f"{path}: link '{lname}'")
        links[str(lname)] = Link(str(entry["chain"]), int(entry["row"]), str(entry["param"]))
    return links


class RobotModel:
    """Kinematic model of the robot's upper body.

    ``joint_names`` fixes the column order of joint arrays ``q`` of shape
    ``(N, J)``; every FK call is vectorised over the N rows.
    """

    def __init__(self, name: str, base_frame: str, joint_limits: Mapping[str, Sequence[float]],
                 chains: Mapping[str, Chain], source: str = "<memory>", links: Mapping[str, Link] | None = None,
                 body: Body | None = None, fingertips: Mapping[str, Fingertip] | None = None):
        self.name = name
        self.fingertips = dict(fingertips or {})
        self.body = body or Body({})
        self.base_frame = base_frame
        self.joint_names = list(joint_limits)
        self.joint_index = {n: i for i, n in enumerate(self.joint_names)}
        self.limits = np.array([joint_limits[n] for n in self.joint_names], dtype=float).reshape(-1, 2)
        self.chains = dict(chains)
        self.source = source
        self.links = dict(links or {})
        for lname, link in self.links.items():
            if link.chain not in self.chains:
                raise ConfigError(f"{source}: link '{lname}' is on chain '{link.chain}', which the file does not"
                                  f" describe (chains: {', '.join(self.chains) or 'none'})")
            if not 0 <= link.row < len(self.chains[link.chain].joints) \
                    or link.param not in DH_PARAMS or lname in self.joint_index:
                raise ConfigError(f"{source}: link '{lname}' must name a chain, a row of it and a DH parameter"
                                  f" ({' or '.join(DH_PARAMS)}), and not be a joint name")
        for chain in self.chains.values():
            for j in chain.joints:
                if j is not None and j not in self.joint_index:
                    raise ConfigError(f"{source}: chain '{chain.name}' names unknown joint '{j}'"
                                      f" (known: {', '.join(self.joint_names)})")

    # ------------------------------------------------------------------ loading
    @classmethod
    def from_yaml(cls, path: str | Path) -> "RobotModel":
        path = Path(path)
        doc = read_yaml(path, "robot config")
        if not isinstance(doc, dict) or not isinstance(doc.get("chains"), dict) \
                or not isinstance(doc.get("joints"), dict):
            raise ConfigError(f"{path}: a robot config needs 'joints' and 'chains' mappings")
        known_keys(doc, ROBOT_KEYS, str(path))        # a misspelt 'links' dropped every link without a word
        if not isinstance(doc.get("links") or {}, dict):
            raise ConfigError(f"{path}: 'links' must be a mapping of link name to {{chain, row, param}}")
        limits = {}
        for jname, lim in doc["joints"].items():
            if not (isinstance(lim, (list, tuple)) and len(lim) == 2):
                raise ConfigError(f"{path}: joint '{jname}' limits must be [lower, upper]")
            lo, hi = (parse_angle(v, f"{path}: joint '{jname}'") for v in lim)
            if not lo < hi:
                raise ConfigError(f"{path}: joint '{jname}' lower limit {lo} is not below upper {hi}")
            if max(abs(lo), abs(hi)) > MAX_JOINT_LIMIT:    # the pose search draws angles between them
                raise ConfigError(f"{path}: joint '{jname}' limits [{lo}, {hi}] reach beyond two turns"
                                  f" (|limit| <= {MAX_JOINT_LIMIT:.2f} rad)")
            limits[str(jname)] = (lo, hi)
        chains = {}
        for cname, rows in doc["chains"].items():
            if not isinstance(rows, list) or not rows:
                raise ConfigError(f"{path}: chain '{cname}' must be a non-empty list of DH rows")
            dh, joints, frames = [], [], []
            for i, row in enumerate(rows):
                where = f"{path}: chain '{cname}' row {i}"
                if not isinstance(row, dict):
                    raise ConfigError(f"{where}: must be a mapping with a, d, alpha, offset, joint")
                known_keys(row, DH_ROW_KEYS, where)
                missing = [k for k in ("a", "d", "alpha", "offset") if k not in row]
                if missing:
                    raise ConfigError(f"{where}: missing {', '.join(missing)}")
                dh.append([parse_angle(row["a"], f"{where} a"), parse_angle(row["d"], f"{where} d"),
                           parse_angle(row["alpha"], f"{where} alpha"), parse_angle(row["offset"], f"{where} offset")])
                for name, length in zip(DH_PARAMS, dh[-1][:2]):
                    if abs(length) > MAX_LINK_LENGTH:
                        raise ConfigError(f"{where} {name}: {length:g} m is beyond {MAX_LINK_LENGTH:g} m"
                                          f" (lengths are metres)")
                joint = row.get("joint")
                if joint is not None and (not isinstance(joint, str) or joint not in limits):
                    raise ConfigError(f"{where}: unknown joint '{joint}'"
                                      f" (not listed under 'joints')")
                joints.append(joint)
                frames.append(frame_name(row.get("frame", f"{cname}_dh{i + 1}"), f"{where} frame"))
            chains[str(cname)] = Chain(str(cname), np.array(dh), tuple(joints), tuple(frames))
        # frames are URDF links and TF frames: one name, one frame (a URDF holds each link once)
        base_frame = frame_name(doc.get("base_frame", "torso"), f"{path}: base_frame")
        named = {base_frame: "the base frame"}
        for cname, chain in chains.items():
            for i, frame in enumerate(chain.frames):
                if frame in named:
                    raise ConfigError(f"{path}: chain '{cname}' row {i}: frame '{frame}' is also {named[frame]}")
                named[frame] = f"chain '{cname}' row {i}'s"
        links = _links(doc.get("links") or {}, path)
        body = _body(doc["body"], limits, f"{path}: body") if "body" in doc else None
        robot = cls(frame_name(doc.get("name", path.stem), f"{path}: name", "robot name"), base_frame,
                    limits, chains, source=str(path), links=links, body=body)
        robot.fingertips = _fingertips(doc.get("fingertips") or {}, chains, {*named, *chains, *limits}, path)
        return robot

    # ------------------------------------------------------------------ corrections
    def kinematic_names(self, chains) -> list:
        """What a kinematic calibration may correct on ``chains``: their joints' angle offsets (NAOqi
        joint names), then their named link lengths, in the config's order."""
        chains = [c for c in chains if c is not None]
        joints = [j for c in chains for j in self.chain_joint_names(c)]
        return list(dict.fromkeys(joints)) + [n for n, link in self.links.items() if link.chain in chains]

    def corrected(self, kinematics: Mapping[str, float]) -> "RobotModel":
        """This robot with kinematic corrections: a joint name's value (rad) is added to the angle the
        joint reports (the DH row's offset), a link name's value (m) to its DH parameter."""
        dh = {name: chain.dh.copy() for name, chain in self.chains.items()}
        for key, value in kinematics.items():
            if key in self.links:
                link = self.links[key]
                dh[link.chain][link.row, DH_PARAMS.index(link.param)] += float(value)
            elif key in self.joint_index:
                for name, chain in self.chains.items():
                    for r, j in enumerate(chain.joints):
                        if j == key:
                            dh[name][r, 3] += float(value)
            else:
                raise ConfigError(f"{self.source}: kinematic correction '{key}' is neither a joint nor a named link"
                                  f" (links: {', '.join(self.links) or 'none'})")
        chains = {name: Chain(name, dh[name], chain.joints, chain.frames) for name, chain in self.chains.items()}
        limits = {n: tuple(self.limits[i]) for i, n in enumerate(self.joint_names)}
        return RobotModel(self.name, self.base_frame, limits, chains, self.source, self.links, self.body,
                          self.fingertips)

    # ------------------------------------------------------------------ fingertips
    def fingertip(self, name: str) -> Fingertip:
        try:
            return self.fingertips[name]
        except KeyError:
            raise ConfigError(f"{self.source}: unknown fingertip '{name}' (fingertips:"
                              f" {', '.join(self.fingertips) or 'none'})") from None

    def rotation_gauge(self, chains) -> str | None:
        """The joint whose offset the touches of a scene on ``chains`` cannot tell from the skin: where the first
        joint of every chain turns about one and the same line of the base frame (both arms' ShoulderPitch about
        the shoulders' axis), turning each of those joints and every skin on the base about that line changes no
        contact, so one of their offsets is held (the first chain's, of ``chains`` in the config's order); None
        where the lines differ (the head's HeadYaw is vertical) or no chain has a joint."""
        chains = [c for c in self.chains if c in set(chains)]
        axes = []
        for name in chains:
            chain = self.chains[name]
            rows = [r for r, j in enumerate(chain.joints) if j is not None]
            if not rows:
                return None
            frames = self.fk_frames(name, np.zeros((1, len(self.joint_names))))[0]
            before = frames[rows[0] - 1] if rows[0] > 0 else np.eye(4)     # no joint before it: fixed in the base
            axes.append((chain.joints[rows[0]], before[:3, 3], before[:3, 2]))
        if not axes:
            return None
        joint, point, direction = axes[0]
        for _, p, d in axes[1:]:
            if abs(abs(float(d @ direction)) - 1.0) > 1e-9 or np.linalg.norm(np.cross(p - point, direction)) > 1e-9:
                return None
        return joint

    # ------------------------------------------------------------------ joints
    def chain_joint_names(self, chain: str) -> list:
        return [j for j in self.chains[chain].joints if j is not None]

    # ------------------------------------------------------------------ kinematics
    def _row_transforms(self, chain: Chain, q: np.ndarray) -> np.ndarray:
        """(N, R, 4, 4) DH transforms of every row."""
        n = q.shape[0]
        rows = len(chain.joints)
        theta = np.broadcast_to(chain.dh[:, 3], (n, rows)).copy()
        for r, jname in enumerate(chain.joints):
            if jname is not None:
                theta[:, r] += q[:, self.joint_index[jname]]
        a, d, alpha = chain.dh[:, 0], chain.dh[:, 1], chain.dh[:, 2]
        ct, st = np.cos(theta), np.sin(theta)
        ca, sa = np.cos(alpha), np.sin(alpha)
        out = np.zeros((n, rows, 4, 4))
        out[..., 0, 0] = ct
        out[..., 0, 1] = -st * ca
        out[..., 0, 2] = st * sa
        out[..., 0, 3] = a * ct
        out[..., 1, 0] = st
        out[..., 1, 1] = ct * ca
        out[..., 1, 2] = -ct * sa
        out[..., 1, 3] = a * st
        out[..., 2, 1] = sa
        out[..., 2, 2] = ca
        out[..., 2, 3] = d
        out[..., 3, 3] = 1.0
        return out

    def fk_frames(self, chain: str, q: np.ndarray) -> np.ndarray:
        """Poses in the base frame of every frame of ``chain``: ``(N, R, 4, 4)``."""
        ch = self._chain(chain)
        q = np.atleast_2d(np.asarray(q, dtype=float))
        rows = self._row_transforms(ch, q)
        out = np.empty_like(rows)
        acc = rows[:, 0]
        out[:, 0] = acc
        for r in range(1, rows.shape[1]):  # loop over <= 6 rows, vectorised over N
            acc = acc @ rows[:, r]
            out[:, r] = acc
        return out

    def fk(self, chain: str | None, q: np.ndarray) -> np.ndarray:
        """Pose of the chain's end frame in the base frame, ``(N, 4, 4)``.

        ``chain=None`` is the base itself (identity), e.g. for the torso skin.
        """
        q = np.atleast_2d(np.asarray(q, dtype=float))
        if chain is None:
            return np.broadcast_to(np.eye(4), (q.shape[0], 4, 4)).copy()
        return self.fk_frames(chain, q)[:, -1]

    def chain_sha256(self, chain: str) -> str:
        """SHA-256 of what a skin frame hanging off ``chain`` was calibrated on: the base frame, then each DH
        row's joint, frame and parameters (12 significant digits: "pi/2" and 1.5707963267949 hash alike)."""
        ch = self._chain(chain)
        rows = [[j, f, *(f"{float(v) + 0.0:.12g}" for v in dh)] for j, f, dh in zip(ch.joints, ch.frames, ch.dh)]
        return hashlib.sha256(json.dumps([self.base_frame, rows]).encode()).hexdigest()

    def end_frame(self, chain: str | None) -> str:
        return self.base_frame if chain is None else self._chain(chain).end_frame

    def _chain(self, chain: str) -> Chain:
        try:
            return self.chains[chain]
        except KeyError:
            raise ConfigError(f"{self.source}: unknown chain '{chain}'"
                              f" (known: {', '.join(self.chains)})") from None
