"""Figures of the model-versus-measurement loop (tables in, figures out; no physics here)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..units import split_unit, unit_label
from .style import OKABE_ITO, figure, label, save_figure


def _nice(col: str) -> str:
    base, suffix = split_unit(col)
    return label(base.replace("_", " "), unit_label(col) if suffix else "")


def _cols(resp: str):
    base, u = split_unit(resp)
    return f"observed_{base}_{u}", f"predicted_{base}_{u}", f"residual_{base}_{u}"


def data_label(synthetic: bool) -> str:
    """Return the legend label of measured points ('synthetic data' for tables made by synth)."""
    return "synthetic data" if synthetic else "data"


def plot_fit(res: pd.DataFrame, curves: pd.DataFrame, main: str, resp: str, path: str | Path,
             title: str = "", noise_sd: float | None = None, extra: pd.DataFrame | None = None,
             extra_label: str = "", data_label: str = "data") -> Path:
    """Draw data and the calibrated model with its 95 % confidence band against ``main``."""
    obs, pred, _ = _cols(resp)
    fig, ax = figure(height_in=2.8)
    ax.plot(res[main], res[obs], "o", ms=3, mfc="none", color="0.25", alpha=0.8, label=data_label)
    for i, (cid, c) in enumerate(curves.groupby("curve_id", sort=True)):
        col = OKABE_ITO[i % len(OKABE_ITO)]
        lab = str(c["curve"].iloc[0])
        if lab == "at data":
            ax.errorbar(c["x"], c["predicted"], yerr=[c["predicted"] - c["lower"], c["upper"] - c["predicted"]],
                        fmt=".", ms=2, color=col, elinewidth=0.6, label="model (95 % band) at the data")
        else:
            ax.fill_between(c["x"], c["lower"], c["upper"], color=col, alpha=0.25, lw=0)
            ax.plot(c["x"], c["predicted"], color=col, label=("model" if lab == "model" else lab) + " (95 % band)")
    if extra is not None:
        for i, (cid, c) in enumerate(extra.groupby("curve_id", sort=True)):
            lab = str(c["curve"].iloc[0])
            if lab == "at data":
                ax.plot(c["x"], c["predicted"], "x", ms=3, color=OKABE_ITO[1], label=extra_label)
            else:
                ax.plot(c["x"], c["predicted"], "--", color=OKABE_ITO[(i + 1) % len(OKABE_ITO)],
                        label=extra_label if i == 0 else None)
    ax.set_xlabel(_nice(main))
    ax.set_ylabel(_nice(resp))
    if title:
        ax.set_title(title)
    ax.legend(loc="best", fontsize=6)
    return save_figure(fig, path)


def plot_residuals(res: pd.DataFrame, covariates: list[str], resp: str, path: str | Path,
                   noise_sd: float | None = None, title: str = "", residual_col: str | None = None) -> Path:
    """Draw the residuals against every covariate, with the noise level as a band."""
    _, _, rcol = _cols(resp)
    rcol = residual_col or rcol
    covs = [c for c in covariates if c in res.columns] or [res.columns[0]]
    n = len(covs)
    ncols = min(n, 3)
    nrows = int(np.ceil(n / ncols))
    fig, axes = figure(ncols=ncols, nrows=nrows, width="page" if ncols > 1 else "column", height_in=2.3 * nrows,
                       squeeze=False)
    for ax, c in zip(axes.ravel(), covs):
        x = res[c].to_numpy(float)
        r = res[rcol].to_numpy(float)
        if noise_sd and np.isfinite(noise_sd):
            ax.axhspan(-noise_sd, noise_sd, color=OKABE_ITO[2], alpha=0.15, lw=0, label="± noise SD")
        ax.axhline(0, color="0.3", lw=0.8)
        ax.plot(x, r, "o", ms=2.5, mfc="none", color=OKABE_ITO[0], alpha=0.8)
        u, inv = np.unique(x, return_inverse=True)
        if 3 <= u.size < x.size:
            ax.plot(u, np.bincount(inv, weights=r) / np.bincount(inv), "-", color=OKABE_ITO[1], lw=1,
                    label="mean at each value")
        ax.set_xlabel(_nice(c))
        ax.set_ylabel(label("residual", unit_label(resp)))
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    axes.ravel()[0].legend(loc="best", fontsize=6)
    if title:
        fig.suptitle(title, fontsize=8)
    return save_figure(fig, path)


def plot_candidates(cands: pd.DataFrame, base_cv: float, base_se: float, noise_sd: float, unit: str,
                    path: str | Path, winner: str | None = None) -> Path:
    """Draw the held-out RMSE of the model and of each candidate effect, with the noise level."""
    names = ["(model as is)"] + list(cands["effect"])
    cv = np.r_[base_cv, cands["cv_rmse"].to_numpy(float)]
    se = np.r_[base_se, cands["cv_rmse_se"].to_numpy(float)]
    fig, ax = figure(height_in=0.35 * len(names) + 1.2)
    y = np.arange(len(names))[::-1]
    colors = ["0.5"] + [OKABE_ITO[1] if n == winner else OKABE_ITO[0] for n in cands["effect"]]
    ax.barh(y, cv, xerr=np.nan_to_num(se), color=colors, alpha=0.8, error_kw={"elinewidth": 0.8})
    if noise_sd and np.isfinite(noise_sd):
        ax.axvline(noise_sd, color=OKABE_ITO[2], ls="--", lw=1, label=f"noise SD {noise_sd:.3g} {unit}")
        ax.legend(loc="lower right", fontsize=6)
    ax.set_yticks(y, names)
    ax.set_xlabel(label("held-out RMSE", unit))
    ax.set_title("candidate effects (± SE)")
    return save_figure(fig, path)


def plot_ledger(hist: pd.DataFrame, path: str | Path, title: str = "") -> Path:
    """Draw the held-out error per revision (± SE), the in-sample RMSE, and the noise level as a band."""
    fig, ax = figure(height_in=2.8)
    x = np.arange(len(hist))
    unit = str(hist["unit"].iloc[-1])
    noise = float(hist["noise_sd"].iloc[-1])
    nse = float(hist["noise_sd_se"].iloc[-1]) if "noise_sd_se" in hist else 0.0
    # without replicates or enough points the "noise" is the data's own spread: only an upper bound
    spread = "noise_method" in hist and str(hist["noise_method"].iloc[-1]).startswith("no replicates and too few")
    if np.isfinite(noise):
        ax.axhspan(noise - nse, noise + nse, color=OKABE_ITO[2], alpha=0.2, lw=0,
                   label=(f"data spread {noise:.3g} {unit} (upper bound on noise)" if spread else
                          f"noise level {noise:.3g} ± {nse:.2g} {unit}"))
        ax.axhline(noise, color=OKABE_ITO[2], lw=0.8)
    ax.errorbar(x, hist["cv_rmse"], yerr=np.nan_to_num(hist["cv_rmse_se"].to_numpy(float)), fmt="o-",
                color=OKABE_ITO[0], capsize=3, label="held-out RMSE (± SE)")
    ax.plot(x, hist["rmse"], "s", mfc="none", color=OKABE_ITO[1], ms=4, label="in-sample RMSE")
    labels = []
    prev: list[str] = []
    for _, row in hist.iterrows():
        effs = [e for e in str(row["effects"] or "").split("+") if e and e != "nan"]
        added = [e for e in effs if e not in prev]
        labels.append(str(row["model"]) if not prev and not added else
                      ("+ " + ", ".join(added) if added else str(row["model"])))
        prev = effs
    ax.set_xticks(x, [lab.replace("+", "\n+", 1) if len(lab) > 14 and not lab.startswith("+") else lab
                      for lab in labels], rotation=0, fontsize=6)
    ax.set_xlim(-0.5, len(hist) - 0.5)
    ax.set_ylim(0, None)
    ax.set_xlabel("model revision (effects added)")
    ax.set_ylabel(label("error", unit))
    ax.set_title(title or "error history")
    ax.legend(loc="upper right", fontsize=6)
    return save_figure(fig, path)
