"""One figure style for the whole project, and atomic figure saving.

Sizes are for a journal column (3.5 in) or a full page width (7.2 in), fonts
readable at that size. Colours: a colour-blind-safe cycle (Okabe-Ito); fixed
roles for published reference points so every figure reads the same way.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # for any pyplot user in the process; the figures here need no pyplot (start-up)
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from ..tables import atomic_path  # noqa: E402

OKABE_ITO = ["#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#F0E442", "#000000"]

#: marker/colour roles of published values (reference tables' ``source_type``)
REFERENCE_STYLE = {
    "experiment": dict(marker="o", color="#000000", mfc="none", ms=6, ls="none"),
    "FE": dict(marker="^", color="#D55E00", ms=6, ls="none"),
    "analytic": dict(marker="s", color="#009E73", ms=5, ls="none"),
    "fit": dict(marker="D", color="#CC79A7", ms=5, ls="none"),
}

COLUMN_WIDTH_IN = 3.5
PAGE_WIDTH_IN = 7.2

RC = {
    "figure.figsize": (COLUMN_WIDTH_IN, 2.6),
    "figure.dpi": 150,
    "savefig.dpi": 300,
    "savefig.bbox": "tight",
    "font.size": 8,
    "axes.titlesize": 8,
    "axes.labelsize": 8,
    "legend.fontsize": 7,
    "xtick.labelsize": 7,
    "ytick.labelsize": 7,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.5,
    "lines.linewidth": 1.2,
    "lines.markersize": 4,
    "axes.prop_cycle": matplotlib.cycler(color=OKABE_ITO),
    "legend.frameon": False,
    "axes.spines.top": False,
    "axes.spines.right": False,
}


def use_style() -> None:
    """Apply the project's matplotlib style (idempotent)."""
    matplotlib.rcParams.update(RC)


def _new_figure(**kw) -> Figure:
    """Return a Figure drawn by Agg, without pyplot (no figure manager, no pyplot import: start-up time)."""
    fig = Figure(**kw)
    FigureCanvasAgg(fig)
    return fig


def figure(ncols: int = 1, nrows: int = 1, width: str = "column", height_in: float | None = None, **kw):
    """Return ``(fig, axes)`` sized for a column or a page; ``kw`` go to ``Figure.subplots`` (sharex, ...)."""
    use_style()
    w = COLUMN_WIDTH_IN if width == "column" else PAGE_WIDTH_IN
    h = height_in if height_in is not None else 2.6 * nrows
    fig = _new_figure(figsize=(w, h), constrained_layout=True)
    return fig, fig.subplots(nrows, ncols, **kw)


def blank_figure(width: str = "column", height_in: float = 2.6):
    """Return an empty figure sized for a column or a page (for custom grids of axes)."""
    use_style()
    w = COLUMN_WIDTH_IN if width == "column" else PAGE_WIDTH_IN
    return _new_figure(figsize=(w, height_in), layout="constrained")


def save_figure(fig, path: str | Path) -> Path:
    """Save ``fig`` atomically (format from the suffix: .png or .pdf)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or "png")
    return path


def label(name: str, unit: str) -> str:
    """Return an axis label 'name [unit]'."""
    return f"{name} [{unit}]" if unit else name
