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

import math

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


#: sample sizes up to which :func:`spearman_permutation_p` enumerates every permutation (8! = 40320)
PERMUTATION_EXACT_N = 8
#: random permutations drawn (seeded, so the p value is repeatable) for larger samples up to PERMUTATION_MAX_N
PERMUTATION_DRAWS = 50_000
#: above this many points Student's t approximation is used (its tail error shrinks as n grows)
PERMUTATION_MAX_N = 60
_PERM_NULL: dict[tuple, np.ndarray] = {}


def _permutation_null(xr: tuple) -> np.ndarray:
    """Return the sorted |rho| of the ranks 1..n permuted against the (average) ranks ``xr`` of x: every
    permutation for n <= PERMUTATION_EXACT_N, else PERMUTATION_DRAWS seeded draws; cached per rank pattern."""
    if xr not in _PERM_NULL:
        n = len(xr)
        x = np.asarray(xr, float) - (n + 1) / 2.0
        if n <= PERMUTATION_EXACT_N:
            from itertools import permutations

            perms = np.array(list(permutations(range(1, n + 1))), float)
        else:
            perms = np.random.default_rng(n).permuted(np.tile(np.arange(1.0, n + 1), (PERMUTATION_DRAWS, 1)), axis=1)
        c = perms - (n + 1) / 2.0
        rho = (c @ x) / math.sqrt(float(c[0] @ c[0]) * float(x @ x))
        _PERM_NULL[xr] = np.sort(np.abs(rho))
    return _PERM_NULL[xr]


def spearman_permutation_p(x, y) -> tuple[float, float]:
    """Return (Spearman's rho, two-sided permutation p) of ``y`` against ``x`` (y without ties; x may have ties).

    Student's t approximation of :func:`spearman` rejects too often in the tails that a Bonferroni family of
    tests uses: at nominal 0.0033 it rejected 1.3-1.4 times as often for n = 8-20 under the null (200,000
    simulated samples). Under the null every order of y's ranks against x is equally likely (Hollander & Wolfe
    1999, Nonparametric Statistical Methods, section 8.5), so p = P(|rho*| >= |rho|) over the permutations:
    exact for n <= PERMUTATION_EXACT_N, else (1 + count) / (1 + draws) over seeded draws (repeatable; SE of
    p about sqrt(p / draws)); n > PERMUTATION_MAX_N, ties in y or a constant sample: :func:`spearman` as is.
    """
    x = np.asarray(x, float).ravel()
    y = np.asarray(y, float).ravel()
    rho, p = spearman(x, y)
    n = x.size
    if not np.isfinite(rho) or n > PERMUTATION_MAX_N or np.unique(y).size < n:
        return rho, p
    null = _permutation_null(tuple(average_ranks(x)))
    hits = null.size - int(np.searchsorted(null, abs(rho) * (1 - 1e-12), side="left"))
    if n <= PERMUTATION_EXACT_N:
        return rho, hits / null.size
    return rho, (1 + hits) / (1 + null.size)


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
