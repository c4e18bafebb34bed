"""Built-in base models and effects of the dynamics kinds ``progression`` and ``trajectory``.

PROVISIONAL (issue 12): metadata only, so that model files and ``diagnose`` candidates
exist; issue 9 registers the definitive versions (the lead takes those at merge). The
physics lives in the engine (:mod:`capsule_cli.dynamics.system`): an effect here changes the
equations of motion, not a column of outputs, so ``apply`` is never called for the built-in
ones (it raises). Base parameter defaults come from ``configs/params/prototype_*.yaml``;
effect forms, off values and sources are the readings of physics.md section 3.
Effects that change the equations of motion combine by adding their terms: their order in a
model file does not matter.

A plugin effect of a dynamics kind (on today's engine) is a drive transform
``apply(drive, x, p, ctx) -> drive``, ``drive = {"f": Hz array, "Pd": N array}`` per condition.
"""
from __future__ import annotations

from ..config import load_param_set
from .registry import BaseModel, Effect, Param, register_base, register_effect

KINDS = ("progression", "trajectory")

_DESC = {
    "mass_magnet_g": "magnet (inner mass) M_m", "mass_capsule_g": "shell M_c", "gap_mm": "forward gap G_1",
    "spring_N_m": "helical spring stiffness k", "damping_Ns_m": "helical spring damping c",
    "constraint_N_m": "forward constraint stiffness k_1", "constraint_damping_Ns_m": "forward contact damping",
    "Pf_N": "Coulomb friction level P_f", "gap_back_mm": "backward gap G_2",
    "constraint_back_N_m": "backward constraint stiffness k_b", "constraint_back_damping_Ns_m": "backward contact damping",
}


def _engine_only(*_args, **_kw):
    raise RuntimeError("dynamics models are run by capsule_cli.dynamics.system, not by apply/predict")


def _base_params(set_name: str) -> tuple[Param, ...]:
    out = []
    for name, v in load_param_set(set_name).items():
        v = float(v)
        hi = max(10.0 * v, 1.0) if name != "Pf_N" else 5.0
        out.append(Param(name, v, (0.0, hi), description=_DESC.get(name, name)))
    return tuple(out)


_EFFECTS = (
    dict(name="speed_dependent_friction",
         description="Shell friction grows with sliding speed: kinetic level P_f + a |V_c|^n (V in mm/s, F in mN), "
                     "breakaway max(P_f, law at 0+), law held below V_min (well posed).",
         source="seed 000 eqs 17-18 and 22-23 (b = P_f); physics.md section 3",
         params=(Param("a_mN", 2.0, (0.0, 50.0), 0.0, description="speed-law coefficient a (V in mm/s)"),
                 Param("n", 0.5, (0.1, 1.5), 0.5, description="speed-law exponent n"))),
    dict(name="secondary_constraint",
         description="A backward constraint at X_r = -G_2: force k_b (X_r + G_2) + c_b V_r, not clipped.",
         source="seed 001 App. A; seed 002 Table 2 (97.06 N/mm, 0.35 N s/m)",
         bases=("one_sided",),
         params=(Param("gap_back_mm", 0.5, (0.02, 3.0), 0.5, description="backward gap G_2"),
                 Param("constraint_back_N_m", 5000.0, (0.0, 2e5), 0.0, description="backward stiffness k_b"),
                 Param("constraint_back_damping_Ns_m", 0.35, (0.0, 2.0), 0.0, free=False,
                       description="backward contact damping c_b (seed 002 Table 2; fixed unless freed)"))),
    dict(name="viscous_drag",
         description="A force -c_v V_c on the shell while it slides (mucus or lubricant film), added to friction.",
         source="seed 001 (lubricants at the capsule-mucosa interface); physics.md section 3",
         params=(Param("drag_Ns_m", 0.01, (0.0, 1.0), 0.0, description="viscous drag coefficient c_v"),)),
    dict(name="substrate_compliance",
         description="The wall deforms tangentially before the shell slides: spring 1/compliance with damper in "
                     "series with Coulomb friction (presliding).",
         source="seed 002 sections 4-5; physics.md section 3",
         params=(Param("compliance_mm_N", 0.1, (0.0, 10.0), 0.0, description="tangential wall compliance 1/k_s"),
                 Param("substrate_damping_Ns_m", 0.05, (0.0, 5.0), 0.05, free=False,
                       description="wall damping c_s (fixed unless freed)"))),
    dict(name="tilt_friction",
         description="The friction level is scaled by (1 + kappa X_r / G_1), held at zero below (capsule tilt).",
         source="seed 002 Fig 5; physics.md section 3",
         params=(Param("kappa", 0.2, (-0.95, 0.95), 0.0, description="tilt modulation kappa"),)),
)

for _kind in KINDS:
    for _base, _set, _src in (("one_sided", "prototype_one_sided", "seed 000 eqs 19-21, Table 2"),
                              ("double_sided", "prototype_double_sided", "seed 001 App. A; seed 002 Table 2")):
        register_base(BaseModel(name=_base, kind=_kind,
                                description=f"{_base.replace('_', '-')} vibro-impact capsule (event-driven engine)",
                                source=_src, params=_base_params(_set), predict=_engine_only))
    for _e in _EFFECTS:
        register_effect(Effect(kind=_kind, covariates=(), apply=_engine_only, **_e))
