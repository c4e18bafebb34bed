"""Built-in base model and effect of the ``relaxation`` kind (response ``pressure_kPa`` over ``time_s``).

Pressure on a capsule held still in a contractive intestine after the wall was
stretched: P(t) = factor * E(t), with the three-element Maxwell modulus
(seed 003 eq 11) as the base and extra Prony arms (seed 004 eq 1) as effects.
"""
from __future__ import annotations

import numpy as np

from ..models import viscoelastic as ve
from ..models.contact import relaxation_pressure_factor
from . import _guess
from .constants import capsule_constants, published
from .registry import BaseModel, Effect, Param, register_base, register_effect

KIND = "relaxation"


def _default_factor() -> float:
    c = capsule_constants()
    return float(relaxation_pressure_factor(c["Ri_case3"], c["Rc"], c["wall"]))


def _maxwell(x, p, ctx):
    return np.asarray(ve.maxwell_relaxation_pressure_Pa(np.asarray(x["time"], float), p["E1"], p["E2"],
                                                        p["eta1"], p["factor"]), float)


register_base(BaseModel(
    name="maxwell", kind=KIND,
    description="Three-element Maxwell wall (one spring-dashpot arm E_1, eta_1 and a parallel spring E_2): "
                "P(t) = factor (E_1 exp(-t E_1/eta_1) + E_2), factor = t_i,e eps / R_c (0.0115 for R_i = 5 mm).",
    source="seed 003 eq 11 and Table 1 (E_1 = 196.43 kPa, E_2 = 757.48 kPa, eta_1 = 5.36 MPa s); seed 003 eq 13",
    params=(Param("E1_kPa", published("E1_kPa"), (0.1, 1e5), description="arm spring E_1"),
            Param("E2_kPa", published("E2_kPa"), (0.1, 1e5), description="equilibrium spring E_2"),
            Param("eta1_MPa_s", published("eta1_MPa_s"), (1e-4, 1e5), description="arm dashpot eta_1"),
            Param("factor", round(_default_factor(), 6), (1e-5, 1.0),
                  description="geometric factor t_i,e eps / R_c (E_1, E_2 and factor: only products identifiable)")),
    predict=_maxwell,
))


def _arm(y, x, p, ctx):
    if p["arm_E"] <= 0:
        return y
    t = np.asarray(x["time"], float)
    return y + ctx["factor"] * ve.prony_modulus_Pa(t, [p["arm_E"]], [p["arm_eta"]], 0.0)


def _arm_guess(r, x, ctx):
    t = np.asarray(x["time"], float)
    span = max(float(t.max() - t.min()), 1e-3)
    dt = float(np.median(np.diff(np.unique(t)))) if np.unique(t).size > 1 else span / 10
    taus = _guess.log_grid(max(dt / 2, 1e-3), span * 3, 60)
    i, a = _guess.scan(r, (np.exp(-t / tau) for tau in taus))
    E = max(a, 1e-3) / max(ctx["factor"], 1e-12)
    return {"arm_E": E, "arm_eta": E * float(taus[i])}


register_effect(Effect(
    name="maxwell_arm", kind=KIND,
    description="One more spring-dashpot arm of the generalised Maxwell (Prony) series, a second relaxation "
                "time: P += factor E_a exp(-t E_a/eta_a). Seed 003 cites a five-element (two-arm) model. "
                "Repeatable: maxwell_arm_2, maxwell_arm_3 ... add further arms (parameters arm_E_2_kPa, ...).",
    source="seed 004 eq 1; seed 003 Fig 5a",
    params=(Param("arm_E_kPa", 100.0, (0.0, 1e6), 0.0, description="arm spring E_a"),
            Param("arm_eta_MPa_s", 0.5, (1e-6, 1e5), 0.5, description="arm dashpot eta_a")),
    covariates=("time_s",), apply=_arm, guess=_arm_guess, repeatable=True,
))
