"""The error ledger: one row per ``compare`` run, the history of a model across revisions.

A Parquet table (default ``results/ledger.parquet``) appended atomically:
timestamp, model name, model hash, effects, data hash, n, RMSE, held-out RMSE
with its standard error, and the noise estimate.
"""
from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import pandas as pd

from ..errors import InputError
from ..tables import Column, TableSchema, provenance, read_table, write_table

LEDGER_SCHEMA = TableSchema("ledger", "error history of models against measurements (one row per compare)", (
    Column("timestamp", "string", "UTC time of the compare run (ISO 8601)", unit=""),
    Column("model", "string", "model name (file's name: or its stem)", unit=""),
    Column("model_file", "string", "model file path", unit=""),
    Column("model_hash", "string", "hash of kind, base, effects and params", unit=""),
    Column("kind", "string", "measurement kind", unit=""),
    Column("effects", "string", "effects switched on, '+'-joined (empty: base only)", unit=""),
    Column("data", "string", "measurement table path", unit=""),
    Column("data_hash", "string", "sha256 (16 hex) of the data file", unit=""),
    Column("n", "int64", "number of measurements", unit=""),
    Column("n_free", "int64", "number of calibrated parameters", unit=""),
    Column("unit", "string", "unit of the errors below", unit=""),
    Column("rmse", "float64", "in-sample RMSE", unit="response unit"),
    Column("cv_rmse", "float64", "held-out (grouped k-fold) RMSE", unit="response unit"),
    Column("cv_rmse_se", "float64", "standard error of cv_rmse", unit="response unit"),
    Column("noise_sd", "float64", "measurement-noise estimate", unit="response unit"),
    Column("noise_sd_se", "float64", "standard error of noise_sd", unit="response unit"),
    Column("noise_method", "string", "how the noise was estimated", unit=""),
))


def read_ledger(path) -> pd.DataFrame:
    """Return the ledger table (several files: concatenated in order); InputError when missing or not a ledger."""
    if isinstance(path, (list, tuple)):
        return pd.concat([read_ledger(p) for p in path], ignore_index=True)
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: ledger not found (run capsule-cli compare --ledger {p} first)")
    df = read_table(p)
    missing = [c.name for c in LEDGER_SCHEMA.columns if c.name not in df.columns]
    if missing:
        raise InputError(f"{p}: not a ledger (missing column '{missing[0]}')")
    return df


def append_ledger(path: str | Path, met: dict) -> pd.DataFrame:
    """Append one compare run (its metrics record) to the ledger at ``path`` and return the ledger."""
    p = Path(path)
    row = {
        "timestamp": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "model": met["model"], "model_file": str(met["model_file"]), "model_hash": met["model_hash"],
        "kind": met["kind"], "effects": "+".join(met["effects"]), "data": met["data"],
        "data_hash": met["data_hash"], "n": int(met["n"]), "n_free": int(met["n_free"]), "unit": met["unit"],
        "rmse": float(met["rmse"]), "cv_rmse": float(met["cv_rmse"]),
        "cv_rmse_se": float(met["cv_rmse_se"]) if met["cv_rmse_se"] is not None else float("nan"),
        "noise_sd": float(met["noise_sd"]), "noise_sd_se": float(met["noise_sd_se"]),
        "noise_method": met["noise_method"],
    }
    new = pd.DataFrame([row])
    if p.is_file():
        old = read_ledger(p)[[c.name for c in LEDGER_SCHEMA.columns]]
        df = pd.concat([old, new], ignore_index=True)
    else:
        df = new
    write_table(df, p, LEDGER_SCHEMA, provenance(ledger=True))
    return df


def select_history(df: pd.DataFrame, model: str | None = None, data_hash: str | None = None) -> pd.DataFrame:
    """Return the rows of one history: a model name (and its revisions), else the last row's data set."""
    if model is not None:
        sel = df[df["model"].astype(str).str.startswith(model)]
        if sel.empty:
            names = ", ".join(sorted(set(df["model"].astype(str))))
            raise InputError(f"ledger: no rows for model '{model}' (models: {names})")
        return sel
    if data_hash is None:
        data_hash = str(df["data_hash"].iloc[-1])
    return df[df["data_hash"].astype(str) == data_hash]
