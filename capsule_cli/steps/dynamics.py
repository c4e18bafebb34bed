"""Compose engine runs into tables: one run, sweeps, magnification maps, landmarks.

Every table has a schema here; writing goes through :mod:`capsule_cli.tables` (atomic
Parquet, units in field metadata, provenance in schema metadata).
"""
from __future__ import annotations

import math
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..tables import Column, TableSchema, provenance, staged_folder, write_json_atomic, write_table
from ..dynamics.model import (STEADY_SETTLE_TOL, CapsuleModel, Drive, EngineOptions, Friction, friction_preset,
                              load_model)
from ..dynamics.run import simulate
from ..dynamics.sweep import run_sweep

C = Column

TRAJECTORY = TableSchema("dynamics_trajectory", "engine state sampled at a fixed rate (seed 000 eqs 19-21)", (
    C("time_s", "float64", "time since the start of the run"),
    C("magnet_mm", "float64", "magnet position X_m"),
    C("capsule_mm", "float64", "capsule (shell) position X_c"),
    C("magnet_velocity_mm_s", "float64", "magnet velocity V_m"),
    C("capsule_velocity_mm_s", "float64", "capsule velocity V_c"),
    C("relative_mm", "float64", "relative displacement X_r = X_m - X_c"),
    C("contact", "int64", "contact state: 0 none, 1 front constraint, 2 back constraint", unit=""),
    C("stick", "bool", "shell stuck (V_c = 0 held by static friction)", unit=""),
    C("Fi_N", "float64", "interaction force F_i on the shell (eq 20)"),
))
EVENTS = TableSchema("dynamics_events", "exact event list of a run (root-found switching times)", (
    C("time_s", "float64", "event time"),
    C("kind", "string", "front/back_contact_on/off, stick, slip_forward, slip_backward, drive_on/off", unit=""),
))
PERIODS = TableSchema("dynamics_periods", "one row per recorded excitation period", (
    C("period", "int64", "period index since the start (phase 0 at period * T)", unit=""),
    C("time_s", "float64", "start time of the period"),
    C("displacement_mm", "float64", "capsule displacement over the period"),
    C("impacts", "int64", "front-constraint impacts in the period", unit=""),
    C("back_impacts", "int64", "back-constraint impacts in the period", unit=""),
    C("max_Fi_N", "float64", "max |F_i| in the period (located at its exact extremum)"),
    C("max_Fi_time_s", "float64", "time of max |F_i|"),
    C("relative_mm", "float64", "Poincare point: X_r at phase 0"),
    C("relative_velocity_mm_s", "float64", "Poincare point: V_r at phase 0"),
    C("capsule_velocity_mm_s", "float64", "V_c at phase 0"),
    C("capsule_mm", "float64", "X_c at phase 0"),
    C("stick_fraction", "float64", "fraction of the period with the shell stuck", unit=""),
    C("stick_events", "int64", "slip-to-stick transitions in the period", unit=""),
))
SWEEP_POINTS = TableSchema("dynamics_sweep_points", "one row per sweep point", (
    C("point", "int64", "index of the point in the value list", unit=""),
    C("value", "float64", "swept parameter value (unit: the 'parameter' of the provenance)", unit="see provenance"),
    C("f_Hz", "float64", "drive frequency of the point"),
    C("velocity_mm_s", "float64", "average capsule velocity over the recorded periods"),
    C("impacts_per_period", "float64", "mean front impacts per period", unit=""),
    C("back_impacts_per_period", "float64", "mean back impacts per period", unit=""),
    C("max_Fi_N", "float64", "max |F_i| over the recorded periods"),
    C("Af", "float64", "magnification factor max|F_i| / P_d (seed 000 eq 24)", unit=""),
    C("period_number", "int64", "period of the response in drive periods (0: none found up to 8)", unit=""),
    C("stick_fraction", "float64", "mean stuck fraction", unit=""),
    C("order", "int64", "position in the run order (continuation protocols)", unit=""),
))
SWEEP = TableSchema("dynamics_sweep", "one row per sweep point per recorded period (Poincare points)", (
    C("point", "int64", "index of the point", unit=""),
    C("value", "float64", "swept parameter value", unit="see provenance"),
    C("period", "int64", "period index", unit=""),
    C("relative_mm", "float64", "Poincare X_r at phase 0"),
    C("relative_velocity_mm_s", "float64", "Poincare V_r at phase 0 (seed 000 Figs 17-18)"),
    C("displacement_mm", "float64", "capsule displacement over the period"),
    C("impacts", "int64", "front impacts in the period", unit=""),
    C("max_Fi_N", "float64", "max |F_i| in the period"),
    C("velocity_mm_s", "float64", "average velocity of the point"),
    C("impacts_per_period", "float64", "mean impacts per period of the point", unit=""),
    C("Af", "float64", "magnification factor of the point", unit=""),
    C("period_number", "int64", "period of the point's response (0: none up to 8)", unit=""),
))
MAGNIFY = TableSchema("dynamics_magnify", "magnification factor A_f = max|F_i|/P_d over (P_d, f) (seed 000 eq 24)", (
    C("friction", "string", "friction of the panel: a Coulomb level in N ('0.007'), 'inf' (shell fixed), "
      "'eq22' or 'eq23' (seed 000 speed laws)", unit=""),
    C("Pf_N", "float64", "Coulomb friction level (inf: shell fixed; NaN: speed law)"),
    C("Pd_N", "float64", "drive amplitude"),
    C("f_Hz", "float64", "drive frequency"),
    C("protocol", "string", "initial conditions: rest (every point from rest) or up/down (continuation in f)",
      unit=""),
    C("Af", "float64", "magnification factor over the recorded (steady) periods", unit=""),
    C("max_Fi_N", "float64", "max |F_i| over the recorded periods"),
    C("impacts_per_period", "float64", "mean front impacts per period", unit=""),
    C("velocity_mm_s", "float64", "average capsule velocity"),
))
LANDMARKS = TableSchema("dynamics_landmarks", "frequency landmarks found by the sweeps beside seed 000 section 5.3", (
    C("case", "string", "friction case label", unit=""),
    C("case_name", "string", "physical name of the friction case", unit=""),
    C("protocol", "string", "initial conditions of the sweep (rest/up/down)", unit=""),
    C("landmark", "string", "what changes at this frequency", unit=""),
    C("found_Hz", "float64", "frequency found by the sweep (NaN: not found in the range)"),
    C("paper_Hz", "float64", "value reported by the paper (NaN: none)"),
    C("difference_Hz", "float64", "found - paper"),
    C("resolution_Hz", "float64", "frequency step of the sweep"),
    C("paper_source", "string", "where the paper reports it", unit=""),
))


