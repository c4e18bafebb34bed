"""``capsule-cli friction``: fit, predict, hoop, figures; bad input exits 2 with one line, writing nothing."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from capsule_cli.cli import main
from capsule_cli.steps.friction import read_friction_reference
from capsule_cli.tables import read_provenance, read_table

REPO = Path(__file__).resolve().parents[1]
MODELS = REPO / "configs" / "models"
REFERENCE = REPO / "configs" / "reference" / "friction_seed000.csv"


def _table(tmp_path, name="pull.csv", sd=1.0, seed=0):
    V = np.repeat([0.2, 0.5, 1, 2, 4, 6, 8, 10, 12.0], 2)
    F = 8.778 * V ** 0.25 + 2.518 + np.random.default_rng(seed).normal(0, sd, V.size)
    p = tmp_path / name
    pd.DataFrame({"speed_mm_s": V, "friction_mN": F, "trial": np.tile([1, 2], V.size // 2)}).to_csv(p, index=False)
    return p


def test_fit_writes_fit_band_residuals_and_figure(tmp_path, cli):
    data = _table(tmp_path)
    out = tmp_path / "fit"
    r = cli("friction", "fit", "--data", data, "--law", "power_fixed_n", "--n-fixed", "0.25", "--groups", "trial",
            "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr
    fit = json.loads((out / "fit.json").read_text())
    assert fit["law"] == "power_fixed_n" and fit["n"] == 18
    a = fit["params"]["a_mN"]
    assert a["ci95"][0] < a["value"] < a["ci95"][1]
    assert a["value"] == pytest.approx(8.778, abs=2.0)
    assert {"r2", "aic", "bic", "sigma_mN"} <= set(fit)
    band = read_table(out / "band.parquet")
    assert {"speed_mm_s", "friction_mN", "ci_low_mN", "ci_high_mN"} <= set(band.columns)
    res = read_table(out / "residuals.parquet")
    assert len(res) == 18 and "group" in res.columns
    assert read_provenance(out / "band.parquet")["version"]
    assert (out / "fit.png").stat().st_size > 5000


@pytest.mark.parametrize("content, what", [
    ("speed_mm_s,friction_mN\n1,3\n2,abc\n3,5\n4,6\n", "non-numeric"),
    ("speed_mm_s,friction_mN\n1,3\n-2,4\n3,5\n4,6\n", "negative speed"),
    ("speed_mm_s,force_mN\n1,3\n2,4\n3,5\n4,6\n", "friction_mN"),
    ("speed_mm_s,friction_mN\n", "empty"),
    ("", "empty"),
    ("speed_mm_s,friction_mN\n1,3\n2,\n3,5\n4,6\n", "NaN"),
])
def test_bad_tables_exit_2_with_one_line_and_write_nothing(tmp_path, capsys, content, what):
    bad = tmp_path / "bad.csv"
    bad.write_text(content)
    out = tmp_path / "out"
    code = main(["friction", "fit", "--data", str(bad), "--law", "power", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and what in err and "bad.csv" in err, err
    assert not out.exists()


def test_bad_table_exits_2_through_the_console_script(tmp_path, cli):
    bad = tmp_path / "bad.csv"
    bad.write_text("speed_mm_s,friction_mN\n1,3\n-0.4,4\n")
    r = cli("friction", "predict", "--model", MODELS / "coulomb.yaml", "--data", bad, "--out", tmp_path / "p.parquet")
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "row 2" in r.stderr and "negative speed" in r.stderr
    assert not (tmp_path / "p.parquet").exists()


def test_predict_contract_coulomb_example_gives_7p79_mN(tmp_path, cli):
    # contract section 4's example model file (configs/models/coulomb.yaml); seed 000 eq 1: 7.79 mN
    out = tmp_path / "coulomb.parquet"
    r = cli("friction", "predict", "--model", MODELS / "coulomb.yaml", "--speeds-mm-s", "0:12:5", "--out", out,
            "--quiet")
    assert r.returncode == 0, r.stderr
    df = read_table(out)
    assert df["speed_mm_s"].tolist() == [0, 3, 6, 9, 12]
    assert np.allclose(df["friction_mN"], 7.79, atol=0.005)


def test_predict_eq17_eq18_and_hoop_model_files(capsys, tmp_path):
    out = tmp_path / "p.csv"
    assert main(["friction", "predict", "--model", str(MODELS / "friction_seed000_eq17.yaml"),
                 "--speeds-mm-s", "1,16", "--out", str(out), "--quiet"]) == 0
    assert pd.read_csv(out)["friction_mN"].tolist() == pytest.approx([8.778 + 2.518, 2 * 8.778 + 2.518], rel=1e-8)
    assert main(["friction", "predict", "--model", str(MODELS / "friction_seed000_eq18.yaml"),
                 "--speeds-mm-s", "16", "--out", str(out), "--quiet"]) == 0
    assert pd.read_csv(out)["friction_mN"].iloc[0] == pytest.approx(2 * 1539 + 1383, rel=1e-8)
    # eq 16 through the hoop_pressure effect: physics.md's 3.45-3.81 N at R_i = 4.4 mm
    assert main(["friction", "predict", "--model", str(MODELS / "friction_case4_hoop.yaml"),
                 "--speeds-mm-s", "0.4,12", "--Ri-mm", "4.4", "--out", str(out), "--quiet"]) == 0
    assert pd.read_csv(out)["friction_mN"].tolist() == pytest.approx([3450, 3810], abs=6)
    # without a radius the hoop effect cannot be evaluated: exit 2, one line
    capsys.readouterr()
    assert main(["friction", "predict", "--model", str(MODELS / "friction_case4_hoop.yaml"),
                 "--speeds-mm-s", "1", "--quiet"]) == 2
    assert "Ri_mm" in capsys.readouterr().err


def test_predict_on_a_table_keeps_the_measured_column(tmp_path):
    data = _table(tmp_path)
    out = tmp_path / "pred.parquet"
    assert main(["friction", "predict", "--model", str(MODELS / "coulomb.yaml"), "--data", str(data),
                 "--out", str(out), "--quiet"]) == 0
    df = read_table(out)
    assert {"measured_friction_mN", "friction_mN", "trial"} <= set(df.columns)


def test_hoop_grid_and_figures(tmp_path):
    hoop = tmp_path / "hoop.parquet"
    assert main(["friction", "hoop", "--Ri-mm", "4.4:5.0:4", "--speeds-mm-s", "0.4,4,12", "--out", str(hoop),
                 "--quiet"]) == 0
    df = read_table(hoop)
    assert len(df) == 12
    row = df[(df["Ri_mm"].round(6) == 5.0) & (df["speed_mm_s"] == 4.0)].iloc[0]
    assert row["hoop_friction_N"] == pytest.approx(1.5, rel=0.06)  # seed 000 FE: about 1.5 N at R_i = 5 mm
    assert row["tail_push_N"] < 0
    curves = {}
    for name, model in (("c", "coulomb.yaml"), ("e17", "friction_seed000_eq17.yaml"),
                        ("e18", "friction_seed000_eq18.yaml")):
        curves[name] = tmp_path / f"{name}.parquet"
        assert main(["friction", "predict", "--model", str(MODELS / model), "--speeds-mm-s", "0:12:13",
                     "--out", str(curves[name]), "--quiet"]) == 0
    fig = tmp_path / "speed.png"
    assert main(["friction", "plot-speed", "--reference", str(REFERENCE), "--hoop", str(hoop), "--coulomb",
                 str(curves["c"]), "--case1-law", str(curves["e17"]), "--case4-law", str(curves["e18"]),
                 "--out", str(fig), "--quiet"]) == 0
    assert fig.stat().st_size > 5000
    fig2 = tmp_path / "radius.png"
    assert main(["friction", "plot-radius", "--hoop", str(hoop), "--reference", str(REFERENCE),
                 "--out", str(fig2), "--quiet"]) == 0
    assert fig2.stat().st_size > 5000
    # a radius that is not in the grid: exit 2, nothing written
    fig3 = tmp_path / "none.png"
    assert main(["friction", "plot-speed", "--reference", str(REFERENCE), "--hoop", str(hoop), "--coulomb",
                 str(curves["c"]), "--case1-law", str(curves["e17"]), "--case4-law", str(curves["e18"]),
                 "--Ri-mm", "4.45", "--out", str(fig3), "--quiet"]) == 2
    assert not fig3.exists()


def test_reference_table_carries_seed000_section4_values_with_citations():
    ref = read_friction_reference(REFERENCE)
    assert ref["source"].str.contains("seed 000").all()
    key = {(str(c), s, round(f, 2)) for c, s, f in zip(ref["case"], ref["statistic"], ref["friction_mN"])}
    for item in [("1", "avg", 19.57), ("1", "avg", 21.45), ("2", "peak", 37.5), ("2", "peak", 88.2),
                 ("2", "avg", 15.6), ("3", "peak", 170.0), ("4", "avg", 3641.87), ("4", "avg", 3973.08),
                 ("4", "min", 2500.0), ("4", "max", 4500.0)]:
        assert item in key, item
    assert set(ref["source_type"]) <= {"experiment", "FE", "analytic", "fit"}
