"""Built-in base models and effects of the ``pressure`` kind (response ``pressure_kPa``).

Bases: Hertz line contact of the capsule on a flat or open intestine (seed 003
eqs 2-5) and the viscoelastic hoop pressure of a contractive intestine on a
rigid capsule with hemispherical ends (seed 003 eqs 8-14). A ``statistic``
column (``avg``/``max``) selects the average or the maximum pressure per row.
Physics comes from :mod:`capsule_cli.models.contact`.
"""
from __future__ import annotations

import numpy as np

from ..models import contact as ct
from . import _guess
from .constants import published
from .friction import CURVATURE_PARAMS, sagitta_ratio
from .registry import BaseModel, Effect, Param, register_base, register_effect

KIND = "pressure"


def _n(x) -> int:
    return int(np.asarray(x["speed"]).size)


def _is_max(x) -> np.ndarray:
    st = x.get("statistic")
    if st is None:
        return np.zeros(_n(x), bool)
    return np.asarray([str(s).strip().lower() == "max" for s in st])


def _ri(x, p):
    """Inner radius per row: the table's Ri_mm column when present, else the parameter [m]."""
    return np.broadcast_to(np.asarray(x["Ri"] if "Ri" in x else p["Ri"], float), (_n(x),))


# ---------------------------------------------------------------------------
# base: Hertz


def _hertz(x, p, ctx):
    Ri = _ri(x, p)
    load = p["load"] * ctx["g"]
    args = (load, ctx["Rc"], Ri, ctx["L"], ctx["Ec"], ctx["nu_c"], ctx["Ei"], ctx["nu_i"])
    return np.where(_is_max(x), ct.hertz_pressure_max_Pa(*args), ct.hertz_pressure_avg_Pa(*args))


register_base(BaseModel(
    name="hertz", kind=KIND,
    description="Hertz line contact of the capsule body on the wall under the capsule's weight "
                "(flat or open intestine): P_avg = F/(2 a L), P_max = 2F/(pi a L); independent of speed.",
    source="seed 003 eqs 2-5 (Case 1: a = 0.236 mm, 0.55 kPa avg, 0.70 kPa max for 0.4 g)",
    params=(Param("load_g", published("load_FE_g"), (0.001, 1000.0), description="capsule load (mass)"),
            Param("Ri_mm", float("inf"), (0.5, float("inf")),
                  description="intestine inner radius (inf: flat); the table's Ri_mm column replaces it")),
    predict=_hertz, column_params=("Ri_mm",),
))


# ---------------------------------------------------------------------------
# base: hoop


def _hoop_args(x, p, ctx):
    return (np.abs(np.asarray(x["speed"], float)), _ri(x, p), ctx["Rc"], ctx["L"], p["wall"],
            p["E1"], p["E2"], p["eta1"])


def _hoop_pressure(x, p, ctx, end_length=None):
    args = _hoop_args(x, p, ctx)
    avg = ct.hoop_pressure_avg_Pa(*args, end_length_m=end_length)
    mx = _is_max(x)
    if mx.any():
        return np.where(mx, ct.hoop_pressure_max_Pa(*args, end_length_m=end_length), avg)
    return avg


def _hoop(x, p, ctx):
    return _hoop_pressure(x, p, ctx)


register_base(BaseModel(
    name="hoop", kind=KIND,
    description="Viscoelastic hoop pressure of a contractive intestine (R_i < R_c) stretched over a rigid "
                "capsule with hemispherical ends, averaged over the cylindrical body (three-element Maxwell "
                "wall, attenuated wall thickness); rises with speed, flat above about 4 mm/s.",
    source="seed 003 eqs 8-14 (10.92 kPa at 10 mm/s, 10.80 kPa at 4 mm/s for R_i = 5 mm; physics.md section 2)",
    params=(Param("Ri_mm", published("Ri_case3_mm", "contact_cases"), (0.5, 50.0),
                  description="intestine inner radius; the table's Ri_mm column replaces it"),
            Param("wall_mm", published("wall_mm"), (0.01, 10.0), description="wall thickness t_i"),
            Param("E1_kPa", published("E1_kPa"), (0.1, 1e5), description="Maxwell arm spring E_1"),
            Param("E2_kPa", published("E2_kPa"), (0.1, 1e5), description="equilibrium spring E_2"),
            Param("eta1_MPa_s", published("eta1_MPa_s"), (1e-4, 1e4), description="Maxwell arm dashpot eta_1")),
    predict=_hoop, column_params=("Ri_mm",),
))


# ---------------------------------------------------------------------------
# effects


