"""Friction figures: tables in, figures out (no physics is computed here).

* :func:`plot_fit` -- a fitted law with its 95 % bands over the data, and the residuals;
* :func:`plot_friction_vs_speed` -- seed 000 Figs 9c and 13c: Case 1 (flat-open) and
  Case 4 (contractive) friction against speed with the published values, the fitted
  laws, the Coulomb line and the hoop-model predictions;
* :func:`plot_hoop_vs_radius` -- the hoop-friction components against R_i.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.patches import Rectangle

from .style import OKABE_ITO, REFERENCE_STYLE, figure, label, save_figure

FIT_COLOR = OKABE_ITO[0]
HOOP_COLORS = {4.4: OKABE_ITO[1], 4.8: OKABE_ITO[2]}
PAPER_FIT_STYLE = dict(color="#CC79A7", ls="-.", lw=1.2)
COULOMB_STYLE = dict(color="#000000", ls="--", lw=1.0)


def _fmt_param(name: str, rec: dict) -> str:
    if rec.get("fixed"):
        return f"{name} = {rec['value']:.3g} (fixed)"
    lo, hi = rec["ci95"]
    return f"{name} = {rec['value']:.4g} [{lo:.3g}, {hi:.3g}]"


#: most data points drawn by :func:`plot_fit` (larger tables are thinned evenly; the fit uses all rows)
MAX_POINTS = 20_000


def plot_fit(residuals: pd.DataFrame, band: pd.DataFrame, summary: dict, path: str | Path,
             data_label: str = "data") -> Path:
    """Draw the data, the fitted curve with its 95 % confidence and prediction bands, and residuals."""
    fig, (ax, axr) = figure(1, 2, width="column", height_in=4.0, sharex=True,
                            gridspec_kw={"height_ratios": [3, 1.2]})
    ax.fill_between(band["speed_mm_s"], band["pi_low_mN"], band["pi_high_mN"], color=FIT_COLOR, alpha=0.10,
                    lw=0, label="95 % prediction band")
    ax.fill_between(band["speed_mm_s"], band["ci_low_mN"], band["ci_high_mN"], color=FIT_COLOR, alpha=0.30,
                    lw=0, label="95 % confidence band")
    ax.plot(band["speed_mm_s"], band["friction_mN"], color=FIT_COLOR, label=f"fit: {summary['formula']}")
    n_all = len(residuals)
    if n_all > MAX_POINTS:  # a million markers take seconds to draw and show nothing more
        step = -(-n_all // MAX_POINTS)
        residuals = residuals.iloc[::step]
        data_label = f"{data_label} (every {step}th of {n_all} points shown)"
    ax.plot(residuals["speed_mm_s"], residuals["friction_mN"], "o", ms=3, color="0.35", mfc="none",
            label=data_label)
    ax.set_ylabel(label("friction", "mN"))
    ax.legend(loc="lower right", fontsize=6)
    params = "\n".join(_fmt_param(k, v) for k, v in summary["params"].items())
    ax.text(0.02, 0.98, f"{params}\nR² = {summary['r2']:.3f}, n = {summary['n']}, AIC = {summary['aic']:.1f}",
            transform=ax.transAxes, va="top", fontsize=6)
    axr.axhline(0, color="0.3", lw=0.8)
    axr.plot(residuals["speed_mm_s"], residuals["residual_mN"], "o", ms=3, color="0.35", mfc="none")
    axr.set_xlabel(label("capsule speed", "mm/s"))
    axr.set_ylabel(label("residual", "mN"))
    ax.set_xlim(0, None)
    return save_figure(fig, path)


def _reference_points(ax, ref: pd.DataFrame, scale: float, with_label: set):
    """Plot reference rows with a speed (avg: filled role style; min/max: triangles)."""
    markers = {"avg": None, "peak": "*", "min": "v", "max": "^"}
    for _, row in ref.iterrows():
        if not np.isfinite(row["speed_mm_s"]):
            continue
        st = dict(REFERENCE_STYLE.get(row["source_type"], REFERENCE_STYLE["experiment"]))
        if markers.get(row["statistic"]):
            st["marker"] = markers[row["statistic"]]
        key = f"{row['source_type']} ({row['statistic']})"
        lab = None
        if key not in with_label:
            with_label.add(key)
            lab = {"avg": f"published {row['source_type']}, average",
                   "min": f"published {row['source_type']}, minimum",
                   "max": f"published {row['source_type']}, maximum",
                   "peak": f"published {row['source_type']}, peak"}[row["statistic"]] + " (seed 000)"
        ax.plot(row["speed_mm_s"], row["friction_mN"] * scale, label=lab, zorder=5, **st)


def _range_boxes(ax, ref: pd.DataFrame, scale: float):
    """Draw 'values lie between min and max over a speed span' rows as dotted boxes."""
    if not {"speed_min_mm_s", "speed_max_mm_s"} <= set(ref.columns):
        return
    spans = ref.dropna(subset=["speed_min_mm_s", "speed_max_mm_s"])
    spans = spans[~np.isfinite(spans["speed_mm_s"])]
    for (lo_v, hi_v), grp in spans.groupby(["speed_min_mm_s", "speed_max_mm_s"]):
        lo = grp.loc[grp["statistic"] == "min", "friction_mN"]
        hi = grp.loc[grp["statistic"] == "max", "friction_mN"]
        if lo.empty or hi.empty:
            continue
        ax.add_patch(Rectangle((lo_v, lo.iloc[0] * scale), hi_v - lo_v, (hi.iloc[0] - lo.iloc[0]) * scale,
                               fill=False, ls=":", ec="0.4", lw=0.9, zorder=1,
                               label=f"published range: {lo.iloc[0] * scale:.3g}-"
                                     f"{hi.iloc[0] * scale:.3g} over {lo_v:g}-{hi_v:g} mm/s"))


def plot_friction_vs_speed(reference: pd.DataFrame, hoop: pd.DataFrame, coulomb: pd.DataFrame,
                           case1_law: pd.DataFrame, case4_law: pd.DataFrame, path: str | Path,
                           fit_band: pd.DataFrame | None = None, fit_points: pd.DataFrame | None = None,
                           fit_summary: dict | None = None, data_label: str = "data",
                           Ri_mm: tuple[float, ...] = (4.4, 4.8)) -> Path:
    """Draw seed 000 Figs 9c and 13c: friction against speed for Cases 1 and 4.

    Parameters
    ----------
    reference : published values (configs/reference/friction_seed000.csv)
    hoop : hoop grid (``friction hoop``), rows for each R_i in ``Ri_mm``
    coulomb : prediction table of the Coulomb model (``friction predict``)
    case1_law, case4_law : prediction tables of the paper's fitted laws (eqs 17, 18)
    fit_band, fit_points, fit_summary : a fit of Case 1 data (``friction fit``), optional
    data_label : legend text of the fitted points (say "synthetic ..." for synthetic data)
    """
    fig, (a1, a4) = figure(2, 1, width="page", height_in=4.0)
    seen: set = set()
    # ---- Case 1: flat-open intestine (mN)
    ref1 = reference[reference["case"].astype(str) == "1"]
    _range_boxes(a1, ref1, 1.0)
    if fit_band is not None:
        a1.fill_between(fit_band["speed_mm_s"], fit_band["ci_low_mN"], fit_band["ci_high_mN"], color=FIT_COLOR,
                        alpha=0.25, lw=0, label="95 % confidence band")
        lab = "fit to the data"
        if fit_summary is not None:
            p = fit_summary["params"]
            if {"a_mN", "b_mN"} <= set(p):
                n = p["n"]["value"] if "n" in p else np.nan
                lab = f"fit: {p['a_mN']['value']:.3g} V^{n:.3g} + {p['b_mN']['value']:.3g}, R² {fit_summary['r2']:.2f}"
        a1.plot(fit_band["speed_mm_s"], fit_band["friction_mN"], color=FIT_COLOR, label=lab)
    if fit_points is not None:
        a1.plot(fit_points["speed_mm_s"], fit_points["friction_mN"], "o", ms=2.5, color="0.55", mfc="none",
                mew=0.6, label=data_label, zorder=2)
    a1.plot(case1_law["speed_mm_s"], case1_law["friction_mN"], label="paper's fit, eq 17",
            **PAPER_FIT_STYLE)
    fe1 = ref1[(ref1["source_type"] == "FE") & ~np.isfinite(ref1["speed_mm_s"])]
    fe_text = f"; FE ≈ {fe1['friction_mN'].iloc[0]:g}" if len(fe1) else ""
    a1.plot(coulomb["speed_mm_s"], coulomb["friction_mN"],
            label=f"Coulomb eq 1: {coulomb['friction_mN'].iloc[0]:.2f} mN{fe_text}", **COULOMB_STYLE)
    _reference_points(a1, ref1, 1.0, seen)
    a1.set_xlabel(label("capsule speed", "mm/s"))
    a1.set_ylabel(label("friction", "mN"))
    a1.set_title("(a) Case 1: flat-open intestine")
    a1.set_xlim(0, None)
    a1.set_ylim(0, max(30.0, float(np.nanmax(ref1["friction_mN"])) * 1.3 if len(ref1) else 30.0))
    a1.annotate("Coulomb under-predicts\nabove ~2 mm/s", xy=(3.0, float(coulomb["friction_mN"].iloc[0])),
                xytext=(4.0, 2.0), fontsize=6, arrowprops=dict(arrowstyle="->", lw=0.6))
    a1.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), fontsize=5.5, ncol=2)
    # ---- Case 4: contractive intestine (N)
    seen4: set = set()
    ref4 = reference[reference["case"].astype(str) == "4"]
    if "Ri_mm" in ref4.columns:
        ref4 = ref4[~np.isfinite(ref4["Ri_mm"])]  # FE values per radius go to the radius figure
    lines = {}
    for r in Ri_mm:
        sub = hoop[np.isclose(hoop["Ri_mm"], r)].sort_values("speed_mm_s")
        if sub.empty:
            raise ValueError(f"hoop table has no rows for R_i = {r} mm")
        lines[r] = sub
    if len(lines) == 2:
        (r1, s1), (r2, s2) = lines.items()
        a4.fill_between(s1["speed_mm_s"], s1["total_friction_N"], s2["total_friction_N"].to_numpy(),
                        color="0.85", lw=0, label=f"between $R_i$ {min(r1, r2):g} and {max(r1, r2):g} mm")
    for r, sub in lines.items():
        a4.plot(sub["speed_mm_s"], sub["total_friction_N"], color=HOOP_COLORS.get(r, None), lw=1.4,
                label=f"hoop model eq 16, $R_i$ {r:g} mm")
    a4.plot(case4_law["speed_mm_s"], case4_law["friction_mN"] * 1e-3, label="paper's fit, eq 18",
            **PAPER_FIT_STYLE)
    a4.plot(coulomb["speed_mm_s"], coulomb["friction_mN"] * 1e-3,
            label=f"Coulomb eq 1: {coulomb['friction_mN'].iloc[0] * 1e-3:.3f} N",
            **COULOMB_STYLE)
    _reference_points(a4, ref4, 1e-3, seen4)
    a4.set_xlabel(label("capsule speed", "mm/s"))
    a4.set_ylabel(label("friction", "N"))
    a4.set_title("(b) Case 4: contractive intestine")
    a4.set_xlim(0, None)
    a4.set_ylim(0, 5.5)
    a4.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), fontsize=5.5, ncol=2)
    return save_figure(fig, path)


COMPONENT_STYLE = {
    "head_resistance_N": ("head resistance f_hr", OKABE_ITO[0], "-"),
    "head_friction_N": ("head friction f_hf", OKABE_ITO[5], "--"),
    "body_friction_N": ("body friction f_bf", OKABE_ITO[2], "-"),
    "tail_push_N": ("tail push f_tr (< 0)", OKABE_ITO[1], "-"),
    "tail_friction_N": ("tail friction f_tf", OKABE_ITO[4], "--"),
}


def plot_hoop_vs_radius(hoop: pd.DataFrame, reference: pd.DataFrame, path: str | Path,
                        speed_mm_s: float = 4.0, case4_Ri_mm: tuple[float, float] = (4.4, 4.8)) -> Path:
    """Draw the hoop-friction components (a) and the total at several speeds (b) against R_i."""
    speeds = np.sort(hoop["speed_mm_s"].unique())
    v0 = speeds[np.argmin(np.abs(speeds - speed_mm_s))]
    sub = hoop[hoop["speed_mm_s"] == v0].sort_values("Ri_mm")
    fig, (a, b) = figure(2, 1, width="page", height_in=4.0)
    ref4 = reference[reference["case"].astype(str) == "4"]
    meas = ref4[(ref4["source_type"] == "experiment") & ref4["statistic"].isin(["min", "max"])]
    fe = ref4[(ref4["source_type"] == "FE")] if "Ri_mm" in ref4.columns else ref4.iloc[:0]
    fe = fe[np.isfinite(fe["Ri_mm"])] if len(fe) else fe
    for ax in (a, b):
        ax.axvspan(*case4_Ri_mm, color="0.92", lw=0, zorder=0)
        if len(meas) >= 2:
            lo, hi = meas["friction_mN"].min() * 1e-3, meas["friction_mN"].max() * 1e-3
            ax.axhspan(lo, hi, color="#E69F00", alpha=0.12, lw=0, zorder=0,
                       label=f"experiment: Case 4 range {lo:g}-{hi:g} N (seed 000)")
        if len(fe):
            ax.plot(fe["Ri_mm"], fe["friction_mN"] * 1e-3, label="FE, no gravity (seed 000)", zorder=5,
                    **REFERENCE_STYLE["FE"])
        ax.axhline(0, color="0.3", lw=0.6)
        ax.set_xlabel(label("intestine inner radius $R_i$", "mm"))
        ax.set_ylabel(label("friction", "N"))
    for col, (name, colour, ls) in COMPONENT_STYLE.items():
        a.plot(sub["Ri_mm"], sub[col], color=colour, ls=ls, label=name)
    a.plot(sub["Ri_mm"], sub["hoop_friction_N"], color="black", lw=1.8, label="hoop friction F_h (eq 15)")
    a.set_title(f"(a) components at V = {v0:g} mm/s")
    a.text(np.mean(case4_Ri_mm), a.get_ylim()[1] * 0.97, "Case 4\n$R_i$ range", ha="center", va="top", fontsize=6)
    a.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), fontsize=5.5, ncol=2)
    pick = np.unique([speeds[0], v0, speeds[-1]])
    for i, v in enumerate(pick):
        s = hoop[hoop["speed_mm_s"] == v].sort_values("Ri_mm")
        b.plot(s["Ri_mm"], s["total_friction_N"], color=OKABE_ITO[(i + 1) % len(OKABE_ITO)],
               ls=["-", "--", ":"][i % 3], label=f"F_c4 = F_g + F_h, V = {v:g} mm/s")
    b.set_title("(b) total friction (eq 16): $R_i$ matters far more than V")
    b.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), fontsize=5.5, ncol=1)
    return save_figure(fig, path)
