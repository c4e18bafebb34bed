"""One engine run as tables: trajectory samples, the exact event list, per-period records, energy.

:func:`simulate` is the Python face of :func:`capsule_cli.dynamics.engine.run_core`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..interrupts import call_interruptibly, deferred_call
from . import engine as E
from .model import CapsuleModel, Drive, EngineOptions, Friction, pack_params


class DynamicsError(InputError):
    """The requested run is ill-posed (literal friction law, Zeno accumulation): exit code 2."""


class EngineFailure(RuntimeError):
    """The engine failed for a numerical reason (a bug or an extreme parameter set)."""


@dataclass
class RunResult:
    """Records of one run (SI inside, tables in the units of their column suffixes)."""

    trajectory: pd.DataFrame
    events: pd.DataFrame
    periods: pd.DataFrame
    energy: dict
    final_state: np.ndarray  # [x_r, v_r, X_c, V_c, contact, shell] at the end (phase 0), periods integrated
    frequency_Hz: float
    params: np.ndarray = field(repr=False, default=None)

    @property
    def average_velocity_mm_s(self) -> float:
        """Mean capsule velocity over the recorded periods [mm/s]."""
        if self.periods.empty:
            return float("nan")
        return float(self.periods["displacement_mm"].mean() * self.frequency_Hz)


def check_status(status: int, t: float, friction: Friction | None = None, where: str = "",
                 plugins: tuple = ()) -> None:
    """Raise a clear error for a non-zero engine status (plugins: the model's ``plugin_forces``, named in
    the error of a failing plugin force)."""
    if status == E.STATUS_OK:
        return
    pre = f"{where}: " if where else ""
    if status == E.STATUS_ILLPOSED:
        detail = ""
        if friction is not None:
            pb, l0, _ = friction.levels()
            detail = (f" (breakaway {pb * 1e3:.4g} mN is below the kinetic level at 0+ "
                      f"{(friction.b_mN if friction.literal else l0 * 1e3):.4g} mN)")
        raise DynamicsError(f"{pre}friction law is ill-posed at t = {t:.9g} s{detail}: the shell can "
                            "neither stick nor slip, a Zeno stick-slip loop; use the well-posed law "
                            "(breakaway = max(static, kinetic at 0+), law held below V_min)")
    if status == E.STATUS_ZENO:
        raise DynamicsError(f"{pre}events accumulate at t = {t:.9g} s (Zeno: more than the allowed number "
                            "of zero-length segments in a row); the run was stopped")
    if status == E.STATUS_PLUGIN:
        names = ", ".join(f"'{pf[1]}'" for pf in plugins) or "a plugin force"
        raise DynamicsError(f"{pre}plugin force {names} raised or returned a non-finite force (NaN or inf) at "
                            f"t = {t:.9g} s; check its formula there (its effect's parameters, e.g. a distance "
                            "that reaches zero)")
    if status == E.STATUS_RKFAIL:
        raise EngineFailure(f"{pre}speed-dependent slip integration exceeded its step budget at t = {t:.9g} s")
    if status == E.STATUS_EVCAP:
        raise EngineFailure(f"{pre}event list capacity exceeded")
    raise EngineFailure(f"{pre}engine status {status}")


def period_columns(per: np.ndarray, f_Hz: float, n_transient: int) -> dict[str, np.ndarray]:
    """Columns of the per-period table (schema ``PERIODS`` of :mod:`capsule_cli.steps.dynamics`)."""
    T = 1.0 / f_Hz
    n = per.shape[0]
    return {
        "period": np.arange(n_transient, n_transient + n, dtype=np.int64),
        "time_s": (np.arange(n_transient, n_transient + n) * T).astype(float),
        "displacement_mm": per[:, E.P_DISP] * 1e3,
        "impacts": per[:, E.P_NFRONT].astype(np.int64),
        "back_impacts": per[:, E.P_NBACK].astype(np.int64),
        "max_Fi_N": per[:, E.P_MAXF],
        "max_Fi_time_s": per[:, E.P_TMAXF],
        "relative_mm": per[:, E.P_XR0] * 1e3,
        "relative_velocity_mm_s": per[:, E.P_VR0] * 1e3,
        "capsule_velocity_mm_s": per[:, E.P_VC0] * 1e3,
        "capsule_mm": per[:, E.P_XC0] * 1e3,
        "stick_fraction": per[:, E.P_STICK],
        "stick_events": per[:, E.P_NSTICK].astype(np.int64),
    }


def _periods_frame(per: np.ndarray, f_Hz: float, n_transient: int):
    import pandas as pd

    return pd.DataFrame(period_columns(per, f_Hz, n_transient))


def trajectory_columns(samples: np.ndarray) -> dict[str, np.ndarray]:
    """Columns of the trajectory table from the engine's sample rows (SI -> mm, mm/s)."""
    sm = samples
    return {
        "time_s": sm[:, E.S_T],
        "magnet_mm": sm[:, E.S_XM] * 1e3,
        "capsule_mm": sm[:, E.S_XC] * 1e3,
        "magnet_velocity_mm_s": sm[:, E.S_VM] * 1e3,
        "capsule_velocity_mm_s": sm[:, E.S_VC] * 1e3,
        "relative_mm": sm[:, E.S_XR] * 1e3,
        "contact": sm[:, E.S_CONTACT].astype(np.int64),
        "stick": sm[:, E.S_STICK] > 0.5,
        "Fi_N": sm[:, E.S_FI],
    }


def event_names(kinds: np.ndarray) -> np.ndarray:
    """Names of the engine's event kind codes (``EVENT_KIND_NAMES``), as an object array."""
    names = np.array([""] + [E.EVENT_KIND_NAMES[k] for k in range(1, max(E.EVENT_KIND_NAMES) + 1)], dtype=object)
    return names[np.asarray(kinds).astype(np.int64)]


