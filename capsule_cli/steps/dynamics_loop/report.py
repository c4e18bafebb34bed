"""What the dynamics loop writes for the reader: the parameter table, the residual table and its schema,
residuals by response class and by run, the plain-words summary of where a model fails, the diagnosis.md report
and the residual figure.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from ...errors import InputError
from ...tables import Column, TableSchema
from ..verdict import FitSummary
from .bound import DynBound, RESPONSE_CLASSES, UNIT, position_rows, row_variance
from .calibration import DynEvaluation, _std_sq
from .noise import _ls_slope


def box_edges(ev: DynEvaluation, owner: str) -> list[str]:
    """Return the parameters of ``owner`` that ended at an edge of their fit box, which the verdict ranks
    last (the model or the bounds may be wrong). A coefficient at a lower bound of exactly 0 is not one: a
    contact or drag damping, a speed-law rise, of zero is a physical value (the term vanishes), not a box
    edge, and a secondary constraint whose contact is undamped is still a secondary constraint. "At" is
    the parameter table's at-bound test (within 1e-6 of the box's span), so a fit that stops a rounding
    step above 0 (a substrate damping of 1e-5 N s/m in a box [0, 10]) counts as zero too. The parameter
    table still reports it as at its bound."""
    return [k for k, p in param_table(ev).items()
            if p["owner"] == owner and p.get("at_bound")
            and not (p["bounds"][0] == 0.0 and p["value"] <= 1e-6 * (p["bounds"][1] - p["bounds"][0]))]


def param_table(ev: DynEvaluation) -> dict:
    """Return ``{key: {value, free, unit, owner, ci95, at_bound, bounds}}``."""
    vals = ev.bound.values(ev.theta)
    free = {s.key for s in ev.bound.free}
    out = {}
    for s in ev.bound.model.specs:
        rec = {"value": vals[s.key], "free": s.key in free, "unit": s.param.unit, "owner": s.owner}
        if s.key in free:
            lo, hi = s.bounds
            v = vals[s.key]
            rec.update(bounds=[lo, hi], ci95=ev.intervals.get(s.key), stderr=ev.stderr.get(s.key),
                       at_bound=bool(abs(v - lo) <= 1e-6 * (hi - lo) or abs(v - hi) <= 1e-6 * (hi - lo)))
        out[s.key] = rec
    return out


# ---------------------------------------------------------------------------
# residuals by regime and condition, in plain words


def residual_frame(ev: DynEvaluation) -> pd.DataFrame:
    """Return the comparison rows with observed, predicted, residuals, held-out, class and fold."""
    df = ev.bound.row_frame()
    base, u = ("velocity", "mm_s") if ev.bound.kind == "progression" else ("capsule", "mm")
    resp = ev.bound.response
    df = df.rename(columns={resp: f"observed_{base}_{u}"})
    df[f"observed_{base}_{u}"] = ev.y
    df[f"predicted_{base}_{u}"] = ev.pred
    df[f"residual_{base}_{u}"] = ev.resid
    df[f"cv_predicted_{base}_{u}"] = ev.cv_pred
    df[f"cv_residual_{base}_{u}"] = ev.y - ev.cv_pred
    df[f"model_spread_{base}_{u}"] = ev.sim["spread"]
    df["standardised_residual"] = ev.resid / np.sqrt(row_variance(ev.sigma, ev.sim))
    df["response_class"] = ev.sim["cls"].astype(str)
    df["fold"] = ev.folds.astype("int64")
    df["cv_group"] = ev.groups.astype("int64")
    return df


def residual_schema(df: pd.DataFrame) -> TableSchema:
    desc = {"fold": "cross-validation fold of the row", "cv_group": "group kept together in cross-validation",
            "response_class": "model response class at the row's drive (no_impact, one_impact, multi_impact, "
                              "irregular)",
            "compared": "position (frames) or average_velocity (drift over whole periods, irregular run)",
            "standardised_residual": "residual / sqrt(noise SD^2 + model spread^2)"}
    cols = []
    for c in df.columns:
        if c in ("fold", "cv_group"):
            dt = "int64"
        elif pd.api.types.is_numeric_dtype(df[c]) and not pd.api.types.is_bool_dtype(df[c]):
            dt = "float64"
        else:
            dt = "string"
        cols.append(Column(c, dt, desc.get(c, "measurement or model column")))
    return TableSchema("residuals", "dynamics model vs measurements per comparison row", tuple(cols))


def by_class(ev: DynEvaluation) -> list[dict]:
    """Return per response class: n, held-out RMSE (plain), standardised held-out RMS, mean residual."""
    out = []
    cls = ev.sim["cls"].astype(str)
    for c in RESPONSE_CLASSES + ("failed",):
        m = cls == c
        if not m.any():
            continue
        out.append({"response_class": c, "n": int(m.sum()), "cv_rmse": ev.plain_cv_rmse(m),
                    "cv_rms_standardised": float(np.sqrt(np.mean(ev.cv_sq[m]))),
                    "mean_residual": float(np.nanmean(ev.resid[m]))})
    return out


def regime_of(ev: DynEvaluation, sigma: float) -> str | None:
    """Return the response class where the held-out misfit concentrates (largest excess standardised
    squared error over sigma^2), or None when no class exceeds twice the noise variance."""
    cls = ev.sim["cls"].astype(str)
    best, score = None, 0.0
    for c in RESPONSE_CLASSES:
        m = cls == c
        if m.sum() < 2:
            continue
        ex = float(np.mean(ev.cv_sq[m]))
        if ex > 2 * sigma ** 2 and ex * m.sum() > score:
            best, score = c, ex * m.sum()
    return best


_CLASS_WORDS = {"no_impact": "the shell is not hit", "one_impact": "the magnet hits the constraint at most once "
                "per period", "multi_impact": "it hits more than once per period", "irregular": "the response is "
                "irregular, with no period of up to 8 drive periods"}


def _span(x: pd.Series) -> str:
    """Return 'lo-hi' of a covariate's values, or the one value when they are all equal."""
    lo, hi = float(x.min()), float(x.max())
    return f"{lo:g}" if lo == hi else f"{lo:g}-{hi:g}"


