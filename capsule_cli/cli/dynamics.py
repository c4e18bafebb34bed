"""Commands of the dynamics stage: simulate, sweep, magnify, bench, dynamics-report."""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import List, Optional

import typer

from ..errors import InputError
from .common import QUIET, check_outputs

FRICTION_HELP = ("shell friction (seed 000 eqs 21-23): coulomb (level --Pf-N), eq22 / eq23 (well-posed "
                 "speed laws, add --literal for the law as written), fixed (P_f = inf)")


def _parse_set(items: list[str] | None) -> dict[str, float]:
    out = {}
    for it in items or []:
        if "=" not in it:
            raise InputError(f"--set '{it}': expected NAME=VALUE (e.g. gap_mm=1.5)")
        k, v = it.split("=", 1)
        try:
            out[k.strip()] = float(v)
        except ValueError:
            raise InputError(f"--set '{it}': value is not a number") from None
    return out


def _load_plugins(plugins) -> None:
    from ..effects.registry import load_plugins

    load_plugins(plugins or [])


def _setup(model, set_, waveform, f_Hz, Pd_N, duty, friction, Pf_N, literal, v_min_mm_s, speed_unit="mm/s",
           static_N=None):
    from ..dynamics.model import Drive
    from ..steps.dynamics import make_friction, resolve_model

    from ..validation import check_model_file_bounds

    overrides = _parse_set(set_)
    check_model_file_bounds(model, overrides)  # the file's bounds hold here as in compare
    m, pf_set = resolve_model(model, overrides)
    if friction == "coulomb" and Pf_N is None:
        Pf_N = pf_set
    fr = make_friction(friction, Pf_N, literal=literal, v_min_mm_s=v_min_mm_s, speed_unit=speed_unit,
                       static_N=static_N)
    d = Drive(amplitude_N=Pd_N, frequency_Hz=f_Hz, waveform=waveform, duty=duty).validate()
    return m, d, fr


def _parse_state(text: str) -> list[float]:
    """'x_r_mm,v_r_mm_s,V_c_mm_s' -> [x_r, v_r, V_c] in SI (m, m/s, m/s)."""
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError:
        raise InputError(f"--initial-state '{text}': expected three numbers x_r_mm,v_r_mm_s,V_c_mm_s") from None
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise InputError(f"--initial-state '{text}': expected three finite numbers x_r_mm,v_r_mm_s,V_c_mm_s")
    return [v * 1e-3 for v in vals]


MODEL_OPT = typer.Option("prototype_one_sided", "--model", help="parameter set in configs/params (name) or a YAML "
                         "path with model-file names (mass_magnet_g, gap_mm, spring_N_m, ...)")
SET_OPT = typer.Option(None, "--set", help="override a model parameter, NAME=VALUE in the unit of its suffix "
                       "(e.g. gap_back_mm=0.2); repeatable")
WAVE_OPT = typer.Option("harmonic", "--waveform", help="harmonic P_d cos(2 pi f t) or square (P_d for a duty fraction)")
DUTY_OPT = typer.Option(0.5, "--duty", help="square-wave duty cycle D in (0, 1) [-]")
FRIC_OPT = typer.Option("coulomb", "--friction", help=FRICTION_HELP)
PF_OPT = typer.Option(None, "--Pf-N", help="Coulomb friction level P_f [N] (default: the parameter set's Pf_N)")
SETTLE_OPT = typer.Option(None, "--settle-tol", help="end each point's transient early, by whole orbits, once its "
                          "state at phase 0 repeats after 1-8 periods within this fraction of the state scales [-] "
                          "(0: run every transient period; default 1e-12, the steady-state runs' STEADY_SETTLE_TOL; a speed "
                          "law uses at least 0.01 x its rk_rtol, the adaptive path's accuracy)")


