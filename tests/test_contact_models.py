"""Contact-pressure models against the papers' numbers (seed 003 eqs 2-14; physics.md sections 1-2).

Parameters come from configs/params/capsule_intestine.yaml (seed 003 Table 1) through
``contact_params_from_config``; no number below is computed by the code under test.
"""
from __future__ import annotations

import numpy as np
import pytest

from capsule_cli.models import contact as cm
from capsule_cli.models import viscoelastic as ve
from capsule_cli.steps.contact import HERTZ_KEYS, HOOP_KEYS, case_radii_from_config, contact_params_from_config

P = contact_params_from_config()
HZ = {k: P[k] for k in HERTZ_KEYS}
HOOP = {k: P[k] for k in HOOP_KEYS}
RI3 = case_radii_from_config()["case3"]  # 5 mm


def _hertz(fn, Ri=np.inf, **kw):
    return fn(P["load_N"], P["Rc_m"], Ri, P["L_m"], **HZ, **kw)


# --- Case 1: Hertz line contact (seed 003 section 2 and 5; 0.4 g capsule) -------------------------

def test_hertz_semi_width_matches_seed003_case1():
    # seed 003 section 2: a = 0.2359 mm. With g = 9.81 m/s^2 we get 0.2360 mm (g = 9.80 gives 0.2359):
    # tolerance 0.1 % covers the choice of g and the paper's 4 digits.
    assert _hertz(cm.hertz_semi_width_m) * 1e3 == pytest.approx(0.2359, rel=1e-3)


def test_hertz_average_pressure_matches_seed003_case1():
    # seed 003 section 5 (Fig 15): analytic P_avg about 0.55 kPa (2 decimals: +-0.005 kPa).
    assert _hertz(cm.hertz_pressure_avg_Pa) / 1e3 == pytest.approx(0.55, abs=0.005)


def test_hertz_maximum_pressure_matches_seed003_case1():
    # seed 003 section 5 (Fig 16): "about 0.70 kPa"; eq 4 gives 0.706 kPa (= 4/pi x 0.554).
    # Tolerance 0.01 kPa: the paper's "about" and rounding of P_avg before scaling.
    pmax = _hertz(cm.hertz_pressure_max_Pa) / 1e3
    assert pmax == pytest.approx(0.70, abs=0.01)
    assert pmax == pytest.approx(4 / np.pi * _hertz(cm.hertz_pressure_avg_Pa) / 1e3, rel=1e-12)


def test_hertz_pressure_distribution_integrates_to_the_load():
    a = _hertz(cm.hertz_semi_width_m)
    r = np.linspace(-a, a, 20001)
    p = cm.hertz_pressure_distribution_Pa(r, P["load_N"], P["Rc_m"], np.inf, P["L_m"], **HZ)
    assert np.trapezoid(p, r) * P["L_m"] == pytest.approx(P["load_N"], rel=1e-4)  # seed 003 eqs 3-4


def test_conforming_and_printed_geometry_agree_on_a_flat_wall_and_differ_in_a_trough():
    flat = [_hertz(cm.hertz_semi_width_m, conforming=c) for c in (False, True)]
    assert flat[0] == pytest.approx(flat[1], rel=1e-12)
    trough = [_hertz(cm.hertz_semi_width_m, Ri=13e-3, conforming=c) for c in (False, True)]
    assert trough[1] > flat[0] > trough[0]  # a conforming contact is wider than a flat one


# --- Case 2: collapsed wall (seed 003 eq 6, closed form ours) --------------------------------------

def test_collapsed_wall_weight_is_half_the_tube_wall():
    w = cm.collapsed_wall_weight_N_m(13e-3, 0.69e-3, 1000.0, 9.81)
    assert w == pytest.approx(1000 * 9.81 * 0.69e-3 * np.pi * (13e-3 + 0.345e-3), rel=1e-12)  # ~0.284 N/m


def test_collapsed_wall_pressure_closed_form():
    args = (13e-3, P["wall_m"], P["rho_i_kg_m3"], P["g_m_s2"], P["Rc_m"], P["L_m"])
    w = cm.collapsed_wall_weight_N_m(*args[:4])
    Ee = cm.hertz_equivalent_modulus_Pa(**HZ)
    p1 = cm.collapsed_wall_pressure_Pa(*args, **HZ)
    assert p1 == pytest.approx(np.sqrt(np.pi * w * Ee / (16 * P["Rc_m"])), rel=1e-12)


def test_collapsed_case2_pressure_is_about_half_the_published_values():
    # Our closed form (not a paper number): 0.42 kPa (capsule, conforming) + 0.58 kPa (wall) = 1.00 kPa.
    # seed 003 section 5 reports about 2.0 kPa measured and 1.85 kPa FE: the dead weight of the wall
    # explains about half. Pinned so that a change of the closed form is noticed.
    kw = dict(wall_m=P["wall_m"], rho_i_kg_m3=P["rho_i_kg_m3"], g_m_s2=P["g_m_s2"], Rc_m=P["Rc_m"],
              length_m=P["L_m"], **HZ)
    p1 = cm.collapsed_wall_pressure_Pa(13e-3, **kw)
    total = cm.collapsed_pressure_avg_Pa(P["load_N"], 13e-3, **kw)
    assert p1 / 1e3 == pytest.approx(0.577, abs=0.002)
    assert total / 1e3 == pytest.approx(0.998, abs=0.003)
    assert total / 1e3 < 0.6 * 1.85


