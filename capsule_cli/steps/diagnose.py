"""Where a model fails and which physical effect is missing (``capsule-cli diagnose``).

Steps: calibrate and cross-validate the model as is (grouped K-fold, :mod:`.crossval`);
estimate the noise (:func:`.residual_tests.noise_estimate` on the residuals of the model
fitted to all rows: robust, outliers flagged by row and left out of the fits, serial correlation along time/position detected); refit
model + each applicable effect from data-based guesses on the same folds; test the end rows of
each covariate, which differences see from one side only, against every model tried
(:func:`edge_outliers`: a mean shift there that accounts for the data better is an outlier, and
the table is diagnosed again without it); test the residuals for structure. The verdict is decided by the pure function
:func:`capsule_cli.steps.verdict.decide_verdict` from those arrays (its rule,
:data:`~capsule_cli.steps.verdict.RULE_TEXT`, is fixed in advance and printed in every
diagnosis.md); writing tables, figures and the new model come after, from its result.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from ..effects.model import Model
from ..effects.registry import Effect, base_name, effects as all_effects, next_instance, si_factor
from ..tables import (DYNAMICS_KINDS, is_synthetic, provenance, response_column, staged_folder, write_json_atomic,
                      write_table, write_text_atomic)
from ..units import split_unit, unit_label
from ..validation import check_model_output
from . import crossval
from .compare import (CURVE_SCHEMA, Evaluation, calibrate, data_hash, evaluate, fit_curves, fit_warnings, main_covariate,
                      param_table,
                      residual_frame, residual_schema)
from .residual_tests import (correct_for_correlation, is_ordered, noise_estimate, numeric_covariates,
                             outlier_threshold, serial_correlation, structure_tests)
from .verdict import (ALPHA_EFFECT, ALPHA_STRUCTURE, RULE_TEXT, FitSummary, Noise, Verdict, aicc, collinear_groups,
                      decide_verdict)

ALPHA = ALPHA_STRUCTURE
CANDIDATE_STARTS = 3  # effects with a data-based guess
PLAIN_STARTS = 8  # effects without one (plugins): more random starts within the bounds


@dataclass
class Candidate:
    effect: Effect
    model: Model
    ev: Evaluation
    delta_cv: float
    delta_cv_se: float
    delta_bic: float
    passes: bool = False
    reason: str = ""
    p_value: float = float("nan")
    p_adjusted: float = float("nan")
    structure: list = None


def skipped_effects(model: Model, df: pd.DataFrame) -> list[dict]:
    """Return the effects of the model's kind not tried, each {effect, reason}."""
    have = set(model.effect_names)
    cols = {base_name(c) for c in df.columns}
    out = []
    for e in all_effects(model.kind):
        if e.name in have:
            continue
        if e.bases and model.base.name not in e.bases:
            out.append({"effect": e.name, "reason": f"applies to base models {', '.join(e.bases)}, not "
                                                    f"{model.base.name}"})
            continue
        miss = [c for c in e.covariates if base_name(c) not in cols]
        if miss:
            out.append({"effect": e.name, "reason": f"the table has no column {', '.join(miss)}"})
            continue
        const = [c for c in e.covariates if base_name(c) in cols
                 and df[[x for x in df.columns if base_name(x) == base_name(c)][0]].nunique() < 2]
        if const:
            out.append({"effect": e.name, "reason": f"tried, but {', '.join(const)} takes one value in the table "
                                                    "(the effect is a constant here)"})
    return out


def applicable_effects(model: Model, df: pd.DataFrame) -> list[Effect]:
    """Return the effects of the model's kind not in it whose covariates the table has; a repeatable effect
    the model already holds (``maxwell_arm``) is offered as its next instance (``maxwell_arm_2``)."""
    have = set(model.effect_names)
    out = []
    for e in all_effects(model.kind):
        if e.name in have:
            e = next_instance(model.kind, e.name, have) if e.repeatable else None
            if e is None:
                continue
        if e.applicable(df.columns, model.base.name):
            out.append(e)
    return out


