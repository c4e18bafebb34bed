"""Each built-in quasi-static effect against the number its cited seed case gives (issue 10 item 7).

Every prediction goes through the registry (a model file's base + effect, bound to a table), so what is
checked is the effect as ``compare``/``diagnose`` use it, not only the physics function under it. The
numbers are those of the spec physics.md section "Friction ... Contact pressure" (quoted from the
seeds). The tolerance is stated per test, with the reason.

Effects with no seed number to reproduce (listed so the gap is visible):
* friction ``viscous``: cited from Armstrong-Helouvry et al. 1994, no seed case;
* friction ``stribeck``: seed 000 eq 22 sets the static level (2.5 mN) at the kinetic law's rest value
  (eq 17: 2.518 mN): the seed reports no breakaway excess to reproduce;
* friction ``wall_weight``: seed 000 Case 3 reports only peaks at folds (up to 170 mN), no level of the
  wall's dead weight alone;
* friction ``curvature``: seed 001 gives pressures and resistance in a curved intestine but no straight
  resistance at the same conditions to form the ratio the effect predicts;
* pressure ``end_shape``: seed 001 reports the *maximum* pressure (53.28 to 16.76 kPa) and the resistance
  as the end lengthens; the reduced model gives the average pressure (it changes by < 1 %), so there is
  no like-for-like number;
* relaxation ``maxwell_arm``: seed 004 eq 1 gives the Prony form only, no arm values.
``circular_folds`` is checked against seed 000 Case 2 in tests/test_diagnose_robust.py, the Coulomb base
and eq 17 in tests/test_effects.py.
"""
from __future__ import annotations

import pandas as pd
import pytest

from capsule_cli.effects.constants import capsule_constants, published
from capsule_cli.effects.registry import get_effect

from test_diagnose import mk

PSI_KPA = 6.894757  # 1 psi in kPa


def predict(model: dict, table: dict):
    return mk(model).bind(pd.DataFrame(table)).predict()


def test_speed_power_law_with_eq18_reproduces_case4_measurements():
    # seed 000 eq 18 (Case 4): F = 1539 V^0.25 + 1383 mN, r^2 = 0.907; measured 3641.87 mN at 4 mm/s and
    # 3973.08 mN at 8 mm/s (physics.md). The constant 1383 mN is the Coulomb base with mu = 1383 / (m g).
    c = capsule_constants()
    mu = 1.383 / (published("mass_g") * 1e-3 * c["g"])
    F = predict({"kind": "friction", "base": "coulomb", "effects": ["speed_power_law"],
                 "params": {"mu": mu, "mass_g": published("mass_g"), "a_mN": 1539.0, "n": 0.25}},
                {"speed_mm_s": [4.0, 8.0]})
    assert F == pytest.approx([3641.87, 3973.08], rel=0.03)  # 3 %: the fit's scatter (r^2 0.91) at these points


def test_speed_power_law_with_eq17_is_within_the_case1_noise_of_the_measurements():
    # seed 000 eq 17 (Case 1): 8.778 V^0.25 + 2.518 mN against 19.57 mN at 8 mm/s and 21.45 mN at 12 mm/s;
    # the seed states a measurement noise of about 5 mN (section 4.1): the law lies within it
    c = capsule_constants()
    mu = 2.518e-3 / (published("mass_g") * 1e-3 * c["g"])
    F = predict({"kind": "friction", "base": "coulomb", "effects": ["speed_power_law"],
                 "params": {"mu": mu, "mass_g": published("mass_g"), "a_mN": 8.778, "n": 0.25}},
                {"speed_mm_s": [8.0, 12.0]})
    assert abs(F[0] - 19.57) < 5.0 and abs(F[1] - 21.45) < 5.0


def test_friction_hoop_pressure_reproduces_case4_fe_and_measured_range():
    # seed 000 section 4.4: FE friction 3.8 N at R_i = 4.4 mm and about 1.5 N at R_i = 5.0 mm; measured
    # 2.5-4.5 N over 0.4-12 mm/s. hoop_scale = 1 is the seed's wall. 2 % / 6 %: FE values quoted as "about"
    model = {"kind": "friction", "base": "coulomb", "effects": ["hoop_pressure"], "params": {"hoop_scale": 1.0}}
    F44 = predict(model, {"speed_mm_s": [0.4, 4.0, 8.0, 12.0], "Ri_mm": [4.4] * 4}) / 1e3
    assert F44[-1] == pytest.approx(3.8, rel=0.02)
    assert ((F44 > 2.5) & (F44 < 4.5)).all()
    F50 = predict(model, {"speed_mm_s": [4.0], "Ri_mm": [5.0]}) / 1e3
    assert F50[0] == pytest.approx(1.5, rel=0.06)


