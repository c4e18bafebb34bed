"""A user's effect in a plugin file behaves like a built-in one: listed, synthesised, fitted, found.

Before the plugin is loaded, diagnose names the covariate (and, for position, the period); after,
the plugin effect is named and brings the held-out error to the noise level.
"""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from capsule_cli.cli import main
from capsule_cli.effects import registry
from capsule_cli.effects.model import build_model
from capsule_cli.steps.compare import run_compare
from capsule_cli.steps.diagnose import run_diagnose
from capsule_cli.steps.synth import synthesize
from capsule_cli.tables import provenance, read_measurements, write_measurements
from test_diagnose import COULOMB_FREE, SP, grid, mk

THERMAL = '''
from capsule_cli.effects import Param, register_effect

@register_effect(name="thermal_softening", kind="friction", covariates=("temperature_C",),
                 params=(Param("thermal_slope_mN", 0.5, (-20.0, 20.0), 0.0, description="mN per degree C"),),
                 description="friction changes linearly with tissue temperature", source="test")
def thermal_softening(y, x, p, ctx):
    return y + p["thermal_slope"] * (x["temperature"] - 37.0)
'''
# a smooth sinusoid along the intestine: not circular_folds' form (localised peaks)
WAVE = '''
import numpy as np
from capsule_cli.effects import Param, register_effect

@register_effect(name="peristaltic_wave", kind="friction", covariates=("position_mm",),
                 params=(Param("wave_amplitude_mN", 2.0, (0.0, 100.0), 0.0),
                         Param("wave_period_mm", 35.0, (5.0, 200.0), 35.0),
                         Param("wave_phase", 0.0, (-7.0, 7.0), 0.0)),
                 description="sinusoidal modulation along the intestine", source="test")
def peristaltic_wave(y, x, p, ctx):
    return y + p["wave_amplitude"] * np.sin(2 * np.pi * x["position"] / p["wave_period"] + p["wave_phase"])
'''


@pytest.fixture
def clean_registry():
    registry._ensure_builtins()  # else an empty registry is saved and restored (built-ins lost for later tests)
    saved, loaded = dict(registry._EFFECTS), set(registry._LOADED_PLUGINS)
    yield
    registry._EFFECTS.clear()
    registry._EFFECTS.update(saved)
    registry._LOADED_PLUGINS.clear()
    registry._LOADED_PLUGINS.update(loaded)


def _plugin_loop(tmp_path, source, truth_params, design, sd, name):
    plug = tmp_path / f"{name}.py"
    plug.write_text(source)
    registry.load_plugins([plug])
    truth = {"kind": "friction", "base": "coulomb", "effects": [name], "params": {"mu": 0.2293, "mass_g": 3.462,
                                                                               **truth_params}}
    df = synthesize(mk(truth), pd.DataFrame(design), sd, 0.0, 1, 3)
    p = tmp_path / "d_synthetic.csv"
    write_measurements(df, p, provenance(synthetic=True))
    d, k = read_measurements(p)
    eff = registry._EFFECTS.pop(("friction", name))  # as before the plugin is loaded
    before = run_diagnose(mk(COULOMB_FREE), d, k, str(p), tmp_path / "d0", None, figures=False)
    registry._EFFECTS[("friction", name)] = eff
    after = run_diagnose(mk(COULOMB_FREE), d, k, str(p), tmp_path / "d1", tmp_path / "new.yaml", figures=False)
    met = run_compare(build_model(tmp_path / "new.yaml"), d, k, str(p), tmp_path / "c1", None, figures=False)
    return before, after, met


def test_temperature_plugin_found(tmp_path, clean_registry):
    design = grid(speed_mm_s=SP, temperature_C=[30, 33, 36, 39, 42])
    design = {k: v * 2 for k, v in design.items()}  # two passes over the grid (no trial column)
    before, after, met = _plugin_loop(tmp_path, THERMAL, {"thermal_slope_mN": 0.8}, design, 1.0, "thermal_softening")
    assert before["verdict"]["missing_effect"] is None
    assert before["verdict"]["covariate"] == "temperature_C"
    assert "write a plugin" in before["verdict"]["message"]
    assert after["verdict"]["missing_effect"] == "thermal_softening"
    assert met["cv_rmse"] <= 1.2 * 1.0
    assert met["params"]["thermal_slope_mN"]["ci95"][0] < 0.8 < met["params"]["thermal_slope_mN"]["ci95"][1]


