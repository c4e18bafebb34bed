"""The measurement noise of dynamics data and the correlation of its residuals.

Progression: replicates pooled over the conditions no fit predicts chaotic, else bounded by the fits' standardised
residual SD (:func:`progression_noise`). Trajectory: the frames' scatter about each run's smooth path
(:func:`trajectory_noise`), the lag-1 correlation of the residuals from frame to frame (:func:`serial_noise`),
and the noise of the table as the loop estimates it before any fit (:func:`noise_of`).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np
import pandas as pd

from ...errors import InputError
from ..residual_tests import correct_for_correlation, is_ordered, noise_estimate, replicate_groups, serial_correlation
from .bound import (DynBound, at_rest, MIN_NOISE_FRAMES, MULTISTABLE_SPREAD_FRACTION, frames_by_position, position_rows,
                    row_variance)
from .calibration import DynEvaluation


def simulated_everywhere(evs: Sequence[DynEvaluation]) -> list[DynEvaluation]:
    """Return the evaluations whose fitted model was simulated on every comparison row (a run or
    condition the engine could not simulate has no prediction, so its residuals would leave those rows
    out, and a fit failing everywhere would read as a perfect one: a residual SD of 0)."""
    return [e for e in evs if bool(np.all(np.isfinite(e.pred)))]


def trajectory_noise(noise: dict, evs: Sequence[DynEvaluation]) -> dict:
    """Return the position-noise estimate of a trajectory table: the smaller of the difference-based
    estimate and the residual SD sqrt(RSS / (n - k)) of the best-fitting model tried (in-sample).

    Frames at 100 per second undersample a capsule that moves in steps at 30-40 Hz, so differences of
    successive frames hold signal, not only noise (the difference-based estimate was 40-130 times the
    generating 0.05 mm in the tests); without replicates the residuals of the most flexible fitted model
    are the other bound. Both are upper bounds of the noise; the smaller is used and the method says which.
    """
    pos = frames_by_position(evs[0].bound.rows)
    evs = simulated_everywhere(evs)
    if not evs:
        return noise
    best = min(evs, key=lambda e: float(np.sum(e.resid[pos] ** 2)))
    n, k = int(pos.sum()), best.k
    if n - k < MIN_NOISE_FRAMES:
        # the frames compared by position are too few to estimate the position noise from the residuals
        # (an average-velocity row's residual holds the model's error of a whole run, not the camera's noise)
        return {**noise, "reliable": False,
                "method": f"{noise.get('method', '')}; frames that undersample the motion inflate it and only {n} "
                          "frames are compared by position: an upper bound of the noise"}
    sd = math.sqrt(float(np.sum(best.resid[pos] ** 2)) / (n - k))
    if np.isfinite(noise["sd"]) and noise["sd"] <= sd:
        return noise  # replicates (an estimate), or the smaller of two bounds (still a bound)
    return _residual_noise(noise, sd, best, f"{n} frames compared by position, {k} free parameters",
                           "which frames that undersample the motion inflate; an upper bound of the noise")


def _model_label(ev: DynEvaluation) -> str:
    """Return the name of ``ev``'s model in a noise method: its effects joined by +, or "the model as is"."""
    return "+".join(ev.bound.model.effect_names) or "the model as is"


def _residual_noise(noise: dict, sd: float, best: DynEvaluation, what: str, why: str,
                    other: str = "difference-based estimate") -> dict:
    """Return ``noise`` with its SD replaced by ``sd``, the residual SD of ``best`` (n - k degrees of
    freedom), and the method saying so (``what``: the rows and parameters; ``why``: why not ``other``, the
    estimate it replaces)."""
    n, k = best.y.size, best.k
    name = _model_label(best)
    return {**noise, "sd": sd, "se": sd / math.sqrt(2 * (n - k)), "dof": int(n - k), "reliable": True,
            "correlated": None, "residual_of": name,
            "method": (f"residual SD of the best-fitting model tried ({name}, {what}): smaller than the "
                       f"{other} ({noise['sd']:.3g}), {why}")}


