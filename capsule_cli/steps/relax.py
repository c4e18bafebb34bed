"""Relaxation step: fit a Prony series (1..n Maxwell arms) to a stress-relaxation record.

Model (seed 004 eq 1 times the geometric factor of seed 003 eq 13):

    P(t) = Σ_j A_j exp(-t / τ_j) + P_∞,

with pressure amplitudes A_j >= 0 [Pa], time constants τ_j [s] and the
equilibrium pressure P_∞ [Pa]. When the geometric factor f = t_i,e ε / R_c is
known, the moduli follow as E_j = A_j / f, E_∞ = P_∞ / f and η_j = E_j τ_j
(seed 003: one arm, E_1 = 196.43 kPa, E_2 = E_∞ = 757.48 kPa, η_1 = 5.36 MPa·s).

Model order (how many arms)
---------------------------
Orders 1..``max_arms`` are fitted with :func:`capsule_cli.fitting.fit_least_squares`
(several starting points). Held-out error comes from K-fold cross-validation
whose folds never split a ``trial`` (with >= 2 trials the folds are whole
trials, K = min(5, number of trials); a single record is split into K = 5
interleaved folds of points). Starting from one arm, arm m + 1 is added only if

1. the CV RMSE drops by more than the standard error of the fold-wise paired
   RMSE difference (std of fold differences / sqrt(K)), **and**
2. BIC drops, **and**
3. the larger fit is well posed: no amplitude at its zero bound and no time
   constant at a bound of its search range.

The search stops at the first order that fails, so one arm is kept unless a
second is supported by held-out error.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..distributions import t_ppf
from ..errors import InputError
from ..fitting import FitResult, fit_least_squares, prediction_band

CV_RULE = ("add arm m+1 only if CV RMSE drops by more than the standard error of the fold-wise paired "
           "RMSE difference AND BIC drops AND no amplitude or time constant of the larger fit sits at a bound; "
           "stop at the first order that fails")


@dataclass
class OrderFit:
    """A Prony fit of one order, parameters in the fitter's units (kPa, log s)."""

    n_arms: int
    fit: FitResult
    tau_bounds_s: tuple[float, float]

    # parameter vector: [P_inf_kPa, A_1_kPa, log_tau_1, ..., A_n_kPa, log_tau_n]

    @property
    def equilibrium_Pa(self) -> float:
        return float(self.fit.values[0]) * 1e3

    @property
    def amplitudes_Pa(self) -> np.ndarray:
        return np.asarray(self.fit.values[1::2]) * 1e3

    @property
    def time_constants_s(self) -> np.ndarray:
        return np.exp(np.asarray(self.fit.values[2::2]))

    def predict_Pa(self, t_s) -> np.ndarray:
        return _prony_kpa(self.fit.values, np.asarray(t_s, float)) * 1e3

    def well_posed(self) -> bool:
        """True when no amplitude sits at zero and no time constant at a bound of its range."""
        return not any(n.startswith(("A_", "log_tau_")) for n in self.fit.at_bound)


@dataclass
class RelaxFit:
    """Result of :func:`fit_prony`: every order fitted, the CV table and the chosen order."""

    orders: dict[int, OrderFit]
    chosen: int
    cv: pd.DataFrame
    cv_scheme: str
    factor: float | None
    n: int
    time_range_s: tuple[float, float]
    rule: str = CV_RULE
    notes: list[str] = field(default_factory=list)

    @property
    def best(self) -> OrderFit:
        return self.orders[self.chosen]

    def predict_Pa(self, t_s, n_arms: int | None = None) -> np.ndarray:
        """Return the fitted pressure [Pa] at times ``t_s`` (chosen order unless ``n_arms``)."""
        return self.orders[n_arms or self.chosen].predict_Pa(t_s)

    def band_Pa(self, t_s, n_arms: int | None = None, level: float = 0.95):
        """Return (centre, lower, upper) [Pa] of the confidence band of the mean curve (delta method)."""
        of = self.orders[n_arms or self.chosen]
        t = np.asarray(t_s, float)
        c, lo, hi = prediction_band(lambda p: _prony_kpa(p, t), of.fit, level=level)
        return c * 1e3, lo * 1e3, hi * 1e3

    def parameters(self, n_arms: int | None = None) -> dict:
        """Return the parameters of an order with 95 % intervals, in kPa, s and (with a factor) kPa, MPa·s."""
        return _parameters(self.orders[n_arms or self.chosen], self.factor)

    def as_dict(self) -> dict:
        """Return the JSON record of the fit (fit.json)."""
        best = self.best
        return {
            "model": "prony: P(t) = sum_j A_j exp(-t/tau_j) + P_inf (seed 004 eq 1 x seed 003 eq 13 factor)",
            "n": self.n,
            "time_range_s": list(self.time_range_s),
            "chosen_n_arms": self.chosen,
            "rule": self.rule,
            "cv_scheme": self.cv_scheme,
            "factor": self.factor,
            "r2": best.fit.r2,
            "rmse_kPa": float(np.sqrt(best.fit.rss / best.fit.n)),
            "residual_sd_kPa": best.fit.sigma,
            "params": self.parameters(),
            "orders": {str(m): {"r2": of.fit.r2, "aic": of.fit.aic, "bic": of.fit.bic,
                                "rss_kPa2": of.fit.rss, "at_bound": of.fit.at_bound,
                                "params": self.parameters(m)} for m, of in self.orders.items()},
            "cv_table": self.cv.to_dict(orient="records"),
            "notes": self.notes,
        }


