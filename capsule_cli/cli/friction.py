"""``capsule-cli friction ...``: fit friction-speed laws, predict with model files, hoop grids, figures."""
from __future__ import annotations

import json
from enum import Enum
from pathlib import Path
from typing import Optional

import typer

from ..errors import InputError
from .common import QUIET, check_outputs, ensure_suffix

friction_app = typer.Typer(
    name="friction",
    help="Capsule-intestine friction: fit friction-speed laws (95 % intervals, band, residuals), "
         "predict with model files (Coulomb, hoop pressure eq 16, fitted laws), hoop-friction grids "
         "(seed 000 eqs 2-18). Speeds in mm/s, frictions in mN (hoop grids in N).",
    no_args_is_help=True,
)


class LawName(str, Enum):
    power = "power"
    power_fixed_n = "power_fixed_n"
    viscous = "viscous"
    stribeck = "stribeck"
    coulomb = "coulomb"


class WallMode(str, Enum):
    attenuated = "attenuated"
    original = "original"


def _is_synthetic(path: Path, df: pd.DataFrame) -> bool:
    prov = df.attrs.get("provenance") or {}
    if not prov and path.suffix.lower() == ".csv":
        side = path.with_name(path.name + ".provenance.json")
        if side.is_file():
            try:
                prov = json.loads(side.read_text())
            except (OSError, ValueError):
                prov = {}
    return bool(prov.get("synthetic")) or "synthetic" in path.name.lower()


@friction_app.command("fit")
def fit_cmd(
    data: Path = typer.Option(..., "--data", "-d", help="Friction table (CSV/Parquet): speed_mm_s (mm/s), "
                              "friction_mN (mN); optional case, trial, ..."),
    law: LawName = typer.Option(LawName.power, "--law", help="power: F = a V^n + b (n free); power_fixed_n: n = "
                                "--n-fixed; viscous: Fc + c V; stribeck: Fc + (Fs-Fc) exp(-(V/Vs)^2); "
                                "coulomb: constant. F in mN, V in mm/s."),
    n_fixed: float = typer.Option(0.25, "--n-fixed", help="Exponent n (-) of power_fixed_n (seed 000: 0.25)."),
    case: Optional[str] = typer.Option(None, "--case", help="Use only the rows of this case (column 'case')."),
    groups: Optional[str] = typer.Option(None, "--groups", help="Label column (e.g. trial) to summarise "
                                         "residuals per group."),
    seed: int = typer.Option(0, "--seed", min=0, help="Seed of the multi-start draws."),
    n_starts: int = typer.Option(6, "--n-starts", min=1, help="Starting points of the least-squares fit."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder: fit.json, band.parquet, "
                             "residuals.parquet, fit.png (written atomically)."),
    quiet: bool = QUIET,
):
    """Fit a friction-speed law: parameters with 95 % intervals, R², AIC/BIC, band, residuals, figure."""
    check_outputs(folder=out)  # before any work (exit 2 naming the path)
    from ..plots.friction import plot_fit
    from ..steps.friction import BAND_SCHEMA, RESIDUALS_SCHEMA, fit_friction_law
    from ..tables import provenance, read_measurements, staged_folder, write_json_atomic, write_table

    df, _ = read_measurements(data, kind="friction")
    if case is not None:
        if "case" not in df.columns:
            raise InputError(f"{data}: --case {case} given but the table has no 'case' column")
        df = df[df["case"].astype(str) == str(case)]
        if df.empty:
            raise InputError(f"{data}: no rows with case {case}")
    g = None
    if groups is not None:
        if groups not in df.columns:
            raise InputError(f"{data}: --groups column '{groups}' not in the table")
        g = df[groups].to_numpy()
    synthetic = _is_synthetic(Path(data), df)
    res = fit_friction_law(df["speed_mm_s"].to_numpy(), df["friction_mN"].to_numpy(), law=law.value,
                           n_fixed=n_fixed, groups=g, seed=seed, n_starts=n_starts)
    summary = res.summary()
    summary.update({"data": str(data), "case": case, "synthetic_data": synthetic,
                    "data_provenance": df.attrs.get("provenance") or {}})
    # a fit is not itself synthetic data; its lineage is recorded (data_synthetic)
    prov = provenance(seed=seed, synthetic=False, data_synthetic=synthetic, law=law.value, data=str(data))
    label = "synthetic data (not measurements)" if synthetic else "data"
    with staged_folder(out) as stage:  # the whole set or nothing (an interrupt while plotting leaves no table)
        write_table(res.band, stage / "band.parquet", BAND_SCHEMA, prov)
        write_table(res.residuals, stage / "residuals.parquet", RESIDUALS_SCHEMA, prov)
        plot_fit(res.residuals, res.band, summary, stage / "fit.png", data_label=label)
        write_json_atomic(stage / "fit.json", summary)
    if not quiet:
        typer.echo(f"{law.value}: " + ", ".join(
            f"{k} = {v['value']:.4g}" + ("" if v.get("fixed") else f" [{v['ci95'][0]:.4g}, {v['ci95'][1]:.4g}]")
            for k, v in summary["params"].items()) + f"; R² = {summary['r2']:.4f}; n = {summary['n']} -> {out}")


