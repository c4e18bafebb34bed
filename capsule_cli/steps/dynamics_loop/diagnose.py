"""``diagnose`` for dynamics data: fit the model as is and each candidate effect (built-in or plugin),
compare them by held-out error under the verdict rule, probe the covariates when no candidate fits, and write the
verdict, report and the improved model file (:func:`run_diagnose`).
"""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from ...effects import registry
from ...effects.model import Model
from ...effects.registry import Effect
from ...errors import InputError
from ...tables import staged_folder, write_json_atomic, write_table, write_text_atomic
from .. import crossval
from ..residual_tests import structure_tests
from ..verdict import (ALPHA_EFFECT, COLLINEAR_R, EXCESS_Z, Noise, RULE_TEXT, collinear_groups, collinear_with,
                       nested_f_test, noise_expectation, p_text, rss_pair)
from .bound import (Budget, DynBound, MIN_HORIZON_PERIODS, MODE_PASSES, ModelNotRunnable, PREDICTABLE_SPREAD_MM,
                    PROBE_TRIGGER, PROBE_Z, UNIT, choose_modes, merge_modes, predictable, row_variance)
from .calibration import DynEvaluation, _plain_sq
from .noise import (blocked_caveat, correlated_noise, noise_rho, public_record, record_serial, serial_noise,
                    trajectory_noise)
from .evaluation import evaluate, held_out_record, knife_edge_records, refit_progression, with_design_expectation
from .outliers import (OUTLIER_RULE, PROGRESSION_RULE, no_effect_named, outlier_rows, scattered_caveat, scattered_rows,
                       scattered_verdict)
from .report import (_plot_residuals, by_class, diagnosis_markdown, drawn_left_out, param_table, residual_frame,
                     residual_schema, run_drift_records, run_drift_table, summary_of,
                     ORIGINS_MEANING, origins_fitted)
from .verdicts import column_probes, concentrated_verdict, dynamics_covariates, dynamics_verdict, left_out_level_verdict
from .compare import _prov, _setup


def consistent_base(base: DynEvaluation, cands: Sequence[dict], budget: Budget, seed: int
                    ) -> tuple[DynEvaluation, str | None]:
    """Return the model as is refitted when a candidate's own values of the shared parameters fit it better.

    The nested F test assumes each fit is at its optimum. On a rugged objective (regimes switch as P_f
    moves) the model as is can stop in a worse local minimum than a candidate reaches for the same
    parameters (one whose effect ends at its off value is then the model as is, fitted better), and the
    candidate would be credited with the calibration's luck. Each candidate's shared values are tried
    (one evaluation each); the best, if better, restarts the calibration and cross-validation of the model
    as is. Returns (evaluation, name of the candidate it was restarted from or None).
    """
    b = base.bound
    if not b.free or not cands:
        return base, None
    best, who = base.fit.cost, None
    for c in cands:
        vals = c["ev"].bound.values(c["ev"].theta)
        x = np.array([vals[k] for k in b.names], float)
        w = np.ones(base.y.size) if base.fit.weights is None else base.fit.weights
        cost = float(np.sum(w ** 2 * _plain_sq(base.y, b.simulate(x, classify=False, y=base.y), base.sigma)))
        if cost < best * (1 - 1e-9):
            best, who, x_best = cost, c["effect"].name, x
    if who is None:
        return base, None
    ev = evaluate(b, base.sigma, base.folds, base.groups, x0=x_best, budget=budget, seed=seed)
    return (ev, who) if ev.rss < base.rss else (base, None)


def nested_starts(m2: Model, eff: Effect, fitted: Mapping[str, DynEvaluation]) -> list[list[float]]:
    """Return starts (free parameters of ``m2`` = a model with ``eff``) at the fits in ``fitted`` of the effects
    ``eff`` nests, set where ``eff`` reduces to each (:attr:`Effect.nest_starts`): the shared parameters at that
    fit's values, ``eff``'s own at the declared setting (a number, or that fit's value of the named parameter).
    A setting naming a parameter the fit does not have is skipped."""
    out = []
    own = {s.param.name: s.key for s in m2.specs if s.owner == eff.name}
    for name, setting in getattr(eff, "nest_starts", ()):
        ev = fitted.get(name)
        if ev is None:
            continue
        got = ev.bound.values(ev.theta)
        try:
            vals = {own[k]: float(got[v]) if isinstance(v, str) else float(v) for k, v in setting}
        except KeyError:
            continue
        shared = {s.key: got[s.key] for s in m2.specs if s.owner != eff.name and s.key in got}
        out.append([s.value for s in m2.with_values(shared | vals).specs if s.free])
    return out


