"""Capsule-intestine contact pressure: Hertz line contact, collapsed wall, viscoelastic hoop pressure.

Pure functions, numpy in and numpy out, SI units throughout ([m], [N], [Pa],
[s]); every array argument broadcasts against the others. Parameter values
come from ``configs/params/`` (see :func:`capsule_cli.steps.contact.contact_params_from_config`).

Models
------
* Case 1, flat or open intestine: Hertz line contact of the capsule body on the
  wall (seed 003 eqs 2-5): :func:`hertz_semi_width_m`,
  :func:`hertz_pressure_avg_Pa`, :func:`hertz_pressure_max_Pa`.
* Case 2, collapsed intestine (seed 003 eq 6, P_c2 = P_c + P_1): the paper has
  no closed form for P_1; :func:`collapsed_wall_pressure_Pa` builds one from
  the weight of the collapsed upper wall, :func:`collapsed_pressure_avg_Pa`
  adds it to the Hertz pressure of the capsule's own weight.
* Case 3, contractive intestine: hoop pressure of the viscoelastic wall
  stretched over the capsule (seed 003 eqs 8-14; seed 000 eqs 3-9 for the
  ends), along the capsule (:func:`hoop_pressure_profile_Pa`) and averaged
  over the cylindrical body (:func:`hoop_pressure_avg_Pa`), with hemispherical
  or semi-elliptical ends (seed 001 section 6, ``end_length_m``).

References
----------
seed 003: Modelling of capsule-intestine contact for a self-propelled capsule robot.
seed 000: Experimental and numerical studies of intestinal frictions ... (eqs 3-9).
seed 001: Finite element analysis of a self-propelled capsule robot ... (section 6).
"""
from __future__ import annotations

import numpy as np

WALL_MODES = ("attenuated", "original")

# ---------------------------------------------------------------------------
# Hertz line contact (Case 1; also the lower contact of Case 2)


def hertz_equivalent_radius_m(Rc_m, Ri_m, conforming=False):
    """Return the equivalent radius R_e [m] of the capsule-wall line contact.

    Parameters
    ----------
    Rc_m : capsule outer radius R_c [m]
    Ri_m : intestine inner radius R_i [m]; ``np.inf`` for a flat wall (Case 1)
    conforming : False (default) uses seed 003's eq 2 as printed,
        R_e = (1/R_c + 1/R_i)^-1; True uses the conforming (concave) form
        R_e = (1/R_c - 1/R_i)^-1 of a cylinder lying inside a trough, which is
        the geometry of a capsule on the bottom of a tube (requires R_i > R_c).
        The two agree for the flat wall R_i = inf.

    Notes
    -----
    seed 003 eq 2 (definition of R_e below it).
    """
    Rc = np.asarray(Rc_m, float)
    inv_ri = 1.0 / np.asarray(Ri_m, float)
    return 1.0 / (1.0 / Rc - inv_ri) if conforming else 1.0 / (1.0 / Rc + inv_ri)


def hertz_equivalent_modulus_Pa(Ec_Pa, nu_c, Ei_Pa, nu_i):
    """Return the equivalent Young's modulus E_e [Pa] = ((1-ν_c²)/E_c + (1-ν_i²)/E_i)^-1 (seed 003 eq 2)."""
    return 1.0 / ((1.0 - np.asarray(nu_c) ** 2) / np.asarray(Ec_Pa, float)
                  + (1.0 - np.asarray(nu_i) ** 2) / np.asarray(Ei_Pa, float))