def _drive_span(rows: pd.DataFrame) -> str:
    """Return 'f lo-hi Hz, P_d lo-hi N' of the rows' drives, or '' when the rows do not carry them."""
    return (f"f {_span(rows['f_Hz'])} Hz, P_d {_span(rows['Pd_N'])} N"
            if {"f_Hz", "Pd_N"} <= set(rows.columns) else "")


#: a trajectory run's misfit is put in words as a drift (:func:`run_drift_words`) when its residual drift rate is
#: this many standard errors (at the noise SD and its frame-to-frame correlation, :func:`slope_se`) from zero and
#: its frames' RMS standardised residual is above RUN_MISFIT_Z (the same 2 noise SDs as the rows' words below)
RUN_DRIFT_Z = 3.0
RUN_MISFIT_Z = 2.0


def run_drift_table(ev: DynEvaluation, sigma: float, rho: float = 0.0) -> pd.DataFrame:
    """Return one row per trajectory run compared by position (empty for progressions): :func:`run_residual_rates`
    (the drift rate of its position residual ``rate_mm_s`` ± ``rate_se_mm_s`` at the noise SD ``sigma`` [mm] and
    the noise's frame-to-frame correlation ``rho``, its drive, class and frames), the RMS of its frames'
    standardised residuals ``rms_standardised_residual``, and
    ``drifts``: the rate is RUN_DRIFT_Z standard errors from zero and the frames misfit (RMS above RUN_MISFIT_Z).
    The numbers behind :func:`run_drift_words`, written beside them in the reports."""
    if ev.bound.kind != "trajectory" or sigma <= 0:
        return pd.DataFrame()
    rf = ev.bound.row_frame()
    pos = position_rows(rf)
    if not pos.any():
        return pd.DataFrame()
    z = ev.resid / np.sqrt(row_variance(sigma, ev.sim))
    fr = rf[pos].assign(resid=ev.resid[pos], response_class=ev.sim["cls"].astype(str)[pos])
    fr["run"] = fr["run"].astype(str)
    per = run_residual_rates(fr, "resid", sigma, rho)
    if per.empty:
        return per
    rms = pd.Series(z[pos], index=fr.index).groupby(fr["run"], sort=False).apply(
        lambda v: float(np.sqrt(np.nanmean(v.to_numpy() ** 2))))
    per["rms_standardised_residual"] = per["run"].map(rms)
    per["drifts"] = ((per["rate_mm_s"].abs() > RUN_DRIFT_Z * per["rate_se_mm_s"])
                     & (per["rms_standardised_residual"] > RUN_MISFIT_Z))
    return per


