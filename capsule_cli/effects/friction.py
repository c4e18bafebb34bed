"""Built-in base model and effects of the ``friction`` kind (response ``friction_mN``).

The base model is Coulomb friction of the capsule's weight (seed 000 eq 1); each
effect adds the term of a physical mechanism the seeds report. Physics is
called from :mod:`capsule_cli.models.friction` and :mod:`capsule_cli.models.contact`,
never re-implemented here; the functions below only compose (SI throughout).
"""
from __future__ import annotations

import numpy as np

from ..models import friction as fr
from ..models.contact import collapsed_wall_weight_N_m
from . import _guess
from .constants import capsule_constants, published
from .registry import BaseModel, Effect, Param, register_base, register_effect

KIND = "friction"


def _n(x) -> int:
    return int(np.asarray(x["speed"]).size)


def _speed(x):
    return np.abs(np.asarray(x["speed"], float))


# ---------------------------------------------------------------------------
# base: Coulomb


def _coulomb(x, p, ctx):
    return np.full(_n(x), float(fr.coulomb_friction_N(p["mu"], p["mass"], ctx["g"])))


register_base(BaseModel(
    name="coulomb", kind=KIND,
    description="Coulomb friction of the capsule's weight, F = mu m g, independent of speed "
                "(the model of Case 1, a flat-open intestine).",
    source="seed 000 eq 1 (7.79 mN for m = 3.462 g, mu = 0.2293)",
    params=(Param("mu", published("mu"), (0.0, 5.0), description="capsule-intestine friction coefficient"),
            Param("mass_g", published("mass_g"), (0.01, 1000.0), description="capsule mass m")),
    predict=_coulomb,
))


# ---------------------------------------------------------------------------
# speed laws


def _power_law(y, x, p, ctx):
    return y + fr.power_law_friction_N(_speed(x), p["a"], p["n"], 0.0, ctx["V_ref"])


def _power_law_guess(r, x, ctx):
    v = _speed(x) / ctx["V_ref"]
    ns = np.linspace(0.1, 2.0, 39)
    i, a = _guess.scan(r, (v ** n for n in ns))
    return {"a": max(a, 1e-6), "n": float(ns[i])}


register_effect(Effect(
    name="speed_power_law", kind=KIND,
    description="Friction rises with sliding speed as a power law, F += a (V/V_ref)^n with V_ref = 1 mm/s: "
                "the viscoelastic wall's rate dependence measured on a flat-open intestine (Case 1: "
                "a = 8.778 mN, n = 0.25) and in a contractive one (Case 4: a = 1539 mN, n = 0.25).",
    source="seed 000 eqs 17-18, section 4",
    params=(Param("a_mN", 5.0, (0.0, 1e5), 0.0, description="friction rise at V = 1 mm/s"),
            Param("n", 0.5, (0.05, 3.0), 1.0, description="speed exponent")),
    covariates=("speed_mm_s",), apply=_power_law, guess=_power_law_guess,
    nests=(("viscous", "n = 1, c = a"),),  # a mN at 1 mm/s = a N s/m
))


def _viscous(y, x, p, ctx):
    return y + fr.viscous_friction_N(_speed(x), p["c"])


def _viscous_guess(r, x, ctx):
    a, _ = _guess.amplitude_with_offset(r, _speed(x))
    return {"c": max(a, 1e-9)}


register_effect(Effect(
    name="viscous", kind=KIND,
    description="A linear viscous term, F += c V (1 N s/m = 1 mN per mm/s): a lubricated (mucus) film "
                "sheared between shell and wall.",
    source="Armstrong-Helouvry, Dupont, Canudas de Wit 1994, Automatica 30(7), section 2.1",
    params=(Param("c_Ns_m", 1.0, (0.0, 1e4), 0.0, description="viscous coefficient"),),
    covariates=("speed_mm_s",), apply=_viscous, guess=_viscous_guess,
))


def _stribeck(y, x, p, ctx):
    return y + fr.stribeck_friction_N(_speed(x), 0.0, p["stribeck"], p["stribeck_speed"])


def _stribeck_guess(r, x, ctx):
    v = _speed(x)
    vs = _guess.log_grid(0.02e-3, 40e-3, 40)
    i, a = _guess.scan(r, (np.exp(-(v / s) ** 2) for s in vs))
    return {"stribeck": max(a, 1e-9), "stribeck_speed": float(vs[i])}


