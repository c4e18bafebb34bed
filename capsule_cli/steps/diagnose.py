"""Where a model fails and which physical effect is missing (``capsule-cli diagnose``).

The rule, fixed in advance (also written into every diagnosis.md):

1. Calibrate and cross-validate the model as is (grouped K-fold, :mod:`.crossval`);
   estimate the noise SD sigma (:func:`.residual_tests.noise_estimate`).
2. For every applicable effect not in the model (its covariates are in the table,
   its base fits) refit model + effect, starting from data-based guesses, and
   cross-validate on the same folds. Record the held-out RMSE, the paired
   difference to the model with its standard error SE_d, and dBIC.
3. A candidate *passes* when (a) its held-out RMSE improves on the model's by more
   than max(2 SE_d, 0.05 sigma), (b) dBIC < -10 (very strong evidence, Kass &
   Raftery 1995), and (c) the model's held-out RMSE exceeds sigma (skipped when
   too few data allow no noise estimate; then "nothing is missing" is not claimed).
4. Of the passing candidates the best (lowest held-out RMSE) is taken, unless a
   simpler one (fewer free parameters) is within one paired SE of it: then the
   simpler one.
5. The winner's residuals are tested for structure (trend, lack of fit, runs,
   periodogram; Bonferroni over all covariates and tests, family alpha = 0.01).
   Structure left against one of the winner's own covariates means its form does
   not fit what is missing: verdict ``missing_effect: null`` with that covariate
   (and the period, for time or position) -- "write a plugin". Structure against
   another covariate is reported with the winner (a second effect may be missing).
6. No candidate passes: if the model's residuals show structure against some
   covariate (same tests and alpha), the verdict names the covariate (and the
   period for time/position): an effect that is not built in depends on it.
   Otherwise: nothing is missing.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from ..effects.model import Model
from ..effects.registry import Effect, base_name, effects as all_effects, si_factor
from ..tables import (is_synthetic, provenance, response_column, write_json_atomic, write_table,
                      write_text_atomic)
from ..units import split_unit, unit_label
from . import crossval
from .compare import (CURVE_SCHEMA, Evaluation, data_hash, evaluate, fit_curves, main_covariate, param_table,
                      residual_frame, residual_schema)
from .residual_tests import is_ordered, noise_estimate, numeric_covariates, structure_tests

ALPHA = 0.01
BIC_THRESHOLD = -10.0
MIN_GAIN_NOISE_FRACTION = 0.05
SE_MULTIPLE = 2.0
CANDIDATE_STARTS = 3  # effects with a data-based guess
PLAIN_STARTS = 8  # effects without one (plugins): more random starts within the bounds

RULE_TEXT = (
    "A candidate effect is named only if (a) it lowers the held-out RMSE by more than "
    f"max({SE_MULTIPLE:g} x the standard error of the paired difference, {MIN_GAIN_NOISE_FRACTION:g} x the noise SD), "
    f"(b) it lowers BIC by more than {-BIC_THRESHOLD:g}, and (c) the model's held-out RMSE exceeds the noise SD. "
    "Among passing candidates a simpler one (fewer free parameters) within one paired standard error of the best "
    "is preferred. If the winner leaves significant residual structure against one of its own covariates, its form "
    "does not fit and no effect is named; the covariate is. With no passing candidate, residual structure "
    f"(trend, lack of fit, runs, periodogram; Bonferroni over covariates and tests, family alpha = {ALPHA:g}) "
    "names the covariate an effect that is not built in depends on; otherwise nothing is missing.")


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


def applicable_effects(model: Model, df: pd.DataFrame) -> list[Effect]:
    """Return the effects of the model's kind not in it whose covariates the table has."""
    have = set(model.effect_names)
    return [e for e in all_effects(model.kind) if e.name not in have and e.applicable(df.columns, model.base.name)]


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


def _significant(struct: list[dict]) -> list[dict]:
    return sorted([s for s in struct if s["p_adjusted"] < ALPHA], key=lambda s: s["p_value"])


def _period_of(struct: list[dict], cov: str) -> float | None:
    for s in struct:
        if s["covariate"] == cov and s["test"] == "periodogram" and s["p_adjusted"] < ALPHA:
            return float(s["periodic_period"])
    return None


def _fmt(v: float, unit: str = "") -> str:
    if v is None or not np.isfinite(v):
        return "n/a"
    s = f"{v:.3g}"
    return f"{s} {unit}".strip()


