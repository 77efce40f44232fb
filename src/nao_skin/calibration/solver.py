"""A bounded, robust Levenberg-Marquardt over the free unknowns of a :class:`ResidualModel` (options as data)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from nao_skin import se3
from nao_skin.calibration.residuals import ResidualModel, gram, jt_dot


@dataclass
class SolveOptions:
    """Options of one least-squares solve, as data (cf. scipy's least_squares)."""

    loss: str = "huber"            # "linear" or "huber" (on each row's distance)
    f_scale: float = 0.002         # metres: where the robust loss starts to discount a row
    max_iterations: int = 50
    ftol: float = 1e-5             # relative cost decrease that ends the solve (re-pairing follows)
    xtol: float = 1e-9             # step size (scaled) that ends the solve
    jacobian: str = "analytic"     # or "2-point" (finite differences, for comparison)
    prior_weight: float = 1e-9     # tiny pull to the prior: keeps unexcited directions there


@dataclass
class SolveResult:
    x: np.ndarray
    cost: float
    iterations: int
    evaluations: int
    converged: bool
    message: str
    # Gauss-Newton normal matrix (robust row weights, prior weights on the diagonal) over the
    # free columns, from the last iteration: its inverse is the posterior covariance / sigma^2
    normal_matrix: np.ndarray | None = None


def _row_weights(dist: np.ndarray, opts: SolveOptions) -> np.ndarray:
    if opts.loss == "linear":
        return np.ones_like(dist)
    if opts.loss == "huber":
        return np.where(dist <= opts.f_scale, 1.0, opts.f_scale / np.maximum(dist, 1e-15))
    raise ValueError(f"unknown loss '{opts.loss}' (linear, huber)")


def _robust_cost(dist: np.ndarray, opts: SolveOptions) -> float:
    if opts.loss == "linear":
        return 0.5 * float(np.sum(dist ** 2))
    c = opts.f_scale
    return float(np.sum(np.where(dist <= c, 0.5 * dist ** 2, c * dist - 0.5 * c * c)))


def solve(model: ResidualModel, x0: np.ndarray, free: np.ndarray, lower: np.ndarray, upper: np.ndarray,
          free_levels: dict, opts: SolveOptions, prior: np.ndarray | None = None,
          prior_weights: np.ndarray | None = None) -> SolveResult:
    """Bounded, robust (IRLS) Levenberg-Marquardt over the ``free`` columns.

    Normal equations are small (at most a few hundred unknowns) and dense;
    bounds are kept by projection; the robust loss is applied per residual
    row (the distance between two paired points), not per coordinate.
    """
    layout = model.layout
    prior = x0.copy() if prior is None else prior
    cols = np.flatnonzero(free)
    x = np.clip(x0.copy(), lower, upper)
    # Gaussian prior on each unknown (m^2 per unit^2): a tiny floor keeps directions the data
    # do not excite at their prior; larger weights (prior_weights) make the fit a MAP estimate
    pw = np.full(len(cols), opts.prior_weight)
    if prior_weights is not None:
        pw = np.maximum(pw, prior_weights[cols])

    def evaluate(xv):
        calib = layout.to_calibration(xv, model.base)
        return calib, model.residuals(calib, xv[layout.fabric_col])

    def cost_of(xv, r):
        d = xv[cols] - prior[cols]
        return _robust_cost(se3.vector_norms(r), opts) + 0.5 * float(pw @ (d * d))

    def jac(xv, calib, r):
        if opts.jacobian == "analytic":
            return model.jacobian(calib, free_levels, cols)
        if opts.jacobian == "2-point":
            out = np.empty((r.size, len(cols)))
            base = r.ravel()
            for j, c in enumerate(cols):
                h = 1e-7 * max(1.0, abs(xv[c]))
                xp = xv.copy()
                xp[c] += h
                out[:, j] = (evaluate(xp)[1].ravel() - base) / h
            return out
        raise ValueError(f"unknown jacobian '{opts.jacobian}' (analytic, 2-point)")

    calib, r = evaluate(x)
    cost = cost_of(x, r)
    evaluations = 1
    if len(cols) == 0:
        return SolveResult(x, cost, 0, 1, True, "no free parameter")
    mu = 1e-3
    converged = False
    message = "maximum iterations"
    it = 0
    h = None
    for it in range(1, opts.max_iterations + 1):
        w = np.repeat(_row_weights(se3.vector_norms(r), opts), 3)
        j = jac(x, calib, r)
        h = gram(j, w)
        g = jt_dot(j, w * r.ravel())
        h[np.diag_indices_from(h)] += pw
        g += pw * (x[cols] - prior[cols])
        diag = np.maximum(np.diag(h).copy(), 1e-12)
        # active set: unknowns on a bound whose gradient pushes outwards stay there this
        # iteration; projecting a full step instead zig-zags along the bounds
        xc = x[cols]
        active = ((xc <= lower[cols]) & (g > 0)) | ((xc >= upper[cols]) & (g < 0))
        inactive = np.flatnonzero(~active)
        if len(inactive) == 0:
            converged = True
            message = "all free unknowns on their bounds"
            break
        h_in = h if len(inactive) == len(cols) else h[np.ix_(inactive, inactive)]
        g_in = g[inactive]
        improved = False
        for _ in range(12):
            try:
                step_in = -scipy.linalg.cho_solve(
                    scipy.linalg.cho_factor(h_in + mu * np.diag(diag[inactive])), g_in)
            except np.linalg.LinAlgError:
                mu *= 10.0
                continue
            step = np.zeros(len(cols))
            step[inactive] = step_in
            x_new = x.copy()
            x_new[cols] = np.clip(x[cols] + step, lower[cols], upper[cols])
            calib_new, r_new = evaluate(x_new)
            evaluations += 1
            cost_new = cost_of(x_new, r_new)
            if cost_new < cost:
                rel = (cost - cost_new) / max(cost, 1e-300)
                scaled_step = np.linalg.norm((x_new - x)[cols] * np.sqrt(diag))
                x, calib, r, cost = x_new, calib_new, r_new, cost_new
                mu = max(mu / 3.0, 1e-9)
                improved = True
                if rel < opts.ftol or scaled_step < opts.xtol:
                    converged = True
                    message = "cost converged" if rel < opts.ftol else "step converged"
                break
            mu *= 4.0
        if not improved:
            converged = True
            message = "no further decrease"
            break
        if converged:
            break
    return SolveResult(x, cost, it, evaluations, converged, message, h)
