"""The effects registry: contract names, nested models (off values), units, model-file semantics."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from capsule_cli.config import load_model_file
from capsule_cli.effects import effects
from capsule_cli.effects.model import build_model
from capsule_cli.errors import InputError
from test_diagnose import mk

CONTRACT = {
    "friction": {"speed_power_law", "viscous", "stribeck", "hoop_pressure", "circular_folds",
                 "viscoelastic_relaxation", "wall_weight", "curvature"},
    "pressure": {"wall_weight", "hoop_pressure", "curvature", "coating", "end_shape"},
    "relaxation": {"maxwell_arm"},
}
TABLE = pd.DataFrame({"speed_mm_s": [0.5, 2.0, 8.0, 12.0], "position_mm": [0, 10, 47, 120.0],
                      "time_s": [0, 5, 30, 100.0], "Ri_mm": [4.4, 4.8, 5.0, 13.0],
                      "bend_radius_mm": [10, 25, 100, 400.0]})
BASES = {"friction": "coulomb", "pressure": "hoop", "relaxation": "maxwell"}


@pytest.mark.parametrize("kind", list(CONTRACT))
def test_contract_effect_names_are_registered(kind):
    assert CONTRACT[kind] <= {e.name for e in effects(kind)}


@pytest.mark.parametrize("kind, name", [(k, n) for k, ns in CONTRACT.items() for n in sorted(ns)])
def test_effect_at_its_off_values_reduces_to_the_base(kind, name):
    eff = next(e for e in effects(kind) if e.name == name)
    base = "hertz" if eff.bases == ("hertz",) else BASES[kind]
    off = {p.name: p.off for p in eff.params}
    m0 = mk({"kind": kind, "base": base, "effects": [], "params": {}})
    m1 = mk({"kind": kind, "base": base, "effects": [name], "params": off})
    y0, y1 = m0.bind(TABLE).predict(), m1.bind(TABLE).predict()
    assert np.allclose(y0, y1, rtol=1e-12, atol=0)
    on = mk({"kind": kind, "base": base, "effects": [name], "params": {}}).bind(TABLE).predict()
    assert not np.allclose(on, y0)  # at its start values the effect does something


def test_coulomb_base_gives_seed000_eq1():
    # seed 000 eq 1: mu m g = 0.2293 x 3.462 g x 9.81 = 7.79 mN (paper rounds to 7.8 mN)
    m = build_model("configs/models/coulomb.yaml")
    assert m.bind(TABLE).predict() == pytest.approx(7.788, abs=0.005)


def test_power_law_effect_matches_seed000_eq17():
    # seed 000 eq 17: F = 8.778 V^0.25 + 2.518 mN; with b = mu m g the rise is 8.778 V^0.25
    m = build_model("configs/models/friction_coulomb_eq17_truth.yaml")
    y = m.bind(TABLE).predict()
    assert y == pytest.approx(7.788 + 8.778 * TABLE["speed_mm_s"].to_numpy() ** 0.25, abs=0.005)


def test_hoop_base_matches_seed003_case3():
    # physics.md section 2: 10.92 kPa at 10 mm/s and 10.80 kPa at 4 mm/s for R_i = 5 mm
    m = mk({"kind": "pressure", "base": "hoop", "effects": [], "params": {}})
    y = m.bind(pd.DataFrame({"speed_mm_s": [10.0, 4.0]})).predict()
    assert y == pytest.approx([10.92, 10.80], abs=0.01)


def test_contract_examples_are_accepted_as_written():
    m = build_model("configs/models/coulomb.yaml")
    assert m.spec("mu").free and m.spec("mu").bounds == (0.0, 1.0) and not m.spec("mass_g").free
    mf = load_model_file("configs/models/progression_one_sided.yaml")
    assert mf.kind == "progression" and mf.params["Pf_N"].free


@pytest.mark.parametrize("doc, msg", [
    ({"kind": "friction", "base": "coulomb", "effects": ["speed_powerlaw"]}, "did you mean 'speed_power_law'"),
    ({"kind": "friction", "base": "coulmb"}, "did you mean 'coulomb'"),
    ({"kind": "friction", "base": "coulomb", "params": {"muu": 0.2}}, "params.muu"),
    ({"kind": "friction", "base": "coulomb", "effects": ["coating"]}, "it is a pressure effect"),
    ({"kind": "pressure", "base": "hertz", "effects": ["coating"]}, "applies to base hoop"),
    ({"kind": "friction", "base": "coulomb", "params": {"mu": {"value": 2.0, "free": True, "bounds": [0, 1]}}},
     "outside its bounds"),
])
def test_bad_model_semantics_raise_one_line(doc, msg):
    with pytest.raises(InputError) as e:
        mk(doc)
    assert msg in str(e.value) and "m.yaml" in str(e.value) and "\n" not in str(e.value)


def test_parameters_convert_to_si_by_suffix():
    # viscous c = 1 N s/m gives 1 mN per mm/s
    m = mk({"kind": "friction", "base": "coulomb", "effects": ["viscous"], "params": {"mu": 0.0, "c_Ns_m": 1.0}})
    assert m.bind(pd.DataFrame({"speed_mm_s": [3.0]})).predict() == pytest.approx([3.0])
