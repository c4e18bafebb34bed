"""The performance benchmark of contract section 6: the engine against scipy solve_ivp with events.

Runs (one process, one call): seed 000 Table 2 one-sided model, harmonic drive P_d = 0.15 N,
Coulomb P_f = 7.8 mN, frequencies in 5-40 Hz (impacting ones from 22 Hz up), all from rest.

* throughput on the same runs: for every frequency, ``baseline_periods`` periods from rest with
  every event recorded. The baseline is solve_ivp with the same events and mode switching
  (:mod:`.reference`) at ``baseline_rtol`` for RK45, DOP853, LSODA and Radau, its step capped
  at 1/16 of the fastest modal period (looser than the reference's 1/100: faster, and it may
  step over brief contacts); the fastest method is the baseline. The engine (:func:`.engine.run_core`, events and per-period records
  on, energy off) runs the identical runs, timed as the best of ``repeat`` calls; its
  long-run throughput (``engine_periods`` from rest) is reported too;
* accuracy: event times and phase-0 states of the engine over ``accuracy_periods`` from rest
  against solve_ivp DOP853 at rtol 1e-12 (atol 1e-15 m, 1e-12 m/s); average-velocity relative
  error on the period-1 runs: both integrators start from the engine's state after
  ``transient_periods`` and run ``velocity_periods`` periods.
"""
from __future__ import annotations

import math
import platform
import time

import numpy as np

from ..interrupts import compile_first, deferred_signals
from . import engine as E
from .model import STEADY_SETTLE_TOL, Drive, EngineOptions, friction_preset, load_model, pack_params
from .reference import ReferenceTimeout, reference_run
from .run import simulate
from .sweep import period_number

DEFAULT_FREQS = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0)
#: runs with dynamics effects: (effect names, parameters) on the one-sided base at the effects' start values
EFFECT_RUNS = ((("speed_dependent_friction",), {}), (("secondary_constraint",), {}), (("viscous_drag",), {}),
               (("tilt_friction",), {}), (("substrate_compliance",), {}),
               (("speed_dependent_friction", "viscous_drag", "tilt_friction", "secondary_constraint"), {}),
               (("substrate_compliance", "tilt_friction"), {}),
               (("speed_dependent_friction", "viscous_drag", "tilt_friction", "secondary_constraint",
                 "substrate_compliance"), {}))


def effect_bench(f_Hz: float = 30.0, amplitude_N: float = 0.15, periods: int = 500, accuracy_periods: int = 5,
                 repeat: int = 3) -> list[dict]:
    """Engine throughput and reference agreement of the runs with dynamics effects (EFFECT_RUNS).

    For each: periods per second from rest (events recorded, energy off, best of ``repeat``) and the
    max event-time error [s] against the tight solve_ivp reference over ``accuracy_periods``.
    """
    from .system import build_system

    out = []
    for names, prm in EFFECT_RUNS:
        sys_ = build_system("one_sided", prm, names)
        d = Drive(amplitude_N, f_Hz)
        fr = sys_.friction()
        te = _engine_time(sys_.model, d, fr, periods, repeat)
        eng = simulate(sys_.model, d, fr, periods=accuracy_periods, options=EngineOptions(energy=False))
        ref = reference_run(sys_.model, d, fr, accuracy_periods, method="DOP853", rtol=1e-12)
        ee = [(t, k) for t, k in zip(eng.events["time_s"], eng.events["kind"]) if not k.startswith("drive")]
        rr = [(t, k) for t, k in ref.events if not k.startswith("drive")]
        same = len(ee) == len(rr) and all(a[1] == b[1] for a, b in zip(ee, rr))
        err = max([abs(a[0] - b[0]) for a, b in zip(ee, rr)] or [0.0]) if same else math.inf
        out.append({"effects": list(names), "f_Hz": f_Hz, "periods_per_s": periods / te,
                    "events_compared": len(ee), "event_sequence_matches": same, "event_time_error_s": err})
    return out


