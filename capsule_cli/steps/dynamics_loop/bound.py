"""A dynamics model bound to a measurement table (:class:`DynBound`): its comparison rows, the engine runs
that predict them (every condition or run in parallel, memoised per parameter point), and the budgets and
constants the rest of the loop shares (:class:`Budget`, :data:`EFFORTS`, the response classes and units).

Also the trajectory comparison modes: position at every frame, or a run's average velocity over whole drive periods
where its response is irregular (:func:`choose_modes`, :func:`position_horizon_s`).
"""
from __future__ import annotations

import math
import time
from collections import OrderedDict
from contextlib import contextmanager
from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from ...dynamics import system as dsys
from ...dynamics.model import EngineOptions, STEADY_SETTLE_TOL
from ...effects.model import FreeParams, Model
from ...errors import InputError
from ...interrupts import deferred_signals


DYN_KINDS = ("progression", "trajectory")
#: response classes of dynamics.system.progression (contract section 2, verdict.regime)
RESPONSE_CLASSES = ("no_impact", "one_impact", "multi_impact", "irregular")
RESPONSE = {"progression": "velocity_mm_s", "trajectory": "capsule_mm"}
UNIT = {"progression": "mm/s", "trajectory": "mm"}
DRIVE_COLS = ("f_Hz", "Pd_N", "duty", "waveform")
XATOL = 2e-4  # Nelder-Mead stop: simplex size in box-scaled coordinates [-] (responses are sensitive)
FATOL_NOISE = 1e-2  # Nelder-Mead stop: cost change in units of the noise variance [-]
#: how a trajectory run's drive is classified (steady response after 60 periods from rest, 16 recorded)
RUN_CLASS_PROTOCOL = dsys.Protocol("rest", 60, 16)
#: Trajectory diagnose: passes of fitting every model with the runs' comparison modes taken from the
#: best-fitting models of the previous pass (:func:`modes_of_best`); 3 = the model as is's modes, then at
#: most two changes (a change of modes refits every model once, about doubling the time).
MODE_PASSES = 3
#: covariate probes (progression and trajectory): fitted when the best built-in candidate leaves a held-out
#: error above this fraction of the model as is's (it removes less than 1 - 0.5^2 = 75 % of the squared error; a
#: hidden built-in effect on the 40-condition grid leaves 2-5 %); see :func:`probe_verdict`
PROBE_TRIGGER = 0.5
#: a probe overrides the built-in verdict only when its held-out RMSE is below the best built-in's by more
#: than this many standard errors of the paired difference (and it passes the F test)
PROBE_Z = 2.0
#: trajectory noise from the residuals of the best-fitting model: at least this many frames compared by
#: position beyond its free parameters (fewer: the noise is only bounded, and the verdict says so)
MIN_NOISE_FRAMES = 20
COLD_STEP = 0.15  # initial Nelder-Mead simplex edge in box coordinates, full calibration [-]
WARM_STEP = 0.02  # the same for warm-started refits (folds, bootstrap): a local refinement [-]
PENALTY = 1e6  # standardised squared error of a row where the engine fails (ill-posed parameters)
#: a batch of fewer condition-periods than this runs on one engine thread. Measured (loaded 2-core machine,
#: OpenMP threading layer): 6 conditions x 56 periods took 3.3 ms CPU on one thread and 16-29 ms CPU (3-6x
#: the wall time) on two; 40 x 84 periods 20 ms against 48 ms. Waking the thread pool costs more than
#: such a batch, and xdist workers or parallel study jobs already use the cores.
SERIAL_BELOW_PERIODS = 4000
#: ... unless the previous such batch took longer than this [s] of wall time: then the batch's conditions are
#: shared by the engine's threads. A speed-law candidate's 40-condition evaluation costs 0.3-1 s on the adaptive
#: segment, where waking the pool (milliseconds) is negligible and two threads nearly halve the wall time.
PARALLEL_ABOVE_S = 0.05

#: Starting-state spread: every condition (irregular, no period <= 8: chaos, a long
#: transient; or periodic but multistable, one of coexisting attractors) is rerun from these initial
#: magnet-to-shell displacements x_r [m] besides exact rest. Periodic conditions were once left out: with a
#: secondary constraint at the prototype's values hidden in the 40-condition design, the fit at the truth
#: (G_2 0.0993 mm, k_b 98,565 N/m) then had held-out 14.8 mm/s against noise 0.5, a few periodic conditions
#: switching attractor as the fold refits moved P_f by < 1 %; with them, 1.06 (0.55 on the conditions
#: that are not irregular). A capsule "at rest" on a bench is not placed better than
#: 1-10 um (the gap G_1 is 1.6 mm), and an independent simulator's "rest" differs from this engine's
#: by its own rounding, which chaos amplifies: on the 40-condition design with a hidden secondary
#: constraint at G_2 = 0.3 mm, the starts' SD exceeds 1.5 mm/s at 10 of its 20 irregular conditions (up
#: to 74 mm/s: two attractors 135 mm/s apart) and at 3 of them the window term was below 1 mm/s
#: (tests/test_dynamics_loop_starts.py).
START_OFFSETS_M = (-1e-5, -1e-6, 1e-6, 1e-5)

#: A condition counts as predictable (``cv_rmse_not_irregular``) when its response is not irregular and its
#: spread over starting states stays below this fraction of the noise SD: a periodic response that one start
#: a few um from rest sends to another attractor (multistable; 54 and 108 mm/s spread at two "multi_impact"
#: conditions of the 40-condition secondary constraint) is no more predictable than chaos. Single-orbit
#: conditions spread by 1e-11 to 1e-5 mm/s, multistable ones by 1 mm/s and more.
MULTISTABLE_SPREAD_FRACTION = 0.1


def predictable(sim: dict, sd) -> np.ndarray:
    """Rows of ``sim`` whose response is neither irregular (no period <= 8) nor multistable (its spread
    over starting states at least MULTISTABLE_SPREAD_FRACTION of the noise SD ``sd``, response unit).
    Trajectory frames compared by position count as predictable whatever the steady class of their run:
    their run's path from rest was checked to be (:func:`choose_modes`)."""
    regular = sim["cls"].astype(str) != "irregular"
    if "by_position" in sim:
        regular = regular | np.asarray(sim["by_position"], bool)
    if "knife_edge" in sim:  # a run on a knife edge of the parameters (:func:`knife_edge_runs`)
        regular = regular & ~np.asarray(sim["knife_edge"], bool)
    if sd is None or not np.isfinite(sd) or sd <= 0:
        return regular
    return regular & (np.asarray(sim["spread"], float) < MULTISTABLE_SPREAD_FRACTION * float(sd))


