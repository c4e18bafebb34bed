"""Prony-series relaxation fit: recovery of seed 003 Table 1 values and model-order choice.

Records are built here from the three-element model of seed 003 Table 1 (E_1 = 196.43 kPa,
E_2 = 757.48 kPa, eta_1 = 5.36 MPa s; relaxation time 27.3 s) with known Gaussian noise. Seed 003
section 3 ran four relaxation trials; we build four trials of 150 s at 2 Hz, noise sd 0.05 kPa
(about 2 % of the relaxing amplitude of 2.27 kPa).
"""
from __future__ import annotations

import numpy as np
import pytest

from capsule_cli.errors import InputError
from capsule_cli.models.contact import relaxation_pressure_factor
from capsule_cli.models.viscoelastic import maxwell_relaxation_pressure_Pa, prony_pressure_Pa
from capsule_cli.steps.contact import contact_params_from_config
from capsule_cli.steps.relax import _folds, fit_prony, fit_prony_order

P = contact_params_from_config()
FACTOR = float(relaxation_pressure_factor(5e-3, P["Rc_m"], P["wall_m"]))  # 0.011527 (R_i = 5 mm)
NOISE_PA = 50.0


def _record(extra_arm=None, seed=11, trials=4):
    rng = np.random.default_rng(seed)
    t1 = np.arange(0.0, 150.0 + 1e-9, 0.5)
    t = np.tile(t1, trials)
    groups = np.repeat([f"trial{i + 1}" for i in range(trials)], t1.size)
    y = maxwell_relaxation_pressure_Pa(t, P["E1_Pa"], P["E2_Pa"], P["eta1_Pa_s"], FACTOR)
    if extra_arm is not None:
        A, tau = extra_arm
        y = y + prony_pressure_Pa(t, [A], [tau], 0.0)
    return t, y + rng.normal(0.0, NOISE_PA, t.size), groups


@pytest.fixture(scope="module")
def one_arm_fit():
    t, y, g = _record()
    return fit_prony(t, y, max_arms=3, groups=g, factor=FACTOR)


def test_one_arm_is_chosen_for_three_element_data(one_arm_fit):
    assert one_arm_fit.chosen == 1
    assert not one_arm_fit.cv.loc[one_arm_fit.cv["n_arms"] == 2, "supported"].item()
    assert "by trial" in one_arm_fit.cv_scheme


def test_table1_values_lie_inside_their_95_percent_intervals(one_arm_fit):
    # seed 003 Table 1 values used to build the record must be inside the fitted 95 % intervals
    pr = one_arm_fit.parameters()
    arm = pr["arms"][0]
    truths = {"E_kPa": P["E1_Pa"] / 1e3, "eta_MPa_s": P["eta1_Pa_s"] / 1e6,
              "tau_s": P["eta1_Pa_s"] / P["E1_Pa"]}
    for name, true in truths.items():
        lo, hi = arm[name]["ci95"]
        assert lo < true < hi, f"{name}: {true} not in [{lo}, {hi}]"
    lo, hi = pr["E_inf_kPa"]["ci95"]
    assert lo < P["E2_Pa"] / 1e3 < hi
    # and the intervals are informative (relative half-width below 5 %)
    assert (arm["E_kPa"]["ci95"][1] - arm["E_kPa"]["ci95"][0]) / 2 < 0.05 * arm["E_kPa"]["value"]
    assert arm["tau_s"]["value"] == pytest.approx(27.3, rel=0.03)


def test_fit_quality_and_noise_estimate(one_arm_fit):
    f = one_arm_fit.best.fit
    assert f.r2 > 0.98  # seed 003 reports R^2 = 0.9803 on its real record
    assert f.sigma * 1e3 == pytest.approx(NOISE_PA, rel=0.1)


def test_two_true_arms_are_detected():
    # a second, fast arm (seed 003 Fig 5a: the five-element model has two arms): 1.5 kPa, 3 s
    t, y, g = _record(extra_arm=(1500.0, 3.0), seed=5)
    fit = fit_prony(t, y, max_arms=3, groups=g, factor=FACTOR)
    assert fit.chosen == 2
    arms = fit.parameters()["arms"]
    assert arms[0]["tau_s"]["ci95"][0] < 3.0 < arms[0]["tau_s"]["ci95"][1]
    assert arms[1]["tau_s"]["ci95"][0] < 27.29 < arms[1]["tau_s"]["ci95"][1]
    row = fit.cv.set_index("n_arms").loc[2]
    assert row["delta_cv_rmse_kPa"] > row["delta_se_kPa"] and row["delta_bic"] < 0


def test_two_starting_points_reach_the_same_optimum():
    t, y, _ = _record(extra_arm=(1500.0, 3.0), seed=5)
    far = fit_prony_order(t, y, 2, x0=[8.0, 0.5, np.log(100.0), 4.0, np.log(0.5)], n_starts=1)
    near = fit_prony_order(t, y, 2, x0=[8.7, 1.5, np.log(3.0), 2.3, np.log(27.0)], n_starts=1)
    assert far.fit.rss == pytest.approx(near.fit.rss, rel=1e-8)
    assert far.fit.values == pytest.approx(near.fit.values, rel=1e-5)


def test_cv_folds_never_split_a_trial():
    groups = np.repeat(["a", "b", "c", "d", "e", "f", "g"], 5)
    folds, scheme = _folds(groups.size, groups)
    assert len(folds) == 5 and "by trial" in scheme
    seen = np.concatenate(folds)
    assert np.sort(seen) == pytest.approx(np.arange(groups.size))
    for idx in folds:
        for g in set(groups[idx]):
            assert set(np.nonzero(groups == g)[0]) <= set(idx)


def test_single_record_uses_interleaved_folds():
    t, y, _ = _record(trials=1)
    fit = fit_prony(t, y, max_arms=2)
    assert fit.chosen == 1 and "interleaved" in fit.cv_scheme
    assert "E_kPa" not in fit.parameters()["arms"][0]  # no factor given: amplitudes only


def test_a_flat_record_is_rejected():
    t = np.linspace(0, 10, 50)
    with pytest.raises(InputError, match="does not change"):
        fit_prony(t, np.full_like(t, 9000.0))


def test_too_few_points_for_the_arms_is_rejected():
    t = np.linspace(0, 10, 6)
    with pytest.raises(InputError, match="too few"):
        fit_prony(t, np.exp(-t) + 1.0, max_arms=3)