def _engine_time(model, drive, fr, periods, repeat=5, events=False):
    """Best wall time [s] of ``repeat`` engine runs of ``periods`` periods from rest (events recorded).

    With ``events``, return (time [s], number of events of the run) instead."""
    opts = EngineOptions(energy=False).pack()
    p = pack_params(model, drive, fr)
    best = math.inf
    nev = 0
    compile_first(E.run_core, p, opts, np.zeros(4), 0, int(periods), 1.0, 0, -1)
    for _ in range(repeat):
        with deferred_signals():  # a Ctrl-C: KeyboardInterrupt once the run returns, not a SystemError
            t = time.perf_counter()
            r = E.run_core(p, opts, np.zeros(4), 0, int(periods), 1.0, 0, -1)
            best = min(best, time.perf_counter() - t)
        status, nev = r[0], int(r[5])
        if status != E.STATUS_OK:
            raise RuntimeError(f"engine status {status} in the benchmark at f = {drive.frequency_Hz} Hz")
    return (best, nev) if events else best


def run_bench(freqs=DEFAULT_FREQS, amplitude_N: float = 0.15, Pf_N: float = 0.0078,
              engine_periods: int = 2000, baseline_periods: int = 60, accuracy_periods: int = 5,
              transient_periods: int = 300, velocity_periods: int = 10,
              methods=("RK45", "DOP853", "LSODA", "Radau"), baseline_rtol: float = 1e-8, repeat: int = 5,
              baseline_steps_per_period: float = 16.0, baseline_repeat: int = 2) -> dict:
    """Return the benchmark record (a JSON-ready dict)."""
    model, _ = load_model("prototype_one_sided")
    fr = friction_preset("coulomb", Pf_N)
    # warm up (compile / load the cache) outside the timings
    simulate(model, Drive(amplitude_N, 30.0), fr, periods=2)
    per_f = []
    tot_eng_t = tot_eng_p = 0.0
    tot_ev = 0
    imp_eng_t = imp_eng_p = 0.0
    long_t = long_p = 0.0
    base = {m: [0.0, 0, 0.0, 0] for m in methods}  # total time, periods, impacting time, impacting periods
    max_ev_err = 0.0
    max_state = 0.0
    max_pos = 0.0
    max_vel = 0.0
    base_ev_err = {m: 0.0 for m in methods}
    vel_errs = []
    for f in freqs:
        d = Drive(amplitude_N, float(f))
        te, nev = _engine_time(model, d, fr, baseline_periods, repeat, events=True)  # the baseline's runs
        tot_ev += nev
        te_long = _engine_time(model, d, fr, engine_periods, 1)
        probe = simulate(model, d, fr, periods=50, transient_periods=transient_periods,
                         options=EngineOptions(energy=False))
        impacting = bool(probe.periods["impacts"].sum() > 0)
        pn = period_number(probe.periods["relative_mm"].to_numpy() * 1e-3,
                           probe.periods["relative_velocity_mm_s"].to_numpy() * 1e-3)
        tot_eng_t += te
        tot_eng_p += baseline_periods
        long_t += te_long
        long_p += engine_periods
        if impacting:
            imp_eng_t += te
            imp_eng_p += baseline_periods
        row = {"f_Hz": f, "impacting": impacting, "period_number": pn,
               "engine_periods_per_s": baseline_periods / te, "engine_long_run_periods_per_s": engine_periods / te_long}
        # accuracy against the tight reference, from rest
        eng = simulate(model, d, fr, periods=accuracy_periods, options=EngineOptions(energy=False))
        ref = reference_run(model, d, fr, accuracy_periods, method="DOP853", rtol=1e-12)
        ee = [(t, k) for t, k in zip(eng.events["time_s"], eng.events["kind"]) if not k.startswith("drive")]
        rr = [(t, k) for t, k in ref.events if not k.startswith("drive")]
        same = len(ee) == len(rr) and all(a[1] == b[1] for a, b in zip(ee, rr))
        ev_err = max([abs(a[0] - b[0]) for a, b in zip(ee, rr)] or [0.0]) if same else math.inf
        P = ref.poincare
        e_states = np.column_stack([eng.periods["relative_mm"] * 1e-3, eng.periods["relative_velocity_mm_s"] * 1e-3,
                                    eng.periods["capsule_mm"] * 1e-3, eng.periods["capsule_velocity_mm_s"] * 1e-3])
        r_states = np.column_stack([P[:-1, 0] - P[:-1, 1], P[:-1, 2] - P[:-1, 3], P[:-1, 1], P[:-1, 3]])
        fin = eng.final_state
        e_states = np.vstack([e_states, [fin[0], fin[1], fin[2], fin[3]]])
        r_states = np.vstack([r_states, [P[-1, 0] - P[-1, 1], P[-1, 2] - P[-1, 3], P[-1, 1], P[-1, 3]]])
        xs = model.gap_m
        vs = xs * 2 * math.pi * f
        dpos = float(np.max(np.abs(e_states[:, [0, 2]] - r_states[:, [0, 2]])))
        dvel = float(np.max(np.abs(e_states[:, [1, 3]] - r_states[:, [1, 3]])))
        max_pos = max(max_pos, dpos)
        max_vel = max(max_vel, dvel)
        max_state = max(max_state, dpos / xs, dvel / vs)
        max_ev_err = max(max_ev_err, ev_err)
        row.update({"events_compared": len(ee), "event_sequence_matches": same, "event_time_error_s": ev_err,
                    "position_error_m": dpos, "velocity_error_m_s": dvel})
        # baseline timings
        for m in methods:
            tb = math.inf
            for _ in range(max(1, int(baseline_repeat))):  # best of baseline_repeat
                t = time.perf_counter()
                b = reference_run(model, d, fr, baseline_periods, method=m, rtol=baseline_rtol,
                                  atol=np.array([1e-11, 1e-11, 1e-8, 1e-8]),
                                  steps_per_period=baseline_steps_per_period)
                tb = min(tb, time.perf_counter() - t)
            base[m][0] += tb
            base[m][1] += baseline_periods
            if impacting:
                base[m][2] += tb
                base[m][3] += baseline_periods
            row[f"{m}_periods_per_s"] = baseline_periods / tb
            bb = [(t_, k) for t_, k in b.events if not k.startswith("drive")]
            n = min(len(bb), len(rr))
            k_ok = all(bb[i][1] == rr[i][1] for i in range(n))
            if n and k_ok:
                # baseline ran more periods than the reference: compare the common prefix
                rr_ = rr[:n]
                base_ev_err[m] = max(base_ev_err[m], max(abs(bb[i][0] - rr_[i][0]) for i in range(n)))
        # average velocity on period-1 runs
        if pn == 1 and impacting:
            st = probe.final_state
            s0 = [st[0], st[1], 0.0, st[3]]
            ev = simulate(model, d, fr, periods=velocity_periods, state0=s0, options=EngineOptions(energy=False))
            rf = reference_run(model, d, fr, velocity_periods, state0=s0, method="DOP853", rtol=1e-12)
            v_eng = ev.final_state[2] / (velocity_periods / f)
            v_ref = rf.poincare[-1, 1] / (velocity_periods / f)
            rel = abs(v_eng - v_ref) / abs(v_ref) if v_ref != 0 else math.inf
            vel_errs.append(rel)
            row.update({"velocity_mm_s": v_eng * 1e3, "velocity_ref_mm_s": v_ref * 1e3, "velocity_rel_error": rel})
        per_f.append(row)
    best = max(methods, key=lambda m: base[m][1] / base[m][0])
    best_imp = max(methods, key=lambda m: (base[m][3] / base[m][2]) if base[m][2] > 0 else 0.0)
    eng_pps = tot_eng_p / tot_eng_t
    base_pps = base[best][1] / base[best][0]
    eng_imp = imp_eng_p / imp_eng_t if imp_eng_t else float("nan")
    base_imp = base[best_imp][3] / base[best_imp][2] if base[best_imp][2] else float("nan")
    return {
        "benchmark": "vibro-impact engine vs scipy.integrate.solve_ivp with events",
        "model": "seed 000 Table 2 one-sided (configs/params/prototype_one_sided.yaml)",
        "drive": {"waveform": "harmonic", "Pd_N": amplitude_N, "f_Hz": list(freqs)},
        "friction": {"kind": "coulomb", "Pf_N": Pf_N},
        "periods_per_s": eng_pps,
        "periods_per_s_note": f"engine on the baseline's runs ({baseline_periods} periods from rest per frequency, "
                              f"best of {repeat})",
        "long_run_periods_per_s": long_p / long_t,
        "us_per_period": 1e6 * tot_eng_t / tot_eng_p,
        "us_per_event": 1e6 * tot_eng_t / tot_ev if tot_ev else None,
        "us_note": "engine wall time on the baseline's runs (events recorded) per period and per event "
                   "(contacts, stick/slip, drive switches), best of repeat",
        "events": tot_ev,
        "baseline_repeat": baseline_repeat,
        "baseline_periods_per_s": base_pps,
        "baseline_method": best,
        "baseline_rtol": baseline_rtol,
        "baseline_steps_per_modal_period": baseline_steps_per_period,
        "speedup": eng_pps / base_pps,
        "impacting_periods_per_s": eng_imp,
        "impacting_baseline_periods_per_s": base_imp,
        "impacting_baseline_method": best_imp,
        "impacting_speedup": eng_imp / base_imp,
        "baseline_methods_periods_per_s": {m: base[m][1] / base[m][0] for m in methods},
        "baseline_max_event_time_error_s": base_ev_err,
        "max_event_time_error_s": max_ev_err,
        "max_state_error": max_state,
        "max_state_error_note": "max over phase-0 states of |engine - reference| / scale, scales G_1 (positions) "
                                "and G_1 2 pi f (velocities)",
        "max_position_error_m": max_pos,
        "max_velocity_error_m_s": max_vel,
        "reference": "solve_ivp DOP853 rtol 1e-12 atol [1e-15 m, 1e-15 m, 1e-12 m/s, 1e-12 m/s], steps capped at "
                     "1/100 of the fastest modal period, same events",
        "accuracy_periods": accuracy_periods,
        "period1_velocity_max_rel_error": max(vel_errs) if vel_errs else None,
        "period1_runs": len(vel_errs),
        "engine_periods": engine_periods,
        "baseline_periods": baseline_periods,
        "per_frequency": per_f,
        "effects": effect_bench(amplitude_N=amplitude_N, repeat=repeat),
        "machine": {"python": platform.python_version(), "processor": platform.processor() or platform.machine()},
    }