def make_friction(kind: str, Pf_N: float | None, literal: bool = False, v_min_mm_s: float | None = None,
                  speed_unit: str = "mm/s", static_N: float | None = None) -> Friction:
    """Return the friction model for a CLI/config choice."""
    if static_N is not None and kind != "coulomb":
        raise InputError("--static-N applies to Coulomb friction only (eq22/eq23 carry their own static levels)")
    if kind == "coulomb" and Pf_N is None:
        raise InputError("--friction coulomb needs --Pf-N (N)")
    if speed_unit != "mm/s" and kind not in ("eq22", "eq23"):
        raise InputError("--law-speed-unit applies to the speed laws eq22 and eq23 only")
    return friction_preset(kind, Pf_N, literal=literal, v_min_mm_s=v_min_mm_s, speed_unit=speed_unit,
                           static_N=static_N)


def resolve_model(model: str, overrides: dict[str, float] | None = None) -> tuple[CapsuleModel, float | None]:
    """Return (model, P_f [N] of the set) from a parameter-set name or YAML path plus overrides."""
    m, pf = load_model(model)
    for name, value in (overrides or {}).items():
        m = m.with_param(name, value)
    return m, pf


def _prov(**extra) -> dict:
    return provenance(**{k: (asdict(v) if hasattr(v, "__dataclass_fields__") else v) for k, v in extra.items()})


def simulate_to_dir(out: Path, model: CapsuleModel, drive: Drive, friction: Friction, periods: int,
                    transient_periods: int, sample_rate_Hz: float, model_name: str = "",
                    options: EngineOptions | None = None) -> dict:
    """Run once; write trajectory, events, periods (Parquet) and summary.json under ``out``."""
    from ..dynamics.run import event_names, period_columns, run_arrays, trajectory_columns

    # arrays straight to Parquet: no pandas on this path (start-up of a short `simulate`, issue 13)
    res = run_arrays(model, drive, friction, periods=periods, transient_periods=transient_periods,
                     sample_rate_Hz=sample_rate_Hz, options=options, interruptible=True)  # one call: Ctrl-C at once
    prov = _prov(model_name=model_name, model=model, drive=drive, friction=friction, periods=periods,
                 transient_periods=transient_periods, sample_rate_Hz=sample_rate_Hz)
    per = period_columns(res.per, drive.frequency_Hz, transient_periods)
    n = len(per["period"])
    from ..dynamics.sweep import period_number
    summary = {
        "model": model_name, "drive": asdict(drive), "friction": asdict(friction),
        "periods": periods, "transient_periods": transient_periods,
        "average_velocity_mm_s": float(per["displacement_mm"].mean() * drive.frequency_Hz) if n else float("nan"),
        "impacts_per_period": float(per["impacts"].mean()) if n else None,
        "max_Fi_N": float(per["max_Fi_N"].max()) if n else None,
        "Af": float(per["max_Fi_N"].max() / drive.amplitude_N) if (n and drive.amplitude_N > 0) else None,
        "period_number": period_number(per["relative_mm"], per["relative_velocity_mm_s"]) if n else None,
        "stick_fraction": float(per["stick_fraction"].mean()) if n else None,
        "n_events": int(len(res.event_times_s)),
        "energy_balance": res.energy,
        "final_state": {"relative_mm": res.final_state[0] * 1e3, "relative_velocity_mm_s": res.final_state[1] * 1e3,
                        "capsule_mm": res.final_state[2] * 1e3, "capsule_velocity_mm_s": res.final_state[3] * 1e3},
        "provenance": prov,
    }
    with staged_folder(out) as stage:  # the four files or none (a long run's trajectory takes seconds to write)
        write_table(trajectory_columns(res.samples), stage / "trajectory.parquet", TRAJECTORY, prov)
        write_table({"time_s": res.event_times_s, "kind": event_names(res.event_kinds)}, stage / "events.parquet",
                    EVENTS, prov)
        write_table(per, stage / "periods.parquet", PERIODS, prov)
        write_json_atomic(stage / "summary.json", summary)
    return summary