# --- Case 3: hoop pressure (seed 003 eqs 8-14; physics.md section 2) ------------------------------

@pytest.mark.parametrize("speed_mm_s, mode, expected_kPa", [
    (4.0, "attenuated", 10.80),   # physics.md section 2; seed 000 FE 10.795 kPa
    (10.0, "attenuated", 10.92),  # physics.md section 2
    (10.0, "original", 11.88),    # physics.md section 2: seed 003 reports 11.87 kPa with t_i
])
def test_hoop_average_pressure_matches_published(speed_mm_s, mode, expected_kPa):
    # tolerance 0.005 kPa: the values are given to 2 decimals
    p = cm.hoop_pressure_avg_Pa(speed_mm_s * 1e-3, RI3, wall_mode=mode, **HOOP)
    assert p / 1e3 == pytest.approx(expected_kPa, abs=0.005)


def test_hoop_original_thickness_is_within_rounding_of_seed003_fe():
    # seed 003 section 5: FE hoop pressure 11.87 kPa at 10 mm/s, matching eq 14
    p = cm.hoop_pressure_avg_Pa(10e-3, RI3, wall_mode="original", **HOOP) / 1e3
    assert abs(p - 11.87) < 0.015


def test_hoop_closed_form_average_equals_integral_of_profile():
    for V in (0.5e-3, 4e-3, 10e-3):
        xc = cm.hoop_contact_start_m(RI3, P["Rc_m"])
        x = np.linspace(xc, xc + P["L_m"], 200001)
        prof = cm.hoop_pressure_profile_Pa(x, V, RI3, **HOOP)
        assert np.trapezoid(prof, x) / P["L_m"] == pytest.approx(cm.hoop_pressure_avg_Pa(V, RI3, **HOOP), rel=1e-8)


def test_hoop_pressure_rises_with_speed_and_is_flat_above_4_mm_s():
    # seed 001 section 4 and seed 003 Fig 18: pressure rises with speed, little change above ~4 mm/s
    v = np.linspace(0.2e-3, 16e-3, 200)
    p = cm.hoop_pressure_avg_Pa(v, RI3, **HOOP)
    assert np.all(np.diff(p) > 0)
    p05, p4, p16 = cm.hoop_pressure_avg_Pa(np.array([0.5e-3, 4e-3, 16e-3]), RI3, **HOOP)
    assert (p4 - p05) / p4 > 0.08   # 9 % rise from 0.5 to 4 mm/s
    assert (p16 - p4) / p4 < 0.02   # 1.3 % from 4 to 16 mm/s


def test_hoop_limits_of_speed():
    factor = cm.relaxation_pressure_factor(RI3, P["Rc_m"], P["wall_m"])
    assert cm.hoop_pressure_avg_Pa(0.0, RI3, **HOOP) == pytest.approx(factor * P["E2_Pa"], rel=1e-12)
    assert cm.hoop_pressure_avg_Pa(1e3, RI3, **HOOP) == pytest.approx(factor * (P["E1_Pa"] + P["E2_Pa"]), rel=1e-5)


def test_relaxation_factor_of_case3():
    # t_i,e = sqrt(5.69^2 + 5.5^2 - 5^2) - 5.5 = 0.6340 mm, eps = 0.1: factor = 0.6340 * 0.1 / 5.5
    assert cm.relaxation_pressure_factor(RI3, P["Rc_m"], P["wall_m"]) == pytest.approx(0.011527, abs=2e-6)


def test_no_hoop_contact_when_the_intestine_is_wider_than_the_capsule():
    assert cm.hoop_pressure_avg_Pa(10e-3, 5.6e-3, **HOOP) == 0.0
    assert cm.hoop_pressure_max_Pa(10e-3, 5.6e-3, **HOOP) == 0.0


def test_hoop_profile_geometry_and_continuity():
    xc = cm.hoop_contact_start_m(RI3, P["Rc_m"])
    assert xc == pytest.approx(np.sqrt(5.5 ** 2 - 5.0 ** 2) * 1e-3, rel=1e-12)  # seed 003 eq 8
    L = P["L_m"]
    R = cm.capsule_radius_m(np.array([0.0, xc, xc + L, 2 * xc + L]), RI3, P["Rc_m"], L)
    assert R == pytest.approx([RI3, P["Rc_m"], P["Rc_m"], RI3], rel=1e-12)
    x = np.linspace(0, 2 * xc + L, 5001)
    prof = cm.hoop_pressure_profile_Pa(x, 10e-3, RI3, **HOOP)
    assert abs(prof[0]) < 1e-6 and abs(prof[-1]) < 1e-6  # zero strain where the contact begins and ends [Pa]
    assert np.max(np.abs(np.diff(prof))) < 0.01 * prof.max()  # continuous along the capsule
    outside = cm.hoop_pressure_profile_Pa(np.array([-1e-3, 2 * xc + L + 1e-3]), 10e-3, RI3, **HOOP)
    assert np.all(outside == 0.0)


