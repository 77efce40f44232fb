"""Predicted taxel error: the linearised posterior of the skin frames, per taxel its predicted RMS error.

The touches' rows are linearised at a calibration ``x`` (the rows' Jacobian ``J``) and the posterior
covariance of the unknowns is

    C = (J^T J / sigma^2 + P)^-1

with ``sigma`` the rows' noise per coordinate (a robust, MAD-based spread of their residuals there) and
``P`` the calibration's prior on patches and triangles (1 / prior std^2 per component; the mounts and the
fabric have next to none). A taxel's predicted RMS error is the root of the trace of ``G C G^T``, ``G``
the derivative of its position (chain-end frame) by the unknowns: what an efficient estimator reaches,
had the pairing no wrong pairs and the noise no tails.

:func:`predicted_error` evaluates it at a calibration's estimate (the engine, after every calibration and
live update), as the figures a truth evaluation reports (each part's median and p95 over its taxels of
their distance from the truth), scaled by the calibration's measured :data:`INEFFICIENCY`; ``nao-skin
bench-bound`` (:mod:`nao_skin.bench.bound`) at a simulated robot's truth, with
the same functions. Frames the calibration held (not estimated): a held patch or triangle component keeps
its prior uncertainty (the touches told the calibration nothing about it); a held mount component and the
fabric when it is not estimated count as known: no prior bounds them (they would swamp the figure). The
kinematic corrections a calibration estimated (kinematics=on/auto, kept) are unknowns like the frames, and
its taxels' distances are then measured where the taxels are, in the base frame at its training poses
(:func:`posed_taxel_jacobian`), as its truth evaluation measures them: a joint offset moves no taxel in
its chain-end frame. Without them the prediction was 0.65 times the true figure there, with them 0.83
(median; kinematic-error preset, kinematics on, 200 touches per pair, seeds 0-19).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np
import scipy.linalg.lapack
import scipy.sparse

from nao_skin.calibration.layout import LEVELS, ParameterLayout
from nao_skin.calibration.fingertip import fingertip_pairs
from nao_skin.calibration.pairing import KIND_FINGERTIP, KIND_NAMES, chain_end_poses, robot_joints
from nao_skin.calibration.plan import Step
from nao_skin.calibration.residuals import ResidualModel
from nao_skin.calibration.rows import pair_step, select_rows
from nao_skin.calibration.stages import PRIOR_GROUPS, fitted_kinds, prior_group_columns
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.touches import TouchSet

DIFFERENCE_STEP = 1e-6      # m or rad: central differences of the taxel positions by the unknowns (linear there)
UNCONSTRAINED = 1e-6        # prior information (1/m^2, 1/rad^2) of the mounts and the fabric: next to none
MAD_SCALE = 1.4826          # MAD -> standard deviation of a normal distribution
SAMPLES = 64                # draws of the posterior for the expected median and p95 of the taxels' distances
# training poses (evenly spaced) a calibration with kinematic corrections has its predicted error measured at
PREDICTION_POSES = 20
# The calibration's true error over the efficient estimator's at the same touches, measured: the posterior
# above is what an estimator without bias would reach; the calibration's rows (closest pairs, COPs over a
# lattice of taxels) are biased per pose, and its true taxel error is 1.45 times the posterior's (the median
# of the ratio over 1140 live updates of 20 simulated sessions, 100-1500 touches; docs/decisions.md, "The
# prediction's honesty and done"). The prediction is the posterior scaled by it.
INEFFICIENCY = 1.45


def robust_sigma(residuals: np.ndarray) -> float:
    """The rows' noise per coordinate (m): the MAD of the residual coordinates about their median, scaled."""
    r = np.asarray(residuals)
    return float(MAD_SCALE * np.median(np.abs(r - np.median(r, axis=0))))