def nested_first(pool: Sequence[Effect]) -> list[Effect]:
    """Return ``pool`` with every effect another one nests before it (:attr:`Effect.nests`), else in order, so
    that the richer one's calibration can start at the nested one's fit (:func:`nested_starts`)."""
    contained = {pair[0] for e in pool for pair in e.nests}
    return sorted(pool, key=lambda e: 0 if e.name in contained else 1)


def fit_candidate(model: Model, eff: Effect, df, base: DynEvaluation, data_path, budget: Budget, seed: int,
                  previous: DynEvaluation | None = None, fitted: Mapping[str, DynEvaluation] | None = None):
    """Return {effect, model, ev} of model + eff (starts: the base fit with the effect at its declared
    start values; the fits in ``fitted`` of effects it nests at the setting where it reduces to them
    (:func:`nested_starts`), or when there is none the base fit with the effect off; ``previous``'s fit (the same
    candidate on other comparison rows) when given; then the scan).

    The nested start: with a viscous drag (0.05 N s/m) hidden in 40 conditions (noise 0.5 mm/s), the speed law's
    other starts ended at a 0.154 mN, n 0.835, in-sample RMSE 0.856 mm/s against the drag's 0.395: the richer
    model fitted worse than the one it contains."""
    vals = base.bound.values(base.theta)
    m2 = model.with_values(vals).with_effect(eff)
    b2 = DynBound(m2, df, where=str(data_path), modes=getattr(base.bound, "modes", None), rk_rtol=budget.rk_rtol)
    off = m2.with_values({s.key: s.param.off for s in m2.specs if s.owner == eff.name})
    x_off = [s.value for s in off.specs if s.free]
    # a fit of an effect it nests replaces the start with the effect off: that fit is at least as good as the
    # model as is (it had the off start too), and the speed law costs ~0.2 s per evaluation on 40 conditions
    extra = ((nested_starts(m2, eff, fitted or {}) or [x_off])
             + ([np.asarray(previous.theta, float)] if previous is not None else []))
    ev = evaluate(b2, base.sigma, base.folds, base.groups, x0=b2.x0, budget=budget, seed=seed,
                  extra_starts=extra, refit_first=[i for i, s in enumerate(b2.free) if s.owner == "base"])
    return {"effect": eff, "model": m2, "ev": ev}


def _fit_all(model: Model, df, data_path, bound: DynBound, sigma: float, folds, groups, pool, budget: Budget,
             seed: int, quiet: bool, previous: dict | None = None):
    """Return (model as is, candidates, skipped, refit_from) fitted on ``bound``'s comparison rows.

    previous: {'base': DynEvaluation, name: DynEvaluation} of an earlier pass on other rows (their fits
    are added as starts)."""
    from ...progress import track

    prev = previous or {}
    x0 = prev["base"].theta if "base" in prev else None
    base = evaluate(bound, sigma, folds, groups, x0=x0, budget=budget, seed=seed)
    cands, skipped = [], []
    for eff in track(nested_first(pool), "trying candidate effects", quiet=quiet):
        try:
            cands.append(fit_candidate(model, eff, df, base, data_path, budget, seed, previous=prev.get(eff.name),
                                       fitted={c["effect"].name: c["ev"] for c in cands}))
        except (NotImplementedError, ModelNotRunnable) as exc:
            skipped.append({"effect": eff.name, "reason": str(exc)})
    base, refit_from = consistent_base(base, cands, budget, seed)
    return base, cands, skipped, refit_from


def _modes_key(modes: Mapping[str, str]) -> tuple:
    return tuple(sorted(modes.items()))


