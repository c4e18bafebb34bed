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


FRICTION_TEXT = {"inf": "$P_f$ = ∞ N", "eq22": "$P_f$ = $F_{c1e}$ (eq 22)", "eq23": "$P_f$ = $F_{c4e}$ (eq 23)"}


def magnify_figure(df: pd.DataFrame, title: str, path: str | Path, scale: str = "shared") -> Path:
    """A_f = max|F_i|/P_d over (f, P_d), one panel per friction, the peak of each panel marked.

    ``scale``: 'shared' (one colour scale for all panels) or 'panel' (one per panel). The
    protocol (column ``protocol``, when present) is written under the title.
    """
    if scale not in ("shared", "panel"):
        raise ValueError(f"scale must be 'shared' or 'panel', got {scale!r}")
    key = "friction" if "friction" in df.columns else "Pf_N"
    levels = list(dict.fromkeys(df[key].tolist()))
    n = len(levels)
    ncols = min(3, n)  # three panels a row keep two-line titles apart at page width
    nrows = int(math.ceil(n / ncols))
    fig, axes = figure(ncols=ncols, nrows=nrows, width="page", height_in=2.5 * nrows, squeeze=False)
    vmax = float(np.nanmax(df["Af"]))
    mesh = None
    for k, lev in enumerate(levels):
        ax = axes[k // ncols][k % ncols]
        sub = df[df[key] == lev].pivot_table(index="Pd_N", columns="f_Hz", values="Af")
        f = sub.columns.to_numpy(float)
        p = sub.index.to_numpy(float)
        a = sub.to_numpy()
        top = float(np.nanmax(a))
        mesh = ax.pcolormesh(_edges(f), _edges(p), a, cmap="viridis", vmin=0,
                             vmax=vmax if scale == "shared" else top, shading="flat")
        if scale == "panel":
            fig.colorbar(mesh, ax=ax, label="$A_f$ [-]")
        i, j = np.unravel_index(np.nanargmax(a), a.shape)
        ax.plot(f[j], p[i], marker="*", color="w", mec="k", mew=0.5, ms=8, ls="none")
        if key == "friction":
            name = FRICTION_TEXT.get(str(lev), f"$P_f$ = {lev} N")
        else:
            name = "$P_f$ = ∞ N" if math.isinf(lev) else f"$P_f$ = {lev:g} N"
        ax.set_title(f"{name}\npeak {top:.0f} at {f[j]:.3g} Hz, {p[i]:.3g} N", fontsize=7)
        ax.set_xlabel(label("drive frequency f", "Hz"))
        ax.set_ylabel(label("drive amplitude $P_d$", "N"))
        ax.grid(False)
    for k in range(n, nrows * ncols):
        axes[k // ncols][k % ncols].set_visible(False)
    if scale == "shared" and mesh is not None:
        fig.colorbar(mesh, ax=axes, label="magnification factor $A_f$ [-]")
    if "protocol" in df.columns and "protocol:" not in title:
        prots = "/".join(dict.fromkeys(df["protocol"].astype(str).tolist()))
        title = f"{title}\nprotocol: {prots} ({PROTOCOL_TEXT.get(prots, prots)}); star: peak of each panel"
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


#: how each kind of engine event is marked in :func:`simulation_figure`
EVENT_STYLE = {
    "front_contact_on": dict(marker="v", color=OKABE_ITO[1], label="front impact (contact on)"),
    "front_contact_off": dict(marker="^", color=OKABE_ITO[1], mfc="none", label="front contact off"),
    "back_contact_on": dict(marker="v", color=OKABE_ITO[3], label="back impact (contact on)"),
    "back_contact_off": dict(marker="^", color=OKABE_ITO[3], mfc="none", label="back contact off"),
    "stick": dict(marker="s", color="0.2", ms=2.5, label="shell sticks"),
    "slip_forward": dict(marker=">", color=OKABE_ITO[2], label="slip forward"),
    "slip_backward": dict(marker="<", color=OKABE_ITO[2], mfc="none", label="slip backward"),
}


def simulation_figure(traj: pd.DataFrame, events: pd.DataFrame, path: str | Path, title: str = "",
                      gap_mm: float | None = None, gap_back_mm: float | None = None,
                      last_periods: float | None = None, period_s: float | None = None) -> Path:
    """One run: positions, velocities and contact force against time with the events marked (left), and
    the phase portrait of the relative motion x_r, v_r (right).

    traj: a ``dynamics_trajectory`` table; events: a ``dynamics_events`` table (exact times);
    gap_mm / gap_back_mm: the front gap G_1 and the back gap G_2 [mm] (drawn on the phase portrait);
    last_periods, period_s: draw only the last ``last_periods`` drive periods of length ``period_s`` [s].
    """
    tr = traj.sort_values("time_s")
    if last_periods and period_s and len(tr):
        tr = tr[tr["time_s"] >= tr["time_s"].iloc[-1] - last_periods * period_s]
    t0, t1 = (float(tr["time_s"].min()), float(tr["time_s"].max())) if len(tr) else (0.0, 0.0)
    ev = events[(events["time_s"] >= t0) & (events["time_s"] <= t1)] if len(events) else events
    fig = blank_figure(width="page", height_in=4.6)
    gs = fig.add_gridspec(3, 2, width_ratios=[1.7, 1])
    ax_x = fig.add_subplot(gs[0, 0])
    ax_v = fig.add_subplot(gs[1, 0], sharex=ax_x)
    ax_f = fig.add_subplot(gs[2, 0], sharex=ax_x)
    ax_p = fig.add_subplot(gs[:, 1])
    t_ms = tr["time_s"] * 1e3
    ax_x.plot(t_ms, tr["magnet_mm"], color=OKABE_ITO[0], label="magnet $X_m$")
    ax_x.plot(t_ms, tr["capsule_mm"], color=OKABE_ITO[1], label="capsule $X_c$")
    ax_v.plot(t_ms, tr["magnet_velocity_mm_s"], color=OKABE_ITO[0], label="magnet $V_m$")
    ax_v.plot(t_ms, tr["capsule_velocity_mm_s"], color=OKABE_ITO[1], label="capsule $V_c$")
    ax_f.plot(t_ms, tr["Fi_N"] * 1e3, color="0.25", lw=0.9, label="interaction force $F_i$")
    if "stick" in tr and tr["stick"].any():
        st = tr["stick"].to_numpy(bool)
        ax_v.fill_between(t_ms, 0, 1, where=st, transform=ax_v.get_xaxis_transform(), color="0.85", lw=0,
                          label="shell stuck", step="mid")
    # exact event times as a rug along the top of the force panel, one row per kind
    rows = {k: 0.97 - 0.07 * i for i, k in enumerate(EVENT_STYLE)}
    xf = blended_transform_factory(ax_f.transData, ax_f.transAxes)
    for kind, style in EVENT_STYLE.items():
        sel = (ev["kind"].astype(str) == kind).to_numpy() if len(ev) else np.zeros(0, bool)
        if sel.any():
            st = dict(style)
            tt = ev["time_s"].to_numpy()[sel] * 1e3
            ax_f.plot(tt, np.full(len(tt), rows[kind]), ls="none", ms=st.pop("ms", 3.5), transform=xf, zorder=4,
                      clip_on=False, **st)
    ax_x.set_ylabel(label("position", "mm"))
    ax_v.set_ylabel(label("velocity", "mm/s"))
    ax_f.set_ylabel(label("$F_i$ on the shell", "mN"))
    ax_f.set_xlabel(label("time", "ms"))
    for ax in (ax_x, ax_v):
        ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), fontsize=6, ncol=3, borderaxespad=0.1)
        ax.tick_params(labelbottom=False)
    ax_f.set_ylim(top=ax_f.get_ylim()[1] * 1.6)  # room for the event rows
    ax_f.legend(loc="upper center", bbox_to_anchor=(0.5, -0.35), fontsize=5.5, ncol=3,
                title="events at their exact (root-found) times", title_fontsize=5.5)
    ax_p.plot(tr["relative_mm"], tr["magnet_velocity_mm_s"] - tr["capsule_velocity_mm_s"], color=OKABE_ITO[0],
              lw=0.8)
    if gap_mm is not None:
        ax_p.axvline(gap_mm, color=OKABE_ITO[1], ls="--", lw=0.8, label=f"front constraint $G_1$ = {gap_mm:g} mm")
    if gap_back_mm is not None:
        ax_p.axvline(-gap_back_mm, color=OKABE_ITO[3], ls="--", lw=0.8,
                     label=f"back constraint $-G_2$ = {-gap_back_mm:g} mm")
    ax_p.set_xlabel(label("relative displacement $x_r = X_m - X_c$", "mm"))
    ax_p.set_ylabel(label("relative velocity $v_r$", "mm/s"))
    ax_p.set_title("phase portrait of the relative motion", fontsize=7)
    if gap_mm is not None or gap_back_mm is not None:
        ax_p.legend(loc="lower left", fontsize=5.5)
    if title:
        fig.suptitle(title, fontsize=8)
    return save_figure(fig, path)