#: how a fitted origin is stated (compare's metrics, diagnosis.json and .md)
ORIGINS_MEANING = ("runs whose positions were measured from their own first frame (the capsule exactly 0 at "
                   "time_s = 0): the model's positions of each are moved by its least-squares offset [mm], which the "
                   "first frame's noise puts there; a run compared by its drift needs none")


def origins_fitted(ev: DynEvaluation) -> dict:
    """Return {run: offset [mm]} of the trajectory runs whose origin ``ev``'s fit profiled (:meth:`DynBound.
    _with_origins`); empty when none."""
    return {str(r): float(v) for r, v in (ev.sim.get("origin_mm") or {}).items()}


def run_drift_records(per: pd.DataFrame) -> list[dict]:
    """Return :func:`run_drift_table`'s rows as JSON records (run, drive, class, frames, rate ± SE, RMS, drifts)."""
    keep = [c for c in ("run", "f_Hz", "Pd_N", "response_class", "frames", "rate_mm_s", "rate_se_mm_s",
                        "rms_standardised_residual", "drifts") if c in per.columns]
    return [{k: (v.item() if hasattr(v, "item") else v) for k, v in rec.items()}
            for rec in per[keep].to_dict("records")]


def run_drift_words(per: pd.DataFrame) -> list[str]:
    """Return where a trajectory model's capsule falls behind or runs ahead, in plain words: the runs of
    :func:`run_drift_table` that drift, grouped by sign, with their drives and response classes, then the runs
    whose frames misfit without a drift. Empty when no run drifts."""
    if per.empty:
        return []
    parts = []
    for sign, word in ((1, "lower"), (-1, "higher")):
        sub = per[per["drifts"] & (np.sign(per["rate_mm_s"]) == sign)]
        if sub.empty:
            continue
        where = _drive_span(sub)
        where = f" ({where})" if where else ""
        classes = " or ".join(_CLASS_WORDS.get(c, c) for c in dict.fromkeys(sub["response_class"]))
        parts.append(f"the model's capsule {'falls behind' if sign > 0 else 'runs ahead of'} the measured one in "
                     f"{len(sub)} of {len(per)} runs compared by position{where}, where {classes}: its average "
                     f"velocity is {word} by {sub['rate_mm_s'].abs().mean():.3g} mm/s on average (the slope of the "
                     "position residual)")
    still = per[~per["drifts"] & (per["rms_standardised_residual"] > RUN_MISFIT_Z)]
    if parts and not still.empty:
        where = _drive_span(still)
        where = f" ({where})" if where else ""
        rms = still["rms_standardised_residual"]
        lo, hi = f"{rms.min():.3g}", f"{rms.max():.3g}"
        parts.append(f"the frames of {len(still)} more run{'s' if len(still) > 1 else ''}{where} are off by "
                     f"{lo if lo == hi else f'{lo}-{hi}'} noise SDs (RMS) without such a drift")
    return parts


