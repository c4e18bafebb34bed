"""capsule-cli compare: calibration with intervals, grouped held-out error, noise estimate, ledger row."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from capsule_cli.cli import main
from capsule_cli.steps.crossval import assign_folds, cv_groups
from capsule_cli.tables import read_table


def test_compare_metrics_residuals_and_ledger(tmp_path):
    data = tmp_path / "d_synthetic.csv"
    assert main(["synth", "--model", "configs/models/coulomb.yaml", "--noise-sd", "1.0", "--replicates", "4",
                 "--seed", "2", "--out", str(data), "--quiet"]) == 0
    ledger = tmp_path / "ledger.parquet"
    for _ in range(2):
        assert main(["compare", "--model", "configs/models/coulomb.yaml", "--data", str(data), "--out",
                     str(tmp_path / "c"), "--ledger", str(ledger), "--quiet"]) == 0
    met = json.loads((tmp_path / "c" / "metrics.json").read_text())
    for key in ("n", "rmse", "mae", "bias", "r2", "cv_rmse", "cv_rmse_se", "noise_sd", "noise_method", "params",
                "model_hash", "effects", "data_hash"):
        assert key in met
    # the data are Coulomb with mu = 0.2293 (seed 000): the 95 % interval holds it, errors at the noise level
    mu = met["params"]["mu"]
    assert mu["ci95"][0] < 0.2293 < mu["ci95"][1]
    assert met["noise_method"].startswith("replicates") and met["noise_sd"] == pytest.approx(1.0, rel=0.3)
    assert met["cv_rmse"] == pytest.approx(1.0, rel=0.3)
    res = read_table(tmp_path / "c" / "residuals.parquet")
    assert res.groupby("trial")["fold"].nunique().max() == 1  # a trial never split across folds
    led = read_table(ledger)
    assert len(led) == 2 and set(led["model"]) == {"coulomb"}
    assert (tmp_path / "c" / "fit.png").stat().st_size > 1000
    assert main(["ledger", "plot", "--ledger", str(ledger), "--out", str(tmp_path / "l.png")]) == 0


def test_groups_keep_identical_covariates_together():
    df = pd.DataFrame({"speed_mm_s": [1, 1, 2, 2, 3, 3, 4, 4, 5, 5.0], "friction_mN": np.arange(10.0)})
    g, how = cv_groups(df, "friction_mN")
    folds = assign_folds(g, 5, 0)
    assert how == "by identical covariate values"
    for s in df["speed_mm_s"].unique():
        assert len(set(folds[df["speed_mm_s"] == s])) == 1


@pytest.mark.parametrize("content, what", [
    ("speed_mm_s,friction_mN\n1,abc\n", "non-numeric"),
    ("speed_mm_s,friction_mN\n-1,3\n", "negative speed"),
    ("speed_mm_s\n1\n", "missing column 'friction_mN'"),
    ("speed_mm_s,friction_mN,temp_X\n1,3,4\n", "unknown unit suffix"),
])
def test_bad_tables_exit_2_with_one_line(tmp_path, capsys, content, what):
    data = tmp_path / "bad.csv"
    data.write_text(content)
    assert main(["compare", "--model", "configs/models/coulomb.yaml", "--data", str(data), "--out",
                 str(tmp_path / "c"), "--ledger", str(tmp_path / "l.parquet")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.csv" in err and what in err
    assert not (tmp_path / "c" / "metrics.json").exists() and not (tmp_path / "l.parquet").exists()