def modes_of_best(base: DynEvaluation, cands: Sequence[dict]) -> tuple[dict[str, str], str]:
    """Return (comparison mode per run, the models they come from): the modes (:func:`choose_modes`) of the
    best-fitting models tried, the best available description of the system that made the data.

    "Best" is the smallest in-sample sum of squared residuals on the current rows, and every model within
    2 standard deviations of a chi-square of it (SSE <= SSE_min (1 + 2 sqrt(2 / n)), n rows): models the data
    cannot rank. A run is compared by position if any of them is periodic there (a speed law with n = 1.01 and
    viscous drag fit the same frames to the noise, and one may still be classed irregular where the other
    settles), by its average velocity only if all of them are irregular there.

    Whether a run is irregular is a property of the measured run, not of the model as is: a model that
    misses an effect can be chaotic where the data are periodic (one-sided base fitted to trajectories
    made with a speed law: irregular at every run, while the speed law's response is periodic), and its
    modes would reduce every run to one average-velocity row, too few to tell the effects apart."""
    evs = [("the model as is", base)] + [(c["effect"].name, c["ev"]) for c in cands]
    sse = [float(np.nansum(e.resid ** 2)) if np.isfinite(e.pred).all() else float("inf") for _, e in evs]
    top = min(sse)
    n = max(len(base.resid), 1)
    near = sorted(((v, name, e) for (name, e), v in zip(evs, sse) if v <= top * (1.0 + 2.0 * math.sqrt(2.0 / n))),
                  key=lambda t: t[0])
    modes = {}
    for _, _, e in near:
        for r, m in choose_modes(e.bound, e.theta).items():
            modes[r] = merge_modes(m, modes.get(r, m))
    return modes, " and ".join(name for _, name, _ in near)


def needs_probes(base: DynEvaluation, cands: Sequence[dict]) -> bool:
    """Whether the covariate probes are fitted: no built-in candidate brings the held-out error below
    PROBE_TRIGGER times the model as is's."""
    best = min([c["ev"].cv_rmse for c in cands], default=base.cv_rmse)
    return bool(best > PROBE_TRIGGER * base.cv_rmse)


def noise_excess(ev: DynEvaluation, noise: Mapping | None) -> tuple[float, float, float] | None:
    """Return (held-out RMSE, its value expected from the noise, standard error of the comparison) of ``ev``
    [response unit], as the quasi-static rule weighs a winner's held-out error against the noise
    (:func:`.verdict.noise_expectation`, EXCESS_Z); None when the noise is not known (no reliable SD)."""
    if not noise or not noise.get("reliable", True) or not np.isfinite(float(noise.get("sd", np.nan))):
        return None
    expect, se = noise_expectation(float(noise["sd"]), noise.get("se"), ev.cv_rmse_se, ev.y.size, ev.k,
                                   int(np.unique(ev.folds).size))
    return ev.cv_rmse, expect, se