def hertz_semi_width_m(load_N, Rc_m, Ri_m, length_m, Ec_Pa, nu_c, Ei_Pa, nu_i, conforming=False):
    """Return the Hertz semi-contact width a [m] of the capsule body on the intestine wall.

    Parameters
    ----------
    load_N : normal load F [N] (capsule weight M_c g in seed 003)
    Rc_m : capsule outer radius R_c [m]
    Ri_m : intestine inner radius R_i [m] (``np.inf``: flat, Case 1)
    length_m : contact length L [m] (the cylindrical body)
    Ec_Pa, nu_c : capsule Young's modulus [Pa] and Poisson ratio [-]
    Ei_Pa, nu_i : intestine Young's modulus [Pa] and Poisson ratio [-]
    conforming : see :func:`hertz_equivalent_radius_m`

    Notes
    -----
    seed 003 eq 2: a = sqrt(4 F R_e / (π L E_e)). For the paper's Case 1
    (F = 0.4 g × g, R_c = 5.5 mm, L = 15 mm) a = 0.2359 mm.
    """
    Re = hertz_equivalent_radius_m(Rc_m, Ri_m, conforming)
    Ee = hertz_equivalent_modulus_Pa(Ec_Pa, nu_c, Ei_Pa, nu_i)
    return np.sqrt(4.0 * np.asarray(load_N, float) * Re / (np.pi * np.asarray(length_m, float) * Ee))


def hertz_pressure_max_Pa(load_N, Rc_m, Ri_m, length_m, Ec_Pa, nu_c, Ei_Pa, nu_i, conforming=False):
    """Return the maximum Hertz contact pressure P_max [Pa] = 2F/(π a L) on the contact axis.

    Arguments as :func:`hertz_semi_width_m`. seed 003 eq 4 (0.70 kPa for Case 1).
    """
    a = hertz_semi_width_m(load_N, Rc_m, Ri_m, length_m, Ec_Pa, nu_c, Ei_Pa, nu_i, conforming)
    return 2.0 * np.asarray(load_N, float) / (np.pi * a * np.asarray(length_m, float))


def hertz_pressure_avg_Pa(load_N, Rc_m, Ri_m, length_m, Ec_Pa, nu_c, Ei_Pa, nu_i, conforming=False):
    """Return the average Hertz contact pressure P_avg [Pa] = F/(2 a L) over the contact strip.

    Arguments as :func:`hertz_semi_width_m`. seed 003 eq 5 (0.55 kPa for Case 1).
    """
    a = hertz_semi_width_m(load_N, Rc_m, Ri_m, length_m, Ec_Pa, nu_c, Ei_Pa, nu_i, conforming)
    return np.asarray(load_N, float) / (2.0 * a * np.asarray(length_m, float))


def hertz_pressure_distribution_Pa(r_m, load_N, Rc_m, Ri_m, length_m, Ec_Pa, nu_c, Ei_Pa, nu_i,
                                   conforming=False):
    """Return the Hertz pressure P(r) [Pa] = P_max sqrt(1 - (r/a)²) across the strip (0 for |r| > a).

    ``r_m`` is the distance from the contact axis [m]. seed 003 eq 3.
    """
    a = hertz_semi_width_m(load_N, Rc_m, Ri_m, length_m, Ec_Pa, nu_c, Ei_Pa, nu_i, conforming)
    pmax = 2.0 * np.asarray(load_N, float) / (np.pi * a * np.asarray(length_m, float))
    q = 1.0 - (np.asarray(r_m, float) / a) ** 2
    return np.where(q > 0, pmax * np.sqrt(np.clip(q, 0.0, None)), 0.0)


# ---------------------------------------------------------------------------
# Collapsed intestine (Case 2)


def collapsed_wall_weight_N_m(Ri_m, wall_m, rho_i_kg_m3, g_m_s2):
    """Return the weight per unit axial length [N/m] of the collapsed upper half of the intestine wall.

    w = ρ_i g t_i π (R_i + t_i/2): half the tube's circumference at the wall's
    mid-surface times its thickness t_i, times density and gravity.

    Parameters
    ----------
    Ri_m : inner radius of the intestine before it collapses [m] (Case 2: 13 mm)
    wall_m : wall thickness t_i [m]
    rho_i_kg_m3 : wall density ρ_i [kg/m³] (1 g/cm³, seed 003 Table 1)
    g_m_s2 : gravitational acceleration [m/s²]

    Notes
    -----
    Closed form built for seed 003 eq 6, which names P_1 (the pressure due to
    the intestine falling on the capsule) without giving it. Seed 003 section 3
    and seed 001 section 2: the upper half of the intestine collapses on the capsule.
    Taking the whole upper half as resting on the capsule is an upper bound:
    part of the draped wall reaches the trough beside the capsule.
    """
    wall = np.asarray(wall_m, float)
    return np.asarray(rho_i_kg_m3, float) * np.asarray(g_m_s2, float) * wall * np.pi * (
        np.asarray(Ri_m, float) + 0.5 * wall)


