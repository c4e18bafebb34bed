"""A model against measurements: calibrate, held-out error, noise, residuals (``capsule-cli compare``).

:func:`evaluate` is the engine shared with ``diagnose``: bounded multi-start
least squares (:func:`capsule_cli.fitting.fit_least_squares`) on all rows, then
grouped K-fold cross-validation (:mod:`capsule_cli.steps.crossval`), each fold
refitted from the full-data optimum.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ..effects.model import BoundModel, Model
from ..errors import InputError
from ..fitting import DEGENERATE_CI_RATIO, FitResult, fit_least_squares, information_criteria, prediction_band
from ..tables import (DYNAMICS_KINDS, Column, TableSchema, is_synthetic, provenance, response_column,
                      staged_folder, write_json_atomic, write_table)
from ..units import split_unit, unit_label
from ..validation import check_model_output
from . import crossval
from .residual_tests import noise_estimate, numeric_covariates

N_STARTS = 6
FIT_TOL = 1e-10  # relative tolerances of each start (1e-10: far below any noise level)
FIT_NFEV_PER_PARAM = 300  # evaluation budget per start and parameter (degenerate directions stop there)


@dataclass
class Evaluation:
    """Calibration and cross-validation of one model on one table (response unit)."""

    bound: BoundModel
    theta: np.ndarray
    fit: FitResult | None
    y: np.ndarray
    pred: np.ndarray
    cv_pred: np.ndarray
    groups: np.ndarray
    folds: np.ndarray
    cv_rmse: float
    cv_rmse_se: float
    rss: float
    bic: float
    aic: float
    extras: dict = field(default_factory=dict)

    @property
    def k(self) -> int:
        return len(self.bound.free)

    @property
    def resid(self) -> np.ndarray:
        return self.y - self.pred

    @property
    def sq_err(self) -> np.ndarray:
        return (self.y - self.cv_pred) ** 2

    @property
    def rmse(self) -> float:
        return math.sqrt(self.rss / self.y.size)


def calibrate(bound: BoundModel, y: np.ndarray, rows: np.ndarray | None = None, x0=None,
              n_starts: int = N_STARTS, seed: int = 0) -> tuple[np.ndarray, FitResult | None]:
    """Return (theta, FitResult) of the bounded least-squares fit on ``rows`` (all when None)."""
    if not bound.free:
        return np.array([], float), None
    yy = y if rows is None else y[rows]
    start = bound.x0 if x0 is None else np.asarray(x0, float)
    fit = fit_least_squares(lambda th: bound.predict(th, rows), yy, start, bound.names, bound.bounds,
                            n_starts=n_starts, seed=seed, tol=FIT_TOL, max_nfev=FIT_NFEV_PER_PARAM * len(start),
                            model_rows=lambda th, idx: bound.predict(th, idx if rows is None else rows[idx]))
    return fit.values, fit


def evaluate(bound: BoundModel, folds: np.ndarray, groups: np.ndarray, x0=None, n_starts: int = N_STARTS,
             seed: int = 0) -> Evaluation:
    """Return the calibration and grouped cross-validation of ``bound`` on its table."""
    y = bound.observed()
    theta, fit = calibrate(bound, y, None, x0, n_starts, seed)
    pred = bound.predict(theta)
    if not np.all(np.isfinite(pred)):
        i = int(np.argmax(~np.isfinite(pred)))
        covs = [c for c in bound.df.columns if c != bound.response and pd.api.types.is_numeric_dtype(bound.df[c])]
        raise InputError(f"{bound.where or 'data'}: row {i + 1}: model '{bound.model.name}' gives a non-finite "
                         f"response there ({', '.join(f'{c}={bound.df[c].iloc[i]}' for c in covs)})")
    cv_pred = np.empty_like(y)
    for f in np.unique(folds):
        test = np.flatnonzero(folds == f)
        train = np.flatnonzero(folds != f)
        th, _ = calibrate(bound, y, train, theta, n_starts=1, seed=seed) if bound.free else (theta, None)
        cv_pred[test] = bound.predict(th, test)
    sq = (y - cv_pred) ** 2
    cv, se = crossval.cv_rmse(sq, groups)
    rss = float(np.sum((y - pred) ** 2))
    aic, bic = information_criteria(rss, y.size, len(bound.free))
    return Evaluation(bound, theta, fit, y, pred, cv_pred, groups, folds, cv, se, rss, bic, aic)


def data_hash(path: str | Path) -> str:
    """Return a short sha256 of a data file's bytes."""
    h = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    return h[:16]


def main_covariate(df: pd.DataFrame, kind: str) -> str:
    """Return the covariate a fit is drawn against (speed, or time for relaxation)."""
    pref = {"relaxation": "time_s"}.get(kind, "speed_mm_s")
    covs = numeric_covariates(df, response_column(kind))
    if pref in df.columns and df[pref].nunique() >= 3:
        return pref
    return max(covs, key=lambda c: df[c].nunique()) if covs else pref


