"""Large tables (issue 11 item 5): the O(rows) shortcuts give the answers of the plain computations.

The 1e6-row timings themselves are a benchmark (benchmarks/friction_fit_scaling.py), not a test.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from capsule_cli.fitting import fit_least_squares
from capsule_cli.steps.friction import _power
from capsule_cli.steps.residual_tests import gasser_sd, noise_estimate


def test_segmented_noise_equals_the_per_segment_loop():
    """noise_estimate's O(rows) segmentation (contiguous runs after sorting) pools the per-trial Gasser
    variances with weights rows - 2, exactly as a loop over the trials does."""
    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(100):
        n = int(rng.integers(5, 90))
        x = rng.uniform(0, 10, n)
        trial = rng.integers(0, int(rng.integers(1, 9)), n)
        y = rng.normal(size=n)
        est = noise_estimate(pd.DataFrame({"speed_mm_s": x, "friction_mN": y, "trial": trial}), "friction_mN")
        sds, ws = [], []
        for min_pts in (5, 3):  # trials of 5+ rows; if none, of 3+ (Gasser's pseudo-residuals need 3)
            for k in np.unique(trial):
                s = np.flatnonzero(trial == k)
                if s.size >= min_pts:
                    o = s[np.argsort(x[s], kind="stable")]
                    sds.append(gasser_sd(x[o], y[o]) ** 2)
                    ws.append(s.size - 2)
            if ws and (min_pts == 5 or sum(ws) >= 6):  # 3-4-row trials: at least 6 pseudo-residuals
                break
            sds, ws = [], []
        if not ws:
            assert not est["reliable"]
            continue
        if est["outliers"]:
            continue
        ref = float(np.average(sds, weights=ws))
        assert abs(est["sd"] ** 2 - ref) <= 1e-12 * ref
        checked += 1
    assert checked >= 50


def test_screened_starts_reach_the_full_multistart_optimum():
    rng = np.random.default_rng(3)
    V = rng.uniform(0.1, 50.0, 30_000)
    F = _power(V, 30.0, 0.25, 10.0) + rng.normal(0, 1.0, V.size)
    lo, hi = np.array([-1e4, 0.01, -1e4]), np.array([1e4, 3.0, 1e4])
    x0 = np.array([5.0, 1.0, 0.0])
    args = dict(names=["a_mN", "n", "b_mN"], bounds=(lo, hi), n_starts=4, seed=0)
    full = fit_least_squares(lambda p: _power(V, *p), F, x0, **args)
    screened = fit_least_squares(lambda p: _power(V, *p), F, x0, **args,
                                 model_rows=lambda p, rows: _power(V[rows], *p), screen_rows=2_000)
    np.testing.assert_allclose(screened.values, full.values, rtol=1e-7)
    np.testing.assert_allclose(screened.stderr, full.stderr, rtol=1e-5)
    assert abs(screened.rss - full.rss) <= 1e-9 * full.rss
    assert screened.starts_converged >= 1
