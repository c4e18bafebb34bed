"""The contact-stage commands: pinned numbers from the paper config, bad input -> one line, exit 2, nothing written."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from capsule_cli import config
from capsule_cli.errors import InputError
from capsule_cli.tables import read_column_units, read_provenance, read_table


def _one_line_exit_2(r):
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "Traceback" not in r.stderr


def test_contact_defaults_reproduce_the_pinned_numbers(cli, tmp_path):
    out = tmp_path / "p.parquet"
    r = cli("contact", "--speed-mm-s", "4,10", "--wall-mode", "attenuated,original", "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr
    df = read_table(out)

    def get(model, stat, v, mode=""):
        sel = df[(df.model == model) & (df.statistic == stat) & np.isclose(df.speed_mm_s, v) & (df.wall_mode == mode)]
        assert len(sel) == 1
        return sel.iloc[0]

    # seed 003 section 2 / 5 (0.4 g capsule): a = 0.2359 mm, P_avg 0.55 kPa, P_max 0.70 kPa
    assert get("hertz", "avg", 4).semi_width_mm == pytest.approx(0.2359, rel=1e-3)
    assert get("hertz", "avg", 4).pressure_kPa == pytest.approx(0.55, abs=0.005)
    assert get("hertz", "max", 4).pressure_kPa == pytest.approx(0.70, abs=0.01)
    # physics.md section 2 (R_i = 5 mm): 10.80 kPa at 4 mm/s, 10.92 kPa at 10 mm/s, 11.88 kPa with t_i
    assert get("hoop", "avg", 4, "attenuated").pressure_kPa == pytest.approx(10.80, abs=0.005)
    assert get("hoop", "avg", 10, "attenuated").pressure_kPa == pytest.approx(10.92, abs=0.005)
    assert get("hoop", "avg", 10, "original").pressure_kPa == pytest.approx(11.88, abs=0.005)
    assert get("hoop", "avg", 10, "attenuated").Ri_mm == 5.0
    assert get("collapsed", "avg", 10).Ri_mm == 13.0
    # the summary on stdout names the numbers too
    assert "10.804" in r.stdout and "0.2360 mm" in r.stdout
    units = read_column_units(out)
    assert units["pressure_kPa"] == "kPa" and units["speed_mm_s"] == "mm/s"
    assert read_provenance(out)["version"]


def test_contact_profile_and_end_shapes(cli, tmp_path):
    out, prof = tmp_path / "e.parquet", tmp_path / "prof.parquet"
    r = cli("contact", "--model", "hoop", "--speeds", "2:10:3", "--end-length-mm", "2.75,5.5,8.25",
            "--out", out, "--profile-out", prof, "--quiet")
    assert r.returncode == 0, r.stderr
    df = read_table(out)
    assert sorted(df.end_length_mm.unique()) == [2.75, 5.5, 8.25]
    assert sorted(df.speed_mm_s.unique()) == [2.0, 6.0, 10.0]
    p = read_table(prof)
    assert set(p.segment) == {"head", "body", "tail"}
    body = p[(p.segment == "body") & (p.speed_mm_s == 10) & (p.end_length_mm == 5.5)]
    assert body.x_body_mm.min() == pytest.approx(0.0, abs=1e-9) and body.x_body_mm.max() == pytest.approx(15.0)


def test_bad_relaxation_table_exits_2_with_one_line_and_writes_nothing(cli, tmp_path):
    bad = tmp_path / "relax.csv"
    bad.write_text("time_s,pressure_kPa\n0,11.0\n1,10.9\n2,abc\n3,10.7\n")
    out = tmp_path / "fit"
    r = cli("relax", "fit", "--data", bad, "--out", out)
    _one_line_exit_2(r)
    assert "relax.csv" in r.stderr and "pressure_kPa" in r.stderr and "row 3" in r.stderr
    assert not out.exists()


def test_relax_fit_writes_fit_curve_residuals_and_figure(cli, tmp_path):
    rng = np.random.default_rng(2)
    t = np.arange(0.0, 120.0, 0.5)
    f = 0.011527  # t_i,e eps / R_c for R_i = 5 mm
    y = f * (196.43 * np.exp(-t / 27.288) + 757.48) + rng.normal(0, 0.05, t.size)  # seed 003 Table 1 [kPa]
    data = tmp_path / "relax.csv"
    table = pd.DataFrame({"trial": np.repeat(["a", "b"], t.size // 2), "time_s": t, "pressure_kPa": y})
    table.to_csv(data, index=False)
    out = tmp_path / "fit"
    r = cli("relax", "fit", "--data", data, "--max-arms", "2", "--Ri-mm", "5", "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr
    rec = json.loads((out / "fit.json").read_text())
    assert rec["chosen_n_arms"] == 1
    assert rec["r2"] > 0.9
    assert {"cv_rmse_kPa", "delta_bic"} <= set(rec["cv_table"][0])
    arm = rec["params"]["arms"][0]
    assert arm["E_kPa"]["ci95"][0] < 196.43 < arm["E_kPa"]["ci95"][1]
    assert (out / "relax_fit.png").stat().st_size > 5000
    curve = read_table(out / "curve.parquet")
    assert set(curve.n_arms) == {1, 2} and curve.chosen.sum() == (curve.n_arms == 1).sum()
    res = read_table(out / "residuals.parquet")
    assert len(res) == t.size and abs(res.residual_kPa.mean()) < 0.02


def test_misspelt_key_in_the_contact_section_of_a_study_config(tmp_path):
    bad = tmp_path / "study.yaml"
    bad.write_text("name: x\ncontact:\n  end_lenghts_mm: [5.5]\n")
    with pytest.raises(InputError) as exc:
        config.load_study_config(bad)
    msg = str(exc.value)
    assert "\n" not in msg and "end_lenghts_mm" in msg and "end_lengths_mm" in msg


def test_misspelt_key_in_a_parameter_file_stops_contact_with_exit_2(cli, tmp_path):
    bad = tmp_path / "params.yaml"
    bad.write_text("title: t\nsource: s\nparams:\n  Rc_mm: {value: 5.5, sorce: seed 003 Table 1}\n")
    out = tmp_path / "t.parquet"
    r = cli("contact", "--params", bad, "--out", out)
    _one_line_exit_2(r)
    assert "sorce" in r.stderr
    assert not out.exists()


@pytest.mark.parametrize("args, text", [
    (["--speed-mm-s", "1,fast"], "'fast' is not a number"),
    (["--speeds", "1:5"], "start:stop:num"),
    (["--speed-mm-s", "-1"], ">= 0"),
    (["--wall-mode", "thin"], "thin"),
    (["--model", "collapsed", "--Ri-mm", "5"], "must exceed"),
])
def test_bad_contact_options_exit_2(cli, tmp_path, args, text):
    out = tmp_path / "t.parquet"
    r = cli("contact", *args, "--out", out)
    _one_line_exit_2(r)
    assert text in r.stderr
    assert not out.exists()


def test_reference_table_and_figure(cli, tmp_path):
    ref = tmp_path / "ref.parquet"
    r = cli("contact-reference", "--out", ref, "--quiet")
    assert r.returncode == 0, r.stderr
    df = read_table(ref)
    assert (df.source.str.len() > 5).all()
    assert set(df.source_type) <= {"experiment", "FE", "analytic", "fit"}
    # seed 003 section 5: Case 2 about 1.85 kPa FE; Case 3 14.38 kPa measured at 13.76 mm/s
    assert ((df.case == "case2") & (df.source_type == "FE") & np.isclose(df.pressure_kPa, 1.85)).any()
    assert ((df.case == "case3") & np.isclose(df.speed_mm_s, 13.76) & np.isclose(df.pressure_kPa, 14.38)).any()
    # a figure from a table that is not a contact_pressure table is bad input
    fig = tmp_path / "f.png"
    r = cli("contact-plot", "speed", "--table", ref, "--out", fig)
    _one_line_exit_2(r)
    assert not fig.exists()