def _guess_values(eff: Effect, ev: Evaluation) -> dict[str, float]:
    """Return data-based start values (declared units) of an effect from the model's residual."""
    out = {}
    if eff.guess is None:
        return out
    b = ev.bound
    unit = si_factor(b.response)
    ctx = {**b.context(ev.theta), "y0": b.predict_si(ev.theta)}
    try:
        g = eff.guess(ev.resid * unit, b.x, ctx) or {}
    except Exception:  # noqa: BLE001  (a failed guess falls back to the declared start)
        return out
    for prm in eff.params:
        if prm.key in g and np.isfinite(g[prm.key]):
            lo, hi = prm.bounds
            v = float(g[prm.key]) / si_factor(prm.name)
            span = hi - lo if np.isfinite(hi - lo) else abs(v) + 1.0
            out[prm.name] = float(np.clip(v, lo + 1e-9 * span, hi - 1e-9 * span))
    return out


def fit_candidate(model: Model, eff: Effect, df: pd.DataFrame, base: Evaluation, seed: int) -> Candidate | None:
    """Return the calibrated and cross-validated model + ``eff`` (None when too few data)."""
    vals = base.bound.values(base.theta)
    m2 = model.with_values(vals).with_effect(eff, _guess_values(eff, base))
    b2 = m2.bind(df)
    if len(b2.free) > b2.n - 2:
        return None
    starts = CANDIDATE_STARTS if eff.guess is not None else PLAIN_STARTS
    ev = evaluate(b2, base.folds, base.groups, x0=b2.x0, n_starts=starts, seed=seed)
    if ev.rss > base.rss * (1 + 1e-9) and base.fit is not None:
        # the nested model can always do as well as the base: retry from the effect's off values
        off = {p.name: p.off for p in eff.params}
        m3 = model.with_values(vals).with_effect(eff, off)
        b3 = m3.bind(df)
        ev3 = evaluate(b3, base.folds, base.groups, x0=b3.x0, n_starts=1, seed=seed)
        if ev3.rss < ev.rss:
            m2, ev = m3, ev3
    d, se = crossval.paired_difference(base.sq_err, ev.sq_err, base.groups)
    return Candidate(eff, m2, ev, d, se, ev.bic - base.bic)


def summary(ev: Evaluation, name: str = "", covariates=(), structure=None, nests=()) -> FitSummary:
    """Return the arrays :func:`decide_verdict` needs from one evaluation (``nests``: the effect's
    :attr:`~capsule_cli.effects.registry.Effect.nests`)."""
    return FitSummary(name, len(ev.bound.free), ev.rss, ev.pred, ev.sq_err, tuple(covariates), structure or [],
                      nests=tuple(nests))


def fit_pair(model: Model, a: Candidate, b: Candidate, df: pd.DataFrame, base: Evaluation, seed: int
             ) -> Evaluation | None:
    """Return the calibrated and cross-validated model + both candidates' effects, started from each one's own
    fit (None when too few data)."""
    m2 = a.model.with_values(a.ev.bound.values(a.ev.theta))
    vb = b.ev.bound.values(b.ev.theta)
    m2 = m2.with_effect(b.effect, {s.param.name: vb[s.key] for s in b.model.specs if s.owner == b.effect.name})
    b2 = m2.bind(df)
    if len(b2.free) > b2.n - 2:
        return None
    return evaluate(b2, base.folds, base.groups, x0=b2.x0, n_starts=CANDIDATE_STARTS, seed=seed)


def pair_summaries(model: Model, cands: list[Candidate], cov: str, df: pd.DataFrame, base: Evaluation,
                   seed: int) -> list[FitSummary]:
    """Return the fits of every pair of candidates that both depend on ``cov`` (two effects at once)."""
    on = [c for c in cands if base_name(cov) in {base_name(e) for e in c.effect.covariates}]
    out = []
    for i, a in enumerate(on):
        for b in on[i + 1:]:
            ev = fit_pair(model, a, b, df, base, seed)
            if ev is not None:
                out.append(FitSummary(f"{a.effect.name}+{b.effect.name}", len(ev.bound.free), ev.rss, ev.pred,
                                      ev.sq_err, (cov,), members=(a.effect.name, b.effect.name)))
    return out


