"""Sweeps over one parameter: bifurcation (Poincare points), progression, impacts, magnification.

Protocols (physics.md section 3: the response is multistable, say which one a figure used):

* ``rest`` -- every point starts from rest (zero state); points run in parallel
  (numba ``prange`` over sweep points);
* ``up`` / ``down`` -- continuation: points in increasing / decreasing order, each starting
  from the previous point's end state (x_r, v_r, V_c at phase 0; X_c reset to 0).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from ..errors import InputError
from . import engine as E
from .model import MODEL_PARAM_NAMES, CapsuleModel, Drive, EngineOptions, Friction, pack_params
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
        dx = np.abs(xr[p:] - xr[:-p]) / sx
        dv = np.abs(vr[p:] - vr[:-p]) / sv
        if max(dx.max(), dv.max()) < rel_tol:
            return p
    return 0


@dataclass
class SweepResult:
    """points: one row per sweep point; poincare: one row per point per recorded period."""

    points: pd.DataFrame
    poincare: pd.DataFrame


def _point_rows(name, value, idx, per, Pd, f_Hz, n_transient):
    T = 1.0 / f_Hz
    n = per.shape[0]
    xr = per[:, E.P_XR0]
    vr = per[:, E.P_VR0]
    disp = per[:, E.P_DISP]
    maxF = per[:, E.P_MAXF]
    pn = period_number(xr, vr)
    avg_v = float(disp.sum() / (n * T)) if n else float("nan")
    point = {
        "point": idx, "value": float(value), "f_Hz": f_Hz,
        "velocity_mm_s": avg_v * 1e3,
        "impacts_per_period": float(per[:, E.P_NFRONT].mean()) if n else float("nan"),
        "back_impacts_per_period": float(per[:, E.P_NBACK].mean()) if n else float("nan"),
        "max_Fi_N": float(maxF.max()) if n else float("nan"),
        "Af": float(maxF.max() / Pd) if (n and Pd > 0) else float("nan"),
        "period_number": int(pn),
        "stick_fraction": float(per[:, E.P_STICK].mean()) if n else float("nan"),
    }
    rows = pd.DataFrame({
        "point": np.full(n, idx, dtype=np.int64),
        "value": np.full(n, float(value)),
        "period": np.arange(n_transient, n_transient + n, dtype=np.int64),
        "relative_mm": xr * 1e3,
        "relative_velocity_mm_s": vr * 1e3,
        "displacement_mm": disp * 1e3,
        "impacts": per[:, E.P_NFRONT].astype(np.int64),
        "max_Fi_N": maxF,
    })
    return point, rows


def run_sweep(model: CapsuleModel, drive: Drive, friction: Friction, name: str, values,
              protocol: str = "rest", transient_periods: int = 200, periods: int = 50,
              options: EngineOptions | None = None, progress=None, state0=None) -> SweepResult:
    """Sweep ``name`` over ``values`` and return per-point and per-period (Poincare) tables.

    ``state0`` = [x_r, v_r, V_c] [m, m/s, m/s] at phase 0: the fixed initial condition of every
    point (``rest`` protocol; default zero) or of the first point of a continuation.

    The sweep table column ``value`` is in the unit of ``name``'s suffix.
    """
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
    points, rows = [], []
    if protocol == "rest":
        st, per, _, _ = E.run_many(P, opts, np.tile(s0, (values.size, 1)), int(transient_periods), int(periods))
        for i in range(values.size):
            check_status(int(st[i]), float("nan"), setups[i][2], f"sweep point {name} = {values[i]:g}")
        results = [per[i] for i in range(values.size)]
        if progress:
            progress(values.size)
    else:
        results = [None] * values.size
        state = s0.copy()
        for i in order:
            st, st_t, _, _, _, _, per, _, fin = E.run_core(P[i], opts, state, int(transient_periods),
                                                           int(periods), 1.0, 0, 0)
            check_status(int(st), float(st_t), setups[i][2], f"sweep point {name} = {values[i]:g}")
            results[i] = per
            state = np.array([fin[0], fin[1], 0.0, fin[3]])
            if progress:
                progress(1)
    for rank, i in enumerate(order):
        d = setups[i][1]
        pt, rw = _point_rows(name, values[i], int(i), results[i], d.amplitude_N, d.frequency_Hz,
                             int(transient_periods))
        pt["order"] = rank
        points.append(pt)
        rows.append(rw)
    pts = pd.DataFrame(points).sort_values("point").reset_index(drop=True)
    poin = pd.concat(rows, ignore_index=True).sort_values(["point", "period"]).reset_index(drop=True)
    poin = poin.merge(pts[["point", "velocity_mm_s", "impacts_per_period", "Af", "period_number"]], on="point")
    return SweepResult(points=pts, poincare=poin)