def serial_noise(rf: pd.DataFrame, evs: Sequence[DynEvaluation], z) -> dict | None:
    """Return the serial correlation of the position noise along time within each trajectory run
    (:func:`.residual_tests.serial_correlation`: lag-1 correlation, p < 0.01), or None.

    Computed on the residuals ``z(ev)`` (standardised by the error model) of the best-fitting model tried, as
    the quasi-static loop does, so that a missing effect one candidate describes is not taken for correlated
    noise. A video track's position noise is often correlated from frame to frame (the tracker's template
    and the blur of a moving capsule change slowly); independent tests along time would then read the
    noise's slow wander as structure: null data with AR(1) position noise (lag-1 correlation 0.8 at 100
    frames/s, SD 0.2 mm, five 1.5-s runs) gave "an effect that is not built in depends on time_s" (runs test
    p = 2.4e-14). With the correlation the rule tests along time against it (periodogram against red noise,
    F tests on whitened residuals; residual_tests.structure_tests, verdict.rss_pair)."""
    cols = [c for c in rf.columns if is_ordered(c)]
    evs = simulated_everywhere(evs)
    if not cols or not evs:
        return None
    best = min(evs, key=lambda e: float(np.sum(np.nan_to_num(z(e)) ** 2)))
    return serial_correlation(rf, np.nan_to_num(z(best)), cols)


def _ls_slope(t: np.ndarray, r: np.ndarray) -> float:
    """Return the least-squares slope of ``r`` over ``t`` (NaN when ``t`` does not vary)."""
    sxx = float(np.sum((t - t.mean()) ** 2)) if t.size else 0.0
    return float(np.sum((t - t.mean()) * (r - r.mean())) / sxx) if sxx > 0 else float("nan")


def detrended_by_run(rf: pd.DataFrame, r: np.ndarray) -> np.ndarray:
    """Return ``r`` less each trajectory run's least-squares line over ``time_s`` (rows compared by position;
    the others as they are): what is left of a residual about the run's drift rate (:func:`run_residual_rates`)."""
    out = np.asarray(r, float).copy()
    pos = position_rows(rf)
    t_all = rf["time_s"].to_numpy(float)
    for idx in rf.index[pos].groupby(rf.loc[pos, "run"].astype(str)).values():
        i = rf.index.get_indexer(idx)
        t, v = t_all[i], out[i]
        ok = np.isfinite(t) & np.isfinite(v)
        t, v, i = t[ok], v[ok], i[ok]
        if t.size >= 3 and np.ptp(t) > 0:
            out[i] = v - v.mean() - _ls_slope(t, v) * (t - t.mean())
    return out


def noise_rho(corr: dict | None) -> float:
    """Return the lag-1 correlation of the noise from frame to frame in a serial-correlation record
    (:func:`serial_noise`), 0 when there is none (white noise)."""
    return float(corr["rho"]) if corr and corr.get("rho") is not None else 0.0


def public_record(corr: dict | None) -> dict | None:
    """Return a serial-correlation record without its private keys (``_order``, ``_segment``), for JSON."""
    return {k: v for k, v in corr.items() if not k.startswith("_")} if corr else None