def prior_information(layout: ParameterLayout, parts, prior_sigma: dict) -> np.ndarray:
    """Prior information per unknown: ``1 / std^2`` for the groups of ``prior_sigma`` (:data:`PRIOR_GROUPS`),
    :data:`UNCONSTRAINED` for the rest."""
    prior = np.full(layout.size, UNCONSTRAINED)
    for group in PRIOR_GROUPS:
        if prior_sigma.get(group):
            prior[prior_group_columns(layout, parts, group)] = 1.0 / prior_sigma[group] ** 2
    return prior


def linearised_rows(skin: SkinModel, touches: TouchSet, calib: SkinCalibration, fabric: float, parts: tuple,
                    options, inliers: np.ndarray | None = None, kinematic: tuple = ()) -> tuple:
    """``(layout, J, row of each Jacobian row's touch, residuals)``: the touches paired at ``calib`` as the
    closing stage pairs them (every part of ``parts`` against every other, ``options.closing_pairs``; only the
    ``inliers`` touches' rows when given), linearised there by every frame of ``parts``, the fabric and the
    ``kinematic`` corrections (names of the robot config's joints and links; none by default: known), and the
    touches' fingertip scenes on ``parts`` of the fingertips ``calib`` holds a sphere of (its four unknowns each).
    ``J`` is sparse (3 rows per paired row); ``None`` for all but the layout when nothing pairs."""
    options = options.in_place()
    scenes = tuple((f, p) for f, p in fingertip_pairs(touches) if p in parts and f in calib.fingertips)
    layout = ParameterLayout(skin, parts, tuple(kinematic), tuple(dict.fromkeys(f for f, _ in scenes)))
    kinds = fitted_kinds(options, {"triangle"})
    pairing = pair_step(touches, skin, calib, Step(parts, (), scenes), kinds, options.row_rules())
    if pairing is not None:
        pairing = select_rows(pairing, tuple(KIND_NAMES[k] for k in kinds) + (KIND_FINGERTIP,), inliers)
    if pairing is None or len(pairing.row_touch) == 0:
        return layout, None, None, None
    # on the robot the calibration's kinematic corrections describe (none: the config's)
    model = ResidualModel(skin, partial(chain_end_poses, touches, skin.with_kinematics(calib)), pairing,
                          touches.part_names, layout, calib, fabric=fabric,
                          kinematic_poses=(lambda c: partial(chain_end_poses, touches, skin.with_kinematics(c)))
                          if kinematic else None, fingertip_names=touches.fingertips)
    jac = scipy.sparse.csr_matrix(model.jacobian(calib, {p: set(LEVELS) for p in parts}))
    return layout, jac, np.repeat(pairing.row_touch, 3), model.residuals(calib)


def taxel_jacobian(skin: SkinModel, layout: ParameterLayout, calib: SkinCalibration) -> tuple:
    """``(G, taxel_part)``: the derivative of every taxel's position (chain-end frame; 3 rows per taxel, the
    parts of ``layout`` in turn, each part's slots) by the unknowns, sparse, and each taxel's part.

    Central differences, one component of every frame of a level at a time: a taxel moves with its own
    mount, patch and triangle only, so 18 differences per part give every column."""
    rows, cols, vals, taxel_part = [], [], [], []
    first = 0
    for name in layout.part_names:
        part = skin.parts[name]
        slots = part.slots
        tri = part.slot_triangle[slots]
        m, p, t, _ = layout.offsets[name]
        n = len(slots)
        base = calib.parts[name]
        for level, block in (("mount", np.full(n, m)), ("patch", p + 6 * part.triangle_patch[tri]),
                             ("triangle", t + 6 * tri)):
            for k in range(6):
                moved = []
                for sign in (1.0, -1.0):
                    corr = base.copy()
                    if level == "mount":
                        corr.mount = corr.mount.copy()
                        corr.mount[k] += sign * DIFFERENCE_STEP
                    else:
                        frames = getattr(corr, level + "es" if level == "patch" else level + "s").copy()
                        frames[:, k] += sign * DIFFERENCE_STEP
                        setattr(corr, level + "es" if level == "patch" else level + "s", frames)
                    moved.append(part.taxel_positions(corr, normals=False)[slots])
                d = (moved[0] - moved[1]) / (2 * DIFFERENCE_STEP)          # (n, 3)
                rows.append(first + np.arange(3 * n))
                cols.append(np.repeat(block + k, 3))
                vals.append(d.ravel())
        first += 3 * n
        taxel_part += [name] * n
    g = scipy.sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                shape=(first, layout.size))
    return g, np.array(taxel_part)


