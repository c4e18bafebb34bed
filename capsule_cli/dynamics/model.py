"""Parameters of the vibro-impact capsule model, drive and shell friction (SI), packed for the engine.

Sources: seed 000 eqs 19-23 and Table 2 (one-sided prototype, labels restored in
physics.md section 1); seed 001 Appendix A and seed 002 Table 2 (double-sided);
``configs/params/prototype_*.yaml`` and ``friction_laws_dynamics.yaml`` hold the
published numbers with their citations.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from ..config import load_param_set
from ..errors import InputError
from ..units import to_si
from . import engine as E

#: parameter names of the model files (contract section 4) -> attribute of :class:`CapsuleModel`
MODEL_PARAM_NAMES = {
    "mass_magnet_g": "mass_magnet_kg",
    "mass_capsule_g": "mass_capsule_kg",
    "gap_mm": "gap_m",
    "spring_N_m": "spring_N_m",
    "damping_Ns_m": "damping_Ns_m",
    "constraint_N_m": "constraint_N_m",
    "constraint_damping_Ns_m": "constraint_damping_Ns_m",
    "gap_back_mm": "gap_back_m",
    "constraint_back_N_m": "constraint_back_N_m",
    "constraint_back_damping_Ns_m": "constraint_back_damping_Ns_m",
    # parameters of the dynamics effects (capsule_cli/effects/dynamics.py; physics.md section 3)
    "a_mN": "speed_a_N",
    "n": "speed_n",
    "drag_Ns_m": "drag_Ns_m",
    "kappa": "tilt_kappa",
    "compliance_mm_N": "compliance_m_N",
    "substrate_damping_Ns_m": "substrate_damping_Ns_m",
}
#: the model-file name of each :class:`CapsuleModel` field (the messages name what the user wrote)
FILE_PARAM_NAMES = {field: name for name, field in MODEL_PARAM_NAMES.items()}


@dataclass(frozen=True)
class CapsuleModel:
    """Two-mass vibro-impact capsule (seed 000 eqs 19-20; seed 001 App. A), SI units.

    mass_magnet_kg : M_m [kg]; mass_capsule_kg : M_c [kg]; spring_N_m : k [N/m];
    damping_Ns_m : c [N s/m]; gap_m : G_1 [m]; constraint_N_m : k_1 [N/m];
    constraint_damping_Ns_m : front contact damping [N s/m] (0 for seed 000's one-sided model);
    double_sided : add the back constraint k_b at x_r <= -G_2 (seed 001 App. A).

    Dynamics effects (physics.md section 3, "Dynamics effects"; each 0 = off = the base exactly):
    speed_a_N : a [N] of the kinetic level P_f + a |V_c / (1 mm/s)|^speed_n (``speed_dependent_friction``,
    the eqs 22-23 form with b = P_f); drag_Ns_m : c_v [N s/m] of the drag -c_v V_c on the sliding
    shell (``viscous_drag``); tilt_kappa : kappa [-] of the level P_f (1 + kappa x_r / G_1), held
    at zero below (``tilt_friction``); compliance_m_N : 1/k_s [m/N] and substrate_damping_Ns_m : c_s [N s/m]
    of the presliding spring-damper between shell and contact patch (``substrate_compliance``; 0 =
    rigid wall). ``secondary_constraint`` sets double_sided with k_b, c_b.
    """

    mass_magnet_kg: float = 1.8e-3
    mass_capsule_kg: float = 1.67e-3
    spring_N_m: float = 62.0
    damping_Ns_m: float = 0.0156
    gap_m: float = 1.6e-3
    constraint_N_m: float = 27.9e3
    constraint_damping_Ns_m: float = 0.0
    double_sided: bool = False
    gap_back_m: float = 0.1e-3
    constraint_back_N_m: float = 0.0
    constraint_back_damping_Ns_m: float = 0.0
    speed_a_N: float = 0.0
    speed_n: float = 0.25
    drag_Ns_m: float = 0.0
    tilt_kappa: float = 0.0
    compliance_m_N: float = 0.0
    substrate_damping_Ns_m: float = 0.0
    #: user plugin forces (role "force", :mod:`capsule_cli.dynamics.plugin_force`): ((kind, effect name,
    #: its parameters in SI in declaration order), ...); their forces add
    plugin_forces: tuple = ()

    @property
    def back_active(self) -> bool:
        """True when the backward constraint exerts a force (double-sided with k_b or c_b > 0):
        with k_b = c_b = 0 it is absent, so the model is the one-sided one exactly."""
        return self.double_sided and (self.constraint_back_N_m > 0 or self.constraint_back_damping_Ns_m > 0)

    def validate(self, where: str = "model", given: Mapping[str, float] | None = None) -> "CapsuleModel":
        """Return self when every field makes a capsule, else raise InputError (one line, prefixed ``where``).

        given: the values as the user wrote them, by model-file name (``mass_capsule_g: -1``); a bad field found
        there is named and shown as written (``mass_capsule_g must be a positive number, got -1.0``), not in SI.
        """
        def bad(field: str, what: str) -> InputError:
            name, shown = field, getattr(self, field)
            file_name = FILE_PARAM_NAMES.get(field)
            if given is not None and file_name in given:
                name, shown = file_name, float(given[file_name])
            return InputError(f"{where}: {name} must be {what}, got {shown}")

        for name in ("mass_magnet_kg", "mass_capsule_kg", "spring_N_m", "gap_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise bad(name, "a positive number")
        for name in ("damping_Ns_m", "constraint_N_m", "constraint_damping_Ns_m", "constraint_back_N_m",
                     "constraint_back_damping_Ns_m", "gap_back_m", "speed_a_N", "drag_Ns_m",
                     "compliance_m_N", "substrate_damping_Ns_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise bad(name, "a non-negative number")
        if not (math.isfinite(self.speed_n) and self.speed_n > 0):
            raise bad("speed_n", "a positive number (the speed-law exponent)")
        if not math.isfinite(self.tilt_kappa):
            raise bad("tilt_kappa", "a finite number")
        if self.double_sided and not self.gap_back_m > 0:
            raise bad("gap_back_m", "> 0 for the double-sided model")
        return self

    @classmethod
    def from_params(cls, params: dict[str, float], double_sided: bool | None = None,
                    where: str = "params") -> "CapsuleModel":
        """Build from model-file names (``mass_magnet_g: 1.8`` ...); unknown names are errors."""
        kw = {}
        for name, value in params.items():
            if name == "Pf_N":
                continue
            if name not in MODEL_PARAM_NAMES:
                raise InputError(f"{where}: unknown model parameter '{name}' "
                                 f"(known: {', '.join(sorted(MODEL_PARAM_NAMES))}, Pf_N)")
            kw[MODEL_PARAM_NAMES[name]] = float(to_si(float(value), name))
        if double_sided is None:
            double_sided = "constraint_back_N_m" in params
        kw["double_sided"] = bool(double_sided)
        return cls(**kw).validate(where, given=params)

    def with_param(self, name: str, value: float) -> "CapsuleModel":
        """Return a copy with one model-file parameter (unit from its suffix) changed."""
        if name not in MODEL_PARAM_NAMES:
            raise InputError(f"unknown model parameter '{name}' (known: {', '.join(sorted(MODEL_PARAM_NAMES))})")
        return replace(self, **{MODEL_PARAM_NAMES[name]: float(to_si(value, name))}).validate(given={name: value})


#: parameter set behind each dynamics base model of a model file (contract section 4)
BASE_PARAM_SETS = {"one_sided": "prototype_one_sided", "double_sided": "prototype_double_sided"}


def _is_model_file(name: str) -> bool:
    from pathlib import Path
    path = Path(name)
    if path.suffix not in (".yaml", ".yml") or not path.is_file():
        return False
    from ..config import read_yaml
    data = read_yaml(path)
    return isinstance(data, dict) and "kind" in data and "base" in data


def load_model(name: str = "prototype_one_sided") -> tuple[CapsuleModel, float | None]:
    """Return (model, P_f [N] or None) from ``configs/params/<name>.yaml``, a parameter-set path,
    or a dynamics model file (contract section 4: kind progression/trajectory, base one_sided or
    double_sided; the base's parameter set overridden by the file's params, free or fixed, at
    their values)."""
    if _is_model_file(name):
        from ..config import load_model_file
        mf = load_model_file(name)
        if mf.kind not in ("progression", "trajectory"):
            raise InputError(f"{name}: kind '{mf.kind}' is not a dynamics model (progression or trajectory)")
        if mf.base not in BASE_PARAM_SETS:
            raise InputError(f"{name}: base '{mf.base}' is not a dynamics base model "
                             f"({', '.join(BASE_PARAM_SETS)})")
        from .system import plugin_roles, resolve_params
        given = {key: float(val if isinstance(val, (int, float)) else val.value) for key, val in mf.params.items()}
        # the base's parameter set, the effects' start values, the file's values (effect terms as data)
        params = resolve_params(mf.base, given, tuple(mf.effects), where=f"{name}: ")
        drives, forces = plugin_roles(tuple(mf.effects), params, where=f"{name}: ")
        if drives:  # applied per data row by synth / compare / diagnose; never silently dropped here
            raise InputError(f"{name}: plugin drive transform(s) {', '.join(e.name for e, _ in drives)} act on "
                             "a data table's drive conditions (synth, compare, diagnose); simulate, sweep and "
                             "magnify take the drive as given: drop them from this model file")
        # plugin parameters live in plugin_forces (and drive transforms in the system), not in the model
        params = {k: v for k, v in params.items() if k in MODEL_PARAM_NAMES or k == "Pf_N"}
        where = str(name)
        double_sided = mf.base == "double_sided" or "secondary_constraint" in mf.effects
    else:
        params = load_param_set(name)
        where = str(name)
        double_sided = None
        forces = ()
    pf = params.pop("Pf_N", None)
    model = CapsuleModel.from_params({**params, **({} if pf is None else {"Pf_N": pf})}, double_sided=double_sided,
                                     where=where)
    if forces:
        model = replace(model, plugin_forces=forces)
    return model, (None if pf is None else float(pf))


@dataclass(frozen=True)
class Drive:
    """External force on the magnet: harmonic P_d cos(2 pi f t) (seed 000) or square wave
    P_d on [nT, nT + D T) (seed 001 App. A). amplitude_N [N], frequency_Hz [Hz], duty [-]."""

    amplitude_N: float = 0.15
    frequency_Hz: float = 30.0
    waveform: str = "harmonic"
    duty: float = 0.5

    def validate(self) -> "Drive":
        if self.waveform not in ("harmonic", "square"):
            raise InputError(f"waveform must be 'harmonic' or 'square', got '{self.waveform}'")
        if not (math.isfinite(self.frequency_Hz) and self.frequency_Hz > 0):
            raise InputError(f"frequency must be > 0 Hz, got {self.frequency_Hz}")
        if not (math.isfinite(self.amplitude_N) and self.amplitude_N >= 0):
            raise InputError(f"drive amplitude must be >= 0 N, got {self.amplitude_N}")
        if self.waveform == "square" and not 0 < self.duty < 1:
            raise InputError(f"duty must lie in (0, 1), got {self.duty}")
        return self


@dataclass(frozen=True)
class Friction:
    """Shell friction (seed 000 eqs 21-23; physics.md section 3), SI.

    kind: 'coulomb' (P_s = P_k = level_N unless static_N given), 'eq22', 'eq23', 'fixed' (P_f = inf),
    or 'law' (a V^n + b with given coefficients).
    The speed laws are F[mN] = a V[mm/s]^n + b. Well-posed mode (default): breakaway
    = max(static, law at 0+ after the hold), law held at its value at V_min below V_min.
    literal=True: breakaway = static as written and the law used down to V = 0 (eq 22 is then
    ill-posed and the engine stops with a clear error instead of looping).
    """

    kind: str = "coulomb"
    level_N: float = 0.0078
    static_N: float | None = None
    a_mN: float = 0.0
    n: float = 0.25
    b_mN: float = 0.0
    v_min_mm_s: float = 0.2
    literal: bool = False
    speed_unit: str = "mm/s"

    @property
    def a_mm_s(self) -> float:
        """Coefficient a [mN] of the law written with V in mm/s.

        ``speed_unit = 'm/s'`` evaluates the law as if V were in m/s (a V[m/s]^n + b): a
        sensitivity case for the hypothesis that seed 000's simulation fed SI speeds to a law fitted
        in mm/s (docs/dynamics.md); the default 'mm/s' is the reading of physics.md section 3.
        """
        return self.a_mN * (1e-3 ** self.n if self.speed_unit == "m/s" else 1.0)

    def validate(self) -> "Friction":
        if self.kind not in ("coulomb", "eq22", "eq23", "fixed", "law"):
            raise InputError(f"unknown friction '{self.kind}' (coulomb, eq22, eq23, fixed, law)")
        if self.kind == "coulomb":
            if not self.level_N > 0:
                raise InputError(f"friction level P_f must be > 0 N (use --friction fixed for P_f = inf), "
                                 f"got {self.level_N}")
            if self.static_N is not None and not (math.isfinite(self.static_N) and self.static_N > 0):
                raise InputError(f"static friction level must be a finite number > 0 N, got {self.static_N}")
        if self.speed_unit not in ("mm/s", "m/s"):
            raise InputError(f"law speed unit must be 'mm/s' or 'm/s', got '{self.speed_unit}'")
        if self.kind in ("eq22", "eq23", "law"):
            if not self.v_min_mm_s >= 0:
                raise InputError(f"V_min must be >= 0 mm/s, got {self.v_min_mm_s}")
            if not self.literal and not self.v_min_mm_s > 0:
                raise InputError("V_min must be > 0 mm/s for the well-posed speed law (or use literal)")
        return self

    def kinetic_N(self, speed_m_s):
        """Return the kinetic level [N] at slip speed [m/s] (the regularised law)."""
        v = np.abs(np.asarray(speed_m_s, dtype=float))
        if self.kind == "coulomb":
            return np.full_like(v, self.level_N)
        if self.kind == "fixed":
            return np.full_like(v, np.inf)
        vmm = v * 1e3
        if not self.literal:
            vmm = np.maximum(vmm, self.v_min_mm_s)
        return 1e-3 * (self.a_mm_s * vmm ** self.n + self.b_mN)

    def levels(self) -> tuple[float, float, float]:
        """Return (breakaway P_b [N], kinetic level below V_min L0 [N], V_min [m/s])."""
        if self.kind == "fixed":
            return math.inf, math.inf, math.inf
        if self.kind == "coulomb":
            if self.static_N is None:
                pb = self.level_N
            else:  # well posed: breakaway never below the kinetic level (unless literal)
                pb = self.static_N if self.literal else max(self.static_N, self.level_N)
            return pb, self.level_N, math.inf
        static = self.static_N if self.static_N is not None else 0.0
        if self.literal:
            return static, 1e-3 * self.b_mN, 0.0
        l0 = 1e-3 * (self.a_mm_s * self.v_min_mm_s ** self.n + self.b_mN)
        return max(static, l0), l0, self.v_min_mm_s * 1e-3


def friction_preset(kind: str, level_N: float | None = None, literal: bool = False,
                    v_min_mm_s: float | None = None, laws: dict[str, float] | None = None,
                    speed_unit: str = "mm/s", static_N: float | None = None) -> Friction:
    """Return a friction model by name: coulomb (level P_f), eq22, eq23, fixed.

    The eq 22/23 coefficients come from ``configs/params/friction_laws_dynamics.yaml``
    (seed 000 eqs 17-18, 22-23); ``speed_unit`` is the unit V is taken in (see Friction.a_mm_s).
    """
    if kind == "fixed":
        return Friction(kind="fixed").validate()
    if kind == "coulomb":
        if level_N is None:
            raise InputError("Coulomb friction needs a level P_f in N (--Pf-N)")
        if math.isinf(level_N):
            return Friction(kind="fixed").validate()
        return Friction(kind="coulomb", level_N=float(level_N), static_N=None if static_N is None else float(static_N),
                        literal=literal).validate()
    if kind not in ("eq22", "eq23"):
        raise InputError(f"unknown friction '{kind}' (coulomb, eq22, eq23, fixed)")
    L = laws if laws is not None else load_param_set("friction_laws_dynamics")
    pre = kind
    vmin = L["v_min_mm_s"] if v_min_mm_s is None else v_min_mm_s
    return Friction(kind=kind, static_N=L[f"{pre}_static_mN"] * 1e-3, a_mN=L[f"{pre}_a_mN"],
                    n=L[f"{pre}_n"], b_mN=L[f"{pre}_b_mN"], v_min_mm_s=float(vmin),
                    literal=literal, speed_unit=speed_unit).validate()


def effective_friction(model: CapsuleModel, friction: Friction) -> Friction:
    """Return the shell friction with the model's ``speed_dependent_friction`` term applied.

    physics.md section 3 ("Dynamics effects"): the kinetic level becomes P_f + a |V_c|^n (V in
    mm/s, the eqs 22-23 form with b = P_f), well posed as eqs 22-23 are: breakaway = max(static,
    law at 0+) and the law held below V_min (``configs/params/friction_laws_dynamics.yaml``,
    0.2 mm/s). With a = 0 (off), or for a shell held fixed, ``friction`` is returned unchanged.
    Only a Coulomb base friction takes the term (eqs 22-23 already are speed laws).
    """
    if model.speed_a_N == 0.0 or friction.kind == "fixed":
        return friction
    if friction.kind != "coulomb":
        raise InputError(f"speed_dependent_friction adds a |V|^n to a Coulomb level; the friction "
                         f"'{friction.kind}' already is a speed law")
    vmin = load_param_set("friction_laws_dynamics")["v_min_mm_s"]
    static = friction.level_N if friction.static_N is None else friction.static_N
    return Friction(kind="law", static_N=static, a_mN=model.speed_a_N * 1e3, n=model.speed_n,
                    b_mN=friction.level_N * 1e3, v_min_mm_s=float(vmin), literal=friction.literal).validate()


#: damping ratio zeta_s = c_s / (2 sqrt(k_s M_c)) of the presliding element below which the engine takes
#: the exact c_s -> 0 limit: the sliding patch then relaxes in c_s / k_s = 2 zeta_s / omega_s, under 1e-6 of
#: the shell's ringing period on the presliding spring. Measured (40-condition progression design,
#: tests/test_dynamics_effects.py): average velocities of every periodic response unchanged to 1e-3 mm/s
#: between zeta_s ~ 1e-6 and c_s = 0; below ~1e-8 the patch mode (rate k_s / c_s > 1e12 / s) is too stiff
#: for the eigenvector-conditioned exact path and its adaptive fallback stalls. A numerical limit, not a
#: physical parameter.
PATCH_ZETA_MIN = 1e-6


def patch_damping_Ns_m(model: CapsuleModel) -> float:
    """Return the presliding damper c_s [N s/m] the engine integrates (``substrate_compliance``,
    physics.md section 3): the model's c_s, or 0 (the exact c_s -> 0 limit) when its damping ratio
    c_s / (2 sqrt(k_s M_c)) is below :data:`PATCH_ZETA_MIN`."""
    cs = model.substrate_damping_Ns_m
    if cs <= 0.0 or model.compliance_m_N <= 0.0:
        return 0.0
    zeta = cs / (2.0 * math.sqrt(model.mass_capsule_kg / model.compliance_m_N))
    return cs if zeta >= PATCH_ZETA_MIN else 0.0


def pack_params(model: CapsuleModel, drive: Drive, friction: Friction) -> np.ndarray:
    """Return the engine's parameter vector (SI) for a model, drive and friction.

    The one place where the row layout of ``engine.I_*`` is filled; the model's dynamics effects
    (speed law, drag, tilt, backward constraint) enter here, each off at 0.
    """
    friction = effective_friction(model, friction)
    back = model.back_active
    p = np.zeros(E.N_PARAMS)
    p[E.I_MM] = model.mass_magnet_kg
    p[E.I_MC] = model.mass_capsule_kg
    p[E.I_K] = model.spring_N_m
    p[E.I_C] = model.damping_Ns_m
    p[E.I_G1] = model.gap_m
    p[E.I_K1] = model.constraint_N_m
    p[E.I_C1] = model.constraint_damping_Ns_m
    p[E.I_G2] = model.gap_back_m if back else 1e300
    p[E.I_KB] = model.constraint_back_N_m if back else 0.0
    p[E.I_CB] = model.constraint_back_damping_Ns_m if back else 0.0
    p[E.I_BACK] = 1.0 if back else 0.0
    p[E.I_PD] = drive.amplitude_N
    p[E.I_F] = drive.frequency_Hz
    p[E.I_WAVE] = 0.0 if drive.waveform == "harmonic" else 1.0
    p[E.I_DUTY] = drive.duty
    pb, l0, vmin = friction.levels()
    p[E.I_PB] = pb
    p[E.I_L0] = l0
    p[E.I_VMIN] = vmin
    speed_law = friction.kind in ("eq22", "eq23", "law")
    p[E.I_LAW] = 1.0 if speed_law else 0.0
    if speed_law:
        # F = 1e-3 [a (1e3 V)^n + b]  with V in m/s, F in N
        p[E.I_LA] = 1e-3 * friction.a_mm_s * 1e3 ** friction.n
        p[E.I_LN] = friction.n
        p[E.I_LB] = 1e-3 * friction.b_mN
    p[E.I_CV] = model.drag_Ns_m
    p[E.I_KAP] = model.tilt_kappa
    compliant = model.compliance_m_N > 0
    if compliant:
        if speed_law and model.substrate_damping_Ns_m > 0:
            raise InputError("substrate_compliance with c_s > 0 takes a Coulomb friction level: a speed law "
                             "would be implicit in the patch speed (use substrate_damping_Ns_m = 0)")
        p[E.I_KS] = 1.0 / model.compliance_m_N
        p[E.I_CS] = patch_damping_Ns_m(model)
    # slips faster than I_VFAST go on the adaptive path: above V_min for a held speed law; every
    # slip under the literal law (no held level); never for Coulomb. Drag, tilt and substrate
    # compliance keep the modes linear: the engine solves them exactly (general linear modes).
    rk_all = speed_law and friction.literal
    p[E.I_VFAST] = 0.0 if rk_all else (vmin if speed_law else math.inf)
    mu = model.mass_magnet_kg * model.mass_capsule_kg / (model.mass_magnet_kg + model.mass_capsule_kg)
    xs = max(model.gap_m, drive.amplitude_N / model.spring_N_m, 1e-6)
    fs = max(drive.amplitude_N, model.spring_N_m * xs, pb if math.isfinite(pb) else 0.0)
    om = 2 * math.pi * drive.frequency_Hz
    p[E.I_XS] = xs
    p[E.I_FS] = fs
    p[E.I_VS] = xs * max(om, math.sqrt(model.spring_N_m / mu))
    if model.plugin_forces:
        from .plugin_force import pack_forces
        pack_forces(p, model.plugin_forces)
    return p


#: Settled-transient tolerance of steady-state runs (maps, sweeps, progression speeds; EngineOptions.settle_tol),
#: a fraction of the state scales: the transient ends early, by whole orbits, once the state at phase 0
#: repeats after 1-8 periods this closely (issue 13). Measured on an 8 x 8 subset of the seed 000 Fig 19 grid
#: (200 + 30 periods from rest, rk_rtol 1e-9) against the full transient: A_f moves by at most 2e-10 (Coulomb
#: and fixed panels) and 6e-9 (eq22, eq23), the average velocity by at most 8e-8 mm/s, and the time falls to
#: 0.15-0.32 (Coulomb, fixed) and 0.63-0.66 (eq22, eq23) of the full transient's. simulate keeps 0 (every period).
#: With a speed law the engine uses at least SETTLE_RTOL_FRACTION x rk_rtol (engine.py), and runs without samples,
#: events or energy fill their recorded periods from the first settled orbit (session 10: docs/dynamics.md).
STEADY_SETTLE_TOL = 1e-12


@dataclass
class EngineOptions:
    """Numerical options: samples_per_fast_period (bracketing grid, 1/N of the fastest modal
    period), energy (accumulate the energy balance), rk_rtol (relative tolerance of the speed-law
    slip's DOP853), zeno_max (zero-length events tolerated in a row), rk_max_steps (per segment),
    exact_general_modes
    (solve the linear modes of drag, tilt and substrate compliance exactly; False integrates them on
    the adaptive path, a cross-check), settle_tol (0: run every transient period; > 0: end the
    transient early, by whole orbits, once the state at phase 0 repeats after 1 to 8 periods within
    settle_tol times the state scales, in the same contact and shell state: the steady state is then
    reached, and the recorded periods are those of the full transient up to that tolerance; a run
    that records no samples, events or energy also fills its recorded periods from the first recorded
    orbit; with a speed law the tolerance is at least SETTLE_RTOL_FRACTION x rk_rtol (engine.py), the
    adaptive path's own accuracy; never with a plugin force)."""

    samples_per_fast_period: float = 8.0
    energy: bool = True
    rk_rtol: float = 1e-11
    zeno_max: int = 200
    rk_max_steps: int = 2_000_000
    exact_general_modes: bool = True
    settle_tol: float = 0.0
    extra: dict = field(default_factory=dict)

    def pack(self) -> np.ndarray:
        o = np.zeros(E.N_OPTS)
        o[E.O_NPER] = self.samples_per_fast_period
        o[E.O_ENERGY] = 1.0 if self.energy else 0.0
        o[E.O_RTOL] = self.rk_rtol
        o[E.O_ZENO] = self.zeno_max
        o[E.O_MAXSTEPS] = self.rk_max_steps
        o[E.O_EXACT] = 1.0 if self.exact_general_modes else 0.0
        o[E.O_SETTLE] = self.settle_tol
        return o
