"""diagnose: every built-in effect of the quasi-static kinds, hidden from the base model, is named, and
once added the held-out error is within 1.2x the true noise; with nothing missing the verdict is null.

Data come from capsule-cli synth's engine (truth = base + effect at published-scale values). Where an
effect is confounded with a free base parameter, that parameter is fixed in the base model (reason given).
"""
from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest

from capsule_cli.config import ModelFile, validate
from capsule_cli.effects.model import build_model
from capsule_cli.steps.compare import run_compare
from capsule_cli.steps.diagnose import run_diagnose
from capsule_cli.steps.residual_tests import lomb_scargle, noise_estimate, runs_test
from capsule_cli.steps.synth import synthesize
from capsule_cli.tables import provenance, read_measurements, write_measurements

SP = [0.2, 0.4, 0.7, 1, 1.5, 2, 3, 4, 6, 8, 10, 12]  # mm/s, the range of seed 000 section 4.1
PSP = [0.5, 1, 2, 3, 4, 6, 8, 10]  # mm/s, seed 001 section 4


def mk(d):
    return build_model(validate(ModelFile, d, "m.yaml"), path="m.yaml")


def grid(**cols):
    keys = list(cols)
    rows = list(itertools.product(*cols.values()))
    return {k: [r[i] for r in rows] for i, k in enumerate(keys)}


def loop(tmp_path, truth, base, design, sd, reps, seed=0, figures=False):
    """synth -> diagnose --write-model -> compare; return (diagnosis, compare metrics or None)."""
    df = synthesize(mk(truth), pd.DataFrame(design), sd, 0.0, reps, seed)
    p = tmp_path / "d_synthetic.csv"
    write_measurements(df, p, provenance(synthetic=True))
    d, k = read_measurements(p)
    r = run_diagnose(mk(base), d, k, str(p), tmp_path / "diag", tmp_path / "new.yaml", seed=seed,
                     figures=figures)
    met = None
    if r["verdict"]["missing_effect"]:
        met = run_compare(build_model(tmp_path / "new.yaml"), d, k, str(p), tmp_path / "cmp", None, figures=False)
    return r, met


def fr(effects, **params):
    return {"kind": "friction", "base": "coulomb", "effects": effects,
            "params": {"mu": 0.2293, "mass_g": 3.462, **params}}


COULOMB_FREE = {"kind": "friction", "base": "coulomb", "effects": [],
                "params": {"mu": {"value": 0.2293, "free": True, "bounds": [0, 1]}, "mass_g": 3.462}}
# wall_weight adds mu m_w g, a constant: confounded with a free mu, so mu is fixed at seed 000's 0.2293
COULOMB_FIXED = {"kind": "friction", "base": "coulomb", "effects": [], "params": {"mu": 0.2293, "mass_g": 3.462}}
POS = grid(speed_mm_s=[2, 8], position_mm=list(np.arange(0, 200, 2.0)))
TIME = grid(speed_mm_s=[2, 8], time_s=list(np.arange(0, 120, 2.0)))
HERTZ = {"kind": "pressure", "base": "hertz", "effects": [], "params": {"load_g": 0.4}}
# load_g fixed: wall_weight (a constant pressure) is confounded with a free load
HOOP_E2 = {"kind": "pressure", "base": "hoop", "effects": [],
           "params": {"E2_kPa": {"value": 757.48, "free": True, "bounds": [100, 3000]}}}
# coating and end_shape scale the hoop pressure: confounded with free moduli, so the seed's wall is fixed
HOOP_FIXED = {"kind": "pressure", "base": "hoop", "effects": [], "params": {}}
MAXWELL = {"kind": "relaxation", "base": "maxwell", "effects": [],
           "params": {k: {"value": v, "free": True, "bounds": b}
                      for k, v, b in [("E1_kPa", 196.43, [1, 1e4]), ("E2_kPa", 757.48, [1, 1e4]),
                                      ("eta1_MPa_s", 5.36, [0.01, 1e3])]}}