def plain_summary(ev: DynEvaluation, sigma: float, rho: float = 0.0, reliable: bool = True) -> str:
    """Return where the model fails by regime and drive condition, in plain words: for a trajectory, first the
    runs where the model's capsule falls behind or runs ahead (:func:`run_drift_words`, noise SD ``sigma``, its
    frame-to-frame correlation ``rho``); else,
    for every response
    class where most rows are off by more than 2 noise SDs, which way and where. ``reliable`` False: ``sigma`` is
    only an upper bound of the noise (too few points, no replicates), so rows within 2 of it are not said to be
    within the noise."""
    unit = UNIT[ev.bound.kind]
    rf = ev.bound.row_frame()
    z = ev.resid / np.sqrt(row_variance(sigma, ev.sim)) if sigma > 0 else ev.resid
    cls = ev.sim["cls"].astype(str)
    drift = run_drift_words(run_drift_table(ev, sigma, rho))
    if drift:
        return "; ".join(drift)
    parts = []
    for c in RESPONSE_CLASSES:
        m = cls == c
        if not m.any():
            continue
        bad = m & (np.abs(z) > 2)
        if bad.sum() < max(2, 0.5 * m.sum()):
            continue
        sub = rf[bad]
        mean_r = float(np.nanmean(ev.resid[bad]))
        word = "lower" if mean_r > 0 else "higher"
        what = "velocity" if ev.bound.kind == "progression" else "position"
        where = _drive_span(sub)
        parts.append(f"the model's {what} is {word} than measured (by {abs(mean_r):.3g} {unit} on average) in "
                     f"{int(bad.sum())} of {int(m.sum())} rows where {_CLASS_WORDS[c]} ({where})")
    if not parts and not reliable:
        return (f"no response regime is off by more than 2 times the noise's upper bound ({sigma:.3g} {unit}); "
                f"the data cannot estimate the noise itself, so they cannot show a smaller misfit")
    if not parts:
        return "the model is within about 2 noise SDs of the data in every response regime"
    return "; ".join(parts)


# ---------------------------------------------------------------------------
# the verdict (pure): the quasi-static rule on standardised held-out errors


def summary_of(ev: DynEvaluation, name: str = "", covariates: Sequence[str] = (), structure=None,
               at_bound: Sequence[str] = (), nests: Sequence[tuple[str, str]] = ()) -> FitSummary:
    """Return the arrays :func:`.verdict.decide_verdict` needs from one dynamics evaluation.

    The residual sum of squares and the held-out squared errors are the standardised ones
    (r^2 sigma^2 / SD_i^2, SD_i^2 = sigma^2 + s_i^2 with s_i the spread of an irregular response), so the
    F test and the held-out comparison see chaos as noise, not as a missing effect; so do the residuals of the
    direct comparison of two candidates (Vuong's test): with plain residuals, the chaotic conditions' spreads
    (up to tens of mm/s) made a secondary constraint fitted to the noise (held-out 0.69 mm/s) "not separable"
    from a substrate compliance held out at 44 mm/s (p = 0.16; 40 conditions, continuation up).
    """
    sq = _std_sq(ev.y, ev.sim, ev.sigma)
    r = ev.y - ev.pred
    std_r = np.where(np.isfinite(r), np.sign(np.nan_to_num(r)) * np.sqrt(sq), np.sqrt(sq))
    return FitSummary(name, ev.k, ev.rss, ev.pred, ev.cv_sq, tuple(covariates), list(structure or []),
                      tuple(at_bound), resid=std_r, nests=tuple(nests), cv_expected=ev.cv_expected)


def _gathered_words(outliers: Sequence[dict]) -> str:
    """Return ' (rows 15, 25, 35 gather at f_Hz = 30, p = 0.008: ...)' for the readings left out that gather at
    one value of a covariate (:func:`concentrated_rows`), or ''."""
    rows = [o for o in outliers if o.get("concentrated")]
    if not rows:
        return ""
    at = rows[0]["concentrated"]
    return (f" (rows {', '.join(str(o['row']) for o in rows)} gather at {at['covariate']} = {at['value']:g}, "
            f"p = {at['p']:.2g}: read as an effect there, not as independent errors)")


def _frame_words(o: Mapping, end: str = "") -> str:
    """Return 'run r2, t = 0.4 s' + ``end`` for a trajectory frame's record (where to look in the video; with ', an
    end of its drift' for a frame a run compared by its average velocity takes its drift from), else ''."""
    if "run" not in o or "time_s" not in o:
        return ""
    return f"run {o['run']}, t = {o['time_s']:g} s" + (", an end of its drift" if o.get("drift_frame") else "") + end


