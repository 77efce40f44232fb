"""What choosing the touches could buy at best: a linearised Bayesian bound on the true taxel error.

At a simulated robot's true skin, every touch of a large pool is paired as
the calibration pairs it (the joint refinement's rows: every part, mount,
patches and triangles free) and its rows' Jacobian ``J_t`` is taken once. For
a set ``S`` of touches the posterior covariance of the unknowns is

    C(S) = (sum_{t in S} J_t^T J_t / sigma^2 + P)^-1

with ``sigma`` the rows' noise per coordinate (robust spread of the residuals
at the truth: the taxel lattices' offset, joint noise) and ``P`` the
calibration's prior on patches and triangles (bound / prior_strength). A
taxel's predicted error is the root of the trace of ``G C G^T``, ``G`` its
position's derivative (chain-end frame) by the unknowns: what an efficient
estimator would reach, had the pairing no wrong pairs and the noise no tails.
The linearisation and the covariance are :mod:`nao_skin.calibration.uncertainty`'s,
which every calibration evaluates at its estimate (its predicted taxel error).

Two ways to choose ``N`` touches from the pool: **random**, and **greedy** -- the
batches that lower the summed taxel variance most (A-optimal, one batch after
the other), choosing with the TRUE robot's Jacobian, which no capture at the
robot knows: a bound on what any guidance choosing among these touches can
buy over random capture. How many random touches reach the greedy choice's
error follows from the random errors at the sizes measured (log-log between
them).

With the kinematics free (:func:`kinematic_bound_row`), the unknowns are the frames and the robot config's
joint offsets and links of every chain, the rows the same, and the taxels are judged where they are: in the
base frame at the training poses, as a calibration with kinematic corrections is judged and predicts its
error (:func:`~nao_skin.calibration.uncertainty.judged_taxel_jacobian`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse

from nao_skin.calibration.layout import ParameterLayout
from nao_skin.calibration.options import CalibrationOptions
from nao_skin.calibration.stages import initial_prior_sigma
from nao_skin.calibration.uncertainty import (covariance, distance_draws, judged_taxel_jacobian, linearised_rows,
                                              prior_information, robust_sigma, taxel_jacobian, taxel_rms)
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.touches import TouchSet


@dataclass
class LinearisedCapture:
    """The pool's rows linearised at the truth, and how the taxels move with the unknowns."""

    jacobian: scipy.sparse.csr_matrix    # (3 rows per paired row, unknowns)
    row_touch: np.ndarray                # touch of each Jacobian row
    n_touches: int
    sigma: float                         # m per coordinate
    prior: np.ndarray                    # prior information per unknown
    taxel_jacobian: scipy.sparse.csr_matrix   # (3 per taxel, unknowns)
    taxel_part: np.ndarray               # part of each taxel
    parts: tuple

    def information(self, touches: np.ndarray) -> np.ndarray:
        """``sum J_t^T J_t / sigma^2`` over the given touches (indices into the pool)."""
        rows = self.jacobian[np.isin(self.row_touch, touches)]
        return (rows.T @ rows).toarray() / self.sigma ** 2

    def predicted_error(self, information: np.ndarray) -> dict:
        """Per part ``(median, p95)`` over its taxels of the predicted RMS error (mm)."""
        rms = 1000.0 * taxel_rms(information, self.prior, self.taxel_jacobian)
        return {p: (float(np.median(rms[self.taxel_part == p])), float(np.percentile(rms[self.taxel_part == p], 95)))
                for p in self.parts}

    def greedy(self, sizes, batch: int) -> dict:
        """``{N: predicted error}`` of the greedy choice at each of ``sizes``: batch after batch the touches
        whose rows lower the summed taxel variance most (each row's gain alone, summed over its touch)."""
        sizes = sorted(set(int(n) for n in sizes))
        chosen: list = []
        information = np.zeros((len(self.prior), len(self.prior)))
        gtg = (self.taxel_jacobian.T @ self.taxel_jacobian).toarray()
        out = {}
        while len(chosen) < sizes[-1]:
            cov = np.linalg.inv(information + np.diag(self.prior))
            jc = np.asarray(self.jacobian @ cov)                       # (rows, unknowns)
            spread = self.sigma ** 2 + np.asarray(self.jacobian.multiply(jc).sum(axis=1)).ravel()
            lowered = np.einsum("ij,ij->i", jc @ gtg, jc) / spread      # summed taxel variance a row removes
            gain = np.bincount(self.row_touch, weights=lowered, minlength=self.n_touches)
            gain[chosen] = -np.inf
            take = min(batch, sizes[-1] - len(chosen))
            chosen += np.argsort(-gain, kind="stable")[:take].tolist()
            information = self.information(np.array(chosen))
            if len(chosen) in sizes:
                out[len(chosen)] = self.predicted_error(information)
        return out