#: parameter points whose runs a bound keeps (the last asked for; at most MEMO_VALUES numbers per array over
#: them all, the conditions' or rows' predictions): the polish starts where the Nelder-Mead ended and each fold's
#: refit where the full fit did, so their first point is one run already. One each-effect diagnose of
#: tests/test_dynamics_loop_each_effect.py: 8 % of its 2034 simulate calls asked for a point and conditions run
#: before, 12 % of its 19,292 condition runs; a two-candidate trajectory diagnose of six 0.4-s runs
#: (tests/test_dynamics_loop_fast.py): 305 of its 3626 calls a point and rows asked for before
MEMO_POINTS = 256
MEMO_VALUES = 2_000_000

#: Robust first stage of a progression calibration: Cauchy loss c^2 log(1 + (r / c)^2) with
#: c = ROBUST_SCALE x the noise SD. A few conditions that jump between attractors as a parameter
#: moves by 1e-3 of its value make the plain sum of squares a needle (the 40-condition secondary
#: constraint: RMSE 0.4 mm/s at the truth, 20-30 mm/s 0.5 um of gap away, median |r| 0.3-0.5 on
#: both); the Cauchy loss caps each such row's say, so the scan and Nelder-Mead see the basin.
ROBUST_SCALE = 4.0
#: graduated robust stage: while the residual scale at the robust optimum (1.4826 x median |r|) is
#: below 0.7 x the loss scale / ROBUST_SCALE (the noise SD was overestimated, e.g. from differences
#: along a rough response without replicates, or the start was far), the loss scale shrinks to
#: ROBUST_SCALE x that residual scale and Nelder-Mead restarts, at most this many times (graduated
#: non-convexity: Blake & Zisserman, Visual Reconstruction, MIT Press 1987)
GRADUATED_ROUNDS = 2


@dataclass(frozen=True)
class Budget:
    """Calibration budget: Sobol scan points per free parameter, Nelder-Mead starts, evaluations
    per start and free parameter, evaluations per fold refit and parameter, bootstrap resamples."""

    scan_per_param: int = 6
    starts: int = 2
    evals_per_param: int = 30
    fold_evals_per_param: int = 10
    bootstrap: int = 20
    #: evaluations per free parameter of the Gauss-Newton polish (trust-region least squares on the residual
    #: vector, finite-difference Jacobian) after the Nelder-Mead starts; 0: none
    polish_evals_per_param: int = 12
    #: relative tolerance of the engine's adaptive slip segments during calibration (EngineOptions.rk_rtol);
    #: None: the engine's default (1e-11). Synth always runs at the default.
    rk_rtol: float | None = None


#: named budgets (CLI --effort): full (default) and quick (smoke runs, a first look, the CI tests).
#: quick: a smaller Sobol scan (4 points per parameter), fewer evaluations per start, fold refit and bootstrap
#: resample. (A scan of 8 points per parameter named a hidden tilt or secondary constraint on ten conditions
#: in 10 of 10 diagnoses at seeds 2-3 against 6 of 10 with 4, but stopped a six-run trajectory fit in a worse
#: minimum, in-sample RMSE 1.6x the noise against 1.2x: the multi-start strategy, not the scan size, is the
#: weak point; see the issue 12 closing note.)
#: Calibration runs the engine's adaptive segments (the speed laws above V_min) at rk_rtol 1e-9 (full) or
#: 1e-8 (quick): on the 40-condition design (configs/designs/progression_grid.csv, hidden speed law) the
#: average velocities move by <= 1.4e-5 mm/s (1e-9) and <= 2.6e-4 mm/s (1e-8) against the default 1e-11,
#: three orders below any velocity noise a progression measurement reaches, for 2x and 3x less engine time.
#: Synth always runs at the engine's default.
EFFORTS = {"full": Budget(rk_rtol=1e-9),
           "quick": Budget(scan_per_param=4, starts=2, evals_per_param=15, fold_evals_per_param=5, bootstrap=5,
                           polish_evals_per_param=10, rk_rtol=1e-8)}


@contextmanager
def engine_threads(condition_periods: int, last_batch_s: float = 0.0):
    """Run the engine's parallel batches inside on one thread when the batch is small
    (< SERIAL_BELOW_PERIODS condition-periods) and the previous one was cheap (< PARALLEL_ABOVE_S of wall
    time); the numba thread count is restored afterwards."""
    if condition_periods >= SERIAL_BELOW_PERIODS or last_batch_s >= PARALLEL_ABOVE_S:
        yield
        return
    import numba

    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(old)


def is_dynamics(kind: str) -> bool:
    """Return True for the dynamics kinds (progression, trajectory)."""
    return kind in DYN_KINDS


def protocol_of(model: Model) -> dsys.Protocol:
    """Return the model file's protocol (contract section 4) with documented defaults."""
    raw = dict(model.content.get("protocol") or {})
    return dsys.Protocol(**{k: raw[k] for k in ("start", "transient_periods", "recorded_periods") if k in raw})


def _drive_of(d: pd.DataFrame, where: str) -> tuple[float, float, float | None, str]:
    for c in ("f_Hz", "Pd_N"):
        if c not in d.columns:
            raise InputError(f"{where}: missing column '{c}' (the drive of each run)")
        if d[c].nunique() != 1:
            raise InputError(f"{where}: column '{c}' changes within run '{d['run'].iloc[0]}' (one drive per run)")
    duty = float(d["duty"].iloc[0]) if "duty" in d.columns else None
    wf = str(d["waveform"].iloc[0]) if "waveform" in d.columns else "harmonic"
    return float(d["f_Hz"].iloc[0]), float(d["Pd_N"].iloc[0]), duty, wf


# ---------------------------------------------------------------------------
# the model tied to a table


def _point(theta) -> bytes:
    """Return the key of a parameter point (b"" for the model file's values) for the runs a bound keeps."""
    return b"" if theta is None else np.asarray(theta, float).tobytes()


class ModelNotRunnable(InputError):
    """The engine could not run a model at any parameter point its calibration tried (a plugin force or drive
    transform that fails everywhere, a parameter set out of the engine's reach): bad input, exit code 2; a
    candidate effect of diagnose that cannot be run is left out with the reason."""


