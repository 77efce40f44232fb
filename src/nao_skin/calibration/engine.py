"""The calibration engine: from touches to corrected skin frames (entry point and options).

One entry point, :func:`calibrate`, with its options as data
(:class:`CalibrationOptions`). The thesis' findings are the defaults: a
reference part is held fixed while the other is fitted (hands from the
torso, then the torso from the hands, then the head from the calibrated
hands), each part level by level (mount, then patches, then triangles),
patches and triangles bounded. Within a stage the touches are re-paired
under the new calibration and solved again until the pairing stops changing.

What the thesis had to do by hand is done here: the mount of a hand that is
~160 degrees off nominal is first found in closed form (a rigid fit of
per-touch contact points, refined ICP-style on the closest COP pairs), so the
local solver starts in the right basin. Touches that no self-contact explains
are set aside by a gate after the mount stage and listed. A triangle with
fewer than ``min_triangle_activations`` paired activations, or a direction
the touches do not excite (Jacobi-scaled normal equations ill-conditioned),
is held at its prior and listed.

Modules of this package: :mod:`.options` (the options table), :mod:`.plan`
(which part against which), :mod:`.pairing` and :mod:`.rows` (pairing for the
solver), :mod:`.first_guess` (closed-form mount fit), :mod:`.stages` (one
stage with re-pairing), :mod:`.layout` (the unknowns as a vector),
:mod:`.residuals` (residuals and Jacobians), :mod:`.solver` (the
Levenberg-Marquardt loop), :mod:`.evaluation` (metrics), :mod:`.report`
(outputs) and :mod:`.pipeline` (recordings in, outputs written).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from typing import Callable, Iterable

import numpy as np
from threadpoolctl import threadpool_limits

from nao_skin.calibration.evaluation import (closest_cop_cost, contact_figure, evaluate, explained, firing_prediction,
                                             fitted_pair_cost, fitted_touch_distances, gate_touches, paired_gain,
                                             fingertip_truth_error, plan_fingertips, plan_pairs, truth_error)
from nao_skin.calibration.first_guess import guess_targets, rigid_mount_guess
from nao_skin.calibration.layout import FINGERTIP_COMPONENTS, KINEMATICS
from nao_skin.calibration.options import LEVELS, CalibrationOptions
from nao_skin.calibration.pairing import robot_joints
from nao_skin.calibration.plan import (Step, joint_step, left_out_pairs, pairs_outside_roles, plan_steps, too_few,
                                       touching_pairs)
from nao_skin.calibration.plausibility import implausible
from nao_skin.calibration.rows import pairing_key
from nao_skin.calibration.press import press_offsets
from nao_skin.calibration.stages import (Stage, StageStart, compress_held, fitted_kinds, initial_prior_sigma,
                                         run_stage)
from nao_skin.calibration.uncertainty import Posterior, predicted_error
from nao_skin.errors import DataError, TooFewTouches
from nao_skin.model.skin import SkinCalibration, SkinModel, part_rank
from nao_skin.touch.datasets import pose_groups
from nao_skin.touch.datasets import split as split_touches
from nao_skin.touch.touches import TouchSet


@dataclass
class CalibrationReport:
    """What a calibration did and how close it brought the touches (``report.json``, ``report.md``).

    ``before``, ``final`` and each stage hold the figures per split (``train``,
    ``test``: mean / median / p90 of the closest COP, taxel, selected contacts'
    taxel and 5-taxel pairs, mm) and, with ground truth, ``truth_taxel_error_mm``.
    """

    options: dict
    plan: list                      # the steps, in order, as named in stages
    parts: list                     # the parts calibrated
    pairs: list                     # the part pairs the touches connect
    before: dict
    stages: list = field(default_factory=list)
    final: dict = field(default_factory=dict)
    fabric_thickness_mm: float = float("nan")
    prior_sigma: dict = field(default_factory=dict)     # std per component group, as the touches left it
    set_aside: list = field(default_factory=list)       # touches no self-contact explains, with the reason
    held: list = field(default_factory=list)            # what no stage estimated
    kinematics: dict = field(default_factory=dict)      # kinematic corrections: estimated, held and why
    fingertips: dict = field(default_factory=dict)      # fingertips' contact spheres: estimated, std, held
    left_out: list = field(default_factory=list)        # pairs too few touches connect, held at the prior
    total_seconds: float = 0.0                          # the engine's, from touches to calibration
    input: dict = field(default_factory=dict)           # what was read (set by the pipeline)
    splits: dict = field(default_factory=dict)          # figures over repeated splits (pipeline, splits > 1)
    scenes: dict = field(default_factory=dict)          # each scene predicted from the others (pipeline, cross_scene)
    warnings: list = field(default_factory=list)        # why the result cannot be the skin's pose (plausibility)

    @property
    def n_set_aside(self) -> int:
        return len(self.set_aside)

    def to_dict(self) -> dict:
        out = asdict(self)
        out["n_set_aside"] = self.n_set_aside
        return out


@dataclass(frozen=True)
class FitState:
    """What a calibration learnt besides the frames that a warm update goes on from: the prior std per group
    of patch and triangle components (:data:`~.stages.PRIOR_GROUPS`), as the touches widened it.

    Not the fabric estimate: each update estimates it again from ``fabric_thickness``, so an early
    estimate from few touches does not carry into the next updates."""

    prior_sigma: dict


@dataclass
class CalibrationResult:
    calibration: SkinCalibration
    report: CalibrationReport
    train: TouchSet
    test: TouchSet
    set_aside: list = field(default_factory=list)
    # the linearised posterior the predicted error came from (what more touches would teach: the guidance)
    posterior: Posterior | None = None

    @property
    def state(self) -> FitState:
        return FitState(dict(self.report.prior_sigma))


# ---------------------------------------------------------------------- planning

def calibrate(touches: TouchSet, skin: SkinModel, options: CalibrationOptions | None = None,
              prior: SkinCalibration | None = None, truth: SkinCalibration | None = None,
              progress: Callable[[str], None] | None = None,
              split: tuple | None = None, warm: Iterable[str] = (),
              anchor: SkinCalibration | None = None, resume: FitState | None = None) -> CalibrationResult:
    """Calibrate the skin parts that the touches connect.

    ``split``: ``(train, test)`` touch sets; by default a seeded random 70/30
    split of ``touches`` (duplicates are expected to be removed before), the touches of one pose on one
    side (``options.split_by``).
    ``truth``: a simulator's ground truth, for the true taxel error in the report.
    ``warm``: parts that ``prior`` already calibrated from (most of) these
    touches, as a live update's previous one did: their mounts are in the
    basin, so their first guess and fixed-reference steps are skipped and the
    joint refinement alone moves them (a step without a joint refinement after
    it still runs, without its first guess). Parts not in ``warm`` get the
    whole plan. A warm calibration measures the final figures on each split
    only (a live update's status shows no more): ``before``, the stages and
    the subsets a self-contact explains have none.
    ``anchor``: with ``warm``, the calibration the live session started from
    (nominal by default): the prior of the patches and triangles stays centred
    there instead of on the last update, which the same touches made.
    ``resume``: with ``warm``, the last update's :attr:`CalibrationResult.state`: the fit starts from its
    prior widths, as from its frames, instead of the options' (the real skin is glued less carefully than
    the assumed widths say: restarting from them pulled its patches back each update).

    The engine runs with one BLAS thread: its matrices are small, and the threads OpenBLAS starts by
    default only contend for the cores with whatever else runs (the recorder and the other nodes of a
    session, a bench's other job): two calibrations at once each took twice as long with them, one
    alone no less time without them.
    """
    with threadpool_limits(1, user_api="blas"):
        return _calibrate(touches, skin, options, prior, truth, progress, split, warm, anchor, resume)


def _calibrate(touches: TouchSet, skin: SkinModel, options: CalibrationOptions | None,
               prior: SkinCalibration | None, truth: SkinCalibration | None,
               progress: Callable[[str], None] | None, split: tuple | None, warm: Iterable[str],
               anchor: SkinCalibration | None, resume: FitState | None) -> CalibrationResult:
    options = options or CalibrationOptions()
    options.validate()
    say = progress or (lambda msg: None)
    t_start = time.perf_counter()
    _check_parts(touches, skin)
    train, test = train_test(touches, options, split)
    if train.n_touches == 0 and touches.n_touches:
        raise TooFewTouches(f"test_fraction {options.test_fraction:g} holds out all {touches.n_touches} touches:"
                            f" none is left to calibrate from; lower it")
    steps = plan_steps(train, options, skin.self_touch)
    _check_enough(train, steps, options)
    start = _start_calibration(prior, skin)
    warm = frozenset(warm)
    resume = resume if warm else None
    fit = _Fit(start, options.fabric_thickness,
               dict(resume.prior_sigma) if resume and resume.prior_sigma else initial_prior_sigma(options),
               np.ones(train.n_touches, bool))
    # with kinematic corrections the true taxel error is measured at the touches' poses
    fit.truth_poses = robot_joints(train, skin) if truth is not None else None
    schedule = _schedule(steps, options, warm)
    report = CalibrationReport(
        options=options.as_mapping(),
        plan=[(prefix if prefix in (JOINT, CLOSING) else "") + step.name
              for round_no, step, prefix in schedule if round_no == 0 or not step.references],
        parts=sorted({p for s in steps for p in s.targets}, key=part_rank),
        pairs=sorted(sorted(p, key=part_rank) for p in touching_pairs(train)),
        before={} if warm else _figures(train, test, skin, fit.calibration, steps, truth, fit.truth_poses),
        left_out=[{"pair": pair, "touches": n, "poses": k, "reason": too_few(n, k, options.min_mount_touches)}
                  for pair, n, k in left_out_pairs(train, options)])
    for entry in report.left_out:
        say(f"{entry['pair']}: left out ({entry['reason']})")
    run = _Run(train, test, skin, options, steps, schedule, start, truth, say, report, warm,
               (anchor or skin.zero_calibration()) if warm else None)
    _run_all(run, fit)
    if options.press_model and not warm:
        # the whole plan again, from the start: the rows' expectations at the calibration just reached (on the
        # robot it describes) are a fixed part of each row (run from the joint refinement on only, it loses on
        # the real recording: docs/decisions.md, "The press model's expectation")
        t0 = time.perf_counter()
        press = press_offsets(train, skin, fit.calibration, fit.fabric, tuple(report.parts))
        say(f"press model: the rows' expectations at this calibration ({time.perf_counter() - t0:.2f} s)")
        fit = _Fit(start.copy(), options.fabric_thickness, initial_prior_sigma(options), np.ones(train.n_touches, bool),
                   truth_poses=fit.truth_poses, press=press)
        _run_all(run, fit, "press model: ")
    posterior = _final_report(run, fit)
    report.total_seconds = time.perf_counter() - t_start
    return CalibrationResult(fit.calibration, report, train, test, fit.set_aside, posterior)


def _final_report(run: _Run, fit: _Fit) -> Posterior | None:
    """The report's entries on the final calibration: its figures, what it held and set aside, the fingertips, its
    warnings (said); the posterior its predicted error came from."""
    train, skin, options, report, say = run.train, run.skin, run.options, run.report, run.say
    report.final = _final_figures(run, fit)
    _kept_apart(run, fit)
    posterior = _predicted(run, fit)
    report.fabric_thickness_mm = 1000.0 * fit.fabric
    fit.calibration.fabric_thickness = fit.fabric      # with the frames: what their closest pairs were measured at
    report.prior_sigma = fit.prior_sigma
    report.set_aside = fit.set_aside
    # held: what no stage estimated (a triangle held while fitted to one reference and freed by the
    # joint refinement, where both references reach ten activations, was estimated: not listed)
    report.held = sorted(compress_held(sorted(fit.held - fit.estimated)))
    report.fingertips = _fingertips_entry(skin, fit)
    outside = pairs_outside_roles(train, options, skin.self_touch)
    report.warnings = ([f"touches of {', '.join(outside)}: no pair of the skin config's self_touch (touching"
                        f" {', '.join(skin.self_touch.touching)}; touched {', '.join(skin.self_touch.touched)};"
                        f" {skin.source}), calibrated one from the other without the plan's order: is it this"
                        f" robot's config?"] if outside else []) \
        + implausible(train, skin, fit.calibration, report.parts, len(fit.set_aside),
                      contact_figure(report.final["train_kept"]), options.gate_mm)
    for line in report.warnings:
        say(f"warning: {line}")
    return posterior


@dataclass
class _Fit:
    """What the stages so far have settled, handed from one stage to the next."""

    calibration: SkinCalibration
    fabric: float                           # m, the fabric estimate so far
    prior_sigma: dict                       # prior std per group (stages.PRIOR_GROUPS)
    inliers: np.ndarray                     # (train touches,) not set aside by the gate
    set_aside: list = field(default_factory=list)
    held: set = field(default_factory=set)              # 'part/frame/comp' some stage held
    estimated: set = field(default_factory=set)         # 'part/frame/comp' some accepted stage estimated
    fingertips_held: set = field(default_factory=set)   # '<fingertip>/<component>' some stage held ...
    fingertips_estimated: set = field(default_factory=set)   # ... and some stage estimated
    # the fitted cost the last stage ended at: the next stage of the same step starts from it
    last_cost: tuple = (None, (), -1, np.inf)           # (step, kinds, n inliers, cost)
    # the last stage's figures and what they measured: the final figures when nothing changed since
    last_measured: tuple = (None, None, None, None)     # (calibration, part pairs, train, test)
    truth_poses: np.ndarray | None = None               # joint angles the true taxel error is measured at
    # each touch's expected cop_skin row at the true skin, subtracted from the rows (calibration/press.py)
    press: dict | None = None
    fabric_stands_in: bool = False                      # the fabric so far was fitted to a fixed reference


@dataclass
class _Run:
    """What every stage of one calibration reads and none changes: the touches (split), the skin, the options, the
    plan and its schedule, the calibration it started from, the truth (a simulator's, or None), where progress is
    said and the report the stages are entered in. ``warm``: the parts a live update's prior already calibrated
    (:func:`calibrate`); ``anchor``: with ``warm``, where the prior of the patches and triangles is centred."""

    train: TouchSet
    test: TouchSet
    skin: SkinModel
    options: CalibrationOptions
    steps: list
    schedule: list                          # (round, step, name prefix), _schedule's
    start: SkinCalibration
    truth: SkinCalibration | None
    say: Callable[[str], None]
    report: CalibrationReport
    warm: frozenset = frozenset()
    anchor: SkinCalibration | None = None

    @property
    def refined(self) -> bool:
        return _refines(self.schedule)


def _run_all(run: _Run, fit: _Fit, label: str = "") -> None:
    """The schedule's stages from ``fit`` on, each with its first guess, then the kinematic path (``label``: a
    prefix of every stage's name)."""
    options, warm = run.options, run.warm
    for round_no, step, prefix in run.schedule:
        if options.initial_guess == "rigid-fit" and round_no == 0 and not warm.issuperset(step.targets) \
                and (step.references or step.fingertips or options.reference == "simultaneous"):
            _first_guess(run, step, fit, label + prefix)
        warm_step = bool(warm) and warm.issuperset(step.targets)
        stage_options = _stage_options(options, prefix, warm_step)
        for levels in _stage_levels(step, options, prefix):
            stage = Stage(step, frozenset(levels), stage_options,
                          _repairings(stage_options, step, warm_step, run.refined), condition=not warm)
            run.report.stages.append(_fit_stage(run, stage, fit, round_no, label + prefix, run.anchor))
    if options.kinematics != "off":
        run.report.kinematics = _fit_kinematics(run, fit)


def _repairings(options: CalibrationOptions, step: Step, warm: bool, refined: bool) -> int:
    """How many re-pairings a stage of ``step`` makes at most: ``options.warm_repairings`` where every part it fits
    was calibrated by the last update (``warm``; a part new to the session gets all ``max_repairings``),
    ``options.reference_repairings`` for a fixed-reference step a joint refinement follows (``refined``: it frees
    the step's frames again), else ``options.max_repairings``."""
    limit = (options.warm_repairings if warm else options.reference_repairings if refined and step.references
             else options.max_repairings)
    return min(limit, options.max_repairings)


def _fingertips_entry(skin: SkinModel, fit: _Fit) -> dict:
    """``report.fingertips``: per fingertip the stages fitted, its contact sphere (m, in its chain's end frame), the
    std of each component where estimated and the components held at the robot config (FINGERTIP_COMPONENTS)."""
    out = {}
    for name in sorted({key.split("/")[0] for key in fit.fingertips_held | fit.fingertips_estimated}):
        centre, radius = fit.calibration.fingertip_sphere(skin.robot, name)
        std = fit.calibration.fingertips_std.get(name)
        held = [c for c in FINGERTIP_COMPONENTS if f"{name}/{c}" in fit.fingertips_held - fit.fingertips_estimated]
        out[name] = {"chain": skin.robot.fingertip(name).chain, "point": centre.tolist(), "radius": radius,
                     "std": None if std is None else [float(v) for v in std], "held": held}
    return out


def _check_parts(touches: TouchSet, skin: SkinModel) -> None:
    for name in touches.part_names:
        if name not in skin.parts:
            raise DataError(f"touches name skin part '{name}' that the skin config does not have"
                            f" (configured: {', '.join(skin.parts)})")


def train_test(touches: TouchSet, options: CalibrationOptions, split: tuple | None = None) -> tuple:
    """``(train, test)`` as :func:`calibrate` splits the touches (``split``: given instead)."""
    train, test = split if split is not None else split_touches(
        touches, options.test_fraction, options.seed, pose_groups(touches) if options.split_by == "pose" else None)
    if options.max_touches is not None and train.n_touches > options.max_touches:
        rng = np.random.default_rng(options.seed)
        train = train.subset(np.sort(rng.choice(train.n_touches, options.max_touches, replace=False)))
    return train, test


def _start_calibration(prior: SkinCalibration | None, skin: SkinModel) -> SkinCalibration:
    calib = (prior or skin.zero_calibration()).copy()
    for name in skin.parts:
        calib.parts.setdefault(name, skin.parts[name].zero_correction())
    return calib


def _schedule(steps: list, options: CalibrationOptions, warm: frozenset = frozenset()) -> list:
    """``(round, step, name prefix)`` in order: the plan's steps each round, then the joint refinement.

    With a joint refinement to follow, a step whose targets are all ``warm``
    is left out: the joint refinement frees those parts anyway.
    """
    # a joint refinement that frees nothing (joint_levels disjoint from levels) is none, and not in the plan
    refine = (options.joint_refinement and options.reference == "fixed" and len(steps) > 1
              and bool(set(options.joint_levels) & set(options.levels)))
    schedule = [(r, step) for r in range(max(1, options.rounds)) for step in steps
                if not (refine and step.references and warm.issuperset(step.targets))]
    joint = joint_step(steps)
    if refine:
        schedule.append((options.rounds, joint))
    out = []
    for round_no, step in schedule:
        prefix = f"round {round_no + 1}: " if options.rounds > 1 and step.references else ""
        if not step.references and options.reference == "fixed" and (step is joint or not step.fingertips):
            prefix = JOINT
        out.append((round_no, step, prefix))
    # a warm update leaves them out: it continues from the last update's frames anyway, within its time
    if refine and not warm and set(options.closing_levels) & set(options.levels):
        out.append((options.rounds, joint, CLOSING))
    return out


JOINT, CLOSING = "joint refinement: ", "closing: "      # name prefixes of the schedule's last stages


def _refines(schedule: list) -> bool:
    """Whether the schedule has a joint refinement (its fixed-reference steps are where it starts)."""
    return any(prefix == JOINT for _, _, prefix in schedule)


def _stage_levels(step: Step, options: CalibrationOptions, prefix: str = ""):
    """The levels freed stage by stage: mount, patches, triangles in turn (or all at once); for the closing
    stages (``prefix`` :data:`CLOSING`), each of ``closing_levels`` alone."""
    if prefix == CLOSING:
        yield from ({level} for level in LEVELS if level in options.closing_levels and level in options.levels)
        return
    levels_seq = ([{"mount"}, {"patch"}, {"triangle"}] if options.strategy == "sequential"
                  else [{"mount", "patch", "triangle"}])
    joint_step = not step.references and options.reference == "fixed"
    for levels in levels_seq:
        levels = levels & set(options.levels)
        if joint_step:
            levels = levels & set(options.joint_levels)
        if levels:
            yield levels


def _stage_options(options: CalibrationOptions, prefix: str, warm: bool) -> CalibrationOptions:
    """The options of the stages of one schedule entry. A closing stage starts with the frames nearly in place:
    it pairs as ``closing_pairs`` says. A warm one (its frames estimated by an earlier update) frees mounts,
    patches and triangles where they are: it pairs as ``warm_pairs`` says."""
    if warm:
        return replace(options, pairs=options.warm_pairs)
    return options.in_place() if prefix == CLOSING else options


def _first_guess(run: _Run, step: Step, fit: _Fit, prefix: str) -> None:
    """Closed-form first guess of each mount that has a reference to be fitted to, kept if it pairs closer."""
    train, skin, options = run.train, run.skin, run.options
    t0 = time.perf_counter()
    for target, refs, tips in guess_targets(step, skin.self_touch):
        guess_step = Step((target,), refs, tuple((f, target) for f in tips))
        before = closest_cop_cost(train, skin, fit.calibration, guess_step, fit.inliers)
        if before * 1000.0 < options.gate_mm / 2:
            continue   # already in the basin (e.g. the torso): the local solver takes it from here
        guess = fit.calibration.copy()
        guess.parts[target].mount = rigid_mount_guess(train, skin, fit.calibration, target, refs, fingertips=tips)
        if closest_cop_cost(train, skin, guess, guess_step, fit.inliers) < before:
            fit.calibration = guess
    run.say(f"{prefix}{step.name}: rigid-fit first guess ({time.perf_counter() - t0:.2f} s)")


def _fit_stage(run: _Run, stage: Stage, fit: _Fit, round_no: int, prefix: str,
               anchor: SkinCalibration | None = None) -> dict:
    """One stage: solve, keep it unless it drove the touches apart, gate after a mount fit; its report entry (named
    with ``prefix``; the stages of ``round_no`` 0 that free the mounts may leave the touches farther apart).
    ``anchor``: where the prior of the patches and triangles is centred (:class:`~.stages.StageStart`). A stage
    that does not report its condition (``stage.condition``) is not measured either."""
    train, skin, step, levels, options = run.train, run.skin, stage.step, set(stage.levels), stage.options
    # a stage is judged on what it fits, as it fits it (closest COP and taxel pairs, at the fabric
    # surfaces): taxel-centre distances grow with the fabric estimate however good the fit
    # (test_calibrate: a stage that drives the touches apart is undone)
    if fit.fabric_stands_in and not step.references:
        # Fitted against a reference that is not calibrated yet, the fabric estimate takes up that reference's
        # offset along its normals too, which helps those stages; but it is no fabric, and a joint stage
        # starting there does not give it all back. The stages that free every part start the fabric over
        # from the configured thickness (measured: docs/method.md, "7. The fabric over the taxels").
        fit.fabric, fit.fabric_stands_in = options.fabric_thickness, False
    kinds = fitted_kinds(options, levels)
    result = run_stage(train, skin, stage, StageStart(fit.calibration, fit.fabric, fit.inliers, fit.prior_sigma,
                                                      anchor, fit.press), run.say)
    # the costs are measured on the pairings the stage made where it started and (when its pairing
    # settled) where it ended, else the touches are paired for them
    started, ended = (result.pairings.get(pairing_key(c)) for c in (fit.calibration, result.calibration))
    last_step, last_kinds, last_inliers, last_cost = fit.last_cost
    cost_before = (last_cost if last_step is step and last_inliers == int(fit.inliers.sum()) and last_kinds == kinds
                   else fitted_pair_cost(train, skin, fit.calibration, step, fit.inliers, kinds, fit.fabric, started,
                                         options.row_rules(fit.press)))
    entry = result.report(prefix + result.name)
    entry["rows"] = list(kinds)
    if KINEMATICS in levels:
        entry["kinematics_held"] = list(result.kinematics_held)
    fit.held |= result.held_components
    fitted = {f"{f}/{c}" for f in step.fingertip_names if f in train.fingertips for c in FINGERTIP_COMPONENTS}
    fit.fingertips_held |= set(result.fingertips_held)
    fit.fingertips_estimated |= fitted - set(result.fingertips_held)
    cost_after = fitted_pair_cost(train, skin, result.calibration, step, fit.inliers, kinds,
                                  result.fabric_thickness_mm / 1000.0, ended, options.row_rules(fit.press))
    if cost_after > 1.25 * cost_before and not (round_no == 0 and "mount" in levels):
        # never silently diverge: a stage that leaves the touches much farther apart is undone
        entry["reverted"] = (f"undone: mean closest {'/'.join(kinds)} pair (at the fabric surfaces)"
                             f" {1000 * cost_after:.2f} mm after vs {1000 * cost_before:.2f} mm before")
        run.say(f"{entry['name']}: {entry['reverted']}")
    else:
        fit.fabric = result.fabric_thickness_mm / 1000.0
        fit.fabric_stands_in |= bool(run.refined and step.references)
        fit.prior_sigma = result.prior_sigma
        fit.calibration = result.calibration
        fit.estimated |= result.estimated_components
        cost_before = cost_after
    fit.last_cost = (step, kinds, int(fit.inliers.sum()), cost_before)
    if "mount" in levels and KINEMATICS not in levels and options.gate_mm > 0:
        paired = result.pairings.get(pairing_key(fit.calibration)) if "cop" in kinds else None   # its COP pairs
        entry["set_aside"] = _gate(run, step, prefix, fit, paired)
    if stage.condition:
        _measure(run, step, fit, entry)
    else:
        run.say(f"{entry['name']}: {entry['iterations']} iterations, {entry['repairings']} pairings,"
                f" {entry['seconds']:.2f} s")
    return entry


def _measure(run: _Run, step: Step, fit: _Fit, entry: dict) -> None:
    """A stage's figures on both splits at the calibration it left (and its true taxel error, with a truth), in its
    report ``entry``; said."""
    entry["train"] = evaluate(run.train, run.skin, fit.calibration, [step])
    entry["test"] = evaluate(run.test, run.skin, fit.calibration, [step])
    fit.last_measured = (fit.calibration, plan_pairs([step]), entry["train"], entry["test"])
    if run.truth is not None:
        entry["truth_taxel_error_mm"] = truth_error(run.skin, fit.calibration, run.truth, step.targets,
                                                    fit.truth_poses)
    label, near = contact_figure(entry["train"])
    run.say(f"{entry['name']}: train {label} {near:.2f} mm,"
            f" taxel {entry['train'].get('taxel_mean_mm', float('nan')):.2f} mm"
            f" ({entry['iterations']} iterations, {entry['repairings']} pairings, {entry['seconds']:.2f} s)")


KINEMATICS_SETTLED = 2e-4   # rad / m: no kinematic correction moved more in a pass (0.01 deg, 0.2 mm)
# auto asks the held-out gain to reach kinematics_min_gain at this one-sided confidence (1.645: 95 %): a
# test split's gain has a spread, and extra unknowns always buy a little, also where the robot is the config
# (the gains and bounds per preset: docs/method.md, "Kinematics")
KINEMATICS_GAIN_Z = 1.645


def _fit_kinematics(run: _Run, fit: _Fit) -> dict:
    """The kinematic path beside the skin-only calibration ``fit`` holds: the plan at mount level only, one
    stage freeing every mount with the joint-angle offsets and link lengths of their chains, then the whole
    plan on the corrected robot and the kinematic stage again until the kinematics settle. What the touches
    do not determine is held at nominal and said so.

    With ``kinematics=auto`` the path is kept only when it brings the test split's closest taxel pairs
    closer by ``kinematics_min_gain``; otherwise the calibration is the skin-only one, unchanged, and
    every kinematic unknown is listed as held with the figures. ``on`` keeps it whatever the figures.
    """
    skin, test, say, options = run.skin, run.test, run.say, run.options
    step = joint_step(run.steps)
    test_before = _held_out_surface_mm(test, skin, fit, step)
    kfit, entries = _kinematic_path(run, fit)
    held_out = paired_gain(test_before, _held_out_surface_mm(test, skin, kfit, step), KINEMATICS_GAIN_Z)
    candidates = skin.robot.kinematic_names(step.chains(skin))
    out = {"mode": options.kinematics, "test_taxel_surface_mm": held_out}
    if options.kinematics == "auto" and not held_out["gain_low"] >= options.kinematics_min_gain:
        asked = f"{100 * options.kinematics_min_gain:.0f} %"
        figures = (f"{held_out['before']:.3f} mm without, {held_out['after']:.3f} mm with the kinematic unknowns,"
                   f" {_percent(held_out['gain'])} closer, at least {_percent(held_out['gain_low'])} at 95 %"
                   f" confidence over {held_out['touches']} touches")
        run.report.stages.extend(dict(e, reverted=f"kinematics={options.kinematics}: the test split's closest taxel"
                                              f" distance (fabric surfaces) is not {asked} closer at 95 % confidence")
                             for e in entries)
        out["accepted"] = False
        out["held"] = [{"name": n, "reason": f"kinematics={options.kinematics}: test closest taxel pairs (fabric"
                                             f" surfaces) {figures}; kept from {asked}"} for n in candidates]
        out["corrections"] = {}
        say(f"kinematics: not kept (test closest taxel, fabric surfaces {figures}; kept from {asked})")
        return out
    vars(fit).update(vars(kfit))
    run.report.stages.extend(entries)
    out["accepted"] = True
    held = entries[-1].get("kinematics_held", [])   # the last kinematic stage decides
    kin = fit.calibration.kinematics
    gauge = skin.robot.rotation_gauge(step.chains(skin))
    out["held"] = [{"name": n, "reason": (f"the scene's gauge: every chain's first joint turns about one line, and"
                                          f" turning them and the skins on the base about it changes no touch"
                                          if n == gauge else
                                          "not determined by the touches: a direction the skin frames stand for"
                                          " too, or one the poses do not excite (Jacobi-scaled normal equations)")}
                   for n in candidates if n in held or n not in kin]
    out["corrections"] = {n: {"value": kin[n], "std": fit.calibration.kinematics_std.get(n, float("nan")),
                              "unit": "m" if n in skin.robot.links else "rad"} for n in candidates if n in kin}
    return out


def _kinematic_path(run: _Run, fit: _Fit) -> tuple:
    """``(fit, report entries)`` of the kinematic path beside the skin-only calibration ``fit`` (its inliers and
    rows' expectations): :func:`_fit_kinematics`' stages, every one fitting the rows of ``kinematics_pairs``
    (docs/method.md, "The contact model")."""
    options = replace(run.options, pairs=run.options.kinematics_pairs)
    step = joint_step(run.steps)
    # The skin-only plan is no starting point: its patches and triangles have absorbed what the kinematics
    # get wrong, and a kinematic stage after it only takes back what the mounts cannot (docs/method.md,
    # "Kinematics"). So a path of its own: the mounts alone (first guesses, the plan at mount level), then
    # the kinematics with every mount, the patches and triangles still at their prior.
    kfit = _Fit(run.start.copy(), options.fabric_thickness, initial_prior_sigma(options), fit.inliers.copy(),
                list(fit.set_aside), press=fit.press)
    entries = []

    def fit_stage(st, levels, round_no, prefix):
        stage = Stage(st, frozenset(levels), options, _repairings(options, st, False, run.refined))
        entries.append(_fit_stage(run, stage, kfit, round_no, prefix))

    for round_no, st, stage_prefix in run.schedule:
        prefix = "kinematics, mounts: " + stage_prefix
        if options.initial_guess == "rigid-fit" and round_no == 0 and (st.references or st.fingertips
                                                                       or options.reference == "simultaneous"):
            _first_guess(run, st, kfit, prefix)
        if any("mount" in levels for levels in _stage_levels(st, options, stage_prefix)):
            fit_stage(st, {"mount"}, round_no, prefix)
    fit_stage(step, {"mount", KINEMATICS}, options.rounds, "kinematics: ")
    for n in range(1, options.kinematics_passes + 1):
        last = dict(kfit.calibration.kinematics)
        calib = kfit.calibration.copy()
        for name, corr in calib.parts.items():   # the skin on the corrected robot, from its prior
            corr.patches, corr.triangles = run.start.parts[name].patches.copy(), run.start.parts[name].triangles.copy()
        kfit.calibration = calib
        kfit.last_cost = (None, (), -1, np.inf)
        for round_no, st, prefix in run.schedule:
            for levels in _stage_levels(st, options, prefix):
                fit_stage(st, levels, round_no, f"kinematics pass {n}: " + prefix)
        fit_stage(step, {"mount", KINEMATICS}, options.rounds, f"kinematics pass {n}: ")
        moved = max((abs(v - last.get(k, 0.0)) for k, v in kfit.calibration.kinematics.items()), default=0.0)
        if moved < KINEMATICS_SETTLED:
            break
    return kfit, entries


def _percent(share: float) -> str:
    return f"{100 * share:.1f} %" if np.isfinite(share) else "not measured"


def _held_out_surface_mm(test: TouchSet, skin: SkinModel, fit: _Fit, step: Step) -> np.ndarray:
    """The held-out figure that decides on the kinematic unknowns, per test touch: its closest taxel
    pairs' mean distance, mm, at the fabric surfaces of ``fit``'s own fabric estimate (each pair capped at
    50 mm; NaN: no pair).

    Not the taxel-centre distance: a calibration that squeezes its fabric estimate pulls the centres
    together however wrong its robot (simulator, kinematic-error seed 0, skin only: fabric 0.0 mm,
    test centre distance 3.31 mm, as on the default preset's 3.31 with its fabric 1.1 mm; at the
    fabric surfaces 3.56 against 2.36 mm). At the surfaces the kinematics buy 33 % there and 4 % on
    the default preset, where the config's robot is the true one.
    """
    return 1000.0 * fitted_touch_distances(test, skin, fit.calibration, step, ("taxel",), fit.fabric)


def _gate(run: _Run, step: Step, prefix: str, fit: _Fit, pairing=None) -> int:
    """Set aside the touches no self-contact explains after a mount fit; how many (``pairing``: the
    touches' COP pairs under ``fit.calibration``, when at hand)."""
    gate_mm = run.options.gate_mm
    gate = gate_touches(run.train, run.skin, fit.calibration, step, gate_mm, fit.inliers, pairing)
    for row, dist in gate:
        fit.inliers[row] = False
        fit.set_aside.append({"touch": str(run.train.keys[row]), "step": prefix + step.name,
                              "reason": f"closest COP pair {dist:.1f} mm after the mount fit > gate"
                                        f" {gate_mm:.0f} mm"})
    return len(gate)


def _figures(train: TouchSet, test: TouchSet, skin: SkinModel, calib: SkinCalibration, steps: list, truth,
             truth_poses) -> dict:
    out = {"train": evaluate(train, skin, calib, steps), "test": evaluate(test, skin, calib, steps)}
    if truth is not None:
        out["truth_taxel_error_mm"] = truth_error(skin, calib, truth, _targets(steps), truth_poses)
    return out


def _targets(steps: list) -> list:
    """The parts the plan calibrates (their true error is the calibration's; the others are held where they start)."""
    return sorted({p for s in steps for p in s.targets}, key=part_rank)


def _final_figures(run: _Run, fit: _Fit) -> dict:
    """The final calibration's figures on each split; but for a warm update, also on the touches a self-contact
    explains (``train_accepted``, ``test_accepted``)."""
    train, test, skin, steps, truth = run.train, run.test, run.skin, run.steps, run.truth
    calib, (measured, pairs, m_train, m_test) = fit.calibration, fit.last_measured
    if measured is calib and pairs == plan_pairs(steps):
        final = {"train": dict(m_train), "test": dict(m_test)}     # the last stage measured this very calibration
        for figures, touches in ((final["train"], train), (final["test"], test)):
            if figures.get("n_touches"):
                figures.update(firing_prediction(touches, skin, calib, pairs, plan_fingertips(steps)))
    else:
        final = {"train": evaluate(train, skin, calib, steps, fired=True),
                 "test": evaluate(test, skin, calib, steps, fired=True)}
    # the same gate on both splits: touches whose closest COP pair stays farther than gate_mm
    # are not explained by a self-contact (experimenter's hand, stray activations)
    for split_name, ts in ((("train", train), ("test", test)) if not run.warm else ()):
        ok = explained(ts, skin, calib, steps, run.options.gate_mm)
        final[f"{split_name}_accepted"] = evaluate(ts.subset(ok), skin, calib, steps)
        final[f"{split_name}_accepted"]["n_not_explained"] = int((~ok).sum())
    if truth is not None:
        final["truth_taxel_error_mm"] = truth_error(skin, calib, truth, _targets(steps), fit.truth_poses)
        if calib.fingertips:
            final["truth_fingertip_error_mm"] = fingertip_truth_error(skin, calib, truth)
    return final


def _kept_apart(run: _Run, fit: _Fit) -> None:
    """``final["train_kept"]``: the figures of the training touches the calibration kept, and
    ``final["train_set_aside"]`` those its gate set aside (experimenter's touches, stray activations: far apart
    under any calibration), each measured apart. The calibration is judged by the touches it kept; the
    training figures of every touch mix the two."""
    train, skin, steps, final = run.train, run.skin, run.steps, run.report.final
    aside = ~fit.inliers
    if not aside.any():
        final["train_kept"] = dict(final["train"])
        return
    final["train_kept"] = evaluate(train.subset(~aside), skin, fit.calibration, steps)
    final["train_set_aside"] = evaluate(train.subset(aside), skin, fit.calibration, steps)


def _predicted(run: _Run, fit: _Fit) -> Posterior | None:
    """The predicted taxel error at the estimate (:func:`~.uncertainty.predicted_error`): per calibrated part
    and ``all``, median and p95 (mm), in ``report.final`` (with the rows' noise it assumed) and on the
    calibration (calibration.yaml). The rows of the touches the gate kept, the prior the stages ended with."""
    train, report = run.train, run.report
    t0 = time.perf_counter()
    parts = tuple(sorted({p for s in run.steps for p in s.targets + s.references if p in train.part_names},
                         key=part_rank))
    # the kinematic corrections the calibration estimated are unknowns of the prediction too
    kin = report.kinematics or {}
    held = {h["name"] for h in kin.get("held", [])}
    kinematic = tuple(n for n in kin.get("corrections", {}) if n not in held) if kin.get("accepted") else ()
    prediction = predicted_error(run.skin, train, fit.calibration, fit.fabric, parts, report.parts, run.options,
                                 fit.prior_sigma, fit.inliers, fit.estimated, kinematic)
    figures, sigma = prediction.figures, prediction.sigma
    report.final["predicted_taxel_error_mm"] = figures
    report.final["predicted_triangle_error_mm"] = prediction.triangles
    report.final["predicted_noise_mm"] = 1000.0 * sigma
    fit.calibration.predicted_error_mm = {p: dict(v) for p, v in figures.items() if p != "all"}
    if figures:
        run.say(f"predicted taxel error median {figures['all']['median']:.2f} mm, p95 {figures['all']['p95']:.2f} mm"
            f" (rows' noise {1000.0 * sigma:.2f} mm; {time.perf_counter() - t0:.2f} s)")
    return prediction.posterior


def _check_enough(train: TouchSet, steps: list, options: CalibrationOptions) -> None:
    """Stop before solving when the touches cannot determine what is asked (one line)."""
    fired = train.parts_of_touch()
    groups = pose_groups(train)
    tip = train.fingertip_of_touch
    for step in steps:
        for target in step.targets:
            others = [p for p in step.targets + step.references if p != target]
            others += [f for f, p in step.fingertips if p == target]
            t = train.part_index(target)
            with_ref = fired[:, t] & (np.any(fired[:, [train.part_index(o) for o in others if o in train.part_names]],
                                             axis=1)
                                      | np.isin(tip, [train.fingertips.index(o) for o in others
                                                      if o in train.fingertips]))
            n = int(with_ref.sum())
            poses = len(np.unique(groups[with_ref]))
            need = options.min_mount_touches
            if poses < need:
                raise TooFewTouches(f"part '{target}' with {'/'.join(others)}: {too_few(n, poses, need)} (about"
                                    f" {int(np.ceil(need / (1 - options.test_fraction)))} before the"
                                    f" {int(options.test_fraction * 100)} % test split)")