def energy_record(energy: np.ndarray, computed: bool) -> dict:
    """The energy balance of a run [J] from the engine's energy slots."""
    # drive work + plugin-force work = dissipation + change in stored energy
    work = energy[E.E_DRIVE] + energy[E.E_PLUGIN]
    diss = energy[E.E_DAMP] + energy[E.E_CONTACT] + energy[E.E_FRIC]
    dstore = energy[E.E_END] - energy[E.E_START]
    scale = max(abs(energy[E.E_DRIVE]), abs(energy[E.E_PLUGIN]), abs(diss), abs(dstore), 1e-300)
    return {
        "drive_work_J": float(energy[E.E_DRIVE]),
        "plugin_work_J": float(energy[E.E_PLUGIN]),
        "spring_damping_J": float(energy[E.E_DAMP]),
        "contact_damping_J": float(energy[E.E_CONTACT]),
        "friction_J": float(energy[E.E_FRIC]),
        "stored_start_J": float(energy[E.E_START]),
        "stored_end_J": float(energy[E.E_END]),
        "residual_J": float(work - diss - dstore),
        "relative_residual": float((work - diss - dstore) / scale),
        "computed": bool(computed),
    }


@dataclass
class RawRun:
    """Records of one run as arrays (no pandas): the fast path of ``simulate`` on the command line."""

    samples: np.ndarray  # engine sample rows (S_* columns), SI
    event_times_s: np.ndarray
    event_kinds: np.ndarray  # engine kind codes (EVENT_KIND_NAMES)
    per: np.ndarray  # per-period rows (P_* columns), SI
    energy: dict
    final_state: np.ndarray
    frequency_Hz: float
    transient_periods: int
    params: np.ndarray = field(repr=False, default=None)


def run_arrays(model: CapsuleModel, drive: Drive, friction: Friction, periods: int = 50,
               transient_periods: int = 0, sample_rate_Hz: float = 0.0, state0=None,
               options: EngineOptions | None = None, record_events: bool = True,
               where: str = "", interruptible: bool = False) -> RawRun:
    """Run the engine and return its records as arrays; arguments as :func:`simulate`.

    interruptible : run the compiled call in a worker thread (:func:`capsule_cli.interrupts.call_interruptibly`),
    so that Ctrl-C stops the caller at once rather than when the run ends (`simulate` of millions of periods);
    otherwise the signals are held for the call and delivered after it.
    """
    model.validate()
    drive.validate()
    friction.validate()
    if periods < 0 or transient_periods < 0:
        raise InputError("periods and transient periods must be >= 0")
    opts = (options or EngineOptions()).pack()
    p = pack_params(model, drive, friction)
    s0 = np.zeros(4) if state0 is None else np.asarray(state0, dtype=float)[:4].copy()
    T = 1.0 / drive.frequency_Hz
    if sample_rate_Hz and sample_rate_Hz > 0:
        dt = 1.0 / sample_rate_Hz
        n_samples = int(math.floor(periods * T / dt + 1e-9)) + 1
    else:
        dt = 1.0
        n_samples = 0
    if n_samples > 20_000_000:
        raise InputError(f"{n_samples} trajectory samples requested; lower --sample-rate-Hz or --periods")
    args = (p, opts, s0, int(transient_periods), int(periods), dt, n_samples, -1 if record_events else 0)
    if interruptible:
        st, st_t, samples, ns, ev, nev, per, energy, final = call_interruptibly(E.run_core, *args)
    else:
        # a Ctrl-C during the compiled run: KeyboardInterrupt after it, not a SystemError
        st, st_t, samples, ns, ev, nev, per, energy, final = deferred_call(E.run_core, *args)
    check_status(int(st), float(st_t), friction, where, model.plugin_forces)
    return RawRun(samples=samples[:ns], event_times_s=ev[:nev, 0], event_kinds=ev[:nev, 1], per=per,
                  energy=energy_record(energy, (options or EngineOptions()).energy), final_state=final,
                  frequency_Hz=drive.frequency_Hz, transient_periods=int(transient_periods), params=p)


def simulate(model: CapsuleModel, drive: Drive, friction: Friction, periods: int = 50,
             transient_periods: int = 0, sample_rate_Hz: float = 0.0, state0=None,
             options: EngineOptions | None = None, record_events: bool = True,
             where: str = "") -> RunResult:
    """Run the engine and return its records as tables.

    Parameters
    ----------
    periods : recorded excitation periods (after the transient)
    transient_periods : periods run first and not recorded
    sample_rate_Hz : trajectory sampling rate [Hz] (0: no trajectory)
    state0 : [x_r, v_r, X_c, V_c] [m, m/s] at t = 0 (default: rest)
    """
    import pandas as pd

    r = run_arrays(model, drive, friction, periods, transient_periods, sample_rate_Hz, state0, options,
                   record_events, where)
    traj = pd.DataFrame(trajectory_columns(r.samples))
    names = np.array([""] + [E.EVENT_KIND_NAMES[k] for k in range(1, max(E.EVENT_KIND_NAMES) + 1)], dtype=object)
    evs = pd.DataFrame({
        "time_s": r.event_times_s,
        "kind": pd.Categorical(event_names(r.event_kinds), categories=list(names[1:])),
    })
    return RunResult(trajectory=traj, events=evs, periods=_periods_frame(r.per, drive.frequency_Hz, transient_periods),
                     energy=r.energy, final_state=r.final_state, frequency_Hz=drive.frequency_Hz, params=r.params)
