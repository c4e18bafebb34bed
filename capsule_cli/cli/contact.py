"""Commands of the contact stage: ``contact``, ``contact-plot``, ``contact-reference`` and ``relax fit``.

Thin layer: parse and validate options, call one step, write atomically, print a short summary.
"""
from __future__ import annotations

import math
from enum import Enum
from pathlib import Path

import typer

from ..errors import InputError
from .common import QUIET, check_outputs, ensure_suffix, out_option


class ModelChoice(str, Enum):
    hertz = "hertz"
    collapsed = "collapsed"
    hoop = "hoop"
    all = "all"


class Case2Geometry(str, Enum):
    conforming = "conforming"
    as_printed = "as_printed"


class PlotKind(str, Enum):
    speed = "speed"
    hoop_speed = "hoop-speed"
    profile = "profile"
    radius = "radius"
    end_shape = "end-shape"


def _speeds(speed_mm_s: str | None, speeds: str | None) -> list[float]:
    from ..steps.contact import parse_float_list, parse_range

    if speed_mm_s is not None and speeds is not None:
        raise InputError("give either --speed-mm-s or --speeds, not both")
    if speeds is not None:
        vals = parse_range(speeds, "--speeds")
    else:
        vals = parse_float_list(speed_mm_s or "0.5,1,2,4,6,8,10,12", "--speed-mm-s")
    bad = [v for v in vals if not (math.isfinite(v) and v >= 0)]
    if bad:
        raise InputError(f"--speed-mm-s: speeds must be finite and >= 0, got {bad[0]:g}")
    return vals


def _summary(df: pd.DataFrame) -> str:
    """A short text table: rows per model/statistic/R_i/end/wall, columns a few speeds."""
    import numpy as np
    import pandas as pd

    speeds = sorted(df["speed_mm_s"].unique())
    if len(speeds) > 6:
        idx = np.unique(np.linspace(0, len(speeds) - 1, 6).round().astype(int))
        speeds = [speeds[i] for i in idx]
    d = df[df["speed_mm_s"].isin(speeds)].copy()
    d["end_length_mm"] = d["end_length_mm"].map(lambda v: "" if not np.isfinite(v) else f"{v:g}")
    keys = ["model", "statistic", "Ri_mm", "end_length_mm", "wall_mode"]
    piv = d.pivot_table(index=keys, columns="speed_mm_s", values="pressure_kPa", aggfunc="first", sort=False)
    piv.columns = [f"{v:g} mm/s" for v in piv.columns]
    piv = piv.rename_axis(index={"Ri_mm": "Ri (mm)", "end_length_mm": "end (mm)", "wall_mode": "wall"})
    lines = ["contact pressure (kPa)", piv.to_string(float_format=lambda v: f"{v:.3f}")]
    hz = df[(df["model"] == "hertz") & (df["statistic"] == "avg")]
    for ri, a in hz.groupby("Ri_mm")["semi_width_mm"].first().items():
        lines.append(f"Hertz semi-width a = {a:.4f} mm (R_i = {ri:g} mm, load {hz['load_g'].iloc[0]:g} g)")
    return "\n".join(lines)