def collapsed_wall_pressure_Pa(Ri_m, wall_m, rho_i_kg_m3, g_m_s2, Rc_m, length_m, Ec_Pa, nu_c, Ei_Pa, nu_i):
    """Return the extra contact pressure P_1 [Pa] from the collapsed upper wall's weight (Case 2).

    The upper wall's weight per unit length w (:func:`collapsed_wall_weight_N_m`)
    rests on the top of the capsule body along its length L; carried over a
    Hertz line contact of the wall on the capsule (R_e = R_c, the same E_e as
    the lower contact), it gives

        a_w = sqrt(4 w R_c / (π E_e)),   P_1 = w / (2 a_w) = sqrt(π w E_e / (16 R_c)),

    i.e. the Hertz average pressure (seed 003 eqs 2 and 5) of a load w·L.

    Parameters
    ----------
    Ri_m, wall_m, rho_i_kg_m3, g_m_s2 : as :func:`collapsed_wall_weight_N_m`
    Rc_m, length_m, Ec_Pa, nu_c, Ei_Pa, nu_i : as :func:`hertz_semi_width_m`

    Notes
    -----
    seed 003 eq 6 names P_1 without a closed form; this one is ours. With
    seed 003 Table 1 values it gives about 0.58 kPa, the same order as the
    capsule's own Hertz pressure: the load per unit length of the wall
    (0.28 N/m) is close to that of the 0.4 g capsule (0.26 N/m), in line with
    the paper's remark that Case 2 pressures are about twice Case 1's.
    """
    w = collapsed_wall_weight_N_m(Ri_m, wall_m, rho_i_kg_m3, g_m_s2)
    L = np.asarray(length_m, float)
    return hertz_pressure_avg_Pa(w * L, Rc_m, np.inf, L, Ec_Pa, nu_c, Ei_Pa, nu_i)


def collapsed_pressure_avg_Pa(load_N, Ri_m, wall_m, rho_i_kg_m3, g_m_s2, Rc_m, length_m, Ec_Pa, nu_c,
                              Ei_Pa, nu_i, conforming=True):
    """Return the Case 2 contact pressure P_c2 = P_c + P_1 [Pa] (seed 003 eq 6).

    P_c is the Hertz average pressure of the capsule's weight ``load_N`` on the
    lower wall of radius R_i (seed 003 eq 5; ``conforming=True`` by default,
    since the capsule lies inside the trough of the collapsed tube, see
    :func:`hertz_equivalent_radius_m`); P_1 is the wall's contribution
    (:func:`collapsed_wall_pressure_Pa`). Arguments as those two functions.

    Notes
    -----
    With seed 003 Table 1 values and a 0.4 g capsule this gives about 1.0 kPa
    (conforming) or 1.2 kPa (eq 2 as printed), about half of the measured
    ~2 kPa and the FE 1.85 kPa (seed 003 section 5): dead weight alone does not
    explain Case 2.
    """
    pc = hertz_pressure_avg_Pa(load_N, Rc_m, Ri_m, length_m, Ec_Pa, nu_c, Ei_Pa, nu_i, conforming)
    p1 = collapsed_wall_pressure_Pa(Ri_m, wall_m, rho_i_kg_m3, g_m_s2, Rc_m, length_m, Ec_Pa, nu_c, Ei_Pa, nu_i)
    return pc + p1


# ---------------------------------------------------------------------------
# Hoop pressure (Case 3): geometry of the capsule surrounded by a narrower intestine


