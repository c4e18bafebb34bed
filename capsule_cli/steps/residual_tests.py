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
  ApJ 302, 757; Cumming 2004, MNRAS 354, 1165); below 60 points M is calibrated by
  simulation (400 detrended white-noise records at the same x; M matches their 90th
  percentile of the peak power), since M = T (f_max - f_min) is too small for short records.

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

from .. import distributions as dist
from ..tables import LABEL_COLUMNS
from ..units import split_unit

#: covariates (base names) whose order is physical (a record along time or position)
ORDERED = ("time", "position")
GROUP_LABELS = ("trial", "run")
#: labels that annotate a row without changing what was measured
NOTE_LABELS = ("source", "note", "id", "label")
#: family false-alarm rate of the outlier flags over all rows of a table (Bonferroni, Student's t with the
#: scale's degrees of freedom; measured: 0-2.5 % of tables with nothing wrong get a flag, 6-200 rows, pairs and
#: groups of four replicates)
OUTLIER_ALPHA = 0.02
#: significance of serial correlation of the noise along time/position
CORRELATION_ALPHA = 0.01


#: segments of 3-4 points (a grid without replicates) give a noise estimate only from this many pseudo-residuals
MIN_PSEUDO_SHORT = 6


def _base(col: str) -> str:
    b, s = split_unit(col)
    return b if s else col


def is_ordered(col: str) -> bool:
    """Return True for covariates that form a record (time, position)."""
    return _base(col) in ORDERED


def trend_test(x, r) -> tuple[float, float]:
    """Return (Spearman rho, two-sided p) of residuals ``r`` against ``x``; p by permutation up to 60 points
    (:func:`capsule_cli.distributions.spearman_permutation_p`: Student's t approximation rejects too often in
    the tails a Bonferroni family uses)."""
    x = np.asarray(x, float)
    if np.unique(x).size < 3:
        return float("nan"), float("nan")
    rho, p = dist.spearman_permutation_p(x, r)
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
    F, p = dist.f_oneway(*parts)
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
    return float(z), dist.norm_cdf(z)


#: below this many points the periodogram's false-alarm probability is simulated (the analytic
#: approximation is anti-conservative for short records)
LS_SIMULATE_BELOW = 60
LS_SIMULATIONS = 400