def probe_verdict(base: DynEvaluation, cands: Sequence[dict], probes: Sequence[dict], verdict: dict,
                  unit: str, alpha: float = ALPHA_EFFECT, noise: Mapping | None = None,
                  covariates: Mapping[str, np.ndarray] | None = None) -> dict:
    """Return the verdict, overridden by a covariate probe when one explains the data better than every
    built-in effect: then an effect that is not built in depends on the probe's covariate.

    A dynamics response is not smooth in the drive (impacts appear and vanish, the speed jumps between
    neighbouring conditions), so the residual-structure tests that name a covariate for quasi-static data
    see scatter, not a trend. Instead a probe (capsule_cli.effects.dynamics: the drive force scaled as
    s (covariate / reference)^b, two free parameters, or the friction level scaled as (covariate / reference)^b,
    one) asks whether a generic dependence on that covariate explains what no built-in does. The friction probe:
    a friction level rising as sqrt(P_d) hidden in 40 conditions (noise 0.5 mm/s) was fitted by no built-in
    nor by the drive probes (held-out 2.0-2.5 mm/s) and read as "nothing is missing" with the noise bounded
    by the speed law's residual SD (2.2): the gap makes the dynamics other than scale-free, so a friction that
    depends on the drive is not a drive force scaled. It overrides when (a) its nested F test against the model
    as is passes at ``alpha`` with Bonferroni over every candidate and probe tried, and (b) its held-out RMSE is
    below the best built-in's by more than PROBE_Z standard errors of the paired difference, or (b') with the noise
    known (``noise``), its held-out RMSE is within EXCESS_Z standard errors of the value expected from the
    noise while the best built-in's exceeds that by more (:func:`noise_excess`): the built-in leaves error
    unexplained that the probe does not. (b') is for misfits concentrated in a few conditions, whose paired
    difference has a large standard error: a coil saturation that is not built in, 40 conditions run by
    continuation down, the probe on P_d held out at 0.87 mm/s against the noise 0.74, a substrate compliance
    at 8.0, better by 7.1 ± 4.2: (b) alone named the compliance. The message says that the probe is not a
    physical model.

    ``covariates`` (name -> values per row, as the rule reads them): when the winning probe's covariate is
    collinear in these data with another (:func:`.verdict.collinear_groups`, |r| >= COLLINEAR_R), the outcome is
    "the data cannot tell" with both named (``confounded``), as the rule says for every covariate it names: a
    function of one is then nearly a function of the other, and which probe fits better is a matter of the
    probes' forms. A friction level linear in a temperature that rose with the frequency (T = 30 C + 0.5 C/Hz
    (f - 15 Hz), 40 conditions, noise 0.5 mm/s) was named "depends on f_Hz" (the f probe held out at 0.583 mm/s,
    the temperature's at 0.647).
    """
    if not probes:
        return verdict
    m = len(cands) + len(probes)
    n = base.y.size
    best_b = min(cands, key=lambda c: c["ev"].cv_rmse) if cands else None
    corr = (noise or {}).get("correlated")
    ok = []
    for p in probes:
        ev = p["ev"]
        # under serially correlated noise (frames of a video track) whitened, as the candidates' F test is
        rss0, rss1 = rss_pair(base.y, summary_of(base), summary_of(ev), corr) if corr else (base.rss, ev.rss)
        _, pv = nested_f_test(rss0, base.k, rss1, ev.k, n)
        p["f_test_p"] = pv
        p["f_test_p_adjusted"] = min(1.0, pv * m) if np.isfinite(pv) else float("nan")
        ref = base if best_b is None or best_b["ev"].cv_rmse > base.cv_rmse else best_b["ev"]
        d, se = crossval.paired_difference(ref.cv_sq, ev.cv_sq, base.groups)
        p["delta_cv_best_builtin"], p["delta_cv_best_builtin_se"] = d, se
        own, other = noise_excess(ev, noise), noise_excess(ref, noise)
        p["at_noise_where_builtin_is_not"] = bool(
            own is not None and other is not None and d > 0 and own[0] <= own[1] + EXCESS_Z * own[2]
            and other[0] > other[1] + EXCESS_Z * other[2])
        passes = bool(np.isfinite(pv) and pv * m < alpha and d > 0
                      and (d > PROBE_Z * se or p["at_noise_where_builtin_is_not"]))
        p["passes"] = passes
        if passes:
            ok.append(p)
    if not ok:
        return verdict
    win = min(ok, key=lambda p: p["ev"].cv_rmse)
    cov = win["effect"].covariates[0]
    vals = win["ev"].bound.values(win["ev"].theta)
    got = [float(vals[prm.name]) for prm in win["effect"].params]
    if getattr(win["effect"], "role", "") == "friction":
        from ...effects.dynamics import PROBE_REFERENCE
        how = f"({cov} / reference)^b" if cov in PROBE_REFERENCE else f"exp(b ({cov} - reference) / scale)"
        form, shown = f"a friction level scaled as {how}", f"b = {got[0]:.3g}"
    else:
        form, shown = f"a drive force scaled as s ({cov} / reference)^b", f"s = {got[0]:.3g}, b = {got[1]:.3g}"
    closest = best_b["effect"].name if best_b else None
    also = list(dict.fromkeys(p["effect"].covariates[0] for p in ok if p["effect"].covariates[0] != cov))
    group = collinear_with(cov, covariates or {})
    cuts = ("No built-in effect explains the data" + (f" (the closest, {closest}, held-out RMSE {base.cv_rmse:.3g} "
                                                       f"-> {best_b['ev'].cv_rmse:.3g} {unit})" if best_b else "")
            + f"; {form}, a covariate probe and not a physical model, cuts it to {win['ev'].cv_rmse:.3g} {unit} "
              f"({shown}, F test {p_text(win['f_test_p'])} x {m} tried")
    if len(group) > 1:
        # the probe's covariate moves with another: a function of one is nearly a function of the other
        others = [c for c in group if c != cov]
        passed = {p["effect"].covariates[0]: p["ev"].cv_rmse for p in ok}
        also_txt = "".join(f"; the probe on {c} cuts it to {passed[c]:.3g} {unit}" for c in others if c in passed)
        msg = (f"the data cannot tell: the missing effect, which is not built in, depends on {' or '.join(group)}, "
               f"which move together in these data (collinear, |r| >= {COLLINEAR_R:g}): they cannot be separated. "
               f"{cuts}){also_txt}. Measure with {others[0]} varied at fixed {cov} (or the other way round) to tell "
               "them apart")
        out = {"outcome": "cannot_tell", "covariate": None, "confounded": group}
    else:
        msg = (f"an effect that is not built in depends on {cov}: write a plugin. {cuts}; "
               f"better than the closest built-in by {win['delta_cv_best_builtin']:.3g} ± "
               f"{win['delta_cv_best_builtin_se']:.2g} {unit}"
               + (", and at the noise level where the built-in is not" if win["at_noise_where_builtin_is_not"]
                  and not win["delta_cv_best_builtin"] > PROBE_Z * win["delta_cv_best_builtin_se"] else "") + ")"
               + (f"; a probe on {', '.join(also)} helps too, less" if also else ""))
        out = {"outcome": "not_built_in", "covariate": cov}
    where = verdict.get("where")
    if where:
        msg += f". Where the model as is fails: {where}"
    return {**verdict, **out, **no_effect_named(), "closest": closest, "message": msg,
            "probe": win["effect"].name}


