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
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse

from nao_skin.calibration.options import CalibrationOptions
from nao_skin.calibration.stages import initial_prior_sigma
from nao_skin.calibration.uncertainty import (linearised_rows, prior_information, robust_sigma, taxel_jacobian,
                                              taxel_rms)
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
    g, taxel_part = taxel_jacobian(skin, layout, truth)
    return LinearisedCapture(jac, row_touch, touches.n_touches, robust_sigma(residuals), prior, g, taxel_part, parts)


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
               options: CalibrationOptions | None = None) -> list:
    """One seed: the simulated pool, then per size the random draws' and the greedy choice's predicted error
    (the rows ``options.closing_pairs`` names, linearised at the truth)."""
    from nao_skin.bench.hard import HardCaseSetup, simulate_case

    sim, touches, _ = simulate_case(skin, "default", seed, HardCaseSetup(n_touches=pool_per_pair))
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