def sweep_to_dir(out: Path, model: CapsuleModel, drive: Drive, friction: Friction, param: str, values,
                 protocol: str, transient_periods: int, periods: int, model_name: str = "", label: str = "",
                 progress=None, state0=None, settle_tol: float | None = None) -> dict:
    """Run a sweep; write ``points.parquet``, ``sweep.parquet`` (Poincare rows) and ``sweep.json``.

    state0 = [x_r, v_r, V_c] [m, m/s] is the initial state of every point (protocol rest) or of the
    first point (up/down); default rest. settle_tol: the settled-transient tolerance
    (EngineOptions.settle_tol); None: STEADY_SETTLE_TOL, as the maps, so that a sweep point and a
    map point are the same computation."""
    settle_tol = float(STEADY_SETTLE_TOL if settle_tol is None else settle_tol)
    res = run_sweep(model, drive, friction, param, values, protocol, transient_periods, periods, progress=progress,
                    state0=state0, options=EngineOptions(settle_tol=settle_tol))
    prov = _prov(model_name=model_name, model=model, drive=drive, friction=friction, parameter=param,
                 protocol=protocol, transient_periods=transient_periods, periods=periods, label=label,
                 settle_tol=settle_tol,
                 initial_state_SI=[0.0, 0.0, 0.0] if state0 is None else [float(x) for x in state0])
    meta = {"parameter": param, "protocol": protocol, "label": label, "n_points": int(len(res.points)),
            "transient_periods": transient_periods, "periods": periods, "provenance": prov}
    with staged_folder(out) as stage:  # the three files or none
        write_table(res.points, stage / "points.parquet", SWEEP_POINTS, prov)
        write_table(res.poincare, stage / "sweep.parquet", SWEEP, prov)
        write_json_atomic(stage / "sweep.json", meta)
    return meta


def magnify_friction(spec) -> tuple[str, Friction, float]:
    """Return (label, friction, P_f [N]) of a magnify friction: a Coulomb level in N, 'inf', 'eq22', 'eq23'.

    P_f is inf for the fixed shell and NaN for the speed laws (seed 000 eqs 21-23).
    """
    text = str(spec).strip().lower()
    if text in ("eq22", "eq23"):
        return text, friction_preset(text), float("nan")
    try:
        level = float(text)
    except ValueError:
        raise InputError(f"friction '{spec}': expected a Coulomb level in N, inf, eq22 or eq23") from None
    if math.isnan(level) or level <= 0:
        raise InputError(f"friction '{spec}': a Coulomb level must be > 0 N (or inf)")
    if math.isinf(level):
        return "inf", friction_preset("fixed"), float("inf")
    return f"{level:g}", friction_preset("coulomb", level), level


def map_rk_rtol() -> float:
    """The adaptive segment's relative tolerance for magnification maps [-] (``rk_rtol`` of
    configs/bench/fig19.yaml, where its measured effect on A_f is stated)."""
    return float(load_fig19()["rk_rtol"])


def load_fig19(path: Path | None = None) -> dict:
    """Return the seed 000 Fig 19 set (configs/bench/fig19.yaml): frictions, grid, periods, protocol."""
    from ..config import configs_dir, read_yaml

    return read_yaml(path or (configs_dir() / "bench" / "fig19.yaml"))


def magnify_arrays(model: CapsuleModel, Pd_values, f_values, friction: Friction, protocol: str,
                   transient_periods: int, periods: int, progress=None, target_chunk_s: float | None = None,
                   rk_rtol: float | None = None, settle_tol: float | None = None):
    """A_f and friends over the (P_d, f) grid of one friction, as (n_Pd, n_f) arrays.

    rest: every point from rest, all points in parallel chunks; up/down: continuation along f
    (increasing / decreasing) from rest at the first frequency, all P_d rows in parallel.
    ``rk_rtol``: relative tolerance of the adaptive segment (speed-law slip, eqs 22-23); None: the
    maps' tolerance (:func:`map_rk_rtol`). Exact (Coulomb, fixed-shell) modes ignore it. ``settle_tol``:
    the settled-transient tolerance (EngineOptions.settle_tol); None: STEADY_SETTLE_TOL (dynamics.model).
    Returns a dict of arrays Af, max_Fi_N, impacts_per_period, velocity_mm_s.
    """
    from ..dynamics import engine as E
    from ..dynamics.model import pack_params
    from ..dynamics.parallel import TARGET_CHUNK_S, run_points, run_rows_continuation, summarize
    from ..dynamics.run import check_status

    if protocol not in ("rest", "up", "down"):
        raise InputError(f"unknown protocol '{protocol}' (one of rest, up, down)")
    Pd = np.asarray(Pd_values, dtype=float)
    f = np.asarray(f_values, dtype=float)
    if Pd.size == 0 or f.size == 0:
        raise InputError("empty magnify grid (--Pd-num and --f-num must be >= 1)")
    if periods < 1:
        raise InputError("magnify needs at least one recorded period")
    for x in Pd:
        Drive(float(x), float(f[0])).validate()
    for x in f:
        Drive(float(Pd[0]), float(x)).validate()
    order = np.arange(f.size)
    if protocol == "up":
        order = np.argsort(f, kind="stable")
    elif protocol == "down":
        order = np.argsort(-f, kind="stable")
    # parameter vectors: the grid in run order along f (Drive is valid: checked above)
    P = np.empty((Pd.size, f.size, E.N_PARAMS))
    for i, a in enumerate(Pd):
        for jj, j in enumerate(order):
            P[i, jj] = pack_params(model, Drive(float(a), float(f[j])), friction)
    opts = EngineOptions(energy=False, rk_rtol=float(map_rk_rtol() if rk_rtol is None else rk_rtol),
                         settle_tol=float(STEADY_SETTLE_TOL if settle_tol is None else settle_tol)).pack()
    if protocol == "rest":
        st, per, _ = run_points(P.reshape(-1, E.N_PARAMS), opts, np.zeros((P.shape[0] * P.shape[1], 4)),
                                int(transient_periods), int(periods), progress=progress,
                                target_chunk_s=target_chunk_s or TARGET_CHUNK_S)
        st = st.reshape(Pd.size, f.size)
        per = per.reshape(Pd.size, f.size, *per.shape[1:])
    else:
        st, per = run_rows_continuation(P, opts, np.zeros((Pd.size, 4)), int(transient_periods), int(periods),
                                        progress=progress)
    inv = np.empty_like(order)
    inv[order] = np.arange(f.size)
    st = st[:, inv]
    per = per[:, inv]
    bad = np.argwhere(st != E.STATUS_OK)
    if bad.size:
        i, j = (int(x) for x in bad[0])
        check_status(int(st[i, j]), float("nan"), friction, f"magnify point P_d = {Pd[i]:g} N, f = {f[j]:g} Hz",
                     model.plugin_forces)
    PdG, fG = np.meshgrid(Pd, f, indexing="ij")
    sm = summarize(per.reshape(-1, *per.shape[2:]), PdG.ravel(), fG.ravel())
    return {k: sm[k].reshape(Pd.size, f.size) for k in ("Af", "max_Fi_N", "impacts_per_period", "velocity_mm_s")}


