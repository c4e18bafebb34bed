"""Figures of the contact stage: tables in, figures out (no physics is recomputed here).

* :func:`plot_pressure_vs_speed`: Cases 1-3, model curves with the published
  values overlaid and labelled by kind (experiment, FE, analytic).
* :func:`plot_hoop_profile`: the hoop pressure along the capsule (speeds or end shapes).
* :func:`plot_pressure_vs_radius`: hoop pressure against the intestine radius R_i.
* :func:`plot_end_shape`: hoop pressure statistics against the end length.
* :func:`plot_relax_fit`: a relaxation record with the fitted Prony series.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from matplotlib.transforms import blended_transform_factory

from .style import OKABE_ITO, REFERENCE_STYLE, figure, label, save_figure

_CASE_TITLES = {"case1": "Case 1: flat intestine (Hertz)", "case2": "Case 2: collapsed intestine",
                "case3": "Case 3: contractive intestine (hoop)"}
_KIND_NAMES = {"experiment": "experiment", "FE": "FE", "analytic": "analytic", "fit": "fit"}


#: marker of published averages by seed paper (maxima are triangles '^')
_SEED_MARKER = {"003": "o", "001": "D", "000": "s", "004": "P"}
_TYPE_COLOUR = {"experiment": "#000000", "FE": "#D55E00", "analytic": "#009E73", "fit": "#CC79A7"}


def _published_key(row) -> tuple[str, str, bool]:
    """(source type, seed number, with gravity) of a reference row, from its columns and citation."""
    import re

    seed = re.search(r"seed (\d{3})", str(row.get("source", "")))
    text = f"{row.get('label', '')} {row.get('note', '')}"
    gravity = "(+g)" in text or "with gravity" in text
    return str(row["source_type"]), seed.group(1) if seed else "", gravity


def _published_name(key: tuple[str, str, bool], statistic: str = "avg") -> str:
    kind, seed, gravity = key
    stat = {"avg": " average", "max": " maximum"}.get(statistic, f" {statistic}")
    return f"{kind}{stat}{', with gravity' if gravity else ''}" + (f" (seed {seed})" if seed else "")


def _overlay_reference(ax, ref: pd.DataFrame, xcol: str, xmax: float = 0.0, annotate: bool = False, seen=None,
                       xlabel_level: float = 0.0):
    """Draw published values, named in the legend by origin (experiment, FE, analytic), seed and gravity.

    Values at a given ``xcol`` are markers: shape by seed, colour by origin, open when measured or
    computed with gravity. Values the paper gives without an ``xcol`` are dotted levels across the axis,
    with their marker in the margin right of the axis (never at a made-up x). No text sits on the curves.
    """
    seen = set() if seen is None else seen
    right = blended_transform_factory(ax.transAxes, ax.transData)
    n_level = 0
    for _, r in ref.iterrows():
        key = _published_key(r)
        kind, seed, gravity = key
        col = _TYPE_COLOUR.get(kind, "#CC79A7")
        mk = "^" if str(r.get("statistic", "avg")) == "max" else _SEED_MARKER.get(seed, "^")
        name = _published_name(key, str(r.get("statistic", "avg")))
        lab = None if name in seen else name
        seen.add(name)
        style = dict(marker=mk, color=col, mfc="none" if gravity or kind == "experiment" else col, ms=5, ls="none",
                     mew=1.0)
        if np.isfinite(r[xcol]):
            ax.plot([r[xcol]], [r["pressure_kPa"]], label=lab, zorder=4, **style)
        else:
            ax.axhline(r["pressure_kPa"], color=col, lw=0.7, ls=":", zorder=1)
            ax.plot([1.03 + 0.05 * (n_level % 2)], [r["pressure_kPa"]], clip_on=False, zorder=4, label=lab,
                    transform=right, **style)
            n_level += 1
    return seen


def _repel(ax, min_gap_pt: float = 7.0, width_pt: float = 70.0) -> None:
    """Move annotation labels apart vertically so that neighbouring labels do not overlap.

    Call after the axis limits are final. Labels whose anchors lie within
    ``width_pt`` horizontally are kept at least ``min_gap_pt`` apart.
    """
    anns = [c for c in ax.texts if hasattr(c, "xyann")]
    if len(anns) < 2:
        return
    fig = ax.figure
    scale = 72.0 / fig.dpi
    pos = []
    for a in anns:
        x, y = ax.transData.transform(a.xy)
        dx, dy = a.xyann
        pos.append([x * scale + dx, y * scale + dy, a])
    pos.sort(key=lambda p: p[1])
    for _ in range(20):
        moved = False
        for i in range(len(pos)):
            for j in range(i + 1, len(pos)):
                if abs(pos[j][0] - pos[i][0]) < width_pt and pos[j][1] - pos[i][1] < min_gap_pt:
                    pos[j][1] = pos[i][1] + min_gap_pt
                    moved = True
        pos.sort(key=lambda p: p[1])
        if not moved:
            break
    for x, y, a in pos:
        ax_x, ax_y = ax.transData.transform(a.xy)
        a.xyann = (a.xyann[0], y - ax_y * scale)


def plot_pressure_vs_speed(table: pd.DataFrame, reference: pd.DataFrame | None, path: str | Path,
                           hoop_Ri_mm: float = 5.0) -> Path:
    """Plot average contact pressure against speed for Cases 1-3 with the published values.

    ``table``: a ``contact_pressure`` table (all three models); ``reference``: the
    reference table (rows of case1-case3 are drawn; speed-independent values as
    dotted levels marked at the right edge). The hoop panel shows R_i = ``hoop_Ri_mm``.
    """
    fig, axes = figure(ncols=3, width="page", height_in=3.6)
    vmax = float(table["speed_mm_s"].max())
    for ax, (case, model) in zip(axes, (("case1", "hertz"), ("case2", "collapsed"), ("case3", "hoop"))):
        t = table[table["model"] == model]
        if model == "hertz":
            for stat, ls, name in (("avg", "-", "Hertz average (eq 5)"), ("max", "--", "Hertz maximum (eq 4)")):
                d = t[t["statistic"] == stat].sort_values("speed_mm_s")
                ax.plot(d["speed_mm_s"], d["pressure_kPa"], ls=ls, color=OKABE_ITO[0], label=name)
        elif model == "collapsed":
            d = t[t["statistic"] == "avg"].sort_values("speed_mm_s")
            ax.plot(d["speed_mm_s"], d["pressure_kPa"], color=OKABE_ITO[0], label="Hertz + wall weight (eq 6)")
            d = t[t["statistic"] == "wall_avg"].sort_values("speed_mm_s")
            ax.plot(d["speed_mm_s"], d["pressure_kPa"], color=OKABE_ITO[0], ls="--", lw=0.9,
                    label="wall share $P_1$")
        else:
            t = t[(t["statistic"] == "avg") & (t["end_length_mm"] == t["end_length_mm"].iloc[0])]
            sel = t[np.isclose(t["Ri_mm"], hoop_Ri_mm)]
            for mode, ls in (("attenuated", "-"), ("original", "--")):
                d = sel[sel["wall_mode"] == mode].sort_values("speed_mm_s")
                if len(d):
                    ax.plot(d["speed_mm_s"], d["pressure_kPa"], ls=ls, color=OKABE_ITO[0],
                            label=f"hoop eq 14, {'$t_{i,e}$' if mode == 'attenuated' else '$t_i$'}")
        seen = set()
        if reference is not None:
            ref = reference[(reference["case"] == case) & reference["statistic"].isin(["avg", "max"])]
            if model == "hoop":
                ref = ref[np.isclose(ref["Ri_mm"], hoop_Ri_mm) & (ref["statistic"] == "avg")]
            _overlay_reference(ax, ref, "speed_mm_s", vmax, seen=seen)
        ri = t["Ri_mm"].iloc[0] if len(t) else np.nan
        rtxt = "$R_i$ = ∞ (flat)" if not np.isfinite(ri) else f"$R_i$ = {hoop_Ri_mm if model == 'hoop' else ri:g} mm"
        ax.set_title(f"{_CASE_TITLES[case]}\n{rtxt}")
        ax.set_xlabel(label("speed $V$", "mm/s"))
        ax.set_xlim(0, vmax * 1.02)  # speeds are >= 0: no point is drawn left of the axis
        lo, hi = ax.get_ylim()
        ax.set_ylim(0, hi * 1.1)
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), fontsize=5.5, ncol=1,
                  title="lines: this model; markers: published\n(dotted: value given without a speed)",
                  title_fontsize=5.5)
    axes[0].set_ylabel(label("contact pressure", "kPa"))
    return save_figure(fig, path)


def plot_hoop_vs_speed(table: pd.DataFrame, path: str | Path) -> Path:
    """Plot the body-averaged hoop pressure against speed, one line per intestine radius R_i.

    ``table``: a ``contact_pressure`` table of the hoop model over speeds and
    several R_i (solid: attenuated wall t_i,e; dashed: original t_i).
    """
    fig, ax = figure(height_in=2.8)
    t = table[(table["model"] == "hoop") & (table["statistic"] == "avg")]
    t = t[t["end_length_mm"] == t["end_length_mm"].iloc[0]]
    for i, ri in enumerate(sorted(t["Ri_mm"].unique())):
        for mode, ls in (("attenuated", "-"), ("original", "--")):
            d = t[(t["Ri_mm"] == ri) & (t["wall_mode"] == mode)].sort_values("speed_mm_s")
            if len(d):
                ax.plot(d["speed_mm_s"], d["pressure_kPa"], ls=ls, color=OKABE_ITO[i % len(OKABE_ITO)],
                        label=f"$R_i$ = {ri:g} mm" if mode == "attenuated" else None)
    ax.set_xlabel(label("speed $V$", "mm/s"))
    ax.set_ylabel(label("hoop pressure on the body (eq 14)", "kPa"))
    ax.set_ylim(bottom=0)
    ax.set_xlim(left=0)
    ax.legend(fontsize=5.5, ncol=2, loc="lower right", title="solid $t_{i,e}$, dashed $t_i$", title_fontsize=5.5)
    return save_figure(fig, path)


def plot_hoop_profile(profile: pd.DataFrame, path: str | Path, by: str = "speed_mm_s",
                      wall_mode: str = "attenuated") -> Path:
    """Plot the hoop pressure along the capsule (head end, body, tail end).

    ``profile``: a ``hoop_profile`` table; one line per value of ``by``
    (``speed_mm_s`` or ``end_length_mm``), x measured from the start of the
    cylindrical body so the body spans [0, L] for every end shape. The capsule
    moves towards its head (negative x).
    """
    fig, ax = figure(height_in=2.9)
    prof = profile[profile["wall_mode"] == wall_mode]
    if prof.empty:
        prof = profile
    values = sorted(prof[by].unique())
    body = prof[prof["segment"] == "body"]
    L = float(body["x_body_mm"].max())
    xmin, xmax = float(prof["x_body_mm"].min()), float(prof["x_body_mm"].max())
    ax.axvspan(xmin, 0.0, color="0.92", lw=0, zorder=0)
    ax.axvspan(L, xmax, color="0.92", lw=0, zorder=0)
    for i, v in enumerate(values):
        d = prof[prof[by] == v].sort_values("x_mm")
        unit = "mm/s" if by == "speed_mm_s" else "mm"
        name = f"$V$ = {v:g} {unit}" if by == "speed_mm_s" else f"$L_e$ = {v:g} {unit}"
        ax.plot(d["x_body_mm"], d["pressure_kPa"], color=OKABE_ITO[i % len(OKABE_ITO)], label=name)
    pmax = float(prof["pressure_kPa"].max())
    ax.set_ylim(0, pmax * 1.35)
    for x, txt in ((0.5 * xmin, "head end"), (0.5 * L, "cylindrical body"), (0.5 * (L + xmax), "tail end")):
        ax.text(x, pmax * 1.27, txt, ha="center", va="center", fontsize=6, color="0.3")
    ax.annotate("", xy=(xmin, pmax * 1.18), xytext=(xmin + 0.2 * (xmax - xmin), pmax * 1.18),
                arrowprops=dict(arrowstyle="->", color="0.3", lw=0.8))
    ax.text(xmin + 0.21 * (xmax - xmin), pmax * 1.18, "motion", va="center", fontsize=6, color="0.3")
    ri = prof["Ri_mm"].iloc[0]
    wall = "$t_{i,e}$" if wall_mode == "attenuated" else "$t_i$"
    extra = (f", $V$ = {prof['speed_mm_s'].iloc[0]:g} mm/s" if by != "speed_mm_s"
             else ("" if prof["end_length_mm"].nunique() > 1
                   else f", end length {prof['end_length_mm'].iloc[0]:g} mm"))
    ax.set_title(f"Hoop pressure along the capsule, $R_i$ = {ri:g} mm, wall {wall}{extra}", fontsize=7)
    ax.set_xlabel(label("axial position from the start of the body $x - x_c$", "mm"))
    ax.set_ylabel(label("hoop pressure $P_h(x)$", "kPa"))
    ax.legend(loc="lower center", fontsize=6, ncol=2)
    return save_figure(fig, path)


def plot_pressure_vs_radius(table: pd.DataFrame, reference: pd.DataFrame | None, path: str | Path) -> Path:
    """Plot the body-averaged hoop pressure against the intestine radius R_i for several speeds.

    ``table``: a ``contact_pressure`` table of the hoop model over R_i; published
    hoop-only FE values at R_i = 5 mm are overlaid.
    """
    fig, ax = figure(height_in=3.9)
    t = table[(table["model"] == "hoop") & (table["statistic"] == "avg")]
    speeds = sorted(t["speed_mm_s"].unique())
    for i, v in enumerate(speeds):
        for mode, ls in (("attenuated", "-"), ("original", "--")):
            d = t[(t["speed_mm_s"] == v) & (t["wall_mode"] == mode)].sort_values("Ri_mm")
            if len(d):
                ax.plot(d["Ri_mm"], d["pressure_kPa"], ls=ls, color=OKABE_ITO[i % len(OKABE_ITO)],
                        label=f"{v:g} mm/s" + ("" if mode == "attenuated" else ", $t_i$"))
    if reference is not None:
        ref = reference[(reference["case"] == "case3") & reference["label"].str.contains("hoop")
                        & np.isfinite(reference["speed_mm_s"])]
        for i, (_, r) in enumerate(ref.sort_values("pressure_kPa").iterrows()):
            key = _published_key(r)
            col = _TYPE_COLOUR.get(key[0], "#CC79A7")
            # the published points share R_i = 5 mm: spread them a little in x so none hides another
            ax.plot([r["Ri_mm"] + 0.03 * (i - (len(ref) - 1) / 2)], [r["pressure_kPa"]], ls="none",
                    marker=_SEED_MARKER.get(key[1], "^"), color=col, mfc=col, ms=4.5, zorder=5,
                    label=f"{_published_name(key)}, hoop only, {r['speed_mm_s']:g} mm/s")
    ax.set_xlabel(label("intestine inner radius $R_i$", "mm"))
    ax.set_ylabel(label("hoop pressure on the body (eq 14)", "kPa"))
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=5.5, ncol=2, loc="upper center", bbox_to_anchor=(0.5, -0.2),
              title="lines: this model at speed (solid $t_{i,e}$, dashed $t_i$); markers: published FE",
              title_fontsize=5.5)
    return save_figure(fig, path)


def plot_end_shape(table: pd.DataFrame, reference: pd.DataFrame | None, path: str | Path,
                   wall_mode: str = "attenuated") -> Path:
    """Plot hoop pressure statistics (body average, contact average, maximum) against the end length.

    ``table``: a ``contact_pressure`` table of the hoop model over end lengths at
    one speed; the FE maxima of seed 001 section 6 are overlaid.
    """
    fig, ax = figure(height_in=3.6)
    t = table[(table["model"] == "hoop") & (table["wall_mode"] == wall_mode)]
    names = {"avg": "body average (eq 14)", "contact_avg": "area average, ends included", "max": "maximum"}
    styles = {"avg": dict(marker="o", ls="-"), "contact_avg": dict(marker="s", ls="-."),
              "max": dict(marker="^", ls="--")}
    for i, (stat, name) in enumerate(names.items()):
        d = t[t["statistic"] == stat].sort_values("end_length_mm")
        ax.plot(d["end_length_mm"], d["pressure_kPa"], ms=3, color=OKABE_ITO[i], label=f"model {name}",
                **styles[stat])
    xmax = float(t["end_length_mm"].max())
    if reference is not None:
        ref = reference[reference["case"] == "case3_end_shape"]
        _overlay_reference(ax, ref, "end_length_mm", xmax, xlabel_level=float(t["end_length_mm"].min()))
    ax.set_xlabel(label("semi-elliptical end length $L_e$", "mm"))
    ax.set_ylabel(label("contact pressure", "kPa"))
    v = t["speed_mm_s"].iloc[0] if len(t) else np.nan
    ax.set_title(f"End shape, $R_i$ = {t['Ri_mm'].iloc[0]:g} mm, $V$ = {v:g} mm/s", fontsize=7)
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=5.5, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2,
              title="lines: this model; markers: published (dotted: end length not stated)", title_fontsize=5.5)
    if reference is not None and len(ref):
        fe_max = ref[(ref["source_type"] == "FE") & (ref["statistic"] == "max")]["pressure_kPa"]
        mod_max = t[t["statistic"] == "max"]["pressure_kPa"]
        if len(fe_max) and len(mod_max) and fe_max.min() > 1.3 * mod_max.max():
            ax.text(0.03, 0.62, f"FE maxima {' and '.join(f'{v:.0f}' for v in sorted(fe_max, reverse=True))} kPa "
                    f"vs model maximum \u2264 {mod_max.max():.0f} kPa:\nthe axisymmetric hoop model has no stress "
                    "concentration\nwhere the end meets the body (3D FE edge contact)",
                    transform=ax.transAxes, fontsize=5.5, color="0.3", va="top")
    return save_figure(fig, path)


def plot_relax_fit(data: pd.DataFrame, curve: pd.DataFrame, path: str | Path, chosen: int) -> Path:
    """Plot a relaxation record, the fitted Prony curves and the residuals of the chosen order.

    ``data``: measured points with ``time_s``, ``pressure_kPa``, ``fitted_kPa``
    (optional ``trial``); ``curve``: the ``relax_curve`` table (``n_arms``,
    ``time_s``, ``pressure_kPa``, ``lower_kPa``, ``upper_kPa``).
    """
    fig, (ax, axr) = figure(nrows=2, height_in=3.6, sharex=True, gridspec_kw={"height_ratios": [2.4, 1]})
    ax.plot(data["time_s"], data["pressure_kPa"], ".", ms=1.5, color="0.6", label="record", rasterized=True)
    for i, (m, d) in enumerate(curve.groupby("n_arms")):
        d = d.sort_values("time_s")
        if m == chosen:
            ax.fill_between(d["time_s"], d["lower_kPa"], d["upper_kPa"], color=OKABE_ITO[0], alpha=0.25, lw=0)
            ax.plot(d["time_s"], d["pressure_kPa"], color=OKABE_ITO[0],
                    label=f"{m} arm{'s' if m > 1 else ''}, chosen (95 % band)")
        else:
            ax.plot(d["time_s"], d["pressure_kPa"], color=OKABE_ITO[(i + 1) % len(OKABE_ITO)], ls="--", lw=0.9,
                    label=f"{m} arm{'s' if m > 1 else ''}")
    ax.set_ylabel(label("contact pressure", "kPa"))
    ax.legend(fontsize=6)
    axr.plot(data["time_s"], data["pressure_kPa"] - data["fitted_kPa"], ".", ms=1.5, color="0.4", rasterized=True)
    axr.axhline(0, color="k", lw=0.6)
    axr.set_xlabel(label("time since the step", "s"))
    axr.set_ylabel(label("residual", "kPa"))
    return save_figure(fig, path)