def _end_length(Rc_m, end_length_m):
    return np.asarray(Rc_m, float) if end_length_m is None else np.asarray(end_length_m, float)


def hoop_contact_start_m(Ri_m, Rc_m, end_length_m=None):
    """Return x_c [m]: axial distance from the first capsule-wall contact to the start of the body.

    The end of axial length a (``end_length_m``; None: hemisphere, a = R_c) is
    the semi-ellipse R(s) = R_c sqrt(1 - (s/a)²) with s measured from the body
    towards the tip; the wall of inner radius R_i first touches it where
    R(s) = R_i, so x_c = a sqrt(1 - (R_i/R_c)²). Zero when R_i >= R_c (no hoop contact).

    Notes
    -----
    seed 003 eq 8 / seed 000 eq 3 (x_c = sqrt(R_c² - R_i²) for a hemisphere);
    semi-elliptical ends of length L_e: seed 001 section 6.
    """
    ratio = np.clip(np.asarray(Ri_m, float) / np.asarray(Rc_m, float), 0.0, 1.0)
    return _end_length(Rc_m, end_length_m) * np.sqrt(1.0 - ratio ** 2)


def hoop_contact_length_m(Ri_m, Rc_m, L_m, end_length_m=None):
    """Return the axial length [m] of the capsule-wall contact, 2 x_c + L (head end, body, tail end)."""
    return 2.0 * hoop_contact_start_m(Ri_m, Rc_m, end_length_m) + np.asarray(L_m, float)


def capsule_radius_m(x_m, Ri_m, Rc_m, L_m, end_length_m=None):
    """Return the capsule radius R(x) [m] along the contact, x from the first contact point [m].

    R(x) = R_c sqrt(1 - ((x_c - x)/a)²) on the head (0 <= x <= x_c), R_c on the
    body (x_c < x <= x_c + L), R_c sqrt(1 - ((x - x_c - L)/a)²) on the tail
    (x_c + L < x <= 2 x_c + L); NaN outside the contact. a = ``end_length_m``
    (None: a = R_c, hemispherical ends).

    Notes
    -----
    seed 000 eq 4 (hemispherical ends); seed 001 section 6 (semi-elliptical ends).
    """
    x, Ri, Rc, L, a = np.broadcast_arrays(*(np.asarray(v, float) for v in
                                            (x_m, Ri_m, Rc_m, L_m, _end_length(Rc_m, end_length_m))))
    xc = hoop_contact_start_m(Ri, Rc, a)
    s = np.where(x <= xc, xc - x, np.where(x > xc + L, x - xc - L, 0.0))
    q = np.clip(1.0 - (s / a) ** 2, 0.0, None)
    R = Rc * np.sqrt(q)
    inside = (x >= 0.0) & (x <= 2.0 * xc + L)
    return np.where(inside, R, np.nan)


def capsule_radius_slope(x_m, Ri_m, Rc_m, L_m, end_length_m=None):
    """Return dR/dx [-] of :func:`capsule_radius_m` (positive on the head, 0 on the body, negative on the tail).

    Used for surface elements R sqrt(1 + R'²) dx (seed 000 eqs 10-14).
    """
    x, Ri, Rc, L, a = np.broadcast_arrays(*(np.asarray(v, float) for v in
                                            (x_m, Ri_m, Rc_m, L_m, _end_length(Rc_m, end_length_m))))
    xc = hoop_contact_start_m(Ri, Rc, a)
    head = x <= xc
    tail = x > xc + L
    s = np.where(head, xc - x, np.where(tail, x - xc - L, 0.0))
    q = np.clip(1.0 - (s / a) ** 2, 1e-300, None)
    mag = Rc * s / (a ** 2 * np.sqrt(q))
    slope = np.where(head, mag, np.where(tail, -mag, 0.0))
    inside = (x >= 0.0) & (x <= 2.0 * xc + L)
    return np.where(inside, slope, np.nan)


