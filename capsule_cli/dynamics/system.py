"""A dynamics model as data: base prototype + dynamics effects, and the two measurement predictions.

The interface of the dynamics loop (contract section 4, kinds ``progression`` and ``trajectory``):

* :func:`build_system` turns a base (``one_sided`` seed 000 eqs 19-21; ``double_sided`` seed 001
  App. A) with model-file parameters and a list of dynamics effects (physics.md section 3,
  "Dynamics effects"; registered in :mod:`capsule_cli.effects.dynamics`) into a :class:`DynSystem`;
* :func:`progression` runs each condition (f, P_d, duty) with a :class:`Protocol` and returns the
  average shell velocity and the response class;
* :func:`trajectory` samples the capsule and magnet displacements from rest at given times.

Effects that change the equations of motion combine by adding their terms to the forces (their
order in a model file does not matter); each one's ``off`` values give the base model exactly.
Parameter values are in the unit of their name's suffix (``gap_mm`` in mm); SI inside.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

import numpy as np

from ..config import load_param_set
from ..errors import InputError, PluginError
from ..interrupts import deferred_call
from . import engine as E
from .model import (BASE_PARAM_SETS, MODEL_PARAM_NAMES, STEADY_SETTLE_TOL, CapsuleModel, Drive, EngineOptions,
                    Friction, friction_preset, pack_params)
from .parallel import period_numbers, run_many
from .run import check_status

#: parameters every dynamics base takes (contract section 4 table); the double-sided base adds BACK_PARAMS
BASE_PARAMS = ("mass_magnet_g", "mass_capsule_g", "gap_mm", "spring_N_m", "damping_Ns_m", "constraint_N_m", "Pf_N")
BACK_PARAMS = ("gap_back_mm", "constraint_back_N_m", "constraint_damping_Ns_m", "constraint_back_damping_Ns_m")
#: the protocols of contract section 4 ("protocol: start")
STARTS = ("rest", "up", "down")
#: number of windows the recorded periods are split into for ``window_sd_mm_s``
N_WINDOWS = 4


@dataclass(frozen=True)
class Protocol:
    """How each condition is run (contract section 4 "protocol").

    start : 'rest' (every condition from rest, drive phase 0), 'up' or 'down' (continuation in f
    within each (P_d, duty): a condition starts from the final state of the previous frequency);
    transient_periods : drive periods run first and not recorded [-];
    recorded_periods : drive periods over which the average velocity is taken [-].
    """

    start: str = "rest"
    transient_periods: int = 120
    recorded_periods: int = 60

    def validate(self) -> "Protocol":
        if self.start not in STARTS:
            raise InputError(f"protocol start must be one of {', '.join(STARTS)}, got '{self.start}'")
        if int(self.transient_periods) != self.transient_periods or self.transient_periods < 0:
            raise InputError(f"protocol transient_periods must be an integer >= 0, got {self.transient_periods}")
        if int(self.recorded_periods) != self.recorded_periods or self.recorded_periods < 1:
            raise InputError(f"protocol recorded_periods must be an integer >= 1, got {self.recorded_periods}")
        return self


@dataclass(frozen=True)
class DynSystem:
    """A dynamics model: base, effects and the resolved parameters (model-file names and units).

    model : the engine's :class:`CapsuleModel` (SI) with the effect terms set;
    Pf_N : Coulomb level P_f [N] (inf: shell held fixed).
    """

    base: str
    effects: tuple[str, ...]
    params: Mapping[str, float] = field(repr=False)
    model: CapsuleModel = field(repr=False)
    Pf_N: float = 0.0078
    #: plugin drive transforms (role "drive"), in model-file order: (effect, its parameters in SI by base name)
    drive_transforms: tuple = field(default=(), repr=False)

    def friction(self) -> Friction:
        """Return the base Coulomb friction (the speed-law effect is applied on packing)."""
        if math.isinf(self.Pf_N):
            return friction_preset("fixed")
        return friction_preset("coulomb", self.Pf_N)

    def params_row(self, drive: Drive) -> np.ndarray:
        """Return the engine's parameter row for one drive condition."""
        return pack_params(self.model, drive, self.friction())


def effect_params(effects: Sequence[str], base: str, kind: str = "progression", where: str = "") -> dict:
    """Return {parameter name: start value} of the listed dynamics effects (registry lookup)."""
    from ..effects.registry import get_effect

    out: dict[str, float] = {}
    for name in effects:
        eff = get_effect(kind, name, where)
        if eff.bases and base not in eff.bases:
            raise InputError(f"{where}effect '{name}' does not apply to base '{base}' (only {', '.join(eff.bases)})")
        for prm in eff.params:
            out[prm.name] = float(prm.start)
    return out


