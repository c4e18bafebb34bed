"""Figures of the model-versus-measurement loop (tables in, figures out; no physics here)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..units import split_unit, unit_label
from .style import OKABE_ITO, blank_figure, figure, label, save_figure


#: covariates whose axis takes the papers' symbol (seed 000 eq 19: the drive amplitude P_d) instead of the column name
_SYMBOLS = {"Pd": "$P_d$"}


def _nice(col: str) -> str:
    base, suffix = split_unit(col)
    return label(_SYMBOLS.get(base, base.replace("_", " ")), unit_label(col) if suffix else "")


def _cols(resp: str):
    base, u = split_unit(resp)
    return f"observed_{base}_{u}", f"predicted_{base}_{u}", f"residual_{base}_{u}"


def data_label(synthetic: bool) -> str:
    """Return the legend label of measured points ('synthetic data' for tables made by synth)."""
    return "synthetic data" if synthetic else "data"


_STAT_WORDS = {"avg": "average", "max": "maximum", "min": "minimum", "wall_avg": "wall share",
               "contact_avg": "area average"}


def origin_of(sources: pd.Series | None, synthetic: bool = False) -> pd.Series | None:
    """Per row, where a data point comes from: 'FE', 'experiment' (from a 'source' column citing the
    paper) or None when the table does not say. Synthetic tables are 'synthetic'."""
    if sources is None:
        return None
    if synthetic:
        return pd.Series("synthetic", index=sources.index)
    txt = sources.astype(str)
    return pd.Series(np.where(txt.str.contains(r"\bFE\b|finite element", case=False, regex=True), "FE",
                              "experiment"), index=sources.index)


def _seeds(sources: pd.Series) -> str:
    found = sorted(set(sources.astype(str).str.findall(r"seed (\d{3})").sum()))
    return ", ".join(f"seed {x}" for x in found)


def _value_text(col: str, value) -> str:
    """'speed_mm_s', 0.5 -> 'V = 0.5 mm/s'; 'statistic', 'max' -> 'maximum'."""
    names = {"speed_mm_s": "V", "Ri_mm": "$R_i$", "bend_radius_mm": "bend radius", "end_length_mm": "$L_e$",
             "time_s": "t", "position_mm": "x"}
    if col == "statistic":
        return _STAT_WORDS.get(str(value), str(value))
    base, suffix = split_unit(col)
    if suffix:
        try:
            return f"{names.get(col, base.replace('_', ' '))} = {float(value):g} {unit_label(col)}"
        except (TypeError, ValueError):
            pass
    return f"{base.replace('_', ' ')}: {value}"


def _parse_curve(lab: str) -> dict[str, str]:
    out = {}
    for part in str(lab).split(", "):
        if "=" in part:
            k, v = part.split("=", 1)
            out[k.strip()] = v.strip()
        elif out:  # a value with a comma in it
            last = list(out)[-1]
            out[last] += ", " + part
    return out


def _matches(res: pd.DataFrame, combo: dict[str, str]) -> np.ndarray:
    ok = np.ones(len(res), bool)
    for k, v in combo.items():
        if k not in res.columns:
            continue
        col = res[k]
        try:
            ok &= np.isclose(col.to_numpy(float), float(v))
        except (TypeError, ValueError):
            ok &= (col.astype(str) == v).to_numpy()
    return ok


_ORIGIN_MARKER = {"FE": dict(marker="^", mfc="none"), "experiment": dict(marker="o", mfc="none"),
                  "synthetic": dict(marker="o", mfc="none"), None: dict(marker="o", mfc="none")}


#: most data markers drawn per panel; larger tables are thinned evenly (a million markers show nothing more)
MAX_POINTS = 20_000


def _thin(df: pd.DataFrame, label: str) -> tuple[pd.DataFrame, str]:
    """Return every k-th row of ``df`` so that at most MAX_POINTS remain, and the label saying so."""
    if len(df) <= MAX_POINTS:
        return df, label
    step = -(-len(df) // MAX_POINTS)
    return df.iloc[::step], f"{label} (every {step}th of {len(df)} points shown)"


def plot_fit(res: pd.DataFrame, curves: pd.DataFrame, main: str, resp: str, path: str | Path,
             title: str = "", noise_sd: float | None = None, extra: pd.DataFrame | None = None,
             extra_label: str = "", data_label: str = "data", outliers: pd.DataFrame | None = None) -> Path:
    """Draw data and the calibrated model with its 95 % confidence band against ``main``; ``outliers`` (rows
    of the data with ``main`` and ``resp``) are drawn as crosses, so the rows left out of the fits are seen.

    One colour per covariate combination (curve), the data points in the colour of their curve; the
    legend names the covariates physically (``V = 0.5 mm/s, maximum``) and only those that vary;
    the ones that do not vary go to the legend title. Data points say where they come from:
    synthetic, published FE or published experiment (from a ``source`` column).
    """
    obs, pred, _ = _cols(resp)
    res, data_label = _thin(res, data_label)
    synthetic = data_label.startswith("synthetic")
    origin = origin_of(res["source"], synthetic) if "source" in res.columns else None
    labels = curves.drop_duplicates("curve_id").sort_values("curve_id")
    combos = {int(r.curve_id): _parse_curve(r.curve) for r in labels.itertuples() if r.curve not in ("model",
                                                                                                    "at data")}
    keys = list(dict.fromkeys(k for c in combos.values() for k in c))
    varying = [k for k in keys if len({c.get(k) for c in combos.values()}) > 1]
    fixed = [k for k in keys if k not in varying]
    many = len(combos) > 3
    fig, ax = figure(width="page" if many else "column", height_in=3.2 if many else 3.6)
    colour = {cid: OKABE_ITO[i % len(OKABE_ITO)] for i, cid in enumerate(sorted(curves["curve_id"].unique()))}
    drawn = np.zeros(len(res), bool)
    for cid, combo in combos.items():
        sel = _matches(res, {k: combo[k] for k in varying}) & ~drawn
        drawn |= sel
        for org in ([None] if origin is None else sorted(origin[sel].unique())):
            pick = sel if origin is None else sel & (origin == org).to_numpy()
            if pick.any():
                ax.plot(res.loc[pick, main], res.loc[pick, obs], ls="none", ms=4, color=colour[cid], mew=1.0,
                        zorder=3, **_ORIGIN_MARKER.get(org, _ORIGIN_MARKER[None]))
    rest = ~drawn
    if rest.any():
        ax.plot(res.loc[rest, main], res.loc[rest, obs], "o", ms=3, mfc="none", color="0.25", alpha=0.8, zorder=3)
    groups = list(curves.groupby("curve_id", sort=True))
    same = len(groups) > 1 and all(len(c) == len(groups[0][1]) and np.allclose(
        c["predicted"].to_numpy(), groups[0][1]["predicted"].to_numpy(), rtol=1e-9, atol=0) for _, c in groups)
    if same and varying:  # the model does not depend on the covariates that vary: one line says so
        c = groups[0][1]
        ax.fill_between(c["x"], c["lower"], c["upper"], color="0.5", alpha=0.25, lw=0)
        ax.plot(c["x"], c["predicted"], color="0.2",
                label="model, the same for every " + " and ".join(_nice(k).split(" [")[0] for k in varying))
        for cid, combo in combos.items():
            ax.plot([], [], "o", ms=4, mfc="none", color=colour[cid],
                    label="data at " + ", ".join(_value_text(k, combo[k]) for k in varying))
        groups = []
    for cid, c in groups:
        col = colour[cid]
        lab = str(c["curve"].iloc[0])
        if lab == "at data":
            ax.errorbar(c["x"], c["predicted"], yerr=[c["predicted"] - c["lower"], c["upper"] - c["predicted"]],
                        fmt=".", ms=2, color=col, elinewidth=0.6, label="model (95 % band) at the data")
        else:
            name = ", ".join(_value_text(k, combos[cid][k]) for k in varying) if cid in combos and varying \
                else "model"
            ax.fill_between(c["x"], c["lower"], c["upper"], color=col, alpha=0.25, lw=0)
            ax.plot(c["x"], c["predicted"], color=col, label=name)
    if extra is not None:
        for i, (cid, c) in enumerate(extra.groupby("curve_id", sort=True)):
            lab = str(c["curve"].iloc[0])
            if lab == "at data":
                ax.plot(c["x"], c["predicted"], "x", ms=3, color=OKABE_ITO[1], label=extra_label)
            else:
                ax.plot(c["x"], c["predicted"], "--", color=colour.get(cid, OKABE_ITO[(i + 1) % len(OKABE_ITO)]),
                        lw=0.9, label=extra_label if i == 0 else None)
    if outliers is not None and len(outliers) and {main, resp} <= set(outliers.columns):
        ax.plot(outliers[main], outliers[resp], "x", ms=5, mew=1.2, color=OKABE_ITO[7], zorder=4,
                label="outlier, left out of the fits")
    # origin of the points, in black so it reads apart from the colours of the covariates
    if origin is None:
        ax.plot([], [], "o", ms=4, mfc="none", color="0.25",
                label=data_label)
    else:
        seeds = _seeds(res["source"])
        for org in sorted(origin.unique()):
            name = {"FE": "published FE", "experiment": "published experiment"}.get(org, "synthetic data")
            ax.plot([], [], ls="none", ms=4, color="0.25", label=f"{name}" + (f" ({seeds})" if seeds and
                                                                               org != "synthetic" else ""),
                    **_ORIGIN_MARKER.get(org, _ORIGIN_MARKER[None]))
    ax.set_xlabel(_nice(main))
    ax.set_ylabel(_nice(resp))
    if title:
        ax.set_title(title, fontsize=7)
    legend_title = "lines: model, 95 % band"
    if fixed:
        legend_title += "\n" + ", ".join(_value_text(k, list(combos.values())[0][k]) for k in fixed)
    if many:  # page width: the legend beside the axes
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=6, title=legend_title, title_fontsize=6,
                  borderaxespad=0.0)
    else:  # column width: below, so the axes keep the width
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.22), fontsize=6, title=legend_title,
                  title_fontsize=6, ncol=2)
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
        step = -(-x.size // MAX_POINTS)  # thinned evenly above MAX_POINTS markers (the mean line uses all)
        ax.plot(x[::step], r[::step], "o", ms=2.5, mfc="none", color=OKABE_ITO[0], alpha=0.8)
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


def noise_band_label(noise: float, se: float, unit: str, method: str) -> str:
    """Return the legend label of the noise band: an estimate ("noise level"), or, as ``method`` says, the data's
    own spread (no replicates and too few points) or an upper bound (no replicates: differences that hold
    signal, or a fit's residual SD), never drawn as the noise level."""
    if method.startswith("no replicates and too few"):
        return f"data spread {noise:.3g} {unit} (upper bound on noise)"
    if "upper bound" in method:
        return f"noise ≤ {noise:.3g} {unit} (no replicates)"
    return f"noise level {noise:.3g} ± {se:.2g} {unit}"


#: the ledger's error axis is logarithmic when its errors and noise level span more than this ratio: a model
#: held out at 37.7 mm/s beside its revision at 0.59 and a noise of 0.45 leaves the last two indistinguishable from
#: zero on a linear axis, and whether the revision reached the noise is what the plot is read for
LEDGER_LOG_SPAN = 20.0


def ledger_log_scale(values) -> bool:
    """Return True when the positive finite ``values`` (errors and noise level [response unit]) span more than
    LEDGER_LOG_SPAN."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v) & (v > 0)]
    return bool(v.size >= 2 and v.max() / v.min() > LEDGER_LOG_SPAN)


def plot_ledger(hist: pd.DataFrame, path: str | Path, title: str = "") -> Path:
    """Draw the held-out error per revision (± SE, its value written beside it), the in-sample RMSE, and the noise
    level as a band; on a logarithmic axis when they span more than LEDGER_LOG_SPAN."""
    fig, ax = figure(height_in=2.8)
    x = np.arange(len(hist))
    unit = str(hist["unit"].iloc[-1])
    noise = float(hist["noise_sd"].iloc[-1])
    nse = float(hist["noise_sd_se"].iloc[-1]) if "noise_sd_se" in hist else 0.0
    method = str(hist["noise_method"].iloc[-1]) if "noise_method" in hist else ""
    cv = hist["cv_rmse"].to_numpy(float)
    log = ledger_log_scale(np.r_[cv, hist["rmse"].to_numpy(float), [noise]])
    if np.isfinite(noise):
        lo = max(noise - nse, noise / 10) if log else noise - nse
        ax.axhspan(lo, noise + nse, color=OKABE_ITO[2], alpha=0.2, lw=0,
                   label=noise_band_label(noise, nse, unit, method))
        ax.axhline(noise, color=OKABE_ITO[2], lw=0.8)
    ax.errorbar(x, hist["cv_rmse"], yerr=np.nan_to_num(hist["cv_rmse_se"].to_numpy(float)), fmt="o-",
                color=OKABE_ITO[0], capsize=3, label="held-out RMSE (± SE)")
    ax.plot(x, hist["rmse"], "s", mfc="none", color=OKABE_ITO[1], ms=4, label="in-sample RMSE")
    for xi, v in zip(x, cv):
        if np.isfinite(v):
            ax.annotate(f"{v:.3g}", (xi, v), xytext=(5, 3), textcoords="offset points", fontsize=6,
                        color=OKABE_ITO[0])
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
    if log:
        ax.set_yscale("log")
        # plain numbers (6, 0.3), not 6 x 10^0: the reader compares them with the annotated values and the noise
        ax.yaxis.set_major_formatter(_plain_log_formatter())
        ax.yaxis.set_minor_formatter(_plain_log_formatter(minor=True))
    else:
        ax.set_ylim(0, None)
    ax.set_xlabel("model revision (effects added)")
    ax.set_ylabel(label("error", unit) + (" (log scale)" if log else ""))
    ax.set_title(title or "error history")
    ax.legend(loc="upper right", fontsize=6)
    return save_figure(fig, path)


def _plain_log_formatter(minor: bool = False):
    """Return a log-axis tick formatter that writes plain numbers (0.3, 6, 40) where matplotlib's default writes
    3 x 10^-1; minor ticks labelled only where the axis spans about two decades or less (its default rule)."""
    from matplotlib.ticker import LogFormatter

    class PlainLog(LogFormatter):
        def __call__(self, x, pos=None):
            return f"{x:g}" if super().__call__(x, pos) else ""

    return PlainLog(labelOnlyBase=False, minor_thresholds=(2, 0.5)) if minor else PlainLog()


def _class_colours(classes: tuple[str, ...]) -> dict[str, str]:
    """Return one colour per response class, by its place in ``classes`` (the same in every figure)."""
    return {c: OKABE_ITO[i % len(OKABE_ITO)] for i, c in enumerate(classes)}


def _value_ticks(ax, x) -> None:
    """Ticks at a drive's few values (<= 6: a design's levels), else at most 5 ticks, so labels do not collide."""
    from matplotlib.ticker import MaxNLocator

    u = np.unique(np.asarray(x, float)[np.isfinite(np.asarray(x, float))])
    if 1 <= u.size <= 6:
        ax.set_xticks(u, [f"{v:g}" for v in u])
    else:
        ax.xaxis.set_major_locator(MaxNLocator(5))


#: at most this many trajectory runs are named at the end of their line in the position-residual panel (more
#: would crowd it; each run's drift rate is in the row below by its drive either way)
RUN_LABELS_MAX = 8


def _label_run_ends(ax, runs: list, xcol: str, rcol: str, gap: float = 0.07) -> None:
    """Name each of ``runs`` ((name, frames) pairs; 2 to RUN_LABELS_MAX of them) right of the panel, each joined
    by a thin line to where its residual ends (the median of its last 5 frames, so one noisy frame does not
    place it); labels closer than ``gap`` of the axis height are moved apart, keeping the runs' order."""
    if not 2 <= len(runs) <= RUN_LABELS_MAX:
        return
    lo, hi = ax.get_ylim()
    ends = []
    for run, d in runs:
        tail = d[rcol].to_numpy(float)[-5:]
        level = float(np.nanmedian(tail)) if np.isfinite(tail).any() else 0.0
        ends.append((float(d[xcol].iloc[-1]), level, _run_label(run, d)))
    order = sorted(range(len(ends)), key=lambda i: ends[i][1])
    frac = [min(max((ends[i][1] - lo) / (hi - lo), 0.0), 1.0) for i in order]
    for k in range(1, len(frac)):  # upwards, then pulled back below the top as a block
        frac[k] = max(frac[k], frac[k - 1] + gap)
    shift = max(0.0, frac[-1] - 1.0)
    frac = [f - shift for f in frac]
    for i, f in zip(order, frac):
        x, y, text = ends[i]
        ax.annotate(text, (x, y), xytext=(1.01, f), textcoords="axes fraction", fontsize=6, va="center",
                    color="0.3", annotation_clip=False, arrowprops={"arrowstyle": "-", "color": "0.6", "lw": 0.5})