def _prony_kpa(p, t):
    """P(t) [kPa] for the parameter vector [P_inf, A_1, log τ_1, ...] (kPa, log s)."""
    out = np.full(t.shape, p[0], dtype=float)
    for j in range((len(p) - 1) // 2):
        out = out + p[1 + 2 * j] * np.exp(-t * np.exp(-p[2 + 2 * j]))
    return out


def _names(m: int) -> list[str]:
    names = ["P_inf_kPa"]
    for j in range(1, m + 1):
        names += [f"A_{j}_kPa", f"log_tau_{j}"]
    return names


def _tau_bounds(t: np.ndarray) -> tuple[float, float]:
    tt = np.unique(t)
    dt = np.diff(tt)
    dt_min = float(dt[dt > 0].min()) if (dt > 0).any() else 1.0
    span = float(tt.max() - tt.min())
    return max(0.5 * dt_min, 1e-6 * span), 10.0 * span


def _x0(t: np.ndarray, y: np.ndarray, m: int, tb: tuple[float, float]) -> np.ndarray:
    """Heuristic start: P_inf from the late record, amplitude split, log-spaced time constants."""
    order = np.argsort(t)
    ts, ys = t[order], y[order]
    k = max(3, ys.size // 10)
    p_inf = float(np.median(ys[-k:]))
    p0 = float(np.median(ys[:max(3, ys.size // 50)]))
    amp = max(p0 - p_inf, 1e-6 * max(abs(p0), 1.0))
    span = float(ts[-1] - ts[0]) or 1.0
    # 1/e time of the single-arm picture
    target = p_inf + amp / np.e
    below = np.nonzero(ys <= target)[0]
    tau1 = float(ts[below[0]] - ts[0]) if below.size else span / 3.0
    tau1 = float(np.clip(tau1, tb[0] * 1.01, tb[1] / 1.01))
    if m == 1:
        taus = [tau1]
    else:
        taus = list(np.geomspace(max(tau1 / 10.0, tb[0] * 1.01), min(tau1 * 3.0, tb[1] / 1.01), m))
    x = [p_inf]
    for tau in taus:
        x += [amp / m, np.log(tau)]
    return np.asarray(x, float)


def fit_prony_order(time_s, pressure_Pa, n_arms: int, x0=None, n_starts: int = 6, seed: int = 0) -> OrderFit:
    """Return the least-squares Prony fit with ``n_arms`` arms (arms sorted by time constant, fastest first).

    Parameters
    ----------
    time_s : times since the step [s]
    pressure_Pa : measured pressures [Pa]
    n_arms : number of Maxwell arms (>= 1)
    x0 : starting point [P_inf_kPa, A_1_kPa, log_tau_1, ...] (default: a heuristic from the record)
    n_starts : number of starting points of the multi-start fit (x0 first)
    seed : random seed of the extra starting points
    """
    t = np.asarray(time_s, float)
    y = np.asarray(pressure_Pa, float) / 1e3
    tb = _tau_bounds(t)
    rng_y = float(np.ptp(y)) or 1.0
    lower = [float(y.min()) - 2 * rng_y] + [0.0, np.log(tb[0])] * n_arms
    upper = [float(y.max())] + [10 * rng_y, np.log(tb[1])] * n_arms
    if x0 is None:
        x0 = _x0(t, y, n_arms, tb)
    fit = fit_least_squares(lambda p: _prony_kpa(p, t), y, x0, _names(n_arms), bounds=(lower, upper),
                            n_starts=n_starts, seed=seed)
    fit = _sorted_by_tau(fit, n_arms)
    return OrderFit(n_arms, fit, tb)


def _sorted_by_tau(fit: FitResult, m: int) -> FitResult:
    """Reorder the arms by increasing time constant (covariance and names permuted consistently)."""
    taus = fit.values[2::2]
    order = np.argsort(taus)
    if np.all(order == np.arange(m)):
        return fit
    idx = [0]
    for j in order:
        idx += [1 + 2 * j, 2 + 2 * j]
    idx = np.asarray(idx)
    old_names = list(fit.names)
    fit.values = fit.values[idx]
    fit.stderr = fit.stderr[idx]
    fit.ci_low = fit.ci_low[idx]
    fit.ci_high = fit.ci_high[idx]
    fit.cov = fit.cov[np.ix_(idx, idx)]
    rename = {old_names[i]: fit.names[k] for k, i in enumerate(idx)}
    fit.at_bound = [rename.get(n, n) for n in fit.at_bound]
    return fit


def _parameters(of: OrderFit, factor: float | None) -> dict:
    """Parameters with 95 % intervals: amplitudes [kPa], time constants [s], equilibrium [kPa], moduli."""
    f = of.fit
    tq = t_ppf(0.975, max(f.n - f.k, 1))
    out = {"P_inf_kPa": {"value": float(f.values[0]), "stderr": float(f.stderr[0]),
                         "ci95": [float(f.ci_low[0]), float(f.ci_high[0])]},
           "arms": []}
    if factor:
        out["E_inf_kPa"] = {"value": float(f.values[0]) / factor, "stderr": float(f.stderr[0]) / factor,
                            "ci95": [float(f.ci_low[0]) / factor, float(f.ci_high[0]) / factor]}
    for j in range(of.n_arms):
        ia, iu = 1 + 2 * j, 2 + 2 * j
        A, u = f.values[ia], f.values[iu]
        se_a, se_u = f.stderr[ia], f.stderr[iu]
        tau = float(np.exp(u))
        arm = {
            "arm": j + 1,
            "A_kPa": {"value": float(A), "stderr": float(se_a), "ci95": [float(f.ci_low[ia]), float(f.ci_high[ia])]},
            "tau_s": {"value": tau, "stderr": float(tau * se_u),
                      "ci95": [float(np.exp(u - tq * se_u)), float(np.exp(u + tq * se_u))]},
        }
        if factor:
            E = A / factor
            eta = E * tau  # kPa·s
            # delta method for eta = A exp(u) / factor
            J = np.array([tau / factor, A * tau / factor])
            C = f.cov[np.ix_([ia, iu], [ia, iu])]
            se_eta = float(np.sqrt(max(J @ C @ J, 0.0)))
            arm["E_kPa"] = {"value": float(E), "stderr": float(se_a / factor),
                            "ci95": [float(f.ci_low[ia] / factor), float(f.ci_high[ia] / factor)]}
            arm["eta_MPa_s"] = {"value": eta / 1e3, "stderr": se_eta / 1e3,
                                "ci95": [(eta - tq * se_eta) / 1e3, (eta + tq * se_eta) / 1e3]}
        arm["at_bound"] = [n for n in f.at_bound if n in (f"A_{j + 1}_kPa", f"log_tau_{j + 1}")]
        out["arms"].append(arm)
    return out


def _folds(n: int, groups) -> tuple[list[np.ndarray], str]:
    """Return held-out index sets that never split a group, and a description of the scheme."""
    if groups is not None:
        g = pd.Series(np.asarray(groups)).astype(str).to_numpy()
        uniq = list(dict.fromkeys(g))  # order of appearance
        if len(uniq) >= 2:
            K = min(5, len(uniq))
            folds = [np.nonzero(np.isin(g, uniq[i::K]))[0] for i in range(K)]
            return folds, f"{K}-fold by trial ({len(uniq)} trials; a trial is never split)"
    K = 5 if n >= 10 else max(2, n // 2)
    return [np.arange(i, n, K) for i in range(K)], f"{K}-fold interleaved points (single record)"


def fit_prony(time_s, pressure_Pa, max_arms: int = 3, groups=None, seed: int = 0, factor: float | None = None,
              n_starts: int = 6) -> RelaxFit:
    """Fit Prony series with 1..``max_arms`` arms and choose the order by held-out error.

    Parameters
    ----------
    time_s : time since the step [s] (>= 0)
    pressure_Pa : contact pressure [Pa]
    max_arms : largest number of arms tried (1-4)
    groups : trial label of each point (CV folds never split a trial); None: one record
    seed : random seed of the multi-start fits
    factor : geometric factor t_i,e ε / R_c [-] to report moduli E_j, E_∞ and
        viscosities η_j as well (optional)
    n_starts : starting points per full-data fit

    Returns
    -------
    RelaxFit with every order's fit, the CV table (per order: cv_rmse, fold
    standard error, paired difference and its standard error, BIC, decision)
    and the chosen order per the rule in the module docstring.
    """
    t = np.asarray(time_s, float)
    y = np.asarray(pressure_Pa, float)
    if t.shape != y.shape or t.ndim != 1:
        raise InputError("relaxation record: time and pressure must be 1-D arrays of the same length")
    if not 1 <= int(max_arms) <= 4:
        raise InputError(f"--max-arms must be between 1 and 4, got {max_arms}")
    if not (np.isfinite(t).all() and np.isfinite(y).all()):
        raise InputError("relaxation record: non-finite time or pressure")
    if (t < 0).any():
        raise InputError("relaxation record: negative time")
    if np.unique(t).size < 3 * max_arms + 3:
        raise InputError(f"relaxation record: {np.unique(t).size} distinct times are too few for "
                         f"{max_arms} arm(s) (need at least {3 * max_arms + 3})")
    if np.ptp(y) <= 0:
        raise InputError("relaxation record: the pressure does not change (nothing relaxes)")

    orders: dict[int, OrderFit] = {}
    for m in range(1, int(max_arms) + 1):
        orders[m] = fit_prony_order(t, y, m, n_starts=n_starts, seed=seed + m)

    folds, scheme = _folds(t.size, groups)
    fold_rmse = {m: [] for m in orders}
    sq_err = {m: np.zeros(t.size) for m in orders}
    for idx in folds:
        train = np.ones(t.size, bool)
        train[idx] = False
        for m, of in orders.items():
            sub = fit_prony_order(t[train], y[train], m, x0=of.fit.values, n_starts=2, seed=seed + 100 + m)
            err = (sub.predict_Pa(t[idx]) - y[idx]) / 1e3
            sq_err[m][idx] = err ** 2
            fold_rmse[m].append(float(np.sqrt(np.mean(err ** 2))))

    rows = []
    chosen, stopped = 1, False
    K = len(folds)
    for m, of in orders.items():
        cv = float(np.sqrt(sq_err[m].mean()))
        row = {"n_arms": m, "cv_rmse_kPa": cv,
               "cv_rmse_se_kPa": float(np.std(fold_rmse[m], ddof=1) / np.sqrt(K)) if K > 1 else float("nan"),
               "rmse_kPa": float(np.sqrt(of.fit.rss / of.fit.n)), "r2": of.fit.r2, "aic": of.fit.aic,
               "bic": of.fit.bic, "well_posed": of.well_posed(),
               "delta_cv_rmse_kPa": float("nan"), "delta_se_kPa": float("nan"), "delta_bic": float("nan"),
               "supported": m == 1}
        if m > 1:
            prev = m - 1
            cv_prev = float(np.sqrt(sq_err[prev].mean()))
            diff = np.asarray(fold_rmse[prev]) - np.asarray(fold_rmse[m])
            se = float(np.std(diff, ddof=1) / np.sqrt(K)) if K > 1 else float("inf")
            dbic = of.fit.bic - orders[prev].fit.bic
            supported = (cv_prev - cv) > se and dbic < 0 and of.well_posed()
            row.update(delta_cv_rmse_kPa=cv_prev - cv, delta_se_kPa=se, delta_bic=dbic, supported=bool(supported))
            if supported and not stopped:
                chosen = m
            else:
                stopped = True
        rows.append(row)
    cv_table = pd.DataFrame(rows)
    cv_table["chosen"] = cv_table["n_arms"] == chosen
    notes = []
    if not orders[chosen].well_posed():
        notes.append(f"the chosen {chosen}-arm fit has parameters at a bound: {orders[chosen].fit.at_bound}")
    notes.append("intervals assume independent noise; filtered (autocorrelated) records make them too narrow")
    return RelaxFit(orders, chosen, cv_table, scheme, factor, int(t.size), (float(t.min()), float(t.max())),
                    notes=notes)
