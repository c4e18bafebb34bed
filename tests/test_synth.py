"""capsule-cli synth: the model at the design's covariates plus stated noise, labelled synthetic."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from capsule_cli.cli import main
from capsule_cli.tables import read_measurements, read_provenance


def test_synth_csv_with_sidecar_and_true_model(tmp_path, capsys):
    out = tmp_path / "case1_synthetic.csv"
    assert main(["synth", "--model", "configs/models/friction_coulomb_eq17_truth.yaml", "--noise-sd", "1.5",
                 "--replicates", "3", "--seed", "4", "--out", str(out), "--quiet"]) == 0
    df, kind = read_measurements(out)
    assert kind == "friction" and len(df) == 36 and sorted(df["trial"].unique()) == [1, 2, 3]
    prov = json.loads((tmp_path / "case1_synthetic.csv.provenance.json").read_text())
    assert prov["synthetic"] is True and prov["seed"] == 4 and prov["noise_sd"] == 1.5
    assert prov["true_model"]["effects"] == ["speed_power_law"] and prov["true_model_hash"]
    assert "warning" not in capsys.readouterr().err
    # noise: within-speed SD close to the stated 1.5 mN (36 points, 24 dof: +-35 %)
    sd = df.groupby("speed_mm_s")["friction_mN"].std(ddof=1)
    assert np.sqrt((sd ** 2).mean()) == pytest.approx(1.5, rel=0.35)


def test_synth_noise_free_parquet_is_the_model(tmp_path, capsys):
    out = tmp_path / "plain.parquet"
    assert main(["synth", "--model", "configs/models/coulomb.yaml", "--noise-sd", "0", "--out", str(out)]) == 0
    assert "does not say 'synthetic'" in capsys.readouterr().err
    df, _ = read_measurements(out)
    assert df["friction_mN"].to_numpy() == pytest.approx(7.788, abs=0.005)  # seed 000 eq 1
    assert read_provenance(out)["synthetic"] is True


def test_synth_design_missing_a_covariate_exits_2(tmp_path, capsys):
    design = tmp_path / "d.csv"
    pd.DataFrame({"speed_mm_s": [1.0, 2.0]}).to_csv(design, index=False)
    model = tmp_path / "m.yaml"
    model.write_text("kind: friction\nbase: coulomb\neffects: [circular_folds]\n")
    assert main(["synth", "--model", str(model), "--design", str(design), "--noise-sd", "1",
                 "--out", str(tmp_path / "x_synthetic.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "position_mm" in err and "circular_folds" in err
    assert not (tmp_path / "x_synthetic.csv").exists()