@friction_app.command("predict")
def predict_cmd(
    model: Path = typer.Option(..., "--model", "-m", help="Model file of kind friction (contract section 4)."),
    data: Optional[Path] = typer.Option(None, "--data", "-d", help="Friction table to predict at "
                                        "(speed_mm_s (mm/s), optional Ri_mm (mm), ...)."),
    speeds_mm_s: Optional[str] = typer.Option(None, "--speeds-mm-s", help="Speeds (mm/s): start:stop:num "
                                              "and/or a,b,c (instead of --data)."),
    Ri_mm: Optional[str] = typer.Option(None, "--Ri-mm", help="With --speeds-mm-s: intestine radii R_i (mm) "
                                        "crossed with the speeds (for hoop_pressure)."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Output table (.parquet or .csv), written "
                                       "atomically; without it the table is printed."),
    quiet: bool = QUIET,
):
    """Predict friction (mN) over speeds or a table with a friction model file."""
    check_outputs(file=out)  # before any work (exit 2 naming the path)
    from ..steps.friction import PREDICTION_SCHEMA, parse_grid, predict_friction
    from ..tables import provenance, read_measurements, write_table, write_text_atomic

    if (data is None) == (speeds_mm_s is None):
        raise InputError("give exactly one of --data or --speeds-mm-s")
    if data is not None and Ri_mm is not None:
        raise InputError("--Ri-mm goes with --speeds-mm-s; with --data the table's Ri_mm column is used")
    if out is not None:
        ensure_suffix(out, (".parquet", ".csv"), "--out")
    from ..validation import check_model_file_bounds

    check_model_file_bounds(model)
    if data is not None:
        table, _ = read_measurements(data, kind="friction")
        pred = predict_friction(model, table=table)
    else:
        v = parse_grid(speeds_mm_s, "--speeds-mm-s")
        if (v < 0).any():
            raise InputError(f"--speeds-mm-s: negative speed {v[v < 0][0]}")
        radii = parse_grid(Ri_mm, "--Ri-mm") if Ri_mm is not None else None
        pred = predict_friction(model, speeds_mm_s=v, Ri_mm=radii)
    if out is None:
        typer.echo(pred.to_csv(index=False).rstrip())
        return
    prov = provenance(config_hash=pred.attrs.get("model_hash"), model=str(model),
                      model_name=pred.attrs.get("model_name"))
    if out.suffix.lower() == ".csv":
        write_text_atomic(out, pred.to_csv(index=False))
    else:
        write_table(pred, out, PREDICTION_SCHEMA, prov)
    if not quiet:
        typer.echo(f"{len(pred)} predictions ({pred['friction_mN'].min():.4g}-{pred['friction_mN'].max():.4g} mN) "
                   f"-> {out}")


@friction_app.command("hoop")
def hoop_cmd(
    Ri_mm: str = typer.Option("4.4,4.8,5.0", "--Ri-mm", help="Intestine inner radii R_i (mm): start:stop:num "
                              "and/or a,b,c."),
    speeds_mm_s: str = typer.Option("0.4:12:30", "--speeds-mm-s", help="Capsule speeds (mm/s): start:stop:num "
                                    "and/or a,b,c."),
    wall_mode: WallMode = typer.Option(WallMode.attenuated, "--wall-mode", help="Wall thickness in the hoop "
                                       "pressure: attenuated t_i,e (seed 000 eq 6) or original t_i (seed 003)."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Output table (.parquet), written atomically; "
                                       "without it a summary is printed."),
    quiet: bool = QUIET,
):
    """Hoop-pressure friction components (N) over speed x R_i (seed 000 eqs 3-16, corrected)."""
    check_outputs(file=out)  # before any work (exit 2 naming the path)
    from ..steps.friction import HOOP_SCHEMA, hoop_table, parse_grid
    from ..tables import provenance, write_table

    radii = parse_grid(Ri_mm, "--Ri-mm")
    speeds = parse_grid(speeds_mm_s, "--speeds-mm-s")
    if (radii <= 0).any():
        raise InputError(f"--Ri-mm: radius must be positive, got {radii[radii <= 0][0]}")
    if (speeds < 0).any():
        raise InputError(f"--speeds-mm-s: negative speed {speeds[speeds < 0][0]}")
    if out is not None:
        ensure_suffix(out, (".parquet",), "--out")
    df = hoop_table(speeds, radii, wall_mode=wall_mode.value)
    if out is not None:
        write_table(df, out, HOOP_SCHEMA, provenance(wall_mode=wall_mode.value,
                                                     params="configs/params/capsule_intestine.yaml"))
    if out is None or not quiet:
        for r, sub in df.groupby("Ri_mm"):
            typer.echo(f"R_i = {r:g} mm: F_h = {sub['hoop_friction_N'].min():.3f}-{sub['hoop_friction_N'].max():.3f} N,"
                       f" F_c4 = {sub['total_friction_N'].min():.3f}-{sub['total_friction_N'].max():.3f} N over "
                       f"{sub['speed_mm_s'].min():g}-{sub['speed_mm_s'].max():g} mm/s")
        if out is not None:
            typer.echo(f"-> {out}")


