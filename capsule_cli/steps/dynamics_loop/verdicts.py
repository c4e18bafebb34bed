"""The dynamics verdict: which effect is missing, in which response class and drive regime the misfit
concentrates (``verdict.regime``), and the verdict's words when the misfit sits in one group of rows or in rows
left out of the comparison. The decision rule itself is the quasi-static loop's (:mod:`capsule_cli.steps.verdict`).
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from ...effects.registry import Effect
from .. import crossval
from ..residual_tests import is_ordered, numeric_covariates
from ..verdict import COLLINEAR_R, Noise, collinear_with, decide_verdict
from .bound import UNIT
from .calibration import DynEvaluation
from .noise import noise_rho
from .evaluation import dominant_cause, dominant_group
from .outliers import no_effect_named
from .report import _CLASS_WORDS, box_edges, plain_summary, regime_of, summary_of


def dynamics_verdict(base: DynEvaluation, cands: Sequence[dict], noise: dict, sigma: float, struct: list[dict],
                     covs: Sequence[str], rf: pd.DataFrame) -> dict:
    """Return the verdict for dynamics data: the quasi-static loop's rule plus the regime.

    ``cands``: dicts {effect: Effect, ev: DynEvaluation, structure: residual-structure records of its
    standardised residuals}. The decision is :func:`.verdict.decide_verdict` (nested F test with
    Bonferroni over the candidates tried and lower held-out error; four outcomes), called on the
    standardised errors of :func:`summary_of`. Dynamics-specific parts kept: ``regime`` names the response
    class where the model as is misfits most (:func:`regime_of`; reported only when the outcome is not
    "nothing is missing"), and the message says where the model fails in plain words (:func:`plain_summary`).
    Each candidate dict gains passes, reason, f_test_p, f_test_p_adjusted, delta_cv, delta_cv_se, delta_bic.
    Returns {outcome, missing_effect, covariate, regime, period, partial, closest, more_measurements,
    measure_where, confounded, message, where}.
    """
    unit = UNIT[base.bound.kind]
    what = "velocity" if base.bound.kind == "progression" else "position"
    sums = []
    for c in cands:
        ev = c["ev"]
        own = [x for x in covs if x in set(c["effect"].covariates)]
        sums.append(summary_of(ev, c["effect"].name, own, c.get("structure"), box_edges(ev, c["effect"].name),
                               nests=c["effect"].nests))
        c["delta_cv"], c["delta_cv_se"] = crossval.paired_difference(base.cv_sq, ev.cv_sq, base.groups)
        c["delta_bic"] = ev.bic - base.bic
    reliable = bool(noise.get("reliable", True))
    # only bounded: the verdict states the bound the report states (``sigma`` is the scale of the standardised
    # residuals; a trajectory's difference-based bound is raised for correlated residuals after the fits)
    bound_sd = float(noise.get("sd") or float("nan"))
    shown = sigma if reliable or not (np.isfinite(bound_sd) and bound_sd > 0) else bound_sd
    nz = Noise(float(shown), float(noise.get("se") or 0.0), reliable,
               str(noise.get("method", "")), noise.get("correlated"), str(noise.get("residual_of", "")),
               str(noise.get("residual_because", "no replicates")))
    v = decide_verdict(base.y, summary_of(base), sums, nz, {c: rf[c].to_numpy(float) for c in covs}, struct,
                       base.groups, int(np.unique(base.folds).size),
                       ordered=[c for c in covs if is_ordered(c)], unit=unit, response=what,
                       repeat="a second run at the same drive" if base.bound.kind == "trajectory" else None)
    tests = {t.name: t for t in v.tests}
    for c in cands:
        t = tests[c["effect"].name]
        c["passes"], c["reason"] = bool(t.supported), t.reason
        c["f_test_p"], c["f_test_p_adjusted"] = t.p_value, t.p_adjusted
    where = plain_summary(base, sigma, noise_rho(noise.get("correlated")), reliable)
    regime = None if v.outcome == "nothing_missing" else regime_of(base, sigma)
    msg = v.message
    if v.outcome != "nothing_missing":
        msg += (". Where the model as is fails" + (f" (mostly where {_CLASS_WORDS[regime]})" if regime else "")
                + f": {where}")
    rests = next((c["ev"] for c in cands if c["effect"].name == v.missing_effect), base)
    dom = dominant_group(rests)
    if dom is not None:
        what_g = "run" if base.bound.kind == "trajectory" else "condition"
        msg += (f". One {what_g} ({dom['group']}) holds {100 * dom['share']:.0f} % of the held-out squared error of "
                f"{'the model as is' if rests is base else v.missing_effect} ({dom['cv_rmse']:.3g} {unit}; "
                f"{dom['cv_rmse_without']:.3g} {unit} without it): {dominant_cause(dom, what_g, sigma, unit)}")
    return {"outcome": v.outcome, "missing_effect": v.missing_effect, "covariate": v.covariate, "regime": regime,
            "alternatives": list(v.alternatives), "dominant_group": dom,
            "period": v.period, "partial": v.partial, "closest": v.closest,
            "more_measurements": v.more_measurements, "measure_where": v.where, "confounded": v.confounded,
            "message": msg, "where": where}


# ---------------------------------------------------------------------------
# compare and diagnose


#: columns of a dynamics table that are not covariates of its residuals: the measured responses (a trajectory's
#: magnet track is a second response, not a condition) and a friction level given row by row (an input of the model)
NOT_COVARIATES = ("velocity_mm_s", "capsule_mm", "magnet_mm", "Pf_N")


def dynamics_covariates(rf: pd.DataFrame, response: str) -> list[str]:
    """Return the covariates a dynamics table's residuals are tested against (that vary in it): the drive
    (f_Hz, Pd_N, duty), time_s, then every other numeric column the table brings (a temperature, a mucus
    layer, a specimen's wall thickness, with its unit suffix), in table order: an effect that is not built in
    may depend on what the researcher recorded beside the drive, and the verdict must be able to name it."""
    first = [c for c in ("f_Hz", "Pd_N", "duty", "time_s") if c in rf.columns]
    extra = [c for c in numeric_covariates(rf, response) if c not in first and c not in NOT_COVARIATES]
    return [c for c in first + extra if rf[c].nunique() >= 2]


def column_probes(rf: pd.DataFrame, covs: Sequence[str], kind: str = "progression") -> list[Effect]:
    """Return the friction probes of the table's own covariates (not the drive's, which have theirs; not
    time): a table column that varies over at least three values gets
    :func:`capsule_cli.effects.dynamics.column_friction_probe` with its median and half its range (trajectories:
    a column constant within each run, the runs' friction levels)."""
    from ...effects.dynamics import PROBE_REFERENCE, column_friction_probe

    out = []
    for c in covs:
        if c in PROBE_REFERENCE or c in ("time_s", "duty") or rf[c].nunique() < 3:
            continue
        x = rf[c].to_numpy(float)
        if kind == "trajectory":
            per_run = rf.groupby("run", sort=False)[c]
            if (per_run.nunique() > 1).any():
                continue  # it changes within a run: not a run's friction level
            x = per_run.first().to_numpy(float)
        out.append(column_friction_probe(c, float(np.median(x)), float(np.ptp(x)) / 2.0))
    return out


def concentrated_verdict(verdict: dict, left_out: Sequence[dict], base: DynEvaluation, unit: str,
                         covariates: Mapping[str, np.ndarray]) -> dict:
    """Return the verdict with the readings left out because they gather at one value of a covariate
    (:func:`concentrated_rows`; ``left_out``: the :func:`outlier_rows` records of the first pass) read as
    an effect that is not built in acting there, not as independent gross errors.

    They stay out of the fits (the noise and the held-out errors are those of the other readings, where the model
    may well be right), and the outcome "nothing is missing" becomes "an effect that is not built in" on that
    covariate ("cannot tell" with the covariates named together when it is collinear with another,
    :func:`.verdict.collinear_groups`), with the other readings' verdict kept in the message. Any other outcome
    (a finding, or "the data cannot tell", which a built-in effect fitted short of the noise also gives) is kept,
    with the readings as a caveat. The message says that the readings may also have gone wrong together (one
    session, one specimen) and where to measure again."""
    grp = [o for o in left_out if o.get("concentrated")]
    if not grp:
        return verdict
    at = grp[0]["concentrated"]
    cov, val = at["covariate"], at["value"]
    zs = [o["z"] for o in grp]
    words = (f"{len(grp)} of the {at['of']} readings at {cov} = {val:g} (rows "
             f"{', '.join(str(o['row']) for o in grp)}) are off every model tried by "
             f"{min(zs):.3g}-{max(zs):.3g} noise SDs, more gathered there than independent gross errors would be "
             f"(p = {at['p']:.2g})")
    return _effect_at_value(verdict, words, f"the other {base.y.size} readings", cov, val,
                            collinear_with(cov, covariates), "between it and its neighbours")


def _effect_at_value(verdict: dict, words: str, others: str, cov: str, val: float, group: Sequence[str],
                     beside: str, **keep) -> dict:
    """Return ``verdict`` with readings left out at ``cov`` = ``val`` (``words``: why) read as an effect that is not
    built in acting there (:func:`concentrated_verdict`, :func:`left_out_level_verdict`): "nothing is missing" on
    ``others`` becomes that finding ("cannot tell" when ``group``, the covariates collinear with ``cov``, holds
    more than it), the others' verdict kept in the message; any other outcome is kept with the readings as a
    caveat. ``beside``: where else to measure; ``keep``: keys added to the verdict either way."""
    again = f"measure again at {cov} = {val:g} and {beside}"
    if verdict["outcome"] != "nothing_missing":
        return {**verdict, **keep, "message": f"{verdict['message']}. Besides, {words}: an effect that is not built "
                                              f"in may act there, or those readings went wrong together; {again}"}
    rest = (f"left out of the fits, {others} say: {verdict['message']}. Or those readings went wrong together (one "
            f"session, one specimen): {again}")
    if len(group) > 1:
        msg = (f"the data cannot tell: {words}, and {cov} moves with {', '.join(c for c in group if c != cov)} in "
               f"these data (collinear, |r| >= {COLLINEAR_R:g}): an effect that is not built in acts where they take "
               f"these values; {rest}")
        out = {"outcome": "cannot_tell", "covariate": None, "confounded": list(group)}
    else:
        msg = f"an effect that is not built in acts at {cov} = {val:g}: {words}; {rest}"
        out = {"outcome": "not_built_in", "covariate": cov}
    return {**verdict, **out, **keep, **no_effect_named(), "message": msg,
            "measure_where": {"covariate": cov, "from": val, "to": val}}


def left_out_level_verdict(verdict: dict, left_out: Sequence[dict], base: DynEvaluation, noise: Mapping, unit: str,
                           covariates: Mapping[str, np.ndarray]) -> dict:
    """Return the verdict on the readings kept once those at the value of a covariate where the misfit gathered
    were left out (:func:`scattered_rows`; ``left_out``: the records of the earlier passes), read as an effect that
    is not built in acting there, as :func:`concentrated_verdict` reads flagged readings that gather.

    "Nothing is missing" on the others becomes "an effect that is not built in acts at Pd_N = 0.2" ("cannot
    tell" with the covariates named together when it is collinear with another), with the others' verdict and
    their noise (``noise``) beside the bound the misfit held; any other outcome is kept, with the level as a
    caveat."""
    grp = [o for o in left_out if o.get("scattered")]
    if not grp:
        return verdict
    at = grp[0]["scattered"]
    cov, val = at["covariate"], at["value"]
    words = (f"the best-fitting model tried ({at['model']}) missed the {len(grp)} readings at {cov} = {val:g} (rows "
             f"{', '.join(str(o['row']) for o in grp)}) by an RMS of {at['rms']:.3g} {unit} against "
             f"{at['rms_other']:.3g} {unit} at the others (Mann-Whitney test of their size p = {at['p']:.2g}, "
             f"Bonferroni over {at['tests']} values), and held the noise bound at {at['noise_bound']:.3g} {unit}")
    group = at.get("collinear") or collinear_with(cov, covariates)  # on the whole table, as the level was read
    return _effect_at_value(verdict, words, f"the other {base.y.size} readings (noise {float(noise['sd']):.3g} {unit})",
                            cov, val, group, "beside it", scattered=at)