def _direction(df, cov, resid) -> str:
    from scipy import stats

    x = df[cov].to_numpy(float)
    if np.unique(x).size < 3:
        return "depends on"
    rho = stats.spearmanr(x, resid)[0]
    if rho > 0.3:
        return "rises with"
    if rho < -0.3:
        return "falls with"
    return "varies with"


def run_diagnose(model: Model, df: pd.DataFrame, kind: str, data_path: str, out_dir: str | Path,
                 write_model: str | Path | None = None, k_folds: int = 5, seed: int = 0,
                 add_best: bool = False, quiet: bool = True, figures: bool = True) -> dict:
    """Diagnose ``model`` against the table; write diagnosis.json/.md, figures and optionally the new model."""
    from . import dynamics_loop

    if dynamics_loop.is_dynamics(kind):  # progression, trajectory: the engine-based loop
        return dynamics_loop.run_diagnose(model, df, data_path, out_dir, write_model, k_folds, seed,
                                          add_best=add_best, quiet=quiet, figures=figures)
    from ..plots import loop as plots
    from ..progress import track

    out = Path(out_dir)
    resp = response_column(kind)
    unit = unit_label(resp)
    rbase = split_unit(resp)[0]
    bound = model.bind(df, where=str(data_path))
    groups, how = crossval.cv_groups(df, resp)
    folds = crossval.assign_folds(groups, k_folds, seed)
    base = evaluate(bound, folds, groups, seed=seed)
    noise = noise_estimate(df, resp)
    sigma = noise["sd"]
    noise_txt = (f"noise is {_fmt(sigma, unit)}" if noise.get("reliable", True)
                 else "the noise level cannot be estimated from so few points: treat this as a hint")
    covs = numeric_covariates(df, resp)
    struct = structure_tests(df, base.resid, covs)

    cands: list[Candidate] = []
    skipped = []
    for eff in track(applicable_effects(model, df), "trying candidate effects", quiet=quiet):
        c = fit_candidate(model, eff, df, base, seed)
        if c is None:
            skipped.append(eff.name)
        else:
            cands.append(c)
    cands.sort(key=lambda c: c.ev.cv_rmse)
    for c in cands:
        need = max(SE_MULTIPLE * (c.delta_cv_se if np.isfinite(c.delta_cv_se) else np.inf),
                   MIN_GAIN_NOISE_FRACTION * sigma)
        why = []
        if not c.delta_cv > need:
            why.append(f"held-out gain {_fmt(c.delta_cv)} <= {_fmt(need)}")
        if not c.delta_bic < BIC_THRESHOLD:
            why.append(f"dBIC {c.delta_bic:.1f} >= {BIC_THRESHOLD:g}")
        if noise.get("reliable", True) and not base.cv_rmse > sigma:
            why.append("the model's held-out RMSE is already at the noise level")
        c.passes = not why
        c.reason = "passes" if c.passes else "; ".join(why)

    passing = [c for c in cands if c.passes]
    winner = None
    if passing:
        best = passing[0]
        near = [c for c in passing
                if c is best or c.ev.cv_rmse - best.ev.cv_rmse
                <= crossval.paired_difference(c.ev.sq_err, best.ev.sq_err, groups)[1]]
        winner = min(near, key=lambda c: (len(c.ev.bound.free), c.ev.cv_rmse))

    verdict = {"missing_effect": None, "covariate": None, "period": None, "period_unit": None, "message": ""}
    left: list[dict] = []
    sig_base = _significant(struct)
    if winner is not None:
        wstruct = structure_tests(df, winner.ev.resid, covs)
        left = _significant(wstruct)
        own = {base_name(c) for c in winner.effect.covariates}
        own_left = [s for s in left if base_name(s["covariate"]) in own]
        mine = [c for c in covs if base_name(c) in own and df[c].nunique() >= 2]
        cov = min(mine, key=lambda c: min((s["p_value"] for s in struct if s["covariate"] == c), default=1.0),
                  default=None)
        if own_left:
            cov = own_left[0]["covariate"]
            period = _period_of(struct, cov) if is_ordered(cov) else None
            verdict.update(covariate=cov, period=period, period_unit=unit_label(cov) if period else None)
            ptxt = f" (period {_fmt(period, unit_label(cov))})" if period else ""
            verdict["message"] = (
                f"an effect not built in depends on {cov}{ptxt}: write a plugin. The closest built-in effect, "
                f"{winner.effect.name}, cuts held-out RMSE from {_fmt(base.cv_rmse, unit)} to "
                f"{_fmt(winner.ev.cv_rmse, unit)} but leaves structure against {cov} "
                f"({own_left[0]['test']}, p = {own_left[0]['p_value']:.2g}); noise is {_fmt(sigma, unit)}")
            winner_named = False
        else:
            winner_named = True
            verdict.update(missing_effect=winner.effect.name, covariate=cov)
            dir_txt = (f"{rbase} {_direction(df, cov, base.resid)} {cov}: " if cov else "")
            verdict["message"] = (
                f"{dir_txt}adding {winner.effect.name} cuts held-out RMSE from {_fmt(base.cv_rmse, unit)} to "
                f"{_fmt(winner.ev.cv_rmse, unit)} (dBIC {winner.delta_bic:.0f}); {noise_txt}")
            if left:
                verdict["message"] += (f". Structure remains against {left[0]['covariate']} "
                                       f"({left[0]['test']}, p = {left[0]['p_value']:.2g}): after adding it, "
                                       "run diagnose again")
    else:
        winner_named = False
    if winner is None:
        if sig_base:
            cov = sig_base[0]["covariate"]
            period = _period_of(struct, cov) if is_ordered(cov) else None
            verdict.update(covariate=cov, period=period, period_unit=unit_label(cov) if period else None)
            ptxt = f" (period {_fmt(period, unit_label(cov))})" if period else ""
            verdict["message"] = (f"an effect not built in depends on {cov}{ptxt}: write a plugin "
                                  f"({rbase} {_direction(df, cov, base.resid)} {cov}; {sig_base[0]['test']} "
                                  f"p = {sig_base[0]['p_value']:.2g}; no built-in candidate passes the rule)")
        elif not noise.get("reliable", True):
            verdict["message"] = (f"no effect can be named: no built-in candidate passes the rule, and with {base.y.size} "
                                  "points and no replicates the noise level cannot be estimated, so the data cannot "
                                  "show whether anything is missing")
            if cands:
                verdict["message"] += f" (best candidate {cands[0].effect.name}: {cands[0].reason})"
        else:
            verdict["message"] = "nothing is missing: the model explains the data to the noise level"
            if cands and cands[0].delta_cv > 0:
                verdict["message"] += (f" (best candidate {cands[0].effect.name}: {cands[0].reason})")

    def cand_rec(c: Candidate) -> dict:
        pt = param_table(c.ev)
        return {"effect": c.effect.name, "origin": c.effect.origin, "cv_rmse": c.ev.cv_rmse,
                "cv_rmse_se": c.ev.cv_rmse_se, "delta_cv_rmse": -c.delta_cv, "delta_cv_rmse_se": c.delta_cv_se,
                "delta_bic": c.delta_bic, "rmse": c.ev.rmse, "n_free": len(c.ev.bound.free),
                "passes": c.passes, "reason": c.reason,
                "params": {k: v for k, v in pt.items() if v.get("owner") == c.effect.name},
                "base_params": {k: v for k, v in pt.items() if v.get("owner") == "base" and v.get("free")}}

    dh = data_hash(data_path)
    result = {
        "model": model.name, "model_file": model.path, "model_hash": model.hash, "kind": kind,
        "base": model.base.name, "effects": model.effect_names, "data": str(data_path), "data_hash": dh,
        "n": int(base.y.size), "unit": unit,
        "noise": {"sd": sigma, "se": noise["se"], "method": noise["method"]},
        "model_as_is": {"cv_rmse": base.cv_rmse, "cv_rmse_se": base.cv_rmse_se, "rmse": base.rmse, "bic": base.bic,
                        "n_free": base.k, "params": param_table(base)},
        "cv": {"folds": int(np.unique(folds).size), "groups": how},
        "candidates": [cand_rec(c) for c in cands],
        "skipped_candidates": skipped,
        "residual_structure": struct,
        "residual_structure_after_winner": left if winner is not None else [],
        "verdict": {k: verdict[k] for k in ("missing_effect", "covariate", "message", "period", "period_unit")},
        "rule": RULE_TEXT, "alpha": ALPHA, "bic_threshold": BIC_THRESHOLD,
    }

    # tables and figures
    out.mkdir(parents=True, exist_ok=True)
    prov = provenance(config_hash=model.hash, seed=seed, data_synthetic=is_synthetic(df), model=model.content, data=str(data_path), data_hash=dh)
    res = residual_frame(base)
    write_table(res, out / "residuals.parquet", residual_schema(res), prov)
    figs = []
    if figures:
        plots.plot_residuals(res, covs, resp, out / "residuals.png", noise_sd=sigma,
                             title=f"{model.name}: residuals against each covariate")
        figs.append("residuals.png")
    if cands and figures:
        ct = pd.DataFrame({"effect": [c.effect.name for c in cands], "cv_rmse": [c.ev.cv_rmse for c in cands],
                           "cv_rmse_se": [c.ev.cv_rmse_se for c in cands]})
        plots.plot_candidates(ct, base.cv_rmse, base.cv_rmse_se, sigma, unit, out / "candidates.png",
                              winner=winner.effect.name if winner_named else None)
        figs.append("candidates.png")
        shown = winner if winner is not None else cands[0]
        main = next((c for c in covs if base_name(c) in {base_name(x) for x in shown.effect.covariates}
                     and df[c].nunique() >= 3), main_covariate(df, kind))
        cres = residual_frame(shown.ev)
        curves = fit_curves(shown.ev, main)
        bcurves = fit_curves(base, main)
        write_table(curves, out / "best_candidate_curve.parquet", CURVE_SCHEMA, {**prov, "covariate": main})
        plots.plot_fit(cres, curves, main, resp, out / "best_candidate.png",
                       title=f"{model.name} + {shown.effect.name}", extra=bcurves,
                       data_label=plots.data_label(is_synthetic(df)),
                       extra_label=f"{model.name} (as is)")
        figs.append("best_candidate.png")
    result["figures"] = figs

    new_model_path = None
    if write_model is not None:
        chosen = winner if winner_named else (cands[0] if (add_best and cands) else None)
        new_model_path = _write_model(model, chosen, Path(write_model), data_path, verdict, winner_named)
        result["written_model"] = str(new_model_path)
    write_json_atomic(out / "diagnosis.json", result)
    write_text_atomic(out / "diagnosis.md", diagnosis_markdown(result, cands, base, winner if winner_named else None,
                                                               new_model_path))
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
    lines += [f"**Verdict.** {v['message'][0].upper() + v['message'][1:]}.", ""]
    lines += [f"- Data: {r['n']} measurements ({r['data']}); held-out error by {r['cv']['folds']}-fold "
              f"cross-validation with groups {r['cv']['groups']}.",
              f"- Noise: {_fmt(r['noise']['sd'], u)} ± {_fmt(r['noise']['se'], u)} ({r['noise']['method']}).",
              f"- The model as is ({r['base']}" + (f" + {', '.join(r['effects'])}" if r['effects'] else "")
              + f", {r['model_as_is']['n_free']} free parameters): held-out RMSE "
              f"{_fmt(r['model_as_is']['cv_rmse'], u)} ± {_fmt(r['model_as_is']['cv_rmse_se'])}, in-sample "
              f"{_fmt(r['model_as_is']['rmse'], u)}.", ""]
    lines += ["## What the residuals show", ""]
    sig = [s for s in r["residual_structure"] if s["p_adjusted"] < ALPHA]
    if not sig:
        lines.append(f"No significant structure against any covariate (family alpha {ALPHA:g}, Bonferroni over "
                     f"{len(r['residual_structure'])} tests).")
    for s in sig:
        extra = f", period {_fmt(s['periodic_period'], unit_label(s['covariate']))}" if s["periodic_period"] else ""
        lines.append(f"- against {s['covariate']}: {s['test']} (statistic {s['statistic']:.3g}, p = "
                     f"{s['p_value']:.2g}{extra})")
    lines += ["", "## Candidate effects, best first", "",
              f"| effect | held-out RMSE [{u}] | change vs model [{u}] | dBIC | free params | verdict rule |",
              "| --- | --- | --- | --- | --- | --- |"]
    for c in cands:
        lines.append(f"| {c.effect.name} | {_fmt(c.ev.cv_rmse)} ± {_fmt(c.ev.cv_rmse_se)} | "
                     f"{_fmt(-c.delta_cv)} ± {_fmt(c.delta_cv_se)} | {c.delta_bic:.1f} | {len(c.ev.bound.free)} | "
                     f"{c.reason} |")
    if not cands:
        lines.append("| (no applicable candidate: the table lacks the covariates they need) | | | | | |")
    if winner is not None:
        lines += ["", f"## {winner.effect.name}", "", winner.effect.description, "",
                  f"Source: {winner.effect.source}.", "", "Fitted parameters (95 % intervals):", ""]
        for k, p in param_table(winner.ev).items():
            if p.get("owner") == winner.effect.name or p.get("free"):
                ci = p.get("ci95")
                ci_txt = f" [{_fmt(ci[0])}, {_fmt(ci[1])}]" if ci else " (fixed)"
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
