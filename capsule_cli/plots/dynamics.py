"""Figures of the dynamics stage: tables in, figures out (never recomputes physics)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.transforms import blended_transform_factory
import pandas as pd

from .style import OKABE_ITO, blank_figure, figure, label, save_figure

PROTOCOL_TEXT = {"rest": "every point from rest", "up": "continuation, f increasing",
                 "down": "continuation, f decreasing"}


def bifurcation_figure(cases: list[tuple[str, pd.DataFrame, pd.DataFrame]], protocol: str, title: str,
                       path: str | Path, paper_lines: dict[str, float] | None = None) -> Path:
    """Poincare V_r vs f (a) and average progression velocity vs f (b), one colour per friction case.

    cases: [(legend name, points table, sweep (Poincare) table)] of frequency sweeps.
    paper_lines: {short landmark name: f [Hz]} the paper reports; drawn as thin dotted lines
    behind the data and named on a top frequency axis, never on the curves.
    """
    fig, (ax1, ax2) = figure(nrows=2, width="page", height_in=5.2, sharex=True)
    for i, (lab, pts, poin) in enumerate(cases):
        col = OKABE_ITO[i % len(OKABE_ITO)]
        ax1.plot(poin["value"], poin["relative_velocity_mm_s"], ".", ms=1.2, mew=0, color=col, alpha=0.7,
                 rasterized=True)
        ax1.plot([], [], "o", ms=3, color=col, label=lab)
        p = pts.sort_values("value")
        ax2.plot(p["value"], p["velocity_mm_s"], ".-", ms=2, lw=0.6, color=col, label=lab)
    at: dict[float, list[str]] = {}
    for name, f in (paper_lines or {}).items():
        if f is not None and math.isfinite(f):
            at.setdefault(float(f), []).append(name)
    for f in at:
        for ax in (ax1, ax2):
            ax.axvline(f, color="0.55", lw=0.6, ls=":", zorder=0)
    if at:
        top = ax1.secondary_xaxis("top")
        fs = sorted(at)
        top.set_xticks(fs, [f"{' / '.join(at[f])}\n{f:g} Hz" for f in fs], fontsize=5.5, color="0.3")
        top.tick_params(length=2, pad=1)
        top.set_xlabel("paper's landmarks (seed 000 section 5.3), dotted", fontsize=6, color="0.3")
    ax1.set_ylabel(label("Poincaré $V_r$ at phase 0", "mm/s"))
    ax2.set_ylabel(label("average capsule velocity", "mm/s"))
    ax2.set_xlabel(label("drive frequency f", "Hz"))
    ax2.axhline(0, color="k", lw=0.5)
    h, lab_ = ax1.get_legend_handles_labels()
    fig.legend(h, lab_, loc="outside lower center", ncol=min(3, len(h)), markerscale=1.5,
               title="shell friction (one colour per case)", title_fontsize=6)
    ax1.set_title("(a) relative velocity at the Poincaré section", loc="left", fontsize=7)
    ax2.set_title("(b) progression", loc="left", fontsize=7)
    fig.suptitle(f"{title}\nprotocol: {protocol} ({PROTOCOL_TEXT.get(protocol, protocol)})", fontsize=8)
    return save_figure(fig, path)


def duty_map_figure(df: pd.DataFrame, title: str, path: str | Path,
                    paper_best: tuple[float, float] | None = None) -> Path:
    """Progression speed over (f, duty): df with columns f_Hz, duty, velocity_mm_s.

    ``paper_best`` (f [Hz], duty [-]) marks the fastest point the paper reports.
    """
    piv = df.pivot_table(index="duty", columns="f_Hz", values="velocity_mm_s")
    fig, ax = figure(width="column", height_in=3.4)
    f = piv.columns.to_numpy(float)
    d = piv.index.to_numpy(float)
    v = piv.to_numpy()
    lim = float(np.nanmax(np.abs(v))) or 1.0
    mesh = ax.pcolormesh(_edges(f), _edges(d, 0.0, 1.0), v, cmap="RdBu_r", vmin=-lim, vmax=lim, shading="flat")
    fig.colorbar(mesh, ax=ax, label=label("average velocity", "mm/s"))
    i, j = np.unravel_index(np.nanargmax(v), v.shape)
    ax.plot(f[j], d[i], "k*", ms=7, label=f"fastest here (simulated): {f[j]:g} Hz, D = {d[i]:.2f}")
    if paper_best is not None:
        ax.plot(*paper_best, "o", mfc="none", mec="k", ms=8,
                label=f"fastest in the paper (3D FE, seed 004): {paper_best[0]:g} Hz, D = {paper_best[1]:g}")
    ax.set_xlabel(label("drive frequency f", "Hz"))
    ax.set_ylabel(label("duty cycle D", ""))
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), fontsize=6, ncol=1, frameon=False)
    ax.set_title(title)
    ax.grid(False)
    return save_figure(fig, path)


def magnify_figure(df: pd.DataFrame, title: str, path: str | Path) -> Path:
    """A_f = max|F_i|/P_d over (f, P_d), one panel per friction level."""
    levels = list(dict.fromkeys(df["Pf_N"].tolist()))
    n = len(levels)
    ncols = min(3, n)
    nrows = int(math.ceil(n / ncols))
    fig, axes = figure(ncols=ncols, nrows=nrows, width="page", height_in=2.3 * nrows, squeeze=False)
    vmax = float(np.nanmax(df["Af"]))
    for k, pf in enumerate(levels):
        ax = axes[k // ncols][k % ncols]
        sub = df[df["Pf_N"] == pf].pivot_table(index="Pd_N", columns="f_Hz", values="Af")
        f = sub.columns.to_numpy(float)
        p = sub.index.to_numpy(float)
        mesh = ax.pcolormesh(_edges(f), _edges(p), sub.to_numpy(), cmap="viridis", vmin=0, vmax=vmax, shading="flat")
        name = "∞ (shell fixed)" if math.isinf(pf) else f"{pf:g} N"
        ax.set_title(f"Coulomb $P_f$ = {name}, max $A_f$ = {np.nanmax(sub.to_numpy()):.0f}", fontsize=7)
        ax.set_xlabel(label("drive frequency f", "Hz"))
        ax.set_ylabel(label("drive amplitude $P_d$", "N"))
        ax.grid(False)
    for k in range(n, nrows * ncols):
        axes[k // ncols][k % ncols].set_visible(False)
    fig.colorbar(mesh, ax=axes, label="magnification factor $A_f$ [-]")
    fig.suptitle(title, fontsize=8)
    return save_figure(fig, path)


def _edges(x: np.ndarray, lo: float | None = 0.0, hi: float | None = None) -> np.ndarray:
    """Cell edges around grid values ``x``, kept inside the physical range [lo, hi] (no cell reaches a
    negative frequency, amplitude or duty)."""
    x = np.asarray(x, float)
    if len(x) == 1:
        e = np.array([x[0] - 0.5, x[0] + 0.5])
    else:
        mid = 0.5 * (x[1:] + x[:-1])
        e = np.concatenate([[x[0] - (mid[0] - x[0])], mid, [x[-1] + (x[-1] - mid[-1])]])
    if lo is not None:
        e[0] = max(e[0], min(lo, x[0]))
    if hi is not None:
        e[-1] = min(e[-1], max(hi, x[-1]))
    return e