#: a covariate's first and last rows are tested by :func:`edge_outliers` when it has at least this many distinct
#: values (fewer: a grid's levels, where the differences' test runs along the other covariates)
EDGE_MIN_LEVELS = 5


def edge_rows(df: pd.DataFrame, covs: list[str]) -> list[int]:
    """Return the positions of the rows at the smallest and largest value of each covariate with at least
    EDGE_MIN_LEVELS distinct values, where that value is held by one row (a replicated end is checked by the
    replicate test): the rows that the differences' outlier test sees from one side only."""
    out = set()
    for c in covs:
        x = df[c].to_numpy(float)
        if np.unique(x).size < EDGE_MIN_LEVELS:
            continue
        for v in (x.min(), x.max()):
            at = np.flatnonzero(x == v)
            if at.size == 1:
                out.add(int(at[0]))
    return sorted(out)


def edge_outliers(base: Evaluation, cands: list[Candidate], rows: list[int], seed: int) -> list[dict]:
    """Return {row, t, threshold, model} of the end ``rows`` that no model tried explains (positions in the
    fitted table).

    Gasser's differences see an end row from one side only: a gross error there moves its matched-filter
    statistic by 0.41 of its size, and one of 8-10 noise SDs at the last of 20 speeds went unflagged, inflated
    the noise to 1.5 SDs and turned a hidden viscous term into "not built in" or "nothing is missing" in 5 of 6
    data sets. Here each model tried (the model as is and every candidate, as fitted to all rows) is refitted
    without the row (warm, from its fit): that is the model plus a mean shift at the row, whose F statistic is
    the row's externally studentised residual squared, t^2 = (RSS - RSS_(i)) / (RSS_(i) / (n - 1 - k)) (Cook &
    Weisberg 1982, Residuals and Influence in Regression, section 2.2.2; for a linear model the usual
    e_i^2 / (s_(i)^2 (1 - h_ii)), exact here without linearising). The row is an outlier when a model with the
    shift has the lowest AICc of all these fits, with and without shifts, and its t exceeds Student's t at
    n - 1 - k degrees of freedom, Bonferroni over the table's n rows at the outlier family alpha
    (:func:`outlier_threshold`). A real effect that a candidate describes is a better account than a shift,
    even when one row carries most of its evidence (a third Maxwell arm of 0.5 s seen mostly at t = 0: the
    two-arm model without that row is an outlier account of it; the three-arm fit of all rows has the lower
    AICc), and a flexible candidate that bends to reach a gross error (a power law's exponent for the last
    speed) is not taken for an effect when the model plus a shift accounts for the data better.
    """
    y = base.y
    n = y.size
    fits = [(e.bound, e.theta, e.rss, name) for e, name in [(base, None)] + [(c.ev, c.effect.name) for c in cands]
            if n - 1 - len(e.bound.free) >= 3 and np.isfinite(e.rss)]
    if not fits:
        return []
    plain = min(aicc(rss, n, len(bound.free)) for bound, _, rss, _ in fits)
    out = []
    for i in rows:
        keep = np.delete(np.arange(n), i)
        best = None
        for bound, th0, rss, name in fits:
            k = len(bound.free)
            th = calibrate(bound, y, keep, th0, n_starts=1, seed=seed)[0] if k else th0
            r = y[keep] - bound.predict(th, keep)
            rss_i = float(r @ r)
            a = aicc(rss_i, n, k + 1)  # the model + a mean shift at row i, on all n rows
            if rss_i > 0 and (best is None or a < best[0]):
                best = (a, rss, rss_i, k, name)
        if best is None or best[0] >= plain:
            continue  # a model without a shift at the row accounts for the data best
        _, rss, rss_i, k, name = best
        dof = n - 1 - k
        t = math.sqrt(max(rss - rss_i, 0.0) / (rss_i / dof))
        thr = outlier_threshold(n, dof=dof)
        if t > thr:
            out.append({"row": int(i), "t": t, "threshold": thr, "model": name or "the model as is"})
    return out


