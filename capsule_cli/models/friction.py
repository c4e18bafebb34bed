"""Capsule-intestine friction models (seed 000 sections 3-4; physics.md section 2).

* :func:`coulomb_friction_N` -- Coulomb friction of the capsule's weight (seed 000 eq 1);
* :func:`power_law_friction_N` -- the fitted friction-speed laws (seed 000 eqs 17-18);
* :func:`viscous_friction_N`, :func:`stribeck_friction_N` -- standard speed laws
  (contract section 4 effects ``viscous`` and ``stribeck``);
* :func:`hoop_friction_components_N`, :func:`hoop_friction_N` -- friction induced by the
  viscoelastic hoop pressure of a contractive intestine (seed 000 eqs 3-15, with the
  two extraction errors fixed as physics.md section 2 says);
* :func:`contractive_friction_N` -- the Case 4 total F_c4 = F_g + F_h (seed 000 eqs 2, 16).

Everything is SI ([m], [m/s], [N], [Pa], [Pa s]) and vectorised (numpy broadcasting).
Parameter values live in ``configs/params/`` (capsule_intestine.yaml, friction_laws.yaml).
"""
from __future__ import annotations

import numpy as np

from .contact import WALL_MODES, capsule_radius_m, hoop_contact_start_m, hoop_pressure_profile_Pa

__all__ = [
    "coulomb_friction_N", "power_law_friction_N", "viscous_friction_N", "stribeck_friction_N",
    "hoop_friction_components_N", "hoop_friction_N", "contractive_friction_N", "HOOP_COMPONENTS", "WALL_MODES",
]

#: component keys of :func:`hoop_friction_components_N` (without ``total``), in eq 15's order
HOOP_COMPONENTS = ("head_resistance", "head_friction", "body_friction", "tail_push", "tail_friction")



# ---------------------------------------------------------------------------
# simple laws


def coulomb_friction_N(mu, mass_kg, g_m_s2):
    """Return the Coulomb friction of the capsule's weight, F = mu m g [N].

    Parameters
    ----------
    mu : capsule-intestine friction coefficient [-] (0.2293, seed 000 Table 1)
    mass_kg : capsule mass [kg] (3.462 g in the friction tests, seed 000 Table 1)
    g_m_s2 : gravitational acceleration [m/s^2]

    Notes
    -----
    Seed 000 eq 1: F_c1 = F_g = mu m g, the model of Case 1 (flat-open intestine).
    With the seed's values it gives 7.79 mN (the paper rounds to 7.8 mN).
    """
    return np.asarray(mu, float) * np.asarray(mass_kg, float) * np.asarray(g_m_s2, float)


def power_law_friction_N(speed_m_s, a_N, n, b_N, V_ref_m_s=1e-3):
    """Return the friction of the power law F = b + a (V / V_ref)^n [N].

    Parameters
    ----------
    speed_m_s : capsule speed V >= 0 [m/s]
    a_N : friction rise at V = V_ref [N]
    n : exponent [-]
    b_N : friction at rest (offset) [N]
    V_ref_m_s : reference speed [m/s]; 1 mm/s makes a and b the papers' coefficients

    Notes
    -----
    Seed 000 eqs 17-18 write F[mN] = a V[mm/s]^n + b: Case 1 (flat-open)
    F_c1e = 8.778 V^0.25 + 2.518 (eq 17), Case 4 (contractive) F_c4e = 1539 V^0.25 + 1383
    (eq 18); see configs/params/friction_laws.yaml. The speed is taken as |V|.
    """
    v = np.abs(np.asarray(speed_m_s, float)) / V_ref_m_s
    return np.asarray(b_N, float) + np.asarray(a_N, float) * np.power(v, n)


def viscous_friction_N(speed_m_s, c_Ns_m):
    """Return the viscous friction F = c V [N].

    Parameters
    ----------
    speed_m_s : capsule speed V [m/s] (sign kept: the force opposes the motion)
    c_Ns_m : viscous coefficient c [N s/m] (1 N s/m = 1 mN per mm/s)

    Notes
    -----
    The linear viscous term of the standard friction models (Armstrong-Helouvry,
    Dupont and Canudas de Wit 1994, Automatica 30(7) 1083-1138, section 2.1);
    contract section 4 effect ``viscous`` (c V added to the base).
    """
    return np.asarray(c_Ns_m, float) * np.asarray(speed_m_s, float)


