"""Friction models of seed 000 (eqs 1, 3-18) against the papers' numbers (physics.md section 2)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate

from capsule_cli.config import load_param_set_si
from capsule_cli.models import contact as cm
from capsule_cli.models import friction as fm

P = load_param_set_si("capsule_intestine")
MM = 1e-3


def hoop(V_mm_s, Ri_mm, wall_mode="attenuated"):
    return fm.hoop_friction_components_N(np.asarray(V_mm_s, float) * MM, np.asarray(Ri_mm, float) * MM, P["Rc"],
                                         P["L"], P["wall"], P["E1"], P["E2"], P["eta1"], P["mu"], wall_mode)


def case4_total_N(V_mm_s, Ri_mm):
    return fm.contractive_friction_N(np.asarray(V_mm_s, float) * MM, Ri_mm * MM, P["Rc"], P["L"], P["wall"],
                                     P["E1"], P["E2"], P["eta1"], P["mu"], P["mass"], P["g"])


def test_coulomb_friction_matches_seed000_eq1():
    # seed 000 eq 1 with mu = 0.2293, m = 3.462 g: 7.79 mN (the paper rounds to 7.8 mN)
    F = fm.coulomb_friction_N(P["mu"], P["mass"], P["g"])
    assert F == pytest.approx(7.79e-3, abs=0.005e-3)


def test_power_law_reproduces_seed000_eq17_and_eq18():
    # eq 17: F = 8.778 V^0.25 + 2.518 mN; eq 18: 1539 V^0.25 + 1383 mN (V in mm/s)
    V = np.array([0.0, 1.0, 16.0]) * MM
    f17 = fm.power_law_friction_N(V, 8.778e-3, 0.25, 2.518e-3)
    assert f17 == pytest.approx(np.array([2.518, 11.296, 2.518 + 2 * 8.778]) * 1e-3, rel=1e-12)
    f18 = fm.power_law_friction_N(4.0 * MM, 1.539, 0.25, 1.383)
    assert f18 == pytest.approx(1.383 + 1.539 * np.sqrt(2.0), rel=1e-12)


def test_viscous_and_stribeck_limits():
    assert fm.viscous_friction_N(2e-3, 3.0) == pytest.approx(6e-3)
    F = fm.stribeck_friction_N(np.array([0.0, 1e-3, 1.0]), 0.010, 0.015, 1e-3)
    assert F[0] == pytest.approx(0.015)               # static level at rest
    assert F[1] == pytest.approx(0.010 + 0.005 / np.e)  # exp(-1) at V = Vs (delta = 2)
    assert F[2] == pytest.approx(0.010)               # Coulomb level at high speed


@pytest.mark.parametrize("Ri_mm, lo_N, hi_N", [(4.4, 3.45, 3.81), (4.8, 2.07, 2.29), (5.0, 1.43, 1.58)])
def test_case4_friction_ranges_match_physics_md(Ri_mm, lo_N, hi_N):
    # physics.md section 2: F_c4 = F_g + F_h over 0.4-12 mm/s, quoted to 0.01 N
    F = case4_total_N([0.4, 12.0], Ri_mm)
    assert F[0] == pytest.approx(lo_N, abs=0.006)
    assert F[1] == pytest.approx(hi_N, abs=0.006)


def test_hoop_friction_at_5mm_is_near_seed000_FE_1p5N():
    # seed 000 section 4.4: the FE (no gravity) gives about 1.5 N at R_i = 5.0 mm; F_h alone is the comparable term
    F = hoop([4.0], 5.0)["total"][0]
    assert F == pytest.approx(1.5, rel=0.06)


def test_hoop_friction_at_4p4mm_lies_in_measured_range_and_near_FE():
    # seed 000 section 4.4: measured 2.5-4.5 N over 0.4-12 mm/s; FE about 3.8 N at R_i = 4.4 mm
    V = np.linspace(0.4, 12.0, 30)
    F = case4_total_N(V, 4.4)
    assert np.all((F > 2.5) & (F < 4.5))
    assert F[-1] == pytest.approx(3.8, rel=0.02)


def test_hoop_components_signs_and_sum():
    c = hoop(np.array([0.4, 4.0, 12.0]), 4.6)
    for key in ("head_resistance", "head_friction", "body_friction", "tail_friction"):
        assert np.all(c[key] > 0), key
    assert np.all(c["tail_push"] < 0)  # physics.md fix (2): the tail's axial term pushes forward
    assert np.allclose(c["total"], sum(c[k] for k in fm.HOOP_COMPONENTS), rtol=1e-14)
    assert np.all(np.diff(c["total"]) > 0)  # less relaxation at higher speed -> more friction


def test_hoop_friction_is_very_sensitive_to_Ri():
    # seed 000 section 4.4: "the friction prediction for R_i = 4.8 mm is much smaller than for 4.4 mm"
    F = hoop(4.0, np.linspace(4.2, 5.4, 13))["total"]
    assert np.all(np.diff(F) < 0)
    assert F[2] / F[6] > 1.6  # 4.4 mm vs 4.8 mm
    assert hoop(4.0, 5.5)["total"] == pytest.approx(0.0, abs=1e-15)  # R_i = R_c: no stretch, no hoop friction
    assert hoop(4.0, 6.0)["total"] == 0.0


def test_hoop_components_match_adaptive_quadrature():
    # independent check of the Gauss-Legendre sums: eqs 10-14 with R sqrt(1 + R'^2) = R_c on the caps
    V, Ri = 0.7e-3, 4.5e-3
    Rc, L, mu = P["Rc"], P["L"], P["mu"]
    xc = np.sqrt(Rc ** 2 - Ri ** 2)

    def Ph(x):
        return float(cm.hoop_pressure_profile_Pa(x, V, Ri, Rc, L, P["wall"], P["E1"], P["E2"], P["eta1"]))

    def R(x):
        return float(cm.capsule_radius_m(x, Ri, Rc, L))

    def q(f, a, b):
        return integrate.quad(f, a, b, epsabs=0, epsrel=1e-12, limit=200)[0]

    ref = {
        "head_resistance": 2 * np.pi * q(lambda x: (xc - x) * Ph(x), 0, xc),
        "head_friction": 2 * np.pi * mu * q(lambda x: R(x) * Ph(x), 0, xc),
        "body_friction": 2 * np.pi * mu * Rc * q(Ph, xc, xc + L),
        "tail_push": 2 * np.pi * q(lambda x: (xc + L - x) * Ph(x), xc + L, 2 * xc + L),
        "tail_friction": 2 * np.pi * mu * q(lambda x: R(x) * Ph(x), xc + L, 2 * xc + L),
    }
    got = fm.hoop_friction_components_N(V, Ri, Rc, L, P["wall"], P["E1"], P["E2"], P["eta1"], mu)
    for k, v in ref.items():
        assert float(got[k]) == pytest.approx(v, rel=1e-9), k


def test_original_wall_thickness_gives_more_friction():
    # t_i (seed 003's choice) is thicker than the stretched t_i,e, so the pressure and friction are larger
    att = hoop(4.0, 4.6)["total"]
    orig = hoop(4.0, 4.6, wall_mode="original")["total"]
    assert orig > att * 1.05
    with pytest.raises(ValueError):
        hoop(4.0, 4.6, wall_mode="thin")


def test_hoop_friction_broadcasts_over_speed_and_radius():
    c = hoop(np.linspace(0.4, 12, 5)[:, None], np.array([4.4, 4.8, 5.0])[None, :])
    assert c["total"].shape == (5, 3)
    single = hoop(12.0, 4.8)["total"]
    assert c["total"][-1, 1] == pytest.approx(float(single), rel=1e-14)