def compute_verdict(df: pd.DataFrame, resp: str, base: Evaluation, cands: list[Candidate], noise: dict,
                    covs: list[str], struct: list[dict], groups: np.ndarray, folds: np.ndarray,
                    pairs: list[FitSummary] = ()) -> Verdict:
    """Return the verdict from the evaluations (no files): structure of each candidate's residuals, then
    :func:`decide_verdict`."""
    sums = []
    for c in cands:
        if c.structure is None:
            c.structure = structure_tests(df, c.ev.resid, covs, correlation=noise.get("correlated"))
        own = [x for x in covs if base_name(x) in {base_name(e) for e in c.effect.covariates}]
        sm = summary(c.ev, c.effect.name, own, c.structure, c.effect.nests)
        sm.at_bound = tuple(k for k, p in param_table(c.ev).items()
                            if p.get("owner") == c.effect.name and p.get("at_bound"))
        sums.append(sm)
    nz = Noise(noise["sd"], noise["se"], noise.get("reliable", True), noise["method"], noise.get("correlated"))
    return decide_verdict(base.y, summary(base), sums, nz, {c: df[c].to_numpy(float) for c in covs}, struct,
                          groups, int(np.unique(folds).size), ordered=[c for c in covs if is_ordered(c)],
                          unit=unit_label(resp), response=split_unit(resp)[0], pairs=pairs)


def _fmt(v: float, unit: str = "") -> str:
    if v is None or not np.isfinite(v):
        return "n/a"
    s = f"{v:.3g}"
    return f"{s} {unit}".strip()


@dataclass
class Diagnosis:
    """What :func:`diagnose_table` found (no files written): the JSON record and the evaluations behind it."""

    result: dict
    base: Evaluation
    cands: list[Candidate]
    winner: Candidate | None
    winner_named: bool
    covs: list[str]
    df: pd.DataFrame  # the rows used (outliers left out)


def outlier_records(df: pd.DataFrame, rows) -> list[dict]:
    """Return one record per flagged row: its 0-based position in ``df`` and its values."""
    return [{"row": int(i), **{c: (float(df.iloc[i][c]) if pd.api.types.is_numeric_dtype(df[c])
                                   else str(df.iloc[i][c])) for c in df.columns}} for i in rows]