def register(app: typer.Typer) -> None:
    """Add ``contact``, ``contact-plot``, ``contact-reference`` and the ``relax`` group to ``app``."""

    @app.command("contact")
    def contact(
        model: ModelChoice = typer.Option(ModelChoice.all, "--model", "-m",
                                          help="hertz (Case 1, seed 003 eqs 2-5), collapsed (Case 2, eq 6 + wall "
                                               "weight), hoop (Case 3, eqs 8-14) or all."),
        speed_mm_s: str = typer.Option(None, "--speed-mm-s",
                                       help="Capsule speeds (mm/s), comma-separated (default 0.5,1,2,4,6,8,10,12)."),
        speeds: str = typer.Option(None, "--speeds", help="Speeds (mm/s) as start:stop:num (evenly spaced)."),
        Ri_mm: str = typer.Option(None, "--Ri-mm",
                                  help="Intestine inner radii (mm), comma-separated ('inf' = flat), used by every "
                                       "selected model. Default: each model's paper case (Case 1 flat, Case 2 "
                                       "13 mm, Case 3 5 mm; configs/params/contact_cases.yaml)."),
        Ri_range: str = typer.Option(None, "--Ri-range", help="Intestine inner radii (mm) as start:stop:num."),
        end_length_mm: str = typer.Option(None, "--end-length-mm",
                                          help="Hoop model: axial length (mm) of the semi-elliptical ends, "
                                               "comma-separated (default R_c = hemispherical; seed 001 section 6)."),
        wall_mode: str = typer.Option("attenuated", "--wall-mode",
                                      help="Hoop wall thickness: attenuated (t_i,e, seed 003 eq 9), original "
                                           "(t_i, reproduces seed 003's 11.87 kPa), or both comma-separated."),
        load_g: float = typer.Option(None, "--load-g",
                                     help="Capsule load (g) of the Hertz and collapsed models (default load_FE_g "
                                          "of the parameter set: 0.4 g, seed 003 section 4)."),
        case2_geometry: Case2Geometry = typer.Option(Case2Geometry.conforming, "--case2-geometry",
                                                     help="Lower contact of Case 2: conforming (capsule in a "
                                                          "trough) or as_printed (seed 003 eq 2 R_e)."),
        params: str = typer.Option("capsule_intestine", "--params",
                                   help="Parameter set: a name in configs/params/ or a YAML path (SI via unit "
                                        "suffixes, each value cited)."),
        out: Path = out_option(help="Output table (.parquet) of pressures (kPa) per model, statistic, speed, R_i."),
        profile_out: Path = typer.Option(None, "--profile-out",
                                         help="Also write the hoop pressure along the capsule (kPa vs mm) "
                                              "(.parquet)."),
        quiet: bool = QUIET,
    ):
        """Contact pressure of the capsule on the intestine over speeds, radii and end shapes.

        Defaults reproduce seed 003: Hertz a = 0.236 mm, P_avg 0.55 kPa, P_max 0.71 kPa
        (0.4 g); hoop 10.80 kPa at 4 mm/s and 10.92 kPa at 10 mm/s (R_i = 5 mm).
        """
        check_outputs(file=out, profile_out=profile_out)  # before any work (exit 2 naming the path)
        import numpy as np

        from ..steps import contact as step
        from ..tables import provenance, write_table
        from ..config import config_hash, load_param_set

        if out is None:
            raise InputError("--out is required (a .parquet file)")
        ensure_suffix(out, (".parquet",), "--out")
        if profile_out is not None:
            ensure_suffix(profile_out, (".parquet",), "--profile-out")
        v = np.asarray(_speeds(speed_mm_s, speeds)) * 1e-3
        if Ri_mm is not None and Ri_range is not None:
            raise InputError("give either --Ri-mm or --Ri-range, not both")
        radii = None
        if Ri_mm is not None:
            radii = step.parse_float_list(Ri_mm, "--Ri-mm")
        elif Ri_range is not None:
            radii = step.parse_range(Ri_range, "--Ri-range")
        if radii is not None and any(r <= 0 for r in radii):
            raise InputError("--Ri-mm: radii must be > 0")
        ends = None
        if end_length_mm is not None:
            ends = step.parse_float_list(end_length_mm, "--end-length-mm")
            if any(not (0 < e < math.inf) for e in ends):
                raise InputError("--end-length-mm: end lengths must be finite and > 0")
            ends = [e * 1e-3 for e in ends]
        modes = [m.strip() for m in wall_mode.split(",") if m.strip()]
        bad = [m for m in modes if m not in ("attenuated", "original")]
        if bad or not modes:
            raise InputError(f"--wall-mode: '{bad[0] if bad else wall_mode}' is not attenuated or original")
        if load_g is not None and not (math.isfinite(load_g) and load_g > 0):
            raise InputError("--load-g must be a positive number of grams")
        p = step.contact_params_from_config(params)
        models = step.MODELS if model == ModelChoice.all else (model.value,)
        load_N = None if load_g is None else load_g * 1e-3 * p["g_m_s2"]
        Ri_m = None if radii is None else [r * 1e-3 for r in radii]
        table = step.pressure_table(models, v, p, Ri_m=Ri_m, end_lengths_m=ends, wall_modes=modes, load_N=load_N,
                                    case2_conforming=case2_geometry == Case2Geometry.conforming)
        profile = None
        if profile_out is not None:
            if "hoop" not in models:
                raise InputError("--profile-out needs the hoop model (--model hoop or all)")
            ri_hoop = Ri_m if Ri_m is not None else [step.case_radii_from_config()["case3"]]
            profile = step.hoop_profile_table(v, p, ri_hoop, ends, modes)
        prov = provenance(config_hash=config_hash(load_param_set(params)), params=str(params),
                          models=list(models), case2_geometry=case2_geometry.value,
                          sources="seed 003 eqs 2-14; seed 000 eqs 3-9; seed 001 section 6")
        write_table(table, out, step.PRESSURE_SCHEMA, prov)
        if profile is not None:
            write_table(profile, profile_out, step.PROFILE_SCHEMA, prov)
        typer.echo(_summary(table))

    @app.command("contact-reference")
    def contact_reference(
        reference: Path = typer.Option(None, "--reference",
                                       help="Reference CSV (default configs/reference/contact_pressure.csv)."),
        out: Path = out_option(help="Output table (.parquet) of published pressures (kPa) with citations."),
        quiet: bool = QUIET,
    ):
        """Render the published contact pressures (with a citation per row) to a Parquet table."""
        check_outputs(file=out)  # before any work (exit 2 naming the path)
        from ..steps import contact as step
        from ..tables import provenance, write_table

        if out is None:
            raise InputError("--out is required (a .parquet file)")
        ensure_suffix(out, (".parquet",), "--out")
        ref = step.load_reference_table(reference)
        src = str(reference) if reference is not None else str(step.reference_path())
        write_table(ref, out, step.REFERENCE_SCHEMA, provenance(reference_csv=src))
        typer.echo(f"{len(ref)} published values ({', '.join(sorted(ref['source_type'].unique()))}) -> {out}")

    @app.command("contact-plot")
    def contact_plot(
        kind: PlotKind = typer.Argument(..., help="speed (Cases 1-3 vs speed), hoop-speed (hoop pressure vs speed "
                                                  "per R_i), profile (hoop pressure along the "
                                                  "capsule), radius (hoop pressure vs R_i), end-shape."),
        table: Path = typer.Option(..., "--table", help="Table written by 'capsule-cli contact' (.parquet): the "
                                                        "pressure table, or the profile table for 'profile'."),
        reference: Path = typer.Option(None, "--reference", help="Reference table (.parquet from contact-reference "
                                                                 "or the .csv) to overlay published values."),
        by: str = typer.Option("speed_mm_s", "--by", help="profile: one line per speed_mm_s or end_length_mm."),
        out: Path = out_option(help="Figure file (.png or .pdf)."),
        quiet: bool = QUIET,
    ):
        """Draw a contact-stage figure from tables (no physics is recomputed)."""
        check_outputs(file=out)  # before any work (exit 2 naming the path)
        from ..plots import contact as plots
        from ..steps import contact as step
        from ..tables import read_table

        if out is None:
            raise InputError("--out is required (.png or .pdf)")
        ensure_suffix(out, (".png", ".pdf"), "--out")
        df = read_table(table)
        ref = None
        if reference is not None:
            ref = step.load_reference_table(reference) if reference.suffix.lower() == ".csv" else read_table(reference)
        need = {"profile": {"x_body_mm", "pressure_kPa"}}.get(kind.value, {"model", "statistic", "pressure_kPa"})
        if not need <= set(df.columns):
            raise InputError(f"{table}: not a {'hoop_profile' if kind == PlotKind.profile else 'contact_pressure'} "
                             f"table (missing {sorted(need - set(df.columns))[0]})")
        if kind == PlotKind.speed:
            plots.plot_pressure_vs_speed(df, ref, out)
        elif kind == PlotKind.hoop_speed:
            plots.plot_hoop_vs_speed(df, out)
        elif kind == PlotKind.profile:
            if by not in ("speed_mm_s", "end_length_mm"):
                raise InputError("--by must be speed_mm_s or end_length_mm")
            plots.plot_hoop_profile(df, out, by=by)
        elif kind == PlotKind.radius:
            plots.plot_pressure_vs_radius(df, ref, out)
        else:
            plots.plot_end_shape(df, ref, out)

    relax = typer.Typer(help="Viscoelastic relaxation of the intestinal wall (Prony series, seed 004 eq 1).",
                        no_args_is_help=True)
    app.add_typer(relax, name="relax")

    @relax.command("fit")
    def relax_fit(
        data: Path = typer.Option(..., "--data", help="Relaxation record (.csv or .parquet): time_s, pressure_kPa "
                                                      "(optional trial; contract section 3)."),
        max_arms: int = typer.Option(3, "--max-arms", min=1, max=4, help="Largest number of Maxwell arms tried."),
        factor: float = typer.Option(None, "--factor", help="Geometric factor t_i,e·ε/R_c (-) to report moduli "
                                                            "E_j, E_inf (kPa) and η_j (MPa·s)."),
        Ri_mm: float = typer.Option(None, "--Ri-mm", help="Compute the factor for this intestine radius (mm) "
                                                          "from --params (attenuated wall)."),
        params: str = typer.Option("capsule_intestine", "--params", help="Parameter set for --Ri-mm."),
        seed: int = typer.Option(0, "--seed", min=0, help="Random seed of the multi-start fits."),
        out: Path = out_option(help="Output folder: fit.json, curve.parquet, residuals.parquet, relax_fit.png."),
        quiet: bool = QUIET,
    ):
        """Fit a Prony series (1..n arms) to a relaxation record; choose the order by held-out error.

        Writes parameters with 95 % intervals, R², the CV table and the chosen order
        (fit.json), the fitted curves with 95 % bands (curve.parquet), residuals and a figure.
        """
        check_outputs(folder=out)  # before any work (exit 2 naming the path)
        import numpy as np
        import pandas as pd

        from ..models.contact import relaxation_pressure_factor
        from ..plots.contact import plot_relax_fit
        from ..steps import contact as cstep
        from ..steps.relax import fit_prony
        from ..tables import (Column, TableSchema, provenance, read_measurements,
                              staged_folder, write_json_atomic, write_table)

        if out is None:
            raise InputError("--out is required (a folder)")
        if out.exists() and not out.is_dir():
            raise InputError(f"{out}: --out must be a folder")
        if factor is not None and Ri_mm is not None:
            raise InputError("give either --factor or --Ri-mm, not both")
        if factor is not None and not (math.isfinite(factor) and factor > 0):
            raise InputError("--factor must be a positive number")
        df, _ = read_measurements(data, kind="relaxation")
        if Ri_mm is not None:
            p = cstep.contact_params_from_config(params)
            if not 0 < Ri_mm * 1e-3 < p["Rc_m"]:
                raise InputError(f"--Ri-mm must lie in (0, R_c = {p['Rc_m'] * 1e3:g} mm) for a hoop contact")
            factor = float(relaxation_pressure_factor(Ri_mm * 1e-3, p["Rc_m"], p["wall_m"]))
        groups = df["trial"].to_numpy() if "trial" in df.columns else None
        t = df["time_s"].to_numpy(float)
        y = df["pressure_kPa"].to_numpy(float) * 1e3
        fit = fit_prony(t, y, max_arms=max_arms, groups=groups, seed=seed, factor=factor)

        grid = np.linspace(0.0, float(t.max()), 400)
        curves = []
        for m in fit.orders:
            c, lo, hi = fit.band_Pa(grid, m)
            curves.append(pd.DataFrame({"n_arms": m, "chosen": m == fit.chosen, "time_s": grid,
                                        "pressure_kPa": c / 1e3, "lower_kPa": lo / 1e3, "upper_kPa": hi / 1e3}))
        curve = pd.concat(curves, ignore_index=True)
        res = pd.DataFrame({"time_s": t, "pressure_kPa": y / 1e3, "fitted_kPa": fit.predict_Pa(t) / 1e3})
        res["residual_kPa"] = res["pressure_kPa"] - res["fitted_kPa"]
        if groups is not None:
            res.insert(0, "trial", pd.Series(groups).astype(str).to_numpy())
        curve_schema = TableSchema("relax_curve", "fitted Prony series per number of arms with the 95 % band of "
                                   "the mean curve (delta method)", (
            Column("n_arms", "int64", "number of Maxwell arms", unit=""),
            Column("chosen", "bool", "the order chosen by held-out error", unit=""),
            Column("time_s", "float64", "time since the step"),
            Column("pressure_kPa", "float64", "fitted contact pressure"),
            Column("lower_kPa", "float64", "lower 95 % bound of the mean curve"),
            Column("upper_kPa", "float64", "upper 95 % bound of the mean curve")))
        res_schema = TableSchema("relax_residuals", "relaxation record with the chosen fit and residuals", (
            Column("trial", "string", "trial label", unit="", required=False),
            Column("time_s", "float64", "time since the step"),
            Column("pressure_kPa", "float64", "measured contact pressure"),
            Column("fitted_kPa", "float64", "fitted contact pressure (chosen order)"),
            Column("residual_kPa", "float64", "measured minus fitted")))
        src_prov = df.attrs.get("provenance") or {}
        prov = provenance(seed=seed, synthetic=bool(src_prov.get("synthetic", False)), data=str(data),
                          chosen_n_arms=fit.chosen)
        record = fit.as_dict()
        record["data"] = str(data)
        with staged_folder(out) as stage:  # the whole set or nothing (an interrupt while plotting leaves no table)
            write_table(curve, stage / "curve.parquet", curve_schema, prov)
            write_table(res, stage / "residuals.parquet", res_schema, prov)
            plot_relax_fit(res, curve, stage / "relax_fit.png", fit.chosen)
            write_json_atomic(stage / "fit.json", record)
        pr = fit.parameters()
        lines = [f"chosen: {fit.chosen} arm(s) ({fit.cv_scheme}); R² = {fit.best.fit.r2:.4f}",
                 f"P_inf = {pr['P_inf_kPa']['value']:.4g} kPa [{pr['P_inf_kPa']['ci95'][0]:.4g}, "
                 f"{pr['P_inf_kPa']['ci95'][1]:.4g}]"]
        for arm in pr["arms"]:
            s = (f"arm {arm['arm']}: A = {arm['A_kPa']['value']:.4g} kPa [{arm['A_kPa']['ci95'][0]:.4g}, "
                 f"{arm['A_kPa']['ci95'][1]:.4g}], tau = {arm['tau_s']['value']:.4g} s "
                 f"[{arm['tau_s']['ci95'][0]:.4g}, {arm['tau_s']['ci95'][1]:.4g}]")
            if "E_kPa" in arm:
                s += f", E = {arm['E_kPa']['value']:.4g} kPa, eta = {arm['eta_MPa_s']['value']:.4g} MPa·s"
            lines.append(s)
        typer.echo("\n".join(lines))