def check_start_values(model: Model) -> None:
    """Raise InputError naming the model file when its parameter values (the free ones at their start) cannot make
    a capsule: a mass, spring stiffness or gap of 0 or less, a negative damping or stiffness, P_f <= 0.

    Checked before any work by `compare`, `diagnose` and `synth`. Before, a fixed ``spring_N_m: 0`` reached the
    calibration, whose every run was refused, and the one line named the data table: "model 'm' could not be run
    at any of the 89 parameter points its calibration tried: params: spring_N_m must be a positive number".
    Plugin effects are not run here (their own checks say what fails, with the plugin's name).
    """
    # the message names a bad value as the file writes it (mass_capsule_g, not the engine's mass_capsule_kg)
    dsys.capsule_of(model.base.name, {s.param.name: s.value for s in model.specs}, tuple(model.effect_names),
                    f"{model.path}: params: ")


def at_rest(t_s) -> np.ndarray:
    """Return which frame times ``t_s`` [s] are the run's start, t = 0 (to 1 ns), where every run is at rest."""
    return np.abs(np.asarray(t_s, float)) <= 1e-9


def zeroed_runs(runs, response: str) -> frozenset:
    """Return the trajectory runs (labels) whose ``response`` position at time_s = 0 is exactly 0 while some later
    frame is not: runs whose positions were measured from their own first frame.

    Every run starts from rest at the origin (contract section 4), and a camera's frame there carries its noise
    like any other. A tracker's positions made relative by subtracting the first frame hold that frame's noise,
    e_0, in every other frame: the run is shifted by -e_0, one draw of the position noise, and no model starting
    at the origin follows it. Left as it is, four 1-s runs with nothing missing (noise 0.3 mm, each zeroed at its
    first frame) gave a missing effect or a covariate on 4 of 4 noise seeds (held-out RMSE 0.33-0.57 mm as is
    against noise 0.31-0.40). An exact zero is the mark: a measured frame is exactly 0 only by rounding. Such a
    run's origin is fitted (:meth:`DynBound._with_origins`)."""
    out = []
    for r, d in runs:
        if response not in d.columns:
            continue
        t, x = d["time_s"].to_numpy(float), d[response].to_numpy(float)
        at0 = at_rest(t)
        if at0.any() and np.all(x[at0] == 0.0) and np.any(np.isfinite(x[~at0]) & (x[~at0] != 0.0)):
            out.append(str(r))
    return frozenset(out)