def diagnose_table(model: Model, df: pd.DataFrame, kind: str, where: str = "", k_folds: int = 5, seed: int = 0,
                   quiet: bool = True, edge_check: bool = True) -> Diagnosis:
    """Fit the model and every applicable candidate, test the residuals and decide the verdict; no files.

    edge_check: end rows of the covariates for which a mean shift accounts for the data better than every model
    tried (:func:`edge_outliers`) are flagged too, and the table is diagnosed again without them (once)."""
    from ..progress import track

    resp = response_column(kind)
    unit = unit_label(resp)
    df_all = df
    bound = model.bind(df, where=str(where))
    check_model_output(bound, None, "start values")  # validation layer: NaN names the effect (exit 2)
    crossval.require_groups(*crossval.cv_groups(df, resp), str(where))
    # the noise (and outliers) from the differences of the residuals of the model fitted to all rows
    theta_all, _ = calibrate(bound, bound.observed(), seed=seed)
    noise = noise_estimate(df, resp, fitted=bound.predict(theta_all))
    outliers = list(noise.get("outliers", []))
    if outliers:  # flagged rows are reported and left out of every fit
        df = df.drop(index=df.index[outliers]).reset_index(drop=True)
        bound = model.bind(df, where=str(where))
    groups, how = crossval.cv_groups(df, resp)
    folds = crossval.assign_folds(groups, k_folds, seed)
    base = evaluate(bound, folds, groups, seed=seed)
    check_model_output(bound, base.theta, "solution")
    covs = numeric_covariates(df, resp)

    cands: list[Candidate] = []
    skipped = skipped_effects(model, df)
    for eff in track(applicable_effects(model, df), "trying candidate effects", quiet=quiet):
        c = fit_candidate(model, eff, df, base, seed)
        if c is None:
            skipped.append({"effect": eff.name, "reason": f"needs more free parameters than {base.y.size} points "
                                                          "allow (at least 2 residual degrees of freedom)"})
        else:
            cands.append(c)
    if edge_check:
        edge = edge_outliers(base, cands, edge_rows(df, covs), seed)
        if edge:
            kept = np.delete(np.arange(len(df_all)), outliers)  # positions in df_all of the fitted rows
            ends = sorted(int(kept[e["row"]]) for e in edge)
            drop = sorted(set(outliers) | set(ends))  # the rows flagged so far stay flagged
            rest = np.delete(np.arange(len(df_all)), drop)
            dg = diagnose_table(model, df_all.drop(index=df_all.index[drop]).reset_index(drop=True), kind, where,
                                k_folds, seed, quiet, edge_check=False)
            r = dg.result
            rows = sorted([int(rest[o["row"]]) for o in r["outliers"]] + drop)
            r["outliers"] = outlier_records(df_all, rows)
            for o in r["outliers"]:
                o["test"] = "end row" if o["row"] in ends else "differences or replicates"
            r["n_rows"] = int(len(df_all))
            r["noise"]["method"] += "; " + "; ".join(
                f"end row {int(kept[e['row']])} left out (a mean shift there accounts for the data better than every "
                f"model tried; externally studentised residual {e['t']:.3g} under {e['model']}, threshold "
                f"{e['threshold']:.3g})" for e in edge)
            return dg
    flexible = min([base] + [c.ev for c in cands], key=lambda e: e.rss)
    corr = serial_correlation(df, flexible.resid, covs)
    noise = correct_for_correlation(noise, corr)
    sigma = noise["sd"]
    struct = structure_tests(df, base.resid, covs, correlation=noise.get("correlated"))
    cands.sort(key=lambda c: c.ev.cv_rmse)
    vres = compute_verdict(df, resp, base, cands, noise, covs, struct, groups, folds)
    pairs: list[FitSummary] = []
    if vres.outcome == "not_built_in" and vres.covariate and len(cands) >= 2:
        # no single effect explains the dependence on a covariate: two built-in effects at once?
        pairs = pair_summaries(model, cands, vres.covariate, df, base, seed)
        if pairs:
            vres = compute_verdict(df, resp, base, cands, noise, covs, struct, groups, folds, pairs)
    verdict = vres.as_dict()
    verdict["period_unit"] = unit_label(vres.covariate) if vres.period else None
    tests = {t.name: t for t in vres.tests}
    for c in cands:
        t = tests[c.effect.name]
        c.passes, c.reason = t.supported, t.reason
        c.p_value, c.p_adjusted = t.p_value, t.p_adjusted
    winner_named = vres.missing_effect is not None
    winner = next((c for c in cands if c.effect.name == vres.missing_effect), None)
    left = vres.structure_used if winner is not None else []
    warn = fit_warnings(param_table(winner.ev if winner is not None else base))
    if warn:
        verdict["message"] += ". Fit warnings: " + "; ".join(warn)
    verdict["fit_warnings"] = warn

    def cand_rec(c: Candidate) -> dict:
        pt = param_table(c.ev)
        return {"effect": c.effect.name, "origin": c.effect.origin, "cv_rmse": c.ev.cv_rmse,
                "cv_rmse_se": c.ev.cv_rmse_se, "delta_cv_rmse": -c.delta_cv, "delta_cv_rmse_se": c.delta_cv_se,
                "delta_bic": c.delta_bic, "rmse": c.ev.rmse, "n_free": len(c.ev.bound.free),
                "passes": c.passes, "reason": c.reason, "f_test_p": c.p_value, "f_test_p_adjusted": c.p_adjusted,
                "params": {k: v for k, v in pt.items() if v.get("owner") == c.effect.name},
                "base_params": {k: v for k, v in pt.items() if v.get("owner") == "base" and v.get("free")}}

    result = {
        "model": model.name, "model_file": model.path, "model_hash": model.hash, "kind": kind,
        "base": model.base.name, "effects": model.effect_names, "data": str(where), "data_hash": None,
        "n": int(base.y.size), "n_rows": int(len(df_all)), "unit": unit,
        "noise": {"sd": sigma, "se": noise["se"], "method": noise["method"], "reliable": noise.get("reliable", True),
                  "correlated": ({k: v for k, v in noise["correlated"].items() if not k.startswith("_")}
                                 if noise.get("correlated") else None)},
        "outliers": outlier_records(df_all, outliers),
        "collinear_covariates": collinear_groups({c: df[c].to_numpy(float) for c in covs}),
        "model_as_is": {"cv_rmse": base.cv_rmse, "cv_rmse_se": base.cv_rmse_se, "rmse": base.rmse, "bic": base.bic,
                        "n_free": base.k, "params": param_table(base)},
        "cv": {"folds": int(np.unique(folds).size), "groups": how},
        "candidates": [cand_rec(c) for c in cands],
        "skipped_candidates": skipped,
        "residual_structure": struct,
        "residual_structure_after_winner": left if winner is not None else [],
        "pairs_tried": [{"effects": list(p.members), "cv_rmse": p.cv_rmse, "n_free": p.n_free,
                         **({"f_test_p": t.p_value, "f_test_p_adjusted": t.p_adjusted, "passes": t.supported,
                             "reason": t.reason} if (t := tests.get(p.name)) else {})} for p in pairs],
        "verdict": verdict,
        "rule": RULE_TEXT, "alpha_effect": ALPHA_EFFECT, "alpha_structure": ALPHA_STRUCTURE,
    }
    return Diagnosis(result, base, cands, winner, winner_named, covs, df)


