"""Sweeps over one parameter: bifurcation (Poincare points), progression, impacts, magnification.

Protocols (physics.md section 3: the response is multistable, say which one a figure used):

* ``rest`` -- every point starts from rest (zero state); points run in parallel
  (numba ``prange`` over sweep points) in chunks (:mod:`.parallel`: interruptible, progress);
* ``up`` / ``down`` -- continuation: points in increasing / decreasing order, each starting
  from the previous point's end state (x_r, v_r, V_c at phase 0; X_c reset to 0).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..errors import InputError
from . import engine as E
from .model import MODEL_PARAM_NAMES, CapsuleModel, Drive, EngineOptions, Friction, pack_params
from .parallel import run_points, run_rows_continuation, summarize
from .run import check_status

DRIVE_PARAMS = ("f_Hz", "Pd_N", "duty")
SWEEPABLE = DRIVE_PARAMS + ("Pf_N",) + tuple(MODEL_PARAM_NAMES)
PROTOCOLS = ("rest", "up", "down")


def apply_param(model: CapsuleModel, drive: Drive, friction: Friction, name: str, value: float):
    """Return (model, drive, friction) with one parameter (unit from its suffix) set."""
    if name == "f_Hz":
        return model, replace(drive, frequency_Hz=float(value)).validate(), friction
    if name == "Pd_N":
        return model, replace(drive, amplitude_N=float(value)).validate(), friction
    if name == "duty":
        if drive.waveform != "square":
            raise InputError("sweeping 'duty' needs the square-wave drive (--waveform square)")
        return model, replace(drive, duty=float(value)).validate(), friction
    if name == "Pf_N":
        if friction.kind not in ("coulomb", "fixed"):
            raise InputError("sweeping 'Pf_N' needs Coulomb friction (--friction coulomb)")
        if math.isinf(value):
            return model, drive, Friction(kind="fixed")
        return model, drive, replace(friction, kind="coulomb", level_N=float(value)).validate()
    if name in MODEL_PARAM_NAMES:
        return model.with_param(name, value), drive, friction
    raise InputError(f"cannot sweep '{name}' (one of: {', '.join(SWEEPABLE)})")


def period_number(xr: np.ndarray, vr: np.ndarray, max_period: int = 8, rel_tol: float = 1e-5) -> int:
    """Return the smallest p <= max_period with P_{i+p} = P_i over the records, 0 if none.

    Points are compared relative to the spread of the response (or 1 um, 1 mm/s floors).
    """
    n = len(xr)
    if n < 2:
        return 0
    sx = max(float(np.ptp(xr)), 1e-6, float(np.max(np.abs(xr))) * 1e-3)
    sv = max(float(np.ptp(vr)), 1e-3, float(np.max(np.abs(vr))) * 1e-3)
    for p in range(1, min(max_period, n - 1) + 1):
        # max(|a|) / s is max(|a| / s) exactly (division by s > 0 is monotone in rounding too)
        if max(np.abs(xr[p:] - xr[:-p]).max() / sx, np.abs(vr[p:] - vr[:-p]).max() / sv) < rel_tol:
            return p
    return 0


@dataclass
class SweepResult:
    """points: one row per sweep point; poincare: one row per point per recorded period."""

    points: pd.DataFrame
    poincare: pd.DataFrame


def run_sweep(model: CapsuleModel, drive: Drive, friction: Friction, name: str, values,
              protocol: str = "rest", transient_periods: int = 200, periods: int = 50,
              options: EngineOptions | None = None, progress=None, state0=None) -> SweepResult:
    """Sweep ``name`` over ``values`` and return per-point and per-period (Poincare) tables.

    ``state0`` = [x_r, v_r, V_c] [m, m/s, m/s] at phase 0: the fixed initial condition of every
    point (``rest`` protocol; default zero) or of the first point of a continuation.

    The sweep table column ``value`` is in the unit of ``name``'s suffix.
    """
    import pandas as pd
    if protocol not in PROTOCOLS:
        raise InputError(f"unknown protocol '{protocol}' (one of {', '.join(PROTOCOLS)})")
    if name not in SWEEPABLE:
        raise InputError(f"cannot sweep '{name}' (one of: {', '.join(SWEEPABLE)})")
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        raise InputError("empty sweep (num must be >= 1)")
    if periods < 1:
        raise InputError("a sweep needs at least one recorded period")
    order = np.arange(values.size)
    if protocol == "up":
        order = np.argsort(values, kind="stable")
    elif protocol == "down":
        order = np.argsort(-values, kind="stable")
    opts = replace(options or EngineOptions(), energy=False).pack()
    s0 = np.zeros(4)
    if state0 is not None:
        st0 = np.asarray(state0, dtype=float)
        if st0.shape != (3,) or not np.all(np.isfinite(st0)):
            raise InputError("initial state must be three finite numbers: x_r [m], v_r [m/s], V_c [m/s]")
        s0 = np.array([st0[0], st0[1], 0.0, st0[2]])
    setups = [apply_param(model, drive, friction, name, v) for v in values]
    P = np.stack([pack_params(*s) for s in setups])
    n = values.size
    if protocol == "rest":
        st, per, _ = run_points(P, opts, np.tile(s0, (n, 1)), int(transient_periods), int(periods),
                                progress=progress)
    else:
        # one row of points in run order: continuation, interruptible between points
        st_r, per_r = run_rows_continuation(P[order][None], opts, s0[None], int(transient_periods), int(periods),
                                            progress=progress)
        st = np.empty(n, dtype=np.int64)
        per = np.empty((n,) + per_r.shape[2:])
        st[order] = st_r[0]
        per[order] = per_r[0]
    bad = np.nonzero(st != E.STATUS_OK)[0]
    if bad.size:
        i = int(order[np.argmax(np.isin(order, bad))]) if protocol != "rest" else int(bad[0])
        check_status(int(st[i]), float("nan"), setups[i][2], f"sweep point {name} = {values[i]:g}",
                     setups[i][0].plugin_forces)
    Pd = np.array([s[1].amplitude_N for s in setups])
    f = np.array([s[1].frequency_Hz for s in setups])
    sm = summarize(per, Pd, f)
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    pts = pd.DataFrame({
        "point": np.arange(n, dtype=np.int64), "value": values, "f_Hz": f,
        "velocity_mm_s": sm["velocity_mm_s"], "impacts_per_period": sm["impacts_per_period"],
        "back_impacts_per_period": sm["back_impacts_per_period"], "max_Fi_N": sm["max_Fi_N"], "Af": sm["Af"],
        "period_number": sm["period_number"], "stick_fraction": sm["stick_fraction"], "order": rank,
    })
    m = int(periods)
    rep = lambda a: np.repeat(a, m)  # noqa: E731
    poin = pd.DataFrame({
        "point": rep(np.arange(n, dtype=np.int64)),
        "value": rep(values),
        "period": np.tile(np.arange(int(transient_periods), int(transient_periods) + m, dtype=np.int64), n),
        "relative_mm": per[:, :, E.P_XR0].ravel() * 1e3,
        "relative_velocity_mm_s": per[:, :, E.P_VR0].ravel() * 1e3,
        "displacement_mm": per[:, :, E.P_DISP].ravel() * 1e3,
        "impacts": per[:, :, E.P_NFRONT].ravel().astype(np.int64),
        "max_Fi_N": per[:, :, E.P_MAXF].ravel(),
        "velocity_mm_s": rep(sm["velocity_mm_s"]),
        "impacts_per_period": rep(sm["impacts_per_period"]),
        "Af": rep(sm["Af"]),
        "period_number": rep(sm["period_number"]),
    })
    return SweepResult(points=pts, poincare=poin)