def param_table(ev: Evaluation) -> dict:
    """Return ``{key: {value, stderr, ci95, at_bound, degenerate, unit, free}}`` for every model parameter.

    ci95 lies inside the parameter's bounds; ``at_bound`` marks a value that ended at a bound (the model or
    the bounds are often wrong then); ``degenerate`` one the data do not determine (see fitting.py).
    """
    vals = ev.bound.values(ev.theta)
    fitted = ev.fit.as_dict() if ev.fit is not None else {}
    out = {}
    for s in ev.bound.model.specs:
        if s.key in ev.bound.column_keys:
            out[s.key] = {"value": None, "free": False, "from_column": s.param.name, "unit": s.param.unit}
            continue
        rec = {"value": vals[s.key], "free": s.key in fitted, "unit": s.param.unit, "owner": s.owner}
        if s.key in fitted:
            rec.update({k: fitted[s.key][k] for k in ("stderr", "ci95", "at_bound", "degenerate")})
            rec["bounds"] = list(s.bounds)
        out[s.key] = rec
    return out


def fit_warnings(params: dict) -> list[str]:
    """Return one plain sentence per free parameter that ended at a bound or is degenerate."""
    out = []
    for k, p in params.items():
        if not p.get("free"):
            continue
        u = f" {p['unit']}" if p.get("unit") else ""
        if p.get("at_bound"):
            lo, hi = p.get("bounds", [None, None])
            out.append(f"{k} ended at its bound ({p['value']:.3g}{u}; bounds [{lo:g}, {hi:g}]): the model's form or "
                       "the bounds are probably wrong")
        if p.get("degenerate"):
            ci = p.get("ci95") or [float("nan"), float("nan")]
            out.append(f"{k} = {p['value']:.3g}{u} is not determined by the data (95 % interval [{ci[0]:.3g}, "
                       f"{ci[1]:.3g}] spans more than {DEGENERATE_CI_RATIO:g} x its value): a degenerate fit, not a "
                       "result")
    return out


def fit_curves(ev: Evaluation, main: str, max_combos: int = 6, n_grid: int = 120) -> pd.DataFrame:
    """Return the calibrated model (and its 95 % confidence band) along ``main`` per covariate combination.

    One curve per combination of the other covariates and labels when there are few
    (<= ``max_combos``); otherwise the band at the data rows themselves.
    """
    df = ev.bound.df
    resp = ev.bound.response
    others = [c for c in df.columns if c not in (main, resp, "trial", "run", "source", "note", "id", "label")]
    combos = df[others].drop_duplicates() if others else pd.DataFrame(index=[0])
    rows = []
    model = ev.bound.model
    if len(combos) <= max_combos:
        lo, hi = float(df[main].min()), float(df[main].max())
        grid = np.linspace(lo, hi, n_grid)
        for ci, (_, combo) in enumerate(combos.iterrows()):
            g = pd.DataFrame({main: grid})
            for c in others:
                g[c] = combo[c]
            g[resp] = 0.0
            gb = model.bind(g[[c for c in df.columns if c in g.columns]])
            gb.free = ev.bound.free
            label = ", ".join(f"{c}={combo[c]}" for c in others) if others else "model"
            rows.append(_band_frame(ev, gb, g[main].to_numpy(), label, ci))
    else:
        order = np.argsort(df[main].to_numpy(), kind="stable")
        rows.append(_band_frame(ev, ev.bound, df[main].to_numpy()[order], "at data", 0, order))
    return pd.concat(rows, ignore_index=True)


def _band_frame(ev, gb, xs, label, ci, order=None):
    def curve(th):
        v = gb.predict(th)
        return v if order is None else v[order]

    if ev.fit is not None:
        c, lo, hi = prediction_band(curve, ev.fit)
    else:
        c = curve(ev.theta)
        lo = hi = c
    return pd.DataFrame({"x": xs, "predicted": c, "lower": lo, "upper": hi, "curve": label, "curve_id": ci})


CURVE_SCHEMA = TableSchema("fit_curve", "calibrated model and its 95 % confidence band along one covariate", (
    Column("x", "float64", "covariate value (unit in the table metadata 'covariate')", unit=""),
    Column("predicted", "float64", "model response", unit=""),
    Column("lower", "float64", "95 % confidence band, lower", unit=""),
    Column("upper", "float64", "95 % confidence band, upper", unit=""),
    Column("curve", "string", "covariate combination of this curve", unit=""),
    Column("curve_id", "int64", "curve index", unit=""),
))


def residual_frame(ev: Evaluation) -> pd.DataFrame:
    """Return the data with observed, predicted, residual, held-out prediction and fold per row."""
    df = ev.bound.df.copy()
    resp = ev.bound.response
    base = split_unit(resp)[0]
    u = split_unit(resp)[1]
    df = df.rename(columns={resp: f"observed_{base}_{u}"})
    df[f"predicted_{base}_{u}"] = ev.pred
    df[f"residual_{base}_{u}"] = ev.resid
    df[f"cv_predicted_{base}_{u}"] = ev.cv_pred
    df[f"cv_residual_{base}_{u}"] = ev.y - ev.cv_pred
    df["fold"] = ev.folds.astype("int64")
    df["cv_group"] = ev.groups.astype("int64")
    return df