def resolve_params(base: str, params: Mapping[str, float], effects: Sequence[str] = (),
                   where: str = "") -> dict[str, float]:
    """Return every parameter of ``base`` + ``effects`` (model-file names): the given ``params``
    over the effects' start values over the base's parameter set in ``configs/params``.

    A parameter that neither the base nor a listed effect declares is an error.
    """
    if base not in BASE_PARAM_SETS:
        raise InputError(f"{where}unknown dynamics base '{base}' (one of {', '.join(BASE_PARAM_SETS)})")
    if len(set(effects)) != len(effects):
        raise InputError(f"{where}an effect is listed twice: {list(effects)}")
    out = dict(load_param_set(BASE_PARAM_SETS[base]))
    known = set(BASE_PARAMS) | set(out) | (set(BACK_PARAMS) if base == "double_sided" else set())
    eff = effect_params(effects, base, where=where)
    for k, v in eff.items():
        out.setdefault(k, v)
        known.add(k)
    for k, v in params.items():
        if k not in known:
            raise InputError(f"{where}parameter '{k}' belongs to neither base '{base}' nor the effects "
                             f"{list(effects)} (known: {', '.join(sorted(known))})")
        try:
            out[k] = float(v)
        except (TypeError, ValueError):
            raise InputError(f"{where}parameter '{k}' must be a number, got {v!r}") from None
        if not (math.isfinite(out[k]) or (k == "Pf_N" and out[k] == math.inf)):
            raise InputError(f"{where}parameter '{k}' must be finite, got {v}")
    return {k: out[k] for k in out if k in known}


def plugin_roles(effects: Sequence[str], full: Mapping[str, float], where: str = "") -> tuple[tuple, tuple]:
    """Return (drive transforms, plugin forces) of the listed effects with their parameters in SI.

    drive transforms: ((effect, {base name: SI value}), ...); plugin forces: ((kind, name, SI values in
    declaration order), ...), compiled and checked here (:func:`.plugin_force.compile_forces`: a force that
    does not compile, raises or returns a non-finite value is one InputError line). A plugin effect with
    another role is an error.
    """
    from ..effects.registry import get_effect, si_factor

    transforms, forces = [], []
    for name in effects:
        eff = get_effect("progression", name, where)
        if eff.role == "drive":
            transforms.append((eff, {prm.key: full[prm.name] * si_factor(prm.name) for prm in eff.params}))
        elif eff.role == "friction":
            continue  # a friction level per condition from a covariate: the caller's (dynamics_loop.DynBound)
        elif eff.role == "force":
            forces.append((eff.kind, eff.name, tuple(full[prm.name] * si_factor(prm.name) for prm in eff.params)))
        elif eff.origin != "built-in":
            raise InputError(f"{where}plugin effect '{name}' ({eff.origin}) of a dynamics kind must be a drive "
                             "transform (register_effect(..., role='drive')) or a force (role='force')")
    if forces:
        from .plugin_force import compile_forces
        compile_forces(forces, where)
    return tuple(transforms), tuple(forces)


def capsule_of(base: str, params: Mapping[str, float], effects: Sequence[str], where: str = ""):
    """Return (every parameter but P_f by model-file name, P_f [N], the checked :class:`CapsuleModel`) of ``base``
    with ``effects`` at ``params``; InputError (prefixed with ``where``, ending in ": ") when they make no capsule.
    The plugin effects are not compiled or run here (:func:`build_system` does that)."""
    full = resolve_params(base, params, effects, where)
    pf = float(full.pop("Pf_N"))
    if not pf > 0:
        raise InputError(f"{where}Pf_N must be > 0 N (inf: shell fixed), got {pf}")
    double = base == "double_sided" or "secondary_constraint" in effects
    engine_params = {k: v for k, v in full.items() if k in MODEL_PARAM_NAMES}
    return full, pf, CapsuleModel.from_params(engine_params, double_sided=double, where=where.rstrip(": ") or "params")