register_effect(Effect(
    name="stribeck", kind=KIND,
    description="Breakaway excess at low speed (Stribeck branch): F += dF exp(-(V/V_s)^2), friction "
                "falls from mu m g + dF at rest to mu m g above the Stribeck speed V_s.",
    source="Armstrong-Helouvry et al. 1994 section 2; LuGre (Canudas de Wit et al. 1995, eq 4); "
           "seed 000 eq 22 (static 2.5 mN vs kinetic law)",
    params=(Param("stribeck_mN", 5.0, (0.0, 1e5), 0.0, description="excess friction at rest dF"),
            Param("stribeck_speed_mm_s", 0.5, (0.01, 50.0), 1.0, description="Stribeck speed V_s")),
    covariates=("speed_mm_s",), apply=_stribeck, guess=_stribeck_guess,
))


# ---------------------------------------------------------------------------
# contractive intestine: hoop pressure


def _hoop_N(x, ctx):
    return fr.hoop_friction_N(_speed(x), np.asarray(x["Ri"], float), ctx["Rc"], ctx["L"], ctx["wall"],
                              ctx["E1"], ctx["E2"], ctx["eta1"], ctx["mu"])


def _hoop(y, x, p, ctx):
    return y + p["hoop_scale"] * _hoop_N(x, ctx)


def _hoop_guess(r, x, ctx):
    a, _ = _guess.amplitude_with_offset(r, _hoop_N(x, ctx))
    return {"hoop_scale": max(a, 1e-6)}


register_effect(Effect(
    name="hoop_pressure", kind=KIND,
    description="A contractive intestine (inner radius R_i < R_c) stretched over the capsule presses on it "
                "with a viscoelastic hoop pressure; its friction F_h (head resistance, head/body/tail "
                "friction, tail push) is added, scaled by hoop_scale (1 = the seed's wall properties).",
    source="seed 000 eqs 3-16 (as corrected in physics.md section 2); seed 003 Table 1",
    params=(Param("hoop_scale", 1.0, (0.0, 20.0), 0.0, description="multiplier of the model's hoop friction"),),
    covariates=("speed_mm_s", "Ri_mm"), apply=_hoop, guess=_hoop_guess,
))


# ---------------------------------------------------------------------------
# circular folds (position)


def fold_train(position_m, spacing_m, width_m, phase_m):
    """Return a periodic train of unit Gaussian peaks at the folds [-].

    Folds sit at ``phase + k * spacing``; the peak is exp(-d^2 / (2 w^2)) with d the
    distance to the nearest fold and w = min(width, spacing/8): peaks stay localised
    (narrower than an eighth of the spacing), which separates folds from a smooth
    periodic modulation.
    """
    x = np.asarray(position_m, float)
    P = max(float(spacing_m), 1e-12)
    w = min(max(float(width_m), 1e-12), P / 8.0)
    d = np.mod(x - float(phase_m) + 0.5 * P, P) - 0.5 * P
    return np.exp(-0.5 * (d / w) ** 2)


def odd_folds(position_m, spacing_m, phase_m):
    """Return 1.0 where the nearest fold is an odd one (k = 1, 3, ... counted from the fold at the phase), else 0."""
    x = np.asarray(position_m, float)
    P = max(float(spacing_m), 1e-12)
    k = np.floor((x - float(phase_m)) / P + 0.5)
    return np.mod(k, 2.0)


def _folds(y, x, p, ctx):
    train = fold_train(x["position"], p["fold_spacing"], p["fold_width"], p["fold_phase"])
    odd = odd_folds(x["position"], p["fold_spacing"], p["fold_phase"])
    return y + p["fold_amplitude"] * (1.0 + (p["fold_height_ratio"] - 1.0) * odd) * train


