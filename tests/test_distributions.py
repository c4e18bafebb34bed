"""capsule_cli.distributions returns what scipy.stats returns (it exists only to avoid importing scipy.stats).

Equality is exact (the same scipy.special function on the same arguments, the same operation order)
except for the noncentral F tail, computed as 1 - CDF from the public function instead of scipy.stats'
private one: there the tolerance is a few rounding units, and the power calculation that reads it
(verdict.measurements_needed) must give the same number of measurements.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy import stats

from capsule_cli import distributions as D


def _same(a: float, b: float) -> bool:
    return (np.isnan(a) and np.isnan(b)) or a == b


def test_normal_t_f_functions_equal_scipy_stats_exactly():
    for z in (-40.0, -8.5, -3.0, -0.3, 0.0, 0.7, 2.5, 6.1, 38.0, np.inf, -np.inf):
        assert _same(D.norm_cdf(z), float(stats.norm.cdf(z)))
        assert _same(D.norm_sf(z), float(stats.norm.sf(z)))
    for q in (1e-300, 1e-12, 2.5e-4, 0.01, 0.3, 0.5, 0.975, 1 - 1e-9):
        assert _same(D.norm_isf(q), float(stats.norm.isf(q)))
        for df in (0.0, 1, 2, 3.5, 7, 18, 250, 1e6):
            assert _same(D.t_ppf(q, df), float(stats.t.ppf(q, df)))
            for dfn in (1, 2, 5):
                assert _same(D.f_isf(q, dfn, df), float(stats.f.isf(q, dfn, df)))
    for df in (1, 7):
        assert _same(D.t_ppf(0.0, df), float(stats.t.ppf(0.0, df)))
        assert _same(D.t_ppf(1.0, df), float(stats.t.ppf(1.0, df)))
    for x in (0.0, 1e-9, 0.4, 1.0, 3.3, 17.0, 1e4, np.inf):
        for dfn in (1, 2, 4):
            for dfd in (1, 3, 16, 400):
                assert _same(D.f_sf(x, dfn, dfd), float(stats.f.sf(x, dfn, dfd)))


def test_noncentral_f_tail_agrees_with_scipy_stats_to_rounding():
    for x in (0.0, 0.5, 2.0, 4.4, 9.0):
        for dfn in (1, 3):
            for dfd in (4, 17, 120):
                for nc in (1e-6, 0.05, 0.3, 4.0, 25.0):
                    ours, ref = D.ncf_sf(x, dfn, dfd, nc), float(stats.ncf.sf(x, dfn, dfd, nc))
                    assert abs(ours - ref) <= 1e-15, (x, dfn, dfd, nc, ours, ref)
                # nc = 0 is the central F (scipy.stats 1.17's ncf.sf returns a negative number there, e.g.
                # -0.48 at x = 0.5, dfn = 1, dfd = 4; the power calculation never asks for nc = 0)
                assert D.ncf_sf(x, dfn, dfd, 0.0) == pytest.approx(D.f_sf(x, dfn, dfd), rel=1e-14, abs=1e-15)


def test_measurements_needed_unchanged_by_the_noncentral_f_tail():
    """The power calculation gives the number scipy.stats gives (a grid of F statistics and designs)."""
    from capsule_cli.steps import verdict as V

    def with_scipy(f_stat, dk, n, k1, alpha, power=V.TARGET_POWER):
        lam = dk * (f_stat - 1.0)
        if not np.isfinite(lam) or lam <= 0.05:
            return None
        for m in range(n + 1, 100 * n + 1):
            dof = m - k1
            if dof < 1:
                continue
            crit = stats.f.isf(alpha, dk, dof)
            if stats.ncf.sf(crit, dk, dof, lam * m / n) >= power:
                return m
        return None

    for f_stat in (1.2, 1.9, 3.0, 5.5, 12.0):
        for dk in (1, 2):
            for n, k1 in ((8, 2), (20, 3), (45, 4)):
                for alpha in (0.01, 0.05):
                    assert V.measurements_needed(f_stat, dk, n, k1, alpha) == with_scipy(f_stat, dk, n, k1, alpha)


def test_spearman_equals_scipy_spearmanr_exactly_with_ties_and_edge_cases():
    rng = np.random.default_rng(7)
    for n in (2, 3, 5, 12, 40, 200):
        for ties in (False, True):
            for _ in range(20):
                x = rng.normal(size=n)
                y = 0.4 * x + rng.normal(size=n)
                if ties:
                    x, y = np.round(x * 2) / 2, np.round(y)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    ref = stats.spearmanr(x, y)
                rho, p = D.spearman(x, y)
                assert _same(rho, float(ref[0])) and _same(p, float(ref[1])), (n, ties, rho, p, ref)
    # constant input, NaN, perfect monotone relation: as scipy (NaN, NaN, rho = +-1 and p = 0)
    assert all(np.isnan(D.spearman([1.0, 1.0, 1.0], [1.0, 2.0, 3.0])))
    assert all(np.isnan(D.spearman([1.0, np.nan, 3.0], [1.0, 2.0, 3.0])))
    for y in ([2.0, 5.0, 9.0, 11.0], [9.0, 5.0, 2.0, 1.0]):
        ref = stats.spearmanr([1.0, 2.0, 3.0, 4.0], y)
        assert D.spearman([1.0, 2.0, 3.0, 4.0], y) == (float(ref[0]), float(ref[1]))
    assert np.array_equal(D.average_ranks([3.0, 1.0, 3.0, 2.0, 3.0]), stats.rankdata([3.0, 1.0, 3.0, 2.0, 3.0]))


def test_f_oneway_equals_scipy_f_oneway_exactly():
    rng = np.random.default_rng(11)
    for k in (2, 3, 6):
        for _ in range(40):
            sizes = rng.integers(1, 9, size=k)
            if sizes.max() < 2:
                sizes[0] = 2
            parts = [rng.normal(loc=0.3 * i, scale=2.0, size=s) for i, s in enumerate(sizes)]
            if rng.random() < 0.2:
                parts = [np.round(p) for p in parts]
            ref = stats.f_oneway(*parts)
            F, p = D.f_oneway(*parts)
            assert _same(F, float(ref[0])) and _same(p, float(ref[1])), (sizes, F, p, ref)
    # every group constant but different: F = inf, p = 0; all equal: NaN; a NaN value: NaN
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for parts in (([1.0, 1.0], [2.0, 2.0, 2.0]), ([3.0, 3.0], [3.0, 3.0]), ([1.0, np.nan], [2.0, 3.0])):
            ref = stats.f_oneway(*parts)
            F, p = D.f_oneway(*parts)
            assert _same(F, float(ref[0])) and _same(p, float(ref[1])), (parts, F, p, ref)



def test_spearman_permutation_p_is_exact_for_small_samples_and_fixes_the_t_tail():
    x6 = np.arange(6.0)
    # every one of the 6! orders is equally likely under the null (Hollander & Wolfe 1999, section 8.5): rho = 1
    # in 2 of 720 (two-sided); an adjacent swap (rho = 1 - 6 x 2 / 210) or better in 2 x 6 of 720
    assert D.spearman_permutation_p(x6, x6 + 1.0) == pytest.approx((1.0, 2 / 720), abs=1e-12)
    swap = [1.0, 0.0, 2.0, 3.0, 4.0, 5.0]
    assert D.spearman_permutation_p(x6, swap)[1] == pytest.approx(12 / 720, abs=1e-12)
    # Student's t gives 0 and 0.0048 for the same two orders (t infinite; t = 5.66 at 4 degrees of freedom)
    assert D.spearman(x6, x6 + 1.0)[1] == 0.0 and D.spearman(x6, swap)[1] == pytest.approx(0.0048, abs=2e-4)
    # n = 15 in the tail a Bonferroni family uses: scipy's permutation test (200,000 pairings) as the reference;
    # the seeded draws agree within 4 standard errors, Student's t is 1.6 times too small (0.00139 vs 0.0023)
    x = np.arange(15.0)
    y = 0.9 * x / 14 * 3 + np.random.default_rng(5).standard_normal(15)
    rho, p = D.spearman_permutation_p(x, y)
    xc = x - x.mean()

    def rho_of(yy, axis=-1):  # Spearman's rho of each resample (y has no ties: ranks are argsort of argsort)
        r = np.argsort(np.argsort(np.moveaxis(yy, axis, -1), axis=-1), axis=-1) - 7.0
        return (r @ xc) / np.sqrt(np.sum(r * r, axis=-1) * (xc @ xc))

    ref = stats.permutation_test((y,), rho_of, permutation_type="pairings", n_resamples=200_000, vectorized=True,
                                 random_state=0).pvalue
    assert p == pytest.approx(ref, abs=1e-3)
    assert D.spearman(x, y)[1] < p / 1.3
    assert D.spearman_permutation_p(x, y) == (rho, p)  # seeded, cached: the same p on every call
    # ties in y, or more than 60 points: Student's t, as spearman
    yt = np.round(y)
    assert np.unique(yt).size < 15 and D.spearman_permutation_p(x, yt) == D.spearman(x, yt)
    big = np.arange(80.0)
    yb = np.sin(big) + 0.01 * big
    assert D.spearman_permutation_p(big, yb) == D.spearman(big, yb)