def build_system(base: str, params: Mapping[str, float], effects: Sequence[str] = (), where: str = "") -> DynSystem:
    """Return the dynamics model of ``base`` ('one_sided' | 'double_sided') with ``effects``.

    params: model-file names with unit suffix (mass_magnet_g, mass_capsule_g, gap_mm, spring_N_m,
    damping_Ns_m, constraint_N_m, Pf_N, gap_back_mm, constraint_back_N_m, constraint_damping_Ns_m,
    constraint_back_damping_Ns_m and the effects' parameters); missing ones take the defaults of
    ``configs/params/prototype_*.yaml`` and the effects' start values. effects: registered
    dynamics effect names (:mod:`capsule_cli.effects.dynamics`, or plugins).
    """
    where = f"{where}: " if where and not where.endswith(": ") else where
    effects = tuple(effects)
    full, pf, model = capsule_of(base, params, effects, where)
    transforms, forces = plugin_roles(effects, full, where)
    if forces:
        model = replace(model, plugin_forces=forces)
    return DynSystem(base=base, effects=effects, params={**full, "Pf_N": pf}, model=model, Pf_N=pf,
                     drive_transforms=tuple(transforms))


def transform_drive(system: DynSystem, f_Hz: float, Pd_N: float, duty: float) -> tuple[float, float, float]:
    """Apply the system's plugin drive transforms to one condition (f [Hz], P_d [N], duty [-]).

    A transform that raises or returns anything but three finite numbers is bad input (one line); one that
    raises anything but an arithmetic error or ValueError (a fault of its code, such as a KeyError for a
    parameter key) is a :class:`PluginError`, which the dynamics loop never takes for a region of the parameters
    the model cannot run in.
    """
    for eff, p in system.drive_transforms:
        try:
            out = eff.apply(float(f_Hz), float(Pd_N), float(duty), dict(p))
            f_Hz, Pd_N, duty = (float(v) for v in out)
        except Exception as exc:  # noqa: BLE001  (a plugin failing at run time is the user's input, exit 2)
            # an arithmetic failure may be the parameters' (a region the model cannot run in); any other is the
            # plugin's code (PluginError: never taken for a region of the parameters)
            err = InputError if isinstance(exc, (ArithmeticError, ValueError)) else PluginError
            keys = f" (p holds {', '.join(map(repr, p)) or 'no keys'})" if isinstance(exc, KeyError) else ""
            raise err(f"drive transform '{eff.name}' ({eff.origin}) failed at f = {f_Hz:g} Hz, "
                      f"Pd = {Pd_N:g} N: {type(exc).__name__}: {exc}{keys}") from None
        if not all(math.isfinite(v) for v in (f_Hz, Pd_N, duty)):
            raise InputError(f"drive transform '{eff.name}' ({eff.origin}) returned a non-finite drive "
                             f"(f = {f_Hz}, Pd = {Pd_N}, duty = {duty})")
    return f_Hz, Pd_N, duty


def _conditions(f_Hz, Pd_N, duty, waveform: str, system: DynSystem | None = None):
    f = np.atleast_1d(np.asarray(f_Hz, dtype=float))
    Pd = np.atleast_1d(np.asarray(Pd_N, dtype=float))
    if duty is None:
        duty = 0.5
        if waveform == "square":
            raise InputError("a square-wave drive needs a duty cycle")
    D = np.atleast_1d(np.asarray(duty, dtype=float))
    try:
        f, Pd, D = np.broadcast_arrays(f, Pd, D)
    except ValueError:
        raise InputError(f"f_Hz, Pd_N and duty have incompatible lengths ({f.size}, {Pd.size}, {D.size})") from None
    if system is not None and system.drive_transforms:
        rows = [transform_drive(system, fr, a, d) for fr, a, d in zip(f, Pd, D)]
    else:
        rows = list(zip(f, Pd, D))
    drives = [Drive(amplitude_N=float(a), frequency_Hz=float(fr), waveform=waveform, duty=float(d)).validate()
              for fr, a, d in rows]
    return f, Pd, D, drives


def summarize_periods(per: np.ndarray, f_Hz: float) -> dict:
    """Return the progression row of one condition from its per-period records (engine columns).

    velocity_mm_s: average shell velocity over the recorded periods; impacts_per_period: mean
    number of constraint impacts (front and back) per period; period_number: 1..8 (0 irregular);
    window_sd_mm_s: sample SD (ddof 1) of the average velocity of N_WINDOWS equal windows.
    """
    cols = summarize_batch(np.asarray(per, float)[None], np.array([float(f_Hz)]))
    return {k: v[0].item() if isinstance(v[0], np.generic) else v[0] for k, v in cols.items()}