def _run_label(run, d: pd.DataFrame) -> str:
    """Return a run's label in the residual figure: its name and, when the frames carry them, its drive
    (f [Hz], P_d [N])."""
    drive = [f"{d[c].iloc[0]:g} {u}" for c, u in (("f_Hz", "Hz"), ("Pd_N", "N")) if c in d.columns]
    return f"{run} ({', '.join(drive)})" if drive else str(run)


def dynamics_residual_figure(frames: pd.DataFrame, xcols: list[str], rcol: str, unit: str, noise_sd: float,
                             classes: tuple[str, ...], title: str = "", drift: pd.DataFrame | None = None,
                             per_run: pd.DataFrame | None = None, run_cols: tuple[str, ...] = (),
                             rho: float = 0.0, left_out: pd.DataFrame | None = None):
    """Return the dynamics loop's residual figure (not saved).

    - ``frames``: the rows compared point by point (a progression's conditions, a trajectory's frames), with
      ``rcol`` [unit] and ``response_class``; one panel per column of ``xcols``, the noise SD as a grey band.
      ``classes``: every response class in a fixed order, one colour each, so that figures before and after an
      effect is added read alike.
    - ``drift``: a trajectory's runs compared by their drift over whole periods (columns run, ``rcol``, sd): a
      narrow panel of their own, so a drift is not read as a position error at one instant.
    - ``per_run``: a trajectory's runs (columns ``rate_mm_s``, ``rate_se_mm_s``, ``response_class`` and the
      columns of ``run_cols``): a second row, the slope of each run's position residual over time against each
      column of ``run_cols`` (the drive and the covariate a verdict names), so that a misfit that grows with
      the drive frequency is seen as it is named. ``rho``: the noise's lag-1 correlation from frame to frame
      that the rates' SEs allow for (0: white), said in the row's title.
    - ``left_out``: readings flagged as outliers and left out of the fits (the columns of ``xcols`` and ``rcol``,
      their residual under the model that flagged them), drawn as black crosses in every panel of ``xcols``;
      those with a ``why`` (readings gathered at one value of a covariate, or the readings at the value where the
      misfit gathered, read as an effect there) as open diamonds labelled with it."""
    colour = _class_colours(classes)
    runs = list(frames.groupby("run", sort=False)) if "run" in frames.columns else []
    rows = 2 if per_run is not None and run_cols else 1
    ratios = [3] * len(xcols) + ([1] if drift is not None and len(drift) else [])
    wide = len(ratios) > 1 or rows > 1
    fig = blank_figure("page" if wide else "column", height_in=2.5 * rows)
    outer = fig.add_gridspec(rows, 1)
    top = outer[0].subgridspec(1, len(ratios), width_ratios=ratios)
    axes = []
    for j, xcol in enumerate(xcols):
        ax = fig.add_subplot(top[0, j])
        ax.axhspan(-noise_sd, noise_sd, color="0.85", lw=0, zorder=0, label="± noise SD")
        if xcol == "time_s" and "run" in frames.columns:  # each run's frames joined, so a run is followed in time
            for _, d in runs:
                ax.plot(d[xcol], d[rcol], "-", color="0.6", lw=0.5, zorder=1)
        for c in classes:
            m = (frames["response_class"] == c).to_numpy()
            if m.any():
                ax.plot(frames[xcol][m], frames[rcol][m], "o", ms=3, color=colour[c], label=c if j == 0 else None)
        if left_out is not None and len(left_out) and xcol in left_out.columns:
            why = left_out["why"] if "why" in left_out.columns else pd.Series("", index=left_out.index)
            for w, d in left_out.groupby(why.fillna(""), sort=False):
                ax.plot(d[xcol], d[rcol], "x" if not w else "D", ms=5 if not w else 4, color="black",
                        mfc="none", label=(f"left out ({w or 'outlier'})") if j == 0 else None)
        if xcol != "time_s":
            shown = [frames[xcol]] + ([left_out[xcol]] if left_out is not None and xcol in left_out.columns else [])
            _value_ticks(ax, pd.concat(shown))  # a value whose readings were all left out keeps its tick
        ax.set_xlabel(_nice(xcol))
        ax.set_ylabel(label("position residual" if xcol == "time_s" else "residual", unit))
        if xcol == "time_s" and "run" in frames.columns:
            _label_run_ends(ax, runs, xcol, rcol)
        axes.append(ax)
    # below the figure, not on the axes: on a dense trajectory panel any corner sat on a frame's point
    handles, names = axes[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="outside lower center", ncol=min(len(handles), 6), fontsize=6)
    if title:
        axes[0].set_title(title)
    if drift is not None and len(drift):
        axd = fig.add_subplot(top[0, len(xcols)])
        runs = drift["run"].astype(str).to_list()
        # in the irregular class's colour, as the run's frames and its drift rate below
        axd.errorbar(range(len(runs)), drift[rcol].to_numpy(float), yerr=drift["sd"].to_numpy(float), fmt="D",
                     ms=4, mfc="none", color=colour.get("irregular", OKABE_ITO[1]), capsize=2)
        axd.axhline(0.0, color="0.6", lw=0.8)
        axd.set_xticks(range(len(runs)), runs, fontsize=6)
        axd.set_xlim(-0.6, len(runs) - 0.4)
        # about zero: a drift is read against no drift at all
        reach = float(np.nanmax(np.abs(drift[rcol].to_numpy(float)) + np.nan_to_num(drift["sd"].to_numpy(float))))
        if reach > 0 and np.isfinite(reach):
            axd.set_ylim(-1.35 * reach, 1.35 * reach)
        axd.set_xlabel("run (irregular)")
        axd.set_ylabel(label("drift residual over whole periods", unit))
        axd.set_title("irregular runs: drift ± SD")  # in the title: a legend sat on a run's bar
    if rows == 2:
        bottom = outer[1].subgridspec(1, len(run_cols))
        for j, xcol in enumerate(run_cols):
            ax = fig.add_subplot(bottom[0, j])
            ax.axhline(0.0, color="0.6", lw=0.8)
            for c in classes:
                m = (per_run["response_class"] == c).to_numpy()
                if m.any():
                    ax.errorbar(per_run.loc[m, xcol], per_run.loc[m, "rate_mm_s"], yerr=per_run.loc[m, "rate_se_mm_s"],
                                fmt="s", ms=4, capsize=2, color=colour[c], label=c)
            _value_ticks(ax, per_run[xcol])
            ax.set_xlabel(_nice(xcol) + " of the run")
            ax.set_ylabel(label("residual drift rate", "mm/s"))
            if j == 0:
                ax.set_title("per run: slope of the position residual over time (± 1 SE at the noise SD"
                             + (f", frame-to-frame correlation {rho:.2g})" if rho else ")"))
    return fig
