"""Bounded nonlinear least squares with honest uncertainty: the one fitting engine
behind ``friction fit``, ``relax fit`` and ``compare``.

``fit_least_squares`` runs :func:`scipy.optimize.least_squares` (trust-region
reflective, bounds respected) from several deterministic starting points and
keeps the best optimum; parameter 95 % intervals come from the Gauss-Newton
covariance s^2 (J^T J)^+ with Student-t quantiles on n - k degrees of freedom,
cut at the parameter's bounds (a value outside them is impossible); parameters
that end at a bound are listed (``at_bound``), and parameters whose interval is
more than ``DEGENERATE_CI_RATIO`` times their value wide, or not finite, are
flagged ``degenerate`` (the data do not determine them: not a result);
``prediction_band`` propagates that covariance to the fitted curve (delta
method). Information criteria use the Gaussian log-likelihood.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy import optimize

from .distributions import t_ppf


#: a 95 % interval wider than this many times |value| marks a parameter the data do not determine
DEGENERATE_CI_RATIO = 10.0


@dataclass
class FitResult:
    """Outcome of a least-squares fit (values in the units the model function uses)."""

    names: list[str]
    values: np.ndarray
    stderr: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    cov: np.ndarray
    residuals: np.ndarray  # data - model
    n: int
    k: int
    rss: float
    r2: float
    aic: float
    bic: float
    sigma: float  # residual standard deviation sqrt(rss / (n - k))
    success: bool
    message: str
    at_bound: list[str] = field(default_factory=list)
    starts_converged: int = 0
    degenerate: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        """Return ``{name: {value, stderr, ci95: [lo, hi], at_bound, degenerate}}`` for JSON."""
        return {n: {"value": float(v), "stderr": float(s), "ci95": [float(lo), float(hi)],
                    "at_bound": n in self.at_bound, "degenerate": n in self.degenerate}
                for n, v, s, lo, hi in zip(self.names, self.values, self.stderr, self.ci_low, self.ci_high)}


def information_criteria(rss: float, n: int, k: int) -> tuple[float, float]:
    """Return (AIC, BIC) of a Gaussian least-squares fit with ``k`` parameters (+ the noise variance)."""
    rss = max(rss, 1e-300)
    loglik = -0.5 * n * (np.log(2 * np.pi * rss / n) + 1.0)
    kk = k + 1
    return float(2 * kk - 2 * loglik), float(kk * np.log(n) - 2 * loglik)


def _starts(x0: np.ndarray, lower: np.ndarray, upper: np.ndarray, n_starts: int, rng) -> list[np.ndarray]:
    """Return starting points: x0 first, then draws spread over the bounds (log-uniform when positive)."""
    pts = [np.clip(x0, lower, upper)]
    for _ in range(max(0, n_starts - 1)):
        p = np.empty_like(x0)
        for i in range(x0.size):
            lo, hi = lower[i], upper[i]
            if np.isfinite(lo) and np.isfinite(hi):
                if lo > 0 and hi / lo > 100:
                    p[i] = np.exp(rng.uniform(np.log(lo), np.log(hi)))
                else:
                    p[i] = rng.uniform(lo, hi)
            else:
                scale = abs(x0[i]) if x0[i] != 0 else 1.0
                p[i] = np.clip(x0[i] + scale * rng.normal(), lo, hi)
        pts.append(p)
    return pts


#: rows above which starting points are screened on a subset (see ``model_rows`` of fit_least_squares)
SCREEN_ROWS = 20_000


def _best_of(resid, starts, lower, upper, x_scale, tol, max_nfev):
    """Return (best scipy solution or None, number of starts that converged) over ``starts``."""
    best, converged = None, 0
    span = np.where(np.isfinite(upper - lower), upper - lower, 1.0)
    for start in starts:
        # keep strictly inside the bounds for the trust-region method
        start = np.clip(start, lower + 1e-12 * span, upper - 1e-12 * span)
        try:
            sol = optimize.least_squares(resid, start, bounds=(lower, upper), method="trf",
                                         x_scale=x_scale, xtol=tol, ftol=tol, gtol=tol, max_nfev=max_nfev)
        except (ValueError, FloatingPointError):
            continue
        converged += int(sol.success)
        if best is None or sol.cost < best.cost * (1 - 1e-12):
            best = sol
    return best, converged


def _near_bound(v: float, lo: float, hi: float, rel: float = 1e-6) -> bool:
    """Return True when ``v`` ended at a bound: within ``rel`` of the span, measured on a log scale for positive
    bounds spanning more than three decades (bounds [1e-6, 1e5] MPa s: a value 0.04 is not at 1e-6, though
    within 1e-6 of the linear span)."""
    if np.isfinite(lo) and np.isfinite(hi) and lo > 0 and hi / lo > 1e3 and v > 0:
        span = math.log(hi / lo)
        return math.log(v / lo) <= rel * span or math.log(hi / v) <= rel * span
    sp = hi - lo if np.isfinite(hi - lo) else math.inf
    return bool((np.isfinite(lo) and v - lo <= rel * max(sp, abs(v), 1e-12))
                or (np.isfinite(hi) and hi - v <= rel * max(sp, abs(v), 1e-12)))


def fit_least_squares(model: Callable[[np.ndarray], np.ndarray], y: np.ndarray, x0: Sequence[float],
                      names: Sequence[str], bounds: tuple[Sequence[float], Sequence[float]] | None = None,
                      sigma: np.ndarray | None = None, n_starts: int = 6, seed: int = 0,
                      x_scale: Sequence[float] | str = "jac", level: float = 0.95, tol: float = 1e-12,
                      max_nfev: int | None = None,
                      model_rows: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
                      screen_rows: int | None = None) -> FitResult:
    """Return the best bounded least-squares fit of ``model(params)`` to ``y``.

    Parameters
    ----------
    model : params -> predictions, same length as ``y``
    y : observations
    x0 : first starting point; further starts are drawn within ``bounds`` (deterministic ``seed``)
    names : parameter names
    bounds : (lower, upper); ±inf allowed
    sigma : per-point standard deviations (weights 1/sigma), optional
    n_starts : number of starting points (multi-start makes the optimum robust to the start)
    level : confidence level of the intervals
    tol : xtol = ftol = gtol of scipy's least_squares per start
    max_nfev : evaluation budget per start (default 2000 x number of parameters)
    model_rows : (params, row indices) -> predictions at those rows, optional. With it, a table of
        more than ``screen_rows`` rows (default :data:`SCREEN_ROWS`) has its starting points
        screened on a deterministic random subset of that many rows; only the best subset
        optimum is then refined on all rows. The result is the full-data optimum reached from
        the best basin, at the cost of about one full-data start instead of ``n_starts``
        (``starts_converged`` then counts the screening fits).
    screen_rows : size of the screening subset (default :data:`SCREEN_ROWS`)
    """
    y = np.asarray(y, float)
    x0 = np.asarray(x0, float)
    k = x0.size
    lower = np.full(k, -np.inf) if bounds is None else np.asarray(bounds[0], float)
    upper = np.full(k, np.inf) if bounds is None else np.asarray(bounds[1], float)
    w = np.ones_like(y) if sigma is None else 1.0 / np.asarray(sigma, float)

    def resid(p):
        r = (np.asarray(model(p), float) - y) * w
        return np.where(np.isfinite(r), r, 1e150)

    rng = np.random.default_rng(seed)
    starts = _starts(x0, lower, upper, n_starts, rng)
    budget = max_nfev if max_nfev is not None else 2000 * k
    n_screen = SCREEN_ROWS if screen_rows is None else int(screen_rows)
    screened = 0
    if model_rows is not None and len(starts) > 1 and y.size > n_screen:
        idx = np.sort(np.random.default_rng([seed, 1]).choice(y.size, n_screen, replace=False))
        y_s, w_s = y[idx], w[idx]

        def resid_s(p):
            r = (np.asarray(model_rows(p, idx), float) - y_s) * w_s
            return np.where(np.isfinite(r), r, 1e150)

        sub, screened = _best_of(resid_s, starts, lower, upper, x_scale, tol, budget)
        if sub is not None:
            starts = [sub.x]
    best, converged = _best_of(resid, starts, lower, upper, x_scale, tol, budget)
    converged = screened if screened else converged
    if best is None:
        raise RuntimeError("least-squares fit failed from every starting point")

    p = best.x
    r_w = best.fun
    n = y.size
    rss_w = float(r_w @ r_w)
    dof = max(n - k, 1)
    s2 = rss_w / dof if sigma is None else 1.0
    J = best.jac
    cov = s2 * np.linalg.pinv(J.T @ J)
    se = np.sqrt(np.clip(np.diag(cov), 0, None))
    tq = t_ppf(0.5 + level / 2, dof)
    residuals = y - np.asarray(model(p), float)
    rss = float(residuals @ residuals)
    ss_tot = float(((y - y.mean()) ** 2).sum())
    r2 = 1.0 - rss / ss_tot if ss_tot > 0 else float("nan")
    aic, bic = information_criteria(rss, n, k)
    at_bound = [nm for nm, v, lo, hi in zip(names, p, lower, upper) if _near_bound(v, lo, hi)]
    lo_ci = np.maximum(p - tq * se, lower)
    hi_ci = np.minimum(p + tq * se, upper)
    degenerate = degenerate_parameters(names, p, se, p - tq * se, p + tq * se)
    return FitResult(list(names), p, se, lo_ci, hi_ci, cov, residuals, n, k, rss, r2, aic, bic,
                     float(np.sqrt(rss / dof)), bool(best.success), str(best.message), at_bound, converged,
                     degenerate)


def degenerate_parameters(names, values, stderr, ci_low, ci_high, ratio: float = DEGENERATE_CI_RATIO) -> list[str]:
    """Return the names whose (unclipped) interval is not finite or wider than ``ratio`` x |value|."""
    out = []
    for nm, v, s, lo, hi in zip(names, values, stderr, ci_low, ci_high):
        if not (np.isfinite(s) and np.isfinite(lo) and np.isfinite(hi)) or (hi - lo) > ratio * abs(v):
            out.append(nm)
    return out


def jacobian_fd(fun: Callable[[np.ndarray], np.ndarray], p: np.ndarray, rel_step: float = 1e-6) -> np.ndarray:
    """Return the forward-difference Jacobian d fun / d p (columns per parameter)."""
    p = np.asarray(p, float)
    f0 = np.asarray(fun(p), float)
    J = np.empty((f0.size, p.size))
    for i in range(p.size):
        h = rel_step * max(abs(p[i]), 1e-8)
        q = p.copy()
        q[i] += h
        J[:, i] = (np.asarray(fun(q), float) - f0) / h
    return J


def prediction_band(curve: Callable[[np.ndarray], np.ndarray], fit: FitResult, level: float = 0.95,
                    observation: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (centre, lower, upper) of the confidence band of ``curve(params)``.

    Delta method with the fit's covariance; ``observation=True`` adds the residual
    variance (a prediction band for new measurements instead of the mean curve).
    """
    centre = np.asarray(curve(fit.values), float)
    J = jacobian_fd(curve, fit.values)
    var = np.einsum("ij,jk,ik->i", J, fit.cov, J)
    if observation:
        var = var + fit.sigma ** 2
    tq = t_ppf(0.5 + level / 2, max(fit.n - fit.k, 1))
    half = tq * np.sqrt(np.clip(var, 0, None))
    return centre, centre - half, centre + half