def run_diagnose(model: Model, df: pd.DataFrame, kind: str, data_path: str, out_dir: str | Path,
                 write_model: str | Path | None = None, k_folds: int = 5, seed: int = 0,
                 add_best: bool = False, quiet: bool = True, figures: bool = True) -> dict:
    """Diagnose ``model`` against the table; write diagnosis.json/.md, figures and optionally the new model."""
    if kind in DYNAMICS_KINDS:  # progression, trajectory: the engine-based loop (imported only then: numba)
        from . import dynamics_loop

        return dynamics_loop.run_diagnose(model, df, data_path, out_dir, write_model, k_folds, seed,
                                          add_best=add_best, quiet=quiet, figures=figures)
    dg = diagnose_table(model, df, kind, str(data_path), k_folds, seed, quiet)
    result, base, cands, winner, winner_named, covs, df = (dg.result, dg.base, dg.cands, dg.winner,
                                                            dg.winner_named, dg.covs, dg.df)
    resp = response_column(kind)
    unit = unit_label(resp)
    sigma = result["noise"]["sd"]
    verdict = result["verdict"]
    dh = data_hash(data_path)
    result["data_hash"] = dh
    result["data_synthetic"] = bool(is_synthetic(df))
    out = Path(out_dir)
    # tables and figures
    prov = provenance(config_hash=model.hash, seed=seed, data_synthetic=is_synthetic(df), model=model.content,
                      data=str(data_path), data_hash=dh)
    with staged_folder(out) as stage:  # the whole set or nothing (an interrupt while plotting leaves no table)
        res = residual_frame(base)
        write_table(res, stage / "residuals.parquet", residual_schema(res), prov)
        figs = []
        if figures:
            from ..plots import loop as plots

            plots.plot_residuals(res, covs, resp, stage / "residuals.png", noise_sd=sigma,
                                 title=f"{model.name}: residuals against each covariate")
            figs.append("residuals.png")
        if cands and figures:
            ct = pd.DataFrame({"effect": [c.effect.name for c in cands], "cv_rmse": [c.ev.cv_rmse for c in cands],
                               "cv_rmse_se": [c.ev.cv_rmse_se for c in cands]})
            plots.plot_candidates(ct, base.cv_rmse, base.cv_rmse_se, sigma, unit, stage / "candidates.png",
                                  winner=winner.effect.name if winner_named else None)
            figs.append("candidates.png")
            shown = winner if winner is not None else cands[0]
            main = next((c for c in covs if base_name(c) in {base_name(x) for x in shown.effect.covariates}
                         and df[c].nunique() >= 3), main_covariate(df, kind))
            cres = residual_frame(shown.ev)
            curves = fit_curves(shown.ev, main)
            bcurves = fit_curves(base, main)
            write_table(curves, stage / "best_candidate_curve.parquet", CURVE_SCHEMA, {**prov, "covariate": main})
            plots.plot_fit(cres, curves, main, resp, stage / "best_candidate.png",
                           title=f"{model.name} + {shown.effect.name}", extra=bcurves,
                           data_label=plots.data_label(is_synthetic(df)),
                           extra_label=f"{model.name} (as is)",
                           outliers=pd.DataFrame(result["outliers"]) if result["outliers"] else None)
            figs.append("best_candidate.png")
        result["figures"] = figs

        new_model_path = None
        if write_model is not None:
            chosen = winner if winner_named else (cands[0] if (add_best and cands) else None)
            new_model_path = _write_model(model, chosen, Path(write_model), data_path, verdict, winner_named)
            result["written_model"] = str(new_model_path)
        write_json_atomic(stage / "diagnosis.json", result)
        write_text_atomic(stage / "diagnosis.md", diagnosis_markdown(
            result, cands, base, winner if winner_named else None, new_model_path))
    return result


