"""``synth`` for dynamics data: progression speeds or camera-recorded trajectories made by a model with
measurement noise, labelled synthetic (:func:`synthesize_progression`, :func:`synthesize_trajectory`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ...dynamics import system as dsys
from ...effects.model import Model
from ...errors import InputError
from ...tables import write_measurements
from .bound import DynBound, check_start_values


# ---------------------------------------------------------------------------
# synth


def synthesize_progression(model: Model, design: pd.DataFrame, noise_sd: float, replicates: int,
                           seed: int) -> pd.DataFrame:
    """Return synthetic progression speeds: design conditions x replicates + Gaussian noise [mm/s].

    Every replicate follows the model file's protocol (a rerun of the same condition), so where the
    response is periodic the replicates differ by the noise only. Where it is irregular (response class
    of the protocol's window), replicate k records periods transient + k * recorded .. (a later window
    of the same run) instead, so irregular responses show their natural spread between replicates.
    (A slowly settling periodic response would otherwise differ between windows by more than the noise,
    with nothing in the model to explain it.)
    """
    if replicates < 1:
        raise InputError(f"--replicates must be >= 1, got {replicates}")
    check_start_values(model)
    bound = DynBound(model, design.assign(velocity_mm_s=0.0), where="design")
    rng = np.random.default_rng(seed)
    base_p = bound.protocol
    parts = []
    first = None
    for k in range(replicates):
        bound.protocol = dsys.Protocol(base_p.start, base_p.transient_periods + k * base_p.recorded_periods,
                                       base_p.recorded_periods)
        sim = bound.simulate(None)
        if not np.all(np.isfinite(sim["pred"])):
            i = int(np.argmax(~np.isfinite(sim["pred"])))
            why = getattr(bound, "last_failure", "")
            raise InputError(f"design row {i + 1}: the model cannot be run there" + (f" ({why})" if why else ""))
        if first is None:
            first = sim
        pred = np.where(first["cls"].astype(str) == "irregular", sim["pred"], first["pred"])
        d = design.copy()
        d["velocity_mm_s"] = pred + noise_sd * rng.standard_normal(len(d))
        parts.append(d)
    bound.protocol = base_p
    return pd.concat(parts, ignore_index=True)


def synthesize_trajectory(model: Model, design: pd.DataFrame, noise_sd: float, frame_rate_Hz: float,
                          seed: int) -> pd.DataFrame:
    """Return synthetic camera records: per design run (run, f_Hz, Pd_N, duration_s[, duty, waveform])
    frames at ``frame_rate_Hz`` from t = 0 (rest, drive phase 0), positions + Gaussian noise [mm]."""
    if not frame_rate_Hz > 0:
        raise InputError(f"--frame-rate-Hz must be > 0, got {frame_rate_Hz}")
    for c in ("run", "f_Hz", "Pd_N", "duration_s"):
        if c not in design.columns:
            raise InputError(f"design: missing column '{c}' (a trajectory design has run, f_Hz, Pd_N, duration_s)")
    check_start_values(model)
    rng = np.random.default_rng(seed)
    vals = {s.key: s.value for s in model.specs}
    sysm = dsys.build_system(model.base.name, {s.param.name: vals[s.key] for s in model.specs}, model.effect_names)
    parts = []
    for _, row in design.iterrows():
        t = np.arange(0.0, float(row["duration_s"]) + 1e-12, 1.0 / frame_rate_Hz)
        duty = float(row["duty"]) if "duty" in design.columns else None
        wf = str(row["waveform"]) if "waveform" in design.columns else "harmonic"
        tr = dsys.trajectory(sysm, float(row["f_Hz"]), float(row["Pd_N"]), t, duty=duty, waveform=wf)
        d = pd.DataFrame({"run": str(row["run"]), "f_Hz": float(row["f_Hz"]), "Pd_N": float(row["Pd_N"]),
                          "time_s": t})
        if "duty" in design.columns:
            d["duty"] = duty
        if "waveform" in design.columns:
            d["waveform"] = wf
        d["magnet_mm"] = tr["magnet_mm"] + noise_sd * rng.standard_normal(t.size)
        d["capsule_mm"] = tr["capsule_mm"] + noise_sd * rng.standard_normal(t.size)
        parts.append(d)
    return pd.concat(parts, ignore_index=True)


def write_synthetic(df: pd.DataFrame, path, prov: dict):
    """Write the synthetic table (CSV + provenance sidecar, or Parquet), labelled synthetic."""
    return write_measurements(df, Path(path), prov)
