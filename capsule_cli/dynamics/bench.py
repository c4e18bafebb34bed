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

from . import engine as E
from .model import Drive, EngineOptions, friction_preset, load_model, pack_params
from .reference import reference_run
from .run import simulate
from .sweep import period_number

DEFAULT_FREQS = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0)
#: runs with dynamics effects: (effect names, parameters) on the one-sided base at the effects' start values
EFFECT_RUNS = ((("speed_dependent_friction",), {}), (("secondary_constraint",), {}), (("viscous_drag",), {}),
               (("tilt_friction",), {}), (("substrate_compliance",), {}),
               (("speed_dependent_friction", "viscous_drag", "tilt_friction", "secondary_constraint"), {}))


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


def _engine_time(model, drive, fr, periods, repeat=5):
    """Best wall time [s] of ``repeat`` engine runs of ``periods`` periods from rest (events recorded)."""
    opts = EngineOptions(energy=False).pack()
    p = pack_params(model, drive, fr)
    best = math.inf
    for _ in range(repeat):
        t = time.perf_counter()
        status = E.run_core(p, opts, np.zeros(4), 0, int(periods), 1.0, 0, -1)[0]
        best = min(best, time.perf_counter() - t)
        if status != E.STATUS_OK:
            raise RuntimeError(f"engine status {status} in the benchmark at f = {drive.frequency_Hz} Hz")
    return best


def run_bench(freqs=DEFAULT_FREQS, amplitude_N: float = 0.15, Pf_N: float = 0.0078,
              engine_periods: int = 2000, baseline_periods: int = 60, accuracy_periods: int = 5,
              transient_periods: int = 300, velocity_periods: int = 10,
              methods=("RK45", "DOP853", "LSODA", "Radau"), baseline_rtol: float = 1e-8, repeat: int = 5,
              baseline_steps_per_period: float = 16.0) -> dict:
    """Return the benchmark record (a JSON-ready dict)."""
    model, _ = load_model("prototype_one_sided")
    fr = friction_preset("coulomb", Pf_N)
    # warm up (compile / load the cache) outside the timings
    simulate(model, Drive(amplitude_N, 30.0), fr, periods=2)
    per_f = []
    tot_eng_t = tot_eng_p = 0.0
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
        te = _engine_time(model, d, fr, baseline_periods, repeat)  # the baseline's runs
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
            t = time.perf_counter()
            b = reference_run(model, d, fr, baseline_periods, method=m, rtol=baseline_rtol,
                              atol=np.array([1e-11, 1e-11, 1e-8, 1e-8]), steps_per_period=baseline_steps_per_period)
            tb = time.perf_counter() - t
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
