"""Parameters of the self-touch simulator, as data: defaults, presets, validation.

``config/simulation.yaml`` holds a ``defaults:`` mapping (the value of every field of
:class:`SimParams`, defined there only) and ``presets:`` that override a few fields each. Lengths
are metres, angles radians unless the field name says ``_deg``.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Mapping

from nao_skin.errors import ConfigError
from nao_skin.rules import known_keys
from nao_skin.touch import DEFAULT_MAX_NEIGHBOR_DIST

if TYPE_CHECKING:    # the skin model (numpy) is imported where a simulation runs, not for the help's preset list
    from nao_skin.model.skin import SkinModel


@dataclass(kw_only=True)
class SimParams:
    """Every parameter of one simulation. The values live in one place, the ``defaults:`` of
    ``config/simulation.yaml`` (:func:`make_params` fills from there what a caller leaves out), except
    the contact distance, which is skinManager's own default."""

    # ------------------------------------------------------------ scene
    pairs: list                           # [hand, touched part]: the hand is pressed on the part
    n_touches: int                        # accepted touches per pair
    start_stamp: float                    # first touch stamp (s); fixed so outputs are reproducible
    touch_interval: list                  # s between touches, uniform
    # ------------------------------------------------------------ true skin placement (ground truth)
    hand_mount_rotation_deg: float        # about the forearm axis (real hands: ~160 deg off the CAD)
    hand_mount_axis_tilt_deg: float       # tilt of that rotation axis away from the forearm axis
    hand_mount_shift: float               # along the forearm axis (m), random sign
    hand_mount_radial: float              # across the forearm axis (m), random direction
    hand_mount_offset: list               # fixed extra shift, mount axes (m)
    body_mount_translation: float         # torso / head mount (m)
    body_mount_rotation: float            # torso / head mount (rad, ~2 deg)
    patch_translation: float              # per patch (m)
    patch_rotation: float                 # per patch (rad, ~3 deg)
    triangle_translation: float           # per triangle (m)
    triangle_rotation: float              # per triangle (rad)
    # ------------------------------------------------------------ true robot (ground truth): how its kinematics
    # differ from the robot config the recording is read with; it poses and fires, the joints record as before
    joint_offset_deg: float               # each arm and head joint truly sits off by up to this, uniform, random sign
    link_errors: dict                     # named link (robot config `links`) -> m added to its length
    # ------------------------------------------------------------ pose search
    pose_restarts: int                    # random starts per target spot
    pose_iterations: int                  # Levenberg-Marquardt iterations
    pose_tolerance: float                 # accepted spot-to-spot position error (m)
    normal_tolerance_deg: float           # accepted deviation from opposed normals
    penetration_tolerance: float          # how far another hand taxel may sit behind the target surface (m)
    spot_radius: float                    # chosen contact spot: random point this close to a triangle centre (m)
    planar_band: float                    # > 0: contact spots only in a band this wide (m) -> poses in a plane
    # ------------------------------------------------------------ contact and activation
    fabric_thickness: float               # fabric over the taxels, each side (m): taxels never coincide
    footprint_radius: list                # pressure spots spread (m)
    pressure_spots: list                  # spots per touch (inclusive)
    spot_size: list                       # radius of one spot (m)
    press_reach: list                     # fires up to this beyond the gap (m)
    # ------------------------------------------------------------ fingertip touches (pairs [fingertip, part])
    fingertip_offset: float               # the true fingertip's sphere centre off the config's, up to this per axis (m)
    fingertip_radius_error: float         # its radius off the config's (m)
    fingertip_footprint: list             # a fingertip's pressure spots spread (m)
    fingertip_spots: list                 # its spots per touch (inclusive)
    fingertip_spot_size: list             # radius of one of its spots (m)
    cluster_distance: float = DEFAULT_MAX_NEIGHBOR_DIST   # taxels closer than this form one contact
    # ------------------------------------------------------------ noise and defects (scaled by noise_scale)
    noise_scale: float                    # multiplies every noise and defect rate below
    joint_noise: float                    # encoder + backlash while the arm is held (rad, std)
    fabric_jitter: float                  # fabric thickness variation (m, std)
    missed_taxel: float                   # probability a firing taxel is not reported
    spurious_taxel: float                 # probability per touch of one stray taxel activation
    duplicate: float                      # probability a touch is recorded twice
    experimenter_hand: float              # hand touches where the experimenter also presses the robot's hand
    non_self_contact: float               # touches whose activations no self-contact explains

    # ------------------------------------------------------------------ derived
    def scaled(self, name: str) -> float:
        """A noise/defect field times ``noise_scale`` (probabilities capped at 1)."""
        value = getattr(self, name) * self.noise_scale
        return min(value, 1.0) if name in PROBABILITIES else value

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def record(self, fingertips: bool = False) -> dict:
        """The fields a recording's simulation.yaml lists: the true robot's only when it is not the config's, the
        fingertips' only when a fingertip pressed (``fingertips``), so other recordings read as they did before
        those fields existed."""
        out = self.to_dict()
        for name in TRUE_ROBOT:
            if not out[name]:
                del out[name]
        for name in () if fingertips else FINGERTIP_FIELDS:
            del out[name]
        return out