def _write_model(model: Model, chosen: Candidate | None, path: Path, data_path, verdict: dict,
                 named: bool) -> Path:
    """Write the model file with the chosen effect appended (fitted values as free starts)."""
    if chosen is None:
        doc = model.to_yaml_dict(name=model.name, notes="diagnose named no missing effect; model unchanged")
        header = (f"# written by capsule-cli diagnose from {model.path} on {data_path}\n"
                  f"# verdict: {verdict['message']}\n# nothing was added.\n")
    else:
        vals = chosen.ev.bound.values(chosen.ev.theta)
        new_name = f"{model.name}+{chosen.effect.name}"
        how = "the verdict's missing effect" if named else "the best-ranked candidate (NOT named by the verdict)"
        doc = chosen.model.to_yaml_dict(values=vals, name=new_name,
                                        notes=f"{chosen.effect.name} added by diagnose ({how}) on {data_path}")
        header = (f"# written by capsule-cli diagnose from {model.path} on {data_path}\n"
                  f"# added: {chosen.effect.name} ({how}); calibrated values as free start values\n")
    text = header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=110)
    write_text_atomic(path, text)
    return path


def diagnosis_markdown(r: dict, cands: list[Candidate], base: Evaluation, winner: Candidate | None,
                       new_model: Path | None) -> str:
    """Return diagnosis.md: the verdict and its evidence in plain words."""
    u = r["unit"]
    v = r["verdict"]
    lines = [f"# Diagnosis: {r['model']} on {Path(r['data']).name}", ""]
    lines += ["What this is: `capsule-cli diagnose` compared the model with the measurements, fitted every "
              "applicable effect not yet in the model, tested the residuals and applied the rule printed at the "
              "end. Every number below comes from `diagnosis.json` beside this file"
              + (" (the data are synthetic: made by `capsule-cli synth`)." if r.get("data_synthetic") else "."), ""]
    lines += [f"**Verdict.** {v['message'][0].upper() + v['message'][1:]}.", ""]
    lines += [f"- Data: {r['n']} measurements ({r['data']}); held-out error by {r['cv']['folds']}-fold "
              f"cross-validation with groups {r['cv']['groups']}.",
              f"- Noise: {_fmt(r['noise']['sd'], u)} ± {_fmt(r['noise']['se'], u)} ({r['noise']['method']}).",
              f"- The model as is ({r['base']}" + (f" + {', '.join(r['effects'])}" if r['effects'] else "")
              + f", {r['model_as_is']['n_free']} free parameters): held-out RMSE "
              f"{_fmt(r['model_as_is']['cv_rmse'], u)} ± {_fmt(r['model_as_is']['cv_rmse_se'])}, in-sample "
              f"{_fmt(r['model_as_is']['rmse'], u)}.", ""]
    if r.get("outliers"):
        lines += [f"- Outliers (more than the rule's threshold of robust noise SDs from their neighbours or "
                  f"replicates, or an end row a mean shift accounts for better than every model tried), left out of every "
                  f"fit: rows {', '.join(str(o['row']) for o in r['outliers'])} "
                  "(0-based data rows).", ""]
    if r.get("collinear_covariates"):
        lines += ["- Collinear covariates (the data cannot separate their effects): "
                  + "; ".join(" and ".join(g) for g in r["collinear_covariates"]) + ".", ""]
    lines += ["## What the residuals show", ""]
    sig = [s for s in r["residual_structure"] if s["p_adjusted"] < ALPHA]
    if not sig:
        lines.append(f"No significant structure against any covariate (family alpha {ALPHA:g}, Bonferroni over "
                     f"{len(r['residual_structure'])} tests).")
    for s in sig:
        extra = f", period {_fmt(s['periodic_period'], unit_label(s['covariate']))}" if s["periodic_period"] else ""
        lines.append(f"- against {s['covariate']}: {s['test']} (statistic {s['statistic']:.3g}, p = "
                     f"{s['p_value']:.2g}{extra})" + (" -- also produced by the serially correlated noise alone"
                                                      if s.get("serial") else ""))
    lines += ["", "## Candidate effects, best first", "",
              f"| effect | held-out RMSE [{u}] | change vs model [{u}] | F test p | dBIC | free params | verdict rule |",
              "| --- | --- | --- | --- | --- | --- | --- |"]
    for c in cands:
        lines.append(f"| {c.effect.name} | {_fmt(c.ev.cv_rmse)} ± {_fmt(c.ev.cv_rmse_se)} | "
                     f"{_fmt(-c.delta_cv)} ± {_fmt(c.delta_cv_se)} | {c.p_value:.2g} | {c.delta_bic:.1f} | "
                     f"{len(c.ev.bound.free)} | "
                     f"{c.reason} |")
    if not cands:
        lines.append("| (no applicable candidate: the table lacks the covariates they need) | | | | | | |")
    if r.get("pairs_tried"):
        lines += ["", "Pairs of effects fitted together (no single effect explained the dependence on "
                  f"{r['verdict'].get('covariate') or 'a covariate'}):", "",
                  f"| effects | held-out RMSE [{u}] | F test p | verdict rule |", "| --- | --- | --- | --- |"]
        lines += [f"| {' + '.join(p['effects'])} | {_fmt(p['cv_rmse'])} | {_fmt(p.get('f_test_p', float('nan')))} | "
                  f"{p.get('reason', '')} |" for p in r["pairs_tried"]]
    if r.get("skipped_candidates"):
        lines += ["", "Not tried (or constant here):", ""]
        lines += [f"- {k['effect']}: {k['reason']}" for k in r["skipped_candidates"]]
    if winner is not None:
        lines += ["", f"## {winner.effect.name}", "", winner.effect.description, "",
                  f"Source: {winner.effect.source}.", "", "Fitted parameters (95 % intervals):", ""]
        for k, p in param_table(winner.ev).items():
            if p.get("owner") == winner.effect.name or p.get("free"):
                ci = p.get("ci95")
                ci_txt = f" [{_fmt(ci[0])}, {_fmt(ci[1])}]" if ci else " (fixed)"
                ci_txt += " -- AT ITS BOUND" if p.get("at_bound") else ""
                ci_txt += " -- DEGENERATE (not determined by the data)" if p.get("degenerate") else ""
                lines.append(f"- {k} = {_fmt(p['value'])} {p.get('unit', '')}{ci_txt}")
        if r.get("residual_structure_after_winner"):
            s = r["residual_structure_after_winner"][0]
            lines += ["", f"After adding it, structure remains against {s['covariate']} ({s['test']}, "
                          f"p = {s['p_value']:.2g}): another effect may be missing."]
    lines += ["", "## Next step", ""]
    if new_model is not None:
        lines.append(f"`capsule-cli compare --model {new_model} --data {r['data']} --out DIR` to confirm the "
                     "held-out error falls to the noise level.")
    elif v["missing_effect"]:
        lines.append("Rerun with `--write-model NEW.yaml` to get the model with the effect added.")
    elif v["covariate"]:
        lines.append(f"Write a plugin effect that depends on {v['covariate']} (see `capsule-cli effects list --help`),"
                     " then `capsule-cli diagnose --plugins FILE.py ...` again.")
    else:
        lines.append("None: keep the model.")
    lines += ["", "## The rule (fixed before looking at the data)", "", RULE_TEXT, ""]
    return "\n".join(lines)