def test_periodic_plugin_period_named_before_and_found_after(tmp_path, clean_registry):
    design = grid(speed_mm_s=[2, 8], position_mm=list(np.arange(0, 200, 2.0)))
    before, after, met = _plugin_loop(tmp_path, WAVE, {"wave_amplitude_mN": 3.0, "wave_period_mm": 37.0,
                                                      "wave_phase": 0.5}, design, 1.0, "peristaltic_wave")
    v = before["verdict"]
    assert v["missing_effect"] is None and v["covariate"] == "position_mm"
    assert v["period"] == pytest.approx(37.0, rel=0.05) and v["period_unit"] == "mm"
    assert after["verdict"]["missing_effect"] == "peristaltic_wave"
    assert met["cv_rmse"] <= 1.2 * 1.0


def test_plugin_is_listed_by_effects_list(tmp_path, capsys, clean_registry):
    plug = tmp_path / "thermal.py"
    plug.write_text(THERMAL)
    assert main(["effects", "list", "--kind", "friction", "--plugins", str(plug), "--json"]) == 0
    items = json.loads(capsys.readouterr().out)
    eff = {e["name"]: e for e in items["effects"]}["thermal_softening"]
    assert eff["covariates"] == ["temperature_C"] and eff["origin"] == "plugin thermal.py"
    assert eff["params"][0]["name"] == "thermal_slope_mN" and eff["params"][0]["unit"] == "mN"


def test_an_effect_declares_the_effects_it_contains_and_effects_list_says_so(tmp_path, capsys, clean_registry):
    plug = tmp_path / "law.py"
    plug.write_text("from capsule_cli.effects import Param, register_effect\n"
                    "register_effect(name='my_law', kind='friction', covariates=('speed_mm_s',), nests=(('viscous', "
                    "'m = 1'),),\n params=(Param('m', 1.0, (0.1, 3.0), 1.0), Param('g_mN', 1.0, (0.0, 9.0), 0.0)))"
                    "(lambda y, x, p, c: y + p['g'] * x['speed'] ** p['m'])\n")
    assert main(["effects", "list", "--kind", "friction", "--plugins", str(plug), "--json"]) == 0
    eff = {e["name"]: e for e in json.loads(capsys.readouterr().out)["effects"]}
    assert eff["my_law"]["nests"] == [{"effect": "viscous", "at": "m = 1"}]
    assert eff["speed_power_law"]["nests"] == [{"effect": "viscous", "at": "n = 1, c = a"}]
    assert eff["viscous"]["nests"] == []
    assert registry.get_effect("trajectory", "speed_dependent_friction").nests == (("viscous_drag", "n = 1, c_v = a"),)
    assert main(["effects", "list", "--kind", "friction", "--plugins", str(plug)]) == 0
    assert "contains viscous at m = 1;" in capsys.readouterr().out


@pytest.mark.parametrize("src, what", [
    ("def broken(:\n", "syntax error"),
    ("from capsule_cli.effects import Param, register_effect\n"
     "register_effect(name='x', kind='friction', params=(Param('k_mN', 1.0, (0, 2)),))(lambda y, x, p, c: y)\n",
     "needs an 'off' value"),
    ("from capsule_cli.effects import register_effect\n"
     "register_effect(name='y', kind='frictionx')(lambda y, x, p, c: y)\n", "unknown kind"),
    ("x = 1\n", "registers no effect"),
    ("from capsule_cli.effects import Param, register_effect\n"
     "register_effect(name='z', kind='friction', nests=(('viscous',),))(lambda y, x, p, c: y)\n",
     "nests must be pairs"),
    ("from capsule_cli.effects import Param, register_effect\n"  # a setting of a parameter it does not have
     "register_effect(name='v', kind='friction', params=(Param('m', 1.0, (0.1, 3.0), 1.0),), nests=(('viscous', "
     "'m = 1'),), nest_starts={'viscous': {'q': 1.0}})(lambda y, x, p, c: y)\n", "nest_starts must map"),
    ("from capsule_cli.effects import Param, register_effect\n"  # a start for an effect it does not nest
     "register_effect(name='u', kind='friction', params=(Param('m', 1.0, (0.1, 3.0), 1.0),), "
     "nest_starts={'viscous': {'m': 1.0}})(lambda y, x, p, c: y)\n", "nest_starts must map"),
    ("from capsule_cli.effects import register_effect\n"  # diagnose's friction probes only
     "register_effect(name='w', kind='progression', role='friction')(lambda x, p: 1.0)\n", "unknown role"),
])
def test_bad_plugin_exits_2_with_one_line(tmp_path, capsys, clean_registry, src, what):
    plug = tmp_path / "bad.py"
    plug.write_text(src)
    assert main(["effects", "list", "--plugins", str(plug)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.py" in err and what in err