def linearise(skin: SkinModel, touches: TouchSet, truth: SkinCalibration, fabric: float,
              options: CalibrationOptions | None = None) -> LinearisedCapture:
    """The pool ``touches`` paired at the truth as the closing stage pairs them (``closing_pairs``), linearised
    there (:mod:`nao_skin.calibration.uncertainty`, as a calibration's predicted error is at its estimate)."""
    options = options or CalibrationOptions()
    parts = tuple(p for p in skin.parts if p in touches.part_names)
    layout, jac, row_touch, residuals = linearised_rows(skin, touches, truth, fabric, parts, options)
    prior = prior_information(layout, parts, initial_prior_sigma(options))
    sigma = robust_sigma(residuals)
    _hold_undetermined_fingertips(prior, layout, jac, sigma, options)
    g, taxel_part = taxel_jacobian(skin, layout, truth)
    return LinearisedCapture(jac, row_touch, touches.n_touches, sigma, prior, g, taxel_part, parts)


KNOWN = 1e16     # prior information (1/m^2) of an unknown held at its value: known


def _hold_undetermined_fingertips(prior: np.ndarray, layout: ParameterLayout, jac, sigma: float, options) -> None:
    """A fingertip sphere's component the pool determines no better than the engine asks
    (:data:`~nao_skin.calibration.stages.FINGERTIP_DETERMINED`, at the calibration's row noise) is held at the
    config's, as the engine holds it (its radius pressed on a flat part alone): known here too, in ``prior``."""
    from nao_skin.calibration.stages import FINGERTIP_DETERMINED, inverse_diagonal

    cols = [c for first in layout.fingertip_cols.values() for c in range(first, first + 4)]
    if not cols or jac is None:
        return
    std = options.residual_sigma * np.sqrt(np.maximum(inverse_diagonal((jac.T @ jac).toarray() + np.diag(prior)), 0.0))
    prior[[c for c in cols if not std[c] <= FINGERTIP_DETERMINED]] = KNOWN


def random_touches_for(error: float, random_errors: dict) -> float:
    """How many random touches reach ``error`` (mm), log-log between the sizes measured (``{N: error}``);
    beyond the largest size, extrapolated from the last two; NaN with fewer than two sizes."""
    sizes = sorted(random_errors)
    if len(sizes) < 2:
        return float("nan")
    for a, b in zip(sizes, sizes[1:]):
        if random_errors[b] <= error or b == sizes[-1]:
            slope = np.log(random_errors[b] / random_errors[a]) / np.log(b / a)
            if not slope < 0:
                return float("nan")
            return float(a * (error / random_errors[a]) ** (1.0 / slope))
    return float("nan")