def record_serial(struct: list[dict], rf: pd.DataFrame, corr: dict | None) -> list[dict]:
    """Return the structure records with the tests along a covariate that is constant within each record of
    serially correlated readings (a trajectory run's drive: f_Hz, Pd_N) marked ``serial``, as
    :func:`.residual_tests.structure_tests` marks those along time: correlated noise makes each run's mean
    residual wander (its variance grows by about (1 + rho) / (1 - rho)), so the runs' means differ by more
    than independent frames allow, with nothing missing (AR(1) noise, lag-1 correlation 0.74: lack of fit
    along f_Hz p = 1e-8 on null data). A dependence on a run's drive is then told only by a candidate that
    passes the whitened F test, or not at all ("the data cannot tell": replicate runs would)."""
    if not corr:
        return struct
    seg = np.asarray(corr["_segment"])
    if np.unique(seg).size < 2:
        return struct
    out = []
    for rec in struct:
        col = rec["covariate"]
        if not rec.get("serial") and rec["test"] != "periodogram" and col in rf.columns:
            per_record = rf[col].groupby(seg).nunique(dropna=False)
            if bool((per_record <= 1).all()):
                rec = {**rec, "serial": True,
                       "method": rec["method"] + f" (constant within each record along {corr['covariate']})"}
        out.append(rec)
    return out


def blocked_in_row_order(values) -> bool:
    """Whether a covariate's levels each occupy one contiguous block of the table's rows (two levels or more):
    the order of a sweep measured one level after another."""
    v = pd.Series(values).astype(str).to_numpy()
    levels = np.unique(v).size
    return bool(levels >= 2 and int(np.sum(v[1:] != v[:-1])) == levels - 1)


def blocked_caveat(verdict: dict, rf: pd.DataFrame) -> dict:
    """Return the verdict with a caveat when it names a covariate of a progression table (not built in) whose
    levels are blocks of the table's rows: if the readings were taken in that order, anything that drifted
    over the session (temperature, wear, a film drying) changes with that covariate too, and a progression
    table has no time column to tell them apart. Null data with AR(1) noise along the rows (lag-1 correlation
    0.7, 40 conditions, one P_d level after another) gave "an effect that is not built in depends on Pd_N"
    (lack of fit p = 7e-4 and 1.8e-3, 2 of 2 seeds). The finding stands; the message says what else it can be,
    and ``verdict.blocked_in_row_order`` is set."""
    cov = verdict.get("covariate")
    if verdict.get("outcome") != "not_built_in" or not cov or cov not in rf.columns or "time_s" in rf.columns \
            or not blocked_in_row_order(rf[cov].to_numpy()):
        return verdict
    return {**verdict, "blocked_in_row_order": True,
            "message": verdict["message"] + (f". The table holds each {cov} level as one block of rows: if they "
                                              "were measured in that order, a drift over the session would look "
                                              f"the same (measure the {cov} levels in a shuffled order, or "
                                              "repeat the first one at the end, to tell)")}


def correlated_noise(noise: dict, corr: dict | None) -> dict:
    """Return ``noise`` marked serially correlated (``corr``, :func:`serial_noise`): the method says so, and
    the standard error of an SD estimated from residuals grows by sqrt((1 + rho^2) / (1 - rho^2)) (the
    variance of a sample variance of AR(1) readings; Bartlett 1946), so that the held-out error is weighed
    against the noise with the uncertainty correlated readings leave. Difference-based and replicate
    estimates are left to :func:`.residual_tests.correct_for_correlation`."""
    if not corr:
        return noise
    out = correct_for_correlation(noise, corr)
    if not str(noise.get("method", "")).startswith(("difference-based", "replicates")):
        rho = float(corr["rho"])
        out["se"] = float(noise["se"]) * math.sqrt((1 + rho ** 2) / (1 - rho ** 2))
    return out