def posed_taxel_jacobian(skin: SkinModel, layout: ParameterLayout, calib: SkinCalibration, g, taxel_part: np.ndarray,
                         poses: np.ndarray) -> tuple:
    """``(G, taxel_part)`` at ``poses`` (N, joints in the robot's order): every taxel's base-frame position at each
    pose (the taxels of :func:`taxel_jacobian`'s ``g`` and ``taxel_part``, one pose after the other) by the
    unknowns, on the robot ``calib`` describes: the frames' columns are ``g``'s turned by the chain end at the
    pose, the kinematic columns central differences. Where a calibration corrects the kinematics, a taxel's
    error is where it is: its truth evaluation measures it so
    (:func:`~nao_skin.calibration.evaluation.truth_error`), and a kinematic unknown moves no taxel in its
    chain-end frame."""
    robot_skin = skin.with_kinematics(calib)
    names = list(layout.part_names)
    g = scipy.sparse.csr_matrix(g)
    n = len(taxel_part)
    turned = []
    rotations = {name: robot_skin.chain_poses(name, poses)[:, :3, :3] for name in names}
    index = np.array([names.index(p) for p in taxel_part])
    # each taxel's 3x3 block on the diagonal: its chain end's rotation at the pose
    block_rows = np.repeat(3 * np.arange(n), 9) + np.tile(np.repeat(np.arange(3), 3), n)
    block_cols = np.repeat(3 * np.arange(n), 9) + np.tile(np.tile(np.arange(3), 3), n)
    for k in range(len(poses)):
        blocks = np.stack([rotations[name][k] for name in names])[index]             # (taxels, 3, 3)
        turn = scipy.sparse.csr_matrix((blocks.ravel(), (block_rows, block_cols)), shape=(3 * n, 3 * n))
        turned.append(turn @ g)
    out = scipy.sparse.vstack(turned).tocsr()       # its kinematic columns are empty: g's are
    columns = []
    for name in layout.kinematic_cols:
        moved = []
        for sign in (1.0, -1.0):
            kin = dict(calib.kinematics)
            kin[name] = kin.get(name, 0.0) + sign * DIFFERENCE_STEP
            on = skin.with_kinematics(SkinCalibration(calib.parts, kin))
            moved.append(np.concatenate([on.taxels_in_base(p, poses, calib)[:, skin.parts[p].slots] for p in names],
                                        axis=1))                                  # (poses, taxels, 3)
        columns.append(((moved[0] - moved[1]) / (2 * DIFFERENCE_STEP)).ravel())
    if columns:
        block = np.stack(columns, axis=1)                                          # (rows, kinematic unknowns)
        rows, which = np.nonzero(block)
        cols = np.array(list(layout.kinematic_cols.values()))[which]
        out = out + scipy.sparse.csr_matrix((block[rows, which], (rows, cols)), shape=out.shape)
    return out.tocsr(), np.tile(taxel_part, len(poses))


def judged_taxel_jacobian(skin: SkinModel, layout: ParameterLayout, calib: SkinCalibration, g, taxel_part: np.ndarray,
                          touches: TouchSet) -> tuple:
    """``(G, taxel_part)`` where a calibration with kinematic unknowns has its taxels judged: in the base frame at
    :data:`PREDICTION_POSES` of the touches' poses, evenly spaced (:func:`posed_taxel_jacobian`); ``g`` and
    ``taxel_part`` themselves (the chain-end frames) when no touch reads every joint of the parts' chains."""
    q = robot_joints(touches, skin)
    chains = {skin.parts[p].chain for p in layout.part_names} - {None}
    read = [skin.robot.joint_index[j] for c in sorted(chains) for j in skin.robot.chain_joint_names(c)]
    q = q[np.all(np.isfinite(q[:, read]), axis=1)]
    if not len(q):
        return g, taxel_part
    q = q[np.unique(np.linspace(0, len(q) - 1, min(PREDICTION_POSES, len(q))).astype(int))]
    return posed_taxel_jacobian(skin, layout, calib, g, taxel_part, q)