def magnify_table(model: CapsuleModel, Pd_values, f_values, frictions, protocol: str, transient_periods: int,
                  periods: int, progress=None, timings: dict | None = None,
                  rk_rtol: float | None = None, settle_tol: float | None = None) -> pd.DataFrame:
    """Return A_f over (P_d, f) for each friction (Coulomb level [N], inf, 'eq22', 'eq23'), one table.

    Rows: frictions in the given order, then P_d, then f (ascending as given). ``timings``, if
    given, receives the wall time [s] of each friction by label. ``rk_rtol``, ``settle_tol``: see
    :func:`magnify_arrays`.
    """
    import pandas as pd
    import time

    Pd = np.asarray(Pd_values, dtype=float)
    f = np.asarray(f_values, dtype=float)
    parsed = [magnify_friction(x) for x in frictions]
    labels = [p[0] for p in parsed]
    if len(set(labels)) != len(labels):
        raise InputError(f"magnify: a friction is given twice ({', '.join(labels)})")
    parts = []
    for label, fr, pf in parsed:
        t0 = time.perf_counter()
        a = magnify_arrays(model, Pd, f, fr, protocol, transient_periods, periods, progress=progress,
                           rk_rtol=rk_rtol, settle_tol=settle_tol)
        if timings is not None:
            timings[label] = time.perf_counter() - t0
        parts.append((label, pf, a))
    n = Pd.size * f.size
    PdG, fG = np.meshgrid(Pd, f, indexing="ij")
    return pd.DataFrame({
        "friction": pd.array(np.repeat(labels, n), dtype="string"),
        "Pf_N": np.repeat([pf for _, pf, _ in parts], n).astype(float),
        "Pd_N": np.tile(PdG.ravel(), len(parts)),
        "f_Hz": np.tile(fG.ravel(), len(parts)),
        "protocol": pd.array([protocol] * (n * len(parts)), dtype="string"),
        **{k: np.concatenate([a[k].ravel() for _, _, a in parts])
           for k in ("Af", "max_Fi_N", "impacts_per_period", "velocity_mm_s")},
    })


def gather_magnify(tables: list[pd.DataFrame], order: list[str] | None = None) -> pd.DataFrame:
    """Join magnify chunks (split along P_d and/or by friction) into one table.

    Rows are ordered as an unchunked run: frictions in ``order`` (default: first appearance),
    then P_d, then f. Raises InputError on overlapping rows, mixed protocols, a friction
    missing from ``order``, or a friction whose (P_d, f) grid is incomplete (when the chunks'
    provenance gives the grid).
    """
    import pandas as pd
    if not tables:
        raise InputError("magnify --gather: no chunk tables given")
    if len({tuple(dict.fromkeys(t["protocol"].tolist())) for t in tables}) != 1:
        raise InputError("magnify --gather: the chunks have different protocols")
    df = pd.concat(tables, ignore_index=True)
    seen = list(dict.fromkeys(df["friction"].tolist()))
    order = list(order) if order else seen
    missing = [x for x in seen if x not in order]
    if missing:
        raise InputError(f"magnify --gather: chunk friction(s) {', '.join(missing)} not among {', '.join(order)}")
    rank = {lab: k for k, lab in enumerate(order)}
    df = df.assign(_r=df["friction"].map(rank).astype(int)).sort_values(["_r", "Pd_N", "f_Hz"], kind="stable")
    df = df.drop(columns="_r").reset_index(drop=True)
    if df.duplicated(["friction", "Pd_N", "f_Hz"]).any():
        raise InputError("magnify --gather: chunks overlap (a (friction, P_d, f) point appears twice)")
    grids = {(tuple(t.attrs.get("provenance", {}).get("Pd_grid_N") or ()),
              tuple(t.attrs.get("provenance", {}).get("f_grid_Hz") or ())) for t in tables}
    if len(grids) == 1:
        (pg, fg), = grids
        if pg and fg:
            want = int(pg[2]) * int(fg[2])
            counts = df.groupby("friction", sort=False).size()
            short = [f"{k} ({v} of {want})" for k, v in counts.items() if v != want]
            if short:
                raise InputError(f"magnify --gather: incomplete map(s): {', '.join(short)} points")
    return df


def gather_magnify_files(paths, order=None) -> tuple[pd.DataFrame, dict]:
    """Read magnify chunk tables and join them (:func:`gather_magnify`); return (table, provenance).

    ``order``: friction specs giving the panel order (default: first appearance). The
    provenance is the chunks' (grid, protocol, periods) plus the list of chunk files.
    """
    from ..tables import read_table

    tabs = [read_table(p) for p in paths]
    labels = [magnify_friction(x)[0] for x in (order or [])]
    df = gather_magnify(tabs, labels or None)
    prov = dict(tabs[0].attrs.get("provenance", {}))
    base = ("package", "version", "git_commit", "config_hash", "seed", "synthetic", "command", "Pd_rows")
    prov = {k: v for k, v in prov.items() if k not in base}
    prov["frictions"] = list(dict.fromkeys(df["friction"].tolist()))
    return df, provenance(**prov, gathered_from=[str(p) for p in paths])