def standardised_residual_sd(ev: DynEvaluation, keep: np.ndarray | None = None) -> float:
    """Return the noise SD sigma that solves sigma^2 = sum_i r_i^2 sigma^2 / (sigma^2 f_i^2 + s_i^2) / (n - k):
    the residual SD of the in-sample fit under the error model (s_i the model's spread, f_i the row's noise
    factor, :func:`row_variance`; with neither, the plain sqrt(RSS / (n - k))), over the rows ``keep`` (a bool
    mask; default every row, n of them). Fixed-point iteration from the value without spread (it only
    decreases)."""
    keep = np.ones(ev.y.size, bool) if keep is None else np.asarray(keep, bool)
    r2 = np.nan_to_num(ev.resid ** 2, nan=0.0)[keep]
    s2 = (np.nan_to_num(ev.sim["spread"]) ** 2 * np.ones(ev.y.size))[keep]
    f2 = (row_variance(1.0, {"spread": np.zeros(ev.y.size), "noise_factor": ev.sim.get("noise_factor")})
          * np.ones(ev.y.size))[keep]
    dof = max(int(keep.sum()) - ev.k, 1)
    sig2 = float(np.sum(r2 / f2)) / dof
    for _ in range(200):
        if sig2 <= 0:
            return 0.0
        new = float(np.sum(r2 * sig2 / (sig2 * f2 + s2))) / dof
        if abs(new - sig2) <= 1e-10 * sig2:
            break
        sig2 = new
    return math.sqrt(max(sig2, 0.0))


#: fewest degrees of freedom of replicates at conditions not predicted chaotic for a noise estimate from them
#: (residual_tests.noise_estimate asks the same of a table's replicates)
MIN_REPLICATE_DOF = 3


def replicate_noise_without_chaos(noise: dict, best: DynEvaluation) -> dict | None:
    """Return the replicate noise estimate of a progression table pooled over the conditions
    whose response ``best`` (the best-fitting model tried) does not predict chaotic, ``noise`` itself when it
    predicts none so, or None when fewer than MIN_REPLICATE_DOF degrees of freedom of replicates would be
    left (:func:`progression_noise` then bounds the noise by the fit).

    A replicate of a chaotic condition (another recorded window, as a lab's repeat) differs from the first
    reading by the chaos as well as by the instrument's noise; that spread is the error model's
    (``sim['spread']``), so pooled into the noise it counts twice and shrinks every standardised error.
    Continuation up, 12 conditions x 2 replicates, a secondary constraint at the prototype's values hidden,
    noise 0.5 mm/s: the replicates of every condition gave 7.2 mm/s. Chaotic here: irregular (no period <= 8)
    with a spread over windows and starts of at least MULTISTABLE_SPREAD_FRACTION of the noise SD, iterated to
    a fixed point (at most 5 rounds), as the spread's threshold moves with the estimate. Kept: an irregular
    response without spread (a long period, the same in every window: null sweeps, continuation up, hold two
    or three) and a periodic one with coexisting attractors (a later window stays on its attractor). Leaving
    those out cost null sweeps their degrees of freedom: one of the first 47 seeds of the up sweep went from
    "nothing is missing" to "the data cannot tell" (0.58 -> 0.24 mm/s).

    The estimate is the table's own (residual_tests.noise_estimate, its outlier test included) on the rows
    left: a condition the fit predicts periodic whose replicates differ grossly (the fit wrong there, or a
    repeat on another attractor) is an outlier like any other."""
    cls = np.asarray(best.sim["cls"]).astype(str)
    spread = np.nan_to_num(np.asarray(best.sim["spread"], float))
    df = best.bound.df.reset_index(drop=True)
    resp = best.bound.response
    sd, rows, out = float(noise["sd"]), None, noise
    for _ in range(5):
        keep = ~((cls == "irregular") & (spread >= MULTISTABLE_SPREAD_FRACTION * sd))
        if rows is not None and np.array_equal(keep, rows):
            break
        rows = keep
        if keep.all():
            return noise
        est = noise_estimate(df[keep], resp)
        if not str(est.get("method", "")).startswith("replicates") or est["dof"] < MIN_REPLICATE_DOF:
            return None
        idx = np.flatnonzero(keep)
        left_out = int(replicate_groups(df[~keep], resp).max(initial=-1) + 1)
        out = {**est, "outliers": [int(idx[i]) for i in est.get("outliers", [])],
               "method": (f"{est['method']}, over the conditions {_model_label(best)} (the best-fitting model tried) "
                          f"does not predict chaotic: the replicates of {left_out} chaotic conditions left out (they "
                          f"differ by the chaos too, which the error model's spread holds; all conditions: "
                          f"{float(noise['sd']):.3g})")}
        sd = float(est["sd"])
    return out