def test_end_length_equal_to_capsule_radius_reproduces_the_hemisphere():
    L = P["L_m"]
    xc = cm.hoop_contact_start_m(RI3, P["Rc_m"])
    x = np.linspace(0, 2 * xc + L, 777)
    for V in (0.5e-3, 10e-3):
        for fn in (cm.hoop_pressure_avg_Pa, cm.hoop_pressure_max_Pa, cm.hoop_pressure_contact_avg_Pa):
            assert fn(V, RI3, end_length_m=P["Rc_m"], **HOOP) == pytest.approx(fn(V, RI3, **HOOP), rel=1e-12)
        assert cm.hoop_pressure_profile_Pa(x, V, RI3, end_length_m=P["Rc_m"], **HOOP) == pytest.approx(
            cm.hoop_pressure_profile_Pa(x, V, RI3, **HOOP), rel=1e-12)


def test_semi_elliptical_end_starts_contact_where_its_radius_equals_Ri():
    a = 8.25e-3  # seed 001 section 6: longest end
    xc = cm.hoop_contact_start_m(RI3, P["Rc_m"], a)
    assert xc == pytest.approx(a * np.sqrt(1 - (5.0 / 5.5) ** 2), rel=1e-12)
    assert cm.capsule_radius_m(0.0, RI3, P["Rc_m"], P["L_m"], a) == pytest.approx(RI3, rel=1e-12)


def test_longer_ends_lower_the_average_pressure_but_not_the_maximum_in_the_reduced_model():
    # seed 001 section 6 (FE, 10 mm/s): average and maximum pressure fall as the end lengthens, the maximum
    # from 53.28 to 16.76 kPa. The reduced membrane model reproduces the falling averages but its maximum
    # (the head-body junction) changes by less than 1 %: it has no edge or curvature concentration.
    ends = np.array([2.75e-3, 5.5e-3, 8.25e-3])
    avg = cm.hoop_pressure_avg_Pa(10e-3, RI3, end_length_m=ends, **HOOP)
    area = cm.hoop_pressure_contact_avg_Pa(10e-3, RI3, end_length_m=ends, **HOOP)
    mx = cm.hoop_pressure_max_Pa(10e-3, RI3, end_length_m=ends, **HOOP)
    assert np.all(np.diff(avg) < 0) and np.all(np.diff(area) < 0)
    assert area[0] / area[-1] > 1.04
    assert np.all(np.diff(mx) < 0) and mx[0] / mx[-1] < 1.01
    assert np.all(area < avg) and np.all(avg < mx)


def test_hoop_functions_broadcast_over_speed_and_radius():
    v = np.array([[0.5e-3], [10e-3]])
    ri = np.array([4.6e-3, 5.0e-3, 5.4e-3])
    out = cm.hoop_pressure_avg_Pa(v, ri, **HOOP)
    assert out.shape == (2, 3)
    assert out[1, 1] == pytest.approx(cm.hoop_pressure_avg_Pa(10e-3, 5e-3, **HOOP), rel=1e-12)
    assert np.all(np.diff(out, axis=1) < 0)  # narrower intestine, higher pressure


# --- viscoelastic (seed 004 eq 1; seed 003 Table 1) -----------------------------------------------

def test_relaxation_time_of_seed003_table1():
    # physics.md section 1: eta_1 / E_1 = 27.3 s
    assert ve.relaxation_time_s(P["E1_Pa"], P["eta1_Pa_s"]) == pytest.approx(27.3, abs=0.05)


def test_prony_series_one_arm_is_the_three_element_model():
    t = np.linspace(0, 200, 101)
    f = 0.0115
    three = ve.maxwell_relaxation_pressure_Pa(t, P["E1_Pa"], P["E2_Pa"], P["eta1_Pa_s"], f)
    prony = f * ve.prony_modulus_Pa(t, [P["E1_Pa"]], [P["eta1_Pa_s"]], P["E2_Pa"])
    assert three == pytest.approx(prony, rel=1e-14)
    assert three[0] == pytest.approx(f * (P["E1_Pa"] + P["E2_Pa"]), rel=1e-14)
    tau = P["eta1_Pa_s"] / P["E1_Pa"]
    form = ve.prony_pressure_Pa(t, [f * P["E1_Pa"]], [tau], f * P["E2_Pa"])
    assert form == pytest.approx(three, rel=1e-12)


def test_prony_series_with_two_arms_adds_them():
    t = np.array([0.0, 10.0, 1e6])
    E = ve.prony_modulus_Pa(t, [100.0, 50.0], [1000.0, 50.0], 7.0)
    assert E[0] == pytest.approx(157.0)
    assert E[1] == pytest.approx(100 * np.exp(-1.0) + 50 * np.exp(-10.0) + 7.0)
    assert E[2] == pytest.approx(7.0)