def bound_rows(skin: SkinModel, seed: int, pool_per_pair: int, sizes, batch: int, draws: int = 2,
               options: CalibrationOptions | None = None, preset: str = "default") -> list:
    """One seed: the simulated pool (``preset``'s scenes), then per size the random draws' and the greedy choice's
    predicted error (the rows ``options.closing_pairs`` names and the fingertip scenes', linearised at the
    truth)."""
    from nao_skin.bench.hard import HardCaseSetup, simulate_case

    sim, touches, _ = simulate_case(skin, preset, seed, HardCaseSetup(n_touches=pool_per_pair))
    lin = linearise(skin, touches, sim.truth, sim.params.fabric_thickness, options)
    rng = np.random.default_rng(seed)
    worst = lambda err: (max(v[0] for v in err.values()), max(v[1] for v in err.values()))  # noqa: E731
    random_median = {}
    rows = []
    for n in sorted(sizes):
        errs = [lin.predicted_error(lin.information(rng.choice(lin.n_touches, n, replace=False)))
                for _ in range(draws)]
        med = float(np.mean([worst(e)[0] for e in errs]))
        p95 = float(np.mean([worst(e)[1] for e in errs]))
        random_median[n] = med
        rows.append({"seed": seed, "touches": n, "pool": lin.n_touches, "sigma_mm": 1000 * lin.sigma,
                     "random_median_mm": med, "random_p95_mm": p95})
    for row, (n, err) in zip(rows, sorted(lin.greedy(sizes, batch).items())):
        row["greedy_median_mm"], row["greedy_p95_mm"] = worst(err)
        row["random_touches_for_greedy"] = random_touches_for(row["greedy_median_mm"], random_median)
        row["ratio"] = row["random_touches_for_greedy"] / n
    return rows


# ------------------------------------------------------------------------------ the bound with the kinematics free
KINEMATIC_PRESET = "kinematic-error"
# rad or m: a kinematic unknown whose posterior std exceeds this has no information of its own -- the frames stand
# for it exactly (the last joint of a chain turns its part as the part's mount does); the engine holds it at
# nominal, where the mount absorbs it, and so does the bound
HELD_STD = 1.0
# the kinematic calibration's goals: its worst part within this ratio of the skin-only figure, and the recovered
# corrections within these tolerances, a link (mm) and a joint offset (deg)
RATIO_GOAL = 1.15
OFFSET_TOLERANCE = {"link_mm": 0.3, "joint_deg": 0.1}


def _held_kinematics(information: np.ndarray, layout: ParameterLayout) -> tuple:
    """``(covariance, held names)``: the posterior covariance with every kinematic unknown the frames stand for
    held (its row and column zero), the unknown of largest std first until none exceeds :data:`HELD_STD`."""
    keep = np.ones(len(information), bool)
    cols = layout.kinematic_cols
    held = []
    while True:
        idx = np.flatnonzero(keep)
        cov = np.zeros_like(information)
        cov[np.ix_(idx, idx)] = covariance(information[np.ix_(idx, idx)])
        free = {name: np.sqrt(cov[col, col]) for name, col in cols.items() if keep[col]}
        if not free or max(free.values()) <= HELD_STD:
            return cov, held
        name = max(free, key=free.get)
        keep[cols[name]] = False
        held.append(name)


def _within(std: np.ndarray, tolerance: float) -> float:
    """The expected share of unknowns within ``tolerance`` of the truth, each error ``N(0, std^2)``."""
    from scipy.special import erf

    return float(np.mean(erf(tolerance / (np.sqrt(2.0) * np.maximum(std, 1e-300))))) if len(std) else float("nan")


@dataclass
class _AtTruth:
    """One simulated robot's training touches linearised at its truth."""

    parts: tuple
    layout: ParameterLayout
    information: np.ndarray     # J^T J / sigma^2 plus the prior
    sigma: float
    n_train: int
    taxels: tuple               # (G, taxel part): where the taxels are judged (uncertainty.judged_taxel_jacobian)

    def worst_median(self, cov: np.ndarray) -> float:
        """The worst part's median distance from the truth (mm), expected over calibrations whose error is
        ``N(0, cov)`` (uncertainty.distance_draws, as a calibration's predicted error is figured): each draw's
        worst part, as each calibration's worst part is what the goals average over seeds."""
        draws = distance_draws(cov, *self.taxels, self.parts)
        return 1000.0 * float(np.mean(np.max([draws[p][0] for p in self.parts], axis=0)))