RTIME = {"time_s": list(np.r_[np.arange(0, 10, 0.5), np.arange(10, 60, 2), np.arange(60, 181, 5)])}

CASES = {
    # effect: (truth, base, design, noise SD, replicates)
    "speed_power_law": (fr(["speed_power_law"], a_mN=8.778, n=0.25), COULOMB_FREE, {"speed_mm_s": SP}, 1.5, 4),
    "viscous": (fr(["viscous"], c_Ns_m=1.5), COULOMB_FREE, {"speed_mm_s": SP}, 1.5, 4),
    "stribeck": (fr(["stribeck"], stribeck_mN=8, stribeck_speed_mm_s=0.8), COULOMB_FREE, {"speed_mm_s": SP}, 1.0, 4),
    "hoop_pressure": (fr(["hoop_pressure"], hoop_scale=1.0), COULOMB_FREE,
                      grid(speed_mm_s=SP[::3], Ri_mm=[4.4, 4.7, 5.0, 5.2]), 50.0, 2),
    "circular_folds": (fr(["circular_folds"], fold_amplitude_mN=20, fold_spacing_mm=50, fold_width_mm=3,
                          fold_phase_mm=10), COULOMB_FREE, POS, 2.0, 1),
    "viscoelastic_relaxation": (fr(["viscoelastic_relaxation"], relax_amplitude_mN=10, relax_time_s=20),
                                COULOMB_FREE, TIME, 1.5, 1),
    "wall_weight": (fr(["wall_weight"], wall_mass_g=2.0), COULOMB_FIXED, {"speed_mm_s": SP}, 1.0, 4),
    "curvature": (fr(["curvature"], curvature_gain=0.5), COULOMB_FREE,
                  grid(speed_mm_s=SP[::2], bend_radius_mm=[10, 15, 25, 50, 100, 400]), 1.0, 2),
    "p_wall_weight": ({**HERTZ, "effects": ["wall_weight"], "params": {"load_g": 0.4, "wall_weight_scale": 1.0}},
                      HERTZ, {"speed_mm_s": PSP, "Ri_mm": [13.0] * 8}, 0.02, 4),
    "p_hoop_pressure": ({**HERTZ, "effects": ["hoop_pressure"], "params": {"load_g": 0.4, "hoop_scale": 1.0}},
                        HERTZ, grid(speed_mm_s=PSP, Ri_mm=[4.6, 5.0, 5.4, 13.0]), 0.3, 2),
    "p_curvature": ({"kind": "pressure", "base": "hoop", "effects": ["curvature"], "params": {"curvature_gain": 0.5}},
                    HOOP_E2, grid(speed_mm_s=PSP, bend_radius_mm=[10, 15, 25, 50, 100, 400]), 0.2, 2),
    "coating": ({"kind": "pressure", "base": "hoop", "effects": ["coating"],
                 "params": {"coating_mm": 0.9, "coating_modulus_kPa": 55.2}},  # seed 004: 0.9 mm, 8 psi
                HOOP_FIXED, {"speed_mm_s": PSP}, 0.1, 4),
    "end_shape": ({"kind": "pressure", "base": "hoop", "effects": ["end_shape"], "params": {"end_length_mm": 12.0}},
                  HOOP_FIXED, {"speed_mm_s": PSP}, 0.02, 4),
    "maxwell_arm": ({"kind": "relaxation", "base": "maxwell", "effects": ["maxwell_arm"],
                     "params": {"arm_E_kPa": 300.0, "arm_eta_MPa_s": 0.6}}, MAXWELL, RTIME, 0.05, 1),
}


@pytest.mark.parametrize("case", list(CASES))
def test_hidden_effect_is_named_and_error_falls_to_noise(tmp_path, case):
    truth, base, design, sd, reps = CASES[case]
    r, met = loop(tmp_path, truth, base, design, sd, reps)
    effect = truth["effects"][0]
    assert r["verdict"]["missing_effect"] == effect, r["verdict"]["message"]
    assert r["candidates"][0]["delta_cv_rmse"] < 0
    assert met is not None and met["effects"] == [effect]
    assert met["cv_rmse"] <= 1.2 * sd, (met["cv_rmse"], sd)
    md = (tmp_path / "diag" / "diagnosis.md").read_text()
    assert effect in md and "held-out RMSE" in md