def hoop_wall_thickness_m(radius_m, Ri_m, wall_m, wall_mode="attenuated"):
    """Return the thickness [m] of the wall stretched to radius R: t_i,e or the original t_i.

    ``wall_mode="attenuated"`` (default): incompressible wall keeping its
    sectional area, t_i,e = sqrt((R_i + t_i)² + R² - R_i²) - R (seed 003 eq 9
    with R = R_c; seed 000 eqs 5-6 with R = R(x), whose printed bracket is an
    extraction typo). ``"original"``: the unstretched t_i, which is what
    reproduces seed 003's own 11.87 kPa at 10 mm/s (physics.md section 2).
    """
    if wall_mode not in WALL_MODES:
        raise ValueError(f"wall_mode must be one of {WALL_MODES}, got {wall_mode!r}")
    R = np.asarray(radius_m, float)
    Ri = np.asarray(Ri_m, float)
    t = np.asarray(wall_m, float)
    if wall_mode == "original":
        return np.broadcast_to(t, np.broadcast_shapes(R.shape, Ri.shape, t.shape)).astype(float)
    return np.sqrt((Ri + t) ** 2 + R ** 2 - Ri ** 2) - R


def hoop_strain(radius_m, Ri_m):
    """Return the hoop strain magnitude ε = (R - R_i)/R_i [-] of the wall stretched to radius R (>= 0).

    seed 003 eq 10 writes (R_i - R_c)/R_i (negative); the magnitude is used.
    """
    R = np.asarray(radius_m, float)
    Ri = np.asarray(Ri_m, float)
    return np.clip((R - Ri) / Ri, 0.0, None)