def _wall_args(x, p, ctx):
    Ri = np.asarray(x["Ri"], float) if "Ri" in x else p["collapsed_Ri"]
    Ri = np.where(np.isfinite(Ri), Ri, p["collapsed_Ri"])
    return (Ri, ctx["wall"], ctx["rho_i"] * p["wall_weight_scale"], ctx["g"], ctx["Rc"], ctx["L"],
            ctx["Ec"], ctx["nu_c"], ctx["Ei"], ctx["nu_i"])


def _wall_weight(y, x, p, ctx):
    if p["wall_weight_scale"] <= 0:
        return y
    return y + ct.collapsed_wall_pressure_Pa(*_wall_args(x, p, ctx))


def _wall_weight_guess(r, x, ctx):
    p1 = float(np.mean(ct.collapsed_wall_pressure_Pa(*_wall_args(x, {"collapsed_Ri": ctx["Ri_case2"],
                                                                    "wall_weight_scale": 1.0}, ctx))))
    m = float(np.mean(r))
    return {"wall_weight_scale": float(np.clip((m / p1) ** 2 if m > 0 and p1 > 0 else 0.1, 1e-3, 50.0))}


register_effect(Effect(
    name="wall_weight", kind=KIND,
    description="A collapsed intestine's upper wall rests on the capsule (seed 003 eq 6, P_c2 = P_c + P_1): "
                "P_1 is the Hertz pressure of the wall's weight per length rho g t pi (R_i + t/2) on the capsule, "
                "scaled by the fraction carried (1 = the whole upper half, an upper bound). A constant: "
                "confounded with a free load.",
    source="seed 003 eq 6 and section 5 (Case 2: ~2 kPa measured, 1.85 kPa FE); capsule_cli.models.contact",
    params=(Param("wall_weight_scale", 1.0, (0.0, 50.0), 0.0, description="fraction of the wall weight carried"),
            Param("collapsed_Ri_mm", published("Ri_case2_mm", "contact_cases"), (1.0, 100.0), 13.0, free=False,
                  description="collapsed intestine radius (the table's Ri_mm when present)")),
    covariates=(), apply=_wall_weight, guess=_wall_weight_guess,
))


def _hoop_term(x, p, ctx):
    Ri = np.asarray(x["Ri"], float)
    Ri_safe = np.where(np.isfinite(Ri) & (Ri < ctx["Rc"]), Ri, ctx["Rc"])
    q = {"Ri": Ri_safe, "wall": ctx["wall"], "E1": ctx["E1"], "E2": ctx["E2"], "eta1": ctx["eta1"]}
    xx = {**x, "Ri": Ri_safe}
    return _hoop_pressure(xx, q, ctx)


def _hoop_effect(y, x, p, ctx):
    return y + p["hoop_scale"] * _hoop_term(x, p, ctx)


def _hoop_effect_guess(r, x, ctx):
    a, _ = _guess.amplitude_with_offset(r, _hoop_term(x, {}, ctx))
    return {"hoop_scale": max(a, 1e-6)}


register_effect(Effect(
    name="hoop_pressure", kind=KIND,
    description="Where the intestine's inner radius R_i is below the capsule's R_c the wall is stretched over "
                "it and adds a viscoelastic hoop pressure (seed 003 eqs 8-14), scaled by hoop_scale "
                "(1 = the seed's wall properties); zero where R_i >= R_c.",
    source="seed 003 eqs 8-14 and Table 1",
    params=(Param("hoop_scale", 1.0, (0.0, 20.0), 0.0, description="multiplier of the model's hoop pressure"),),
    covariates=("speed_mm_s", "Ri_mm"), apply=_hoop_effect, guess=_hoop_effect_guess, bases=("hertz",),
))


def _curvature(y, x, p, ctx):
    s = sagitta_ratio(x["bend_radius"], ctx["length_total"], ctx["Rc"])
    return y * np.clip(1.0 + p["curvature_gain"] * s ** p["curvature_exponent"], 0.0, None)


def _curvature_guess(r, x, ctx):
    s = sagitta_ratio(x["bend_radius"], ctx["length_total"], ctx["Rc"])
    a, _ = _guess.amplitude_with_offset(r, np.asarray(ctx["y0"]) * s, nonnegative=False)
    return {"curvature_gain": float(np.clip(a, -0.85, 45.0))}


register_effect(Effect(
    name="curvature", kind=KIND,
    description="In a bent intestine (bending radius R_b) the straight capsule pushes the wall aside by the "
                "sagitta s = l^2/(8 R_b) of its length l: P *= 1 + k (s/R_c)^m. Seed 001 (with mesentery): "
                "maximum pressure 23.80 kPa at R_b = 25 mm rising to 36.36 kPa at 10 mm; near the straight "
                "tube above 200 mm.",
    source="seed 001 section 5 (Fig 12)",
    params=CURVATURE_PARAMS, covariates=("bend_radius_mm",), apply=_curvature, guess=_curvature_guess,
))