NOISES = ("joint_noise", "fabric_jitter", "missed_taxel", "spurious_taxel", "duplicate",
          "experimenter_hand", "non_self_contact")
TRUE_ROBOT = ("joint_offset_deg", "link_errors")
FINGERTIP_FIELDS = ("fingertip_offset", "fingertip_radius_error", "fingertip_footprint", "fingertip_spots",
                    "fingertip_spot_size")
PROBABILITIES = ("missed_taxel", "spurious_taxel", "duplicate", "experimenter_hand", "non_self_contact")
_NON_NEGATIVE = NOISES + ("noise_scale", "hand_mount_rotation_deg", "hand_mount_axis_tilt_deg",
                          "hand_mount_shift", "hand_mount_radial", "body_mount_translation",
                          "body_mount_rotation", "patch_translation", "patch_rotation",
                          "triangle_translation", "triangle_rotation", "fabric_thickness", "planar_band",
                          "joint_offset_deg", "fingertip_offset")
_POSITIVE = ("pose_tolerance", "normal_tolerance_deg", "penetration_tolerance", "spot_radius",
             "cluster_distance")
MAX_METRES = 10.0          # a Nao is half a metre tall
MIN_TOUCH_INTERVAL = 0.001     # s: touches closer than a millisecond would share a stamp's nanoseconds
MAX_CLUSTER_DISTANCE = 0.5     # m: beyond, every taxel of a part is one contact (clusters lie 1000 m apart)
MAX_JOINT_OFFSET_DEG = 20.0    # the truth file of a larger one would be refused by every command
MAX_NUMBER = 1e6
# the bundled recording has 1000 per pair; the poses of 10**12 would ask for terabytes before the first one
POSE_SEARCH_LIMITS = {"pose_restarts": 1000, "pose_iterations": 10_000}
# seconds: 2033, leaving a recording of years before the int32 seconds of a ROS header end (2038)
MAX_START_STAMP = 2.0e9
MAX_TOUCHES_PER_PAIR = 100_000
_RANGES = ("touch_interval", "footprint_radius", "pressure_spots", "spot_size", "press_reach", "fingertip_footprint",
           "fingertip_spots", "fingertip_spot_size")


PARAMS_FILE_KEYS = ("defaults", "presets")


def default_params_file() -> Path:
    from nao_skin.paths import config_dir

    return config_dir() / "simulation.yaml"


def _read_doc(path: Path) -> dict:
    from nao_skin.paths import read_yaml

    doc = read_yaml(path, "simulation parameters")
    if not isinstance(doc, dict) or not all(isinstance(doc.get(key) or {}, dict) for key in PARAMS_FILE_KEYS) \
            or not set(doc) & set(PARAMS_FILE_KEYS):
        raise ConfigError(f"{path}: expected 'defaults:' and 'presets:' mappings")
    # another config given here (a robot's: 'joints', 'chains') simulated with the built-in defaults
    known_keys(doc, PARAMS_FILE_KEYS, str(path))
    presets = {}
    for name, fields in (doc.get("presets") or {}).items():   # named on the command line: by their text
        if str(name) in presets:
            raise ConfigError(f"{path}: preset '{name}' is given twice")
        presets[str(name)] = fields
    doc = dict(doc, presets=presets)
    for name, fields in presets.items():
        if not isinstance(fields or {}, dict):
            raise ConfigError(f"{path}: preset '{name}': expected a mapping of parameter: value")
        if name == "default":    # the preset 'default' is the file's defaults: this one would never be read
            raise ConfigError(f"{path}: preset 'default': the defaults are 'defaults:'; put its fields there")
        # a misspelt field of any preset is said whichever preset runs, not only when that one does
        _check_fields(fields or {}, f"{path}: preset '{name}'")
    _check_fields(doc.get("defaults") or {}, f"{path}: defaults")
    return doc


def _check_fields(values: Mapping, where: str) -> None:
    unknown = sorted(map(str, set(values) - {f.name for f in dataclasses.fields(SimParams)}))
    if unknown:
        raise ConfigError(f"{where}: unknown field(s) {', '.join(unknown)}")


def preset_names(path: str | Path | None = None) -> list:
    doc = _read_doc(Path(path) if path else default_params_file())
    return ["default", *(doc.get("presets") or {})]     # a preset named 'default' is refused on reading