def summarize_batch(per: np.ndarray, f_Hz: np.ndarray) -> dict[str, np.ndarray]:
    """Return :func:`summarize_periods` of each condition as columns, for per of shape (conditions, recorded
    periods, engine columns) and f_Hz (conditions,) [Hz]; computed for all conditions at once (each row's sums
    run over a contiguous row, as for one condition alone: the same numbers)."""
    m, n = per.shape[0], per.shape[1]
    T = 1.0 / np.asarray(f_Hz, float)
    disp = np.ascontiguousarray(per[:, :, E.P_DISP])
    impacts = np.ascontiguousarray(per[:, :, E.P_NFRONT] + per[:, :, E.P_NBACK])
    pn = period_numbers(np.ascontiguousarray(per[:, :, E.P_XR0]), np.ascontiguousarray(per[:, :, E.P_VR0]))
    # the windows np.array_split makes (the first n % N_WINDOWS one period longer), the empty ones dropped
    q, r = divmod(n, N_WINDOWS)
    ends = np.cumsum([q + 1] * r + [q] * (N_WINDOWS - r))
    bounds = [(a, b) for a, b in zip(np.r_[0, ends[:-1]], ends) if b > a]
    wv = np.empty((m, len(bounds)))
    for j, (a, b) in enumerate(bounds):
        wv[:, j] = disp[:, a:b].sum(axis=1) / ((b - a) * T) * 1e3
    hits = impacts.sum(axis=1)
    cls = np.where(hits == 0, "no_impact", np.where(pn == 0, "irregular", np.where(np.all(impacts == 1, axis=1),
                                                                                "one_impact", "multi_impact")))
    return {
        "velocity_mm_s": disp.sum(axis=1) / (n * T) * 1e3,
        "impacts_per_period": impacts.mean(axis=1),
        "period_number": pn.astype(int),
        "response_class": cls.astype(object),
        "window_sd_mm_s": np.std(wv, axis=1, ddof=1) if len(bounds) > 1 else np.full(m, np.nan),
    }


def progression_columns(system: DynSystem, f_Hz, Pd_N, duty=None, waveform: str = "harmonic",
                        protocol: Protocol = Protocol(), options: EngineOptions | None = None,
                        start_offset_m=None, Pf_N=None) -> dict[str, np.ndarray]:
    """Return the steady progression per condition (same order as the inputs) as columns (name: array).

    Pf_N: Coulomb friction level P_f [N] per condition (scalar or one per condition) instead of the
    system's (a table's ``Pf_N`` column, or a level that depends on a covariate); None: the system's.

    start_offset_m: magnet-to-shell displacement x_r [m] (scalar or one per condition) added to each
    condition's starting state, to estimate a response's spread over starting states (multistable or
    chaotic conditions); None: none. Protocol rest: the start is rest + the offset. Protocol up/down: the
    offset is added to the state the condition starts from (rest at the sweep's first frequency, else the
    previous frequency's end state), as the rounding of another simulator or the state handed over between
    two measurements would move it.

    Columns: velocity_mm_s (average shell velocity over the recorded periods), impacts_per_period
    (mean), period_number (1..8, 0 = irregular/none found), response_class ('no_impact' |
    'one_impact' | 'multi_impact' | 'irregular'), window_sd_mm_s (SD of the average velocity of
    the recorded periods split into 4 windows). Protocol up/down: continuation in f within each
    (P_d, duty), from rest at the first frequency.
    """
    protocol = protocol.validate()
    f_in, Pd, D, drives = _conditions(f_Hz, Pd_N, duty, waveform, system)
    f = np.array([d.frequency_Hz for d in drives])  # the driven frequency (after plugin transforms)
    n = len(drives)
    if n == 0:
        return summarize_batch(np.zeros((0, 1, E.N_PERIOD_COLS)), np.zeros(0))
    # steady state only: a settled transient ends early (STEADY_SETTLE_TOL unless the options say otherwise)
    opts = replace(options or EngineOptions(settle_tol=STEADY_SETTLE_TOL), energy=False).pack()
    if Pf_N is None:
        P = np.stack([system.params_row(d) for d in drives])
    else:
        pfs = np.broadcast_to(np.asarray(Pf_N, float), (n,))
        bad = ~((pfs > 0) & np.isfinite(pfs))
        if bad.any():
            raise InputError(f"Pf_N per condition must be finite and > 0 N, got {pfs[bad][0]}")
        P = np.stack([pack_params(system.model, d, friction_preset("coulomb", float(pf)))
                      for d, pf in zip(drives, pfs)])
    ntr, nrec = int(protocol.transient_periods), int(protocol.recorded_periods)
    fr = system.friction()
    results: list = [None] * n
    if protocol.start == "rest":
        states0 = np.zeros((n, 4))
        if start_offset_m is not None:
            states0[:, 0] = np.broadcast_to(np.asarray(start_offset_m, float), (n,))
        st, per, _, _ = run_many(P, opts, states0, ntr, nrec)
        for i in range(n):
            check_status(int(st[i]), float("nan"), fr, f"condition f = {f[i]:g} Hz, Pd = {Pd[i]:g} N",
                         system.model.plugin_forces)
            results[i] = per[i]
    else:
        offs = (np.zeros(n) if start_offset_m is None
                else np.broadcast_to(np.asarray(start_offset_m, float), (n,)).copy())
        groups: dict[tuple[float, float], list[int]] = {}
        for i in range(n):
            groups.setdefault((float(Pd[i]), float(D[i])), []).append(i)
        # the sweeps (one per amplitude) advance in lockstep: their k-th frequencies run as one parallel batch,
        # each from its own sweep's carried state (the same run per condition as one sweep at a time)
        sweeps = [sorted(idx, key=lambda i: f_in[i], reverse=protocol.start == "down") for idx in groups.values()]
        states = np.zeros((len(sweeps), 4))
        for k in range(max(len(sw) for sw in sweeps)):
            live = [j for j, sw in enumerate(sweeps) if k < len(sw)]
            idx = np.array([sweeps[j][k] for j in live], int)
            s0 = states[live].copy()
            s0[:, 0] += offs[idx]
            st, per, _, fin = run_many(np.ascontiguousarray(P[idx]), opts, s0, ntr, nrec)
            for j, i, st_i, per_i, fin_i in zip(live, idx, st, per, fin):
                check_status(int(st_i), float("nan"), fr, f"condition f = {f[i]:g} Hz, Pd = {Pd[i]:g} N",
                             system.model.plugin_forces)
                results[i] = per_i
                states[j] = (fin_i[0], fin_i[1], 0.0, fin_i[3])
    return summarize_batch(np.stack(results), f)