def covariance(information: np.ndarray) -> np.ndarray:
    """The inverse of a symmetric positive definite ``information`` (Cholesky; LU if it is not)."""
    factor, info = scipy.linalg.lapack.dpotrf(information, lower=1, clean=1)
    if info == 0:
        inv, info = scipy.linalg.lapack.dpotri(factor, lower=1)
        if info == 0:
            return np.tril(inv) + np.tril(inv, -1).T
    return np.linalg.inv(information)


def taxel_rms(information: np.ndarray, prior: np.ndarray, g) -> np.ndarray:
    """Each taxel's predicted RMS error (m): ``sqrt(trace(G_i C G_i^T))``, ``C = (information + diag(prior))^-1``
    (``g``: :func:`taxel_jacobian`'s, 3 rows per taxel)."""
    return rms_of(covariance(information + np.diag(prior)), g)


def rms_of(cov: np.ndarray, g) -> np.ndarray:
    """Each taxel's RMS error (m) were the unknowns' error of covariance ``cov`` (``g`` as :func:`taxel_rms`'s)."""
    gc = np.asarray(g @ cov)
    var = (np.asarray(g.multiply(gc).sum(axis=1)).ravel() if scipy.sparse.issparse(g)
           else np.einsum("ij,ij->i", gc, g))
    return np.sqrt(np.maximum(var.reshape(-1, 3).sum(axis=1), 0.0))


def distance_draws(cov: np.ndarray, g, taxel_part: np.ndarray, parts, samples: int = SAMPLES) -> dict:
    """``{part: (medians, p95s)}`` (m, each ``(samples,)``): over each part's taxels, the median and p95 of their
    distance from the truth in each of ``samples`` draws of the unknowns' error from ``N(0, cov)`` (a fixed
    seed: the same calibration gives the same draws); ``all`` over the taxels of ``parts``. What one
    calibration's truth-error evaluation (:func:`~nao_skin.calibration.evaluation.truth_error`) would report,
    were its error one of the draws, the taxels' errors as correlated as their shared frames make them."""
    try:
        factor = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:     # not quite positive definite (covariance() fell back to LU): its square root
        w, v = np.linalg.eigh((cov + cov.T) / 2)
        factor = v * np.sqrt(np.clip(w, 0.0, None))
    draws = np.random.default_rng(0).standard_normal((len(cov), samples))
    moved = np.asarray(g @ (factor @ draws))                                 # (3 per taxel, samples)
    dist = np.linalg.norm(moved.reshape(-1, 3, samples), axis=1)             # (taxels, samples)

    def quantiles(sel):
        return np.median(dist[sel], axis=0), np.percentile(dist[sel], 95, axis=0)

    out = {p: quantiles(taxel_part == p) for p in parts if np.any(taxel_part == p)}
    if len(dist):
        out["all"] = quantiles(np.isin(taxel_part, list(parts)))
    return out


def distance_figures(cov: np.ndarray, g, taxel_part: np.ndarray, parts, samples: int = SAMPLES) -> dict:
    """``{part: {median, p95}, all: {...}}`` (m): the expected median and p95 over each part's taxels of their
    distance from the truth, were the unknowns' error ``N(0, cov)``: :func:`distance_draws`' quantiles averaged
    over the draws. A taxel's RMS error is larger than its typical distance (an isotropic one: the median
    distance 0.89 times it, the 95th percentile 1.61 times)."""
    return {p: {"median": float(np.mean(med)), "p95": float(np.mean(p95))}
            for p, (med, p95) in distance_draws(cov, g, taxel_part, parts, samples).items()}