def coating_factor(Ri_m, Rc_m, wall_m, E_wall_Pa, coating_m, E_coating_Pa):
    """Return the pressure ratio [-] of a coated to a bare rigid capsule: two springs in series.

    The stretched wall acts as a spring of stiffness per area k_w = E_w t_i,e / (R_c R_i)
    (hoop pressure per unit radial interference, seed 003 eqs 9-13 with E_w the
    instantaneous modulus E_1 + E_2); an elastomer layer of thickness h and modulus E_c
    as k_c = E_c / h. In series the pressure is k_c / (k_c + k_w) of the bare one.
    """
    t = ct.hoop_wall_thickness_m(Rc_m, Ri_m, wall_m)
    kw = np.asarray(E_wall_Pa, float) * t / (np.asarray(Rc_m, float) * np.asarray(Ri_m, float))
    h = np.asarray(coating_m, float)
    return 1.0 / (1.0 + kw * h / np.asarray(E_coating_Pa, float))


def _coating(y, x, p, ctx):
    Ri = np.asarray(x["Ri"], float) if "Ri" in x else ctx["Ri"]
    return y * coating_factor(Ri, ctx["Rc"], ctx["wall"], ctx["E1"] + ctx["E2"], p["coating"],
                              p["coating_modulus"])


def _coating_guess(r, x, ctx):
    y0 = np.asarray(ctx["y0"], float)
    ratio = float(np.clip(np.mean(r + y0) / max(np.mean(y0), 1e-12), 0.05, 0.999))
    Ri = np.asarray(x["Ri"], float) if "Ri" in x else ctx["Ri"]
    f1 = float(np.mean(coating_factor(Ri, ctx["Rc"], ctx["wall"], ctx["E1"] + ctx["E2"], 1e-3, 110.3e3)))
    # factor = 1/(1 + K h): K from the 1 mm factor, h from the observed ratio
    K = (1.0 / f1 - 1.0) / 1e-3
    return {"coating": float(np.clip((1.0 / ratio - 1.0) / K, 1e-5, 4.9e-3))}


register_effect(Effect(
    name="coating", kind=KIND,
    description="A soft elastomer coating on the shell acts as a spring in series with the stretched wall and "
                "lowers the contact pressure by k_c/(k_c + k_w), k_c = E_c/h, k_w = E_w t_i,e/(R_c R_i). "
                "Seed 004: 0.9 mm coating, pressure rises from 12.22 to 13.88 kPa (avg) as its modulus rises "
                "from 8 to 16 psi. Only h/E_c is identifiable: the modulus is fixed unless freed; table "
                "columns coating_mm / coating_modulus_kPa replace the parameters row by row.",
    source="seed 004 section 3 (coating stiffness and thickness)",
    params=(Param("coating_mm", 0.9, (0.0, 5.0), 0.0, description="coating thickness h"),
            Param("coating_modulus_kPa", 110.3, (1.0, 1e5), 110.3, free=False,
                  description="coating Young's modulus E_c (16 psi)")),
    covariates=(), apply=_coating, guess=_coating_guess, bases=("hoop",),
))


def _end_shape(y, x, p, ctx):
    q = {"Ri": ctx["Ri"], "wall": ctx["wall"], "E1": ctx["E1"], "E2": ctx["E2"], "eta1": ctx["eta1"]}
    a = np.asarray(p["end_length"], float)
    ref = _hoop_pressure(x, q, ctx, None)
    new = _hoop_pressure(x, q, ctx, a)
    with np.errstate(invalid="ignore", divide="ignore"):
        return y * np.where(ref > 0, new / ref, 1.0)


register_effect(Effect(
    name="end_shape", kind=KIND,
    description="Semi-elliptical capsule ends of axial length a instead of hemispheres (a = R_c): a longer end "
                "lets the wall relax before the body, changing the hoop pressure (seed 001 section 6: "
                "resistance 1.45-1.63 N, maximum pressure 53.28 to 16.76 kPa as the end lengthens; 5.5 mm "
                "recommended). Applied as the ratio of the hoop model with and without the end length.",
    source="seed 001 section 6; capsule_cli.models.contact (end_length_m)",
    params=(Param("end_length_mm", 1.5 * published("Rc_mm"), (0.5, 40.0), published("Rc_mm"),
                  description="axial length of the semi-elliptical ends"),),
    covariates=(), apply=_end_shape, bases=("hoop",),
))
