"""Data-based start values for effect parameters (shared by the built-in effects).

Each helper fits a one-shape term ``A * shape`` plus a constant to a residual
by linear least squares, scanning the shape's nonlinear parameter on a grid;
the best grid point is the start of the nonlinear calibration (robust to the
many local optima of exponentials, power laws and periodic trains).
"""
from __future__ import annotations

import numpy as np


def amplitude_with_offset(r: np.ndarray, shape: np.ndarray, nonnegative: bool = True) -> tuple[float, float]:
    """Return ``(A, rss_reduction)`` of r ~ c + A * shape (A >= 0 when ``nonnegative``)."""
    r = np.asarray(r, float)
    s = np.asarray(shape, float)
    sc = s - s.mean()
    rc = r - r.mean()
    den = float(sc @ sc)
    if den <= 0 or not np.isfinite(den):
        return 0.0, 0.0
    a = float(sc @ rc) / den
    if nonnegative and a < 0:
        return 0.0, 0.0
    return a, a * a * den


def scan(r: np.ndarray, shapes, nonnegative: bool = True):
    """Return ``(best_index, A)`` over candidate shapes (an iterable of arrays)."""
    best, best_red, best_a = 0, -1.0, 0.0
    for i, s in enumerate(shapes):
        a, red = amplitude_with_offset(r, s, nonnegative)
        if red > best_red:
            best, best_red, best_a = i, red, a
    return best, best_a


def log_grid(lo: float, hi: float, n: int = 40) -> np.ndarray:
    """Return ``n`` log-spaced values in [lo, hi] (lo, hi > 0)."""
    return np.exp(np.linspace(np.log(lo), np.log(hi), n))