def friction_kind(spec) -> str:
    """Cost class of a magnify friction: coulomb, fixed, eq22 or eq23."""
    label = magnify_friction(spec)[0]
    return label if label in ("fixed", "eq22", "eq23") else ("fixed" if label == "inf" else "coulomb")


def plan_magnify_jobs(frictions, Pd_num: int, f_num: int, periods_per_point: int,
                      cost_us_per_period: dict[str, float], target_job_s: float, threads: int = 1) -> list[dict]:
    """Split magnify work into jobs of about ``target_job_s`` [s] wall time each.

    Estimated cost of a friction's map: points x periods x ``cost_us_per_period[kind]`` [us on one
    core] / ``threads``. A map estimated above the target is split along P_d into near-equal
    row ranges (each running the whole f axis, so continuation gives the same result); maps
    below it are grouped, first fit in the given order, into jobs of whole maps.
    Returns [{'name', 'frictions' (labels), 'rows' (start, stop), 'est_s'}].
    """
    jobs: list[dict] = []
    small: list[dict] = []
    for spec in frictions:
        label = magnify_friction(spec)[0]
        est = Pd_num * f_num * periods_per_point * cost_us_per_period[friction_kind(spec)] * 1e-6 / max(1, threads)
        if est > target_job_s and Pd_num > 1:
            n = int(math.ceil(est / target_job_s))
            for a, b in Pd_chunks(Pd_num, n):
                jobs.append({"frictions": [label], "rows": (a, b), "est_s": est * (b - a) / Pd_num})
            continue
        for g in small:
            if g["est_s"] + est <= target_job_s:
                g["frictions"].append(label)
                g["est_s"] += est
                break
        else:
            small.append({"frictions": [label], "rows": (0, Pd_num), "est_s": est})
    out = small + jobs
    for k, j in enumerate(out):
        j["name"] = f"job{k:03d}"
    return out