def _folds_guess(r, x, ctx):
    pos = np.asarray(x["position"], float)
    span = float(pos.max() - pos.min())
    u = np.unique(pos)
    step = float(np.median(np.diff(u))) if u.size > 1 else 1e-3
    lo = max(10e-3, 4 * step)
    hi = max(lo * 1.01, min(1.0, span / 1.5))
    best = (-1.0, 50e-3, 3e-3, 0.0, 0.0)
    rc = np.asarray(r, float) - np.mean(r)
    for P in _guess.log_grid(lo, hi, 80):
        phases = np.linspace(0, P, 24, endpoint=False)
        for frac in (1 / 40, 1 / 20, 1 / 10):
            w = max(P * frac, 0.3e-3)
            B = np.stack([fold_train(pos, P, w, ph) for ph in phases], axis=1)
            Bc = B - B.mean(axis=0)
            den = (Bc * Bc).sum(axis=0)
            num = Bc.T @ rc
            with np.errstate(invalid="ignore", divide="ignore"):
                a = np.where(den > 0, num / den, 0.0)
                red = np.where(a > 0, a * num, 0.0)
            j = int(np.argmax(red))
            if red[j] > best[0]:
                best = (float(red[j]), float(P), float(w), float(phases[j]), float(a[j]))
    _, P, w, ph, a = best
    # folds of two heights: the scan may lock onto the large folds only (spacing 2s); try half the
    # spacing too, and fit the even and odd folds' heights by least squares on the two trains
    rr = np.asarray(r, float)
    choice = None
    for PP, pp in ((P, ph), (P / 2, ph), (P / 2, ph - P / 2)):
        if PP < lo * 0.99:
            continue
        ww = min(w, PP / 8)
        tr = fold_train(pos, PP, ww, pp)
        odd = odd_folds(pos, PP, pp)
        B = np.stack([tr * (1 - odd), tr * odd, np.ones_like(tr)], axis=1)
        coef, *_ = np.linalg.lstsq(B, rr, rcond=None)
        if not (np.all(np.isfinite(coef)) and coef[0] > 0 and coef[1] >= 0):
            continue
        rss = float(np.sum((rr - B @ coef) ** 2))
        if choice is None or rss < choice[0] * 0.98:  # the simpler (first) unless clearly better
            choice = (rss, PP, ww, pp, float(coef[0]), float(coef[1] / coef[0]))
    if choice is not None:
        _, P, w, ph, A, ratio = choice
        return {"fold_amplitude": A, "fold_height_ratio": float(np.clip(ratio, 0.0, 20.0)), "fold_spacing": P,
                "fold_width": w, "fold_phase": ph}
    return {"fold_amplitude": max(a, 1e-9), "fold_height_ratio": 1.0, "fold_spacing": P, "fold_width": w,
            "fold_phase": ph}


register_effect(Effect(
    name="circular_folds", kind=KIND,
    description="Circular folds of the mucosa: friction peaks each time the capsule climbs a fold, "
                "F += sum_k A_k exp(-(x - x0 - k s)^2 / (2 w^2)) over position x (fold spacing s, peak width w "
                "<= s/8, fold k = 0 at x0), with A_k = A for even folds and r A for odd ones (folds of two "
                "heights alternate; r = 1: all alike). Seed 000 Case 2: folds 1.67-2.34 mm high, 3.1-3.3 mm "
                "wide, 50 mm apart; a small and a large fold, peaks 37.5 and 88.2 mN over 15.6 mN between folds "
                "(A = 21.9 mN, r = 3.32).",
    source="seed 000 section 4.2 (Fig 11)",
    params=(Param("fold_amplitude_mN", 20.0, (0.0, 1e5), 0.0, description="peak friction of even folds above the base"),
            Param("fold_height_ratio", 1.0, (0.0, 20.0), 1.0,
                  description="peak of odd folds over peak of even folds (folds of two heights; 1: all alike)"),
            Param("fold_spacing_mm", 50.0, (10.0, 1000.0), 50.0, description="distance between folds s"),
            Param("fold_width_mm", 3.0, (0.3, 100.0), 3.0, description="peak width w (Gaussian sigma)"),
            Param("fold_phase_mm", 0.0, (-1000.0, 1000.0), 0.0, description="position x0 of a fold")),
    covariates=("position_mm",), apply=_folds, guess=_folds_guess,
))


# ---------------------------------------------------------------------------
# viscoelastic relaxation (time)


def _relax(y, x, p, ctx):
    return y + p["relax_amplitude"] * np.exp(-np.asarray(x["time"], float) / p["relax_time"])


