"""Commands of the loop: synth, compare, diagnose, effects list, ledger show|plot."""
from __future__ import annotations

import json
from pathlib import Path
from typing import List, Optional

import typer

from ..errors import InputError
from .common import QUIET, check_outputs

PLUGINS = typer.Option(None, "--plugins", help="Python file(s) registering extra effects (repeat the option).")
SEED = typer.Option(0, "--seed", min=0, help="Random seed (fold assignment, multi-start, noise).")
EFFORT = typer.Option("full", "--effort", help="Dynamics kinds (progression, trajectory): calibration budget, "
                      "'full' or 'quick' (fewer starts, evaluations and bootstrap resamples: a first look, smoke runs).")
FOLDS = typer.Option(5, "--folds", min=2, help="Number of cross-validation folds (groups: trial/run, else identical covariates; progression: conditions).")


def _load(model_path: Path, plugins: Optional[List[Path]]):
    from ..effects.model import build_model
    from ..effects.registry import load_plugins
    from ..validation import check_model_file_bounds

    load_plugins(plugins or [])
    check_model_file_bounds(model_path)
    return build_model(model_path)


DROP = typer.Option(False, "--drop-incomplete", help="Leave out (and list) rows with an empty numeric cell "
                    "or a statistic the models do not predict, and columns empty throughout: published summary "
                    "tables such as configs/reference/*.csv.")


def _data(data: Path, model, kind: Optional[str], drop_incomplete: bool = False):
    from ..tables import read_measurements

    k = kind or model.kind
    if k != model.kind:
        raise InputError(f"{model.path}: a {model.kind} model cannot be compared with a {k} table")
    df, k = read_measurements(data, kind=k, drop_incomplete=drop_incomplete)
    for d in df.attrs.get("dropped_rows", []):
        what = f"row {d['row']}" if "row" in d else f"column '{d['column']}'"
        typer.echo(f"capsule-cli: note: {data}: {what} left out ({d['reason']})", err=True)
    return df, k


def _effort(name: str):
    from ..steps.dynamics_loop import EFFORTS

    if name not in EFFORTS:
        raise InputError(f"--effort: unknown '{name}' (one of {', '.join(EFFORTS)})")
    return EFFORTS[name]


def free_parameter_lines(params: dict) -> list[str]:
    """Return one line per free parameter of a compare's metrics (``params``: {key: {value, free, ci95}}; the key
    carries its unit): ``  Pf_N = 0.00775 [0.00768, 0.00781] (95 %)``, without brackets when there is no
    interval."""
    out = []
    for key, rec in params.items():
        if not rec.get("free"):
            continue
        ci = rec.get("ci95")
        out.append(f"  {key} = {rec['value']:.4g}" + (f" [{ci[0]:.4g}, {ci[1]:.4g}] (95 %)" if ci else ""))
    return out