def _ls_power(x: np.ndarray, Y: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Return the normalised Lomb-Scargle power (fraction of variance) of each column of Y at frequencies f."""
    w = 2 * np.pi * f[:, None]
    tau = np.arctan2(np.sum(np.sin(2 * w * x), axis=1), np.sum(np.cos(2 * w * x), axis=1)) / (2 * w[:, 0])
    arg = w * (x[None, :] - tau[:, None])
    c, s = np.cos(arg), np.sin(arg)
    with np.errstate(invalid="ignore", divide="ignore"):
        P = 0.5 * ((c @ Y) ** 2 / np.sum(c * c, axis=1)[:, None] + (s @ Y) ** 2 / np.sum(s * s, axis=1)[:, None])
    return 2.0 * P / np.sum(Y * Y, axis=0)[None, :]


def lomb_scargle(x, r, n_freq_max: int = 4000, rho: float = 0.0) -> tuple[float, float, float]:
    """Return (peak power [0-1], false-alarm p, period [unit of x]) of the detrended residuals.

    Frequencies from 2 cycles over the span up to the mean-spacing Nyquist limit,
    oversampled 5 times. With ``rho`` > 0 (AR(1) noise of lag-1 correlation rho at the mean
    spacing) each frequency's power is divided by the red-noise spectrum
    (1 - rho^2) / (1 - 2 rho cos(2 pi f dx) + rho^2), floored at the white level 1, before the
    false-alarm probability (exponential law of the periodogram over its expected value).
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
    M = max(1.0, T * (fmax - fmin))
    if rho > 0:
        # power over the AR(1) spectrum (mean 1) in units of the variance: exponential under the null
        # never below the white level: leakage from the strong low frequencies would otherwise pass for
        # a period at high frequencies, where the AR(1) spectrum is tiny
        red = np.maximum((1 - rho * rho) / (1 - 2 * rho * np.cos(2 * np.pi * f * dx) + rho * rho), 1.0)
        zr = P / (yy / n) / red
        k = int(np.nanargmax(zr))
        single = float(np.exp(-zr[k]))
        fap = float(-np.expm1(M * np.log1p(-min(single, 1 - 1e-16)))) if single > 0 else 0.0
        return float(2.0 * P[k] / yy), min(max(fap, 0.0), 1.0), float(1.0 / f[k])
    p = np.clip(2.0 * P / yy, 0.0, 1.0)
    k = int(np.nanargmax(p))
    z = float(p[k])
    if n < LS_SIMULATE_BELOW:
        # false-alarm probability by simulation: the largest power of white-noise records at the same x,
        # detrended alike (fixed seed)
        rng = np.random.default_rng(12345)
        Y = rng.standard_normal((n, LS_SIMULATIONS))
        Y = Y - A @ np.linalg.lstsq(A, Y, rcond=None)[0]
        peak = np.nanmax(_ls_power(x, Y, f), axis=0)
        # the number of independent frequencies M that makes the analytic law match the simulated 90th
        # percentile; the tail then follows the analytic law with that M
        s90 = (1.0 - float(np.quantile(peak, 0.9))) ** (0.5 * (n - 3))
        M = max(1.0, math.log(0.1) / math.log1p(-min(max(s90, 1e-300), 1 - 1e-16)))
        single = (1.0 - z) ** (0.5 * (n - 3))
        fap = float(-np.expm1(M * np.log1p(-min(single, 1 - 1e-16)))) if single > 0 else 0.0
        return z, min(max(fap, 0.0), 1.0), float(1.0 / f[k])
    single = (1.0 - z) ** (0.5 * (n - 3))
    fap = float(-np.expm1(M * np.log1p(-min(single, 1 - 1e-16)))) if single > 0 else 0.0
    return z, min(max(fap, 0.0), 1.0), float(1.0 / f[k])


def structure_tests(df: pd.DataFrame, residual: np.ndarray, covariates: list[str],
                    correlation: dict | None = None) -> list[dict]:
    """Return one record per (covariate, test): {covariate, test, statistic, p_value, periodic_period, method}.

    With ``correlation`` (serially correlated residuals, :func:`serial_correlation`) the periodogram
    of ordered covariates is tested against the AR(1) red-noise spectrum (Schulz & Mudelsee 2002,
    Comput. Geosci. 28, 421), and the trend, lack-of-fit and runs tests along ordered covariates are
    marked ``serial: True``: correlated noise alone makes them fire, so they are no evidence of an effect.
    """
    out = []
    r = np.asarray(residual, float)
    ar1 = correlation["rho"] if correlation else 0.0
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
            power, p, period = lomb_scargle(x, r, rho=ar1)
            if np.isfinite(p):
                out.append({"covariate": col, "test": "periodogram", "statistic": power, "p_value": p,
                            "periodic_period": period, "method": "Lomb-Scargle, false-alarm probability"})
    m = max(len(out), 1)
    for rec in out:
        rec["p_adjusted"] = min(1.0, rec["p_value"] * m)
        rec["serial"] = bool(correlation) and is_ordered(rec["covariate"]) and rec["test"] != "periodogram"
        if correlation and is_ordered(rec["covariate"]) and rec["test"] == "periodogram":
            rec["method"] += f" against AR(1) red noise (rho = {ar1:.2f})"
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
    if y.size < 3:
        return float("nan")
    x0, x1, x2 = x[:-2], x[1:-1], x[2:]
    span = x2 - x0
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.where(span > 0, (x2 - x1) / span, 0.5)
    b = 1.0 - a
    e = a * y[:-2] + b * y[2:] - y[1:-1]
    c2 = a * a + b * b + 1.0
    return float(np.sqrt(np.mean(e * e / c2)))


#: variance of the mean square of equally spaced Gasser pseudo-residuals over that of independent ones,
#: 1 + 2 (rho_1^2 + rho_2^2) with rho_1 = -2/3, rho_2 = 1/6: their effective degrees of freedom are m / 1.94
PSEUDO_DOF_FACTOR = 1.0 + 2.0 * ((2.0 / 3.0) ** 2 + (1.0 / 6.0) ** 2)


def outlier_threshold(n: int, alpha: float = OUTLIER_ALPHA, dof: float = math.inf) -> float:
    """Return the |z| above which a row is an outlier: Bonferroni over n rows at family ``alpha``, >= 3.5.

    With ``dof`` (degrees of freedom of the SD the deviation is divided by) the quantile is Student's t's,
    as in Rosner's (1983) generalized ESD: a scale estimated from few points makes large ratios common.
    """
    q = alpha / (2 * max(n, 1))
    z = dist.norm_isf(q) if not np.isfinite(dof) else (dist.t_ppf(1 - q, dof) if dof >= 1 else math.inf)
    return max(3.5, z)


def _robust_scale(z: np.ndarray) -> float:
    """Return 1.4826 x the median absolute value (the normal-consistent MAD about zero)."""
    z = np.asarray(z, float)
    return float(1.4826 * np.median(np.abs(z))) if z.size else float("nan")


def max_outliers(n: int) -> int:
    """Return the most rows the outlier search may flag in a table of n rows (one in five, 1-20)."""
    return int(max(1, min(20, n // 5)))


def esd_select(zs: list[tuple[float, float]], n: int) -> int:
    """Return how many of the sequentially removed rows are outliers: the largest i whose (z_i, dof_i) has
    z_i > :func:`outlier_threshold` (n, dof_i) (generalized ESD, Rosner 1983, Technometrics 25, 165: a later,
    larger deviation unmasks earlier ones)."""
    hits = [i + 1 for i, (z, dof) in enumerate(zs) if np.isfinite(z) and z > outlier_threshold(n, dof=dof)]
    return max(hits) if hits else 0


def _replicate_noise(y: np.ndarray, g: np.ndarray, resid: np.ndarray | None = None
                     ) -> tuple[float, int, np.ndarray]:
    """Return (pooled SD, dof, outlier mask) at replicate groups.

    Generalized ESD (Rosner 1983) over the rows: the row with the largest leave-one-out deviation from the
    other rows of its group, d = (y - mean of the others) / sqrt(1 + 1/m), is removed, its z = |d| / (pooled
    SD of the rows left) recorded, up to :func:`max_outliers` times; the first i rows are outliers, i the last
    step whose z exceeds :func:`outlier_threshold` (Student's t with the pooled degrees of freedom left). In a pair both rows deviate alike: the one farther from the
    model fitted to all rows (``resid``, when given) is taken, else the later row.
    """
    n = y.size
    keep = np.ones(n, bool)

    def pooled(kp):
        cnt = np.bincount(g[kp], minlength=g.max() + 1).astype(float)
        tot = np.bincount(g[kp], weights=y[kp], minlength=g.max() + 1)
        mean = np.where(cnt > 0, tot / np.maximum(cnt, 1), 0.0)
        dof = int(np.sum(np.maximum(cnt - 1, 0)))
        ss = float(np.sum(((y - mean[g]) ** 2)[kp & (cnt[g] >= 2)]))
        return (math.sqrt(ss / dof) if dof > 0 else float("nan")), dof, cnt, tot

    order, zs = [], []
    tie = np.abs(resid) if resid is not None else np.arange(n, dtype=float)
    for _ in range(max_outliers(n)):
        _, _, cnt, tot = pooled(keep)
        m = cnt[g] - 1.0
        with np.errstate(invalid="ignore", divide="ignore"):
            d = np.where(keep & (m > 0), (y - (tot[g] - y) / np.maximum(m, 1)) / np.sqrt(1.0 + 1.0 / np.maximum(m, 1)),
                         np.nan)
        a = np.abs(d)
        if not np.any(np.isfinite(a)):
            break
        top = np.nanmax(a)
        near = np.flatnonzero(np.isfinite(a) & (a >= top * (1 - 1e-9)))
        i = int(near[np.argmax(tie[near])])
        keep[i] = False
        sd, dof_left, _, _ = pooled(keep)
        zs.append((top / sd if sd > 0 else float("inf"), float(dof_left)))
        order.append(i)
    out = np.zeros(n, bool)
    out[order[:esd_select(zs, n)]] = True
    sd, dof, _, _ = pooled(~out)
    return sd, dof, out


def _pseudo_coefs(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the normalised weights (L, C, R) of each interior point's pseudo-residual on its left
    neighbour, itself and its right neighbour (Gasser et al. 1986): e = L y[:-2] + C y[1:-1] + R y[2:]."""
    x0, x1, x2 = x[:-2], x[1:-1], x[2:]
    span = x2 - x0
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.where(span > 0, (x2 - x1) / span, 0.5)
    b = 1.0 - a
    c = np.sqrt(a * a + b * b + 1.0)
    return a / c, -1.0 / c, b / c


def spike_statistic(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (z per point in units of the noise SD, pseudo-residuals) of one ordered record (>= 5 points).

    A single gross error A at point i moves the pseudo-residuals by A D[:, i] (D the pseudo-residual
    operator, e = D y); the matched filter s = D^T e (Turin 1960, IRE Trans. IT-6, 311) is largest at the
    erroneous point, edge points included, and under white noise of SD sigma s_i ~ N(0, sigma^2 (D^T D)^2_ii):
    z_i = s_i / sqrt((D^T D)^2_ii) in units of sigma. D^T D is pentadiagonal, so this costs O(points).
    """
    n = x.size
    L, C, R = _pseudo_coefs(x)
    e = L * y[:-2] + C * y[1:-1] + R * y[2:]
    s = np.zeros(n)
    s[:-2] += L * e
    s[1:-1] += C * e
    s[2:] += R * e
    d0 = np.zeros(n)
    d0[:-2] += L * L
    d0[1:-1] += C * C
    d0[2:] += R * R
    d1 = np.zeros(n - 1)  # (i, i+1)
    d1[:-1] += L * C
    d1[1:] += C * R
    d2 = L * R  # (i, i+2)
    q = d0 * d0
    q[:-1] += d1 * d1
    q[1:] += d1 * d1
    q[:-2] += d2 * d2
    q[2:] += d2 * d2
    return s / np.sqrt(np.maximum(q, 1e-300)), e


def _difference_outliers(x: np.ndarray, y: np.ndarray, segs: list[np.ndarray], n_rows: int) -> list[int]:
    """Return the positions (into x, y) of outliers over the ordered segments (index arrays, >= 5 points).

    Outliers by generalized ESD (Rosner 1983) on :func:`spike_statistic`: the point with the largest |z|
    (in units of the current estimate) is removed, its z against the SD of the points left recorded, up to
    :func:`max_outliers` times; the first i removed are outliers, i the last step above
    :func:`outlier_threshold` (Bonferroni over the table's rows; Student's t with the pseudo-residuals'
    effective degrees of freedom, m / :data:`PSEUDO_DOF_FACTOR`).
    """
    segs = [np.asarray(s_, int) for s_ in segs if len(s_) >= 5]
    cache = [spike_statistic(x[s_], y[s_]) for s_ in segs]

    def scale():
        num = sum(float(e @ e) for _, e in cache)
        cnt = sum(e.size for _, e in cache)
        return (math.sqrt(num / cnt) if cnt else float("nan")), cnt

    removed, zs = [], []
    for _ in range(max_outliers(n_rows)):
        best = None
        for k, (z, _) in enumerate(cache):
            if z.size == 0:
                continue
            j = int(np.argmax(np.abs(z)))
            if best is None or abs(z[j]) > best[0]:
                best = (abs(z[j]), k, j)
        if best is None:
            break
        _, k, j = best
        raw = abs(float(cache[k][0][j]))
        removed.append(int(segs[k][j]))
        segs[k] = np.delete(segs[k], j)
        cache[k] = spike_statistic(x[segs[k]], y[segs[k]]) if segs[k].size >= 5 else (np.zeros(0), np.zeros(0))
        sd, cnt = scale()
        zs.append((raw / sd if sd > 0 else float("inf"), cnt / PSEUDO_DOF_FACTOR))
    flagged = removed[:esd_select(zs, n_rows)]
    return flagged


def _pseudo(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Return the normalised Gasser pseudo-residuals (N(0, sigma^2) for white noise) of interior points."""
    x0, x1, x2 = x[:-2], x[1:-1], x[2:]
    span = x2 - x0
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.where(span > 0, (x2 - x1) / span, 0.5)
    b = 1.0 - a
    return (a * y[:-2] + b * y[2:] - y[1:-1]) / np.sqrt(a * a + b * b + 1.0)


def _ar1_pseudo_stats(rho: float) -> tuple[float, float]:
    """Return (variance factor, lag-1 correlation) of equally spaced pseudo-residuals under AR(1) noise rho."""
    c = np.array([0.5, -1.0, 0.5])

    def cov(lag):
        return sum(c[j] * c[k] * rho ** abs(lag + k - j) for j in range(3) for k in range(3))

    v = cov(0)
    return v / 1.5, cov(1) / v


def record_order(df: pd.DataFrame, covariate: str) -> tuple[np.ndarray, np.ndarray]:
    """Return (rows along ``covariate`` within each trial/run, segment id per row): the record's order."""
    labels = [c for c in GROUP_LABELS if c in df.columns]
    d = df.reset_index(drop=True)
    order = d.sort_values(labels + [covariate], kind="stable").index.to_numpy()
    seg = d.groupby(labels, sort=False).ngroup().to_numpy() if labels else np.zeros(len(d), int)
    return order, seg


def lag1_correlation(r: np.ndarray, order: np.ndarray, segment: np.ndarray) -> tuple[float, float]:
    """Return (lag-1 autocorrelation, one-sided p against independence) of ``r`` along a record.

    Within segments; p from the normal approximation r1 ~ N(-1/m, 1/m) of independent errors
    (Box & Jenkins, Time Series Analysis, section 6.2).
    """
    r = np.asarray(r, float)[order]
    seg = np.asarray(segment)[order]
    if seg.size:  # deviations from each segment's mean (group means by bincount: O(rows))
        ids = pd.factorize(seg)[0]
        r = r - (np.bincount(ids, weights=r) / np.bincount(ids))[ids]
    same = seg[1:] == seg[:-1]
    m = int(same.sum())
    den = float(r @ r)
    if m < 8 or den <= 0:
        return float("nan"), float("nan")
    r1 = float(np.sum(r[1:][same] * r[:-1][same]) / den)
    z = (r1 + 1.0 / m) * math.sqrt(m)
    return r1, dist.norm_sf(z)


def serial_correlation(df: pd.DataFrame, residual: np.ndarray, covariates: list[str],
                       alpha: float = CORRELATION_ALPHA) -> dict | None:
    """Return {covariate, rho, p_value} of serially correlated residuals along time/position, or None.

    Computed on the residuals of the most flexible fit tried (so a missing smooth effect that a candidate
    explains is not mistaken for correlated noise). Private keys ``_order``/``_segment`` give the record.
    """
    best = None
    for c in covariates:
        if not is_ordered(c) or df[c].nunique() < 8:
            continue
        order, seg = record_order(df, c)
        rho, p = lag1_correlation(residual, order, seg)
        if np.isfinite(p) and p < alpha / max(1, sum(map(is_ordered, covariates))) and rho > 0:
            # the lag-1 sample correlation of a short record is biased low: E[r1] = rho - (1 + 4 rho)/n
            # (Kendall 1954, Biometrika 41, 403), corrected so that the red-noise background is not too flat
            rho_c = rho + (1 + 4 * rho) / max(len(residual), 1)
            if best is None or p < best["p_value"]:
                best = {"covariate": c, "rho": float(min(rho_c, 0.95)), "p_value": p, "_order": order,
                        "_segment": seg}
    return best


def correct_for_correlation(noise: dict, corr: dict | None) -> dict:
    """Return the noise estimate corrected for AR(1) correlation: differences of correlated readings
    understate the noise (variance factor of pseudo-residuals 1 - 4 rho/3 + rho^2/3, equal spacing)."""
    if not corr:
        return noise
    out = dict(noise, correlated=corr)
    if noise["method"].startswith("difference-based"):
        f = _ar1_pseudo_stats(corr["rho"])[0]
        out["sd"] = noise["sd"] / math.sqrt(f)
        out["se"] = noise["se"] / math.sqrt(f) * math.sqrt((1 + corr["rho"]) / (1 - corr["rho"]))
    out["method"] = (noise["method"] + f"; residuals serially correlated along {corr['covariate']} (lag-1 "
                     f"correlation {corr['rho']:.2f}, p = {corr['p_value']:.2g})"
                     + (": SD corrected for AR(1) noise" if noise["method"].startswith("difference-based") else ""))
    return out


def noise_estimate(df: pd.DataFrame, response: str, fitted: np.ndarray | None = None) -> dict:
    """Return {sd, se, method, dof, reliable, outliers, correlated} of the measurement noise (response unit).

    Replicates: pooled within-group SD at identical covariates; outliers by generalized ESD on the
    leave-one-out deviations (:func:`_replicate_noise`), left out.
    Otherwise the difference-based estimator of Gasser, Sroka & Jennen-Steinmetz (1986) along each
    ordering (within trials and levels of the other covariates), the smallest taken; outliers by generalized
    ESD on the matched-filter statistic of a single gross error (:func:`spike_statistic`, edge rows
    included), left out. ``fitted`` (the model's predictions per row, fitted to all rows): the differences
    are taken of the residuals y - fitted, so that curvature the model describes (a fast relaxation, a steep
    speed law between sparse points) neither inflates the estimate nor is flagged as outliers; differences
    of a smooth fitted curve are themselves smooth, so the estimator stays model-free in what is left.
    In a replicate pair the row farther from the fit is the one flagged. Along time/position, serial correlation of the noise (AR(1),
    :func:`serial_correlation`, p < 0.01) is detected; the SD is then corrected for it (differences of
    correlated readings understate the noise) and ``correlated`` gives {covariate, rho, p_value}.
    ``outliers`` lists the flagged rows (0-based positions in ``df``).
    """
    y = df[response].to_numpy(dtype=float)
    res = None if fitted is None else y - np.asarray(fitted, float)
    g = replicate_groups(df, response)
    counts = np.bincount(g)
    dof = int(np.sum(counts[counts >= 2] - 1))
    if dof >= 3 and (counts >= 2).sum() >= 2:
        sd, dof, out = _replicate_noise(y, g, res)
        rows = [int(i) for i in np.flatnonzero(out)]
        return {"sd": sd, "se": sd / math.sqrt(2 * max(dof, 1)), "dof": dof, "reliable": True, "outliers": rows,
                "correlated": None,
                "method": f"replicates: pooled within-group SD at identical covariates "
                          f"({int((counts >= 2).sum())} groups, {dof} degrees of freedom"
                          + (f"; {len(rows)} outlier rows left out" if rows else "") + ")"}
    covs = numeric_covariates(df, response)
    labels = [c for c in GROUP_LABELS if c in df.columns]
    # other labels that change what was measured (statistic avg/max, case ...) split the records too
    labels += [c for c in df.columns if c not in labels and c not in covs and c != response
               and c not in NOTE_LABELS and df[c].nunique(dropna=False) > 1]
    found = []
    # segments of 5+ points first; a grid with fewer levels per covariate (4 speeds x 4 temperatures, no
    # replicates) still has 3-4 points per segment: Gasser's pseudo-residuals need 3 (outliers are only
    # searched in segments of 5+), and at least MIN_PSEUDO_SHORT of them are asked for
    for min_pts in (5, 3):
        for c in covs:
            if df[c].nunique() < 3:
                continue
            others = [o for o in covs if o != c and df[o].nunique() <= max(10, len(df) // 10)]
            d = df.reset_index(drop=True)
            order = d.sort_values(labels + others + [c], kind="stable").index.to_numpy()
            x = d[c].to_numpy(dtype=float)[order]
            yy = (y if res is None else res)[order]
            if labels + others:  # rows sorted by the labels first: each segment is one contiguous run (O(rows))
                key = d.loc[order, labels + others].groupby(labels + others, sort=False, dropna=False).ngroup().to_numpy()
                segs = np.split(np.arange(y.size), np.flatnonzero(key[1:] != key[:-1]) + 1)
            else:
                segs = [np.arange(y.size)]
            segs = [s for s in segs if s.size >= min_pts]
            if not segs:
                continue
            flagged = [int(order[i]) for i in _difference_outliers(x, yy, segs, y.size)]
            fl = set(flagged)
            gone = np.array(sorted(fl), int)
            clean = [s[~np.isin(order[s], gone)] for s in segs]
            clean = [s for s in clean if s.size >= min_pts]
            if not clean:
                continue
            pe = [_pseudo(x[s], yy[s]) for s in clean]
            allp = np.concatenate(pe)
            if min_pts < 5 and allp.size < MIN_PSEUDO_SHORT:
                continue  # a handful of 3-point curvatures measures the curve, not the noise
            sd = float(np.sqrt(np.mean(allp ** 2)))
            corr = None
            found.append((sd, c, sorted(fl), corr, int(allp.size)))
        if found:
            break
    # correlated noise is a property of the noise: when an ordering shows it, its corrected estimate is used
    pool = [f for f in found if f[3]] or found
    best = min(pool, key=lambda f: f[0]) if pool else None
    if best is None:
        sd = float(np.std(y, ddof=1)) if y.size > 1 else float("nan")
        return {"sd": sd, "se": sd / math.sqrt(max(2 * (y.size - 1), 1)), "dof": int(y.size - 1), "reliable": False,
                "outliers": [], "correlated": None,
                "method": "no replicates and too few points along any covariate: SD of the data (an upper bound)"}
    sd, how, rows, corr, m = best
    se = sd / math.sqrt(max(m, 1)) * (math.sqrt((1 + corr["rho"]) / (1 - corr["rho"])) if corr else 1.0)
    return {"sd": sd, "se": se, "dof": int(m), "reliable": True, "outliers": rows, "correlated": corr,
            "method": f"difference-based (Gasser, Sroka & Jennen-Steinmetz 1986) along {how}"
                      + (f" within each {', '.join(labels)}" if labels else "")
                      + ": no replicates at identical covariates"
                      + ("; differences of the residuals from the model fitted to all rows" if res is not None else "")
                      + (f"; {len(rows)} outlier rows left out" if rows else "")
                      + (f"; serially correlated noise along {how} (AR(1) rho = {corr['rho']:.2f}, p = "
                         f"{corr['p_value']:.2g}), SD corrected for it" if corr else "")}