def stribeck_friction_N(speed_m_s, Fc_N, Fs_N, Vs_m_s, delta=2.0):
    """Return the Stribeck friction curve F = Fc + (Fs - Fc) exp(-(|V|/Vs)^delta) [N].

    Parameters
    ----------
    speed_m_s : capsule speed V [m/s] (the magnitude is used)
    Fc_N : Coulomb (kinetic) level reached at high speed [N]
    Fs_N : static (breakaway) level at V = 0 [N]
    Vs_m_s : Stribeck speed [m/s] (> 0)
    delta : shape exponent [-]; 2 is the Gaussian form

    Notes
    -----
    The steady-state Stribeck curve g(V) of Armstrong-Helouvry, Dupont and Canudas
    de Wit (1994), Automatica 30(7) 1083-1138, section 2, in the exponential form used
    by the LuGre model (Canudas de Wit, Olsson, Astrom and Lischinsky 1995, IEEE TAC
    40(3) 419-425, eq 4; Olsson et al. 1998, Eur. J. Control 4, 176-195) without its
    viscous term (that is :func:`viscous_friction_N`). Fs < Fc gives friction
    rising with speed, Fs > Fc the classic falling (Stribeck) branch.
    """
    v = np.abs(np.asarray(speed_m_s, float))
    Fc = np.asarray(Fc_N, float)
    return Fc + (np.asarray(Fs_N, float) - Fc) * np.exp(-np.power(v / np.asarray(Vs_m_s, float), delta))


# ---------------------------------------------------------------------------
# hoop-pressure friction of a contractive intestine (seed 000 eqs 3-15)


def _gauss_panels(n_panels: int, n_gauss: int) -> tuple[np.ndarray, np.ndarray]:
    """Return composite Gauss-Legendre nodes and weights on [0, 1]."""
    u, w = np.polynomial.legendre.leggauss(n_gauss)
    edges = np.linspace(0.0, 1.0, n_panels + 1)
    h = np.diff(edges)
    nodes = (edges[:-1, None] + 0.5 * h[:, None] * (u[None, :] + 1.0)).ravel()
    weights = (0.5 * h[:, None] * w[None, :]).ravel()
    return nodes, weights


_NODES, _WEIGHTS = _gauss_panels(16, 12)