def _settle_tol(value):
    """The settled-transient tolerance of a sweep or map: the option, else STEADY_SETTLE_TOL."""
    from ..dynamics.model import STEADY_SETTLE_TOL

    v = STEADY_SETTLE_TOL if value is None else float(value)
    if not (math.isfinite(v) and 0.0 <= v <= 1e-6):
        raise InputError(f"--settle-tol {v:g}: expected 0 (off) or a tolerance up to 1e-6")
    return v


LIT_OPT = typer.Option(False, "--literal", help="eq22/eq23 exactly as written (eq22 is ill-posed: the run stops "
                       "with a clear error)")
STATIC_OPT = typer.Option(None, "--static-N", help="Coulomb breakaway (static) level [N] when it differs from the "
                          "kinetic --Pf-N (held at least at --Pf-N unless --literal)")
UNIT_OPT = typer.Option("mm/s", "--law-speed-unit", help="unit V is taken in by the eq22/eq23 laws: mm/s (as "
                        "fitted, physics.md) or m/s (sensitivity case: the law fed SI speeds, docs/dynamics.md)")
PLUGINS_OPT = typer.Option(None, "--plugins", help="Python file(s) registering effects a --model file lists "
                           "(drive transforms, plugin forces: capsule_cli.dynamics.plugin_force); repeatable")
VMIN_OPT = typer.Option(None, "--v-min-mm-s", help="speed [mm/s] below which the speed law is held (default 0.2)")