def residual_fits(evs: Sequence[DynEvaluation]) -> list[tuple[float, DynEvaluation]]:
    """Return (standardised residual SD, evaluation) of each fit in ``evs`` simulated on every row and left with at
    least 3 residual degrees of freedom: the fits a progression's noise bound and outlier test are read from."""
    return [(standardised_residual_sd(e), e) for e in simulated_everywhere(evs) if e.y.size - e.k >= 3]


def progression_noise(noise: dict, evs: Sequence[DynEvaluation]) -> dict:
    """Return the noise estimate of a progression table after the fits ``evs``.

    Without replicates: the smaller of the difference-based estimate and the smallest standardised residual
    SD (:func:`standardised_residual_sd`, n - k degrees of freedom) of the models tried. Differences of
    neighbouring conditions measure the noise only where the response is smooth along the covariate; a
    progression speed jumps between neighbouring frequencies as impacts appear and vanish (40-condition
    grid, 0.5 mm/s noise, one value per condition: 20.6 mm/s from differences). Both are upper bounds of
    the noise; the smaller is used and the method says which.

    With replicates: the replicate estimate over the conditions the best-fitting model does not predict
    chaotic (:func:`replicate_noise_without_chaos`).
    """
    if not evs:
        return noise
    fits = residual_fits(evs)
    if not fits:
        return noise
    sd, best = min(fits, key=lambda t: t[0])
    why = ("which a speed that jumps between neighbouring conditions inflates; no replicates: an upper bound of "
           "the noise")
    replicated = str(noise.get("method", "")).startswith("replicates")
    if replicated:
        calm = replicate_noise_without_chaos(noise, best)
        if calm is not None:
            return calm
        # the replicates of the conditions not predicted chaotic are too few: the pooled estimate (which holds
        # the chaotic conditions' spread) and the fit's standardised residual SD are both upper bounds
        why = (f"whose replicates of chaotic conditions hold the chaos, the others' too few for an estimate "
               f"(fewer than {MIN_REPLICATE_DOF} degrees of freedom)")
    if not (sd > 0) or (np.isfinite(noise["sd"]) and noise["sd"] <= sd):
        return noise
    out = _residual_noise(noise, sd, best, f"{best.y.size} conditions, {best.k} free parameters, standardised by "
                          "the model's spread where the response is irregular", why,
                          "pooled replicate estimate" if replicated else "difference-based estimate")
    if replicated:
        out["residual_because"] = "too few replicates where the fits predict no chaos"
    return out


def noise_of(bound: DynBound) -> dict:
    """Return the measurement-noise estimate of the table (residual_tests.noise_estimate).

    progression: replicates (identical conditions) when present, else difference-based along the
    covariates, marked not reliable (an upper bound; :func:`progression_noise` revises it after the fits);
    trajectory: replicate runs (the same drive) when present, else difference-based along time within
    each run (position noise), marked not reliable (frames undersample the motion: an upper bound;
    :func:`trajectory_noise` revises it after the fits).
    """
    resp = bound.response
    df = bound.df
    if bound.kind == "trajectory":
        # differences along time within each run; frames at the same time are replicates only in runs with
        # the same drive (the drive as one text label: runs at other drives share frame times, not positions)
        drive = df["run"].astype(str).map(lambda r: "|".join(map(str, bound.run_drive[r])))
        df = df[[c for c in ("run", "time_s", resp) if c in df.columns]].assign(drive=drive)
    noise = noise_estimate(df, resp)
    if bound.kind == "trajectory" and not str(noise.get("method", "")).startswith("replicates"):
        # frames undersample a capsule that moves in steps at the drive frequency: an upper bound
        # (compare and diagnose revise it: trajectory_noise)
        noise = {**noise, "reliable": False,
                 "method": f"{noise.get('method', '')}; frames undersample a capsule that moves in steps: "
                           "an upper bound of the noise"}
    if bound.kind == "progression" and not str(noise.get("method", "")).startswith("replicates"):
        # a progression speed jumps between neighbouring conditions (impacts appear and vanish), so the
        # differences hold signal: a bound, not an estimate (diagnose revises it: progression_noise)
        noise = {**noise, "reliable": False,
                 "method": f"{noise.get('method', '')}; no replicates, and the speed is not smooth between "
                           "neighbouring conditions: data spread, an upper bound of the noise"}
    return noise


