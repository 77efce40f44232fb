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
per cent is no reason to recalibrate (README, "Has the skin moved?").

Both calibrations are measured at the fabric surfaces of the fabric the calibration was made with (its
report's estimate): the mount stages do not estimate it, and judged at another fabric the mounts of a
calibration that fits move by about the difference along the normals.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

from nao_skin.calibration.engine import CalibrationResult, calibrate
from nao_skin.calibration.evaluation import fitted_touch_distances, paired_gain, plan_pairs, truth_error
from nao_skin.calibration.options import CalibrationOptions
from nao_skin.calibration.pairing import robot_joints
from nao_skin.calibration.plan import Step, plan_steps
from nao_skin.model.skin import SkinCalibration, SkinModel, pair_label, part_rank
from nao_skin.touch.touches import TouchSet

DEFAULT_TOLERANCE_MM = 1.0   # about what a calibration from a full recording is sure of (README, Results)
CONFIDENCE_Z = 1.645         # one-sided 95 %
MIN_GAIN = 0.05              # the held-out gain's lower bound must reach it: a part that moved gains far more

FITS, MOVED, NOT_CHECKED = "fits", "moved", "not checked"


@dataclass
class PartCheck:
    """The verdict on one skin part and what it rests on."""

    part: str
    verdict: str                      # FITS, MOVED or NOT_CHECKED
    reason: str                       # one line: the figures the verdict rests on, or why none
    pairs: list = field(default_factory=list)      # the part pairs that touched (labels, e.g. 'l_hand+torso')
    moved_mm: dict | None = None      # its taxels, refit against the calibration: median, p95, max (mm)
    held_out_cop_mm: dict | None = None   # paired_gain of its pairs' test touches' closest COP (mm)


@dataclass
class CheckResult:
    """What :func:`check_calibration` found: a verdict per skin part, and the refit it rests on."""

    parts: dict                       # part name -> PartCheck, every part of the skin
    tolerance_mm: float
    refit: CalibrationResult

    @property
    def moved(self) -> list:
        return [name for name, p in self.parts.items() if p.verdict == MOVED]

    def as_dict(self) -> dict:
        return {"tolerance_mm": self.tolerance_mm, "moved": self.moved,
                "touches": {"train": self.refit.train.n_touches, "test": self.refit.test.n_touches},
                "fabric_thickness_mm": self.refit.report.fabric_thickness_mm,
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


def check_calibration(touches: TouchSet, skin: SkinModel, calibration: SkinCalibration,
                      tolerance_mm: float = DEFAULT_TOLERANCE_MM, fabric_mm: float | None = None,
                      options: CalibrationOptions | None = None, progress: Callable[[str], None] | None = None) -> CheckResult:
    """Judge ``calibration`` by new ``touches`` (exact duplicates removed): which parts still fit, which moved.

    The touches are split as a calibration splits them (``options``: seed, ``test_fraction``, ``split_by``);
    the mounts are refit on the training touches from ``calibration`` (its patches, triangles and kinematic
    corrections kept), and judged on the held-out ones. A part no pair of the new touches calibrates is
    :data:`NOT_CHECKED`, and so is one without a held-out touch. ``fabric_mm``: the fabric thickness the
    calibration was made with (its report's ``fabric_thickness_mm``; default: the options').
    """
    options = check_options(options, fabric_mm)
    refit = calibrate(touches, skin, options, prior=calibration, progress=progress)
    steps = plan_steps(refit.train, options, skin.self_touch)
    pairs = plan_pairs(steps)
    fabric = refit.report.fabric_thickness_mm / 1000.0
    poses = robot_joints(refit.train, skin) if calibration.kinematics else None
    out = {}
    for name in skin.parts:
        partners = tuple(sorted({b for pair in pairs for a, b in (pair, pair[::-1]) if a == name}, key=part_rank))
        labels = [pair_label((name, other)) for other in partners]
        if not partners:
            out[name] = PartCheck(name, NOT_CHECKED, "no pair of the new touches calibrates it (too few touches"
                                                     " with another part, or none)")
            continue
        moved = truth_error(skin, refit.calibration, calibration, parts=[name], poses=poses)[name]
        step = Step((name,), partners)
        gain = paired_gain(1000.0 * fitted_touch_distances(refit.test, skin, calibration, step, ("cop",), fabric),
                           1000.0 * fitted_touch_distances(refit.test, skin, refit.calibration, step, ("cop",), fabric),
                           CONFIDENCE_Z)
        out[name] = _verdict(name, labels, moved, gain, tolerance_mm)
    return CheckResult(out, tolerance_mm, refit)


def _verdict(name: str, labels: list, moved: dict, gain: dict, tolerance_mm: float) -> PartCheck:
    taxels = f"the refit puts its taxels {moved['median']:.2f} mm (median; max {moved['max']:.2f}) from the calibration's"
    if gain["touches"] < 2:
        return PartCheck(name, NOT_CHECKED, f"{taxels}, but no held-out touch of {', '.join(labels)} says whether"
                                            f" that is the skin or the few touches (record more)",
                         labels, moved, gain)
    held_out = (f"held-out closest COP of {', '.join(labels)} {gain['before']:.2f} mm with the calibration,"
                f" {gain['after']:.2f} with the refit ({_percent(gain['gain'])} % closer, at least"
                f" {_percent(gain['gain_low'])} % at 95 % confidence, {gain['touches']} touches)")
    if moved["median"] >= tolerance_mm and gain["gain_low"] >= MIN_GAIN:
        # one pair of parts tells how the two sit relative to each other, not which of them moved
        alone = (f"; {labels[0]} is its only pair: whether it or the other part moved, touches of another pair"
                 f" tell" if len(labels) == 1 else "")
        return PartCheck(name, MOVED, f"{taxels}, at least {tolerance_mm:g} mm; {held_out}{alone}", labels, moved,
                         gain)
    why = (f"below {tolerance_mm:g} mm" if moved["median"] < tolerance_mm
           else f"the held-out touches do not come {_percent(MIN_GAIN)} % closer with it at 95 % confidence")
    return PartCheck(name, FITS, f"{taxels}, {why}; {held_out}", labels, moved, gain)


def _percent(share: float) -> int:
    return int(round(100 * share))      # no "-0 %"