def residual_schema(df: pd.DataFrame) -> TableSchema:
    cols = []
    for c in df.columns:
        dt = "int64" if c in ("fold", "cv_group") else ("float64" if pd.api.types.is_numeric_dtype(df[c]) else "string")
        if c == "trial" and pd.api.types.is_integer_dtype(df[c]):
            dt = "int64"
        cols.append(Column(c, dt, {"fold": "cross-validation fold of the row",
                                   "cv_group": "group kept together in cross-validation"}.get(c, "measurement or model column")))
    return TableSchema("residuals", "model vs measurements per row (compare)", tuple(cols))


def metrics(ev: Evaluation, noise: dict, data_path: str, dhash: str, k_folds: int, group_how: str) -> dict:
    """Return the metrics record of contract section 2 (compare)."""
    y, r = ev.y, ev.resid
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    resp = ev.bound.response
    m = ev.bound.model
    return {
        "model": m.name, "model_file": m.path, "model_hash": m.hash, "kind": m.kind, "base": m.base.name,
        "effects": m.effect_names, "data": str(data_path), "data_hash": dhash,
        "response": resp, "unit": unit_label(resp),
        "n": int(y.size), "n_free": ev.k,
        "rmse": ev.rmse, "mae": float(np.mean(np.abs(r))), "bias": float(np.mean(-r)),
        "r2": (1.0 - ev.rss / ss_tot) if ss_tot > 0 else None,
        "cv_rmse": ev.cv_rmse, "cv_rmse_se": ev.cv_rmse_se,
        "cv": {"folds": int(np.unique(ev.folds).size), "requested_folds": k_folds, "groups": group_how,
               "n_groups": int(np.unique(ev.groups).size)},
        "noise_sd": noise["sd"], "noise_sd_se": noise["se"], "noise_method": noise["method"],
        "noise_reliable": bool(noise.get("reliable", True)),
        "noise_outlier_rows": [int(i) for i in noise.get("outliers", [])],
        "cv_rmse_over_noise": ev.cv_rmse / noise["sd"] if noise["sd"] and noise["sd"] > 0 else None,
        "aic": ev.aic, "bic": ev.bic,
        "params": param_table(ev),
        "fit_warnings": fit_warnings(param_table(ev)),
        "fit_converged": None if ev.fit is None else bool(ev.fit.success),
    }


def run_compare(model: Model, df: pd.DataFrame, kind: str, data_path: str, out_dir: str | Path,
                ledger: str | Path | None, k_folds: int = 5, seed: int = 0, figures: bool = True) -> dict:
    """Calibrate ``model`` on the table, cross-validate, write metrics, residuals, figures and a ledger row."""
    if kind in DYNAMICS_KINDS:  # progression, trajectory: the engine-based loop (imported only then: numba)
        from . import dynamics_loop

        return dynamics_loop.run_compare(model, df, data_path, out_dir, ledger, k_folds, seed, figures)
    from .ledger import append_ledger

    out = Path(out_dir)
    bound = model.bind(df, where=str(data_path))
    check_model_output(bound, None, "start values")  # NaN from the model: exit 2 naming the effect
    resp = bound.response
    groups, how = crossval.cv_groups(df, resp)
    crossval.require_groups(groups, how, str(data_path))
    folds = crossval.assign_folds(groups, k_folds, seed)
    ev = evaluate(bound, folds, groups, seed=seed)
    check_model_output(bound, ev.theta, "solution")
    noise = noise_estimate(df, resp, fitted=ev.pred)  # differences of the residuals (curvature removed)
    dh = data_hash(data_path)
    met = metrics(ev, noise, data_path, dh, k_folds, how)
    # derived tables are not synthetic data themselves: they record that their input was
    prov = provenance(config_hash=model.hash, seed=seed, data_synthetic=is_synthetic(df),
                      model=model.content, data=str(data_path), data_hash=dh)
    res = residual_frame(ev)
    main = main_covariate(df, kind)
    curves = fit_curves(ev, main)
    covs = numeric_covariates(df, resp)
    with staged_folder(out) as stage:  # the whole set or nothing (an interrupt while plotting leaves no table)
        write_table(res, stage / "residuals.parquet", residual_schema(res), prov)
        write_table(curves, stage / "fit_curve.parquet", CURVE_SCHEMA, {**prov, "covariate": main})
        met["figures"] = []
        if figures:
            _figures(res, curves, main, resp, stage, model, data_path, noise, covs, is_synthetic(df))
            met["figures"] = ["fit.png", "residuals.png"]
        write_json_atomic(stage / "metrics.json", met)
        if ledger is not None:
            append_ledger(ledger, met)
    return met


def _figures(res, curves, main, resp, out, model, data_path, noise, covs, synthetic=False):
    from ..plots import loop as plots

    plots.plot_fit(res, curves, main, resp, out / "fit.png", title=f"{model.name} vs {Path(data_path).name}",
                   noise_sd=noise["sd"], data_label=plots.data_label(synthetic))
    plots.plot_residuals(res, covs, resp, out / "residuals.png", noise_sd=noise["sd"],
                         title=f"{model.name}: residuals")