def Pd_chunks(n_Pd: int, n_chunks: int) -> list[tuple[int, int]]:
    """Split P_d indices 0..n_Pd-1 into ``n_chunks`` contiguous [start, stop) ranges of near-equal size."""
    n_chunks = max(1, min(int(n_chunks), int(n_Pd)))
    edges = np.linspace(0, n_Pd, n_chunks + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


# ---------------------------------------------------------------------------
# landmarks (seed 000 section 5.3; physics.md section 3)

#: the paper's landmarks: figure -> [(landmark, Hz, source)]; NaN: the paper gives no number
PAPER_LANDMARKS = {
    "fig17": [("first grazing (impacts from here on)", 21.9, "seed 000 section 5.3 (Fig 17)"),
              ("period-1 with two impacts begins", float("nan"),
               "seed 000 section 5.3 (Fig 17: after the chaos windows, no value given)"),
              ("two impacts -> one impact per period", 28.66, "seed 000 section 5.3 (Fig 17)"),
              ("onset of forward progression", 31.76, "seed 000 section 5.3 (Fig 17)")],
    "fig18": [("first grazing (impacts from here on)", float("nan"),
               "none: P_d/k = 2.42 mm > G_1, impacts at every f (physics.md section 3)"),
              ("period-1 with two impacts begins", 13.32,
               "seed 000 section 5.3 (Fig 18: chaos -> period-1 with two impacts)"),
              ("two impacts -> one impact per period", 23.4, "seed 000 section 5.3 (Fig 18)"),
              ("onset of forward progression", 13.32,
               "seed 000 section 5.3 (Fig 18: 'no significant forward progression until f = 13.32 Hz')")],
}


def _from_here_on(f: np.ndarray, ok: np.ndarray) -> float:
    """Smallest f such that ``ok`` holds there and at every higher f (NaN if not at the top)."""
    if len(ok) == 0 or not ok[-1]:
        return float("nan")
    i = len(ok) - 1
    while i > 0 and ok[i - 1]:
        i -= 1
    return float(f[i])


def _longest_run_start(f: np.ndarray, ok: np.ndarray) -> float:
    """First f of the longest run of consecutive points where ``ok`` holds (NaN if none)."""
    best_len, best_i, i = 0, -1, 0
    while i < len(ok):
        if ok[i]:
            j = i
            while j + 1 < len(ok) and ok[j + 1]:
                j += 1
            if j - i + 1 > best_len:
                best_len, best_i = j - i + 1, i
            i = j + 1
        else:
            i += 1
    return float(f[best_i]) if best_i >= 0 else float("nan")


def find_landmarks(points: pd.DataFrame, v_tol_mm_s: float = 1e-3) -> dict[str, float]:
    """Return the frequency landmarks of a sweep over f (seed 000 section 5.3 wording).

    The definitions (also printed in ``landmarks.md`` and used in docs/dynamics.md):

    * first grazing: the lowest f from which every higher f impacts, provided some lower f
      does not (NaN when every point impacts, as with P_f = 2.5 N); impacts in a window below
      it (eq 22 read in mm/s) are reported apart by :func:`impact_windows_below`;
    * period-1 with two impacts begins: first f of the longest run of period-1 responses
      with two impacts per period, at or above the first grazing when there is one (the
      paper's order: grazing, chaos windows, period-1 with two impacts, one impact);
    * two -> one impact: the lowest f from which every higher f has exactly one impact per
      period (NaN if no point has two or more);
    * onset of forward progression: the lowest f from which every higher f has an average
      velocity above ``v_tol_mm_s`` [mm/s].
    """
    p = points.sort_values("value")
    f = p["value"].to_numpy()
    imp = p["impacts_per_period"].to_numpy()
    per1 = p["period_number"].to_numpy() == 1
    first_grazing = _from_here_on(f, imp > 0) if (imp == 0).any() else float("nan")
    above = f >= first_grazing if np.isfinite(first_grazing) else np.ones(len(f), bool)
    return {
        "first grazing (impacts from here on)": first_grazing,
        "period-1 with two impacts begins": _longest_run_start(f, per1 & np.isclose(imp, 2.0) & above),
        "two impacts -> one impact per period": _from_here_on(f, np.isclose(imp, 1.0)) if (imp >= 2).any()
        else float("nan"),
        "onset of forward progression": _from_here_on(f, p["velocity_mm_s"].to_numpy() > v_tol_mm_s),
    }


def impact_windows_below(points: pd.DataFrame, first_grazing_Hz: float) -> list[tuple[float, float]]:
    """Return the frequency windows [f_lo, f_hi] [Hz] below the first grazing where the shell impacts."""
    if not np.isfinite(first_grazing_Hz):
        return []
    p = points.sort_values("value")
    f = p["value"].to_numpy()
    hit = (p["impacts_per_period"].to_numpy() > 0) & (f < first_grazing_Hz)
    windows, start = [], None
    for i, h in enumerate(hit):
        if h and start is None:
            start = f[i]
        if start is not None and (not h or i == len(hit) - 1):
            windows.append((float(start), float(f[i] if h else f[i - 1])))
            start = None
    return windows


def case_name(friction: dict | None, label: str = "") -> str:
    """Physical name of a friction case from its provenance (``asdict(Friction)``), for legends and tables."""
    if not friction:
        return label
    kind = friction.get("kind")
    unit = friction.get("speed_unit", "mm/s")
    if kind == "coulomb":
        lvl = float(friction.get("level_N", float("nan")))
        txt = f"Coulomb $P_f$ = {lvl * 1e3:g} mN" if lvl < 0.1 else f"Coulomb $P_f$ = {lvl:g} N"
        st = friction.get("static_N")
        return txt + (f", static {st:g} N" if st is not None else "")
    if kind == "fixed":
        return "shell fixed ($P_f$ = ∞)"
    if kind in ("eq22", "eq23"):
        law = f"speed law eq {kind[2:]}"
        reading = "as written" if friction.get("literal") else "well-posed"
        return f"{law}, V in {unit}" + (" (sensitivity)" if unit != "mm/s" else "") + \
            ("" if reading == "well-posed" else " (literal)")
    return label or str(kind)


def plain(text: str) -> str:
    """A legend name without TeX markup (for markdown tables)."""
    return text.replace("$P_f$", "P_f").replace("$", "")


def landmark_table(sweeps: list[tuple[str, str, str, pd.DataFrame]]) -> pd.DataFrame:
    """Return the landmarks of each (case label, figure, protocol, points) beside the paper's values."""
    import pandas as pd
    rows = []
    for label, figure, protocol, points in sweeps:
        found = find_landmarks(points)
        vals = np.sort(points["value"].to_numpy())
        res = float(np.min(np.diff(vals))) if len(vals) > 1 else float("nan")
        name = case_name(points.attrs.get("provenance", {}).get("friction"), label)
        for lm_name, paper, src in PAPER_LANDMARKS[figure]:
            got = found[lm_name]
            rows.append({"case": label, "case_name": plain(name), "protocol": protocol, "landmark": lm_name,
                         "found_Hz": got, "paper_Hz": paper, "difference_Hz": got - paper, "resolution_Hz": res,
                         "paper_source": src})
    return pd.DataFrame(rows)


LANDMARK_DEFINITIONS = {
    "first grazing (impacts from here on)":
        "the lowest f from which the magnet hits the front constraint at every higher f of the sweep, provided "
        "some lower f does not impact ('-' when every f impacts). Impact windows below it are listed apart.",
    "period-1 with two impacts begins":
        "the first f of the longest run of period-1 responses (the Poincaré point repeats every drive period) "
        "with two impacts per period, searched at or above the first grazing.",
    "two impacts -> one impact per period":
        "the lowest f from which every higher f has exactly one impact per period ('-' when no f has two).",
    "onset of forward progression":
        "the lowest f from which every higher f has an average capsule velocity above 0.001 mm/s.",
}

_PROTOCOL_WORDS = {"rest": "every frequency from rest (zero state at phase 0)",
                   "up": "continuation: each frequency starts from the end state of the next lower one",
                   "down": "continuation: each frequency starts from the end state of the next higher one"}


def _fmt_hz(x: float) -> str:
    return "-" if not np.isfinite(x) else f"{x:.2f}"


def landmarks_markdown(lm: pd.DataFrame, parsed: list[tuple[str, str, str, pd.DataFrame, str]]) -> str:
    """Markdown report of the landmarks: title, what and where from, drive, protocol, definitions, tables.

    parsed: [(case label, figure, protocol, points table (with provenance), source folder)].
    """
    out = ["# Frequency landmarks of the vibro-impact sweeps beside seed 000 section 5.3", "",
           "What this is: the drive frequencies at which the response of the one-sided capsule prototype "
           "changes character, found by the frequency sweeps of `make study` (rule `dynamics_report`), beside the "
           "values that seed 000 section 5.3 reports for its Figs 17 and 18. Our numbers come from the sweep "
           "tables listed under *Sources* (`points.parquet`, one row per frequency); the paper's from the text of "
           "seed 000 section 5.3 (`PAPER_LANDMARKS` in `capsule_cli/steps/dynamics.py`). "
           "`docs/dynamics.md` discusses the differences. All data are simulated (no measurement).", "",
           "## Drive, model and protocol", ""]
    out += ["| case | friction (physical) | seed 000 figure | protocol | model | drive | frequencies | periods "
            "(transient + recorded) |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for label, fig, protocol, pts, _ in parsed:
        prov = pts.attrs.get("provenance", {})
        drv = prov.get("drive", {})
        f = np.sort(pts["value"].to_numpy())
        step = float(np.min(np.diff(f))) if len(f) > 1 else float("nan")
        wave = drv.get("waveform", "harmonic")
        amp = drv.get("amplitude_N")
        drive = ("harmonic P_d cos(2 pi f t)" if wave == "harmonic" else wave) + \
            (f", P_d = {amp * 1e3:g} mN" if amp is not None else "")
        out.append(f"| `{label}` | {plain(case_name(prov.get('friction'), label))} | Fig {fig[-2:]} | {protocol} | "
                   f"{prov.get('model_name', '?')} | {drive} | "
                   f"{f.min():g} to {f.max():g} Hz, step {step:.2g} Hz | "
                   f"{prov.get('transient_periods', '?')} + {prov.get('periods', '?')} |")
    out += ["", "Protocols: " + "; ".join(f"**{k}**: {v}" for k, v in _PROTOCOL_WORDS.items()
                                          if k in {p for _, _, p, _, _ in parsed}) + ". "
            "The response is multistable, so a landmark can differ between protocols (hysteresis).", "",
            "## Definitions", ""]
    out += [f"* **{k}**: {v}" for k, v in LANDMARK_DEFINITIONS.items()]
    out += ["* **found - paper**: our value minus the paper's; compare it with the sweep step (the grid "
            "resolution) and with the spread between protocols.", ""]
    for fig, title in (("fig17", "Seed 000 Fig 17 (P_d = 150 mN, low friction)"),
                       ("fig18", "Seed 000 Fig 18 (P_d = 150 mN, high friction)")):
        sub = lm[lm["case"].isin([lab for lab, fg, _, _, _ in parsed if fg == fig])]
        if sub.empty:
            continue
        out += [f"## {title}", "",
                "| friction | protocol | landmark | found [Hz] | paper [Hz] | found - paper [Hz] | sweep step [Hz] |",
                "| --- | --- | --- | --- | --- | --- | --- |"]
        for r in sub.itertuples():
            out.append(f"| {r.case_name} | {r.protocol} | {r.landmark} | {_fmt_hz(r.found_Hz)} | "
                       f"{_fmt_hz(r.paper_Hz)} | {_fmt_hz(r.difference_Hz)} | {_fmt_hz(r.resolution_Hz)} |")
        out += ["", "Where the paper's values come from: " + "; ".join(
            dict.fromkeys(f"{n}: {src}" for n, _, src in PAPER_LANDMARKS[fig])) + ".", ""]
    notes = []
    for label, fig, protocol, pts, _ in parsed:
        g = find_landmarks(pts)["first grazing (impacts from here on)"]
        w = impact_windows_below(pts, g)
        if w:
            name = plain(case_name(pts.attrs.get("provenance", {}).get("friction"), label))
            notes.append(f"* {name}, {protocol}: impacts also at " +
                         ", ".join(f"{a:g}-{b:g} Hz" if a != b else f"{a:g} Hz" for a, b in w) +
                         f", below the first grazing at {g:.2f} Hz (the friction holds the shell while the "
                         "spring stretches; docs/dynamics.md).")
    if notes:
        out += ["## Impacts below the first grazing", ""] + notes + [""]
    out += ["## Sources", ""] + [f"* `{label}` ({protocol}): `{src}/points.parquet`"
                                 for label, _, protocol, _, src in parsed] + [""]
    return "\n".join(out)


DUTY_MAP = TableSchema("dynamics_duty_map", "square-wave progression speed over (f, duty) (seed 004 Scenario 3)", (
    C("f_Hz", "float64", "drive frequency"),
    C("duty", "float64", "duty cycle D", unit=""),
    C("velocity_mm_s", "float64", "average capsule velocity"),
    C("impacts_per_period", "float64", "mean front impacts per period", unit=""),
    C("back_impacts_per_period", "float64", "mean back impacts per period", unit=""),
    C("period_number", "int64", "period of the response (0: none up to 8)", unit=""),
))


#: seed 004 section 6 (Scenario 3, FE model of the coated capsule, 1.2 N square wave)
PAPER_DUTY_BEST = (30.0, 0.2)
PAPER_DUTY_SOURCE = "seed 004 section 6: fastest at 30 Hz, duty 0.2; at 10 Hz the capsule vibrates in place"


def duty_map_summary(dm: pd.DataFrame) -> str:
    """Markdown: the map's fastest point and the lowest frequency's speeds beside seed 004 section 6."""
    best = dm.loc[dm["velocity_mm_s"].idxmax()]
    f_lo = dm["f_Hz"].min()
    lo = dm[dm["f_Hz"] == f_lo]["velocity_mm_s"]
    at_paper = dm[np.isclose(dm["f_Hz"], PAPER_DUTY_BEST[0]) & np.isclose(dm["duty"], PAPER_DUTY_BEST[1])]
    v_paper = f"{at_paper['velocity_mm_s'].iloc[0]:.3g} mm/s" if len(at_paper) else "not on the grid"
    rows = [
        "# Square-wave progression speed over frequency and duty cycle beside seed 004 section 6", "",
        "What this is: the average capsule velocity of the double-sided two-mass model (seed 002 Table 2) under a "
        "square-wave drive, over drive frequency f and duty cycle D, simulated by the duty sweeps of `make study` "
        "(rule `dynamics_report`; tables `duty/f*/points.parquet`, gathered in `duty_map.parquet` beside this "
        "file). The paper's values come from the text of seed 004 section 6 (a 3D FE model).", "",
        f"Grid: f = {', '.join(f'{x:g}' for x in sorted(dm['f_Hz'].unique()))} Hz; D from "
        f"{dm['duty'].min():.3g} to {dm['duty'].max():.3g} ({dm['duty'].nunique()} values).", "",
        "| quantity | this model | seed 004 (FE) |",
        "| --- | --- | --- |",
        f"| fastest (f, duty) | {best['f_Hz']:g} Hz, {best['duty']:.3g} ({best['velocity_mm_s']:.3g} mm/s) | "
        f"{PAPER_DUTY_BEST[0]:g} Hz, {PAPER_DUTY_BEST[1]:g} |",
        f"| speed at the paper's fastest point | {v_paper} | the fastest of its grid |",
        f"| speeds at {f_lo:g} Hz | {lo.min():.3g} to {lo.max():.3g} mm/s | "
        + ("about 0 (vibrates in place)" if np.isclose(f_lo, 10.0) else "not reported (at 10 Hz: about 0)") + " |",
    ]
    note = ("\nSource: " + PAPER_DUTY_SOURCE + ". The paper's numbers come from a 3D FE model of a coated, "
            "soft capsule in a compliant intestine; this map is the rigid-substrate two-mass model with the "
            "assumed gap split of configs/params/prototype_double_sided.yaml, so differences are expected.\n")
    return "\n".join(rows) + "\n" + note


def report(out: Path, sweeps: list[str], duty_sweeps: list[str], magnify: Path | None) -> list[Path]:
    """Write the landmark table and the figures of the dynamics study from sweep folders."""
    import pandas as pd
    import json

    from ..plots import dynamics as P
    from ..tables import read_table, write_text_atomic

    out = Path(out)
    written: list[Path] = []
    parsed = []
    for spec in sweeps:
        parts = spec.split(":", 3)
        if len(parts) != 4 or parts[1] not in PAPER_LANDMARKS:
            raise InputError(f"--sweep '{spec}': expected LABEL:FIGURE:PROTOCOL:DIR with FIGURE fig17 or fig18")
        label, fig, protocol, d = parts
        meta = json.loads((Path(d) / "sweep.json").read_text()) if (Path(d) / "sweep.json").is_file() else {}
        if meta and meta.get("parameter") != "f_Hz":
            raise InputError(f"{d}: not a frequency sweep (parameter {meta.get('parameter')})")
        parsed.append((label, fig, protocol, read_table(Path(d) / "points.parquet"),
                       read_table(Path(d) / "sweep.parquet"), d))
    if parsed:
        lm = landmark_table([(lab, fig, prot, pts) for lab, fig, prot, pts, _, _ in parsed])
        prov = provenance(sources=sweeps)
        written.append(write_table(lm, out / "landmarks.parquet", LANDMARKS, prov))
        written.append(write_text_atomic(out / "landmarks.md", landmarks_markdown(
            lm, [(lab, fig, prot, pts, d) for lab, fig, prot, pts, _, d in parsed])))
        short = {"first grazing (impacts from here on)": "grazing",
                 "period-1 with two impacts begins": "period-1, 2 impacts",
                 "two impacts -> one impact per period": "2→1 impacts",
                 "onset of forward progression": "forward"}
        for fig in ("fig17", "fig18"):
            for protocol in dict.fromkeys(p for _, fg, p, _, _, _ in parsed if fg == fig):
                cases = [(case_name(pts.attrs.get("provenance", {}).get("friction"), lab), pts, poin)
                         for lab, fg, prot, pts, poin, _ in parsed if fg == fig and prot == protocol]
                amps = sorted({pts.attrs.get("provenance", {}).get("drive", {}).get("amplitude_N") for _, pts, _ in cases}
                              - {None})
                amp = ", ".join(f"{a * 1e3:g}" for a in amps) or "?"
                title = f"Seed 000 Fig {fig[-2:]}: harmonic drive $P_d$ = {amp} mN, one-sided prototype (simulated)"
                written.append(P.bifurcation_figure(cases, protocol, title, out / f"{fig}_{protocol}.png",
                                                    {short[k]: hz for k, hz, _ in PAPER_LANDMARKS[fig]}))
    if duty_sweeps:
        rows = []
        protocols = set()
        for d in duty_sweeps:
            pts = read_table(Path(d) / "points.parquet")
            meta = json.loads((Path(d) / "sweep.json").read_text())
            if meta.get("parameter") != "duty":
                raise InputError(f"{d}: not a duty sweep (parameter {meta.get('parameter')})")
            protocols.add(meta.get("protocol"))
            rows.append(pd.DataFrame({"f_Hz": pts["f_Hz"], "duty": pts["value"], "velocity_mm_s": pts["velocity_mm_s"],
                                      "impacts_per_period": pts["impacts_per_period"],
                                      "back_impacts_per_period": pts["back_impacts_per_period"],
                                      "period_number": pts["period_number"]}))
        dm = pd.concat(rows, ignore_index=True).sort_values(["f_Hz", "duty"]).reset_index(drop=True)
        written.append(write_table(dm, out / "duty_map.parquet", DUTY_MAP, provenance(sources=duty_sweeps)))
        prot = "/".join(sorted(p for p in protocols if p))
        Pd = read_table(Path(duty_sweeps[0]) / "points.parquet").attrs["provenance"].get("drive", {}).get("amplitude_N")
        written.append(P.duty_map_figure(dm, f"Square wave $P_d$ = {Pd} N, double-sided model (seed 004 Scenario 3)\n"
                                         f"protocol: {prot} ({P.PROTOCOL_TEXT.get(prot, prot)})",
                                         out / "duty_map.png", paper_best=PAPER_DUTY_BEST))
        written.append(write_text_atomic(out / "duty_map.md", duty_map_summary(dm)))
    if magnify is not None:
        df = read_table(magnify)
        prot = df.attrs["provenance"].get("protocol", "?")
        written.append(P.magnify_figure(df, f"Magnification factor $A_f$ = max|$F_i$|/$P_d$ (seed 000 eq 24, Fig 19), one-sided prototype, simulated; protocol: {prot}",
                                        out / "magnify.png"))
    return written
