"""Synthetic measurements from a model file plus noise (``capsule-cli synth``).

The model (with any effects, built in or from plugins) is evaluated at the
covariates of a design table; Gaussian noise of standard deviation
sqrt(sd^2 + (rel * y)^2) in the response unit is added per replicate. The table
is labelled synthetic in its metadata with the true model (file content and
hash), the noise, the seed and the design.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..config import config_hash, configs_dir
from ..effects.model import Model
from ..errors import InputError
from ..tables import (DYNAMICS_KINDS, LABEL_COLUMNS, check_column_names, numeric_column, provenance,
                      response_column, user_path, write_measurements)
from ..units import split_unit

#: default design per kind (configs/designs/)
DEFAULT_DESIGNS = {"friction": "friction_speed.csv", "pressure": "pressure_speed.csv",
                   "relaxation": "relaxation_record.csv", "progression": "progression_grid.csv",
                   "trajectory": "trajectory_runs.csv"}


def default_design(kind: str) -> Path:
    """Return the default design table of a kind."""
    if kind not in DEFAULT_DESIGNS:
        raise InputError(f"no default design for kind '{kind}': give --design")
    return configs_dir() / "designs" / DEFAULT_DESIGNS[kind]


def read_design(path: str | Path, kind: str) -> pd.DataFrame:
    """Return a validated design table: covariate columns with unit suffixes (+ labels), no response.

    Numeric columns pass the checks of measurement tables (:func:`capsule_cli.tables.numeric_column`),
    so ``synth`` never writes data that ``compare`` would reject.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: design file not found")
    try:
        df = pd.read_csv(p) if p.suffix.lower() == ".csv" else pd.read_parquet(p)
    except Exception as exc:  # noqa: BLE001
        raise InputError(f"{p}: cannot be read ({str(exc).splitlines()[0]})") from None
    if df.empty:
        raise InputError(f"{p}: empty design (no rows)")
    df.columns = check_column_names(p, df.columns)
    resp = response_column(kind)
    if resp in df.columns:
        df = df.drop(columns=[resp])
    for col in df.columns:
        if col in LABEL_COLUMNS:
            if df[col].isna().any():
                i = int(np.argmax(df[col].isna().to_numpy()))
                raise InputError(f"{p}: column '{col}' row {i + 1}: missing label")
            continue
        if split_unit(col)[1] is None and col not in ("duty",):
            raise InputError(f"{p}: column '{col}': no unit suffix (e.g. speed_mm_s, position_mm, temperature_C)")
        df[col] = numeric_column(p, col, df[col])  # validated like measurements (negative speed, duty ...)
    return df


def synthesize(model: Model, design: pd.DataFrame, noise_sd: float, noise_rel: float, replicates: int,
               seed: int, where: str = "design", frame_rate_Hz: float = 100.0) -> pd.DataFrame:
    """Return the synthetic table: design rows x replicates (``trial`` 1..N) with the noisy response.

    Dynamics kinds go to :mod:`.dynamics_loop`: progression speeds at the design's conditions
    (replicates as repeated rows), trajectories as a camera records them at ``frame_rate_Hz``.
    """
    if model.kind in DYNAMICS_KINDS:  # the engine-based loop, imported only then (numba)
        from . import dynamics_loop

        if noise_rel:
            raise InputError("--noise-rel is not available for dynamics data: give --noise-sd")
        if noise_sd < 0:
            raise InputError("noise must be >= 0")
        if model.kind == "progression":
            return dynamics_loop.synthesize_progression(model, design, noise_sd, replicates, seed)
        if replicates != 1:
            raise InputError(f"{where}: trajectory replicates are separate runs: list them in the design")
        return dynamics_loop.synthesize_trajectory(model, design, noise_sd, frame_rate_Hz, seed)
    if replicates < 1:
        raise InputError(f"--replicates must be >= 1, got {replicates}")
    if noise_sd < 0 or noise_rel < 0:
        raise InputError("noise must be >= 0")
    if replicates > 1 and "trial" in design.columns:
        raise InputError(f"{where}: has a 'trial' column already; use --replicates 1")
    resp = response_column(model.kind)
    bound = model.bind(design.assign(**{resp: 0.0}), where=where)
    y = bound.predict()
    if not np.all(np.isfinite(y)):
        i = int(np.argmax(~np.isfinite(y)))
        raise InputError(f"{where}: row {i + 1}: the model gives a non-finite response there")
    rng = np.random.default_rng(seed)
    parts = []
    for k in range(replicates):
        d = design.copy()
        if replicates > 1 or "trial" not in d.columns:
            d["trial"] = k + 1
        sd = np.sqrt(noise_sd ** 2 + (noise_rel * y) ** 2)
        d[resp] = y + sd * rng.standard_normal(y.size)
        parts.append(d)
    out = pd.concat(parts, ignore_index=True)
    cols = [c for c in out.columns if c not in ("trial", resp)] + ["trial", resp]
    out = out[cols]
    out["trial"] = out["trial"].astype("int64") if pd.api.types.is_numeric_dtype(out["trial"]) else out["trial"]
    return out


def synth_provenance(model: Model, model_text: str, noise_sd: float, noise_rel: float, replicates: int, seed: int,
                     design_path: str, unit: str, plugins: list[str], **extra) -> dict:
    """Return the metadata of a synthetic table (true model, noise, seed, design; ``extra``: e.g. the
    trajectory frame rate)."""
    return provenance(config_hash=model.hash, seed=seed, synthetic=True, **extra,
                      true_model=model.content, true_model_text=model_text, true_model_hash=model.hash,
                      true_model_file=user_path(model.path) if model.path else model.path, noise_sd=noise_sd, noise_rel=noise_rel, noise_unit=unit,
                      replicates=replicates, design=user_path(design_path), plugins=plugins,
                      design_hash=config_hash(Path(design_path).read_text(encoding="utf-8", errors="replace"))
                      if Path(design_path).is_file() else None)


def write_synthetic(df: pd.DataFrame, path: str | Path, prov: dict) -> Path:
    """Write the synthetic table exactly at ``path`` (CSV + provenance sidecar, or Parquet)."""
    p = Path(path)
    if p.suffix.lower() not in (".csv", ".parquet", ".pq"):
        raise InputError(f"{p}: --out must end with .csv or .parquet")
    return write_measurements(df, p, prov)