def test_viscoelastic_relaxation_time_is_the_maxwell_walls():
    # seed 003 Table 1: tau = eta_1 / E_1 = 5.36 MPa s / 196.43 kPa = 27.29 s; the effect's start value
    tau = next(p.start for p in get_effect("friction", "viscoelastic_relaxation").params if p.name == "relax_time_s")
    assert tau == pytest.approx(published("eta1_MPa_s") / published("E1_kPa") * 1e3, rel=0.001)
    assert tau == pytest.approx(27.29, abs=0.02)


def test_pressure_hoop_pressure_on_hertz_reproduces_case3_fe_with_gravity():
    # seed 003 section 5, Case 3 (R_i = 5 mm, 13.76 mm/s): FE with gravity 13 kPa, hoop only 12 kPa,
    # 14.38 kPa measured at that speed. Hertz (weight) + hoop: within 10 % of the FE with gravity, below
    # the measurement (the reduced model has no end effects)
    P = predict({"kind": "pressure", "base": "hertz", "effects": ["hoop_pressure"], "params": {}},
                {"speed_mm_s": [13.76], "Ri_mm": [5.0]})[0]
    assert P == pytest.approx(13.0, rel=0.10)
    assert P < 14.38


def test_pressure_wall_weight_explains_two_thirds_of_case2():
    # seed 003 section 5, Case 2 (collapsed, R_i = 13 mm): about 2.0 kPa measured, 1.85 kPa FE. The dead
    # weight of the wall on top of the Hertz contact gives 1.24 kPa: the effect explains about two thirds
    # of the FE value (known gap, pinned so that a change is noticed; diagnose can fit wall_weight_scale)
    P = predict({"kind": "pressure", "base": "hertz", "effects": ["wall_weight"], "params": {}},
                {"speed_mm_s": [14.96], "Ri_mm": [13.0]})[0]
    assert P == pytest.approx(1.238, abs=0.005)
    assert 0.6 < P / 1.85 < 0.75


def test_coating_reproduces_seed004_modulus_ratio_and_overstates_the_thickness_effect():
    # seed 004 section 4: with a 0.9 mm coating the average pressure rises from 12.22 to 13.88 kPa as its
    # modulus rises from 8 to 16 psi (ratio 0.880); the effect's ratio is within 3 % of it. Only ratios
    # compare: the seed's FE is a vibrating capsule, our base the quasi-static hoop model
    def P(E_psi, h_mm):
        return predict({"kind": "pressure", "base": "hoop", "effects": ["coating"],
                        "params": {"coating_mm": h_mm, "coating_modulus_kPa": E_psi * PSI_KPA}},
                       {"speed_mm_s": [10.0]})[0]

    assert P(8, 0.9) / P(16, 0.9) == pytest.approx(12.22 / 13.88, rel=0.03)
    # section 5: at 10 psi, 0.3 -> 0.9 mm lowers the average from 13.91 to 13.25 kPa (ratio 0.953); the
    # series-spring model gives 0.85: it overstates the thickness effect (known gap, pinned)
    thick = P(10, 0.9) / P(10, 0.3)
    assert thick == pytest.approx(0.851, abs=0.005) and thick < 13.25 / 13.91 - 0.05


def test_pressure_curvature_default_gain_matches_seed001_radius_ratio():
    # seed 001 section 5, without mesentery: the maximum pressure falls from 45.37 to 28.14 kPa as the bending
    # radius grows from 10 to 400 mm (ratio 1.61); the default gain gives 1.74: within 10 %
    P = predict({"kind": "pressure", "base": "hoop", "effects": ["curvature"], "params": {}},
                {"speed_mm_s": [10.0, 10.0], "bend_radius_mm": [10.0, 400.0]})
    assert P[0] / P[1] == pytest.approx(45.37 / 28.14, rel=0.10)