def load_params(preset: str = "default", overrides: Mapping | None = None,
                path: str | Path | None = None) -> SimParams:
    """The file's defaults, then the preset's fields, then ``overrides``; validated (what the file leaves
    out, the bundled file's defaults give: :func:`make_params`)."""
    path = Path(path) if path else default_params_file()
    doc = _read_doc(path)
    presets = doc.get("presets") or {}
    values = dict(doc.get("defaults") or {})
    if preset != "default":
        if preset not in presets:
            raise ConfigError(f"{path}: unknown preset '{preset}' (known: {', '.join(map(str, ['default', *presets]))})")
        values.update(presets[preset] or {})
    values.update(overrides or {})
    return make_params(values, where=f"{path}: preset '{preset}'")


def make_params(values: Mapping | SimParams, where: str = "simulation parameters") -> SimParams:
    """A validated :class:`SimParams`: the bundled ``config/simulation.yaml`` defaults, then ``values``
    (a mapping of field overrides, or a SimParams)."""
    if isinstance(values, SimParams):
        values = values.to_dict()
    fields = dataclasses.fields(SimParams)
    _check_fields(values, where)
    bundled = default_params_file()
    values = {**(_read_doc(bundled).get("defaults") or {}), **values}
    missing = [f.name for f in fields if f.name not in values and f.default is dataclasses.MISSING]
    if missing:
        raise ConfigError(f"{bundled}: 'defaults' lacks {', '.join(missing)} (every simulation parameter has its"
                          f" value there)")
    params = SimParams(**values)
    validate(params, where)
    return params


