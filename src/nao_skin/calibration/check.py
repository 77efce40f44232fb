"""Does a calibration still fit the skin? A new recording judged against it, part by part.

Skin glued by hand creeps, and a patch pressed back on after a fall sits elsewhere. A calibration made
months ago says nothing of that; a few minutes of new touches do. :func:`check_calibration` fits the
mounts of every part the new touches reach, starting from the calibration (the mount level only: a
check needs what moved, not a finer calibration from a few touches), and judges each part by two
figures: how far the refit carries its taxels from where the calibration puts them, and whether the
refit brings the held-out touches of that part's pairs closer than the calibration does. A part has
moved when both say so: its taxels go at least ``tolerance_mm`` (median) and its held-out closest COP
pairs come at least ``MIN_GAIN`` closer at 95 % confidence. Either alone is not enough: a refit from a
hundred touches wanders up to about a millimetre where nothing moved, and on one pair of parts (the
real recording) several millimetres along what one pair cannot tell apart; a held-out gain of a few
per cent is no reason to recalibrate (docs/method.md, "Has the skin moved?").

Both calibrations are measured at the fabric surfaces of the fabric thickness the calibration was made with
(its file's ``fabric_thickness``, the engine's estimate; the mount stages do not estimate it). Judged at
another fabric, the mounts of a calibration that fits move by about the difference along the normals (the
real recording's calibration estimated 0.05 mm: at the configured 1 mm its own touches called both parts
moved). A calibration without one (written before it was kept) is judged at the fabric the new training
touches imply under it (:func:`implied_fabric`), which also takes up part of a move along a part's normal
(a review: the real recording's torso shifted 3 mm that way came out `fits`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.stats import t as student_t

from nao_skin.calibration.engine import CalibrationResult, calibrate, train_test
from nao_skin.calibration.evaluation import fitted_touch_distances, paired_gain, truth_error
from nao_skin.calibration.options import DEFAULT_TOLERANCE_MM, CalibrationOptions
from nao_skin.calibration.pairing import robot_joints
from nao_skin.calibration.plan import Step, pair_poses
from nao_skin.calibration.rows import pair_step
from nao_skin.calibration.stages import fitted_kinds
from nao_skin.model.skin import SkinCalibration, SkinModel, pair_label, part_rank
from nao_skin.touch.touches import TouchSet

CONFIDENCE = 0.95            # one-sided, Student's t over the held-out touches
MIN_GAIN = 0.05              # the held-out gain's lower bound must reach it: a part that moved gains far more
MIN_HELD_OUT = 10            # held-out touches of a part's pairs below which no verdict is given

FITS, MOVED, NOT_CHECKED, NOT_CALIBRATED = "fits", "moved", "not checked", "not calibrated"


@dataclass
class PartCheck:
    """The verdict on one skin part and what it rests on."""

    part: str
    verdict: str                      # FITS, MOVED, NOT_CHECKED or NOT_CALIBRATED
    reason: str                       # one line: the figures the verdict rests on, or why none
    pairs: list = field(default_factory=list)      # the part pairs that touched (labels, e.g. 'l_hand+torso')
    moved_mm: dict | None = None      # its taxels, refit against the calibration: median, p95, max (mm)
    held_out_cop_mm: dict | None = None   # paired_gain of its pairs' test touches' closest COP (mm)


@dataclass
class CheckResult:
    """What :func:`check_calibration` found: a verdict per skin part, and the refit it rests on."""

    parts: dict                       # part name -> PartCheck, every part of the skin
    tolerance_mm: float
    fabric_mm: float                  # the fabric thickness both were measured at
    fabric_from: str                  # 'given', 'calibration' (its file's), 'estimated' (implied_fabric) or
                                      # 'configured' (the options': no pair to estimate it from)
    refit: CalibrationResult

    @property
    def moved(self) -> list:
        return [name for name, p in self.parts.items() if p.verdict == MOVED]

    def as_dict(self) -> dict:
        return {"tolerance_mm": self.tolerance_mm, "moved": self.moved,
                "split": {"train": self.refit.train.n_touches, "test": self.refit.test.n_touches},
                "fabric_mm": self.fabric_mm, "fabric_from": self.fabric_from,
                "parts": {name: {"verdict": p.verdict, "reason": p.reason, "pairs": p.pairs,
                                 "moved_mm": p.moved_mm, "held_out_cop_mm": p.held_out_cop_mm}
                          for name, p in self.parts.items()}}


def check_options(options: CalibrationOptions | None = None, fabric_mm: float | None = None) -> CalibrationOptions:
    """The refit's options: ``options`` (the defaults) at the mount level only, without kinematic unknowns,
    fitting the rows a calibration's last stages fit (``closing_pairs``), at ``fabric_mm`` (default: the
    options' ``fabric_thickness``)."""
    options = options or CalibrationOptions()
    options = replace(options, levels=["mount"], joint_levels=["mount"], closing_levels=[], kinematics="off",
                      mount_pairs=options.closing_pairs,
                      fabric_thickness=options.fabric_thickness if fabric_mm is None else fabric_mm / 1000.0)
    options.validate()
    return options