def progression(system: DynSystem, f_Hz, Pd_N, duty=None, waveform: str = "harmonic",
                protocol: Protocol = Protocol(), options: EngineOptions | None = None,
                start_offset_m=None, Pf_N=None) -> pd.DataFrame:
    """Return one row per condition (same order as the inputs) of the steady progression: the table of
    :func:`progression_columns` (its arguments and columns)."""
    import pandas as pd
    cols = progression_columns(system, f_Hz, Pd_N, duty=duty, waveform=waveform, protocol=protocol,
                               options=options, start_offset_m=start_offset_m, Pf_N=Pf_N)
    if cols["velocity_mm_s"].size == 0:
        return pd.DataFrame(columns=list(cols))
    return pd.DataFrame(cols)


def trajectory(system: DynSystem, f_Hz: float, Pd_N: float, time_s, duty=None, waveform: str = "harmonic",
               options: EngineOptions | None = None, start_offset_m: float = 0.0) -> dict:
    """Return {'capsule_mm': array, 'magnet_mm': array} at ``time_s`` [s] from rest at drive phase 0
    (F = P_d cos 2 pi f t), each sample exact (closed form or the adaptive segment's dense output).

    start_offset_m: initial magnet-to-shell displacement x_r [m] instead of exact rest (the start's
    uncertainty, as in :func:`progression`); positions are still measured from the shell's start."""
    t = np.asarray(time_s, dtype=float).ravel()
    if t.size and (not np.all(np.isfinite(t)) or t.min() < 0):
        raise InputError("trajectory times must be finite and >= 0 s")
    _, _, _, drives = _conditions(f_Hz, Pd_N, duty, waveform, system)
    if len(drives) != 1:
        raise InputError("trajectory takes one condition (scalar f_Hz, Pd_N, duty)")
    d = drives[0]
    order = np.argsort(t, kind="stable")
    ts = t[order]
    n_periods = int(math.floor((ts[-1] if ts.size else 0.0) * d.frequency_Hz)) + 1
    opts = replace(options or EngineOptions(), energy=False).pack()
    state0 = np.zeros(4)
    state0[0] = float(start_offset_m)
    # a Ctrl-C during the compiled run: KeyboardInterrupt after it, not a SystemError
    st, st_t, sm, ns, *_ = deferred_call(E.run_core_at, system.params_row(d), opts, state0, 0, n_periods, ts, 0)
    check_status(int(st), float(st_t), system.friction(), f"trajectory f = {d.frequency_Hz:g} Hz",
                 system.model.plugin_forces)
    if ns != ts.size:
        raise RuntimeError(f"trajectory: {ns} of {ts.size} samples written")
    cap = np.empty(t.size)
    mag = np.empty(t.size)
    cap[order] = sm[:ns, E.S_XC] * 1e3
    mag[order] = sm[:ns, E.S_XM] * 1e3
    return {"capsule_mm": cap, "magnet_mm": mag}