class DynBound(FreeParams):
    """A dynamics model tied to a table: ``simulate(theta)`` gives predictions per comparison row.

    theta holds the free parameters in the unit of each name's suffix (as in the model file).
    """

    def __init__(self, model: Model, df: pd.DataFrame, where: str = "", modes: Mapping | None = None,
                 rk_rtol: float | None = None):
        self.model, self.df, self.where = model, df.reset_index(drop=True), where or "table"
        self.options = None if rk_rtol is None else EngineOptions(rk_rtol=float(rk_rtol), settle_tol=STEADY_SETTLE_TOL)
        self.n_sim = 0  # model evaluations (simulate calls) so far: the budget actually used
        self.n_ran = 0  # of them, those the engine ran (a prediction came out)
        self.last_failure = ""  # why the last run that failed could not be run
        self.last_batch_s = 0.0  # wall time of the last progression batch [s] (engine_threads)
        #: runs kept by parameter point: a progression's conditions (:meth:`_sim_progression`), a trajectory's
        #: predictions at given rows (:meth:`simulate`)
        self._memo: OrderedDict = OrderedDict()
        self.kind = model.kind
        self.protocol = protocol_of(model)
        self.free = [s for s in model.specs if s.free]
        self.response = RESPONSE[self.kind]
        self.column_pf = self.kind == "progression" and "Pf_N" in df.columns
        if self.column_pf and any(s.param.name == "Pf_N" for s in self.free):
            raise InputError(f"{model.path}: params.Pf_N: free, but the table gives 'Pf_N' row by row: "
                             "fix it or drop the column")
        #: effects that scale the friction level at each condition by a function of a covariate (role "friction":
        #: the friction probes of diagnose), with their covariate
        self.friction_mods = [(e, e.covariates[0]) for e in model.effects if e.role == "friction"]
        for e, cov in self.friction_mods:
            if cov not in self.df.columns:
                raise InputError(f"{self.where}: effect '{e.name}' needs the column '{cov}'")
            if self.kind == "trajectory" and (self.df.groupby("run", sort=False)[cov].nunique() > 1).any():
                raise InputError(f"{self.where}: effect '{e.name}' sets a run's friction level from '{cov}', "
                                 "which changes within a run")
        if self.kind == "progression":
            cols = [c for c in DRIVE_COLS + ("Pf_N",) if c in self.df.columns]
            cols += [cov for _, cov in self.friction_mods if cov not in cols]
            self.cond_cols = cols
            key = self.df[cols].astype(str).agg("|".join, axis=1)
            self.cond_index, uniq = pd.factorize(key)
            first = pd.Series(np.arange(len(self.df))).groupby(self.cond_index).first().to_numpy()
            self.conditions = self.df.iloc[first][cols].reset_index(drop=True)
            c = self.conditions
            #: the conditions' drives: f [Hz], P_d [N], duty [-] (None: the default) and waveform (per condition,
            #: or one name)
            self._cond_drive = (c["f_Hz"].to_numpy(float), c["Pd_N"].to_numpy(float),
                                c["duty"].to_numpy(float) if "duty" in c else None,
                                c["waveform"].to_numpy(object) if "waveform" in c else "harmonic")
        else:
            self.runs = [(str(r), d) for r, d in self.df.groupby("run", sort=False)]
            self.run_drive = {r: _drive_of(d, self.where) for r, d in self.runs}
            #: per run, its frames' times [s] in the table's order
            self._run_t = {r: d["time_s"].to_numpy(float) for r, d in self.runs}
            #: per run, the value of each friction effect's covariate (one per run, checked above)
            self._run_cov = {r: {cov: float(d[cov].iloc[0]) for _, cov in self.friction_mods} for r, d in self.runs}
            self.modes = dict(modes) if modes else {r: "position" for r, _ in self.runs}
            #: runs whose origin is fitted (:func:`zeroed_runs`): their positions were measured from their own
            #: first frame, whose noise shifts the whole run
            self.origin_runs = zeroed_runs(self.runs, self.response)
            self._build_rows()

    # -- parameters: names, x0, bounds, values() from effects.model.FreeParams

    def params_by_name(self, theta=None) -> dict[str, float]:
        """Return every parameter's value at ``theta`` by its model-file name (unit of its suffix)."""
        vals = self.values(theta)
        return {s.param.name: vals[s.key] for s in self.model.specs}

    def system(self, theta=None) -> dsys.DynSystem:
        return dsys.build_system(self.model.base.name, self.params_by_name(theta), self.model.effect_names)

    def run_system(self, sysm: dsys.DynSystem, theta, run: str) -> dsys.DynSystem:
        """Return trajectory ``run``'s system: ``sysm`` with its friction level P_f times the factors of the
        effects of role "friction" at the run's covariate values (:meth:`condition_pf` for progressions);
        ``sysm`` itself when the model has none."""
        if not self.friction_mods:
            return sysm
        by_name = self.params_by_name(theta)
        pf = float(sysm.Pf_N)
        for eff, cov in self.friction_mods:
            pf *= float(eff.apply(self._run_cov[run][cov], {prm.key: float(by_name[prm.name]) for prm in eff.params}))
        return replace(sysm, Pf_N=pf)

    # -- rows
    def _build_rows(self):
        """Trajectory comparison rows: frames of position-mode runs, one row per velocity-mode run; a run
        compared by position up to its predictability horizon has both (its frames up to it, then its row)."""
        rows, obs, groups, factor = [], [], [], []
        # per run, in the rows' order (:meth:`_sim_trajectory`): (run, its frames' times [s] in the table's order,
        # its position rows (positions in ``rows``) and their frames' positions in the run, its average-velocity
        # row or -1)
        blocks = []
        for gi, (r, d) in enumerate(self.runs):
            until = position_horizon_s(self.modes[r])
            js, loc, drift = np.zeros(0, int), np.zeros(0, int), -1
            if self.modes[r] == "position" or until is not None:
                e = d if until is None else d[d["time_s"] <= until + 1e-9]
                js = np.arange(len(rows), len(rows) + len(e))
                loc = d.index.get_indexer(e.index)
                for i in e.index:
                    rows.append(("position", r, int(i)))
                obs += list(e[self.response].to_numpy(float))
                groups += [gi] * len(e)
                factor += [1.0] * len(e)
            if self.modes[r] != "position":
                drift = len(rows)
                rows.append(("average_velocity", r, int(d.index[0])))
                obs.append(run_drift(self._run_t[r], d[self.response].to_numpy(float), self.run_drive[r][0])[1])
                groups.append(gi)
                factor.append(drift_noise_factor(self._run_t[r], self.run_drive[r][0]))
            blocks.append((r, self._run_t[r], js, loc, drift))
        self.rows = rows
        self._blocks = blocks
        self._by_position = frames_by_position(rows)
        # per row: its run (its place in ``blocks``), and the frame time in drive periods (inf for an
        # average-velocity row)
        self._row_block = np.array([gi for gi, (_, _, js, _, drift) in enumerate(blocks)
                                    for _ in range(js.size + (drift >= 0))], int)
        t = self.df["time_s"].to_numpy(float)[[i for _, _, i in rows]] if rows else np.zeros(0)
        self._row_time = np.where(self._by_position, t, np.inf)
        self._row_periods = self._row_time * np.array([self.run_drive[r][0] for _, r, _ in rows], float)
        self._obs = np.array(obs, float)
        self._groups = np.array(groups, int)
        #: per row: its noise SD in units of one frame's (:func:`row_variance`)
        self.noise_factor = np.array(factor, float)

    def observed(self) -> np.ndarray:
        if self.kind == "progression":
            return self.df[self.response].to_numpy(float)
        return self._obs

    def row_frame(self) -> pd.DataFrame:
        """Return the table behind the comparison rows (progression: the data; trajectory: per row)."""
        if self.kind == "progression":
            return self.df.copy()
        recs = []
        for mode, r, i in self.rows:
            rec = self.df.loc[i].to_dict()
            rec["compared"] = mode
            if mode == "average_velocity":
                rec["time_s"] = whole_periods_s(float(self._run_t[r].max()), self.run_drive[r][0])
            recs.append(rec)
        return pd.DataFrame(recs)

    def groups(self) -> tuple[np.ndarray, str]:
        """Return the cross-validation groups: a trajectory's runs; a progression's conditions (its readings
        at one drive together, whatever their ``run`` label: the held-out error is over conditions, as the
        issue asks, also when each run is a replicate sweep over every condition, where groups by run would
        predict each condition from its own replicate)."""
        if self.kind == "progression":
            return np.asarray(self.cond_index, int), "by condition (the readings at one drive together)"
        return self._groups, "by 'run'"

    # -- simulation
    def simulate(self, theta=None, rows=None, classify: bool = True, starts: bool = False, y=None) -> dict:
        """Return {'pred', 'spread', 'cls'} per comparison row (response unit; spread: SD of the
        model's own average there; cls: response class at the row's drive).

        rows: only these comparison rows are needed (a fold's or a bootstrap resample's training rows):
        only their conditions (runs) are simulated, the other rows are NaN. classify=False (trajectory):
        skip the steady-response classification of each run, which a plain least-squares cost does not use.
        starts=True (progression): every condition is also run from the starting states START_OFFSETS_M
        (protocol up/down: each sweep again, the offset added to the state each condition starts from); its
        prediction is the mean over all starts and its spread the larger of the window term and the
        starting-state SD (module docstring, error model). A continuation protocol always simulates whole
        sweeps, whatever ``rows`` asks for. Trajectory: each run compared by its drift is also run from
        those starting states; the drift's spread is the larger of the window term and their SD (the drift
        stays the one from rest). A trajectory's dict also holds ``noise_factor`` (:func:`row_variance`).

        y: the observations being fitted (one per comparison row): a trajectory run whose origin is fitted
        (``origin_runs``) has its position rows' predictions moved by its offset, profiled from ``y`` on the rows
        asked for (:meth:`_with_origins`), and the dict holds ``origin_mm`` ({run: offset [mm]}). Every caller that
        compares predictions with observations passes them; without ``y`` the model's positions from the origin.
        """
        self.n_sim += 1
        if self.kind == "trajectory" and dsys.E.run_core_at.overloads:
            # one signal block for the runs (a few ms) instead of 15 us per run; not before the engine is compiled
            # (the first runs compile it, minutes with a cold cache, with the signals free: deferred_call)
            with deferred_signals():
                out = self._simulate(theta, rows, classify, starts)
        else:  # one block per parallel call of the engine (each column of a continuation sweep)
            out = self._simulate(theta, rows, classify, starts)
        if np.isfinite(out["pred"]).any():
            self.n_ran += 1
        if y is not None and self.kind == "trajectory" and self.origin_runs:
            out = self._with_origins(out, np.asarray(y, float), rows)
        return out

    def _with_origins(self, out: dict, y: np.ndarray, rows) -> dict:
        """Return ``out`` (a trajectory's :meth:`simulate` dict) with each run of ``origin_runs`` moved by its
        least-squares offset: the mean of y - pred over its position rows among ``rows`` (all when None; a run
        with none of them keeps its predictions), added to every position row of the run (a fold's held-out run
        gets the offset of its own frames: the origin belongs to the run's measurement, not to the model), and
        ``origin_mm`` = {run: offset [mm]}. The offset is profiled, not searched: for any parameters it is the
        best one, so the fits and their costs are those of the model with one more linear parameter per run."""
        pred = np.array(out["pred"], float)
        asked = None
        if rows is not None:
            asked = np.zeros(len(self.rows), bool)
            asked[np.asarray(rows, int)] = True
        origin = {}
        for r, _, js, _, _ in self._blocks:
            if r not in self.origin_runs or not js.size:
                continue
            use = js if asked is None else js[asked[js]]
            d = y[use] - pred[use]
            d = d[np.isfinite(d)]
            if d.size:
                origin[r] = float(np.mean(d))
                pred[js] += origin[r]
        return {**out, "pred": pred, "origin_mm": origin}

    def _simulate(self, theta, rows, classify: bool, starts: bool) -> dict:
        if self.kind == "progression":
            return self._sim_progression(theta, rows, starts)
        # a point asked for again with the same rows (the horizon continuation and the polish revisit points):
        # the same run, kept
        key = (_point(theta), None if rows is None else np.asarray(rows, np.int64).tobytes(), bool(classify),
               bool(starts))
        hit = self._memo.get(key)
        if hit is None:
            hit = self._sim_trajectory(theta, rows, classify, starts)
            self._keep(key, hit, len(self.rows))
        else:
            self._memo.move_to_end(key)
        return {k: v.copy() if k in ("pred", "spread", "cls") else v for k, v in hit.items()}

    def _sim_progression(self, theta, rows=None, starts: bool = False) -> dict:
        self.last_failure = ""  # why the last batch could not be run ("" when it ran)
        c = self.conditions
        n = len(c)
        vel, spread = np.full(n, np.nan), np.full(n, np.nan)
        cls = np.array(["failed"] * n, dtype=object)
        need = np.ones(n, bool)
        # a continuation sweep runs through every frequency of its amplitude in order: a fold's conditions are
        # simulated within the whole sweep, never as a sweep of their own (another history)
        if rows is not None and self.protocol.start == "rest":
            need[:] = False
            need[np.unique(self.cond_index[np.asarray(rows, int)])] = True
        # a point asked for again (a fold's refit starts at the full fit, the polish at the best start): only the
        # conditions not run there yet (each condition's run is its own, whatever the batch: the same numbers)
        key = None if starts else (_point(theta), self.protocol, repr(self.options))
        hit = None if key is None else self._memo.get(key)
        todo = need if hit is None else need & ~hit[3]
        if hit is not None and not todo.any():
            self._memo.move_to_end(key)
        else:
            sel = np.flatnonzero(todo)
            try:
                sysm = self.system(theta)
                pfs = self.condition_pf(theta, sysm)
                f, pdn, du, wf = self._cond_drive
                per = sel.size * (self.protocol.transient_periods + self.protocol.recorded_periods)
                t0 = time.perf_counter()
                with engine_threads(per, self.last_batch_s):
                    out = dsys.progression_columns(sysm, f[sel], pdn[sel], duty=None if du is None else du[sel],
                                                   waveform=wf if isinstance(wf, str) else wf[sel],
                                                   protocol=self.protocol, options=self.options,
                                                   Pf_N=None if pfs is None else pfs[sel])
                self.last_batch_s = time.perf_counter() - t0
            except NotImplementedError:
                raise
            except (InputError, RuntimeError, ValueError, FloatingPointError) as exc:
                self.last_failure = str(exc)
                ci = self.cond_index
                return {"pred": vel[ci], "spread": spread[ci], "cls": cls[ci]}
            vel[sel] = out["velocity_mm_s"]
            cls[sel] = out["response_class"]
            spread[sel] = np.where(cls[sel] == "irregular", out["window_sd_mm_s"] / 2, 0.0)
            if key is not None:
                hit = self._remember(key, hit, sel, vel, spread, cls)
        if hit is not None:  # the conditions asked for, run now or before at this point
            vel[need], spread[need], cls[need] = hit[0][need], hit[1][need], hit[2][need]
        if starts:
            # every condition: a periodic response can coexist with another attractor (multistable),
            # reached from a start a few um away or after a small change of a parameter
            self._start_spread(sysm, sel, vel, spread, pfs)
        ci = self.cond_index
        return {"pred": vel[ci], "spread": spread[ci], "cls": cls[ci]}

    def _remember(self, key, hit, sel: np.ndarray, vel: np.ndarray, spread: np.ndarray, cls: np.ndarray) -> tuple:
        """Keep the conditions ``sel`` just run at ``key`` (velocity, spread, class; merged into ``hit``, the ones
        kept there before) with the points asked for last (:meth:`_keep`); return the record kept."""
        if hit is None:
            n = len(self.conditions)
            hit = (np.full(n, np.nan), np.full(n, np.nan), np.array(["failed"] * n, dtype=object), np.zeros(n, bool))
        hit[0][sel], hit[1][sel], hit[2][sel], hit[3][sel] = vel[sel], spread[sel], cls[sel], True
        self._keep(key, hit, len(self.conditions))
        return hit

    def _keep(self, key, value, size: int) -> None:
        """Keep ``value`` (``size`` numbers per array) under ``key`` as the last point asked for: at most
        MEMO_POINTS points and MEMO_VALUES numbers per array over them all (the oldest go first)."""
        self._memo[key] = value
        self._memo.move_to_end(key)
        while len(self._memo) > max(1, min(MEMO_POINTS, MEMO_VALUES // max(size, 1))):
            self._memo.popitem(last=False)

    def condition_pf(self, theta, sysm: dsys.DynSystem) -> np.ndarray | None:
        """Return the friction level P_f [N] of each condition when it is not the model's one value (the table's
        ``Pf_N`` column, times the factors of effects of role "friction" at the condition's covariate value),
        else None."""
        if not (self.column_pf or self.friction_mods):
            return None
        c = self.conditions
        pf = c["Pf_N"].to_numpy(float).copy() if self.column_pf else np.full(len(c), float(sysm.Pf_N))
        if self.friction_mods:
            by_name = self.params_by_name(theta)
            for eff, cov in self.friction_mods:
                p = {prm.key: float(by_name[prm.name]) for prm in eff.params}
                pf *= np.array([eff.apply(x, p) for x in c[cov].to_numpy(float)], float)
        return pf

    def _start_spread(self, sysm, irr: np.ndarray, vel: np.ndarray, spread: np.ndarray,
                      pfs: np.ndarray | None = None) -> None:
        """Rerun conditions ``irr`` from START_OFFSETS_M (rest: one parallel batch; up/down: each sweep again,
        the offset added to the state every condition starts from) and set, in place, their
        velocity to the mean over all starts (rest included) and their spread to
        max(window term, SD over starts x sqrt(1 + 1 / starts)): the SD of a new run's average about that
        mean. Conditions that fail from a perturbed start keep the rest run's values."""
        f, pdn, du, wf = self._cond_drive
        m, offs = irr.size, np.asarray(START_OFFSETS_M, float)
        # rest: every condition from each offset (one parallel batch); continuation: each sweep again with the
        # offset added to the state every condition starts from (the state handed over is as uncertain)
        sweeps = [np.tile(irr, offs.size)] if self.protocol.start == "rest" else [irr] * offs.size
        off_of = [np.repeat(offs, m)] if self.protocol.start == "rest" else list(offs)
        v = [vel[irr]]
        try:
            for rep, off in zip(sweeps, off_of):
                with engine_threads(rep.size * (self.protocol.transient_periods + self.protocol.recorded_periods)):
                    out = dsys.progression_columns(sysm, f[rep], pdn[rep], duty=None if du is None else du[rep],
                                                   waveform=wf if isinstance(wf, str) else wf[rep],
                                                   protocol=self.protocol, options=self.options, start_offset_m=off,
                                                   Pf_N=None if pfs is None else pfs[rep])
                v.append(np.asarray(out["velocity_mm_s"], float))
        except (InputError, RuntimeError, ValueError, FloatingPointError):
            return
        v = np.vstack([v[0]] + [np.reshape(x, (-1, m)) for x in v[1:]])
        k = v.shape[0]
        vel[irr] = v.mean(axis=0)
        spread[irr] = np.maximum(spread[irr], v.std(axis=0, ddof=1) * math.sqrt(1.0 + 1.0 / k))

    def run_summary(self, theta=None) -> dict[str, dict]:
        """Return per trajectory run the model's steady response at the run's drive (progression summary
        after RUN_CLASS_PROTOCOL) and the run's whole periods from t = 0."""
        sysm = self.system(theta)
        out = {}
        for r, _ in self.runs:
            f, pdn, duty, wf = self.run_drive[r]
            k = max(int(math.floor(self._run_t[r].max() * f + 1e-9)), 1)
            with engine_threads(1):
                pr = dsys.progression(self.run_system(sysm, theta, r), [f], [pdn], duty=duty, waveform=wf,
                                      protocol=RUN_CLASS_PROTOCOL, options=self.options)
            out[r] = pr.iloc[0].to_dict() | {"periods": k}
        return out

    def start_spread_mm(self, theta, run: str) -> float:
        """Return the largest distance [response unit, mm] between the model's path of trajectory ``run`` from
        rest and its paths from the starting states START_OFFSETS_M, over the run's frames (inf where the
        engine fails): how far the start's uncertainty moves the prediction within the measured time."""
        return float(np.max(self.start_spread_path(theta, run), initial=0.0))

    def start_spread_path(self, theta, run: str) -> np.ndarray:
        """Return per frame of trajectory ``run`` the largest distance [response unit, mm] between the model's
        path from rest and its paths from the starting states START_OFFSETS_M (inf everywhere where the engine
        fails)."""
        return self.path_and_spread(theta, run)[1]

    def path_and_spread(self, theta, run: str) -> tuple[np.ndarray, np.ndarray]:
        """Return per frame of trajectory ``run`` (its rows' order) the model's position [response unit, mm] on its
        path from rest and :meth:`start_spread_path` there (NaN and inf everywhere where the engine fails)."""
        f, pdn, duty, wf = self.run_drive[run]
        t = self._run_t[run]
        try:
            sysm = self.run_system(self.system(theta), theta, run)

            def path(x0: float) -> np.ndarray:
                return np.asarray(dsys.trajectory(sysm, f, pdn, t, duty=duty, waveform=wf, options=self.options,
                                                  start_offset_m=x0)[self.response], float)

            ref = path(0.0)
            return ref, np.max([np.abs(path(x0) - ref) for x0 in START_OFFSETS_M], axis=0)
        except (InputError, RuntimeError, ValueError, FloatingPointError):
            return np.full(t.size, np.nan), np.full(t.size, np.inf)

    def horizon_rows(self, rows, periods: float) -> np.ndarray | None:
        """Return the comparison rows (among ``rows``; all when None) of position-mode frames within the
        first ``periods`` drive periods of their run, or None when that leaves too few rows to fit the
        free parameters or all of them."""
        idx = np.arange(len(self.rows)) if rows is None else np.asarray(rows, int)
        keep = idx[self._row_periods[idx] <= periods + 1e-9]
        if keep.size < 3 * len(self.free) + 2 or keep.size == idx.size:
            return None
        return keep

    def _sim_trajectory(self, theta, rows=None, classify: bool = True, starts: bool = False) -> dict:
        m = len(self.rows)
        pred, spread = np.full(m, np.nan), np.zeros(m)
        fac = self.noise_factor
        cls = np.array(["failed"] * m, dtype=object)
        by_position = self._by_position
        need, t_max = None, {}
        if rows is not None:  # only these rows' runs, each up to its last needed frame
            sel = np.asarray(rows, int)
            last = np.full(len(self._blocks), -np.inf)
            np.maximum.at(last, self._row_block[sel], self._row_time[sel])
            t_max = {self._blocks[k][0]: float(last[k]) for k in np.unique(self._row_block[sel])}
            need = set(t_max)
        try:
            sysm = self.system(theta)
            summ = self.run_summary(theta) if classify else {}
        except NotImplementedError:
            raise
        except (InputError, RuntimeError, ValueError, FloatingPointError) as exc:
            self.last_failure = str(exc)
            return {"pred": pred, "spread": spread, "cls": cls, "by_position": by_position, "noise_factor": fac}
        try:
            # run by run, in the rows' order; a run the engine cannot run leaves its rows and every later one NaN
            # (a large penalty in the costs) and "failed" (but the row it failed at, which has its class)
            for r, t, js, loc, drift in self._blocks:
                if need is not None and r not in need:
                    continue
                s = summ.get(r)
                c = s["response_class"] if s else "not_classified"
                f, pdn, duty, wf = self.run_drive[r]
                rs = self.run_system(sysm, theta, r)
                x, whole = None, False  # the model's positions at the run's frames (NaN where not simulated)
                if js.size:
                    cls[js[0]] = c
                    keep = t <= t_max[r] if r in t_max else np.ones(t.size, bool)
                    tr = dsys.trajectory(rs, f, pdn, t[keep], duty=duty, waveform=wf, options=self.options)
                    x = np.full(t.size, np.nan)
                    x[keep] = tr[self.response]
                    whole = bool(keep.all())
                    pred[js], cls[js] = x[loc], c
                if drift >= 0:
                    # drift over the run's whole periods from rest, taken from the model's positions at the run's
                    # frames as the observed one is from the data's (run_drift); spread from the window SD. A run
                    # also compared by position up to its horizon was simulated at every frame above
                    cls[drift] = c
                    if not whole:
                        x = np.asarray(dsys.trajectory(rs, f, pdn, t, duty=duty, waveform=wf,
                                                       options=self.options)[self.response], float)
                    dur, pred[drift] = run_drift(t, x, f)
                    spread[drift] = ((s["window_sd_mm_s"] / 2) * dur if s and s["response_class"] == "irregular"
                                     else 0.0)
                    if starts:
                        spread[drift] = max(spread[drift], self._drift_start_sd(rs, r, pred[drift]))
        except (InputError, RuntimeError, ValueError, FloatingPointError) as exc:
            self.last_failure = str(exc)  # rows not reached stay NaN (a large penalty in the costs)
        return {"pred": pred, "spread": spread, "cls": cls, "by_position": by_position, "noise_factor": fac}

    def positions_mm(self, theta, run: str, t_s) -> np.ndarray:
        """Return the model's capsule position [mm] in trajectory ``run`` at the times ``t_s`` [s], from rest at
        drive phase 0 (any times: a frame that is not a comparison row, such as one left out as an outlier)."""
        f, pdn, duty, wf = self.run_drive[run]
        tr = dsys.trajectory(self.run_system(self.system(theta), theta, run), f, pdn, np.asarray(t_s, float),
                             duty=duty, waveform=wf, options=self.options)
        return np.asarray(tr[self.response], float)

    def _drift_start_sd(self, sysm: dsys.DynSystem, run: str, drift_mm: float) -> float:
        """Return the SD [mm] of trajectory ``run``'s drift (:func:`run_drift`) over its runs from rest (``drift_mm``)
        and from START_OFFSETS_M, times sqrt(1 + 1 / starts) (the SD of a new run's drift about their mean), as
        :meth:`_start_spread` does for a progression condition. A run is compared by its drift because its path
        from rest is not predictable; its drift need not be either: three 3-s runs with nothing missing, the
        22 Hz / 0.15 N run's drift over 3 s spread by 0.96 mm over starts 1-10 um from rest (noise 0.3 mm a
        frame), its window term by 0.0008 mm. 0 where a start fails."""
        f, pdn, duty, wf = self.run_drive[run]
        t = self._run_t[run]
        v = [drift_mm]
        try:
            for x0 in START_OFFSETS_M:
                tr = dsys.trajectory(sysm, f, pdn, t, duty=duty, waveform=wf, options=self.options,
                                     start_offset_m=x0)
                v.append(run_drift(t, tr[self.response], f)[1])
        except (InputError, RuntimeError, ValueError, FloatingPointError):
            return 0.0
        return float(np.std(v, ddof=1) * math.sqrt(1.0 + 1.0 / len(v)))


#: A trajectory run whose steady response is irregular is still compared by position when the model's path
#: from rest is predictable over the run: the capsule positions at its frames, run again from the starting
#: states START_OFFSETS_M (1-10 um from rest), stay within this distance [mm] of the path from rest. Half a
#: pixel of a camera that images a 100 mm field over 1000 pixels, and a tenth to a half of the sub-millimetre
#: position noise of video tracking. Measured over 2 s on 220 runs (five models, 11 frequencies 10-40 Hz x
#: P_d 0.1-0.3 N): a start 10 um off moves most paths by 0.003-0.05 mm (the offset carried through), a chaotic
#: one by 0.2-50 mm; 6 of the 63 runs whose steady response is irregular stay within 0.05 mm. With a secondary
#: constraint at G_2 = 0.3 mm (configs/designs/trajectory_runs.csv) the 30 Hz run's steady response is
#: irregular while its starts stay within 0.02 mm over its second; before, every such run was reduced to one
#: average-velocity row (four 1-s runs, irregular for the fitted models: four rows, "the data cannot tell").
PREDICTABLE_SPREAD_MM = 0.05


def whole_periods_s(t_max_s: float, f_Hz: float) -> float:
    """Return T = k / f [s], the end of the last whole drive period by ``t_max_s`` (at least one period)."""
    return max(int(math.floor(t_max_s * f_Hz + 1e-9)), 1) / f_Hz


def run_drift(t_s: np.ndarray, x_mm: np.ndarray, f_Hz: float) -> tuple[float, float]:
    """Return (T [s], x(T) - x(0) [mm]): a trajectory run's drift over its whole drive periods from rest
    (T: :func:`whole_periods_s` of its last frame), the positions linearly interpolated between the frames
    around 0 and T. The observed drift and the model's are both taken this way, the model's from its positions
    at the run's own frames: interpolating between frames 10 ms apart, across the capsule's steps, biases the
    drift (24 Hz, P_d 0.15 N, 100 frames/s: -42.685 mm interpolated at T = 14 / 24 s against -42.809 exact),
    and an exact model drift against an interpolated observed one read that bias as a misfit (null
    trajectories: the irregular 24 Hz run's row 2.1-3.3 noise SDs off in every seed, tilt_friction named by
    the F test in 4 of 27 data sets)."""
    o = np.argsort(t_s, kind="stable")
    t, x = np.asarray(t_s, float)[o], np.asarray(x_mm, float)[o]
    T = whole_periods_s(float(t.max()), f_Hz)
    return T, float(np.interp(T, t, x) - np.interp(0.0, t, x))


def drift_weights(t_s: np.ndarray, f_Hz: float) -> np.ndarray:
    """Return the weight [-] :func:`run_drift` puts on each frame (``t_s`` in any order; the drift is linear in the
    positions, sum_i w_i x_i): -1 at t = 0 (or -(1 - l), -l on the frames around it) and +1 at T, or 1 - l, l on
    the two frames around it; 0 elsewhere. Only these frames move a run's average-velocity row."""
    t = np.asarray(t_s, float)
    o = np.argsort(t, kind="stable")
    ts = t[o]
    T = whole_periods_s(float(ts.max()), f_Hz)
    w = np.zeros(ts.size)
    for x, sign in ((T, 1.0), (0.0, -1.0)):
        j = int(np.clip(np.searchsorted(ts, x, side="right") - 1, 0, ts.size - 1))
        if j + 1 < ts.size and ts[j] < x:
            lam = (x - ts[j]) / (ts[j + 1] - ts[j])
            w[j] += sign * (1.0 - lam)
            w[j + 1] += sign * lam
        else:
            w[j] += sign
    out = np.zeros(ts.size)
    out[o] = w
    return out


def drift_noise_factor(t_s: np.ndarray, f_Hz: float) -> float:
    """Return the noise SD of a run's drift x(T) - x(0) (:func:`run_drift`) in units of one frame's position
    noise SD [-]: the norm of the interpolation weights the drift puts on the frames (:func:`drift_weights`;
    white noise). Frames at t = 0 and T give sqrt(2); T between two frames sqrt(1 + (1 - l)^2 + l^2). An
    average-velocity row standardised by one frame's noise counted a drift that the noise moves by 0.42 mm
    (0.3 mm per frame) as known to 0.3 mm: three 3-s runs with nothing missing, tilt_friction fitted two such
    rows of the two runs the position frames do not cover and passed the F test at p = 5e-5 (0.0017 with the
    drifts' own noise and spread: still named, a false alarm of that noise draw)."""
    return float(np.sqrt(np.sum(drift_weights(t_s, f_Hz) ** 2)))


def row_variance(sigma: float, sim: dict) -> np.ndarray:
    """Return each comparison row's error variance [response unit^2]: sigma^2 f_i^2 + s_i^2, f_i the row's noise
    factor (``sim['noise_factor']``: 1 for a frame or a progression reading, :func:`drift_noise_factor` for a
    trajectory run's drift) and s_i the model's spread there."""
    f = sim.get("noise_factor")
    f2 = 1.0 if f is None else np.asarray(f, float) ** 2
    return sigma ** 2 * f2 + np.nan_to_num(sim["spread"]) ** 2


def choose_modes(bound: DynBound, theta) -> dict[str, str]:
    """Return per trajectory run 'position', 'average_velocity' or 'position to T s'.

    'position' where the model's steady response at the run's drive is not irregular (no period <= 8;
    RUN_CLASS_PROTOCOL) or its path from rest is predictable over the run (:meth:`DynBound.start_spread_path`
    within PREDICTABLE_SPREAD_MM at every frame). Otherwise the run's average velocity over its whole periods,
    and, when its path stays predictable for at least MIN_HORIZON_PERIODS drive periods, its positions up to
    the last frame T before the spread first exceeds PREDICTABLE_SPREAD_MM ('position to T s': both)."""
    summ = bound.run_summary(theta)
    out = {}
    for r, s in summ.items():
        if s["response_class"] != "irregular":
            out[r] = "position"
            continue
        spread = bound.start_spread_path(theta, r)
        off = np.flatnonzero(~(spread <= PREDICTABLE_SPREAD_MM))
        if off.size == 0:
            out[r] = "position"
            continue
        t = dict(bound.runs)[r]["time_s"].to_numpy(float)
        until = float(t[off[0] - 1]) if off[0] > 0 else 0.0
        out[r] = (position_until(until) if until * bound.run_drive[r][0] >= MIN_HORIZON_PERIODS - 1e-9
                  else "average_velocity")
    return out


#: the shortest predictability horizon [drive periods] for which a run with an unpredictable path keeps its
#: frames up to it: the first horizon of the calibration's continuation (HORIZON_PERIODS), where the
#: positions from rest already identify a secondary constraint's gap and stiffness
MIN_HORIZON_PERIODS = 3.0


def position_until(t_s: float) -> str:
    """Return the comparison mode of a run compared by position up to t_s [s] (and by its average velocity)."""
    return f"position to {t_s:.9g} s"


def position_horizon_s(mode: str) -> float | None:
    """Return T [s] of a mode 'position to T s', else None."""
    if mode.startswith("position to "):
        return float(mode.split()[2])
    return None


def merge_modes(a: str, b: str) -> str:
    """Return the more informative of two comparison modes of one run: position, then position to the later
    horizon, then average velocity."""
    def rank(m: str) -> float:
        return math.inf if m == "position" else (position_horizon_s(m) if position_horizon_s(m) is not None
                                                  else -1.0)
    return a if rank(a) >= rank(b) else b


def frames_by_position(rows: Sequence[tuple]) -> np.ndarray:
    """Return the mask of a trajectory's comparison rows (``DynBound.rows``: mode, run, table row) that are frames
    compared by position (not a run's average-velocity row)."""
    return np.array([mode == "position" for mode, _, _ in rows], bool)


def position_rows(rf: pd.DataFrame) -> np.ndarray:
    """Return the mask of a trajectory row frame's rows compared by position (every row when it has no
    ``compared`` column)."""
    return (rf["compared"] == "position").to_numpy() if "compared" in rf.columns else np.ones(len(rf), bool)