def _at_truth(skin: SkinModel, preset: str, seed: int, per_pair: int, options: CalibrationOptions,
              kinematics_free: bool) -> _AtTruth:
    from nao_skin.bench.hard import HardCaseSetup, simulate_case
    from nao_skin.calibration.engine import train_test

    sim, touches, _ = simulate_case(skin, preset, seed, HardCaseSetup(n_touches=per_pair))
    train, _ = train_test(touches, options)
    parts = tuple(p for p in skin.parts if p in train.part_names)
    chains = sorted({skin.parts[p].chain for p in parts} - {None})
    kinematic = tuple(skin.robot.kinematic_names(chains)) if kinematics_free else ()
    fabric = sim.params.fabric_thickness
    layout, jac, _, residuals = linearised_rows(skin, train, sim.truth, fabric, parts, options, kinematic=kinematic)
    sigma = robust_sigma(residuals)
    information = (jac.T @ jac).toarray() / sigma ** 2 + np.diag(prior_information(layout, parts,
                                                                                      initial_prior_sigma(options)))
    g, taxel_part = taxel_jacobian(skin, layout, sim.truth)
    taxels = judged_taxel_jacobian(skin, layout, sim.truth, g, taxel_part, train) if kinematic else (g, taxel_part)
    return _AtTruth(parts, layout, information, sigma, train.n_touches, taxels)


def kinematic_bound_row(skin: SkinModel, seed: int, per_pair: int, options: CalibrationOptions | None = None) -> dict:
    """One seed: what an efficient estimator reaches with the arm and head kinematics free, against the skin alone.

    ``per_pair`` touches per pair simulated on the default preset and on :data:`KINEMATIC_PRESET` (joints off by up
    to 2 deg, the elbow offsets 15 mm off), each split as a calibration splits it (``options``: test_fraction,
    seed) and its training touches linearised at the truth (rows ``options.closing_pairs``). Figures as a
    calibration predicts its error (:func:`~nao_skin.calibration.uncertainty.judged_taxel_jacobian`: with
    kinematic unknowns, in the base frame at its training poses), the worst part's median expected over the
    posterior's draws: the default preset's skin-only bound, the kinematic preset's with its kinematics known
    (its skin frames only) and free (joint offsets and links of every chain, what the frames stand for held);
    the free unknowns' posterior std, and the share of them an efficient estimator brings within
    :data:`OFFSET_TOLERANCE`."""
    options = options or CalibrationOptions()
    plain = _at_truth(skin, "default", seed, per_pair, options, kinematics_free=False)
    kin = _at_truth(skin, KINEMATIC_PRESET, seed, per_pair, options, kinematics_free=True)
    frames = np.arange(kin.layout.fabric_col + 1)
    known = np.zeros_like(kin.information)
    known[np.ix_(frames, frames)] = covariance(kin.information[np.ix_(frames, frames)])
    free, held = _held_kinematics(kin.information, kin.layout)
    std = {name: float(np.sqrt(free[col, col])) for name, col in kin.layout.kinematic_cols.items() if name not in held}
    links = {n: 1000.0 * s for n, s in std.items() if n in skin.robot.links}
    joints = {n: float(np.degrees(s)) for n, s in std.items() if n not in skin.robot.links}
    row = {"seed": int(seed), "per_pair": int(per_pair), "train_touches": plain.n_train,
           "kinematic_train_touches": kin.n_train, "sigma_mm": 1000.0 * plain.sigma,
           "skin_only_mm": plain.worst_median(covariance(plain.information)),
           "kinematics_known_mm": kin.worst_median(known),
           "kinematics_free_mm": kin.worst_median(free),
           "held": sorted(held), "link_std_mm": links, "joint_std_deg": joints,
           "links_within": _within(np.array(list(links.values())), OFFSET_TOLERANCE["link_mm"]),
           "joints_within": _within(np.array(list(joints.values())), OFFSET_TOLERANCE["joint_deg"])}
    row["ratio"] = row["kinematics_free_mm"] / row["skin_only_mm"]
    return row