#: a trajectory frame at t = 0 more than this many times the position noise's upper bound from successive frames
#: (:func:`check_rest_origin`) from the rest position is taken for a table whose positions are not measured from
#: it. That bound holds the motion between frames (1.5-2 mm at 100 frames per second against a noise of 0.05-0.3
#: mm in the benchmarks' tables), so only an origin far off is caught, and not a tracker's lost frame of a few mm
#: (the outlier screen's: :func:`.outliers.outlier_rows`); differences of AR(1) noise understate its SD
#: (by 0.38 at a lag-1 correlation of 0.8), which leaves a frame of a correct table beyond the threshold with
#: p ~ 1e-4 at worst.
ORIGIN_Z = 10.0


def check_rest_origin(bound: DynBound) -> None:
    """Raise InputError when a trajectory run's frame at t = 0 is far from the rest position.

    Every run starts from rest at the origin at drive phase 0 (contract section 4; :func:`.bound.run_drift`), so its
    position there is the camera's noise alone, whatever the parameters. The scale is the difference-based
    estimate along time within each run (:func:`.residual_tests.noise_estimate`, runs never taken as replicates of
    each other): an upper bound of the noise, free of any offset. A frame at time_s = 0 more than ORIGIN_Z times
    that far from 0 [mm] is a table whose positions are measured from another origin (a tracker's image
    coordinates), or a frame the tracker lost. Left in, every model misses by the offset, and diagnose named the
    candidate that bends furthest towards it (four runs shifted by 0.7-55 mm, nothing missing: "adding
    substrate_compliance cuts held-out RMSE from 35.7 to 35.4 mm"). Runs without a frame at t = 0 are not checked
    (the capsule moves 0.6-3 mm within the first 10 ms at 20-40 Hz). A run zeroed at its first frame passes, and
    its origin is fitted (:func:`.bound.zeroed_runs`)."""
    if bound.kind != "trajectory":
        return
    df = bound.df
    at0 = np.flatnonzero(at_rest(df["time_s"]))
    if not at0.size:
        return
    for col in ("capsule_mm", "magnet_mm"):
        if col not in df.columns:
            continue
        sd = float(noise_estimate(df[["run", "time_s", col]].assign(drive=df["run"].astype(str)), col)["sd"])
        if not (np.isfinite(sd) and sd > 0):
            continue
        x = df[col].to_numpy(float)[at0]
        far = np.flatnonzero(np.isfinite(x) & (np.abs(x) > ORIGIN_Z * sd))
        if far.size:
            i = int(at0[far[0]])
            raise InputError(
                f"{bound.where}: column '{col}' row {i + 1}: run '{df['run'].iloc[i]}' is at {x[far[0]]:.4g} mm at "
                f"time_s = 0, where every run starts from rest at the origin; that is {abs(x[far[0]]) / sd:.0f} "
                f"times the position noise's upper bound ({sd:.3g} mm, from successive frames): measure each run's "
                "positions from the capsule's rest position (subtract it, or subtract the run's first frame: such a "
                "run's origin is then fitted), or drop the frame if the tracker lost the marker there")