def test_nothing_missing_is_null_in_at_least_90_percent_of_20_seeds(tmp_path):
    truth = fr(["speed_power_law"], a_mN=8.778, n=0.25)  # seed 000 eq 17
    model = {"kind": "friction", "base": "coulomb", "effects": ["speed_power_law"],
             "params": {"mu": {"value": 0.2293, "free": True, "bounds": [0, 1]}, "mass_g": 3.462,
                        "a_mN": {"value": 5, "free": True, "bounds": [0, 100]},
                        "n": {"value": 0.5, "free": True, "bounds": [0.05, 3]}}}
    nulls = 0
    for seed in range(20):
        r, _ = loop(tmp_path / f"s{seed}", truth, model, {"speed_mm_s": SP}, 1.5, 3, seed=seed)
        v = r["verdict"]
        nulls += v["missing_effect"] is None and v["covariate"] is None
        if v["missing_effect"] is None and v["covariate"] is None:
            assert v["message"].startswith("nothing is missing")
    assert nulls >= 18


def test_diagnosis_json_has_the_contract_keys(tmp_path):
    truth, base, design, sd, reps = CASES["viscous"]
    r, _ = loop(tmp_path, truth, base, design, sd, reps, figures=True)
    for c in r["candidates"]:
        assert {"effect", "cv_rmse", "delta_cv_rmse", "delta_bic", "params"} <= set(c)
    assert [c["cv_rmse"] for c in r["candidates"]] == sorted(c["cv_rmse"] for c in r["candidates"])
    for s in r["residual_structure"]:
        assert {"covariate", "test", "statistic", "p_value", "periodic_period"} <= set(s)
    assert {"missing_effect", "covariate", "message"} <= set(r["verdict"])
    for f in ("residuals.png", "candidates.png", "best_candidate.png", "diagnosis.md"):
        assert (tmp_path / "diag" / f).stat().st_size > 1000
    new = (tmp_path / "new.yaml").read_text()
    assert "effects: [viscous]" in new and "c_Ns_m" in new


def test_periodogram_finds_the_period_and_runs_test_sees_drift():
    rng = np.random.default_rng(1)
    x = np.arange(0, 200, 2.0)
    r = np.sin(2 * np.pi * x / 37.0) + 0.3 * rng.standard_normal(x.size)
    power, p, period = lomb_scargle(x, r)
    assert p < 1e-6 and period == pytest.approx(37.0, rel=0.03)
    _, p_noise, _ = lomb_scargle(x, rng.standard_normal(x.size))
    assert p_noise > 0.01
    assert runs_test(x, np.sin(x / 60.0))[1] < 1e-3
    assert runs_test(x, rng.standard_normal(x.size))[1] > 0.01


def test_noise_estimates_replicates_and_difference_based():
    rng = np.random.default_rng(2)
    sp = np.repeat(np.linspace(0.2, 12, 12), 5)
    y = 8 + 3 * sp ** 0.5 + 1.5 * rng.standard_normal(sp.size)
    n = noise_estimate(pd.DataFrame({"speed_mm_s": sp, "friction_mN": y}), "friction_mN")
    assert n["method"].startswith("replicates") and n["sd"] == pytest.approx(1.5, rel=0.25)
    sp = np.linspace(0.2, 12, 80)
    y = 8 + 3 * sp ** 0.5 + 1.5 * rng.standard_normal(sp.size)
    n = noise_estimate(pd.DataFrame({"speed_mm_s": sp, "friction_mN": y}), "friction_mN")
    assert n["method"].startswith("difference-based") and n["sd"] == pytest.approx(1.5, rel=0.25)
