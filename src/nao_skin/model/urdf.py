"""The URDF side of the model: expand ``urdf/nao_skin.urdf.xacro``, parse a URDF, walk its joints.

Pure helpers (no ROS): the xacro is expanded with the PyPI ``xacro`` package,
the result is read with ``xml.etree``. :class:`UrdfModel` computes link poses
in the root link's frame for N joint configurations at once, which is how the
tests prove that the URDF and :mod:`nao_skin.skin` describe the same frames.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from nao_skin import se3
from nao_skin.errors import ConfigError, DataError
from nao_skin.paths import read_text, safe_load, urdf_dir

XACRO_NAME = "nao_skin.urdf.xacro"
_MOVING = ("revolute", "continuous", "prismatic")


def default_xacro() -> Path:
    return urdf_dir() / XACRO_NAME


def expand_xacro(calibration: str | Path | None = None, robot_config: str | Path | None = None,
                 xacro_file: str | Path | None = None, skin_frames: bool = True) -> str:
    """URDF text of the xacro for a calibration YAML (default: the nominal one next to the xacro).

    ``skin_frames=False``: the robot's body only, for a robot_state_publisher
    while the calibrate node publishes the skin frames. Paths are made
    absolute here because xacro resolves relative ones against the xacro
    file's directory. Raises :class:`ConfigError` (one line) when the file is
    missing or xacro fails.
    """
    import xacro  # imported late: only this function needs it

    xacro_file = Path(xacro_file) if xacro_file is not None else default_xacro()
    mappings = {"skin_frames": "true" if skin_frames else "false"}
    for arg, path in (("calibration", calibration), ("robot_config", robot_config)):
        if path is not None:
            path = Path(path).resolve()
            if not path.is_file():
                raise ConfigError(f"{path}: {arg} file for the URDF does not exist")
            mappings[arg] = str(path)
    if not xacro_file.is_file():
        raise ConfigError(f"{xacro_file}: xacro file does not exist")
    try:
        doc = xacro.process_file(str(xacro_file.resolve()), mappings=mappings)
    except Exception as exc:  # XacroException, ExpatError, or whatever a bad YAML made xacro raise
        where = calibration if calibration is not None else xacro_file
        raise ConfigError(f"{where}: xacro expansion of {xacro_file.name} failed: {exc}") from None
    finally:
        xacro.all_includes.clear()  # xacro keeps a module-level list that would grow per call
    for tag in ("link", "joint"):   # a robot frame named like a skin frame (or a generated one) collides
        seen: set = set()
        for element in doc.getElementsByTagName(tag):
            name = element.getAttribute("name")
            if name in seen:
                where = robot_config if robot_config is not None else xacro_file
                raise ConfigError(f"{where}: the URDF would define the {tag} '{name}' twice: a frame or joint of"
                                  f" the robot config is named like a skin frame or another generated name;"
                                  f" rename it")
            seen.add(name)
    return doc.toprettyxml(indent="  ")


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray        # (4, 4) child joint frame in the parent link at zero motion
    axis: np.ndarray          # (3,) unit, in the joint frame
    lower: float = -np.inf
    upper: float = np.inf


def _floats(text: str | None, count: int, where: str, default: Sequence[float]) -> np.ndarray:
    if text is None:
        return np.array(default, dtype=float)
    try:
        values = np.array([float(v) for v in text.split()], dtype=float)
    except ValueError:
        raise ConfigError(f"{where}: not {count} numbers: {text!r}") from None
    if values.shape != (count,) or not np.all(np.isfinite(values)):
        raise ConfigError(f"{where}: not {count} finite numbers: {text!r}")
    return values


class UrdfModel:
    """Links and joints of a URDF; link poses in the root frame for batches of joint positions."""

    def __init__(self, name: str, links: Sequence[str], joints: Sequence[UrdfJoint], source: str = "<memory>"):
        self.name = name
        self.links = list(links)
        self.source = source
        self.joints = {j.name: j for j in joints}
        self.joint_of_child = {}
        for j in joints:
            for end in (j.parent, j.child):
                if end not in self.links:
                    raise ConfigError(f"{source}: joint '{j.name}' names unknown link '{end}'")
            if j.child in self.joint_of_child:
                raise ConfigError(f"{source}: link '{j.child}' is the child of two joints"
                                  f" ('{self.joint_of_child[j.child].name}' and '{j.name}')")
            self.joint_of_child[j.child] = j
        roots = [link for link in self.links if link not in self.joint_of_child]
        if len(roots) != 1:
            raise ConfigError(f"{source}: a URDF needs exactly one root link, found {roots}")
        self.root = roots[0]
        self.order = self._topological_order()

    @classmethod
    def from_string(cls, text: str, source: str = "<string>") -> "UrdfModel":
        try:
            root = ET.fromstring(text)
        except ET.ParseError as exc:
            raise ConfigError(f"{source}: not valid XML ({exc})") from None
        if root.tag != "robot":
            raise ConfigError(f"{source}: the root element is <{root.tag}>, not <robot>")
        links = []
        for link in root.findall("link"):
            name = link.get("name")
            if not name:
                raise ConfigError(f"{source}: a <link> has no name")
            if name in links:
                raise ConfigError(f"{source}: link '{name}' is defined twice")
            links.append(name)
        joints = []
        for elem in root.findall("joint"):
            name, jtype = elem.get("name"), elem.get("type")
            where = f"{source}: joint '{name}'"
            if not name or jtype not in ("fixed",) + _MOVING:
                raise ConfigError(f"{where}: needs a name and a type fixed/revolute/continuous/prismatic"
                                  f" (got {jtype!r})")
            parent, child = elem.find("parent"), elem.find("child")
            if parent is None or child is None or not parent.get("link") or not child.get("link"):
                raise ConfigError(f"{where}: needs <parent link=...> and <child link=...>")
            origin = elem.find("origin")
            xyz = _floats(None if origin is None else origin.get("xyz"), 3, f"{where} origin xyz", (0, 0, 0))
            rpy = _floats(None if origin is None else origin.get("rpy"), 3, f"{where} origin rpy", (0, 0, 0))
            pose = np.eye(4)
            pose[:3, :3] = se3.matrix_from_rpy(rpy)
            pose[:3, 3] = xyz
            axis_elem = elem.find("axis")
            axis = _floats(None if axis_elem is None else axis_elem.get("xyz"), 3, f"{where} axis", (1, 0, 0))
            if jtype in _MOVING:
                norm = np.linalg.norm(axis)
                if norm < 1e-12:
                    raise ConfigError(f"{where}: axis is zero")
                axis = axis / norm
            limit = elem.find("limit")
            lower = float(limit.get("lower", "-inf")) if limit is not None else -np.inf
            upper = float(limit.get("upper", "inf")) if limit is not None else np.inf
            joints.append(UrdfJoint(name, jtype, parent.get("link"), child.get("link"), pose, axis, lower, upper))
        return cls(root.get("name", ""), links, joints, source)

    @classmethod
    def from_file(cls, path: str | Path) -> "UrdfModel":
        from nao_skin.paths import read_text

        return cls.from_string(read_text(path, "URDF", ConfigError), str(path))

    # ------------------------------------------------------------------ structure
    def _topological_order(self) -> list:
        """Joints ordered so that a joint's parent link pose is known before it is used."""
        children: dict = {}
        for j in self.joints.values():
            children.setdefault(j.parent, []).append(j)
        order, stack = [], [self.root]
        while stack:
            link = stack.pop()
            for j in children.get(link, []):
                order.append(j)
                stack.append(j.child)
        if len(order) != len(self.joints):
            raise ConfigError(f"{self.source}: the joints do not form a tree from '{self.root}' (a cycle?)")
        return order

    @property
    def moving_joint_names(self) -> list:
        return [j.name for j in self.order if j.type in _MOVING]

    # ------------------------------------------------------------------ kinematics
    def link_poses(self, positions: Mapping[str, np.ndarray], links: Sequence[str] | None = None,
                   where: str = "joint positions") -> dict:
        """Poses of ``links`` (default: all) in the root frame, each ``(N, 4, 4)``.

        ``positions`` maps every moving joint to an ``(N,)`` array (or a scalar);
        N poses are computed at once, the loop runs over the tree's joints only.
        """
        missing = [n for n in self.moving_joint_names if n not in positions]
        if missing:
            raise DataError(f"{where}: no position for joint(s) {', '.join(missing)}")
        values = {n: np.atleast_1d(np.asarray(positions[n], dtype=float)) for n in self.moving_joint_names}
        n = max((len(v) for v in values.values()), default=1)
        poses = {self.root: np.broadcast_to(np.eye(4), (n, 4, 4))}
        for j in self.order:
            pose = poses[j.parent] @ j.origin
            if j.type in ("revolute", "continuous"):
                q = np.broadcast_to(values[j.name], (n,))
                pose = pose @ se3.pose_matrix(np.concatenate([np.zeros((n, 3)), q[:, None] * j.axis], axis=1))
            elif j.type == "prismatic":
                q = np.broadcast_to(values[j.name], (n,))
                motion = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
                motion[:, :3, 3] = q[:, None] * j.axis
                pose = pose @ motion
            poses[j.child] = pose
        if links is None:
            return poses
        unknown = [link for link in links if link not in poses]
        if unknown:
            raise DataError(f"{self.source}: unknown link(s) {', '.join(unknown)}")
        return {link: poses[link] for link in links}