def diagnosis_markdown(r: dict) -> str:
    """Return diagnosis.md for dynamics data: verdict, regimes, candidates, rule."""
    u, v = r["unit"], r["verdict"]
    msg = v["message"]
    flagged = [o for o in r.get("outliers") or () if not o.get("scattered")]
    level = [o for o in r.get("outliers") or () if o.get("scattered")]
    lv = level[0]["scattered"] if level else {}
    lines = [f"# Diagnosis: {r['model']} on {Path(r['data']).name}", "",
             f"**Verdict.** {msg[0].upper() + msg[1:]}.", "",
             f"- Outcome: {v['outcome'].replace('_', ' ')}" + (" (partial step)" if v.get("partial") else "") + ".",
             f"- Regime where the misfit concentrates: {v['regime'] or 'none'}; covariate: {v['covariate'] or 'none'}"
             + (f" (collinear, not separable by these data: {', '.join(v['confounded'])})" if v.get("confounded")
                else "") + ".",
             f"- Candidates tried: {', '.join(r['candidates_tried']) or 'none'}.",
             (f"- Protocol: {r['protocol']}." if r.get("kind") != "trajectory" else
              "- Runs: each from rest at drive phase 0 (F = P_d cos 2 pi f t), the trajectory kind's time axis; the "
              "model file's protocol does not apply."),
             f"- Noise: {r['noise']['sd']:.3g} {u} ({r['noise']['method']}).",
             *(["- Outliers, left out of every fit (0-based data rows; how far from the best-fitting model tried, "
                "in noise SDs of the other rows): " + ", ".join(f"row {o['row']} ({_frame_words(o, '; ')}{o['z']:.3g}, "
                                                                 f"threshold {o['threshold']:.3g})" for o in flagged)
                + ". No other model tried accounts for these readings: check them" + _gathered_words(flagged)
                + "."] if flagged else []),
             *([f"- Left out of every fit, the readings at {lv['covariate']} = {lv['value']:g}, where the misfit "
                f"gathered (0-based data rows; residual under {lv['model']}): "
                + ", ".join(f"row {o['row']} ({o['residual']:+.3g} {u})" for o in level)
                + f". With them, that model's residual SD bounded the noise at {lv['noise_bound']:.3g} {u}."]
               if level else []),
             f"- Model as is: held-out {r['model_as_is']['cv_rmse']:.3g} ± {r['model_as_is']['cv_rmse_se']:.2g} {u} "
             f"(standardised by the error model), {r['cv']['folds']} folds {r['cv']['groups']}"
             + (lambda h: f"; as the truth on these runs it is held out at {h['mean']:.3g} ± {h['sd']:.2g} {u} "
                f"({h['draws']} draws, {h['as_high']} of them as high as the data's, Monte Carlo p = "
                f"{h['p_value']:.3g}; {h['method']})." if h else ".")(r["model_as_is"].get("held_out_if_true")), "",
             "## By response class (model as is)", "", f"| class | n | held-out RMSE [{u}] | mean residual [{u}] |",
             "| --- | --- | --- | --- |"]
    for c in r["model_as_is"]["by_response_class"]:
        lines.append(f"| {c['response_class']} | {c['n']} | {c['cv_rmse']:.3g} | {c['mean_residual']:.3g} |")
    if r["model_as_is"].get("by_run"):
        lines += ["", "## By run (model as is)", "", "Drift rate: the slope of the run's position residual (measured - "
                  "model) over time, ± 1 SE at the noise SD" + (
                      f" and its lag-1 correlation from frame to frame ({r['noise']['correlated']['rho']:.2g})"
                      if (r["noise"].get("correlated") or {}).get("rho") else "")
                  + "; RMS: of the frames' standardised residuals.", "",
                  "| run | f [Hz] | P_d [N] | class | frames | drift rate [mm/s] | RMS | drifts |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for q in r["model_as_is"]["by_run"]:
            lines.append(f"| {q['run']} | {q.get('f_Hz', float('nan')):g} | {q.get('Pd_N', float('nan')):g} | "
                         f"{q['response_class']} | {q['frames']} | {q['rate_mm_s']:.3g} ± {q['rate_se_mm_s']:.2g} | "
                         f"{q['rms_standardised_residual']:.3g} | {'yes' if q['drifts'] else 'no'} |")
    lines += ["", f"Where it fails: {r['where_it_fails']}.", "", "## Candidates, best first", "",
              f"| effect | held-out [{u}] | change [{u}] | dBIC | free | rule |",
              "| --- | --- | --- | --- | --- | --- |"]
    for c in r["candidates"]:
        lines.append(f"| {c['effect']} | {c['cv_rmse']:.3g} | "
                     f"{c['delta_cv_rmse']:.3g} ± {c['delta_cv_rmse_se']:.2g} | {c['delta_bic']:.1f} | "
                     f"{c['n_free']} | {c['reason']} |")
    for s in r["skipped_candidates"]:
        lines.append(f"| {s['effect']} | not tried: {s['reason']} | | | | |")
    if r.get("covariate_probes"):
        lines += ["", "## Covariate probes (not physical models)", "", r["covariate_probes_rule"] + ".", "",
                  f"| probe | held-out [{u}] | better than the best built-in by [{u}] | F test p | names it |",
                  "| --- | --- | --- | --- | --- |"]
        for p in r["covariate_probes"]:
            lines.append(f"| {p['probe']} | {p['cv_rmse']:.3g} | {p['better_than_best_builtin_by']:.3g} ± "
                         f"{p['better_than_best_builtin_by_se']:.2g} | {p['f_test_p']:.3g} | "
                         f"{'yes' if p['passes'] else 'no'} |")
    knife = [k["words"] for c in r.get("candidates", [])[:1] for k in c.get("knife_edge_runs", [])]
    if knife:
        what = "Runs" if r.get("kind") == "trajectory" else "Conditions"
        lines += ["", f"{what} on a knife edge of {r['candidates'][0]['effect']}'s parameters: " + "; ".join(knife)
                  + "."]
    if r.get("model_as_is", {}).get("origins_fitted_mm"):
        lines += ["", "Origins fitted (model as is; " + ORIGINS_MEANING + "): "
                  + ", ".join(f"{k} {v:+.3g} mm" for k, v in r["model_as_is"]["origins_fitted_mm"].items()) + "."]
    if r.get("runs_compared_by"):
        lines += ["", "Runs compared by: " + ", ".join(f"{k}: {v}" for k, v in r["runs_compared_by"].items())
                  + f" ({r.get('runs_compared_by_from', '')})."]
    if r.get("written_model"):
        lines += ["", "## Next step", "", f"`capsule-cli compare --model {r['written_model']} --data {r['data']} "
                  "--out DIR`"]
    lines += ["", "## The rule (fixed before looking at the data)", "", r["rule"], ""]
    return "\n".join(lines)


def slope_se(t_s: np.ndarray, sigma: float, rho: float = 0.0) -> float:
    """Return the standard error of the least-squares slope of readings at times ``t_s`` [s] over time, for
    noise of SD ``sigma`` whose lag-1 correlation from one reading to the next (in time order) is ``rho``
    (AR(1): correlation rho^k at k readings apart). Exact for the given times: SD x sqrt(w' R w), w the
    slope's weights (t - mean t) / Sxx; for rho = 0 it is SD / sqrt(Sxx). Correlated readings carry less
    information about a slope than independent ones: at rho 0.8, 100 equally spaced frames, the SE is
    2.8 times the white-noise one (sqrt((1 + rho) / (1 - rho)) = 3 for long records, as for the mean of
    AR(1) readings; e.g. Box, Jenkins & Reinsel, Time Series Analysis)."""
    t = np.sort(np.asarray(t_s, float))
    sxx = float(np.sum((t - t.mean()) ** 2))
    if t.size < 2 or sxx <= 0:
        return float("nan")
    w = (t - t.mean()) / sxx
    v = float(w @ w)
    if rho > 0:
        lags = min(t.size - 1, int(np.ceil(np.log(1e-12) / np.log(min(rho, 0.999)))))
        for k in range(1, lags + 1):
            v += 2.0 * rho ** k * float(w[:-k] @ w[k:])
    return float(sigma * np.sqrt(max(v, 0.0)))


def run_residual_rates(frames: pd.DataFrame, rcol: str, sigma: float, rho: float = 0.0) -> pd.DataFrame:
    """Return one row per trajectory run compared by position: the least-squares slope of its position residual
    (measured - model) over the frame times ``rate_mm_s`` [mm/s] (how much faster the capsule went than the
    model), its standard error (``rate_se_mm_s``, :func:`slope_se`) for noise of SD ``sigma`` [mm] whose lag-1
    correlation from frame to frame is ``rho`` (0: white), the run's most common
    response class, and every numeric column constant within each run (its drive f_Hz, Pd_N and, for instance,
    a temperature recorded per run). Runs of fewer than 3 frames are left out."""
    recs = []
    for run, d in frames.groupby("run", sort=False):
        t = d["time_s"].to_numpy(float)
        r = d[rcol].to_numpy(float)
        ok = np.isfinite(t) & np.isfinite(r)
        t, r = t[ok], r[ok]
        if t.size < 3 or np.ptp(t) <= 0:
            continue
        rec = {"run": str(run), "rate_mm_s": _ls_slope(t, r),
               "rate_se_mm_s": slope_se(t, sigma, rho),
               "response_class": str(d["response_class"].mode().iloc[0]), "frames": int(t.size)}
        for c in d.columns:
            if c not in rec and c != "time_s" and pd.api.types.is_numeric_dtype(d[c]) and d[c].nunique() == 1:
                rec[c] = d[c].iloc[0]
        recs.append(rec)
    return pd.DataFrame(recs)


def _nice_value(at: Mapping) -> str:
    """Return 'f = 30 Hz' for {covariate: 'f_Hz', value: 30.0}: a column's value in words for a legend."""
    from ...units import split_unit, unit_label

    name, unit = split_unit(at["covariate"])
    return f"{name} = {at['value']:g}" + (f" {unit_label(at['covariate'])}" if unit else "")


def _left_out_why(o: Mapping) -> str:
    """Return why a reading was left out, for a legend: 'gathered at f = 30 Hz' (flagged readings that gather,
    :func:`concentrated_rows`), 'misfit gathered at P_d = 0.2 N' (:func:`scattered_rows`) or '' (an outlier)."""
    if o.get("concentrated"):
        return f"gathered at {_nice_value(o['concentrated'])}"
    if o.get("scattered"):
        return f"misfit gathered at {_nice_value(o['scattered'])}"
    return ""


def drawn_left_out(ev: DynEvaluation, left_out: Sequence[dict]) -> list[dict]:
    """Return the records of the rows left out (:func:`outlier_rows`, :func:`scattered_rows`) with ``residual``
    under ``ev``'s model where a simulation gives it alone: a trajectory frame, its run simulated from rest to the
    frame's time, so that the residual figure draws it against the model the other frames are drawn against
    (the record's residual is the flagging model's: in a 4-run diagnose a 2.5 mm tracking error was drawn at
    +2.7 mm beside its run's frames at +4.3 mm); a progression reading run from rest, its condition simulated
    alone. A reading of a continuation sweep keeps its residual under the model that flagged it: its condition
    takes its state from the conditions before it, some of which may be left out too."""
    b = ev.bound
    if b.kind == "progression":
        if b.protocol.start != "rest" or not left_out:
            return list(left_out)
        cols = [c for c in b.df.columns if all(c in o for o in left_out)]
        try:
            alone = DynBound(b.model, pd.DataFrame([{c: o[c] for c in cols} for o in left_out]), where=b.where,
                             rk_rtol=None if b.options is None else b.options.rk_rtol)
            pred = alone.simulate(ev.theta, classify=False)["pred"]
        except (InputError, RuntimeError, ValueError, FloatingPointError, KeyError):
            return list(left_out)
        return [{**o, "residual": float(o[b.response]) - float(p)} if math.isfinite(p) else o
                for o, p in zip(left_out, pred)]
    runs = {str(r): r for r in b.run_drive}
    out = []
    for o in left_out:
        run = o.get("run")
        key = str(int(run)) if isinstance(run, float) and run.is_integer() else str(run)
        if key in runs and "time_s" in o and b.response in o:
            try:
                pred = float(b.positions_mm(ev.theta, runs[key], [float(o["time_s"])])[0])
                pred += ((getattr(ev, "sim", None) or {}).get("origin_mm") or {}).get(runs[key], 0.0)  # origin fitted
            except (InputError, RuntimeError, ValueError, FloatingPointError):
                pred = math.nan
            if math.isfinite(pred):
                o = {**o, "residual": float(o[b.response]) - pred}
        out.append(o)
    return out


def _plot_residuals(res: pd.DataFrame, ev: DynEvaluation, path: Path, title: str,
                    covariate: str | Sequence[str] | None = None, rho: float = 0.0,
                    outliers: Sequence[dict] = ()):
    """Draw and save the residuals by response class; return the figure.

    - progression: against the drive frequency and amplitude, and against ``covariate`` (the one a verdict
      names, or the collinear ones it cannot tell apart) when it is another column;
    - trajectory: the position residuals against the frame time, and a second row with each run's residual
      drift rate (:func:`run_residual_rates`, its SE at the noise's frame-to-frame correlation ``rho``) against
      f, P_d and ``covariate`` when the runs hold 2 or more values of it. A run compared by its drift over
      whole periods (``compared = average_velocity``) has one
      residual that is not a frame's: it is drawn in a panel of its own, per run, so that it is not read as a
      position error at one instant;
    - both: the rows left out as ``outliers`` (:func:`outlier_rows` records) as crosses at their ``residual``
      (:func:`drawn_left_out`); those gathered at one value of a covariate (:func:`concentrated_rows`) and the
      readings at the value where the misfit gathered (:func:`scattered_rows`) as diamonds."""
    from ...plots.loop import dynamics_residual_figure
    from ...plots.style import save_figure

    col = [c for c in res.columns if c.startswith("residual_")][0]
    named = [covariate] if isinstance(covariate, str) else list(covariate or ())
    wanted = [c for c in ("f_Hz", "Pd_N", *named) if c]
    drift_m = (res["compared"] == "average_velocity").to_numpy() if "compared" in res.columns \
        else np.zeros(len(res), bool)
    frames = res[~drift_m]
    drift = per_run = None
    run_cols: tuple = ()
    if ev.bound.kind == "progression":
        xcols = list(dict.fromkeys(["f_Hz"] + [c for c in wanted[1:] if c in res.columns and res[c].nunique() >= 2]))
    else:
        xcols = ["time_s"]
        if drift_m.any():
            # each drift's own SD (row_variance: two frames' noise, the spread over windows and starting states)
            sim = getattr(ev, "sim", None)
            sd = (np.sqrt(row_variance(ev.sigma, sim) * np.ones(len(res))) if sim is not None
                  else np.full(len(res), float(ev.sigma)))
            drift = res[drift_m].assign(sd=sd[drift_m])
        if "run" in frames.columns and len(frames):
            per_run = run_residual_rates(frames, col, float(ev.sigma), rho)
            run_cols = tuple(dict.fromkeys(c for c in wanted if c in per_run.columns and per_run[c].nunique() >= 2))
    left = pd.DataFrame([{**o, col: o["residual"], "why": _left_out_why(o)}
                         for o in outliers if "residual" in o]) if outliers else None
    fig = dynamics_residual_figure(frames, xcols, col, UNIT[ev.bound.kind], float(ev.sigma),
                                   RESPONSE_CLASSES + ("failed",), title, drift, per_run, run_cols, rho, left)
    save_figure(fig, path)
    return fig