def register(app: typer.Typer) -> None:
    """Add this stage's commands to app."""

    @app.command("simulate")
    def simulate_cmd(
        out: Path = typer.Option(..., "--out", "-o", help="output folder: trajectory.parquet, events.parquet, "
                                 "periods.parquet, summary.json (written atomically)"),
        f_Hz: float = typer.Option(30.0, "--f-Hz", help="drive frequency f [Hz]"),
        Pd_N: float = typer.Option(0.15, "--Pd-N", help="drive amplitude P_d [N]"),
        model: str = MODEL_OPT, set_: Optional[List[str]] = SET_OPT, waveform: str = WAVE_OPT,
        duty: float = DUTY_OPT, friction: str = FRIC_OPT, Pf_N: Optional[float] = PF_OPT,
        literal: bool = LIT_OPT, v_min_mm_s: Optional[float] = VMIN_OPT, law_speed_unit: str = UNIT_OPT,
        static_N: Optional[float] = STATIC_OPT, plugins: Optional[List[Path]] = PLUGINS_OPT,
        periods: int = typer.Option(50, "--periods", help="recorded drive periods [-]"),
        transient_periods: int = typer.Option(0, "--transient-periods", help="periods run first, not recorded [-]"),
        sample_rate_Hz: float = typer.Option(5000.0, "--sample-rate-Hz", help="trajectory sampling rate [Hz] "
                                             "(0: no trajectory)"),
        figure: Optional[Path] = typer.Option(None, "--figure", help="also draw the run to this PNG/PDF: "
                                              "positions, velocities and contact force against time with the "
                                              "events marked, and the phase portrait x_r, v_r"),
        figure_periods: float = typer.Option(5.0, "--figure-periods", help="drive periods drawn by --figure, "
                                             "the last ones of the run [-]"),
        quiet: bool = QUIET,
    ):
        """One vibro-impact run (seed 000 eqs 19-23): trajectory, exact events, per-period table, energy balance."""
        check_outputs(folder=out)  # before any work (exit 2 naming the path)
        from ..progress import compile_notice
        from ..steps.dynamics import simulate_to_dir

        _load_plugins(plugins)
        m, d, fr = _setup(model, set_, waveform, f_Hz, Pd_N, duty, friction, Pf_N, literal, v_min_mm_s,
                          law_speed_unit, static_N)
        if figure is not None:
            from .common import ensure_suffix
            ensure_suffix(figure, (".png", ".pdf"), "--figure")
            if sample_rate_Hz <= 0:
                raise InputError("--figure needs a trajectory: --sample-rate-Hz > 0")
        compile_notice(quiet, ("run_core",))
        s = simulate_to_dir(out, m, d, fr, periods, transient_periods, sample_rate_Hz, model_name=model)
        if figure is not None:
            from ..plots.dynamics import simulation_figure
            from ..steps.dynamics import case_name
            from ..tables import read_table

            from dataclasses import asdict
            simulation_figure(read_table(out / "trajectory.parquet"), read_table(out / "events.parquet"), figure,
                              title=f"{model}: {d.waveform} drive $P_d$ = {Pd_N * 1e3:g} mN at {f_Hz:g} Hz, "
                                    f"{case_name(asdict(fr))} (simulated; last {figure_periods:g} periods)",
                              gap_mm=m.gap_m * 1e3, gap_back_mm=m.gap_back_m * 1e3 if m.double_sided else None,
                              last_periods=figure_periods, period_s=1.0 / f_Hz)
        if not quiet:
            typer.echo(f"{out}: v = {s['average_velocity_mm_s']:.6g} mm/s, {s['impacts_per_period']} impacts/period, "
                       f"A_f = {s['Af']:.4g}, energy residual {s['energy_balance']['relative_residual']:.1e}",
                       err=True)

    @app.command("sweep")
    def sweep_cmd(
        out: Path = typer.Option(..., "--out", "-o", help="output folder: points.parquet (one row per point), "
                                 "sweep.parquet (Poincare rows per recorded period), sweep.json"),
        param: str = typer.Option("f_Hz", "--param", help="swept parameter: f_Hz, Pd_N, Pf_N, duty or a model "
                                  "parameter (gap_mm, spring_N_m, ...); unit from its suffix"),
        start: float = typer.Option(..., "--start", help="first value, in the unit of --param's suffix (Hz for f_Hz, N for Pd_N and Pf_N, "
                             "mm for gap_mm; dimensionless for duty)"),
        stop: float = typer.Option(..., "--stop", help="last value, in the unit of --param's suffix (Hz for f_Hz, N for Pd_N and Pf_N, "
                            "mm for gap_mm; dimensionless for duty)"),
        num: int = typer.Option(50, "--num", help="number of points [-]"),
        protocol: str = typer.Option("rest", "--protocol", help="rest (every point from rest, parallel), up / down "
                                     "(continuation from the previous end state)"),
        f_Hz: float = typer.Option(30.0, "--f-Hz", help="drive frequency f [Hz] (when not swept)"),
        Pd_N: float = typer.Option(0.15, "--Pd-N", help="drive amplitude P_d [N] (when not swept)"),
        model: str = MODEL_OPT, set_: Optional[List[str]] = SET_OPT, waveform: str = WAVE_OPT,
        duty: float = DUTY_OPT, friction: str = FRIC_OPT, Pf_N: Optional[float] = PF_OPT,
        literal: bool = LIT_OPT, v_min_mm_s: Optional[float] = VMIN_OPT, law_speed_unit: str = UNIT_OPT,
        static_N: Optional[float] = STATIC_OPT, plugins: Optional[List[Path]] = PLUGINS_OPT,
        transient_periods: int = typer.Option(300, "--transient-periods", help="periods discarded per point [-]"),
        periods: int = typer.Option(50, "--periods", help="periods recorded per point [-]"),
        label: str = typer.Option("", "--label", help="name of the sweep (stored in the provenance)"),
        initial_state: str = typer.Option("0,0,0", "--initial-state", help="fixed initial condition at phase 0: "
                                          "x_r [mm], v_r [mm/s], V_c [mm/s], comma-separated (every point for "
                                          "rest, the first point for up/down)"),
        settle_tol: Optional[float] = SETTLE_OPT,
        quiet: bool = QUIET,
    ):
        """Bifurcation / progression sweep over one parameter (Poincare points, velocity, impacts, A_f)."""
        check_outputs(folder=out)  # before any work (exit 2 naming the path)
        import numpy as np

        from ..progress import compile_notice, exit_on_interrupt, task
        from ..steps.dynamics import sweep_to_dir

        if num < 1:
            raise InputError("--num must be >= 1")
        _load_plugins(plugins)
        m, d, fr = _setup(model, set_, waveform, f_Hz, Pd_N, duty, friction, Pf_N, literal, v_min_mm_s,
                          law_speed_unit, static_N)
        state0 = _parse_state(initial_state)
        settle_tol = _settle_tol(settle_tol)
        values = np.linspace(start, stop, num)
        compile_notice(quiet, ("run_many",))
        with exit_on_interrupt(), task(f"sweep {param}", num, quiet) as advance:
            meta = sweep_to_dir(out, m, d, fr, param, values, protocol, transient_periods, periods,
                                model_name=model, label=label, progress=advance, state0=state0,
                                settle_tol=settle_tol)
        if not quiet:
            typer.echo(f"{out}: {meta['n_points']} points ({protocol})", err=True)

    @app.command("magnify")
    def magnify_cmd(
        out: Path = typer.Option(..., "--out", "-o", help="output Parquet file of A_f over (friction, P_d, f)"),
        Pd_start_N: float = typer.Option(0.01, "--Pd-start-N", help="first amplitude [N]"),
        Pd_stop_N: float = typer.Option(0.5, "--Pd-stop-N", help="last amplitude [N]"),
        Pd_num: int = typer.Option(20, "--Pd-num", help="number of amplitudes [-]"),
        f_start_Hz: float = typer.Option(5.0, "--f-start-Hz", help="first frequency [Hz]"),
        f_stop_Hz: float = typer.Option(40.0, "--f-stop-Hz", help="last frequency [Hz]"),
        f_num: int = typer.Option(36, "--f-num", help="number of frequencies [-]"),
        Pf_N: Optional[List[float]] = typer.Option(None, "--Pf-N", help="Coulomb level(s) [N]; 'inf' = shell fixed; "
                                                   "repeatable (default: the model's Pf_N when no --law / --fig19)"),
        law: Optional[List[str]] = typer.Option(None, "--law", help="speed-law friction eq22 or eq23 (seed 000, "
                                                "well-posed form); repeatable"),
        fig19: bool = typer.Option(False, "--fig19", help="the eight frictions of seed 000 Fig 19 "
                                   "(configs/bench/fig19.yaml: 0.007, 0.17, 2.5, 4.5, 10 N, inf, eq22, eq23)"),
        protocol: str = typer.Option("rest", "--protocol", help="rest, or up/down continuation in f"),
        model: str = MODEL_OPT, set_: Optional[List[str]] = SET_OPT, plugins: Optional[List[Path]] = PLUGINS_OPT,
        transient_periods: int = typer.Option(200, "--transient-periods", help="periods discarded per point "
                                              "(steady state only is recorded) [-]"),
        periods: int = typer.Option(30, "--periods", help="periods recorded per point [-]"),
        Pd_rows: Optional[str] = typer.Option(None, "--Pd-rows", help="compute only amplitudes START:STOP "
                                              "(0-based indices into the P_d grid, STOP excluded): one chunk of a "
                                              "split map, joined with --gather"),
        gather: Optional[List[Path]] = typer.Option(None, "--gather", help="join these chunk tables (split along "
                                                    "P_d) into --out instead of computing; repeatable"),
        figure: Optional[Path] = typer.Option(None, "--figure", help="also draw the maps to this PNG/PDF"),
        scale: str = typer.Option("shared", "--scale", help="colour scale of the figure: shared (all panels) or "
                                  "panel (one per panel)"),
        rk_rtol: Optional[float] = typer.Option(None, "--rk-rtol", help="relative tolerance of the speed-law "
                                                "(eq22/eq23) panels' adaptive integration [-] (default: rk_rtol of "
                                                "configs/bench/fig19.yaml; Coulomb panels are exact)"),
        settle_tol: Optional[float] = SETTLE_OPT,
        quiet: bool = QUIET,
    ):
        """Magnification factor maps A_f = max|F_i|/P_d over (P_d, f) (seed 000 eq 24, Fig 19)."""
        check_outputs(file=out)  # before any work (exit 2 naming the path)
        import numpy as np

        from ..progress import compile_notice, exit_on_interrupt, task
        from ..steps.dynamics import (MAGNIFY, gather_magnify_files, load_fig19, magnify_table, map_rk_rtol,
                                      resolve_model)
        from ..tables import provenance, write_table

        if scale not in ("shared", "panel"):
            raise InputError(f"--scale '{scale}': expected shared or panel")
        if gather:
            if Pd_rows is not None:
                raise InputError("--gather joins chunks: do not give --Pd-rows with it")
            order = ([str(x) for x in load_fig19()["frictions"]] if fig19 else []) + \
                [str(x) for x in (Pf_N or [])] + list(law or [])
            df, prov = gather_magnify_files(gather, order)
        else:
            frictions: list = []
            if fig19:
                frictions += list(load_fig19()["frictions"])
            frictions += [str(x) for x in (Pf_N or [])] + list(law or [])
            _load_plugins(plugins)  # before the model: a model file may list a plugin's effect
            m, pf_set = resolve_model(model, _parse_set(set_))
            if not frictions:
                # the model's own P_f, as simulate and sweep take it (Fig 19's lowest level without one)
                frictions = [str(pf_set if pf_set is not None else load_fig19()["frictions"][0])]
            if Pd_num < 1 or f_num < 1:
                raise InputError("--Pd-num and --f-num must be >= 1")
            if rk_rtol is None:
                rk_rtol = map_rk_rtol()
            if not (math.isfinite(rk_rtol) and 1e-14 <= rk_rtol <= 1e-4):
                raise InputError(f"--rk-rtol {rk_rtol:g}: expected a tolerance in [1e-14, 1e-4]")
            settle_tol = _settle_tol(settle_tol)
            Pd = np.linspace(Pd_start_N, Pd_stop_N, Pd_num)
            f = np.linspace(f_start_Hz, f_stop_Hz, f_num)
            rows = None
            if Pd_rows is not None:
                try:
                    a, b = (int(x) for x in Pd_rows.split(":"))
                except ValueError:
                    raise InputError(f"--Pd-rows '{Pd_rows}': expected START:STOP (integers)") from None
                if not 0 <= a < b <= Pd_num:
                    raise InputError(f"--Pd-rows '{Pd_rows}': need 0 <= START < STOP <= --Pd-num ({Pd_num})")
                rows = [a, b]
                Pd = Pd[a:b]
            compile_notice(quiet)
            with exit_on_interrupt(), task("magnify", len(frictions) * Pd.size * f.size, quiet) as advance:
                df = magnify_table(m, Pd, f, frictions, protocol, transient_periods, periods, progress=advance,
                                   rk_rtol=rk_rtol, settle_tol=settle_tol)
            prov = provenance(model_name=model, protocol=protocol, transient_periods=transient_periods,
                              periods=periods, frictions=[str(x) for x in frictions],
                              Pd_grid_N=[Pd_start_N, Pd_stop_N, Pd_num], f_grid_Hz=[f_start_Hz, f_stop_Hz, f_num],
                              Pd_rows=rows, rk_rtol=rk_rtol, settle_tol=settle_tol)
        write_table(df, out, MAGNIFY, prov)
        if figure is not None:
            from ..plots.dynamics import magnify_figure

            magnify_figure(df, "Magnification factor $A_f$ (seed 000 Fig 19)", figure, scale=scale)
        if not quiet:
            peaks = df.groupby("friction", sort=False)["Af"].max()
            typer.echo(f"{out}: max A_f " + ", ".join(f"{k}: {v:.4g}" for k, v in peaks.items()), err=True)

    @app.command("bench")
    def bench_cmd(
        json_out: bool = typer.Option(False, "--json", help="print the record as one JSON object on stdout"),
        out: Optional[Path] = typer.Option(None, "--out", "-o", help="also write the JSON record to this file"),
        engine_periods: int = typer.Option(5000, "--engine-periods", help="periods of the engine's long-run "
                                            "throughput per frequency [-]"),
        baseline_periods: int = typer.Option(60, "--baseline-periods", help="periods from rest per frequency of the "
                                              "timed runs, the same for solve_ivp and the engine [-]"),
        fig19: bool = typer.Option(False, "--fig19", help="time the seed 000 Fig 19 set instead (configs/bench/"
                                   "fig19.yaml: 8 frictions, 100 x 100, 200 + 30 periods from rest)"),
        Pd_num: Optional[int] = typer.Option(None, "--Pd-num", help="with --fig19: amplitudes actually run (a "
                                             "subset of the grid; the wall time is also extrapolated) [-]"),
        f_num: Optional[int] = typer.Option(None, "--f-num", help="with --fig19: frequencies actually run [-]"),
        startup: bool = typer.Option(False, "--startup", help="time start-up instead: `capsule-cli --help` and a "
                                     "warm 20-period simulate, fresh processes"),
        quiet: bool = QUIET,
    ):
        """Benchmark (contract section 6): the engine against scipy solve_ivp with events, same runs."""
        check_outputs(file=out)  # before any work (exit 2 naming the path)
        from .. import progress as PR
        from ..dynamics import bench as B
        from ..tables import _jsonable, write_json_atomic

        if startup:
            rec = B.run_startup_bench()
        elif fig19:
            if (Pd_num is not None and Pd_num < 1) or (f_num is not None and f_num < 1):
                raise InputError("--Pd-num and --f-num must be >= 1")
            PR.compile_notice(quiet, ("run_many", "run_core"))
            cfg_n = (Pd_num or 100) * (f_num or 100) * 8
            with PR.task("bench --fig19", cfg_n, quiet) as advance:
                rec = B.run_fig19_bench(Pd_num=Pd_num, f_num=f_num, progress=advance)
        else:
            PR.compile_notice(quiet, ("run_core",))
            rec = B.run_bench(engine_periods=engine_periods, baseline_periods=baseline_periods)
        if out is not None:
            write_json_atomic(out, rec)
        if json_out:
            typer.echo(json.dumps(_jsonable(rec)))
        elif not quiet and (startup or fig19):
            typer.echo(json.dumps(_jsonable(rec), indent=1), err=True)
        elif not quiet:
            typer.echo(f"engine {rec['periods_per_s']:.4g} periods/s, baseline ({rec['baseline_method']}) "
                       f"{rec['baseline_periods_per_s']:.4g} periods/s, speedup {rec['speedup']:.0f} "
                       f"(impacting runs {rec['impacting_speedup']:.0f}); max event-time error "
                       f"{rec['max_event_time_error_s']:.2e} s")

    @app.command("dynamics-report")
    def report_cmd(
        out: Path = typer.Option(..., "--out", "-o", help="output folder: landmarks.parquet/.csv and figures"),
        sweep: Optional[List[str]] = typer.Option(None, "--sweep", help="a frequency sweep as LABEL:FIGURE:PROTOCOL:DIR "
                                                  "(FIGURE fig17 or fig18); repeatable"),
        duty_sweep: Optional[List[str]] = typer.Option(None, "--duty-sweep", help="folder of a duty sweep at one "
                                                       "frequency (square wave); repeatable"),
        magnify: Optional[Path] = typer.Option(None, "--magnify", help="magnify Parquet table to draw"),
        quiet: bool = QUIET,
    ):
        """Figures and the landmark table of the dynamics study (tables in, figures out)."""
        check_outputs(folder=out)  # before any work (exit 2 naming the path)
        from ..steps.dynamics import report
        paths = report(out, sweep or [], duty_sweep or [], magnify)
        if not quiet:
            typer.echo(f"{out}: {len(paths)} files", err=True)