def per_part(rms_mm: np.ndarray, taxel_part: np.ndarray, parts) -> dict:
    """``{part: {median, p95}, all: {...}}`` of per-taxel values (mm)."""
    def figures(v):
        return {"median": float(np.median(v)), "p95": float(np.percentile(v, 95))}

    out = {p: figures(rms_mm[taxel_part == p]) for p in parts if np.any(taxel_part == p)}
    if len(rms_mm):
        out["all"] = figures(rms_mm[np.isin(taxel_part, list(parts))])
    return out


def per_triangle(skin: SkinModel, rms_mm: np.ndarray, taxel_part: np.ndarray, parts) -> dict:
    """``{part: {triangle id: mm}}``: the median predicted RMS error of each triangle's taxels (``rms_mm`` in
    :func:`taxel_jacobian`'s order: each part's slots in turn), for the parts of ``parts``."""
    out = {}
    for name in parts:
        sel = taxel_part == name
        if not np.any(sel):
            continue
        part = skin.parts[name]
        rows = part.slot_triangle[part.slots]
        values = rms_mm[sel]
        out[name] = {int(tid): float(np.median(values[rows == r])) for r, tid in enumerate(part.triangle_ids)
                     if np.any(rows == r)}
    return out


@dataclass
class Posterior:
    """The linearised posterior at a calibration, as its predicted error used it: handed on to whoever asks what
    more touches would teach (the guidance)."""

    layout: ParameterLayout              # the unknowns (every frame of ``layout.part_names``, the fabric)
    free: np.ndarray                     # the columns of ``layout`` the covariance covers (the rest: known)
    cov: np.ndarray                      # (free, free): m^2 and rad^2, scaled by INEFFICIENCY^2
    sigma: float                         # the rows' noise per coordinate (m)
    rows_per_touch: float                # 3-vector rows per paired touch (the kinds of the closing stage)
    taxel_jacobian: scipy.sparse.csr_matrix   # (3 per taxel, free): each taxel's position by the unknowns
    taxel_part: np.ndarray               # the part of each taxel (each part's slots in turn)

    def taxels_of(self, part: str) -> np.ndarray:
        """Rows of ``part``'s taxels (its slots in order) in :attr:`taxel_jacobian` (3 rows each)."""
        return np.flatnonzero(self.taxel_part == part)

    def median_draws(self, parts, samples: int = 256) -> dict:
        """``{part: (samples,)}`` m: each of ``parts``' median taxel distance in draws of the posterior: how far
        the truth's figures may lie from the predicted ones were the posterior exact (a spread no prediction
        of the error from the touches can remove)."""
        draws = distance_draws(self.cov, self.taxel_jacobian, self.taxel_part, parts, samples)
        return {p: draws[p][0] for p in parts if p in draws}

    def taxel_information(self) -> np.ndarray:
        """``G^T G``: how the unknowns move the taxels (the summed taxel variance is ``trace(G C G^T)``)."""
        return (self.taxel_jacobian.T @ self.taxel_jacobian).toarray()

    def variance_lowered(self, row: np.ndarray, taxel_information: np.ndarray | None = None) -> float:
        """The summed variance of every taxel (m^2) one more touch would remove, its contact's row having the
        Jacobian ``row`` (3, free): the bound's greedy criterion (:mod:`nao_skin.bench.bound`) at the estimate
        (``taxel_information``: :meth:`taxel_information`'s, made once for many rows). A touch gives
        :attr:`rows_per_touch` such rows (one per kind of the closing stage); they see the same contact, so
        count as one row of that much less noise."""
        h = self.taxel_information() if taxel_information is None else taxel_information
        moved = row @ self.cov                                              # (3, free)
        spread = moved @ row.T + np.eye(3) * self.sigma ** 2 * INEFFICIENCY ** 2 / max(self.rows_per_touch, 1.0)
        return float(np.trace(np.linalg.solve(spread, moved @ h @ moved.T)))