def _metres(value) -> bool:
    """A finite length within MAX_METRES: far beyond, forward kinematics overflows (warnings on stderr)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and abs(value) <= MAX_METRES


def validate(p: SimParams, where: str = "simulation parameters") -> None:
    from nao_skin.model.skin import MAX_JOINT_CORRECTION, MAX_LINK_CORRECTION

    def number(name):
        v = getattr(p, name)
        # far beyond any size or noise of the simulator, products overflow (warnings on stderr, then NaN)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not abs(v) <= MAX_NUMBER:
            raise ConfigError(f"{where}: '{name}' must be a finite number of at most {MAX_NUMBER:g}, got {v!r}")
        return float(v)

    for name in _NON_NEGATIVE:
        if number(name) < 0:
            raise ConfigError(f"{where}: '{name}' must not be negative, got {getattr(p, name)}")
    for name in _POSITIVE:
        if number(name) <= 0:
            raise ConfigError(f"{where}: '{name}' must be positive, got {getattr(p, name)}")
    for name in PROBABILITIES:
        if number(name) > 1:
            raise ConfigError(f"{where}: '{name}' is a probability, got {getattr(p, name)} > 1")
    for name in _RANGES:
        v = getattr(p, name)
        if (not isinstance(v, (list, tuple)) or len(v) != 2
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
                or not 0 <= v[0] <= v[1]):
            raise ConfigError(f"{where}: '{name}' must be [low, high] with 0 <= low <= high, got {v!r}")
    # what the readers and the calibration file take: a recording its own tools refuse or merge is no recording
    if p.touch_interval[0] < MIN_TOUCH_INTERVAL:    # two touches at one stamp are one touch in a bag
        raise ConfigError(f"{where}: 'touch_interval' must start at {MIN_TOUCH_INTERVAL} s or more, got"
                          f" {p.touch_interval!r}")
    if p.cluster_distance > MAX_CLUSTER_DISTANCE:
        raise ConfigError(f"{where}: 'cluster_distance' {p.cluster_distance} m is beyond {MAX_CLUSTER_DISTANCE} m"
                          f" (a neighbourhood of taxels, skinManager's maxNeighborDist: about 0.012 m)")
    for name in ("body_mount_rotation", "patch_rotation", "triangle_rotation"):
        if number(name) > math.pi:
            raise ConfigError(f"{where}: '{name}' {getattr(p, name)} rad is more than half a turn")
    if number("joint_offset_deg") > MAX_JOINT_OFFSET_DEG:
        raise ConfigError(f"{where}: 'joint_offset_deg' {p.joint_offset_deg} is more than {MAX_JOINT_OFFSET_DEG} deg"
                          f" (a calibration file takes joint offsets up to {math.degrees(MAX_JOINT_CORRECTION):.1f})")
    if p.press_reach[0] <= 0:      # a taxel's depth is its slack over the reach: 0 divides by it
        raise ConfigError(f"{where}: 'press_reach' must start above 0 m (a compliant fabric), got {p.press_reach!r}")
    if p.pressure_spots[0] < 1:
        raise ConfigError(f"{where}: 'pressure_spots' must start at 1 or more, got {p.pressure_spots!r}")
    for name in ("n_touches", "pose_restarts", "pose_iterations"):
        v = getattr(p, name)
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ConfigError(f"{where}: '{name}' must be a whole number >= 1, got {v!r}")
    for name, most in POSE_SEARCH_LIMITS.items():     # beyond, the batched pose search asks for gigabytes
        if getattr(p, name) > most:
            raise ConfigError(f"{where}: '{name}' {getattr(p, name)} is more than {most}")
    # a stamp is seconds since 1970 as rosbag2 stores it (unsigned nanoseconds in 64 bits)
    stamp = p.start_stamp
    if isinstance(stamp, bool) or not isinstance(stamp, (int, float)) or not 0 <= stamp <= MAX_START_STAMP:
        raise ConfigError(f"{where}: 'start_stamp' must be seconds since 1970 from 0 to {MAX_START_STAMP:.0f},"
                          f" got {p.start_stamp!r}")
    if p.n_touches > MAX_TOUCHES_PER_PAIR:
        raise ConfigError(f"{where}: 'n_touches' {p.n_touches} is more than {MAX_TOUCHES_PER_PAIR} touches per pair")
    off = p.hand_mount_offset
    if not isinstance(off, (list, tuple)) or len(off) != 3 or not all(_metres(x) for x in off):
        raise ConfigError(f"{where}: 'hand_mount_offset' must be [x, y, z] metres, got {off!r}")
    if not isinstance(p.link_errors, dict) or not all(_metres(v) for v in p.link_errors.values()):
        raise ConfigError(f"{where}: 'link_errors' must map link names to metres, got {p.link_errors!r}")
    if any(abs(v) > MAX_LINK_CORRECTION for v in p.link_errors.values()):
        raise ConfigError(f"{where}: 'link_errors' beyond {MAX_LINK_CORRECTION} m (a calibration file takes link"
                          f" corrections up to that), got {p.link_errors!r}")
    if not isinstance(p.pairs, (list, tuple)) or not p.pairs:
        raise ConfigError(f"{where}: 'pairs' must be a non-empty list of [hand, part] pairs")
    seen = set()
    for pair in p.pairs:
        if _as_pair(pair) is None:
            raise ConfigError(f"{where}: pair {pair!r} must be two skin part names, e.g. [l_hand, torso], or a"
                              f" fingertip and a part, e.g. [r_finger, torso]")
        hand, target = _as_pair(pair)     # which parts can touch is the skin config's (simulate checks)
        if (hand, target) in seen:
            raise ConfigError(f"{where}: pair {hand}-{target} is listed twice")
        seen.add((hand, target))


def check_pairs(pairs, skin: SkinModel, where: str | None = None) -> None:
    """Each ``(hand, target)`` of ``pairs`` two parts of ``skin``, a touching part pressed on a touched
    one of its config's ``self_touch``, or a fingertip of its robot pressed on a part of its ``fingertip_touch``
    (what this simulator models); ``where``: the parameters' source."""
    roles = skin.self_touch
    at = f"{where}: " if where else ""
    for hand, target in pairs:
        if hand in skin.robot.fingertips:
            if (hand, target) not in skin.fingertip_touch.pairs():
                pressed = [p for f, p in skin.fingertip_touch.pairs() if f == hand]
                raise ConfigError(f"{at}the simulator cannot make {hand}-{target} touch: the skin config's"
                                  f" fingertip_touch has fingertip {hand} press {', '.join(pressed) or 'no part'}"
                                  f" ({skin.source})")
            continue
        for part in (hand, target):
            if part not in skin.parts:
                raise ConfigError(f"{at}simulation pair {hand}-{target}: skin part '{part}' is not in {skin.source}"
                                  f" (configured: {', '.join(skin.parts)})")
        if hand not in roles.touching or target not in roles.touched:
            raise ConfigError(f"{at}the simulator cannot make {hand}-{target} touch (it presses a touching part,"
                              f" {' or '.join(roles.touching)}, on a touched one, {' or '.join(roles.touched)}:"
                              f" the skin config's self_touch)")


def pair_list(p: SimParams) -> list:
    """Pairs as ``(hand, target)`` tuples (checked parameters: each a pair)."""
    return [_as_pair(pair) for pair in p.pairs]


def _as_pair(pair) -> tuple | None:
    """``(hand, target)`` of a ``pairs`` entry, ``[l_hand, torso]`` or ``"l_hand-torso"``; None when it is
    neither."""
    if isinstance(pair, str):
        pair = pair.replace("-", " ").split()
    if isinstance(pair, (list, tuple)) and len(pair) == 2 and all(isinstance(x, str) for x in pair):
        return tuple(pair)
    return None