# ---------------------------------------------------------------------------
# seed 000 Fig 19 set (contract section 6: `capsule-cli bench --fig19 --json`)


#: wall-time budget [s] of each solve_ivp sample run of ``bench --fig19``: past it the run stops and the
#: ratio is reported as a lower bound (some stick-slip points make solve_ivp crawl for minutes)
FIG19_SAMPLE_BUDGET_S = 10.0


def run_fig19_bench(Pd_num: int | None = None, f_num: int | None = None, frictions=None,
                    sample_periods: int = 20, sample_method: str = "RK45", baseline_rtol: float = 1e-8,
                    baseline_steps_per_period: float = 16.0, progress=None,
                    sample_budget_s: float = FIG19_SAMPLE_BUDGET_S) -> dict:
    """Time the Fig 19 maps (configs/bench/fig19.yaml) friction by friction; return a JSON-ready dict.

    ``Pd_num`` x ``f_num`` (default: the config's 100 x 100) sets the grid actually run; a smaller
    grid measures a subset of the same P_d and f ranges and ``fig19_wall_s_extrapolated`` scales
    its wall time to the full grid by the number of points (an estimate: say so when quoting it).
    Ratio to solve_ivp: per friction, one sample point (the grid centre) run ``sample_periods``
    periods from rest by the engine (best of 3) and by solve_ivp (``sample_method``, rtol
    ``baseline_rtol``, steps capped at 1/``baseline_steps_per_period`` of the fastest modal period).
    A solve_ivp run that passes ``sample_budget_s`` of wall time is stopped: its record then says
    ``solve_ivp_timed_out`` and its ratio is a lower bound (the budget over the engine's time).
    """
    from ..steps.dynamics import load_fig19, magnify_arrays, magnify_friction

    cfg = load_fig19()
    model, _ = load_model(cfg["model"])
    n_Pd = int(Pd_num or cfg["Pd_num"])
    n_f = int(f_num or cfg["f_num"])
    Pd = np.linspace(cfg["Pd_start_N"], cfg["Pd_stop_N"], n_Pd)
    f = np.linspace(cfg["f_start_Hz"], cfg["f_stop_Hz"], n_f)
    nt, nr = int(cfg["transient_periods"]), int(cfg["recorded_periods"])
    specs = list(frictions or cfg["frictions"])
    rk_rtol = float(cfg["rk_rtol"])  # the maps' tolerance of the speed-law panels' adaptive segment
    settle_tol = STEADY_SETTLE_TOL  # the maps' settled-transient test (magnify's default)
    # warm up: load (or compile) the engine outside the timings
    magnify_arrays(model, Pd[:1], f[:2], friction_preset("coulomb", 0.007), cfg["protocol"], 2, 1)
    per_fr = {}
    peaks = {}
    sample = {}
    total = 0.0
    for spec in specs:
        label, fr, _ = magnify_friction(spec)
        t0 = time.perf_counter()
        a = magnify_arrays(model, Pd, f, fr, cfg["protocol"], nt, nr, progress=progress, rk_rtol=rk_rtol,
                           settle_tol=settle_tol)
        per_fr[label] = time.perf_counter() - t0
        total += per_fr[label]
        i, j = np.unravel_index(np.nanargmax(a["Af"]), a["Af"].shape)
        peaks[label] = {"max_Af": float(a["Af"][i, j]), "Pd_N": float(Pd[i]), "f_Hz": float(f[j])}
        # sample point against solve_ivp, same periods from rest
        d = Drive(float(Pd[n_Pd // 2]), float(f[n_f // 2]))
        te = _engine_time(model, d, fr, sample_periods, repeat=3)
        tb = math.inf
        timed_out = False
        for _ in range(2):
            t1 = time.perf_counter()
            try:
                reference_run(model, d, fr, sample_periods, method=sample_method, rtol=baseline_rtol,
                              atol=np.array([1e-11, 1e-11, 1e-8, 1e-8]), steps_per_period=baseline_steps_per_period,
                              max_wall_s=sample_budget_s)
            except ReferenceTimeout:
                timed_out = True
                tb = sample_budget_s
                break
            tb = min(tb, time.perf_counter() - t1)
        sample[label] = {"Pd_N": d.amplitude_N, "f_Hz": d.frequency_Hz, "engine_s": te, "solve_ivp_s": tb,
                         "solve_ivp_over_engine": tb / te, "solve_ivp_timed_out": timed_out}
    n_points = n_Pd * n_f * len(specs)
    full_points = int(cfg["Pd_num"]) * int(cfg["f_num"]) * len(cfg["frictions"])
    periods_total = n_points * (nt + nr)
    import numba

    return {
        "benchmark": "seed 000 Fig 19 magnification maps (configs/bench/fig19.yaml), protocol "
                     f"{cfg['protocol']}, {nt} transient + {nr} recorded periods per point",
        "grid": {"Pd_num": n_Pd, "f_num": n_f, "frictions": [magnify_friction(s)[0] for s in specs],
                 "full_grid": n_Pd == int(cfg["Pd_num"]) and n_f == int(cfg["f_num"])
                 and len(specs) == len(cfg["frictions"])},
        "fig19_wall_s": total,
        "fig19_periods_per_s": periods_total / total,
        "fig19_periods_per_s_note": "periods of the maps (transient + recorded per point) per second of wall time; "
                                    "transient periods skipped once a point has settled on a periodic orbit "
                                    "(settle_tol) count as run",
        "fig19_wall_s_extrapolated": total * full_points / n_points,
        "fig19_wall_s_extrapolated_note": "wall time of the run grid scaled by points to the full "
                                          f"{cfg['Pd_num']} x {cfg['f_num']} x {len(cfg['frictions'])} set",
        "wall_us_per_period": 1e6 * total / periods_total,
        "wall_us_per_period_note": "wall time over all threads per simulated period (not per-core engine time)",
        "wall_s_per_friction": per_fr,
        "max_Af_per_friction": peaks,
        "solve_ivp_sample": sample,
        "solve_ivp_sample_method": f"{sample_method} rtol {baseline_rtol}, {sample_periods} periods from rest, "
                                   f"steps capped at 1/{baseline_steps_per_period:g} of the fastest modal period; "
                                   "engine best of 3, solve_ivp best of 2; a solve_ivp run past "
                                   f"{sample_budget_s:g} s is stopped (solve_ivp_timed_out: its solve_ivp_s is "
                                   "that budget and its ratio a lower bound)",
        "solve_ivp_over_engine_median": float(np.median([v["solve_ivp_over_engine"] for v in sample.values()])),
        "solve_ivp_over_engine_median_note": "over the frictions' samples; a timed-out sample enters with its lower bound",
        "rk_rtol": rk_rtol,
        "rk_rtol_note": "relative tolerance of the adaptive (speed-law) segment in the maps, configs/bench/fig19.yaml",
        "settle_tol": settle_tol,
        "settle_tol_note": "settled-transient tolerance of the maps (magnify's default, STEADY_SETTLE_TOL; 0: every "
                           "transient period run)",
        "threads": int(numba.get_num_threads()),
        "machine": {"python": platform.python_version(), "processor": platform.processor() or platform.machine()},
    }


def run_startup_bench(repeat: int = 7) -> dict:
    """Start-up wall times [s] of `capsule-cli --help` and a warm 20-period `simulate` (issue 13 item 5).

    Each is the median of ``repeat`` fresh subprocesses (``python -m capsule_cli``, the environment
    as given: with PYTHONDONTWRITEBYTECODE set, the package's modules are compiled on every start);
    one simulate runs first to warm the engine's on-disk cache. Also reports min and max.
    """
    import os
    import statistics
    import subprocess
    import sys
    import tempfile

    def times(args):
        out = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "capsule_cli", *args], check=True, capture_output=True)
            out.append(time.perf_counter() - t0)
        return out

    with tempfile.TemporaryDirectory() as tmp:
        sim = ["simulate", "--quiet", "--out", f"{tmp}/sim", "--periods", "20"]
        subprocess.run([sys.executable, "-m", "capsule_cli", *sim], check=True, capture_output=True)  # warm cache
        th = times(["--help"])
        ts = times(sim)
    return {"help_s": statistics.median(th), "simulate_20_periods_s": statistics.median(ts),
            "help_s_min_max": [min(th), max(th)], "simulate_20_periods_s_min_max": [min(ts), max(ts)],
            "target_s": 1.0, "repeat": repeat,
            "pythondontwritebytecode": bool(os.environ.get("PYTHONDONTWRITEBYTECODE")),
            "note": f"median of {repeat} fresh processes each; `simulate --out DIR --periods 20` (default "
                    "trajectory sampling, all tables and summary.json written); the engine cache warmed first"}
