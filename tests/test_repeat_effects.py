"""An effect a model may hold more than once (issue 10 item 4): a third Maxwell arm.

``maxwell_arm`` is repeatable: ``maxwell_arm_2`` is a second instance with its own parameters
(``arm_E_2_kPa``, ``arm_eta_2_MPa_s``), usable in model files and offered by ``diagnose`` when the model
already holds one arm. Data come from capsule-cli synth's engine (three relaxation times: the base arm
27.3 s of seed 003 Table 1, and arms of 2 s and 8 s).
"""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from capsule_cli.effects.model import build_model
from capsule_cli.effects.registry import effect_instance, get_effect
from capsule_cli.errors import InputError
from capsule_cli.steps.compare import run_compare
from capsule_cli.steps.diagnose import run_diagnose
from capsule_cli.steps.synth import synthesize
from capsule_cli.tables import read_measurements

from test_diagnose import MAXWELL, RTIME, loop, mk

THREE_ARMS = {"kind": "relaxation", "base": "maxwell", "effects": ["maxwell_arm", "maxwell_arm_2"],
              "params": {"arm_E_kPa": 300.0, "arm_eta_MPa_s": 0.6,  # tau = 2 s
                         "arm_E_2_kPa": 200.0, "arm_eta_2_MPa_s": 1.6}}  # tau = 8 s


def test_second_instance_has_its_own_parameters_and_the_same_physics():
    arm = get_effect("relaxation", "maxwell_arm")
    arm2 = get_effect("relaxation", "maxwell_arm_2")
    assert arm2 is effect_instance(arm, 2) and arm2.name == "maxwell_arm_2"
    assert [p.name for p in arm2.params] == ["arm_E_2_kPa", "arm_eta_2_MPa_s"]
    assert [p.bounds for p in arm2.params] == [p.bounds for p in arm.params]
    # two arms of the same values add up to one arm of twice the modulus at the same time constant
    design = pd.DataFrame(RTIME)
    two = synthesize(mk({"kind": "relaxation", "base": "maxwell", "effects": ["maxwell_arm", "maxwell_arm_2"],
                         "params": {"arm_E_kPa": 150.0, "arm_eta_MPa_s": 0.3, "arm_E_2_kPa": 150.0,
                                    "arm_eta_2_MPa_s": 0.3}}), design, 0.0, 0.0, 1, 0)
    one = synthesize(mk({"kind": "relaxation", "base": "maxwell", "effects": ["maxwell_arm"],
                         "params": {"arm_E_kPa": 300.0, "arm_eta_MPa_s": 0.6}}), design, 0.0, 0.0, 1, 0)
    np.testing.assert_allclose(two["pressure_kPa"], one["pressure_kPa"], rtol=1e-12)


def test_non_repeatable_effects_stay_single():
    with pytest.raises(InputError, match="cannot be added more than once"):
        mk({"kind": "friction", "base": "coulomb", "effects": ["viscous", "viscous_2"], "params": {}})
    with pytest.raises(InputError, match="listed twice"):
        mk({"kind": "relaxation", "base": "maxwell", "effects": ["maxwell_arm", "maxwell_arm"], "params": {}})


def test_third_arm_step_by_step_until_the_error_falls_to_noise(tmp_path):
    sd = 0.05  # kPa
    r, met = loop(tmp_path, THREE_ARMS, MAXWELL, RTIME, sd, 1)
    assert r["verdict"]["missing_effect"] == "maxwell_arm", r["verdict"]["message"]
    assert met["cv_rmse"] > 1.2 * sd  # one arm added: two relaxation times still leave an error above the noise
    data = tmp_path / "d_synthetic.csv"
    d, k = read_measurements(data)
    m1 = build_model(tmp_path / "new.yaml")
    assert m1.effect_names == ["maxwell_arm"]
    r2 = run_diagnose(m1, d, k, str(data), tmp_path / "d2", tmp_path / "new2.yaml", figures=False)
    assert r2["verdict"]["missing_effect"] == "maxwell_arm_2", r2["verdict"]["message"]
    assert "maxwell_arm_2" in [c["effect"] for c in r2["candidates"]]
    m2 = build_model(tmp_path / "new2.yaml")
    assert m2.effect_names == ["maxwell_arm", "maxwell_arm_2"]
    assert {"arm_E_kPa", "arm_E_2_kPa", "arm_eta_2_MPa_s"} <= {s.key for s in m2.specs if s.free}
    met2 = run_compare(m2, d, k, str(data), tmp_path / "cmp2", None, figures=False)
    # the error falls to the noise: in sample as low as the true three-arm model's on these data, held out
    # within 1.4 x the noise SD (7 free parameters on 59 points of three exponentials: over seeds 0-3 the
    # held-out RMSE was 0.96-1.37 x the noise SD, the in-sample RMSE 0.96-0.99 x the truth's)
    truth = synthesize(mk(THREE_ARMS), pd.DataFrame(RTIME), 0.0, 0.0, 1, 0)["pressure_kPa"].to_numpy()
    rmse_truth = float(np.sqrt(np.mean((d["pressure_kPa"].to_numpy() - truth) ** 2)))
    assert met2["rmse"] <= 1.05 * rmse_truth, (met2["rmse"], rmse_truth)
    assert met2["cv_rmse"] <= 1.4 * sd and met2["cv_rmse"] < met["cv_rmse"], (met2["cv_rmse"], met["cv_rmse"])
    # the three arms find the fast time constant (2 s) and two well apart above it (three exponentials
    # 2, 8 and 27 s apart trade the slower two against each other at this noise). Which arm holds which
    # time constant is a labelling the data cannot fix: the base arm took the 2 s one on one machine and
    # the 27 s one on another, with the same error; only the set of the three is compared.
    vals = {s.key: s.value for s in m2.specs}
    taus = sorted([vals[f"arm_eta{s}_MPa_s"] / vals[f"arm_E{s}_kPa"] * 1e3 for s in ("", "_2")]
                  + [vals["eta1_MPa_s"] / vals["E1_kPa"] * 1e3])
    assert taus[0] == pytest.approx(2.0, rel=0.15), taus
    assert 2 * taus[0] < taus[1] < taus[2], taus