@dataclass
class Prediction:
    """:func:`predicted_error`'s result."""

    figures: dict                        # part (and all) -> {median, p95} of the taxels' predicted distance, mm
    sigma: float                         # the rows' noise per coordinate it assumed (m); NaN: nothing paired
    triangles: dict                      # part -> {triangle id: median predicted RMS error of its taxels, mm}
    posterior: Posterior | None = None


def predicted_error(skin: SkinModel, touches: TouchSet, calib: SkinCalibration, fabric: float, parts: tuple,
                    reported, options, prior_sigma: dict, inliers: np.ndarray | None = None,
                    estimated=None, kinematic: tuple = ()) -> Prediction:
    """Per part of ``reported`` (and ``all``) the predicted median and p95 over
    its taxels of their distance from the truth (mm, :func:`distance_figures`) at the estimate ``calib``: the
    rows the calibration kept (``inliers``) linearised there, their noise from their residuals, the
    calibration's prior (``prior_sigma``), the posterior scaled by :data:`INEFFICIENCY`. ``parts``: every
    part the touches pair (the references of the reported ones too). ``estimated``: the
    ``part/frame/component`` names the calibration estimated (None: every one); the others are held (see the
    module's text). ``kinematic``: the kinematic corrections it estimated (names); with any, the distances are
    measured in the base frame at :data:`PREDICTION_POSES` of the touches' poses. ``sigma``: the rows' noise per
    coordinate (m) it assumed; ``triangles``: :func:`per_triangle`'s, each triangle's median predicted RMS
    error (the uncertainty map); the posterior they came from. Empty, NaN noise, when no row pairs."""
    layout, jac, row_touch, residuals = linearised_rows(skin, touches, calib, fabric, parts, options, inliers,
                                                        kinematic)
    sigma = robust_sigma(residuals) if jac is not None else float("nan")
    if not sigma > 0:
        return Prediction({}, sigma, {})
    prior = prior_information(layout, parts, prior_sigma)
    keep = np.ones(layout.size, bool)           # the unknowns the touches informed
    known = np.zeros(layout.size, bool)          # held without a prior: counted as known
    if estimated is not None:
        estimated = set(estimated)
        for col in range(layout.fabric_col):
            if layout.describe(col) not in estimated:
                keep[col] = False
                known[col] = prior[col] <= UNCONSTRAINED
    if not options.estimate_fabric:
        keep[layout.fabric_col], known[layout.fabric_col] = False, True
    for name, first in layout.fingertip_cols.items():    # a sphere's component held at the config's: known
        held = ~np.isfinite(calib.fingertips_std.get(name, np.full(4, np.nan)))
        keep[first:first + 4] &= ~held
        known[first:first + 4] |= held
    jac = jac[:, np.flatnonzero(keep)]
    information = np.zeros((layout.size, layout.size))
    information[np.ix_(keep, keep)] = (jac.T @ jac).toarray() / sigma ** 2
    g, taxel_part = taxel_jacobian(skin, layout, calib)
    free = np.flatnonzero(~known)
    cov = covariance(information[np.ix_(free, free)] + np.diag(prior[free])) * INEFFICIENCY ** 2
    rms = rms_of(cov, g[:, free])
    shown = [p for p in parts if p in reported]
    where, where_part = judged_taxel_jacobian(skin, layout, calib, g, taxel_part, touches) if kinematic \
        else (g, taxel_part)
    figures = {p: {k: 1000.0 * v for k, v in f.items()}
               for p, f in distance_figures(cov, where[:, free], where_part, shown).items()}
    posterior = Posterior(layout, free, cov, sigma, len(row_touch) / 3 / len(np.unique(row_touch)),
                          scipy.sparse.csr_matrix(g[:, free]), taxel_part)
    return Prediction(figures, sigma, per_triangle(skin, 1000.0 * rms, taxel_part, shown), posterior)
