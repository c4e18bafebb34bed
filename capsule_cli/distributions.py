"""Distribution functions and two classical tests on :mod:`scipy.special`, without importing scipy.stats.

``import scipy.stats`` costs about 0.3 s (it loads scipy.spatial, scipy.interpolate, ndimage and about a
hundred distributions), a sixth of a whole ``capsule-cli diagnose`` run (issue 10 item 10). The
diagnosis needs only a few tail probabilities and two tests; scipy.stats computes each of them with the
:mod:`scipy.special` function called here (scipy 1.17, ``scipy/stats/_continuous_distns.py``:
``norm_gen``, ``t_gen``, ``f_gen``, ``ncf_gen``; ``_stats_py.py``: ``spearmanr``, ``f_oneway``), so
these return the same numbers, checked against scipy.stats in ``tests/test_distributions.py``.
Arguments are plain numbers (no units: statistics, probabilities, degrees of freedom).
"""
from __future__ import annotations

import numpy as np
from scipy import special


def norm_cdf(z: float) -> float:
    """Return P(Z <= z) of the standard normal distribution (``scipy.stats.norm.cdf``)."""
    return float(special.ndtr(z))


def norm_sf(z: float) -> float:
    """Return P(Z > z) of the standard normal distribution (``scipy.stats.norm.sf``)."""
    return float(special.ndtr(-z))


def norm_isf(q: float) -> float:
    """Return the z with P(Z > z) = q, 0 < q < 1, of the standard normal (``scipy.stats.norm.isf``)."""
    return float(-special.ndtri(q))


def t_ppf(q: float, df: float) -> float:
    """Return the q-quantile of Student's t with ``df`` degrees of freedom (``scipy.stats.t.ppf``).

    NaN unless df > 0 and 0 <= q <= 1 (q = 0 and 1 give -inf and inf), as scipy.stats.
    """
    if not (df > 0) or not (0 <= q <= 1):
        return float("nan")
    if q == 0 or q == 1:
        return float("-inf") if q == 0 else float("inf")
    return float(special.stdtrit(df, q))


def f_sf(x: float, dfn: float, dfd: float) -> float:
    """Return P(F > x) of the F distribution with (dfn, dfd) degrees of freedom (``scipy.stats.f.sf``)."""
    if not (dfn > 0 and dfd > 0) or x != x:
        return float("nan")
    if x <= 0:
        return 1.0
    return float(special.fdtrc(dfn, dfd, x))


def f_isf(q: float, dfn: float, dfd: float) -> float:
    """Return the x with P(F > x) = q, 0 < q < 1, of the F distribution (``scipy.stats.f.isf``)."""
    if not (dfn > 0 and dfd > 0) or not (0 < q < 1):
        return float("nan")
    return float(special.fdtri(dfn, dfd, 1.0 - q))


def ncf_sf(x: float, dfn: float, dfd: float, nc: float) -> float:
    """Return P(F' > x) of the noncentral F distribution with noncentrality ``nc``, as 1 - CDF.

    ``scipy.stats.ncf.sf`` calls a private scipy.special function; the public CDF (``ncfdtr``) agrees to
    rounding away from the far tail, which is all a power calculation (power ~ 0.8) reads.
    """
    if not (dfn > 0 and dfd > 0 and nc >= 0) or x != x:
        return float("nan")
    if x <= 0:
        return 1.0
    return float(1.0 - special.ncfdtr(dfn, dfd, nc, x))


def average_ranks(a) -> np.ndarray:
    """Return the ranks 1..n of ``a``, ties given their average rank (``scipy.stats.rankdata``, 'average')."""
    a = np.asarray(a, float).ravel()
    sorter = np.argsort(a, kind="mergesort")
    inv = np.empty(sorter.size, dtype=np.intp)
    inv[sorter] = np.arange(sorter.size, dtype=np.intp)
    s = a[sorter]
    obs = np.r_[True, s[1:] != s[:-1]]
    dense = obs.cumsum()[inv]
    count = np.r_[np.nonzero(obs)[0], len(obs)]
    return 0.5 * (count[dense] + count[dense - 1] + 1)


def spearman(x, y) -> tuple[float, float]:
    """Return (Spearman's rank correlation rho, two-sided p) of paired samples ``x``, ``y``.

    rho is Pearson's correlation of the average ranks; p from Student's t with n - 2 degrees of freedom
    of t = rho sqrt((n - 2) / (1 - rho^2)) (Zar 1972, JASA 67, 578), as ``scipy.stats.spearmanr``. NaN
    when n < 2, when either sample is constant, or when a value is NaN.
    """
    x = np.asarray(x, float).ravel()
    y = np.asarray(y, float).ravel()
    n = x.size
    if n != y.size:
        raise ValueError(f"spearman: samples of different lengths {n} and {y.size}")
    if n <= 1 or (x[0] == x).all() or (y[0] == y).all() or np.isnan(x).any() or np.isnan(y).any():
        return float("nan"), float("nan")
    ranked = np.column_stack((average_ranks(x), average_ranks(y)))  # the layout scipy uses (same rounding)
    rs = np.corrcoef(ranked, rowvar=False)
    dof = n - 2
    with np.errstate(divide="ignore"):
        t = rs * np.sqrt((dof / ((rs + 1.0) * (1.0 - rs))).clip(0))
    p = 2 * special.stdtr(dof, -np.abs(t))
    return float(rs[1, 0]), float(p[1, 0])


def f_oneway(*samples) -> tuple[float, float]:
    """Return (F, p) of the one-way analysis of variance of the group means of ``samples`` (1-D arrays).

    F = (between-group mean square) / (within-group mean square) with k - 1 and N - k degrees of freedom
    (Draper & Smith, Applied Regression Analysis, 3rd ed., section 2.1), sums of squares about the grand
    mean, as ``scipy.stats.f_oneway`` (equal variances). F = inf when every group is constant but the
    groups differ, NaN when all values are equal, when a group is empty or every group has one value, or
    when a value is NaN.
    """
    parts = [np.asarray(s, float).ravel() for s in samples]
    if len(parts) < 2:
        raise TypeError(f"f_oneway: at least two samples are required; got {len(parts)}")
    alldata = np.concatenate(parts)
    if any(p.size == 0 for p in parts) or all(p.size == 1 for p in parts) or np.isnan(alldata).any():
        return float("nan"), float("nan")
    bign = alldata.shape[-1]
    all_const = all(bool(np.all(np.diff(p) == 0)) for p in parts)
    all_same_const = bool(np.all(np.diff(alldata) == 0))
    offset = np.mean(alldata, axis=-1, keepdims=True)
    centred = alldata - offset
    normalized_ss = np.sum(centred, axis=-1) ** 2. / bign
    sstot = np.vecdot(centred, centred, axis=-1) - normalized_ss
    ssbn = 0
    for p in parts:
        ssbn = ssbn + np.sum(p - offset, axis=-1) ** 2. / p.shape[-1]
    ssbn = ssbn - normalized_ss
    sswn = sstot - ssbn
    dfbn = len(parts) - 1
    dfwn = bign - len(parts)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = (ssbn / dfbn) / (sswn / dfwn)
    if all_same_const:
        f = np.nan
    elif all_const:
        f = np.inf
    return float(f), float(special.fdtrc(dfbn, dfwn, f))