@friction_app.command("plot-speed")
def plot_speed_cmd(
    reference: Path = typer.Option(..., "--reference", help="Published values (configs/reference/friction_seed000.csv)."),
    hoop: Path = typer.Option(..., "--hoop", help="Hoop grid from `friction hoop` (.parquet)."),
    coulomb: Path = typer.Option(..., "--coulomb", help="Coulomb prediction from `friction predict` (.parquet)."),
    case1_law: Path = typer.Option(..., "--case1-law", help="Eq 17 prediction from `friction predict` (.parquet)."),
    case4_law: Path = typer.Option(..., "--case4-law", help="Eq 18 prediction from `friction predict` (.parquet)."),
    fit: Optional[Path] = typer.Option(None, "--fit", help="Folder of a Case 1 `friction fit` (optional)."),
    Ri_mm: str = typer.Option("4.4,4.8", "--Ri-mm", help="Radii R_i (mm) of the hoop lines (in the hoop grid)."),
    out: Path = typer.Option(..., "--out", "-o", help="Figure (.png or .pdf), written atomically."),
    quiet: bool = QUIET,
):
    """Figure: friction vs speed, Case 1 and Case 4 (seed 000 Figs 9c and 13c)."""
    check_outputs(file=out)  # before any work (exit 2 naming the path)
    import numpy as np

    from ..plots.friction import plot_friction_vs_speed
    from ..steps.friction import parse_grid, read_friction_reference
    from ..tables import read_table

    ensure_suffix(out, (".png", ".pdf"), "--out")
    ref = read_friction_reference(reference)
    tabs = {k: read_table(p) for k, p in (("hoop", hoop), ("coulomb", coulomb), ("c1", case1_law), ("c4", case4_law))}
    radii = tuple(float(r) for r in parse_grid(Ri_mm, "--Ri-mm"))
    for r in radii:
        if not np.isclose(tabs["hoop"]["Ri_mm"], r).any():
            raise InputError(f"{hoop}: no rows for R_i = {r:g} mm (--Ri-mm)")
    band = points = summary = None
    label = "data"
    if fit is not None:
        band = read_table(fit / "band.parquet")
        points = read_table(fit / "residuals.parquet")
        try:
            summary = json.loads((fit / "fit.json").read_text())
        except (OSError, ValueError) as exc:
            raise InputError(f"{fit / 'fit.json'}: cannot be read ({exc})") from None
        if summary.get("synthetic_data"):
            prov = summary.get("data_provenance") or {}
            truth = (prov.get("true_model") or {}).get("name") or Path(str(prov.get("true_model_file", "model"))).stem
            noise = prov.get("noise_sd")
            label = f"synthetic data: {truth} + noise" + (f" (sd {noise:g} mN)" if isinstance(noise, (int, float)) else "")
    plot_friction_vs_speed(ref, tabs["hoop"], tabs["coulomb"], tabs["c1"], tabs["c4"], out, fit_band=band,
                           fit_points=points, fit_summary=summary, data_label=label, Ri_mm=radii)
    if not quiet:
        typer.echo(f"-> {out}")


@friction_app.command("plot-radius")
def plot_radius_cmd(
    hoop: Path = typer.Option(..., "--hoop", help="Hoop grid from `friction hoop` (.parquet) over R_i."),
    reference: Path = typer.Option(..., "--reference", help="Published values (configs/reference/friction_seed000.csv)."),
    speed_mm_s: float = typer.Option(4.0, "--speed-mm-s", help="Speed (mm/s) of the components panel "
                                     "(nearest grid speed)."),
    out: Path = typer.Option(..., "--out", "-o", help="Figure (.png or .pdf), written atomically."),
    quiet: bool = QUIET,
):
    """Figure: hoop-friction components vs intestine radius R_i (sensitivity to R_i)."""
    check_outputs(file=out)  # before any work (exit 2 naming the path)
    from ..plots.friction import plot_hoop_vs_radius
    from ..steps.friction import read_friction_reference
    from ..tables import read_table

    ensure_suffix(out, (".png", ".pdf"), "--out")
    ref = read_friction_reference(reference)
    df = read_table(hoop)
    if df["Ri_mm"].nunique() < 2:
        raise InputError(f"{hoop}: needs at least two radii R_i for a radius figure")
    plot_hoop_vs_radius(df, ref, out, speed_mm_s=speed_mm_s)
    if not quiet:
        typer.echo(f"-> {out}")


def register(app: typer.Typer) -> None:
    """Add the ``friction`` command group to ``app``."""
    app.add_typer(friction_app, name="friction")
