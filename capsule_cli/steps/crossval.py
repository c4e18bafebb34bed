"""Grouped K-fold cross-validation: held-out error that never splits a trial or replicate group.

Groups: the ``trial`` (or ``run``) label when it has at least two values, else
rows with identical covariates (replicates stay together). Groups are shuffled
with a seed and dealt to K folds (K = min(K, number of groups)). The held-out
RMSE's standard error and the standard error of the difference between two
models use the per-point squared errors (paired), clustered by group when there
are at least 8 groups (Bates, Hastie & Tibshirani 2023, JASA 119, 1434, on
why the naive CV standard error is only a guide).
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from ..errors import InputError
from .residual_tests import GROUP_LABELS, replicate_groups


def cv_groups(df: pd.DataFrame, response: str) -> tuple[np.ndarray, str]:
    """Return (group id per row, how the groups were formed)."""
    for lab in GROUP_LABELS:
        if lab in df.columns and df[lab].nunique() >= 2:
            return df.groupby(lab, sort=False).ngroup().to_numpy(), f"by '{lab}'"
    return replicate_groups(df, response), "by identical covariate values"


def require_groups(groups: np.ndarray, how: str, where: str, nouns: str = "groups of readings") -> None:
    """Raise InputError (one line, prefixed ``where``) unless ``groups`` holds at least 2 groups.

    Cross-validation leaves each group out in turn and predicts it from the others; with one group there is
    nothing left to fit on, and an error computed there would be the start values' error, not a prediction.
    nouns: what a group is, in the plural ('conditions', 'runs'); how: how the groups were formed ('' to leave
    it unsaid)."""
    n = int(np.unique(groups).size)
    if n < 2:
        raise InputError(f"{where}: the held-out error needs at least 2 {nouns}, each left out in turn and predicted "
                         f"from the others; the table has {n}" + (f" ({how})" if how else ""))


def assign_folds(groups: np.ndarray, k: int, seed: int) -> np.ndarray:
    """Return a fold index per row: groups shuffled (seeded) and dealt round-robin to ``k`` folds."""
    ids = np.unique(groups)
    k = int(max(2, min(k, ids.size)))
    rng = np.random.default_rng(seed)
    perm = rng.permutation(ids)
    fold_of = {g: i % k for i, g in enumerate(perm)}
    return np.array([fold_of[g] for g in groups], int)


def _clusters(groups: np.ndarray) -> np.ndarray:
    return groups if np.unique(groups).size >= 8 else np.arange(groups.size)


def _mean_se(values: np.ndarray, groups: np.ndarray, always: bool = False) -> tuple[float, float]:
    """Return (mean, standard error) of per-point values, clustered by ``groups`` (when there are at least 8, or
    ``always``)."""
    v = np.asarray(values, float)
    n = v.size
    cl = np.asarray(groups) if always else _clusters(groups)
    ids, inv = np.unique(cl, return_inverse=True)
    G = ids.size
    m = float(v.mean())
    if G < 2:
        return m, float("nan")
    sums = np.bincount(inv, weights=v - m)
    var = G / (G - 1) * float(np.sum(sums ** 2)) / n ** 2
    return m, math.sqrt(max(var, 0.0))


def cv_rmse_se_few_groups(sq_err: np.ndarray, groups: np.ndarray) -> tuple[float, int] | None:
    """Return (standard error of the held-out RMSE clustered by group, groups - 1 degrees of freedom) when there
    are fewer than 8 groups of several rows each (where :func:`cv_rmse` counts rows as independent), else None.

    With a few trajectory runs a run missed as a whole (its drive on a ridge of the parameters the other runs do
    not pin down) makes its rows' held-out errors move together: a speed law fitted to five 1.5-s runs (noise
    0.2 mm), held out 0.242 mm, has a standard error of 0.0073 mm counted by frame and 0.038 clustered by run.
    The clustered error has only groups - 1 degrees of freedom (compare with a t quantile: Cameron & Miller 2015,
    J. Human Resources 50, 317, section VI)."""
    dof = few_groups(groups)
    return None if dof is None else (_rmse_se(sq_err, np.asarray(groups), always=True)[1], dof)


def _rmse_se(sq_err: np.ndarray, groups: np.ndarray, always: bool = False) -> tuple[float, float]:
    """Return (RMSE, its standard error, delta method) from per-point squared errors (:func:`_mean_se`)."""
    mse, se = _mean_se(sq_err, groups, always)
    rmse = math.sqrt(max(mse, 0.0))
    return rmse, (se / (2 * rmse) if rmse > 0 else float("nan"))


def cv_rmse(sq_err: np.ndarray, groups: np.ndarray) -> tuple[float, float]:
    """Return (held-out RMSE, its standard error) from per-point held-out squared errors."""
    return _rmse_se(sq_err, groups)


def paired_difference(sq_a: np.ndarray, sq_b: np.ndarray, groups: np.ndarray, always: bool = False
                      ) -> tuple[float, float]:
    """Return (RMSE_a - RMSE_b, its standard error) from paired per-point held-out squared errors (clustered by
    group as :func:`_mean_se`; ``always``: by group however few)."""
    ra = math.sqrt(float(np.mean(sq_a)))
    rb = math.sqrt(float(np.mean(sq_b)))
    _, se = _mean_se(np.asarray(sq_a) - np.asarray(sq_b), groups, always)
    return ra - rb, (se / (ra + rb) if ra + rb > 0 else float("nan"))


def few_groups(groups: np.ndarray) -> int | None:
    """Return groups - 1 (the degrees of freedom of a standard error clustered by group) when there are fewer than
    8 groups of several rows each, where :func:`_mean_se` counts rows as independent, else None."""
    g = np.asarray(groups)
    G = np.unique(g).size
    return None if G >= 8 or G < 2 or G == g.size else G - 1
