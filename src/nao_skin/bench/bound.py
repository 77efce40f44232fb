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
from functools import partial

import numpy as np
import scipy.sparse

from nao_skin.calibration.layout import LEVELS, ParameterLayout
from nao_skin.calibration.options import CalibrationOptions
from nao_skin.calibration.pairing import KIND_NAMES, chain_end_poses
from nao_skin.calibration.plan import Step
from nao_skin.calibration.residuals import ResidualModel
from nao_skin.calibration.rows import pair_step, select_rows
from nao_skin.calibration.stages import fitted_kinds, initial_prior_sigma, prior_group_columns
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.touches import TouchSet

DIFFERENCE_STEP = 1e-6      # m or rad: central differences of the taxel positions by the unknowns (linear there)
UNCONSTRAINED = 1e-6        # prior information (1/m^2, 1/rad^2) of the mounts and the fabric: next to none


@dataclass
class LinearisedCapture:
    """The pool's rows linearised at the truth, and how the taxels move with the unknowns."""

    jacobian: scipy.sparse.csr_matrix    # (3 rows per paired row, unknowns)
    row_touch: np.ndarray                # touch of each Jacobian row
    n_touches: int
    sigma: float                         # m per coordinate
    prior: np.ndarray                    # prior information per unknown
    taxel_jacobian: np.ndarray           # (3 per taxel, unknowns)
    taxel_part: np.ndarray               # part of each taxel
    parts: tuple

    def information(self, touches: np.ndarray) -> np.ndarray:
        """``sum J_t^T J_t / sigma^2`` over the given touches (indices into the pool)."""
        rows = self.jacobian[np.isin(self.row_touch, touches)]
        return (rows.T @ rows).toarray() / self.sigma ** 2

    def predicted_error(self, information: np.ndarray) -> dict:
        """Per part ``(median, p95)`` over its taxels of the predicted RMS error (mm)."""
        cov = np.linalg.inv(information + np.diag(self.prior))
        g = self.taxel_jacobian
        var = np.einsum("ij,ij->i", g @ cov, g).reshape(-1, 3).sum(axis=1)
        rms = 1000.0 * np.sqrt(np.maximum(var, 0.0))
        return {p: (float(np.median(rms[self.taxel_part == p])), float(np.percentile(rms[self.taxel_part == p], 95)))
                for p in self.parts}

    def greedy(self, sizes, batch: int) -> dict:
        """``{N: predicted error}`` of the greedy choice at each of ``sizes``: batch after batch the touches
        whose rows lower the summed taxel variance most (each row's gain alone, summed over its touch)."""
        sizes = sorted(set(int(n) for n in sizes))
        chosen: list = []
        information = np.zeros((len(self.prior), len(self.prior)))
        gtg = self.taxel_jacobian.T @ self.taxel_jacobian
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
    there."""
    options = (options or CalibrationOptions()).in_place()
    parts = tuple(p for p in skin.parts if p in touches.part_names)
    layout = ParameterLayout(skin, parts, ())
    kinds = fitted_kinds(options, {"triangle"})
    pairing = select_rows(pair_step(touches, skin, truth, Step(parts, ()), kinds, options.plane_rows()),
                          tuple(KIND_NAMES[k] for k in kinds))
    model = ResidualModel(skin, partial(chain_end_poses, touches, skin), pairing, touches.part_names, layout, truth,
                          fabric=fabric)
    jac = scipy.sparse.csr_matrix(model.jacobian(truth, {p: set(LEVELS) for p in parts}))
    residuals = model.residuals(truth)
    sigma = float(1.4826 * np.median(np.abs(residuals - np.median(residuals, axis=0))))
    prior = np.full(layout.size, UNCONSTRAINED)
    for group, std in initial_prior_sigma(options).items():
        prior[prior_group_columns(layout, parts, group)] = 1.0 / std ** 2
    x0 = layout.to_vector(truth, fabric)
    blocks, taxel_part = [], []
    for p in parts:
        m, _, _, end = layout.offsets[p]
        part = skin.parts[p]
        g = np.zeros((3 * len(part.slots), layout.size))
        for col in range(m, end):
            moved = []
            for sign in (1.0, -1.0):
                x = x0.copy()
                x[col] += sign * DIFFERENCE_STEP
                moved.append(part.taxel_positions(layout.to_calibration(x, truth).parts[p])[0][part.slots])
            g[:, col] = ((moved[0] - moved[1]) / (2 * DIFFERENCE_STEP)).ravel()
        blocks.append(g)
        taxel_part += [p] * len(part.slots)
    return LinearisedCapture(jac, np.repeat(pairing.row_touch, 3), touches.n_touches, sigma, prior,
                             np.vstack(blocks), np.array(taxel_part), parts)


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


def bound_rows(skin: SkinModel, seed: int, pool_per_pair: int, sizes, batch: int, draws: int = 2) -> list:
    """One seed: the simulated pool, then per size the random draws' and the greedy choice's predicted error."""
    from nao_skin.bench.hard import HardCaseSetup, simulate_case

    sim, touches, _ = simulate_case(skin, "default", seed, HardCaseSetup(n_touches=pool_per_pair))
    lin = linearise(skin, touches, sim.truth, sim.params.fabric_thickness)
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
