"""A user-written plugin FORCE is found by diagnose and fitted to the noise level (issue 9 item 4 with
issue 12 item 7's example): a magnetic attraction between magnet and shell that grows as they approach,
hidden in synthetic progression data.

The plugin is written as a user would (a file registering a ``progression`` effect with ``role="force"``).
Every mode with a plugin force goes through the engine's adaptive segment, so this runs minutes: it is run
by ``make test-slow``, not by CI's ``make test``.
"""
from __future__ import annotations

import pytest

from capsule_cli.effects import registry
from capsule_cli.steps import dynamics_loop as DL

from test_dynamics_loop import BUDGET, DESIGN, NOISE
from test_dynamics_loop_plugin import _model

pytestmark = pytest.mark.slow

PLUGIN = '''
import math
from capsule_cli.effects import Param, register_effect


@register_effect(
    name="magnet_attraction", kind="progression", role="force",
    params=(Param("attraction_mN", start=5.0, bounds=(0.0, 60.0), off=0.0,
                  description="attraction between magnet and shell at the forward gap"),),
    description="Magnet and shell attract, more as they approach: F = A exp(-(G_1 - x_r) / 0.3 mm).",
    source="test: a user's plugin")
def magnet_attraction(t, x_m, v_m, x_c, v_c, p):
    F = p[0] * math.exp(-(1.6e-3 - (x_m - x_c)) / 0.3e-3)
    return F, -F
'''


@pytest.fixture
def plugin(tmp_path):
    path = tmp_path / "magnet.py"
    path.write_text(PLUGIN)
    registry.load_plugins([path], entry_points=False)
    yield path
    registry.unregister_effect("progression", "magnet_attraction")  # keep other tests' candidates unchanged
    registry._LOADED_PLUGINS.discard(str(path.resolve()))


def test_plugin_force_is_found_and_fitted_to_noise(tmp_path, plugin):
    truth = _model(tmp_path, "truth", ["magnet_attraction"], {"Pf_N": 0.02, "attraction_mN": 30.0})
    base = _model(tmp_path, "base", [], {"Pf_N": {"value": 0.03, "free": True, "bounds": [0.001, 0.2]}})
    df = DL.synthesize_progression(truth, DESIGN, NOISE, 2, 5)
    path = tmp_path / "magnet_synthetic.csv"
    df.to_csv(path, index=False)
    r = DL.run_diagnose(base, df, str(path), tmp_path / "diag", k_folds=3, seed=5, figures=False, budget=BUDGET)
    v = r["verdict"]
    assert v["missing_effect"] == "magnet_attraction", v["message"]
    win = next(c for c in r["candidates"] if c["effect"] == "magnet_attraction")
    assert win["origin"].startswith("plugin")
    # held-out error over all rows at the noise level (measured 0.52 mm/s against NOISE = 0.5, the base
    # model 1.07); over the regular (period <= 8) rows alone it is 0.74 mm/s on this small design: one
    # one-impact condition (34 Hz, 0.25 N) stays 1 mm/s off at the fitted 33 mN, so that subset is not asserted
    assert win["cv_rmse"] <= 1.2 * NOISE
    assert win["cv_rmse"] < 0.6 * next(c for c in r["candidates"] if c["effect"] == "viscous_drag")["cv_rmse"]
    assert abs(win["params"]["attraction_mN"]["value"] - 30.0) < 8.0