def hoop_friction_components_N(speed_m_s, Ri_m, Rc_m, L_m, wall_m, E1_Pa, E2_Pa, eta1_Pa_s, mu,
                               wall_mode="attenuated") -> dict[str, np.ndarray]:
    """Return the five hoop-induced friction components and their sum F_h [N].

    Parameters
    ----------
    speed_m_s : capsule speed V [m/s] (array; broadcast with ``Ri_m``)
    Ri_m : intestine inner radius R_i [m] (array; 4.4-4.8 mm in seed 000 Case 4; >= R_c: no contact, 0)
    Rc_m : capsule radius R_c [m] (5.5 mm)
    L_m : cylindrical body length L [m] (15 mm)
    wall_m : wall thickness t_i [m] (0.69 mm)
    E1_Pa, E2_Pa, eta1_Pa_s : Maxwell parameters (196.43 kPa, 757.48 kPa, 5.36 MPa s)
    mu : friction coefficient [-] (0.2293)
    wall_mode : "attenuated" (t_i,e, seed 000 eq 6, default) or "original" (t_i, as seed 003
        used); see :func:`capsule_cli.models.contact.hoop_wall_thickness_m`

    Returns
    -------
    dict of arrays [N] with keys ``head_resistance`` (f_hr, eq 10), ``head_friction``
    (f_hf, eq 11), ``body_friction`` (f_bf, eq 12), ``tail_push`` (f_tr, eq 13, < 0),
    ``tail_friction`` (f_tf, eq 14) and ``total`` = F_h, eq 15 as corrected.

    Notes
    -----
    The hoop pressure along the capsule, P_h(x) = t_i,e(x) tau(x) / R(x) with
    eps(x) = (R(x) - R_i)/R_i and tau(x) = eps (E_1 exp(-E_1 x/(eta_1 V)) + E_2) (seed 000
    eqs 4-9, strain sign fixed), is :func:`capsule_cli.models.contact.hoop_pressure_profile_Pa`
    (hemispherical ends); x runs from the head's first contact point.
    Seed 000 eqs 10-15 with physics.md section 2's two fixes. (1) On the spherical
    caps the surface element is R(x) sqrt(1 + R'(x)^2) dx = R_c dx, so with the
    axial and radial direction cosines (x_c - x)/R_c and R(x)/R_c of the cap normal:
    f_hr = 2 pi int_0^xc (x_c - x) P_h dx, f_hf = 2 pi mu int_0^xc R P_h dx,
    f_bf = 2 pi mu R_c int_xc^(xc+L) P_h dx,
    f_tr = 2 pi int_(xc+L)^(2xc+L) (x_c + L - x) P_h dx (the tail's lever is <= 0: the
    tail pushes the capsule forward), f_tf = 2 pi mu int_(xc+L)^(2xc+L) R P_h dx.
    (2) Eq 15 as extracted reads "f_tr + f_tr"; the total is
    F_h = f_hr + f_hf + f_bf + f_tr + f_tf. The integrals use composite Gauss-Legendre
    quadrature (16 panels x 12 nodes per segment; it agrees with adaptive
    quadrature to 1e-12 relative for 0.01-100 mm/s and R_i = 4.2-5.4 mm). Seed 000's FE (no gravity) gives about
    1.5 N at R_i = 5.0 mm rising to 3.8 N at 4.4 mm (section 4.4).
    """
    V, Ri = np.broadcast_arrays(np.abs(np.asarray(speed_m_s, float)), np.asarray(Ri_m, float))
    if np.any(Ri <= 0):
        raise ValueError("intestine inner radius must be positive")
    xc = hoop_contact_start_m(Ri, Rc_m)[..., None]  # seed 000 eq 3
    Vn, Rin = V[..., None], Ri[..., None]
    u, w = _NODES, _WEIGHTS

    def pressure(x):
        return hoop_pressure_profile_Pa(x, Vn, Rin, Rc_m, L_m, wall_m, E1_Pa, E2_Pa, eta1_Pa_s, wall_mode)

    def radius(x):
        return np.nan_to_num(capsule_radius_m(x, Rin, Rc_m, L_m))

    two_pi = 2.0 * np.pi
    # head: x in [0, x_c]
    xh = xc * u
    Ph = pressure(xh)
    head_resistance = two_pi * np.sum(w * (xc - xh) * Ph, axis=-1) * xc[..., 0]
    head_friction = two_pi * mu * np.sum(w * radius(xh) * Ph, axis=-1) * xc[..., 0]
    # body: x in (x_c, x_c + L]
    xb = xc + L_m * u
    body_friction = two_pi * mu * Rc_m * np.sum(w * pressure(xb), axis=-1) * L_m
    # tail: x in (x_c + L, 2 x_c + L]
    xt = xc + L_m + xc * u
    Pt = pressure(xt)
    tail_push = two_pi * np.sum(w * (xc + L_m - xt) * Pt, axis=-1) * xc[..., 0]
    tail_friction = two_pi * mu * np.sum(w * radius(xt) * Pt, axis=-1) * xc[..., 0]

    no_contact = Ri >= Rc_m
    out = {
        "head_resistance": head_resistance, "head_friction": head_friction,
        "body_friction": body_friction, "tail_push": tail_push, "tail_friction": tail_friction,
    }
    out = {k: np.where(no_contact, 0.0, v) for k, v in out.items()}
    out["total"] = sum(out[k] for k in HOOP_COMPONENTS)
    return out


def hoop_friction_N(speed_m_s, Ri_m, Rc_m, L_m, wall_m, E1_Pa, E2_Pa, eta1_Pa_s, mu, wall_mode="attenuated"):
    """Return the hoop-pressure-induced friction F_h [N] (seed 000 eq 15 as corrected).

    The sum of the five components of :func:`hoop_friction_components_N` (see there
    for parameters and the two fixes of physics.md section 2). Without the weight's
    Coulomb term; add it with :func:`contractive_friction_N` (eq 16).
    """
    return hoop_friction_components_N(speed_m_s, Ri_m, Rc_m, L_m, wall_m, E1_Pa, E2_Pa, eta1_Pa_s, mu,
                                      wall_mode)["total"]


def contractive_friction_N(speed_m_s, Ri_m, Rc_m, L_m, wall_m, E1_Pa, E2_Pa, eta1_Pa_s, mu, mass_kg, g_m_s2,
                           wall_mode="attenuated"):
    """Return the total Case 4 friction F_c4 = F_g + F_h [N] (seed 000 eqs 2 and 16).

    F_g = mu m g (:func:`coulomb_friction_N`) plus the hoop friction F_h
    (:func:`hoop_friction_N`). physics.md section 2 quotes this total: about
    3.45-3.81 N for R_i = 4.4 mm over 0.4-12 mm/s, 2.07-2.29 N for 4.8 mm and
    1.43-1.58 N for 5.0 mm (seed 000 section 4.4 measured 2.5-4.5 N).
    """
    return coulomb_friction_N(mu, mass_kg, g_m_s2) + hoop_friction_N(
        speed_m_s, Ri_m, Rc_m, L_m, wall_m, E1_Pa, E2_Pa, eta1_Pa_s, mu, wall_mode)
