"""Tests for structure left in a model's residuals, and the measurement-noise estimate.

Per covariate (``residual_structure`` of contract section 2, diagnose):

* ``trend`` -- Spearman rank correlation of residual and covariate;
* ``lack_of_fit`` -- one-way ANOVA F test of the residual means across the
  covariate's distinct values when they repeat (replicates), else across
  quantile bins (Draper & Smith, Applied Regression Analysis, 3rd ed., section 2.1);
* ``runs`` -- Wald-Wolfowitz runs test on the residual signs ordered by the
  covariate (one-sided: too few runs means the residuals drift together);
* ``periodogram`` -- for ordered covariates (time, position): the Lomb-Scargle
  periodogram of the linearly detrended residuals (standard normalisation), its
  peak period and false-alarm probability FAP = 1 - (1 - (1 - p)^((N-3)/2))^M over
  M independent frequencies (Scargle 1982, ApJ 263, 835; Horne & Baliunas 1986,
  ApJ 302, 757; Cumming 2004, MNRAS 354, 1165).

Noise (:func:`noise_estimate`): the pooled within-group standard deviation at
identical covariates when replicates exist; otherwise the difference-based
estimator of Gasser, Sroka & Jennen-Steinmetz (1986, Biometrika 73, 625), the
pseudo-residual form of Rice (1984, Ann. Stat. 12, 1215), along each ordering of
the covariates (within trials first), the smallest taken.
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import stats

from ..tables import LABEL_COLUMNS
from ..units import split_unit

#: covariates (base names) whose order is physical (a record along time or position)
ORDERED = ("time", "position")
GROUP_LABELS = ("trial", "run")
#: labels that annotate a row without changing what was measured
NOTE_LABELS = ("source", "note", "id", "label")


def _base(col: str) -> str:
    b, s = split_unit(col)
    return b if s else col


def is_ordered(col: str) -> bool:
    """Return True for covariates that form a record (time, position)."""
    return _base(col) in ORDERED


def trend_test(x, r) -> tuple[float, float]:
    """Return (Spearman rho, two-sided p) of residuals ``r`` against ``x``."""
    x = np.asarray(x, float)
    if np.unique(x).size < 3:
        return float("nan"), float("nan")
    rho, p = stats.spearmanr(x, r)
    return float(rho), float(p)


def lack_of_fit_test(x, r) -> tuple[float, float, str]:
    """Return (F, p, method) of the residual means across the covariate's values or bins."""
    x = np.asarray(x, float)
    r = np.asarray(r, float)
    u, inv = np.unique(x, return_inverse=True)
    if u.size < 2:
        return float("nan"), float("nan"), "none"
    if u.size < x.size and u.size >= 2 and x.size - u.size >= 2:
        groups, method = inv, "replicates"
    else:
        nb = int(np.clip(x.size // 8, 3, 10))
        if x.size < 2 * nb:
            return float("nan"), float("nan"), "none"
        edges = np.quantile(x, np.linspace(0, 1, nb + 1))
        groups = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, nb - 1)
        method = "binned"
    parts = [r[groups == g] for g in np.unique(groups)]
    parts = [q for q in parts if q.size > 0]
    if len(parts) < 2 or sum(q.size for q in parts) - len(parts) < 2:
        return float("nan"), float("nan"), "none"
    if all(q.size < 2 for q in parts):
        return float("nan"), float("nan"), "none"
    F, p = stats.f_oneway(*parts)
    return float(F), float(p), method


def runs_test(x, r) -> tuple[float, float]:
    """Return (z, one-sided p) of the Wald-Wolfowitz runs test on residual signs ordered by ``x``.

    With repeated covariate values the mean residual per value is used (order within ties is arbitrary).
    """
    x = np.asarray(x, float)
    r = np.asarray(r, float)
    u, inv = np.unique(x, return_inverse=True)
    if u.size < x.size:
        r = np.bincount(inv, weights=r) / np.bincount(inv)
    else:
        r = r[np.argsort(x, kind="stable")]
    s = np.sign(r - np.median(r))
    s = s[s != 0]
    n1, n2 = int((s > 0).sum()), int((s < 0).sum())
    n = n1 + n2
    if n < 6 or n1 == 0 or n2 == 0:
        return float("nan"), float("nan")
    runs = 1 + int((s[1:] != s[:-1]).sum())
    mean = 2 * n1 * n2 / n + 1
    var = 2 * n1 * n2 * (2 * n1 * n2 - n) / (n * n * (n - 1))
    if var <= 0:
        return float("nan"), float("nan")
    z = (runs - mean) / math.sqrt(var)
    return float(z), float(stats.norm.cdf(z))


def lomb_scargle(x, r, n_freq_max: int = 4000) -> tuple[float, float, float]:
    """Return (peak power [0-1], false-alarm p, period [unit of x]) of the detrended residuals.

    Frequencies from 2 cycles over the span up to the mean-spacing Nyquist limit,
    oversampled 5 times.
    """
    x = np.asarray(x, float)
    r = np.asarray(r, float)
    n = x.size
    u = np.unique(x)
    if u.size < 12:
        return float("nan"), float("nan"), float("nan")
    T = float(x.max() - x.min())
    A = np.vstack([np.ones_like(x), x - x.mean()]).T
    y = r - A @ np.linalg.lstsq(A, r, rcond=None)[0]
    yy = float(y @ y)
    if yy <= 0:
        return float("nan"), float("nan"), float("nan")
    dx = T / (u.size - 1)
    fmin, fmax = 2.0 / T, 0.5 / dx
    if fmax <= fmin:
        return float("nan"), float("nan"), float("nan")
    nf = int(min(n_freq_max, max(50, 5 * T * (fmax - fmin))))
    f = np.linspace(fmin, fmax, nf)
    w = 2 * np.pi * f[:, None]
    tau = np.arctan2(np.sum(np.sin(2 * w * x), axis=1), np.sum(np.cos(2 * w * x), axis=1)) / (2 * w[:, 0])
    arg = w * (x[None, :] - tau[:, None])
    c, s = np.cos(arg), np.sin(arg)
    with np.errstate(invalid="ignore", divide="ignore"):
        P = 0.5 * ((c @ y) ** 2 / np.sum(c * c, axis=1) + (s @ y) ** 2 / np.sum(s * s, axis=1))
    p = np.clip(2.0 * P / yy, 0.0, 1.0)
    k = int(np.nanargmax(p))
    z = float(p[k])
    single = (1.0 - z) ** (0.5 * (n - 3))
    M = max(1.0, T * (fmax - fmin))
    fap = float(-np.expm1(M * np.log1p(-min(single, 1 - 1e-16)))) if single > 0 else 0.0
    return z, min(max(fap, 0.0), 1.0), float(1.0 / f[k])


def structure_tests(df: pd.DataFrame, residual: np.ndarray, covariates: list[str]) -> list[dict]:
    """Return one record per (covariate, test): {covariate, test, statistic, p_value, periodic_period, method}."""
    out = []
    r = np.asarray(residual, float)
    for col in covariates:
        x = df[col].to_numpy(dtype=float)
        if np.unique(x).size < 2:
            continue
        rho, p = trend_test(x, r)
        if np.isfinite(p):
            out.append({"covariate": col, "test": "trend", "statistic": rho, "p_value": p,
                        "periodic_period": None, "method": "Spearman rank correlation"})
        F, p, how = lack_of_fit_test(x, r)
        if np.isfinite(p):
            out.append({"covariate": col, "test": "lack_of_fit", "statistic": F, "p_value": p,
                        "periodic_period": None, "method": f"one-way ANOVA of residual means ({how})"})
        z, p = runs_test(x, r)
        if np.isfinite(p):
            out.append({"covariate": col, "test": "runs", "statistic": z, "p_value": p,
                        "periodic_period": None, "method": "Wald-Wolfowitz runs of residual signs (one-sided)"})
        if is_ordered(col):
            power, p, period = lomb_scargle(x, r)
            if np.isfinite(p):
                out.append({"covariate": col, "test": "periodogram", "statistic": power, "p_value": p,
                            "periodic_period": period, "method": "Lomb-Scargle, false-alarm probability"})
    m = max(len(out), 1)
    for rec in out:
        rec["p_adjusted"] = min(1.0, rec["p_value"] * m)
    return out


# ---------------------------------------------------------------------------
# noise


def numeric_covariates(df: pd.DataFrame, response: str) -> list[str]:
    """Return numeric covariate columns (no response, no labels)."""
    return [c for c in df.columns if c != response and c not in LABEL_COLUMNS
            and pd.api.types.is_numeric_dtype(df[c])]


def replicate_groups(df: pd.DataFrame, response: str) -> np.ndarray:
    """Return a group id per row: rows with identical covariates (and labels other than trial/run)."""
    keys = [c for c in df.columns if c != response and c not in GROUP_LABELS and c not in NOTE_LABELS]
    if not keys:
        return np.zeros(len(df), int)
    return df.groupby(keys, sort=False, dropna=False).ngroup().to_numpy()


def gasser_sd(x: np.ndarray, y: np.ndarray) -> float:
    """Return the Gasser-Sroka-Jennen-Steinmetz noise SD of ``y`` along the ordered ``x``."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    if y.size < 5:
        return float("nan")
    x0, x1, x2 = x[:-2], x[1:-1], x[2:]
    span = x2 - x0
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.where(span > 0, (x2 - x1) / span, 0.5)
    b = 1.0 - a
    e = a * y[:-2] + b * y[2:] - y[1:-1]
    c2 = a * a + b * b + 1.0
    return float(np.sqrt(np.mean(e * e / c2)))


def _segment_gasser_var(x: np.ndarray, y: np.ndarray, seg: np.ndarray) -> float | None:
    """Return the pooled Gasser variance over contiguous segments ``seg`` of >= 5 rows (None if none).

    Vectorised form of :func:`gasser_sd` per segment, squared and averaged with weights
    (rows - 2): the triples that straddle two segments are left out; O(rows), no per-row Python.
    """
    if y.size < 5:
        return None
    size = np.bincount(seg)
    mid = seg[1:-1]
    ok = (seg[:-2] == seg[2:]) & (size[mid] >= 5)
    if not ok.any():
        return None
    x0, x1, x2 = x[:-2], x[1:-1], x[2:]
    span = x2 - x0
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.where(span > 0, (x2 - x1) / span, 0.5)
    b = 1.0 - a
    e = a * y[:-2] + b * y[2:] - y[1:-1]
    term = e * e / (a * a + b * b + 1.0)
    sums = np.bincount(mid[ok], weights=term[ok], minlength=size.size)
    cnt = np.bincount(mid[ok], minlength=size.size)
    use = (size >= 5) & (cnt > 0)
    return float(np.average(sums[use] / cnt[use], weights=size[use] - 2))


def noise_estimate(df: pd.DataFrame, response: str) -> dict:
    """Return {sd, se, method, dof} of the measurement noise (response unit)."""
    y = df[response].to_numpy(dtype=float)
    g = replicate_groups(df, response)
    counts = np.bincount(g)
    rep = counts[g] >= 2
    dof = int(np.sum(counts[counts >= 2] - 1))
    if dof >= 3 and (counts >= 2).sum() >= 2:
        means = np.bincount(g, weights=y) / counts
        ss = float(np.sum((y[rep] - means[g][rep]) ** 2))
        sd = math.sqrt(ss / dof)
        return {"sd": sd, "se": sd / math.sqrt(2 * dof), "dof": dof, "reliable": True,
                "method": f"replicates: pooled within-group SD at identical covariates "
                          f"({int((counts >= 2).sum())} groups, {dof} degrees of freedom)"}
    covs = numeric_covariates(df, response)
    labels = [c for c in GROUP_LABELS if c in df.columns]
    best, how = float("nan"), ""
    for c in covs:
        if df[c].nunique() < 3:
            continue
        # segments: the trial and the other covariates that take few values; differences restart there
        others = [o for o in covs if o != c and df[o].nunique() <= max(10, len(df) // 10)]
        d = df.reset_index(drop=True)
        order = d.sort_values(labels + others + [c], kind="stable").index.to_numpy()
        x = d[c].to_numpy(dtype=float)[order]
        yy = y[order]
        seg = (d.loc[order, labels + others].groupby(labels + others, sort=False, dropna=False).ngroup().to_numpy()
               if labels + others else np.zeros(y.size, dtype=np.int64))
        var = _segment_gasser_var(x, yy, seg)
        if var is None:
            continue
        sd = math.sqrt(var)
        if not np.isfinite(best) or sd < best:
            best, how = sd, c
    if not np.isfinite(best):
        sd = float(np.std(y, ddof=1)) if y.size > 1 else float("nan")
        return {"sd": sd, "se": sd / math.sqrt(max(2 * (y.size - 1), 1)), "dof": int(y.size - 1), "reliable": False,
                "method": "no replicates and too few points along any covariate: SD of the data (an upper bound)"}
    n = y.size
    return {"sd": best, "se": best / math.sqrt(max(n - 2, 1)), "dof": int(n - 2), "reliable": True,
            "method": f"difference-based (Gasser, Sroka & Jennen-Steinmetz 1986) along {how}"
                      + (f" within each {', '.join(labels)}" if labels else "")
                      + ": no replicates at identical covariates"}
