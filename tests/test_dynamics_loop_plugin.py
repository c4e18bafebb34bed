"""A user-written dynamics plugin effect is found by diagnose and fitted to the noise level (issue 12 item 7).

The plugin is written as a user would: a file registering an effect of kind ``progression``. On today's
engine a dynamics plugin is a drive transform (``register_effect(..., role="drive")``,
``apply(f_Hz, Pd_N, duty, p) -> (f_Hz, Pd_N, duty)``, issue 9 item 4, first sort): here a drive coil that saturates, so the force on the magnet grows less than the set
amplitude, P_d,eff = P_d (1 - s P_d / 0.3 N).
"""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from capsule_cli.effects import registry
from capsule_cli.effects.model import build_model
from capsule_cli.steps import dynamics_loop as DL

from test_dynamics_loop import BUDGET, DESIGN, NOISE, PROTO

# minutes of engine time on the opened engine: run by `make test-slow`, not by CI's `make test`
pytestmark = pytest.mark.slow

PLUGIN = '''
from capsule_cli.effects import Param, register_effect



@register_effect(
    name="coil_saturation", kind="progression", role="drive", covariates=("Pd_N",),
    params=(Param("saturation", start=0.2, bounds=(0.0, 0.9), off=0.0,
                  description="relative loss of drive force at a set amplitude of 0.3 N"),),
    description="The drive coil saturates: the force on the magnet is P_d (1 - s P_d / 0.3 N).",
    source="test: a user's plugin")
def coil_saturation(f_Hz, Pd_N, duty, p):
    return f_Hz, Pd_N * (1.0 - p["saturation"] * Pd_N / 0.3), duty
'''


@pytest.fixture
def plugin(tmp_path):
    path = tmp_path / "coil.py"
    path.write_text(PLUGIN)
    registry.load_plugins([path], entry_points=False)
    yield path
    registry.unregister_effect("progression", "coil_saturation")  # keep other tests' candidates unchanged
    registry._LOADED_PLUGINS.discard(str(path.resolve()))


def _model(tmp_path, name, effects, params):
    doc = {"kind": "progression", "base": "one_sided", "effects": effects, "params": params, "protocol": PROTO}
    (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(doc))
    return build_model(tmp_path / f"{name}.yaml")


def test_plugin_effect_is_found_through_its_covariate_and_fitted_to_noise(tmp_path, plugin):
    truth = _model(tmp_path, "truth", ["coil_saturation"], {"Pf_N": 0.02, "saturation": 0.45})
    base = _model(tmp_path, "base", [], {"Pf_N": {"value": 0.03, "free": True, "bounds": [0.001, 0.2]}})
    df = DL.synthesize_progression(truth, DESIGN, NOISE, 2, 5)
    path = tmp_path / "coil_synthetic.csv"
    df.to_csv(path, index=False)
    r = DL.run_diagnose(base, df, str(path), tmp_path / "diag", k_folds=3, seed=5, figures=False, budget=BUDGET)
    v = r["verdict"]
    assert v["missing_effect"] == "coil_saturation", v["message"]
    assert v["covariate"] == "Pd_N"
    win = next(c for c in r["candidates"] if c["effect"] == "coil_saturation")
    assert win["origin"].startswith("plugin")
    assert win["cv_rmse_not_irregular"] <= 1.2 * NOISE
    assert abs(win["params"]["saturation"]["value"] - 0.45) < 0.1