def _relax_guess(r, x, ctx):
    t = np.asarray(x["time"], float)
    span = max(float(t.max() - t.min()), 1e-3)
    taus = _guess.log_grid(max(span / 300, 0.05), min(span * 5, 1e4), 50)
    i, a = _guess.scan(r, (np.exp(-t / tau) for tau in taus))
    return {"relax_amplitude": max(a, 1e-9), "relax_time": float(taus[i])}


register_effect(Effect(
    name="viscoelastic_relaxation", kind=KIND,
    description="Friction decays in time as the stretched viscoelastic wall relaxes (seed 000 Case 4 phases I "
                "and IV): F += A exp(-t/tau), tau near eta_1/E_1 = 27.3 s of the Maxwell wall model.",
    source="seed 000 section 4.4 (Fig 13); seed 003 Table 1 (eta_1/E_1)",
    params=(Param("relax_amplitude_mN", 5.0, (0.0, 1e5), 0.0, description="friction excess at t = 0"),
            Param("relax_time_s", 27.3, (0.05, 1e4), 27.3, description="relaxation time tau")),
    covariates=("time_s",), apply=_relax, guess=_relax_guess,
))


# ---------------------------------------------------------------------------
# wall weight and curvature


def _default_wall_mass_g() -> float:
    c = capsule_constants()
    w = collapsed_wall_weight_N_m(c["Ri_case2"], c["wall"], c["rho_i"], c["g"])  # [N/m]
    return float(w * c["length_total"] / c["g"] * 1e3)


def _wall_weight(y, x, p, ctx):
    return y + ctx["mu"] * p["wall_mass"] * ctx["g"]


def _wall_weight_guess(r, x, ctx):
    return {"wall_mass": max(float(np.mean(r)) / max(ctx["mu"] * ctx["g"], 1e-12), 1e-9)}


register_effect(Effect(
    name="wall_weight", kind=KIND,
    description="A collapsed intestine's upper wall rests on the capsule and adds normal load: "
                "F += mu m_w g, m_w the wall mass carried (default: the upper half-tube of a 13 mm intestine "
                "over the capsule's 26 mm). A constant: confounded with a free mu.",
    source="seed 003 eq 6 (P_c2 = P_c + P_1); seed 000 section 4.3 (Case 3 frictions up to 170 mN)",
    params=(Param("wall_mass_g", round(_default_wall_mass_g(), 4), (0.0, 100.0), 0.0,
                  description="mass of intestinal wall carried by the capsule"),),
    covariates=(), apply=_wall_weight, guess=_wall_weight_guess,
))


def sagitta_ratio(bend_radius_m, length_m, Rc_m):
    """Return s/R_c [-], the sagitta s = l^2/(8 R_b) of the capsule's chord l in a bend, over R_c."""
    Rb = np.asarray(bend_radius_m, float)
    with np.errstate(divide="ignore"):
        return np.where(np.isfinite(Rb) & (Rb > 0), length_m ** 2 / (8.0 * Rb * Rc_m), 0.0)


def _curvature(y, x, p, ctx):
    s = sagitta_ratio(x["bend_radius"], ctx["length_total"], ctx["Rc"])
    return y * np.clip(1.0 + p["curvature_gain"] * s ** p["curvature_exponent"], 0.0, None)


def _curvature_guess(r, x, ctx):
    s = sagitta_ratio(x["bend_radius"], ctx["length_total"], ctx["Rc"])
    a, _ = _guess.amplitude_with_offset(r, np.asarray(ctx["y0"]) * s, nonnegative=False)
    return {"curvature_gain": a}


CURVATURE_PARAMS = (
    Param("curvature_gain", 0.5, (-0.9, 50.0), 0.0, description="relative rise per unit sagitta/R_c"),
    Param("curvature_exponent", 1.0, (0.25, 4.0), 1.0, free=False,
          description="power of the sagitta ratio (fixed at 1 unless freed)"),
)

register_effect(Effect(
    name="curvature", kind=KIND,
    description="In a bent intestine (bending radius R_b) the straight capsule must push the wall aside by the "
                "sagitta s = l^2/(8 R_b) of its length l, raising the normal load: "
                "F *= 1 + k (s/R_c)^m. Seed 001: pressure and resistance rise sharply for R_b = 10-25 mm and "
                "approach the straight tube above 200 mm.",
    source="seed 001 section 5 (Fig 12)",
    params=CURVATURE_PARAMS, covariates=("bend_radius_mm",), apply=_curvature, guess=_curvature_guess,
))