def _relaxation_factor(x_m, speed_m_s, E1_Pa, eta1_Pa_s):
    """exp(-E_1 x / (η_1 V)); V = 0 means fully relaxed (0 for x > 0, 1 at x = 0)."""
    x = np.asarray(x_m, float)
    V = np.asarray(speed_m_s, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        arg = np.asarray(E1_Pa, float) * x / (np.asarray(eta1_Pa_s, float) * V)
    arg = np.where(x <= 0.0, 0.0, arg)
    return np.exp(-np.where(np.isnan(arg), np.inf, arg))


def hoop_pressure_profile_Pa(x_m, speed_m_s, Ri_m, Rc_m, L_m, wall_m, E1_Pa, E2_Pa, eta1_Pa_s,
                             wall_mode="attenuated", end_length_m=None):
    """Return the hoop pressure P_h(x) [Pa] along the capsule, x from the first contact point [m].

    Parameters
    ----------
    x_m : axial position from the point where the head first touches the wall [m]
        (the body spans [x_c, x_c + L], the whole contact [0, 2 x_c + L];
        see :func:`hoop_contact_start_m`); 0 outside the contact
    speed_m_s : constant capsule speed V [m/s] (>= 0; V = 0 gives the fully relaxed wall)
    Ri_m : intestine inner radius R_i [m] (< R_c for contact; R_i >= R_c gives 0)
    Rc_m : capsule outer radius R_c [m]
    L_m : length of the cylindrical body L [m]
    wall_m : unstretched wall thickness t_i [m]
    E1_Pa, E2_Pa, eta1_Pa_s : three-element Maxwell model (arm spring E_1 [Pa],
        equilibrium spring E_2 [Pa], dashpot η_1 [Pa·s])
    wall_mode : "attenuated" (t_i,e, default) or "original" (t_i), see :func:`hoop_wall_thickness_m`
    end_length_m : axial length of the semi-elliptical ends [m]; None = hemispherical (= R_c)

    Notes
    -----
    seed 003 eqs 8-13 on the body, generalised to the ends as in seed 000 eqs 4-9:
    ε(x) = (R(x) - R_i)/R_i, τ(x) = ε(x) (E_1 exp(-E_1 x/(η_1 V)) + E_2),
    P_h(x) = t(x) τ(x) / R(x), with t(x) the (attenuated) wall thickness at
    radius R(x). The material point first touched at x = 0 has been loaded for
    a time x/V. Like the papers, the tail is treated with the same
    quasi-static law (no unloading history).
    """
    x, V, Ri, Rc, L, t = np.broadcast_arrays(*(np.asarray(v, float) for v in
                                               (x_m, speed_m_s, Ri_m, Rc_m, L_m, wall_m)))
    R = capsule_radius_m(x, Ri, Rc, L, end_length_m)
    inside = np.isfinite(R)
    Rs = np.where(inside, R, Rc)
    thick = hoop_wall_thickness_m(Rs, Ri, t, wall_mode)
    eps = hoop_strain(Rs, Ri)
    tau = eps * (np.asarray(E1_Pa, float) * _relaxation_factor(x, V, E1_Pa, eta1_Pa_s) + np.asarray(E2_Pa, float))
    return np.where(inside, thick * tau / Rs, 0.0)


def hoop_pressure_avg_Pa(speed_m_s, Ri_m, Rc_m, L_m, wall_m, E1_Pa, E2_Pa, eta1_Pa_s,
                         wall_mode="attenuated", end_length_m=None):
    """Return the hoop pressure averaged over the cylindrical body, P_h [Pa] (seed 003 eq 14).

    P_h = (1/L) ∫_{x_c}^{x_c+L} P_h(x) dx in closed form:
    (t/R_c) ε [E_2 + E_1 (η_1 V/(E_1 L)) exp(-E_1 x_c/(η_1 V)) (1 - exp(-E_1 L/(η_1 V)))],
    with ε = (R_c - R_i)/R_i and t = t_i,e (attenuated) or t_i (original).
    Arguments as :func:`hoop_pressure_profile_Pa`; broadcasts over speed and R_i.

    Notes
    -----
    seed 003 eqs 8-14. For R_i = 5 mm and seed 003 Table 1: 10.92 kPa at
    10 mm/s and 10.80 kPa at 4 mm/s (seed 000's FE: 10.795 kPa); 11.88 kPa at
    10 mm/s with the original thickness (seed 003 reports 11.87 kPa). The end
    length enters only through x_c (longer ends: more relaxation before the body).
    """
    V, Ri, Rc, L, t, a = np.broadcast_arrays(*(np.asarray(v, float) for v in
                                               (speed_m_s, Ri_m, Rc_m, L_m, wall_m, _end_length(Rc_m, end_length_m))))
    E1 = np.asarray(E1_Pa, float)
    E2 = np.asarray(E2_Pa, float)
    eta1 = np.asarray(eta1_Pa_s, float)
    xc = hoop_contact_start_m(Ri, Rc, a)
    thick = hoop_wall_thickness_m(Rc, Ri, t, wall_mode)
    eps = hoop_strain(Rc, Ri)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        k = E1 / (eta1 * V)  # decay rate along x [1/m]; inf at V = 0
        kL = k * L
        mean_exp = np.exp(-k * xc) * (-np.expm1(-kL)) / kL
    mean_exp = np.where(V > 0, mean_exp, 0.0)
    return thick * eps * (E1 * mean_exp + E2) / Rc


def _gauss_segments(x0, x1, n):
    """Gauss-Legendre nodes and weights on [x0, x1] (arrays broadcast; nodes on the last axis)."""
    u, w = np.polynomial.legendre.leggauss(n)
    x0 = np.asarray(x0, float)[..., None]
    x1 = np.asarray(x1, float)[..., None]
    half = 0.5 * (x1 - x0)
    return x0 + half * (u + 1.0), half * w


def hoop_pressure_contact_avg_Pa(speed_m_s, Ri_m, Rc_m, L_m, wall_m, E1_Pa, E2_Pa, eta1_Pa_s,
                                 wall_mode="attenuated", end_length_m=None, n_nodes=64):
    """Return the hoop pressure averaged over the whole contact surface (ends and body) [Pa].

    Area-weighted mean ∫ P_h(x) 2π R(x) sqrt(1 + R'(x)²) dx / ∫ 2π R(x) sqrt(1 + R'(x)²) dx
    over [0, 2 x_c + L] (surface element as seed 000 eqs 10-14), by Gauss-Legendre
    quadrature with ``n_nodes`` per segment. Unlike :func:`hoop_pressure_avg_Pa`
    (body only, seed 003 eq 14) it includes the lower pressures on the ends, so
    it is closer to an FE "average contact pressure" (seed 001 sections 4 and 6).
    """
    V, Ri, Rc, L, t, a = np.broadcast_arrays(*(np.asarray(v, float) for v in
                                               (speed_m_s, Ri_m, Rc_m, L_m, wall_m, _end_length(Rc_m, end_length_m))))
    xc = hoop_contact_start_m(Ri, Rc, a)
    num = np.zeros(V.shape)
    den = np.zeros(V.shape)
    for lo, hi in ((0.0 * xc, xc), (xc, xc + L), (xc + L, 2 * xc + L)):
        xs, ws = _gauss_segments(lo, hi, n_nodes)
        ex = lambda v: np.asarray(v)[..., None]  # noqa: E731
        R = capsule_radius_m(xs, ex(Ri), ex(Rc), ex(L), ex(a))
        dR = capsule_radius_slope(xs, ex(Ri), ex(Rc), ex(L), ex(a))
        dA = 2.0 * np.pi * R * np.sqrt(1.0 + dR ** 2)
        P = hoop_pressure_profile_Pa(xs, ex(V), ex(Ri), ex(Rc), ex(L), ex(t), E1_Pa, E2_Pa, eta1_Pa_s,
                                     wall_mode, ex(a))
        num = num + np.nansum(P * dA * ws, axis=-1)
        den = den + np.nansum(dA * ws, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / den, 0.0)


def hoop_pressure_max_Pa(speed_m_s, Ri_m, Rc_m, L_m, wall_m, E1_Pa, E2_Pa, eta1_Pa_s,
                         wall_mode="attenuated", end_length_m=None, n_grid=2001):
    """Return the maximum of the hoop pressure profile over the contact [Pa].

    On the body the profile decays with x (relaxation), and on the tail the
    strain falls, so the maximum lies on the head end or at the head-body
    junction x = x_c; it is found on a grid of ``n_grid`` points over the head
    plus the junction. In this reduced membrane model the maximum is close to
    the body value at x_c and hardly depends on the end length: it has no
    meridional-curvature or contact-edge concentration, which is what makes
    seed 001's FE maxima (53.28 to 16.76 kPa as the end lengthens) large.
    """
    V, Ri, Rc, L, t, a = np.broadcast_arrays(*(np.asarray(v, float) for v in
                                               (speed_m_s, Ri_m, Rc_m, L_m, wall_m, _end_length(Rc_m, end_length_m))))
    xc = hoop_contact_start_m(Ri, Rc, a)
    frac = np.linspace(0.0, 1.0, n_grid)
    xs = xc[..., None] * frac
    ex = lambda v: np.asarray(v)[..., None]  # noqa: E731
    P = hoop_pressure_profile_Pa(xs, ex(V), ex(Ri), ex(Rc), ex(L), ex(t), E1_Pa, E2_Pa, eta1_Pa_s,
                                 wall_mode, ex(a))
    return P.max(axis=-1)


def relaxation_pressure_factor(Ri_m, Rc_m, wall_m, wall_mode="attenuated"):
    """Return the factor [-] that turns the wall modulus E(t) into contact pressure, t_i,e ε / R_c.

    Pressure on a capsule held still in a contractive intestine:
    P(t) = factor · E(t) (seed 003 eqs 9-13 with x/V replaced by t; contract
    section 4, relaxation base ``maxwell``). 0.01153 for R_i = 5 mm (attenuated wall).
    """
    thick = hoop_wall_thickness_m(Rc_m, Ri_m, wall_m, wall_mode)
    return thick * hoop_strain(Rc_m, Ri_m) / np.asarray(Rc_m, float)