def check_calibration_origins(path: str | Path, skin) -> None:
    """Check that a calibration file holds every frame's URDF origin, each the pose its correction gives.

    The xacro reads ``origin`` (xyz/rpy) while the Python model reads
    ``correction``; loading checks the origins a file gives, a URDF needs them
    all. Raises :class:`ConfigError` naming the file and the frame.
    """
    from nao_skin.model.skin import SkinCalibration, check_origins

    path = Path(path)
    calib = SkinCalibration.load(path, skin)          # one-line errors for malformed files
    # C loader when available: this runs on every `nao-skin urdf` and the file has ~100 entries
    doc = safe_load(read_text(path, "as a calibration", ConfigError))
    check_origins(path, doc, calib, skin, complete=True)


def rotation_angle(rot_a: np.ndarray, rot_b: np.ndarray) -> np.ndarray:
    """Angle (rad) of ``R_a^T R_b`` for batches of 3x3 rotations: how far apart two orientations are."""
    rel = np.swapaxes(rot_a, -1, -2) @ rot_b
    return np.linalg.norm(se3.matrix_to_rotvec(rel), axis=-1)


__all__ = ["UrdfJoint", "UrdfModel", "check_calibration_origins", "default_xacro", "expand_xacro", "rotation_angle", "urdf_dir"]
