"""``compare`` for dynamics data: calibrate the model, cross-validate over conditions or runs, bootstrap the
parameter intervals, and write the metrics, residuals, figure and ledger row (:func:`run_compare`).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd

from ...effects.model import Model
from ...tables import is_synthetic, provenance, staged_folder, write_json_atomic, write_table
from .. import crossval
from ..verdict import Noise
from .bound import (Budget, DynBound, MULTISTABLE_SPREAD_FRACTION, UNIT, check_start_values, choose_modes, predictable,
                    row_variance)
from .calibration import DynEvaluation, calibrate
from .noise import (check_rest_origin, detrended_by_run, noise_of, noise_rho, public_record, serial_noise,
                    trajectory_noise)
from .evaluation import (bootstrap_intervals, evaluate, held_out_record, knife_edge_records, refit_progression,
                         with_design_expectation)
from .outliers import outlier_rows
from .report import (RUN_DRIFT_Z, RUN_MISFIT_Z, _frame_words, _plot_residuals, by_class, param_table, plain_summary,
                     residual_frame, residual_schema, run_drift_records, run_drift_table, ORIGINS_MEANING,
                     origins_fitted)
from .verdicts import dynamics_covariates


def _setup(model: Model, df: pd.DataFrame, data_path: str, k_folds: int, seed: int, budget: Budget):
    check_start_values(model)
    bound = DynBound(model, df, where=str(data_path), rk_rtol=budget.rk_rtol)
    crossval.require_groups(bound.groups()[0], "", str(data_path),
                            "conditions (drives)" if bound.kind == "progression" else "runs")
    noise = noise_of(bound)
    check_rest_origin(bound)
    sigma = float(noise["sd"]) if noise["sd"] and np.isfinite(noise["sd"]) and noise["sd"] > 0 else 1.0
    if bound.kind == "trajectory":
        # first pass in position mode, then irregular runs by average velocity (the mode stays fixed)
        pre = calibrate(bound, bound.observed(), sigma, None, None, budget, seed)
        bound = DynBound(model, df, where=str(data_path), modes=choose_modes(bound, pre.theta), rk_rtol=budget.rk_rtol)
    groups, how = bound.groups()
    folds = crossval.assign_folds(groups, k_folds, seed)
    return bound, noise, sigma, groups, how, folds


def _metrics(ev: DynEvaluation, noise: dict, data_path: str, dhash: str, k_folds: int, how: str,
             budget: Budget) -> dict:
    m = ev.bound.model
    regular = predictable(ev.sim, noise["sd"])
    rec = {
        "model": m.name, "model_file": m.path, "model_hash": m.hash, "kind": m.kind, "base": m.base.name,
        "effects": m.effect_names, "data": str(data_path), "data_hash": dhash,
        "response": ev.bound.response, "unit": UNIT[m.kind], "n": int(ev.y.size), "n_free": ev.k,
        "rmse": ev.rmse, "mae": float(np.nanmean(np.abs(ev.resid))), "bias": float(np.nanmean(-ev.resid)),
        "r2": float(1 - np.nansum(ev.resid ** 2) / np.sum((ev.y - ev.y.mean()) ** 2)) if np.ptp(ev.y) > 0 else None,
        "cv_rmse": ev.cv_rmse, "cv_rmse_se": ev.cv_rmse_se,
        "cv_rmse_meaning": "held-out RMS of residuals standardised by the error model (noise and the spread of "
                           "irregular responses), in the response unit",
        "cv_rmse_plain": ev.plain_cv_rmse(), "cv_rmse_not_irregular": ev.plain_cv_rmse(regular),
        "knife_edge_runs": knife_edge_records(ev),
        "cv_rmse_not_irregular_meaning": (
            "plain held-out RMSE on the conditions whose response is neither irregular nor multistable "
            f"(its starts within {MULTISTABLE_SPREAD_FRACTION:g} noise SD)"),
        "cv": {"folds": int(np.unique(ev.folds).size), "requested_folds": k_folds, "groups": how,
               "n_groups": int(np.unique(ev.groups).size)},
        "noise_sd": noise["sd"], "noise_sd_se": noise["se"], "noise_method": noise["method"],
        "noise_reliable": bool(noise.get("reliable", True)),
        "cv_rmse_over_noise": ev.cv_rmse / noise["sd"] if noise["sd"] else None,
        "bic": ev.bic, "params": param_table(ev),
        "intervals": ev.interval_method if ev.intervals else "none (no free parameter or bootstrap off)",
        "protocol": ev.bound.protocol.__dict__,
        "by_response_class": by_class(ev),
        "calibration": {"method": "Sobol scan + bounded Nelder-Mead (derivative-free, scaled to [0, 1])",
                        "starts": ev.fit.starts, "evaluations": ev.fit.nfev, "seconds": ev.seconds},
    }
    if ev.bound.kind == "trajectory":
        rec["runs_compared_by"] = {r: mode for r, mode in ev.bound.modes.items()}
        origins = origins_fitted(ev)
        if origins:
            rec["origins_fitted_mm"], rec["origins_fitted_meaning"] = origins, ORIGINS_MEANING
    return rec


def _prov(model, seed, df, data_path, dh):
    return provenance(config_hash=model.hash, seed=seed, data_synthetic=is_synthetic(df), model=model.content,
                      data=str(data_path), data_hash=dh)


def _compare_fit(bound: DynBound, noise: dict, sigma: float, folds, groups, budget: Budget, seed: int,
                 x0=None) -> tuple[DynEvaluation, dict]:
    """Return (evaluation, revised noise) of compare's one model on ``bound`` (``x0``: a warm start).

    Without replicates the differences only bound the noise: the fit's own residual SD is the other bound,
    and the smaller is reported, as diagnose does over all its models (a trajectory's differences gave
    1.39 mm against a generating 0.2 mm, which the ledger drew as the noise level under a fit at 0.2); a
    progression fit is refined with the revised noise (refit_progression)."""
    ev = evaluate(bound, sigma, folds, groups, x0=x0, budget=budget, seed=seed)
    if bound.kind == "progression":
        noise, ev = refit_progression(noise, ev, [], budget, seed)
    else:
        noise = trajectory_noise(noise, [ev])
        if noise.get("reliable", True) and 0 < float(noise["sd"]) < sigma:
            ev = ev.with_sigma(float(noise["sd"]))
    return ev, noise


def run_compare(model: Model, df: pd.DataFrame, data_path: str, out_dir, ledger=None, k_folds: int = 5,
                seed: int = 0, figures: bool = True, budget: Budget = Budget()) -> dict:
    """Calibrate a dynamics model, cross-validate, bootstrap intervals; write metrics, residuals, ledger row."""
    from ..compare import data_hash
    from ..ledger import append_ledger

    out = Path(out_dir)
    bound, noise0, sigma, groups, how, folds = _setup(model, df, data_path, k_folds, seed, budget)
    ev, noise = _compare_fit(bound, noise0, sigma, folds, groups, budget, seed)
    if bound.kind == "trajectory":
        # held out above the noise over a few runs: is that what the model gives as the truth on them?
        ev = with_design_expectation(ev, Noise(ev.sigma, float(noise.get("se") or 0.0),
                                               bool(noise.get("reliable", True))), True, budget, seed)
    rho, corr = 0.0, None
    if bound.kind == "trajectory":
        # a video track's position noise is often correlated from frame to frame: the per-run drift rates' SEs
        # and a parametric bootstrap's noise allow for the lag-1 correlation of this model's residuals about each
        # run's drift line (serial_noise, as diagnose finds it over the models it fits; here the one model, its
        # drift taken out first, so that the misfit the rate measures is not read as correlated noise that
        # widens its own SE)
        rf = bound.row_frame()
        corr = serial_noise(rf, [ev], lambda e: detrended_by_run(
            rf, e.resid / np.sqrt(row_variance(e.sigma, e.sim))))
        rho = noise_rho(corr)
    if budget.bootstrap and bound.free:
        # the noise estimate's degrees of freedom from its standard error (se = sd / sqrt(2 dof))
        se_rel = float(noise.get("se") or 0.0) / float(noise["sd"]) if noise.get("sd") else 0.0
        ev.intervals, ev.stderr, ev.interval_method = bootstrap_intervals(
            ev, budget.bootstrap, budget, seed, rho, 0.5 / se_rel ** 2 if se_rel > 0 else math.inf)
    dh = data_hash(data_path)
    met = _metrics(ev, noise, data_path, dh, k_folds, how, budget)
    if ev.cv_expected is not None:
        met["held_out_if_true"] = held_out_record(ev)
    if bound.kind == "trajectory":
        met["residuals_correlated"] = public_record(corr)
    # in words at the noise the errors are standardised with (the revised estimate, not the first bound)
    met["where_it_fails"] = plain_summary(ev, ev.sigma, rho, bool(noise.get("reliable", True)))
    gross = compare_outliers(ev, noise0, sigma, k_folds, budget, seed)
    met["outliers"] = gross
    if gross:
        met["where_it_fails"] = (compare_outlier_words(gross, ev.cv_rmse, float(noise["sd"]), UNIT[model.kind])
                                 + ". " + met["where_it_fails"][:1].upper() + met["where_it_fails"][1:])
    if bound.kind == "trajectory":
        met["by_run"] = run_drift_records(run_drift_table(ev, ev.sigma, rho))
        met["by_run_meaning"] = (
            "per run compared by position: rate_mm_s, the least-squares slope of its position residual (measured "
            "- model) over time; rate_se_mm_s, its SE at the noise SD" + (
                f" and the residuals' lag-1 correlation from frame to frame ({rho:.3g}, AR(1); found in this model's "
                "residuals about each run's drift line, so a misfit that is not a drift widens it as correlated "
                "noise would)" if rho else
                " (white noise: no serial correlation found in the residuals about each run's drift line)")
            + f"; it drifts when the rate is {RUN_DRIFT_Z:g} SEs from zero and the frames' RMS standardised "
              f"residual is above {RUN_MISFIT_Z:g}")
    res = residual_frame(ev)
    with staged_folder(out) as stage:  # the whole set or nothing (an interrupt while plotting leaves no table)
        write_table(res, stage / "residuals.parquet", residual_schema(res), _prov(model, seed, df, data_path, dh))
        met["figures"] = []
        if figures:
            _plot_residuals(res, ev, stage / "residuals.png", f"{model.name}: residuals by condition and class",
                            rho=rho)
            met["figures"] = ["residuals.png"]
        write_json_atomic(stage / "metrics.json", met)
        if ledger is not None:
            append_ledger(ledger, met)
    return met


def compare_outliers(ev: DynEvaluation, noise: dict, sigma: float, k_folds: int, budget: Budget, seed: int
                     ) -> dict | None:
    """Return what the rows a compared model misses grossly do to its numbers, or None when there are none.

    The rows are those :func:`outlier_rows` flags with this one model tried (generalized ESD on its fit's
    standardised residuals; progression readings, trajectory frames compared by position). compare keeps them
    in every number it reports, as the ledger compares models on the same rows; with one model tried, a reading
    gone wrong and a misfit at that reading look alike (diagnose tells them apart with the candidates). The
    model is also fitted and cross-validated without them (as compare does, ``noise`` the first estimate and
    ``sigma`` its SD; warm-started; a trajectory's runs compared as before). Record: ``rows`` (the
    :func:`outlier_rows` records, rows of the table with its values), ``n`` (rows compared without them),
    ``cv_rmse``, ``cv_rmse_plain``, ``noise_sd``, ``noise_method`` of that fit. A 4-run trajectory (noise 0.1 mm,
    a viscous drag) with three frames a tracker got 2.5-4 mm wrong: the drag model compared held out at 0.336 mm
    against a noise bound of 0.304, the three frames' doing; its plain held-out error on the other frames was
    0.173 mm, as the fits with the three frames in them were pulled; refitted without them 0.099 and 0.099."""
    from ..diagnose import outlier_records

    b = ev.bound
    rf = b.row_frame()
    found = outlier_rows([ev], {c: rf[c].to_numpy(float) for c in dynamics_covariates(rf, b.response)})
    if not found:
        return None
    drop = [o["row"] for o in found]
    found = [{**o, **rec} for o, rec in zip(found, outlier_records(b.df, drop))]
    kept = DynBound(b.model, b.df.drop(index=drop).reset_index(drop=True), where=b.where,
                    modes=b.modes if b.kind == "trajectory" else None, rk_rtol=budget.rk_rtol)
    groups, _ = kept.groups()
    folds = crossval.assign_folds(groups, k_folds, seed)
    ev2, noise2 = _compare_fit(kept, noise, sigma, folds, groups, budget, seed, x0=ev.theta)
    return {"rows": found, "n": int(ev2.y.size), "cv_rmse": ev2.cv_rmse, "cv_rmse_plain": ev2.plain_cv_rmse(),
            "noise_sd": float(noise2["sd"]), "noise_method": noise2["method"]}


def compare_outlier_words(out: Mapping, cv_rmse: float, noise_sd: float, unit: str) -> str:
    """Return the sentence of compare's where_it_fails on :func:`compare_outliers` ``out``: the rows, how far off,
    and the held-out error and noise without them beside the ones reported (``cv_rmse``, ``noise_sd``)."""
    rows = out["rows"]
    zs = [o["z"] for o in rows]
    where = ", ".join(f"row {o['row']}" + (f" ({_frame_words(o)})" if _frame_words(o) else "") for o in rows)
    gathered = rows[0].get("concentrated")
    why = (f"they gather at {gathered['covariate']} = {gathered['value']:g} (p = {gathered['p']:.2g}): a misfit "
           "there more likely than independent errors" if gathered else
           "readings gone wrong, or a misfit there; diagnose leaves out the rows that no model it tries accounts "
           "for")
    without = (f"fitted without them, this model is held out at {out['cv_rmse']:.3g} {unit} against a noise of "
               f"{out['noise_sd']:.3g} {unit}")
    return (f"{len(rows)} of the rows ({where}) are {min(zs):.3g}-{max(zs):.3g} noise SDs off this model "
            f"({why}): {without}; the numbers reported keep them (held out {cv_rmse:.3g} {unit}, noise "
            f"{noise_sd:.3g} {unit})")
