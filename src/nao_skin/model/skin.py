"""Skin model: parts -> patches -> triangles -> taxel slots, their frames and corrections.

Frame tree of one skin part (all poses rigid)::

    chain end (e.g. l_wrist_link, or torso)
      -> <part>_skin_mount          nominal M_n, corrected by exp(dM)
         -> <part>_skin_patch_<p>   nominal P_n[p] (relative to the mount), * exp(dP[p])
            -> <part>_skin_triangle_<t>  nominal T_n[t] (relative to its patch), * exp(dT[t])
               -> taxels: fixed coordinates in their triangle frame

Nominal frames come from the layout: the mount sits at the centroid of the
part's taxels with the chain end's axes; a patch or triangle frame sits at the
centroid of its taxels with z along the mean taxel normal. Putting origins at
centroids keeps rotation and translation corrections nearly decoupled, which
is what makes the per-component bounds of the thesis meaningful and the
least-squares problem well conditioned.

A taxel at slot s of triangle t in patch p reaches the chain end frame as
``M_n exp(dM) P_n[p] exp(dP[p]) T_n[t] exp(dT[t]) q_s`` and the base (torso)
frame through the chain's forward kinematics.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, NamedTuple

import numpy as np
import yaml

from nao_skin import se3
from nao_skin.errors import ConfigError, DataError
from nao_skin.model.robot import RobotModel
from nao_skin.model.taxel_file import DEFAULT_SLOTS, SLOTS_PER_TRIANGLE, TaxelFile, read_taxel_file, write_taxel_file
from nao_skin.paths import DANGLING_LINK, read_yaml
from nao_skin.rules import known_keys

PART_NAMES = ("r_hand", "l_hand", "torso", "head")   # skinManager part names on the Nao: listed first


@dataclass(frozen=True)
class SelfTouch:
    """Which skin parts touch (an arm's end) and which they touch: a skin config's ``self_touch``.

    Each in the order the calibration plan takes them (thesis 2.5): each touching part first, fitted to
    the first touched part it presses, then each touched part, fitted to the calibrated touching parts.
    """

    touching: tuple
    touched: tuple

    def pairs(self) -> tuple:
        """Every ``(touching, touched)`` pair."""
        return tuple((a, b) for a in self.touching for b in self.touched)


@dataclass(frozen=True)
class FingertipTouch:
    """Which fingertips (of the robot config) press which skin parts: a skin config's ``fingertip_touch``.
    Only the pressed part fires. A fingertip never presses the skin of its own arm: those pairs are not
    among :meth:`pairs`."""

    touching: tuple = ()
    touched: tuple = ()
    same_arm: frozenset = frozenset()     # (fingertip, part) pairs on one chain

    def pairs(self) -> tuple:
        """Every ``(fingertip, touched part)`` pair."""
        return tuple((f, p) for f in self.touching for p in self.touched if (f, p) not in self.same_arm)


def part_rank(name: str) -> tuple:
    """Order of parts everywhere: r_hand, l_hand, torso, head, then others by name (a total order: what
    follows it, a plan's steps or a joint stage's parameters, never hangs on a set's order)."""
    return (PART_NAMES.index(name) if name in PART_NAMES else len(PART_NAMES), name)


def scene_label(fingertip: str, part: str) -> str:
    """The name of a fingertip scene in reports and status messages: 'r_finger-torso'."""
    return f"{fingertip}-{part}"


def pair_label(parts) -> str:
    """The name of a set of touching parts in reports and status messages: 'r_hand+torso' (:func:`part_rank` order)."""
    return "+".join(sorted(parts, key=part_rank))


def _frame_from(origin: np.ndarray, z_axis: np.ndarray, x_hint: np.ndarray) -> np.ndarray:
    """Right-handed frame at ``origin`` with z along ``z_axis`` and x towards ``x_hint``."""
    z = z_axis / np.linalg.norm(z_axis)
    x = x_hint - (x_hint @ z) * z
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [1.0, 0.0, 0.0])
        if np.linalg.norm(x) < 1e-9:
            x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    out = np.eye(4)
    out[:3, 0] = x
    out[:3, 1] = np.cross(z, x)
    out[:3, 2] = z
    out[:3, 3] = origin
    return out


def _mean_normal(points: np.ndarray, normals: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    n = normals.sum(axis=0)
    if np.linalg.norm(n) > 1e-9:
        return n / np.linalg.norm(n)
    if len(points) >= 3:  # no normals in the file: plane fit, oriented like the fallback
        _, _, vt = np.linalg.svd(points - points.mean(axis=0))
        n = vt[2]
        return n if n @ fallback >= 0 else -n
    return fallback


@dataclass
class PartCorrection:
    """SE(3) corrections (6-vectors t, rotvec) of one part's mount, patches and triangles."""

    mount: np.ndarray          # (6,)
    patches: np.ndarray        # (P, 6) in the order of SkinPart.patch_ids
    triangles: np.ndarray      # (T, 6) in the order of SkinPart.triangle_ids

    def copy(self) -> "PartCorrection":
        return PartCorrection(self.mount.copy(), self.patches.copy(), self.triangles.copy())


class SkinFrame(NamedTuple):
    """One calibrated skin frame relative to its parent: what the URDF, /tf_static and calibration.yaml hold."""

    kind: str                  # "mount", "patch" or "triangle"
    number: int | None         # patch or triangle number; None for the mount
    parent: str
    frame: str
    correction: np.ndarray     # (6,) t, rotvec: applied after the nominal pose, in the frame's own axes
    pose: np.ndarray           # (4, 4) nominal pose * exp(correction), relative to ``parent``


@dataclass
class SkinPart:
    name: str
    chain: str | None
    parent_frame: str
    source: str
    positions: np.ndarray            # (S, 3) nominal, chain-end frame
    normals: np.ndarray              # (S, 3)
    present: np.ndarray              # (S,) bool
    triangle_ids: np.ndarray         # (T,) triangle numbers (slot // 12)
    patch_ids: np.ndarray            # (P,) patch numbers
    triangle_patch: np.ndarray       # (T,) row into patch_ids
    slot_triangle: np.ndarray        # (S,) row into triangle_ids, -1 if no taxel
    mount_nominal: np.ndarray        # (4, 4) in the chain-end frame
    patch_nominal: np.ndarray        # (P, 4, 4) relative to the mount
    triangle_nominal: np.ndarray     # (T, 4, 4) relative to its patch
    taxel_local: np.ndarray          # (S, 3) in the nominal triangle frame
    normal_local: np.ndarray         # (S, 3) in the nominal triangle frame
    layout_file: str = ""            # the taxel file the layout came from
    # what the skin config gave beside the layout (None: derived from it): kept when --taxels replaces the layout
    patch_table: dict | None = None  # patch number -> triangle numbers
    mount_given: np.ndarray | None = None   # (4, 4) nominal mount

    @property
    def layout_sha256(self) -> str:
        """Hash of the layout itself (slots, positions, normals): same taxels, same hash, whatever the file.

        A calibration is only meaningful on the layout it was made with; this is
        what ``calibration.yaml`` records and checks.
        """
        import hashlib

        h = hashlib.sha256(np.packbits(self.present).tobytes())
        for a in (self.positions, self.normals):
            h.update(np.ascontiguousarray(np.round(np.where(self.present[:, None], a, 0.0), 9) + 0.0).tobytes())
        return h.hexdigest()

    # ------------------------------------------------------------------ sizes and names
    @property
    def n_slots(self) -> int:
        return len(self.present)

    @property
    def slots(self) -> np.ndarray:
        """Slot numbers of the present taxels."""
        return np.flatnonzero(self.present)

    @property
    def mount_frame(self) -> str:
        return f"{self.name}_skin_mount"

    def patch_frame(self, patch_id: int) -> str:
        return f"{self.name}_skin_patch_{int(patch_id)}"

    def triangle_frame(self, triangle_id: int) -> str:
        return f"{self.name}_skin_triangle_{int(triangle_id)}"

    def zero_correction(self) -> PartCorrection:
        return PartCorrection(np.zeros(6), np.zeros((len(self.patch_ids), 6)),
                              np.zeros((len(self.triangle_ids), 6)))

    # ------------------------------------------------------------------ frames
    def frame_poses(self, corr: PartCorrection | None = None):
        """Calibrated poses in the chain-end frame: mount (4,4), patches (P,4,4), triangles (T,4,4)."""
        corr = corr or self.zero_correction()
        # one batched Rodrigues for every frame: this runs at every residual and re-pairing
        n_p = len(corr.patches)
        deltas = se3.pose_matrix(np.concatenate([np.reshape(corr.mount, (1, 6)), corr.patches, corr.triangles]))
        mount = self.mount_nominal @ deltas[0]
        patches = mount @ self.patch_nominal @ deltas[1:1 + n_p]
        triangles = patches[self.triangle_patch] @ self.triangle_nominal @ deltas[1 + n_p:]
        return mount, patches, triangles

    def frames(self, corr: PartCorrection | None = None) -> list:
        """The part's frames relative to their parents (:class:`SkinFrame`): the mount, the patches, the triangles."""
        corr = corr or self.zero_correction()
        mount = self.mount_nominal @ se3.pose_matrix(corr.mount)
        patches = self.patch_nominal @ se3.pose_matrix(corr.patches)
        tris = self.triangle_nominal @ se3.pose_matrix(corr.triangles)
        return ([SkinFrame("mount", None, self.parent_frame, self.mount_frame, corr.mount, mount)]
                + [SkinFrame("patch", int(pid), self.mount_frame, self.patch_frame(pid), corr.patches[i], patches[i])
                   for i, pid in enumerate(self.patch_ids)]
                + [SkinFrame("triangle", int(tid), self.patch_frame(self.patch_ids[self.triangle_patch[i]]),
                             self.triangle_frame(tid), corr.triangles[i], tris[i])
                   for i, tid in enumerate(self.triangle_ids)])

    def taxel_positions(self, corr: PartCorrection | None = None, normals: bool = True):
        """Calibrated ``(positions, normals)`` of every slot in the chain-end frame (NaN where no taxel);
        with ``normals=False`` the positions alone (the pairing's hot path needs no normals)."""
        _, _, tri = self.frame_poses(corr)
        pos = np.full((self.n_slots, 3), np.nan)
        idx = self.slots
        frames = tri[self.slot_triangle[idx]]
        pos[idx] = se3.transform_points(frames, self.taxel_local[idx])
        if not normals:
            return pos
        nor = np.full((self.n_slots, 3), np.nan)
        nor[idx] = se3.rotate_vectors(frames, self.normal_local[idx])
        return pos, nor

    def write_taxel_file(self, path: str | Path, corr: PartCorrection | None = None) -> None:
        pos, nor = self.taxel_positions(corr)
        write_taxel_file(path, np.nan_to_num(pos), np.nan_to_num(nor), self.present, self.name)


def build_part(name: str, chain: str | None, parent_frame: str, taxels: TaxelFile,
               patches: Mapping[int, list] | None, source: str,
               mount_pose: np.ndarray | None = None, layout_file: str = "") -> SkinPart:
    """Derive the nominal frame tree of a part from its layout and patch table."""
    n_slots = len(taxels.positions)
    present = taxels.present
    n_tri_slots = n_slots // SLOTS_PER_TRIANGLE
    tri_of_slot = np.arange(n_slots) // SLOTS_PER_TRIANGLE
    given = patches
    if patches is None:  # Nao convention: 16 triangles per patch
        used = np.unique(tri_of_slot[present])
        patches = {}
        for t in used:
            patches.setdefault(int(t) // 16, []).append(int(t))
    owner: dict = {}
    for pid, tris in patches.items():
        if not isinstance(tris, (list, tuple)):
            raise ConfigError(f"{source}: part '{name}' patch {pid}: expected a list of triangle numbers")
        for t in tris:
            if isinstance(t, bool) or not isinstance(t, int) or not 0 <= t < n_tri_slots:
                raise ConfigError(f"{source}: part '{name}' patch {pid}: triangle {t!r} is not in 0..{n_tri_slots - 1}")
            if t in owner:
                raise ConfigError(f"{source}: part '{name}': triangle {t} is listed in patch {owner[t]} and in patch {pid}")
            owner[t] = int(pid)
    orphan = sorted({int(t) for t in tri_of_slot[present]} - set(owner))
    if orphan:
        raise ConfigError(f"{source}: part '{name}': triangles {orphan} have taxels in the layout but are in no patch")
    triangle_ids = np.array(sorted(t for t in owner if np.any(present[tri_of_slot == t])), dtype=int)
    empty = sorted(set(owner) - set(triangle_ids.tolist()))
    if len(triangle_ids) == 0:
        raise ConfigError(f"{source}: part '{name}': the layout has no taxel in any listed triangle")
    patch_ids = np.array(sorted({owner[t] for t in triangle_ids}), dtype=int)
    patch_row = {p: i for i, p in enumerate(patch_ids)}
    tri_row = {t: i for i, t in enumerate(triangle_ids)}
    triangle_patch = np.array([patch_row[owner[t]] for t in triangle_ids], dtype=int)
    slot_triangle = np.array([tri_row.get(int(t), -1) if present[s] else -1
                              for s, t in enumerate(tri_of_slot)], dtype=int)
    del empty  # triangles listed without any known taxel simply get no frame

    pos, nor = taxels.positions, taxels.normals
    all_pts = pos[present]
    mount_abs = np.eye(4)
    mount_abs[:3, 3] = all_pts.mean(axis=0)
    if mount_pose is not None:
        mount_abs = np.asarray(mount_pose, dtype=float)
    mean_n = _mean_normal(all_pts, nor[present], np.array([0.0, 0.0, 1.0]))
    patch_abs = np.empty((len(patch_ids), 4, 4))
    for i, p in enumerate(patch_ids):
        sel = present & np.isin(tri_of_slot, triangle_ids[triangle_patch == i])
        pts = pos[sel]
        centre = pts.mean(axis=0)
        # x along the patch's principal direction, for a frame that reads like the patch
        _, _, vt = np.linalg.svd(pts - centre) if len(pts) > 1 else (None, None, np.eye(3))
        patch_abs[i] = _frame_from(centre, _mean_normal(pts, nor[sel], mean_n), vt[0])
    tri_abs = np.empty((len(triangle_ids), 4, 4))
    for i, t in enumerate(triangle_ids):
        sel = present & (tri_of_slot == t)
        pts = pos[sel]
        centre = pts.mean(axis=0)
        fallback = patch_abs[triangle_patch[i]][:3, 2]
        tri_abs[i] = _frame_from(centre, _mean_normal(pts, nor[sel], fallback), pts[0] - centre)
    patch_rel = se3.invert(mount_abs) @ patch_abs
    tri_rel = se3.invert(patch_abs[triangle_patch]) @ tri_abs
    taxel_local = np.zeros((n_slots, 3))
    normal_local = np.zeros((n_slots, 3))
    idx = np.flatnonzero(present)
    inv = se3.invert(tri_abs[slot_triangle[idx]])
    taxel_local[idx] = se3.transform_points(inv, pos[idx])
    normal_local[idx] = se3.rotate_vectors(inv, nor[idx])
    return SkinPart(name, chain, parent_frame, source, pos.copy(), nor.copy(), present.copy(),
                    triangle_ids, patch_ids, triangle_patch, slot_triangle, mount_abs, patch_rel,
                    tri_rel, taxel_local, normal_local, layout_file or source,
                    {int(k): list(v) for k, v in given.items()} if given is not None else None,
                    None if mount_pose is None else np.asarray(mount_pose, dtype=float).copy())


CALIBRATION_FORMAT = "nao_skin/calibration/1"
# A kinematic correction is a few mm or degrees (the solver itself stops at 3 cm and 0.2 rad): beyond these
# is a broken file or another unit
MAX_LINK_CORRECTION = 0.1       # m
MAX_JOINT_CORRECTION = 0.5      # rad
# A Nao is half a metre tall: a skin frame farther off than this is another unit (mm) or a broken file.
MAX_OFFSET = 10.0
# Any rotation vector equals one of norm <= pi; far beyond is a broken file (and squaring 1e300 overflows).
MAX_ROTATION = 100.0
# skinManager parts have 384 slots; iCub's largest (an arm) 768: far beyond is a typo that costs memory
MAX_SLOTS = 12 * 1024


def _slot_count(value, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 < value <= MAX_SLOTS \
            or value % SLOTS_PER_TRIANGLE:
        raise ConfigError(f"{where}: slots {value!r}: expected a multiple of {SLOTS_PER_TRIANGLE}"
                          f" (slot = {SLOTS_PER_TRIANGLE} * triangle + k) in {SLOTS_PER_TRIANGLE}..{MAX_SLOTS}")
    return value


# a whole number written in ASCII digits (str.isdigit() and int() also take '²' or '١'); as a patch or
# triangle number, no more digits than an int64 holds (int() refuses 5000)
INTEGER_TEXT = re.compile(r"-?[0-9]+")
WHOLE_NUMBER = re.compile(r"-?[0-9]{1,18}")


def _whole_number(key, where: str, high: int | None = None) -> int:
    """A patch or triangle number as YAML gives it (an int, or a string of one): not 0.5, not 'abc'; with
    ``high``, in 0..high (a patch number names frames: not -3, not 10**23)."""
    if isinstance(key, bool) or not isinstance(key, (int, str)) or (
            isinstance(key, str) and not WHOLE_NUMBER.fullmatch(key.strip())):
        digits = isinstance(key, str) and INTEGER_TEXT.fullmatch(key.strip()) is not None   # too many of them
        raise ConfigError(f"{where} {key!r}: expected a whole number"
                          + (f" in 0..{high}" if digits and high is not None else ""))
    if high is not None and not 0 <= int(key) <= high:
        raise ConfigError(f"{where} {key!r}: expected a whole number in 0..{high}")
    return int(key)


def _numbered(mapping: Mapping, where: str, high: int | None = None) -> dict:
    """``mapping`` keyed by whole numbers (:func:`_whole_number`); one number given twice (as 3 and '3', or
    '03') is refused, as any key given twice is."""
    out, given = {}, {}
    for key, value in mapping.items():
        number = _whole_number(key, where, high)
        if number in out:
            raise ConfigError(f"{where} {number} is given twice (as {given[number]!r} and {key!r})")
        out[number], given[number] = value, key
    return out


def _mount_vector(mount, where: str) -> np.ndarray:
    """``xyz`` + ``rotvec`` of a skin config's nominal mount: 6 finite numbers (missing ones zero)."""
    if not isinstance(mount, dict):
        raise ConfigError(f"{where}: expected {{xyz: [x, y, z], rotvec: [rx, ry, rz]}}")
    known_keys(mount, ("xyz", "rotvec"), where)      # 'rpy' would be dropped without a word
    try:
        vector = np.array([float(v) for key in ("xyz", "rotvec") for v in mount.get(key, [0.0, 0.0, 0.0])])
    except (TypeError, ValueError, OverflowError):
        vector = None
    if vector is None or not _plausible_pose(vector):
        raise ConfigError(f"{where}: xyz and rotvec must be 3 finite numbers each, metres (at most"
                          f" {MAX_OFFSET:g}) and radians (at most {MAX_ROTATION:g})")
    return vector


def _written(value) -> float:
    """A number as calibration files give it: 10 decimals, and no "-0.0" (``+ 0.0`` turns it to 0.0)."""
    return round(float(value), 10) + 0.0


def _plausible_pose(vector: np.ndarray) -> bool:
    """6 finite numbers, a translation and a rotation vector within :data:`MAX_OFFSET` / :data:`MAX_ROTATION`."""
    return vector.shape == (6,) and bool(np.all(np.isfinite(vector))) \
        and np.abs(vector[:3]).max() <= MAX_OFFSET and np.abs(vector[3:]).max() <= MAX_ROTATION


PART_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
SKIN_CONFIG_KEYS = ("robot", "parts", "self_touch", "fingertip_touch")
MAX_PATCH_NUMBER = 65535   # patch numbers are labels (frame names), skinManager's are small

PART_KEYS = ("chain", "taxel_file", "slots", "patches", "mount")


class SkinModel:
    """The robot plus its skin parts: taxel positions in the base frame for batches of poses."""

    def __init__(self, robot: RobotModel, parts: Mapping[str, SkinPart], source: str, self_touch: SelfTouch,
                 fingertip_touch: FingertipTouch = FingertipTouch()):
        self.robot = robot
        self.parts = dict(parts)
        self.source = source
        self.self_touch = self_touch
        self.fingertip_touch = fingertip_touch
        # the last skin on a corrected robot (with_kinematics): the same corrections give the same
        # object, so what touch sets derive from it (forward kinematics) is computed once
        self._corrected: tuple = ((), self)

    @classmethod
    def from_yaml(cls, path: str | Path, robot: RobotModel | None = None) -> "SkinModel":
        """Load ``config/nao_skin.yaml``-style files (paths inside are relative to the file)."""
        path = Path(path)
        doc = read_yaml(path, "skin config")
        if not isinstance(doc, dict) or not isinstance(doc.get("parts"), dict) or not doc["parts"]:
            raise ConfigError(f"{path}: a skin config needs a 'parts' mapping with at least one part")
        known_keys(doc, SKIN_CONFIG_KEYS, f"{path}")
        if robot is None:
            if not isinstance(doc.get("robot"), str):
                raise ConfigError(f"{path}: names no 'robot' config file")
            robot = RobotModel.from_yaml(path.parent / doc["robot"])
        parts = {}
        for name, spec in doc["parts"].items():
            where = f"{path}: part '{name}'"
            if not isinstance(name, str) or not PART_NAME.match(name):
                # a part's name becomes TF frame names and file names (taxels/<part>.txt of an output)
                raise ConfigError(f"{where}: a part name is a letter, then letters, digits or '_'")
            if not isinstance(spec, dict) or not isinstance(spec.get("taxel_file"), str) or "chain" not in spec:
                raise ConfigError(f"{where}: needs 'taxel_file' and 'chain' (null for the base)")
            known_keys(spec, PART_KEYS, where)
            chain = spec.get("chain")
            if chain is not None and (not isinstance(chain, str) or chain not in robot.chains):
                raise ConfigError(f"{where}: unknown chain {chain!r} (robot has {', '.join(robot.chains)})")
            taxel_path = path.parent / spec["taxel_file"]
            taxels = read_taxel_file(taxel_path, _slot_count(spec.get("slots", DEFAULT_SLOTS), where))
            patches = spec.get("patches")
            if patches is not None:
                if not isinstance(patches, dict):
                    raise ConfigError(f"{where}: 'patches' must map patch numbers to lists of triangles")
                patches = _numbered(patches, f"{where}: patch", MAX_PATCH_NUMBER)
            mount = None
            if "mount" in spec:
                mount = se3.pose_matrix(_mount_vector(spec["mount"], f"{where}: mount"))
            parts[str(name)] = build_part(str(name), chain, robot.end_frame(chain), taxels, patches,
                                          str(path), mount, str(taxel_path))
        if "self_touch" not in doc:
            raise ConfigError(f"{path}: names no 'self_touch' (which parts touch which, e.g. touching: [r_hand,"
                              f" l_hand], touched: [torso, head])")
        self_touch = _self_touch(doc["self_touch"], parts, f"{path}: self_touch")
        fingertip_touch = (_fingertip_touch(doc["fingertip_touch"], parts, robot, f"{path}: fingertip_touch")
                           if doc.get("fingertip_touch") is not None else FingertipTouch())
        return cls(robot, parts, str(path), self_touch, fingertip_touch)

    def source_files(self) -> list:
        """The files this model was read from: the skin config, the robot config and every part's layout
        (what an output must never be written over)."""
        files = (self.source, self.robot.source, *(p.layout_file for p in self.parts.values()))
        return list(dict.fromkeys(f for f in files if f and Path(f).is_file()))     # not "<memory>"

    def part(self, name: str) -> SkinPart:
        try:
            return self.parts[name]
        except KeyError:
            raise DataError(f"unknown skin part '{name}' (configured: {', '.join(self.parts)})") from None

    def with_kinematics(self, calib: "SkinCalibration | Mapping[str, float] | None") -> "SkinModel":
        """This skin on the robot a calibration's kinematic corrections describe (itself when there are none)."""
        kin = calib.kinematics if isinstance(calib, SkinCalibration) else (calib or {})
        key = tuple(sorted((k, float(v)) for k, v in kin.items() if v != 0.0))
        if not key:
            return self
        if self._corrected[0] != key:
            self._corrected = (key, SkinModel(self.robot.corrected(dict(key)), self.parts, self.source,
                                              self.self_touch, self.fingertip_touch))
        return self._corrected[1]

    def zero_calibration(self) -> "SkinCalibration":
        return SkinCalibration({n: p.zero_correction() for n, p in self.parts.items()})

    def chain_poses(self, part: str, q: np.ndarray) -> np.ndarray:
        """Pose of the part's chain end in the base frame for N poses: (N, 4, 4)."""
        return self.robot.fk(self.part(part).chain, q)

    def taxels_in_base(self, part: str, q: np.ndarray, calib: "SkinCalibration | None" = None,
                       slots: np.ndarray | None = None) -> np.ndarray:
        """Calibrated taxel positions in the base frame.

        ``slots=None``: every slot, ``(N, S, 3)``; ``slots`` of shape ``(N, K)``:
        the given slot per pose, ``(N, K, 3)`` (one vectorised call, no loop over N).
        """
        p = self.part(part)
        corr = calib.parts[part] if calib is not None and part in calib.parts else None
        local, _ = p.taxel_positions(corr)
        chain = self.chain_poses(part, q)
        if slots is None:
            return se3.transform_points(chain[:, None], local[None])
        slots = np.asarray(slots)
        return se3.transform_points(chain[:, None], local[slots])


@dataclass
class SkinCalibration:
    """Corrections of every part; what calibration finds and the URDF consumes."""

    parts: dict = field(default_factory=dict)    # part name -> PartCorrection
    # corrections of the robot config (RobotModel.corrected): NAOqi joint name -> rad added to the
    # angle the joint reports, named link (e.g. LElbowOffsetY) -> m added to its DH parameter
    kinematics: dict = field(default_factory=dict)
    kinematics_std: dict = field(default_factory=dict)   # their standard deviations, from the normal equations
    # m: the pressed fabric over the taxels the calibration's touches implied (the engine's estimate), what
    # its closest pairs were measured at; None where nothing estimated it (nominal, older files)
    fabric_thickness: float | None = None
    # part -> {median, p95} (mm): its taxels' predicted RMS error, the linearised posterior at the estimate
    # (calibration/uncertainty.py); empty where nothing predicted it (nominal, older files)
    predicted_error_mm: dict = field(default_factory=dict)
    # fingertip (robot config) -> (4,) correction of its contact sphere: centre (m, in its chain's end frame)
    # and radius (m), added to the robot config's; a fingertip without touches has none
    fingertips: dict = field(default_factory=dict)
    fingertips_std: dict = field(default_factory=dict)   # (4,) standard deviations where estimated

    def copy(self) -> "SkinCalibration":
        return SkinCalibration({k: v.copy() for k, v in self.parts.items()}, dict(self.kinematics),
                               dict(self.kinematics_std), self.fabric_thickness,
                               {k: dict(v) for k, v in self.predicted_error_mm.items()},
                               {k: np.array(v, dtype=float) for k, v in self.fingertips.items()},
                               {k: np.array(v, dtype=float) for k, v in self.fingertips_std.items()})

    def fingertip_sphere(self, robot: RobotModel, name: str) -> tuple:
        """``(centre (3,), radius)`` of a fingertip's contact sphere under this calibration, in its chain's end
        frame."""
        tip = robot.fingertip(name)
        corr = self.fingertips.get(name)
        if corr is None:
            return tip.point.copy(), tip.radius
        return tip.point + corr[:3], tip.radius + float(corr[3])

    # ------------------------------------------------------------------ YAML
    def to_dict(self, skin: SkinModel) -> dict:
        def entry(f: SkinFrame) -> dict:
            # the rotation vector of norm <= pi: a fit may wind one past it (the same rotation), and load()
            # refuses what no rotation needs; a frame beyond MAX_OFFSET is a diverged fit, not a file to write
            vector = f.correction
            if np.all(np.isfinite(vector)):
                from scipy.spatial.transform import Rotation

                vector = np.concatenate([vector[:3], Rotation.from_rotvec(vector[3:]).as_rotvec()])
            if not _plausible_pose(vector):
                raise DataError(f"{f.frame}: correction {np.round(f.correction, 3).tolist()} is no skin frame's"
                                f" (non-finite, or translated beyond {MAX_OFFSET:g} m): the fit diverged;"
                                f" nothing written")
            return {
                "frame": f.frame, "parent": f.parent,
                "correction": {"translation": [_written(v) for v in vector[:3]],
                               "rotation_vector": [_written(v) for v in vector[3:]]},
                # calibrated pose relative to the parent frame, in URDF terms (for xacro)
                "origin": {"xyz": [_written(v) for v in f.pose[:3, 3]],
                           "rpy": [_written(v) for v in se3.rpy_from_matrix(f.pose[:3, :3])]},
            }

        # how many entries follow, ahead of them: a file cut short (a copy that stopped, a full disk
        # elsewhere) is refused by load() instead of read as a calibration with frames at nominal
        n_frames = sum(1 + len(part.patch_ids) + len(part.triangle_ids) for part in skin.parts.values())
        out = {"format": CALIBRATION_FORMAT, "robot": skin.robot.name, "base_frame": skin.robot.base_frame,
               "contents": {"frames": n_frames, **({"kinematics": len(self.kinematics)} if self.kinematics else {}),
                            **({"fingertips": len(self.fingertips)} if self.fingertips else {})}}
        if self.fabric_thickness is not None:   # ahead of the parts: a file cut short loses the frames first
            out["fabric_thickness"] = {"value": round(float(self.fabric_thickness), 9), "unit": "m"}
        out["parts"] = {}
        for name, part in skin.parts.items():
            mount, *others = part.frames(self.parts.get(name))
            out["parts"][name] = {
                "chain": part.chain,
                # the arm or head the frames hang off, as the robot config described it: load() refuses another
                **({"chain_sha256": skin.robot.chain_sha256(part.chain)} if part.chain else {}),
                # the layout the corrections belong to: load() refuses another one
                "layout": {"file": Path(part.layout_file).name, "sha256": part.layout_sha256},
                # absent where nothing predicted it: such files read as before
                **({"predicted_taxel_error_mm": {k: round(float(v), 4) for k, v in
                                                 self.predicted_error_mm[name].items()}}
                   if name in self.predicted_error_mm else {}),
                "mount": entry(mount),
                "patches": {f.number: entry(f) for f in others if f.kind == "patch"},
                "triangles": {f.number: entry(f) for f in others if f.kind == "triangle"},
            }
        if self.kinematics:   # absent without kinematic corrections: such files read as before
            out["kinematics"] = {
                name: {"correction": round(float(v), 10), "unit": "m" if name in skin.robot.links else "rad",
                       **({"std": round(float(self.kinematics_std[name]), 10)} if name in self.kinematics_std else {})}
                for name, v in self.kinematics.items()}
        if self.fingertips:   # absent without fingertip touches: such files read as before
            out["fingertips"] = {name: self._fingertip_entry(skin.robot, name) for name in self.fingertips}
        return out

    def _fingertip_entry(self, robot: RobotModel, name: str) -> dict:
        """A fingertip's entry of calibration.yaml: its correction, the contact sphere it gives (in the chain's end
        frame: what a user reads) and their std where estimated."""
        corr, std = self.fingertips[name], self.fingertips_std.get(name)
        centre, radius = self.fingertip_sphere(robot, name)
        return {"chain": robot.fingertip(name).chain,
                "correction": {"point": [_written(v) for v in corr[:3]], "radius": _written(corr[3])},
                "point": [_written(v) for v in centre], "radius": _written(radius),
                **({"std": {"point": [_written(v) for v in std[:3]], "radius": _written(std[3])}}
                   if std is not None else {})}

    def save(self, path: str | Path, skin: SkinModel, comment: str = "") -> None:
        header = (f"{CALIBRATION_HEADER}\n"
                  "# correction: translation (m) and rotation vector (rad) in the frame's own axes,\n"
                  "#   applied after the nominal pose from the layout; origin: resulting pose relative\n"
                  "#   to the parent frame (URDF xyz/rpy), read by urdf/nao_skin.urdf.xacro.\n"
                  "# contents: how many frames and kinematic corrections the file holds (checked on load).\n")
        if self.fabric_thickness is not None:
            header += ("# fabric_thickness: the pressed fabric over the taxels the touches implied (m); nao-skin\n"
                       "#   check judges new touches at it.\n")
        if self.predicted_error_mm:
            header += ("# predicted_taxel_error_mm: per part, the median and p95 over its taxels of the predicted RMS\n"
                       "#   error (mm), from the linearised posterior at the estimate (not measured).\n")
        if self.fingertips:
            header += ("# fingertips: per fingertip of the robot config, its contact sphere's centre (m, in its chain's\n"
                       "#   end frame) and radius (m): the correction added to the config's and the result.\n")
        if self.kinematics:
            header += ("# kinematics: corrections of the robot config, a joint's (rad) added to the angle it\n"
                       "#   reports, a link's (m) to its DH parameter; std from the normal equations.\n")
        if comment:
            header += "".join(f"# {line}\n" for line in comment.splitlines())
        Path(path).write_text(header + yaml.safe_dump(self.to_dict(skin), sort_keys=False, width=120))

    @classmethod
    def load(cls, path: str | Path, skin: SkinModel) -> "SkinCalibration":
        path = Path(path)
        doc = read_yaml(path, "calibration")
        if not isinstance(doc, dict) or not isinstance(doc.get("parts"), dict):
            raise ConfigError(f"{path}: a calibration needs a 'parts' mapping")
        if "format" not in doc and "self_touch" in doc:    # both have 'robot' and 'parts': say which it is
            raise ConfigError(f"{path}: is a skin config (it has 'self_touch:'), not a calibration")
        if doc.get("format", CALIBRATION_FORMAT) != CALIBRATION_FORMAT:     # older files have none
            raise ConfigError(f"{path}: format {doc['format']!r}, not {CALIBRATION_FORMAT}: another kind of file"
                              f" or a newer nao_skin's")
        if "robot" in doc and doc["robot"] != skin.robot.name:
            raise ConfigError(f"{path}: made for robot {doc['robot']!r}; the skin config's robot is"
                              f" {skin.robot.name!r} ({skin.robot.source}): give the robot config it was made"
                              f" with (--robot FILE, or a skin config whose 'robot:' names it)")
        if "base_frame" in doc and doc["base_frame"] != skin.robot.base_frame:
            raise ConfigError(f"{path}: its frames hang off base frame {doc['base_frame']!r}; the robot config's is"
                              f" {skin.robot.base_frame!r} ({skin.robot.source})")
        _check_contents(path, doc)     # first: a file cut short is said as such, not as its last entry broken
        calib = skin.zero_calibration()

        def vec(entry, where):
            try:
                c = entry["correction"]
                translation, rotation = list(c["translation"]), list(c["rotation_vector"])
                values = translation + rotation
                v = np.array(values, dtype=float)
            except (KeyError, TypeError):
                raise ConfigError(f"{path}: {where}: needs correction.translation and correction.rotation_vector") from None
            except (ValueError, OverflowError):     # not numbers ('0.1 m'), an integer beyond any float
                v = np.full(6, np.nan)
            # true is no 1 m, and "000" no three zeros
            if len(translation) != 3 or any(isinstance(x, (bool, str)) for x in values) or not _plausible_pose(v):
                raise ConfigError(f"{path}: {where}: correction must be 3 + 3 finite numbers, metres (at most"
                                  f" {MAX_OFFSET:g}) and radians (at most {MAX_ROTATION:g})")
            return v

        def entries(spec, key, where) -> dict:
            value = spec.get(key) or {}
            if not isinstance(value, dict):
                raise ConfigError(f"{path}: {where}: '{key}' must be a mapping")
            return value

        for name, spec in doc["parts"].items():
            if name not in skin.parts:
                raise ConfigError(f"{path}: unknown skin part '{name}' (configured: {', '.join(skin.parts)})")
            if not isinstance(spec, dict):
                raise ConfigError(f"{path}: part '{name}': expected a mapping (layout, mount, patches, triangles)")
            part = skin.parts[name]
            if "chain" in spec and spec["chain"] != part.chain:   # its frames would hang off another arm
                raise ConfigError(f"{path}: part '{name}' was calibrated on chain {spec['chain']!r}; the skin config"
                                  f" hangs it off {part.chain!r}")
            _check_chain(path, name, spec.get("chain_sha256"), part, skin.robot)
            _check_layout(path, name, spec.get("layout"), part)
            corr = calib.parts[name]
            if "predicted_taxel_error_mm" in spec:
                calib.predicted_error_mm[name] = _predicted_entry(path, name, spec["predicted_taxel_error_mm"])
            if "mount" in spec:
                corr.mount = vec(spec["mount"], f"part '{name}' mount")
            rows = {int(p): i for i, p in enumerate(part.patch_ids)}
            for pid, entry in _numbered(entries(spec, "patches", f"part '{name}'"), f"{path}: part '{name}' patch").items():
                if pid not in rows:
                    raise ConfigError(f"{path}: part '{name}' has no patch {pid}")
                corr.patches[rows[pid]] = vec(entry, f"part '{name}' patch {pid}")
            rows = {int(t): i for i, t in enumerate(part.triangle_ids)}
            for tid, entry in _numbered(entries(spec, "triangles", f"part '{name}'"),
                                        f"{path}: part '{name}' triangle").items():
                if tid not in rows:
                    raise ConfigError(f"{path}: part '{name}' has no triangle {tid}")
                corr.triangles[rows[tid]] = vec(entry, f"part '{name}' triangle {tid}")
        for name, entry in entries(doc, "kinematics", "calibration").items():
            if name not in skin.robot.links and name not in skin.robot.joint_index:
                raise ConfigError(f"{path}: kinematics: '{name}' is neither a joint nor a named link of"
                                  f" {skin.robot.name}")
            unit, limit = ("m", MAX_LINK_CORRECTION) if name in skin.robot.links else ("rad", MAX_JOINT_CORRECTION)
            try:
                if any(isinstance(entry.get(k), bool) for k in ("correction", "std")):
                    raise TypeError("true is no number")
                correction = float(entry["correction"])
                std = float(entry["std"]) if "std" in entry else None
            except (KeyError, TypeError, ValueError, OverflowError, AttributeError):
                correction = std = math.nan
            # a link length (m) or a joint offset (rad): beyond a few cm or tens of degrees is a broken file
            if not abs(correction) <= limit or not (std is None or 0 <= std < math.inf):
                raise ConfigError(f"{path}: kinematics: '{name}' needs a finite numeric correction (at most"
                                  f" {limit:g} {unit}) and, if given, a finite std >= 0")
            if entry.get("unit", unit) != unit:
                raise ConfigError(f"{path}: kinematics: '{name}' is in {unit}, not {entry.get('unit')!r}"
                                  f" (a {'link length' if unit == 'm' else 'joint offset'})")
            calib.kinematics[str(name)] = correction
            if std is not None:
                calib.kinematics_std[str(name)] = std
        for name, entry in entries(doc, "fingertips", "calibration").items():
            calib.fingertips[str(name)], std = _fingertip_entry(path, name, entry, skin.robot)
            if std is not None:
                calib.fingertips_std[str(name)] = std
        if "fabric_thickness" in doc:
            calib.fabric_thickness = _fabric_entry(path, doc["fabric_thickness"])
        check_origins(path, doc, calib, skin)
        return calib


MAX_FABRIC = 0.01          # m: the calibration options' own limit of a fabric thickness


def _fabric_entry(path: Path, entry) -> float:
    """The ``fabric_thickness`` of a calibration file: ``{value: m, unit: m}``, 0 to :data:`MAX_FABRIC`."""
    try:
        value = entry["value"]
        ok = (not isinstance(value, bool) and isinstance(value, (int, float)) and entry.get("unit", "m") == "m"
              and 0.0 <= float(value) <= MAX_FABRIC)
    except (TypeError, KeyError, AttributeError, OverflowError):
        ok = False
    if not ok:
        raise ConfigError(f"{path}: fabric_thickness must be {{value: metres from 0 to {MAX_FABRIC:g}, unit: m}}")
    return float(value)


def _predicted_entry(path: Path, name: str, entry) -> dict:
    """A part's ``predicted_taxel_error_mm`` in a calibration file: ``{median: mm, p95: mm}``, finite, >= 0."""
    try:
        values = {key: entry[key] for key in ("median", "p95")}
        ok = set(entry) == set(values) and all(not isinstance(v, bool) and isinstance(v, (int, float))
                                               and 0.0 <= float(v) < math.inf for v in values.values())
    except (TypeError, KeyError, AttributeError, OverflowError):
        ok = False
    if not ok:
        raise ConfigError(f"{path}: part '{name}': predicted_taxel_error_mm must be {{median: mm, p95: mm}}, finite"
                          f" numbers >= 0")
    return {key: float(v) for key, v in values.items()}


def _fingertip_entry(path: Path, name, entry, robot: RobotModel) -> tuple:
    """A fingertip of a calibration file: ``(correction (4,), std (4,) or None)``; its ``point`` and ``radius``
    must be what the correction gives (one of the two edited: nao-skin reads the correction)."""
    where = f"{path}: fingertips: '{name}'"
    if name not in robot.fingertips:
        raise ConfigError(f"{where}: not a fingertip of {robot.source} (fingertips:"
                          f" {', '.join(robot.fingertips) or 'none'})")

    def numbers(value, n):
        try:
            ok = (isinstance(value, list) and len(value) == n and not any(isinstance(v, (bool, str)) for v in value))
            out = np.array(value, dtype=float) if ok else None
        except (TypeError, ValueError, OverflowError):
            out = None
        return out if out is not None and np.all(np.isfinite(out)) else None

    try:
        corr = numbers([*entry["correction"]["point"], entry["correction"]["radius"]], 4)
        std = numbers([*entry["std"]["point"], entry["std"]["radius"]], 4) if "std" in entry else None
    except (KeyError, TypeError, AttributeError):
        corr = std = None
    if corr is None or np.abs(corr).max() > MAX_LINK_CORRECTION or ("std" in entry and std is None):
        raise ConfigError(f"{where}: needs correction: {{point: [x, y, z], radius: r}}, finite metres (at most"
                          f" {MAX_LINK_CORRECTION:g}), and, if given, std of the same shape")
    tip = robot.fingertips[name]
    given = numbers([*entry.get("point", tip.point + corr[:3]), entry.get("radius", tip.radius + corr[3])], 4)
    if given is None or np.abs(given - np.append(tip.point + corr[:3], tip.radius + corr[3])).max() > ORIGIN_TOLERANCE:
        raise ConfigError(f"{where}: point/radius are not what the correction gives the robot config's fingertip:"
                          f" one of the two was edited (nao-skin reads the correction); make them agree")
    return corr, std


ORIGIN_TOLERANCE = 1e-8   # m and rad; files hold origins rounded to 1e-10


def check_origins(path: Path, doc: dict, calib: "SkinCalibration", skin: SkinModel, complete: bool = False) -> None:
    """Each frame's URDF ``origin`` (xyz/rpy) in a calibration file ``doc`` is the pose its correction gives.

    The xacro, robot_state_publisher and every consumer of ``/tf`` read ``origin``; the Python model reads
    ``correction``: a hand-edited origin would make the two disagree without a word. An entry without an
    origin is a hand-written correction and taken as it is, unless ``complete`` (a URDF needs every frame).
    Raises :class:`ConfigError` naming the file and the frame.
    """
    expected = calib.to_dict(skin)
    for name, part in expected["parts"].items():
        given = doc["parts"].get(name)
        if not isinstance(given, dict):
            if complete:
                raise ConfigError(f"{path}: no entry for skin part '{name}' (the URDF would lack its frames)")
            continue
        entries = [("mount", part["mount"], given.get("mount"))]
        for kind, key in (("patch", "patches"), ("triangle", "triangles")):
            have = {int(k): v for k, v in (given.get(key) or {}).items()}
            entries += [(f"{kind} {i}", e, have.get(int(i))) for i, e in part[key].items()]
        for label, want, have in entries:
            where = f"{path}: part '{name}' {label}"
            if not complete and not (isinstance(have, dict) and "origin" in have):
                continue
            if not isinstance(have, dict):
                raise ConfigError(f"{where}: missing (the URDF would lack frame '{want['frame']}')")
            if have.get("frame") != want["frame"] or have.get("parent") != want["parent"]:
                raise ConfigError(f"{where}: frame/parent {have.get('frame')!r}/{have.get('parent')!r},"
                                  f" expected {want['frame']!r}/{want['parent']!r}")
            try:
                xyz = np.array(have["origin"]["xyz"], dtype=float)
                rpy = np.array(have["origin"]["rpy"], dtype=float)
            except (KeyError, TypeError, ValueError, OverflowError):
                raise ConfigError(f"{where}: needs origin.xyz and origin.rpy (3 numbers each)") from None
            if xyz.shape != (3,) or rpy.shape != (3,):
                raise ConfigError(f"{where}: needs origin.xyz and origin.rpy (3 numbers each)")
            if not (np.all(np.isfinite(xyz)) and np.all(np.isfinite(rpy))):
                raise ConfigError(f"{where}: origin.xyz and origin.rpy must be finite numbers (the URDF and /tf read"
                                  f" them), not {xyz.tolist()} / {rpy.tolist()}")
            d_t = np.abs(xyz - np.array(want["origin"]["xyz"])).max()
            rel = se3.matrix_from_rpy(rpy).T @ se3.matrix_from_rpy(np.array(want["origin"]["rpy"]))
            d_r = float(np.linalg.norm(se3.matrix_to_rotvec(rel)))
            if not (d_t <= ORIGIN_TOLERANCE and d_r <= ORIGIN_TOLERANCE):
                raise ConfigError(f"{where}: origin is {d_t:.3g} m / {d_r:.3g} rad off the pose its"
                                  f" correction gives: one of the two was edited (nao-skin reads the correction,"
                                  f" the URDF and /tf the origin); make them agree")


CALIBRATION_HEADER = "# nao_skin calibration: pose corrections of skin mount, patch and triangle frames."


def _check_contents(path: Path, doc: dict) -> None:
    """The entries read against the ``contents`` the file announces ahead of them (files without it, older
    or written by hand, are taken as they are)."""
    if "contents" not in doc:
        return
    said = doc["contents"]
    if isinstance(said, dict):
        said = {"kinematics": 0, "fingertips": 0, **said}    # without such corrections the counts are left out
    if not (isinstance(said, dict) and set(said) == {"frames", "kinematics", "fingertips"}
            and all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in said.values())):
        raise ConfigError(f"{path}: contents must be a mapping of frames and (optional) kinematics and fingertips, each"
                          f" a whole number >= 0")
    frames = 0
    for spec in doc["parts"].values():
        if isinstance(spec, dict):       # anything else is said by load(), naming the part
            frames += ("mount" in spec) + sum(len(spec[key]) for key in ("patches", "triangles")
                                              if isinstance(spec.get(key), dict))
    kinematics = len(doc["kinematics"]) if isinstance(doc.get("kinematics"), dict) else 0
    fingertips = len(doc["fingertips"]) if isinstance(doc.get("fingertips"), dict) else 0
    if (frames, kinematics, fingertips) != (said["frames"], said["kinematics"], said["fingertips"]):
        holds, says = f"{frames} frames and {kinematics}", f"{said['frames']} and {said['kinematics']}"
        if fingertips or said["fingertips"]:
            holds, says = (f"{frames} frames, {kinematics} kinematic corrections and {fingertips} fingertips",
                           f"{said['frames']}, {said['kinematics']} and {said['fingertips']}")
        else:
            holds += " kinematic corrections"
        raise ConfigError(f"{path}: holds {holds} where its contents line says {says}: the file was cut short or"
                          f" edited;"
                          f" restore it, or after a deliberate edit correct that line")


def skin_frame_transforms(skin: SkinModel, calib: SkinCalibration) -> list:
    """``[(parent, child, 4x4)]`` of every skin frame of every part: the poses calibration.yaml and the URDF hold."""
    return [(f.parent, f.frame, f.pose)
            for name, part in skin.parts.items() for f in part.frames(calib.parts.get(name))]


def _check_chain(path: Path, name: str, recorded, part: SkinPart, robot: RobotModel) -> None:
    """A calibration applies only to the chain description it was made on: the same config name with other DH
    rows would put every frame elsewhere without a word (older files, without a record, pass)."""
    if recorded is None or part.chain is None:
        return
    here = robot.chain_sha256(part.chain)
    if str(recorded) != here:
        raise ConfigError(f"{path}: part '{name}' was calibrated on another description of chain {part.chain!r}"
                          f" (sha256 {str(recorded)[:12]}) than the robot config's {robot.source} (sha256"
                          f" {here[:12]}): its DH rows, joints or frames differ; give the robot config the"
                          f" calibration was made with")


def _check_layout(path: Path, name: str, recorded, part: SkinPart) -> None:
    """A calibration applies only to the layout it was made with (older files, without a record, pass)."""
    if recorded is None:
        return
    if not isinstance(recorded, dict) or not isinstance(recorded.get("sha256"), str):
        raise ConfigError(f"{path}: part '{name}': 'layout' must be a mapping with 'file' and 'sha256' (the taxel"
                          f" file the part was calibrated on), got {recorded!r}")
    if str(recorded["sha256"]) != part.layout_sha256:
        raise ConfigError(f"{path}: part '{name}' was calibrated on the layout {recorded.get('file', '?')}"
                          f" (sha256 {str(recorded['sha256'])[:12]}), not on {Path(part.layout_file).name}"
                          f" (sha256 {part.layout_sha256[:12]}) used here; give the same layout"
                          f" ({taxels_said(name)})")


def part_from_layout(name: str, chain: str | None, robot: RobotModel, taxel_file: str | Path,
                     layout: TaxelFile | None = None) -> SkinPart:
    """A part built from a taxel file alone (patches: 16 triangles each, the Nao convention); ``layout``: the
    file's contents, when already read."""
    layout = read_taxel_file(taxel_file) if layout is None else layout
    return build_part(name, chain, robot.end_frame(chain), layout, None, str(taxel_file), layout_file=str(taxel_file))


def _covers(patch_table: Mapping[int, list], layout: TaxelFile) -> bool:
    """Whether ``patch_table`` places every triangle with a taxel in ``layout``, and only triangles it has slots for."""
    n_tri = len(layout.positions) // SLOTS_PER_TRIANGLE
    listed = {t for tris in patch_table.values() for t in tris}
    used = set((np.flatnonzero(layout.present) // SLOTS_PER_TRIANGLE).tolist())
    return used <= listed and all(isinstance(t, int) and 0 <= t < n_tri for t in listed)


def _self_touch(spec, parts: Mapping, where: str) -> SelfTouch:
    """A skin config's ``self_touch``: ``{touching: [parts], touched: [parts]}``, parts of that config."""
    if not isinstance(spec, dict) or set(spec) != {"touching", "touched"}:
        raise ConfigError(f"{where}: expected {{touching: [parts], touched: [parts]}}, e.g. touching: [r_hand,"
                          f" l_hand] and touched: [torso, head]")
    roles = {}
    for role in ("touching", "touched"):
        names = spec[role]
        if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
            raise ConfigError(f"{where}: {role} must be a non-empty list of part names, got {names!r}")
        unknown = [n for n in names if n not in parts]
        if unknown:
            raise ConfigError(f"{where}: {role}: {', '.join(unknown)} {'is' if len(unknown) == 1 else 'are'} not"
                              f" a part of this config (its parts: {', '.join(parts)})")
        if len(set(names)) < len(names):
            raise ConfigError(f"{where}: {role}: a part is listed twice, got {names}")
        roles[role] = tuple(names)
    both = set(roles["touching"]) & set(roles["touched"])
    if both:
        raise ConfigError(f"{where}: {', '.join(sorted(both))} both touching and touched")
    return SelfTouch(**roles)


def _fingertip_touch(spec, parts: Mapping, robot: RobotModel, where: str) -> FingertipTouch:
    """A skin config's ``fingertip_touch``: ``{touching: [fingertips of the robot config], touched: [parts]}``."""
    if not isinstance(spec, dict) or set(spec) != {"touching", "touched"}:
        raise ConfigError(f"{where}: expected {{touching: [fingertips], touched: [parts]}}, e.g. touching: [r_finger]"
                          f" and touched: [torso, head, l_hand]")
    for role, known, what in (("touching", robot.fingertips, f"a fingertip of {robot.source}"),
                              ("touched", parts, "a part of this config")):
        names = spec[role]
        if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
            raise ConfigError(f"{where}: {role} must be a non-empty list of names, got {names!r}")
        unknown = [n for n in names if n not in known]
        if unknown:
            raise ConfigError(f"{where}: {role}: {', '.join(unknown)} {'is' if len(unknown) == 1 else 'are'} not"
                              f" {what} (known: {', '.join(known) or 'none'})")
        if len(set(names)) < len(names):
            raise ConfigError(f"{where}: {role}: a name is listed twice, got {names}")
    same_arm = frozenset((f, p) for f in spec["touching"] for p in spec["touched"]
                         if parts[p].chain == robot.fingertips[f].chain)
    return FingertipTouch(tuple(spec["touching"]), tuple(spec["touched"]), same_arm)


def parse_pairs(items, parts=None, where: str = "pair", fingertips=()) -> tuple:
    """``'hand-part'`` strings (e.g. ``'l_hand-torso'``, or ``'r_finger-torso'`` with a fingertip of ``fingertips``
    pressing) as ``(hand, part)`` tuples; empty strings are skipped.

    ``parts``: the skin parts both sides must name (the first may be one of ``fingertips``; None: not checked here).
    """
    out = []
    for item in items:
        item = str(item).strip()
        if not item:
            continue
        hand, sep, part = item.partition("-")
        if not sep or not hand or not part or hand == part or (
                parts is not None and not (part in parts and (hand in parts or hand in fingertips))):
            of = f" of two skin parts ({', '.join(parts)})" if parts is not None else " of two skin parts"
            tips = f" or a fingertip ({', '.join(fingertips)}) and a part, e.g. {next(iter(fingertips))}-torso" \
                if fingertips else ""
            raise ConfigError(f"{where} {item!r}: expected HAND-PART{of}, e.g. l_hand-torso{tips}")
        if (hand, part) in out:
            raise ConfigError(f"{where} {item!r} is given twice")
        out.append((hand, part))
    return tuple(out)


def taxels_said(part: str = "PART") -> str:
    """How a user names a part's own taxel file, whichever way they work (the core cannot know)."""
    return f"--taxels {part}=FILE (ros2 launch: taxels:={part}=FILE)"


def parse_taxel_files(items, where: str = "--taxels") -> dict:
    """``PART=FILE`` strings (``--taxels``, a node's ``taxels`` parameter) as ``{part: Path}``; empty items skipped."""
    files = {}
    for item in items:
        if not item:
            continue
        part, sep, path = item.partition("=")
        if not sep or not part or not path:
            raise ConfigError(f"{where} {item!r}: expected PART=FILE, e.g. l_hand=l_hand.taxels.txt")
        if part in files:
            raise ConfigError(f"{where} {item!r}: part '{part}' is given twice")
        if Path(path).is_dir():
            raise ConfigError(f"{where} {item!r}: {path} is a directory, not a taxel file")
        if not Path(path).is_file():
            what = ("not a regular file" if Path(path).exists()     # /dev/zero, a FIFO
                    else DANGLING_LINK if Path(path).is_symlink()
                    else "no such file")
            raise ConfigError(f"{where} {item!r}: {path}: {what}")
        files[part] = Path(path)
    return files


def load_skin(skin_config: str | Path | None = None, taxel_files: Mapping[str, str | Path] | None = None,
              robot_config: str | Path | None = None, where: str = "--taxels") -> SkinModel:
    """The skin every command uses: the skin config, with the named parts' layouts from their own files.

    A part named in ``taxel_files`` (one the config has) keeps its chain from
    the config and takes its layout from the file, e.g. a
    recording's own, grouped by the config's patch table (and placed by its
    nominal mount) where that table places every triangle of the file, else 16
    triangles per patch; every other part stays as configured. ``where``: how the user named the files
    (``--taxels``, a node's ``parameter taxels``), for the one line that refuses them.
    """
    from nao_skin.paths import default_skin_config

    robot = RobotModel.from_yaml(robot_config) if robot_config else None
    skin = SkinModel.from_yaml(skin_config or default_skin_config(), robot)
    parts = dict(skin.parts)
    for name, path in (taxel_files or {}).items():
        if name not in parts:
            raise ConfigError(f"{where} {name}={path}: unknown skin part '{name}' (configured in {skin.source}:"
                              f" {', '.join(parts)})")
        chain = parts[name].chain
        was = skin.parts.get(name)
        layout = read_taxel_file(path)
        if was is not None and was.patch_table is not None and _covers(was.patch_table, layout):
            # the config's own patch table (and nominal mount), where it places every triangle of the new
            # layout: the same layout given again must not be regrouped by the convention
            parts[name] = build_part(name, chain, skin.robot.end_frame(chain), layout, was.patch_table,
                                     f"{skin.source} with --taxels {name}={path}", was.mount_given, str(path))
        else:
            parts[name] = part_from_layout(name, chain, skin.robot, path, layout)
    if not taxel_files:
        return skin
    return SkinModel(skin.robot, parts, f"{skin.source} + " + ", ".join(str(p) for p in taxel_files.values()),
                     skin.self_touch, skin.fingertip_touch)
