"""Configs: every file in configs/ validates; unknown keys are errors with one clear line."""
from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from capsule_cli import config
from capsule_cli.errors import InputError
from capsule_cli.units import to_si

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


@pytest.mark.parametrize("path", sorted((CONFIGS / "params").glob("*.yaml")), ids=lambda p: p.name)
def test_every_parameter_set_validates_and_cites_each_value(path):
    ps = config.load_param_set_file(path)
    assert ps.params, f"{path.name} has no parameters"
    for name, entry in ps.params.items():
        assert len(entry.source) >= 5, f"{path.name}:{name} lacks a citation"


@pytest.mark.parametrize("path", [CONFIGS / "study.yaml", CONFIGS / "smoke.yaml"], ids=lambda p: p.name)
def test_study_configs_validate(path):
    cfg = config.load_study_config(path)
    assert cfg.results_dir


@pytest.mark.parametrize("path", sorted((CONFIGS / "models").glob("*.yaml")) if (CONFIGS / "models").exists() else [],
                         ids=lambda p: p.name)
def test_every_model_file_validates(path):
    assert config.load_model_file(path).kind


@pytest.mark.parametrize("path", sorted((CONFIGS / "reference").glob("*.csv")) if (CONFIGS / "reference").exists() else [],
                         ids=lambda p: p.name)
def test_reference_tables_cite_every_row(path):
    df = pd.read_csv(path, comment="#")
    assert "source" in df.columns, f"{path.name} has no 'source' column"
    assert df["source"].notna().all() and (df["source"].astype(str).str.len() > 5).all()


def _all_fields(model, prefix=""):
    for name, field in model.model_fields.items():
        yield prefix + name, field
        ann = field.annotation
        if isinstance(ann, type) and issubclass(ann, config.Strict):
            yield from _all_fields(ann, prefix + name + ".")


def test_every_study_config_field_is_described():
    """Schema meta-test (style.md section 4): an undocumented field fails."""
    missing = [n for n, f in _all_fields(config.StudyConfig) if not (f.description or "").strip()]
    assert not missing, f"fields without description: {missing}"


def test_misspelt_key_is_one_line_error_naming_file_and_suggestion(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nresult_dir: out\n")
    with pytest.raises(InputError) as exc:
        config.load_study_config(bad)
    msg = str(exc.value)
    assert "\n" not in msg
    assert "bad.yaml" in msg and "result_dir" in msg and "results_dir" in msg


def test_misspelt_key_in_parameter_entry_is_rejected(tmp_path):
    bad = tmp_path / "p.yaml"
    bad.write_text("title: t\nsource: s\nparams:\n  Rc_mm: {value: 5.5, sorce: seed 003}\n")
    with pytest.raises(InputError, match="sorce"):
        config.load_param_set_file(bad)


def test_duplicate_yaml_key_is_rejected(tmp_path):
    bad = tmp_path / "d.yaml"
    bad.write_text("name: a\nname: b\n")
    with pytest.raises(InputError, match="duplicate key 'name'"):
        config.read_yaml(bad)


def test_contract_model_file_examples_are_accepted(tmp_path):
    """contract.md section 4: both examples must be accepted as written."""
    a = tmp_path / "coulomb.yaml"
    a.write_text(
        "kind: friction            # one of the measurement kinds\n"
        "base: coulomb             # the base model of that kind\n"
        "effects: []               # names from `capsule-cli effects list`, applied in order\n"
        "params:                   # a number is fixed; a mapping may free it for calibration\n"
        "  mu: {value: 0.2293, free: true, bounds: [0.0, 1.0]}\n"
        "  mass_g: 3.462\n")
    m = config.load_model_file(a)
    assert m.params["mu"].free and m.params["mass_g"] == pytest.approx(3.462)
    b = tmp_path / "dyn.yaml"
    b.write_text("kind: progression\nbase: one_sided\neffects: []\nparams:\n"
                 "  Pf_N: {value: 0.0078, free: true, bounds: [0.0, 0.5]}\n")
    assert config.load_model_file(b).base == "one_sided"


def test_parameter_sets_convert_to_si():
    si = config.load_param_set_si("capsule_intestine")
    # seed 003 Table 1: R_c = 5.50 mm, E_1 = 196.43 kPa, eta_1 = 5.36 MPa s
    assert si["Rc"] == pytest.approx(5.5e-3)
    assert si["E1"] == pytest.approx(196.43e3)
    assert si["eta1"] == pytest.approx(5.36e6)
    # relaxation time eta_1 / E_1 = 27.3 s (physics.md section 1)
    assert si["eta1"] / si["E1"] == pytest.approx(27.3, abs=0.05)
    assert to_si(0.062, "N_mm") == pytest.approx(62.0)