def implied_fabric(train: TouchSet, skin: SkinModel, calibration: SkinCalibration, parts: tuple,
                   options: CalibrationOptions) -> float:
    """The fabric thickness (m, within ``fabric_bounds``) that brings ``train``'s fitted pairs closest under
    ``calibration`` as it is: what the new touches say of the fabric, with nothing else moved."""
    step = Step(parts, ())
    kinds = fitted_kinds(options, {"mount"})
    pairing = pair_step(train, skin, calibration, step, kinds)    # the fabric lifts the paired points, not which

    def mean_mm(fabric: float) -> float:
        return float(np.nanmean(1000.0 * fitted_touch_distances(train, skin, calibration, step, kinds, fabric,
                                                                pairing)))

    low, high = options.fabric_bounds
    return float(minimize_scalar(mean_mm, bounds=(low, high), method="bounded", options={"xatol": 1e-5}).x)


def check_calibration(touches: TouchSet, skin: SkinModel, calibration: SkinCalibration,
                      tolerance_mm: float = DEFAULT_TOLERANCE_MM, fabric_mm: float | None = None,
                      options: CalibrationOptions | None = None,
                      progress: Callable[[str], None] | None = None) -> CheckResult:
    """Judge ``calibration`` by new ``touches`` (exact duplicates removed): which parts still fit, which moved.

    The touches are split as a calibration splits them (``options``: seed, ``test_fraction``, ``split_by``);
    the mounts are refit on the training touches from ``calibration`` (its patches, triangles and kinematic
    corrections kept), and judged on the held-out ones. ``fabric_mm``: the fabric thickness to measure at
    (default: the calibration's, else :func:`implied_fabric` of the training touches). A part no pair of the new touches calibrates
    is :data:`NOT_CHECKED`, and so is one with fewer than :data:`MIN_HELD_OUT` held-out touches, or one the
    refit moves while the held-out touches cannot yet tell whether that helps; a part the calibration holds at
    its nominal placement is :data:`NOT_CALIBRATED`.
    """
    options = check_options(options)
    train, test = train_test(touches, options)
    poses_per_pair = pair_poses(train)
    pairs = sorted((tuple(sorted(p, key=part_rank)) for p, n in poses_per_pair.items()
                    if n >= options.min_mount_touches), key=lambda p: [part_rank(n) for n in p])
    fabric_from = "given" if fabric_mm is not None else "configured"
    if fabric_mm is None and calibration.fabric_thickness is not None:
        fabric_mm, fabric_from = 1000.0 * calibration.fabric_thickness, "calibration"
    elif fabric_mm is None and pairs:
        fabric_mm, fabric_from = 1000.0 * implied_fabric(
            train, skin, calibration, tuple(sorted({n for p in pairs for n in p}, key=part_rank)), options), "estimated"
    options = check_options(options, fabric_mm)
    refit = calibrate(touches, skin, options, prior=calibration, progress=progress, split=(train, test))
    fabric = options.fabric_thickness
    poses = robot_joints(train, skin) if calibration.kinematics else None
    out = {}
    for name in skin.parts:
        partners = tuple(sorted({b for pair in pairs for a, b in (pair, pair[::-1]) if a == name}, key=part_rank))
        labels = [pair_label((name, other)) for other in partners]
        if not partners:
            out[name] = PartCheck(name, NOT_CHECKED, f"no pair of the new touches calibrates it (fewer than"
                                                     f" {options.min_mount_touches} training poses with another"
                                                     f" part, or none)")
            continue
        moved = truth_error(skin, refit.calibration, calibration, parts=[name], poses=poses)[name]
        step = Step((name,), partners)
        before = 1000.0 * fitted_touch_distances(test, skin, calibration, step, ("cop",), fabric)
        after = 1000.0 * fitted_touch_distances(test, skin, refit.calibration, step, ("cop",), fabric)
        n = int(np.sum(np.isfinite(before) & np.isfinite(after)))
        gain = paired_gain(before, after, float(student_t.ppf(CONFIDENCE, n - 1)) if n > 1 else np.inf)
        nominal = not _calibrated(calibration, name)
        out[name] = _verdict(name, labels, moved, gain, tolerance_mm, nominal)
    return CheckResult(out, tolerance_mm, options.fabric_thickness * 1000.0, fabric_from, refit)