def run_diagnose(model: Model, df: pd.DataFrame, data_path: str, out_dir, write_model=None, k_folds: int = 5,
                 seed: int = 0, add_best: bool = False, quiet: bool = True, figures: bool = True,
                 budget: Budget = Budget(), candidates: Sequence[str] | None = None,
                 outliers_left_out: Sequence[dict] | None = None, started: float | None = None) -> dict:
    """Diagnose a dynamics model: candidates, verdict (with regime), diagnosis.json/.md, --write-model.

    candidates: names of the effects to try (default: every applicable effect, as the contract says); a
    subset is stated in diagnosis.json (``candidates_tried``) and the verdict's Bonferroni factor counts
    only those tried.

    Rows that no model tried accounts for (progression readings, trajectory frames compared by position:
    :func:`outlier_rows`, after the model as is, the candidates and any covariate probes are fitted) are
    reported and left out, and the table is diagnosed
    again without them (once; ``outliers_left_out``: the records of the rows left out so far, positions in the
    table given, for the later passes, and ``started``: the first pass's start, time.perf_counter(), so that
    budget.seconds counts every pass). Without replicates, when the misfit of the best fit gathers at one value of
    a covariate (:func:`scattered_verdict`), the readings there are left out too (:func:`scattered_rows`, once)
    and the others diagnosed again, outliers among them included (at most three passes).
    """
    from ..compare import data_hash
    from ..diagnose import applicable_effects, outlier_records

    t0 = time.perf_counter() if started is None else started
    out = Path(out_dir)
    pool = applicable_effects(model, df)
    if candidates is not None:  # checked before any work
        unknown = sorted(set(candidates) - {e.name for e in pool})
        if unknown:
            raise InputError(f"candidates {unknown} are not applicable effects of kind {model.kind} "
                             f"(applicable: {', '.join(e.name for e in pool)})")
        pool = [e for e in pool if e.name in set(candidates)]
    bound, noise, sigma, groups, how, folds = _setup(model, df, data_path, k_folds, seed, budget)
    reliable = bool(noise.get("reliable", True))
    base, cands, skipped, refit_from = _fit_all(model, df, data_path, bound, sigma, folds, groups, pool, budget,
                                                seed, quiet)
    modes_from = "the model as is"
    if bound.kind == "trajectory":
        # the runs' comparison modes follow the best-fitting model tried; when they differ from the current
        # ones, every model is refitted on the new rows (its earlier fit a start); at most MODE_PASSES passes.
        # A cycle (the best model on rows A says B, on rows B says A) is settled by comparing by position every
        # run that either says is periodic (positions tell more; a run goes to its average velocity only when
        # both agree it is irregular); a pass already fitted on those rows is reused.
        done = {_modes_key(bound.modes): (bound, groups, how, folds, base, cands, skipped, refit_from, modes_from)}
        for _ in range(MODE_PASSES - 1):
            modes, who = modes_of_best(base, cands)
            if modes == bound.modes:
                break
            if _modes_key(modes) in done:
                modes = {r: merge_modes(m, bound.modes[r]) for r, m in modes.items()}
                who = (f"{who} and {modes_from} (their modes alternate): position wherever either model's "
                       "response is periodic")
                if _modes_key(modes) in done:
                    bound, groups, how, folds, base, cands, skipped, refit_from, _ = done[_modes_key(modes)]
                    modes_from = who
                    break
            bound = DynBound(model, df, where=str(data_path), modes=modes, rk_rtol=budget.rk_rtol)
            groups, how = bound.groups()
            folds = crossval.assign_folds(groups, k_folds, seed)
            prev = {"base": base} | {c["effect"].name: c["ev"] for c in cands}
            base, cands, skipped, refit_from = _fit_all(model, df, data_path, bound, sigma, folds, groups, pool,
                                                        budget, seed, quiet, previous=prev)
            modes_from = who
            done[_modes_key(modes)] = (bound, groups, how, folds, base, cands, skipped, refit_from, modes_from)
    rf = bound.row_frame()
    covs = dynamics_covariates(rf, bound.response)
    z = lambda ev: ev.resid / np.sqrt(row_variance(sigma, ev.sim))  # noqa: E731
    corr = noise.get("correlated")
    if bound.kind == "trajectory" and not corr:
        # frames of a video track: the camera's position noise is often correlated from frame to frame
        corr = serial_noise(rf, [base] + [c["ev"] for c in cands], z)
    probes = []
    if needs_probes(base, cands):
        # no built-in explains the data: which covariate does the missing effect depend on? (probe_verdict)
        # the table's own columns' probes are made for this table (their reference is its median): they replace
        # any of the same name an earlier table left in the registry. Trajectories: over the runs' drives, and
        # a friction level per run
        pool = {pe.name: pe for pe in registry.probes(model.kind)}
        pool |= {pe.name: pe for pe in column_probes(rf, covs, bound.kind)}
        for pe in pool.values():
            if pe.covariates[0] in rf.columns and rf[pe.covariates[0]].nunique() >= 3:
                try:
                    probes.append(fit_candidate(model, pe, df, base, data_path, budget, seed))
                except ModelNotRunnable as exc:
                    skipped.append({"effect": pe.name, "reason": str(exc)})
    left = list(outliers_left_out or ())

    def diagnose_without(found: list[dict]) -> dict:
        # diagnose the table without the rows ``found`` (their positions in ``df``), recorded at their positions
        # in the table given (``df`` is that table without the rows ``left``)
        drop = [o["row"] for o in found]
        table_row = np.delete(np.arange(len(df) + len(left)), sorted(o["row"] for o in left))
        recs = [{**o, **rec, "row": int(table_row[o["row"]])} for o, rec in zip(found, outlier_records(df, drop))]
        return run_diagnose(model, df.drop(index=df.index[drop]).reset_index(drop=True), data_path, out_dir,
                            write_model, k_folds, seed, add_best, quiet, figures, budget, candidates,
                            outliers_left_out=left + recs, started=t0)

    if all(o.get("scattered") for o in left):
        # after the probes: a reading that only a dependence no built-in describes explains is no outlier
        # (a friction level set by a temperature column: the row farthest from the built-ins is the effect's).
        # Once, and again after a level's readings were left out (scattered_rows): the noise bound they held
        # may have hidden a gross reading among the others. Trajectories: a frame the tracker got wrong
        flagged = outlier_rows([base] + [c["ev"] for c in cands + probes], {c: rf[c].to_numpy(float) for c in covs})
        if flagged:
            return diagnose_without(flagged)
    if bound.kind == "progression":
        revised, base = refit_progression(noise, base, cands + probes, budget, seed)
        if revised is not noise:
            noise, sigma, reliable = revised, float(revised["sd"]), True
            # the refined candidates' own values of the shared parameters may fit the model as is better
            base, again = consistent_base(base, cands, budget, seed)
            refit_from = again or refit_from
    struct = record_serial(structure_tests(rf, np.nan_to_num(z(base)), covs, correlation=corr), rf, corr)
    for c in cands:
        c["structure"] = record_serial(structure_tests(rf, np.nan_to_num(z(c["ev"])), covs, correlation=corr), rf,
                                       corr)
    if bound.kind == "trajectory":
        # every model fitted bounds the noise, the probes too (as refit_progression's revision counts them)
        noise = correlated_noise(trajectory_noise(noise, [base] + [c["ev"] for c in cands + probes]), corr)
        reliable = bool(noise.get("reliable", True))
        if reliable and 0 < float(noise["sd"]) < sigma:
            # the spreads (irregular runs, knife edges) weigh against the noise, not against its upper bound
            # from frame differences (as for progressions above)
            base = base.with_sigma(float(noise["sd"]))
            for c in cands + probes:
                c["ev"] = c["ev"].with_sigma(float(noise["sd"]))
    sig_v = float(noise["sd"]) if reliable else sigma
    rho = noise_rho(noise.get("correlated"))  # the frames' noise correlation the runs' drift rates allow for
    # over a few runs the held-out error of a correct model is what its parameters' error makes it on these runs:
    # measured, not taken from the linear model, for the model as is and then for the effect named
    nz = Noise(sig_v, float(noise.get("se") or 0.0), reliable)
    base = with_design_expectation(base, nz, False, budget, seed)
    verdict = dynamics_verdict(base, cands, noise, sig_v, struct, covs, rf)
    named = next((c for c in cands if c["effect"].name == verdict["missing_effect"]), None)
    if named is not None:
        ev_named = with_design_expectation(named["ev"], nz, True, budget, seed)
        if ev_named is not named["ev"]:
            named["ev"] = ev_named
            verdict = dynamics_verdict(base, cands, noise, sig_v, struct, covs, rf)
    cov_values = {c: rf[c].to_numpy(float) for c in covs}
    verdict = probe_verdict(base, cands, probes, verdict, UNIT[model.kind], noise=noise | {"reliable": reliable},
                            covariates=cov_values)
    verdict = blocked_caveat(verdict, rf)
    verdict = concentrated_verdict(verdict, left, base, UNIT[model.kind], cov_values)
    verdict = left_out_level_verdict(verdict, left, base, noise, UNIT[model.kind], cov_values)
    if bound.kind == "progression":
        evs = [base] + [c["ev"] for c in cands + probes]
        verdict = scattered_verdict(verdict, noise, evs, cov_values, UNIT[model.kind])
        if verdict.get("scattered") and not any(o.get("scattered") for o in left):
            # the readings at that value hold the misfit that bounds the noise: leave them out and diagnose the
            # others again (once), so that the noise and every error beside the verdict are theirs
            level = scattered_rows(verdict["scattered"], evs, cov_values, k_folds)
            if level:
                return diagnose_without(level)
        verdict = scattered_caveat(verdict, evs, cov_values, UNIT[model.kind])
    cands.sort(key=lambda c: c["ev"].cv_rmse)
    dh = data_hash(data_path)

    def rec(c):
        pt = param_table(c["ev"])
        return {"effect": c["effect"].name, "origin": c["effect"].origin, "cv_rmse": c["ev"].cv_rmse,
                "cv_rmse_se": c["ev"].cv_rmse_se, "cv_rmse_not_irregular":
                    c["ev"].plain_cv_rmse(predictable(c["ev"].sim, noise["sd"])),
                "delta_cv_rmse": -c["delta_cv"], "delta_cv_rmse_se": c["delta_cv_se"], "delta_bic": c["delta_bic"],
                "rmse": c["ev"].rmse, "n_free": c["ev"].k, "passes": c["passes"], "reason": c["reason"],
                "f_test_p": c["f_test_p"], "f_test_p_adjusted": c["f_test_p_adjusted"], "seconds": c["ev"].seconds,
                "evaluations": c["ev"].bound.n_sim, "knife_edge_runs": knife_edge_records(c["ev"]),
                "held_out_if_true": held_out_record(c["ev"]),
                "params": {k: v for k, v in pt.items() if v["owner"] == c["effect"].name}}

    origins = origins_fitted(base)
    result = {
        "model": model.name, "model_file": model.path, "model_hash": model.hash, "kind": model.kind,
        "base": model.base.name, "effects": model.effect_names, "data": str(data_path), "data_hash": dh,
        "n": int(base.y.size), "n_rows": int(base.y.size) + len(outliers_left_out or ()),
        "outliers": list(outliers_left_out or ()),
        "unit": UNIT[model.kind], "protocol": bound.protocol.__dict__,
        "noise": {"sd": noise["sd"], "se": noise["se"], "method": noise["method"], "reliable": reliable,
                  "correlated": public_record(noise.get("correlated"))},
        "model_as_is": {"cv_rmse": base.cv_rmse, "cv_rmse_se": base.cv_rmse_se, "rmse": base.rmse,
                        "bic": base.bic, "n_free": base.k, "params": param_table(base),
                        "held_out_if_true": held_out_record(base),
                        "by_response_class": by_class(base),
                        "by_run": run_drift_records(run_drift_table(base, sig_v, rho)),
                        **({"origins_fitted_mm": origins, "origins_fitted_meaning": ORIGINS_MEANING}
                           if origins else {})},
        "cv": {"folds": int(np.unique(folds).size), "groups": how},
        "candidates": [rec(c) for c in cands], "skipped_candidates": skipped,
        "residual_structure": struct,
        "collinear_covariates": collinear_groups(cov_values),
        "candidates_tried": [c["effect"].name for c in cands],
        "covariate_probes": [{"probe": p["effect"].name, "covariate": p["effect"].covariates[0],
                              "form": p["effect"].description, "cv_rmse": p["ev"].cv_rmse,
                              "cv_rmse_se": p["ev"].cv_rmse_se, "f_test_p": p.get("f_test_p"),
                              "f_test_p_adjusted": p.get("f_test_p_adjusted"),
                              "better_than_best_builtin_by": p.get("delta_cv_best_builtin"),
                              "better_than_best_builtin_by_se": p.get("delta_cv_best_builtin_se"),
                              "passes": p.get("passes"),
                              "params": {k: v for k, v in param_table(p["ev"]).items() if v["free"]}} for p in probes],
        "covariate_probes_rule": (f"fitted when no built-in candidate brings the held-out RMSE below "
                                  f"{PROBE_TRIGGER:g} x the model as is's; a probe names the covariate when its F "
                                  f"test passes (Bonferroni over candidates and probes) and its held-out RMSE is "
                                  f"below the best built-in's by more than {PROBE_Z:g} standard errors, or, the "
                                  f"noise known, it is within {EXCESS_Z:g} standard errors of the value expected "
                                  f"from the noise while the best built-in's is not"),
        "model_as_is_refitted_from": refit_from,
        "verdict": {k: v for k, v in verdict.items() if k != "where"},
        "where_it_fails": verdict["where"],
        "rule": RULE_TEXT + (" Dynamics: the F test and held-out errors use residuals standardised by the error "
                             "model (noise and the window spread of irregular responses); the regime is the "
                             "response class where the model as is misfits most."
                             + " When no built-in candidate explains the data, covariate probes (the drive force "
                               "or the friction level scaled by a function of one covariate: a drive, or a column "
                               "the table brings; for trajectories a run's) are fitted; one that passes the F test "
                               "(Bonferroni over candidates and probes) and beats every built-in by more than "
                               f"{PROBE_Z:g} standard errors of held-out RMSE, or is held out at the noise where the "
                               "best built-in is not, names its covariate (an effect that is not built in)."
                             + (PROGRESSION_RULE if bound.kind == "progression" else OUTLIER_RULE)),
        "budget": {**budget.__dict__, "seconds": time.perf_counter() - t0,
                   "base_seconds": base.seconds, "base_evaluations": bound.n_sim},
    }
    if bound.kind == "trajectory":
        result["runs_compared_by"] = dict(bound.modes)
        result["runs_compared_by_from"] = (f"the response of {modes_from} (fitted) at each run's drive: "
                                           "irregular (no period up to 8) and its path from rest not "
                                           f"predictable over the run (starts 1-10 um from rest part by more "
                                           f"than {PREDICTABLE_SPREAD_MM:g} mm) -> average_velocity, and "
                                           "position to the last frame before they part when that is at least "
                                           f"{MIN_HORIZON_PERIODS:g} drive periods; else position")
    res = residual_frame(base)
    with staged_folder(out) as stage:  # the whole set or nothing (an interrupt while plotting leaves no table)
        write_table(res, stage / "residuals.parquet", residual_schema(res), _prov(model, seed, df, data_path, dh))
        result["figures"] = []
        if figures:
            _plot_residuals(res, base, stage / "residuals.png", f"{model.name}: residuals by condition and class",
                            covariate=verdict.get("covariate") or verdict.get("confounded"), rho=rho,
                            outliers=drawn_left_out(base, outliers_left_out or ()))
            result["figures"].append("residuals.png")
        if write_model is not None:
            named = next((c for c in cands if c["effect"].name == verdict["missing_effect"]), None)
            chosen = named or (cands[0] if (add_best and cands) else None)
            _write_model(model, chosen, Path(write_model), data_path, verdict, named is not None)
            result["written_model"] = str(write_model)
        write_json_atomic(stage / "diagnosis.json", result)
        write_text_atomic(stage / "diagnosis.md", diagnosis_markdown(result))
    return result


def _write_model(model: Model, chosen, path: Path, data_path, verdict, named: bool) -> Path:
    import yaml

    if chosen is None:
        doc = model.to_yaml_dict(name=model.name, notes="diagnose named no missing effect; model unchanged")
        header = f"# written by capsule-cli diagnose from {model.path} on {data_path}\n# nothing was added.\n"
    else:
        ev = chosen["ev"]
        how = "the verdict's missing effect" if named else "the best-ranked candidate (NOT named by the verdict)"
        doc = chosen["model"].to_yaml_dict(values=ev.bound.values(ev.theta),
                                           name=f"{model.name}+{chosen['effect'].name}",
                                           notes=f"{chosen['effect'].name} added by diagnose ({how}) on {data_path}")
        header = (f"# written by capsule-cli diagnose from {model.path} on {data_path}\n"
                  f"# added: {chosen['effect'].name} ({how}); calibrated values as free start values\n")
    write_text_atomic(path, header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=110))
    return path
