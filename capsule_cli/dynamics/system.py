"""A dynamics model as a system the loop can run: base + effects -> progression and trajectories.

PROVISIONAL (issue 12): this file implements, on today's engine, the interface that
issue 9 implements on the opened engine; at merge the lead takes issue 9's version.
It holds no loop logic.

* :class:`Protocol` -- how each condition was run (contract section 4 ``protocol``);
* :func:`build_system` -- base ``one_sided``/``double_sided`` (seed 000 eqs 19-21; seed 001
  App. A) from ``configs/params/prototype_*.yaml``, overridden by model-file parameters, with
  the dynamics effects of physics.md section 3 that today's engine can express:
  ``speed_dependent_friction`` (the engine's speed law, P_f + a V^n: seed 000 eqs 22-23 with
  b = P_f, well posed as physics.md section 3 says) and ``secondary_constraint`` (the engine's
  backward constraint, seed 001 App. A). ``viscous_drag``, ``substrate_compliance`` and
  ``tilt_friction`` raise NotImplementedError here. A plugin effect of a dynamics kind is a
  *drive transform* here: ``apply(drive, x, p, ctx) -> drive`` with ``drive = {"f": Hz array,
  "Pd": N array}`` per condition (issue 9 item 4, first sort).
* :func:`progression` -- average progression velocity, impacts and response class per condition;
* :func:`trajectory` -- capsule and magnet positions at given times from rest at drive phase 0.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from ..config import load_param_set
from ..units import to_si
from . import engine as E
from .model import BASE_PARAM_SETS, MODEL_PARAM_NAMES, CapsuleModel, Drive, EngineOptions, Friction, pack_params
from .run import check_status, simulate
from .sweep import period_number

#: response classes (contract section 2, diagnose)
RESPONSE_CLASSES = ("no_impact", "one_impact", "multi_impact", "irregular")
#: effects today's engine cannot express (issue 9 adds them)
UNAVAILABLE = ("viscous_drag", "substrate_compliance", "tilt_friction")
BUILTIN = ("speed_dependent_friction", "secondary_constraint") + UNAVAILABLE
N_WINDOWS = 4
#: Poincare points closer than this fraction of their spread count as repeating (period detection):
#: loose enough that a slowly decaying transient after a short transient run is not called irregular
PERIOD_REL_TOL = 1e-3
#: relative tolerance of the adaptive (speed-law) slip segments in loop runs: far below any measurement
#: noise of a progression speed or a camera position; the exact (linear) segments are unaffected
LOOP_RK_RTOL = 1e-8


@dataclass(frozen=True)
class Protocol:
    """How each condition was run (contract section 4 ``protocol``).

    start : 'rest' (every condition from rest), 'up' or 'down' (continuation in f at each amplitude)
    transient_periods : drive periods run first and not recorded [-]
    recorded_periods : drive periods over which the average velocity is taken [-]
    """

    start: str = "rest"
    transient_periods: int = 120
    recorded_periods: int = 60


@dataclass(frozen=True)
class DynSystem:
    """A dynamics model ready to run: capsule, shell friction, and drive transforms (plugins)."""

    base: str
    model: CapsuleModel
    friction: Friction
    effects: tuple[str, ...] = ()
    transforms: tuple = field(default=())  # ((Effect, {key: SI}), ...)


@lru_cache(maxsize=8)
def _param_set(name: str) -> tuple[tuple[str, float], ...]:
    """Return a configs/params set as ((name, value), ...), read once per process."""
    return tuple((k, float(v)) for k, v in load_param_set(name).items())


def build_system(base: str, params: Mapping[str, float], effects: Sequence[str] = ()) -> DynSystem:
    """Return the system of a base model (``one_sided``/``double_sided``) with ``effects`` switched on.

    ``params`` are model-file names with unit suffix (``Pf_N``, ``gap_mm``, ``a_mN`` ...);
    missing ones come from the base's parameter set in ``configs/params``.
    speed_dependent_friction: kinetic level P_f + a |V|^n (V in mm/s, F in mN; seed 000 eqs 22-23
    with b = P_f), breakaway max(P_f, law at 0+), law held below V_min (physics.md section 3;
    V_min from ``configs/params/friction_laws_dynamics.yaml``). secondary_constraint: the backward
    constraint k_b (X_r + G_2) + c_b V_r at X_r <= -G_2 (seed 001 App. A). Off values give the base.
    """
    if base not in BASE_PARAM_SETS:
        raise ValueError(f"unknown dynamics base '{base}' (one of {', '.join(BASE_PARAM_SETS)})")
    for name in effects:
        if name in UNAVAILABLE:
            raise NotImplementedError(f"effect '{name}' needs the opened engine (issue 9); "
                                      "today's engine cannot simulate it")
    merged = dict(_param_set(BASE_PARAM_SETS[base]))
    merged.update({k: float(v) for k, v in params.items()})
    pf = float(merged.pop("Pf_N"))
    kw = {k: v for k, v in merged.items() if k in MODEL_PARAM_NAMES}
    double = base == "double_sided"
    if "secondary_constraint" in effects:
        on = kw.get("constraint_back_N_m", 0.0) > 0 or kw.get("constraint_back_damping_Ns_m", 0.0) > 0
        double = double or on
    if not double:
        for k in ("gap_back_mm", "constraint_back_N_m", "constraint_back_damping_Ns_m"):
            kw.pop(k, None)
    model = CapsuleModel.from_params(kw, double_sided=double, where=f"{base} model")
    if "speed_dependent_friction" in effects and float(merged.get("a_mN", 0.0)) != 0.0:
        vmin = dict(_param_set("friction_laws_dynamics"))["v_min_mm_s"]
        fr = Friction(kind="law", static_N=pf, a_mN=float(merged["a_mN"]), n=float(merged.get("n", 0.25)),
                      b_mN=pf * 1e3, v_min_mm_s=vmin)
    elif math.isinf(pf):
        fr = Friction(kind="fixed")
    else:
        fr = Friction(kind="coulomb", level_N=pf)
    fr.validate()
    transforms = []
    others = [e for e in effects if e not in BUILTIN]
    if others:
        from ..effects.registry import get_effect
        for name in others:
            eff = get_effect("progression", name)
            p = {prm.key: float(to_si(float(merged.get(prm.name, prm.start)), prm.name)) for prm in eff.params}
            transforms.append((eff, p))
    return DynSystem(base, model, fr, tuple(effects), tuple(transforms))


def _drives(system: DynSystem, f_Hz, Pd_N, duty, waveform) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    f = np.atleast_1d(np.asarray(f_Hz, float))
    pd_ = np.broadcast_to(np.asarray(Pd_N, float), f.shape).copy()
    f = f.copy()
    du = np.broadcast_to(np.asarray(0.5 if duty is None else duty, float), f.shape)
    wf = np.broadcast_to(np.asarray(waveform, dtype=object), f.shape)
    if system.transforms:
        drive = {"f": f, "Pd": pd_}
        x = {"f": f.copy(), "Pd": pd_.copy(), "duty": du}
        for eff, p in system.transforms:
            drive = eff.apply(drive, x, p, {"model": system.model})
        f = np.asarray(drive["f"], float) * np.ones_like(f)
        pd_ = np.asarray(drive["Pd"], float) * np.ones_like(f)
        if not (np.all(np.isfinite(f)) and np.all(np.isfinite(pd_))):
            raise ValueError("a plugin drive transform returned a non-finite drive")
    return f, pd_, du, wf


def _summary(per: np.ndarray, f: float) -> dict:
    n = per.shape[0]
    T = 1.0 / f
    disp = per[:, E.P_DISP]
    pn = period_number(per[:, E.P_XR0], per[:, E.P_VR0], rel_tol=PERIOD_REL_TOL)
    imp = float((per[:, E.P_NFRONT] + per[:, E.P_NBACK]).mean())
    # windows of whole response periods (period_number), so a periodic response has SD ~ 0
    m = max(pn, 1)
    size = (n // N_WINDOWS) // m * m
    w = [disp[i * size:(i + 1) * size] for i in range(N_WINDOWS)] if size > 0 else [disp]
    wv = np.array([x.sum() / (x.size * T) for x in w]) * 1e3
    if pn == 0:
        cls = "irregular"
    elif imp == 0:
        cls = "no_impact"
    elif imp <= 1.0 + 1e-9:
        cls = "one_impact"
    else:
        cls = "multi_impact"
    return {"velocity_mm_s": float(disp.sum() / (n * T) * 1e3), "impacts_per_period": imp,
            "period_number": int(pn), "response_class": cls,
            "window_sd_mm_s": float(np.std(wv, ddof=1)) if wv.size > 1 else 0.0}


def progression(system: DynSystem, f_Hz, Pd_N, duty=None, waveform="harmonic",
                protocol: Protocol = Protocol()) -> pd.DataFrame:
    """Return one row per condition (input order): velocity_mm_s [mm/s], impacts_per_period [-]
    (front + back), period_number (1..8, 0 irregular), response_class (no_impact: none;
    one_impact: at most one per period; multi_impact: more; irregular: no period <= 8),
    window_sd_mm_s (SD of the average velocity over the recorded periods split into 4 windows).

    protocol.start 'rest': every condition from rest (run in parallel); 'up'/'down':
    continuation in f within each (P_d, duty, waveform), each condition starting from the
    previous one's end state (x_r, v_r, V_c; X_c reset), physics.md section 3.
    """
    f, pdn, du, wf = _drives(system, f_Hz, Pd_N, duty, waveform)
    n = f.size
    setups = [Drive(float(pdn[i]), float(f[i]), str(wf[i]), float(du[i])).validate() for i in range(n)]
    P = np.stack([pack_params(system.model, d, system.friction) for d in setups])
    opts = EngineOptions(energy=False, rk_rtol=LOOP_RK_RTOL).pack()
    ntr, nrec = int(protocol.transient_periods), int(protocol.recorded_periods)
    if protocol.start == "rest":
        st, per, _, _ = E.run_many(P, opts, np.zeros((n, 4)), ntr, nrec)
        for i in range(n):
            check_status(int(st[i]), float("nan"), system.friction, f"condition f = {f[i]:g} Hz, Pd = {pdn[i]:g} N")
        results = [per[i] for i in range(n)]
    elif protocol.start in ("up", "down"):
        results = [None] * n
        keys = pd.DataFrame({"Pd": pdn, "duty": du, "wf": wf.astype(str)}).groupby(["Pd", "duty", "wf"]).indices
        for idx in keys.values():
            order = idx[np.argsort(f[idx] * (1 if protocol.start == "up" else -1), kind="stable")]
            state = np.zeros(4)
            for i in order:
                st, st_t, _, _, _, _, per, _, fin = E.run_core(P[i], opts, state, ntr, nrec, 1.0, 0, 0)
                check_status(int(st), float(st_t), system.friction, f"condition f = {f[i]:g} Hz, Pd = {pdn[i]:g} N")
                results[i] = per
                state = np.array([fin[0], fin[1], 0.0, fin[3]])
    else:
        raise ValueError(f"unknown protocol start '{protocol.start}' (rest, up, down)")
    return pd.DataFrame([_summary(results[i], float(f[i])) for i in range(n)])


def trajectory(system: DynSystem, f_Hz: float, Pd_N: float, time_s, duty=None, waveform="harmonic") -> dict:
    """Return ``{'capsule_mm': array, 'magnet_mm': array}`` [mm] at ``time_s`` [s], from rest at drive
    phase 0 (F = P_d cos 2 pi f t). Samples on the grid of the smallest time step, interpolated."""
    t = np.asarray(time_s, float)
    f, pdn, du, wf = _drives(system, [f_Hz], [Pd_N], duty, waveform)
    d = Drive(float(pdn[0]), float(f[0]), str(wf[0]), float(du[0])).validate()
    tmax = float(t.max()) if t.size else 0.0
    steps = np.diff(np.unique(t))
    dt = float(steps.min()) if steps.size else max(tmax, 1e-3)
    periods = int(math.ceil(tmax * d.frequency_Hz + 1e-9)) + 1
    res = simulate(system.model, d, system.friction, periods=periods, transient_periods=0,
                   sample_rate_Hz=1.0 / dt, options=EngineOptions(energy=False, rk_rtol=LOOP_RK_RTOL), record_events=False)
    tr = res.trajectory
    ts = tr["time_s"].to_numpy()
    return {"capsule_mm": np.interp(t, ts, tr["capsule_mm"].to_numpy()),
            "magnet_mm": np.interp(t, ts, tr["magnet_mm"].to_numpy())}


def with_protocol(protocol: Protocol, **changes) -> Protocol:
    """Return a copy of ``protocol`` with fields changed."""
    return replace(protocol, **changes)