def _calibrated(calibration: SkinCalibration, name: str) -> bool:
    """Whether the calibration moved the part from its nominal placement at all (every correction exactly 0:
    no touch ever calibrated it)."""
    c = calibration.parts.get(name)
    return c is not None and bool(np.any(c.mount) or np.any(c.patches) or np.any(c.triangles))


def _verdict(name: str, labels: list, moved: dict, gain: dict, tolerance_mm: float, nominal: bool) -> PartCheck:
    taxels = f"the refit puts its taxels {moved['median']:.2f} mm (median; max {moved['max']:.2f}) from the calibration's"
    if nominal:
        return PartCheck(name, NOT_CALIBRATED, f"the calibration holds it at its nominal placement (no touch"
                                               f" calibrated it); {taxels}: calibrate it", labels, moved, gain)
    if gain["touches"] < MIN_HELD_OUT:
        return PartCheck(name, NOT_CHECKED, f"{taxels}, but {gain['touches']} held-out touches of"
                                            f" {', '.join(labels)} cannot say whether that is the skin or the few"
                                            f" touches (at least {MIN_HELD_OUT}: record more)", labels, moved, gain)
    closer = (f"{_percent(gain['gain'])} % closer" if gain["gain"] >= 0 else f"{_percent(-gain['gain'])} % farther")
    held_out = (f"held-out closest COP of {', '.join(labels)} {gain['before']:.2f} mm with the calibration,"
                f" {gain['after']:.2f} with the refit ({closer}, lower 95 % bound {_percent(gain['gain_low'])} %,"
                f" {gain['touches']} touches)")
    if moved["median"] < tolerance_mm:
        return PartCheck(name, FITS, f"{taxels}, below {tolerance_mm:g} mm; {held_out}", labels, moved, gain)
    if gain["gain_low"] >= MIN_GAIN:
        # one pair of parts tells how the two sit relative to each other, not which of them moved
        alone = (f"; {labels[0]} is its only pair: whether it or the other part moved, touches of another pair"
                 f" tell" if len(labels) == 1 else "")
        return PartCheck(name, MOVED, f"{taxels}, at least {tolerance_mm:g} mm; {held_out}, at least"
                                      f" {_percent(MIN_GAIN)} %{alone}", labels, moved, gain)
    if gain["gain"] >= MIN_GAIN:     # the refit helps, but too few touches to be sure
        return PartCheck(name, NOT_CHECKED, f"{taxels}, at least {tolerance_mm:g} mm, and {held_out}: too few to"
                                            f" be sure it is {_percent(MIN_GAIN)} % or more (record more)",
                         labels, moved, gain)
    return PartCheck(name, FITS, f"{taxels}, but the held-out touches do not come {_percent(MIN_GAIN)} % closer"
                                 f" with it; {held_out}", labels, moved, gain)


def _percent(share: float) -> int:
    return int(round(100 * share))      # no "-0 %"