def register(app: typer.Typer) -> None:
    """Add the loop's commands to ``app``."""

    @app.command("synth")
    def synth(
        model: Path = typer.Option(..., "--model", help="Model file (contract section 4) with the true effects."),
        out: Path = typer.Option(..., "--out", "-o", help="Output table, .csv (+ .provenance.json) or .parquet; "
                                                          "name it *_synthetic.*"),
        noise_sd: Optional[float] = typer.Option(None, "--noise-sd", help="Noise SD in the response unit "
                                                 "(friction: mN; pressure, relaxation: kPa; progression: mm/s; "
                                                 "trajectory: mm)."),
        noise_rel: float = typer.Option(0.0, "--noise-rel", help="Extra noise proportional to the response "
                                        "(fraction, e.g. 0.02 = 2 %)."),
        design: Optional[Path] = typer.Option(None, "--design", help="Design table of covariates (CSV, unit-suffixed "
                                              "columns: speed_mm_s, position_mm, time_s, Ri_mm, ...); default per kind "
                                              "in configs/designs/."),
        replicates: int = typer.Option(1, "--replicates", help="Repeats of every design row (column 'trial'; "
                                       "progression: repeated rows, each a later recorded window)."),
        frame_rate_Hz: float = typer.Option(100.0, "--frame-rate-Hz", help="Trajectory kind: camera frame rate "
                                            "[Hz] (frames from t = 0, rest, drive phase 0)."),
        seed: int = SEED,
        plugins: Optional[List[Path]] = PLUGINS,
        quiet: bool = QUIET,
    ):
        """Synthetic measurements from a model file plus Gaussian noise, labelled synthetic in the metadata."""
        check_outputs(file=out)  # before any work (exit 2 naming the path)
        from ..steps import synth as st
        from ..units import unit_label
        from ..tables import response_column

        if noise_sd is None and noise_rel == 0.0:
            raise InputError("give --noise-sd (in the response unit) and/or --noise-rel")
        m = _load(model, plugins)
        dpath = design or st.default_design(m.kind)
        d = st.read_design(dpath, m.kind)
        df = st.synthesize(m, d, noise_sd or 0.0, noise_rel, replicates, seed, where=str(dpath),
                           frame_rate_Hz=frame_rate_Hz)
        if "synthetic" not in out.name.lower():
            typer.echo(f"capsule-cli: warning: {out.name} does not say 'synthetic' in its name; "
                       "the metadata does, but name synthetic data *_synthetic.*", err=True)
        prov = st.synth_provenance(m, model.read_text(encoding="utf-8"), noise_sd or 0.0, noise_rel, replicates,
                                   seed, str(dpath), unit_label(response_column(m.kind)),
                                   [str(p) for p in plugins or []],
                                   **({"frame_rate_Hz": frame_rate_Hz} if m.kind == "trajectory" else {}))
        st.write_synthetic(df, out, prov)
        if not quiet:
            typer.echo(f"wrote {out} ({len(df)} rows, synthetic, true model {m.name})", err=True)

    @app.command("compare")
    def compare(
        model: Path = typer.Option(..., "--model", help="Model file (contract section 4)."),
        data: Path = typer.Option(..., "--data", help="Measurement table (.csv or .parquet, contract section 3)."),
        out: Path = typer.Option(..., "--out", "-o", help="Output folder: metrics.json, residuals.parquet, figures."),
        ledger: Path = typer.Option(Path("results/ledger.parquet"), "--ledger", help="Ledger to append a row to."),
        kind: Optional[str] = typer.Option(None, "--kind", help="Table kind (default: the model's)."),
        folds: int = FOLDS,
        seed: int = SEED,
        effort: str = EFFORT,
        plugins: Optional[List[Path]] = PLUGINS,
        drop_incomplete: bool = DROP,
        quiet: bool = QUIET,
    ):
        """Calibrate a model's free parameters on measurements; error metrics (held-out RMSE, noise), figures, ledger row."""
        check_outputs(folder=out, ledger=ledger)  # before any work (exit 2 naming the path)
        from ..steps.compare import run_compare
        from ..steps.diagnose import DYNAMICS_KINDS

        m = _load(model, plugins)
        df, k = _data(data, m, kind, drop_incomplete)
        if k in DYNAMICS_KINDS:  # the engine-based loop, imported only then (numba)
            from ..steps import dynamics_loop

            met = dynamics_loop.run_compare(m, df, str(data), out, ledger, folds, seed, budget=_effort(effort))
        else:
            met = run_compare(m, df, k, str(data), out, ledger, folds, seed)
        if not quiet:
            typer.echo(f"{m.name}: n={met['n']} rmse={met['rmse']:.4g} cv_rmse={met['cv_rmse']:.4g}"
                       f"±{met['cv_rmse_se']:.2g} noise={met['noise_sd']:.4g} {met['unit']}", err=True)
            for line in free_parameter_lines(met.get("params", {})):
                typer.echo(line, err=True)
            if met.get("origins_fitted_mm"):
                typer.echo("  origins fitted (runs zeroed at their first frame): " + ", ".join(
                    f"{r} {v:+.3g}" for r, v in met["origins_fitted_mm"].items()) + " mm", err=True)

    @app.command("diagnose")
    def diagnose(
        model: Path = typer.Option(..., "--model", help="Model file (contract section 4)."),
        data: Path = typer.Option(..., "--data", help="Measurement table (.csv or .parquet)."),
        out: Path = typer.Option(..., "--out", "-o", help="Output folder: diagnosis.json, diagnosis.md, figures."),
        write_model: Optional[Path] = typer.Option(None, "--write-model", help="Write the model with the missing "
                                                   "effect added (fitted values as start values) to this YAML."),
        add_best: bool = typer.Option(False, "--add-best", help="With --write-model: add the best-ranked candidate "
                                      "even when the verdict names none (marked so in the file)."),
        kind: Optional[str] = typer.Option(None, "--kind", help="Table kind (default: the model's)."),
        folds: int = FOLDS,
        seed: int = SEED,
        effort: str = EFFORT,
        candidate: Optional[List[str]] = typer.Option(None, "--candidate", help="Dynamics kinds: try only this "
                                                      "effect (repeat the option; default every applicable one). "
                                                      "The verdict's Bonferroni factor counts those tried."),
        plugins: Optional[List[Path]] = PLUGINS,
        drop_incomplete: bool = DROP,
        no_figures: bool = typer.Option(False, "--no-figures", help="Skip the figures (residuals, candidates, best "
                                        "candidate's fit): write the tables and diagnosis.json/.md only, without "
                                        "matplotlib (about a third of a small diagnose's time)."),
        quiet: bool = QUIET,
    ):
        """Where the model fails and which physical effect is missing: a verdict by a rule fixed in advance (F test, held-out error)."""
        check_outputs(folder=out, write_model=write_model)  # before any work (exit 2 naming the path)
        from ..steps.diagnose import DYNAMICS_KINDS, run_diagnose

        m = _load(model, plugins)
        df, k = _data(data, m, kind, drop_incomplete)
        if k in DYNAMICS_KINDS:  # the engine-based loop, imported only then (numba)
            from ..steps import dynamics_loop

            r = dynamics_loop.run_diagnose(m, df, str(data), out, write_model, folds, seed, add_best=add_best,
                                           quiet=quiet, figures=not no_figures, budget=_effort(effort),
                                           candidates=candidate or None)
        else:
            if candidate:
                raise InputError("--candidate: only for the dynamics kinds (progression, trajectory)")
            r = run_diagnose(m, df, k, str(data), out, write_model, folds, seed, add_best=add_best, quiet=quiet,
                             figures=not no_figures)
        if write_model is not None and r["verdict"]["missing_effect"] is None and not add_best:
            typer.echo(f"capsule-cli: note: no effect named; {write_model} is the model unchanged", err=True)
        if not quiet:
            typer.echo(r["verdict"]["message"], err=True)

    effects_app = typer.Typer(help="The physical effects available to models (built in and from plugins).",
                              no_args_is_help=True)
    app.add_typer(effects_app, name="effects")

    @effects_app.command("list")
    def effects_list(
        kind: Optional[str] = typer.Option(None, "--kind", help="Only this kind (friction, pressure, relaxation)."),
        plugins: Optional[List[Path]] = PLUGINS,
        as_json: bool = typer.Option(False, "--json", help="Print JSON instead of text."),
    ):
        """List base models and effects with their parameters (unit from the name's suffix), covariates and sources.

        A plugin file registers effects with capsule_cli.effects.register_effect; functions see SI values
        keyed by names without unit suffix (see capsule_cli/effects/registry.py).
        """
        from ..effects.registry import KINDS, bases, effects, load_plugins

        if kind is not None and kind not in KINDS:
            raise InputError(f"--kind: unknown kind '{kind}' (one of {', '.join(KINDS)})")
        load_plugins(plugins or [])

        def prm(p):
            return {"name": p.name, "unit": p.unit, "start": p.start, "bounds": list(p.bounds), "off": p.off,
                    "free_by_default": p.free, "description": p.description}

        items = {
            "bases": [{"name": b.name, "kind": b.kind, "description": b.description, "source": b.source,
                       "params": [prm(p) for p in b.params]} for b in bases(kind)],
            "effects": [{"name": e.name, "kind": e.kind, "origin": e.origin, "covariates": list(e.covariates),
                         "bases": list(e.bases), "description": e.description, "source": e.source,
                         "repeatable": e.repeatable, "role": e.role,
                         "nests": [{"effect": a, "at": b} for a, b in e.nests],
                         "params": [prm(p) for p in e.params]} for e in effects(kind)],
        }
        if as_json:
            typer.echo(json.dumps(items, indent=2, default=str))
            return
        for k in KINDS:
            bs = [b for b in items["bases"] if b["kind"] == k]
            es = [e for e in items["effects"] if e["kind"] == k]
            if not bs and not es:
                continue
            typer.echo(f"== {k} ==")
            for b in bs:
                typer.echo(f"base {b['name']}: {b['description']} [{b['source']}]")
                for p in b["params"]:
                    typer.echo(f"    {p['name']:<22} default {p['start']:<10g} [{p['unit'] or '-'}]  {p['description']}")
            for e in es:
                needs = f" needs {', '.join(e['covariates'])};" if e["covariates"] else ""
                only = f" base {'/'.join(e['bases'])} only;" if e["bases"] else ""
                rep = f" repeatable as {e['name']}_2, {e['name']}_3 ...;" if e["repeatable"] else ""
                rep += "".join(f" contains {x['effect']} at {x['at']};" for x in e["nests"])
                role = {"drive": " drive transform;",
                        "force": " plugin force (numba, adaptive path);"}.get(e["role"], "")
                typer.echo(f"effect {e['name']} ({e['origin']};{role}{needs}{only}{rep} source: {e['source']})")
                typer.echo(f"    {e['description']}")
                for p in e["params"]:
                    lo, hi = p["bounds"]
                    typer.echo(f"    {p['name']:<22} start {p['start']:<9g} bounds [{lo:g}, {hi:g}] off {p['off']:g}"
                               f" [{p['unit'] or '-'}]{'' if p['free_by_default'] else ' (fixed unless freed)'}"
                               f"  {p['description']}")
            typer.echo("")

    ledger_app = typer.Typer(help="The error history of a model across revisions.", no_args_is_help=True)
    app.add_typer(ledger_app, name="ledger")

    @ledger_app.command("show")
    def ledger_show(
        ledger: Optional[List[Path]] = typer.Option(None, "--ledger", help="Ledger file(s), read in order "
                                                    "(default results/ledger.parquet)."),
        model: Optional[str] = typer.Option(None, "--model", help="Only rows of this model name (and its revisions)."),
        as_json: bool = typer.Option(False, "--json", help="Print JSON rows."),
    ):
        """Print the ledger as a table (errors in the response unit)."""
        from ..steps.ledger import read_ledger

        df = read_ledger(ledger or [Path("results/ledger.parquet")])
        if model is not None:
            df = df[df["model"].astype(str).str.startswith(model)]
        cols = ["timestamp", "model", "effects", "data_hash", "n", "rmse", "cv_rmse", "cv_rmse_se", "noise_sd", "unit"]
        if as_json:
            typer.echo(df[cols].to_json(orient="records", indent=2))
            return
        import pandas as pd

        with pd.option_context("display.width", 200, "display.max_columns", 20, "display.float_format", "{:.4g}".format):
            typer.echo(df[cols].to_string(index=False))

    @ledger_app.command("plot")
    def ledger_plot(
        out: Path = typer.Option(..., "--out", "-o", help="Figure file (.png or .pdf)."),
        ledger: Optional[List[Path]] = typer.Option(None, "--ledger", help="Ledger file(s), read in order "
                                                    "(default results/ledger.parquet)."),
        model: Optional[str] = typer.Option(None, "--model", help="Rows of this model name (default: the rows on "
                                            "the data set of the last row)."),
        title: str = typer.Option("", "--title", help="Figure title."),
    ):
        """Plot the held-out error per revision (± SE) with the noise level as a band: the error falling."""
        check_outputs(file=out)  # before any work (exit 2 naming the path)
        from ..plots.loop import plot_ledger
        from ..steps.ledger import read_ledger, select_history
        from .common import ensure_suffix

        ensure_suffix(out, (".png", ".pdf"), "--out")
        hist = select_history(read_ledger(ledger or [Path("results/ledger.parquet")]), model)
        plot_ledger(hist, out, title=title or f"error history on {Path(str(hist['data'].iloc[-1])).name}")
        cv = hist["cv_rmse"].to_numpy(float)
        typer.echo(f"{out}: {len(hist)} revision(s), held-out RMSE {cv[0]:.3g} -> {cv[-1]:.3g} "
                   f"{hist['unit'].iloc[-1]}", err=True)
