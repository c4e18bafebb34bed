"""diagnose on data shaped like real pull tests (issue 10): outliers, correlated sensor noise, collinear
covariates, two effects at once (a partial step), folds of two heights, fits at bounds, the published tables.

Data come from capsule-cli synth's engine; the outlier and correlated-noise cases perturb its table as a
sensor would (stated per test).
"""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from capsule_cli.cli import main
from capsule_cli.effects.model import build_model
from capsule_cli.fitting import fit_least_squares
from capsule_cli.steps.diagnose import diagnose_table, run_diagnose
from capsule_cli.steps.residual_tests import noise_estimate
from capsule_cli.steps.synth import synthesize
from capsule_cli.tables import read_measurements

from test_diagnose import COULOMB_FREE, SP, fr, loop, mk

SP20 = list(np.round(np.geomspace(0.2, 12, 20), 3))


def test_two_outliers_are_flagged_by_row_and_do_not_hide_a_speed_effect():
    truth = fr(["speed_power_law"], a_mN=3.0, n=0.25)
    df = synthesize(mk(truth), pd.DataFrame({"speed_mm_s": SP20}), 1.0, 0.0, 1, 7)
    df.loc[5, "friction_mN"] += 10.0  # two gross errors of the gauge (+10 and -8 noise SDs)
    df.loc[14, "friction_mN"] -= 8.0
    r = diagnose_table(mk(COULOMB_FREE), df, "friction").result
    assert [o["row"] for o in r["outliers"]] == [5, 14]
    assert r["noise"]["sd"] < 1.3  # not inflated by the outliers (true SD 1 mN)
    assert r["verdict"]["missing_effect"] == "speed_power_law", r["verdict"]["message"]
    assert r["n"] == 18 and r["n_rows"] == 20


def test_replicate_outlier_is_flagged_and_left_out_of_the_noise():
    rng = np.random.default_rng(3)
    sp = np.repeat([0.5, 1, 2, 5, 10.0], 4)
    y = 8 + 2 * np.sqrt(sp) + rng.standard_normal(sp.size)
    y[6] += 12.0
    n = noise_estimate(pd.DataFrame({"speed_mm_s": sp, "friction_mN": y}), "friction_mN")
    assert n["outliers"] == [6] and n["sd"] == pytest.approx(1.0, rel=0.4)
    clean = noise_estimate(pd.DataFrame({"speed_mm_s": sp, "friction_mN": np.delete(y, 6)[:19].tolist() + [y[7]]}),
                           "friction_mN")
    assert clean["outliers"] == []


def test_correlated_sensor_noise_is_no_periodic_finding():
    rng = np.random.default_rng(11)
    t = np.arange(0, 120, 1.0)
    df = synthesize(mk(COULOMB_FREE), pd.DataFrame({"speed_mm_s": 2.0, "time_s": t}), 0.0, 0.0, 1, 0)
    e = np.zeros(t.size)
    e[0] = rng.standard_normal()
    for i in range(1, t.size):  # AR(1) gauge noise, lag-1 correlation 0.8, marginal SD 1 mN
        e[i] = 0.8 * e[i - 1] + 0.6 * rng.standard_normal()
    df["friction_mN"] += e
    r = diagnose_table(mk(COULOMB_FREE), df, "friction").result
    v = r["verdict"]
    assert v["outcome"] in ("cannot_tell", "nothing_missing") and v["period"] is None, v["message"]
    assert v["missing_effect"] is None and v["covariate"] is None
    assert r["noise"]["correlated"]["covariate"] == "time_s" and r["noise"]["correlated"]["rho"] > 0.5
    assert 0.6 < r["noise"]["sd"] < 1.6  # corrected: differences of correlated readings understate it
    assert "correlated" in v["message"]


def test_collinear_time_and_position_are_named_together():
    t = np.arange(0, 60, 1.5)
    truth = fr(["viscoelastic_relaxation"], relax_amplitude_mN=6.0, relax_time_s=15.0)
    df = synthesize(mk(truth), pd.DataFrame({"speed_mm_s": 2.0, "time_s": t, "position_mm": 2.0 * t}), 1.0, 0.0,
                    1, 4)
    r = diagnose_table(mk(COULOMB_FREE), df, "friction").result
    v = r["verdict"]
    assert r["collinear_covariates"] == [["time_s", "position_mm"]]
    assert v["outcome"] == "cannot_tell" and v["missing_effect"] is None
    assert set(v["confounded"]) == {"time_s", "position_mm"}
    assert "time_s" in v["message"] and "position_mm" in v["message"] and "cannot be separated" in v["message"]


def test_stribeck_plus_power_law_goes_step_by_step(tmp_path):
    """Two effects hidden: the first diagnose names a partial step, and diagnose --write-model run again adds
    the missing effects one at a time until both are in the model, each step lowering the held-out error.

    At noise seed 0 the first step cannot tell a viscous term from the power law it is a special case of (the
    power law fitted at n = 1.57, nested F test p = 0.08, held out 1.37 against 1.41 mN): the viscous term is
    named, the power law not separable; then the Stribeck drop (held out 1.03), then the power law (0.914, the
    noise 0.83). Before the nested rule asked for a held-out error lower by 2 standard errors, the 0.04 mN named
    the power law first and the loop took two steps."""
    truth = fr(["stribeck", "speed_power_law"], stribeck_mN=8, stribeck_speed_mm_s=0.8, a_mN=8.778, n=0.25)
    r, _ = loop(tmp_path, truth, COULOMB_FREE, {"speed_mm_s": SP}, 1.0, 3, seed=0)
    v = r["verdict"]
    assert v["outcome"] == "missing_effect" and v["partial"] and v["message"].startswith("partial step")
    assert v["missing_effect"] in ("speed_power_law", "stribeck", "viscous")
    if v["missing_effect"] == "viscous":  # the power law contains it: named with it as not separable
        assert "speed_power_law" in v["alternatives"] and "not separable" in v["message"]
    d, k = read_measurements(tmp_path / "d_synthetic.csv")
    named, model, cv = [v["missing_effect"]], tmp_path / "new.yaml", [r["model_as_is"]["cv_rmse"]]
    for step in range(2, 4):
        if {"speed_power_law", "stribeck"} <= set(named):
            break
        out = tmp_path / f"new{step}.yaml"
        rs = run_diagnose(build_model(model), d, k, str(tmp_path / "d_synthetic.csv"), tmp_path / f"d{step}",
                          str(out), figures=False)
        cv.append(rs["model_as_is"]["cv_rmse"])
        assert rs["verdict"]["outcome"] == "missing_effect", rs["verdict"]["message"]
        named.append(rs["verdict"]["missing_effect"])
        model = out
    assert {"speed_power_law", "stribeck"} <= set(named) and len(set(named)) == len(named), named
    assert all(b < a for a, b in zip(cv, cv[1:])), cv


def test_folds_of_two_heights_seed000_case2(tmp_path):
    # seed 000 section 4.2: peaks 37.5 (small fold) and 88.2 mN (large fold) over 15.6 mN, folds 50 mm apart
    mu = 15.6e-3 / (3.462e-3 * 9.80665)
    truth = {"kind": "friction", "base": "coulomb", "effects": ["circular_folds"],
             "params": {"mu": mu, "mass_g": 3.462, "fold_amplitude_mN": 37.5 - 15.6,
                        "fold_height_ratio": (88.2 - 15.6) / (37.5 - 15.6), "fold_spacing_mm": 50.0,
                        "fold_width_mm": 3.0, "fold_phase_mm": 25.0}}
    design = {"speed_mm_s": [8.0] * 150, "position_mm": list(np.arange(0, 150, 1.0))}
    r, met = loop(tmp_path, truth, COULOMB_FREE, design, 2.0, 1)
    assert r["verdict"]["missing_effect"] == "circular_folds", r["verdict"]["message"]
    p = met["params"]
    base = p["mu"]["value"] * 3.462e-3 * 9.80665 * 1e3
    even = base + p["fold_amplitude_mN"]["value"]
    odd = base + p["fold_amplitude_mN"]["value"] * p["fold_height_ratio"]["value"]
    small, large = sorted([even, odd])  # which fold counts as k = 0 depends on the fitted phase
    assert base == pytest.approx(15.6, abs=1.0)
    assert small == pytest.approx(37.5, rel=0.08) and large == pytest.approx(88.2, rel=0.05)


def test_intervals_stay_inside_bounds_and_degenerate_fits_are_flagged():
    rng = np.random.default_rng(0)
    v = np.geomspace(0.2, 12, 20)
    y = 8.0 + rng.standard_normal(v.size)  # flat data: a power law's amplitude and exponent are not determined

    def model(p):
        return p[0] + p[1] * v ** p[2]

    f = fit_least_squares(model, y, [8.0, 1.0, 0.5], ["c", "a", "n"], ([0.0, 0.0, 0.05], [100.0, 1e4, 3.0]))
    assert np.all(f.ci_low >= [0.0, 0.0, 0.05]) and np.all(f.ci_high <= [100.0, 1e4, 3.0])
    assert "a" in f.degenerate or "n" in f.degenerate
    assert "c" not in f.degenerate
    # data below zero: mu ends at its bound 0, and its interval stops there
    g = fit_least_squares(lambda p: np.full(v.size, p[0]), -0.01 + 0.02 * rng.standard_normal(v.size), [0.1],
                          ["mu"], ([0.0], [1.0]))
    assert g.ci_low[0] >= 0.0 and "mu" in g.at_bound


def test_reference_tables_are_read_and_compared(tmp_path, capsys):
    for f in ("configs/reference/friction_seed000.csv", "configs/reference/contact_pressure.csv"):
        df, kind = read_measurements(f, drop_incomplete=True)
        assert len(df) > 0 and "source_type" in df.attrs["text_labels"]
        assert df.attrs["dropped_rows"]  # unstated values and unsupported statistics are listed
    df, _ = read_measurements("configs/reference/contact_pressure.csv", drop_incomplete=True)
    assert set(df["statistic"]) == {"avg", "max"}
    assert np.isinf(df["Ri_mm"]).any()  # the flat, cut-open intestine
    assert main(["compare", "--model", "configs/models/coulomb.yaml", "--data", "configs/reference/friction_seed000.csv",
                 "--out", str(tmp_path / "c"), "--ledger", str(tmp_path / "l.parquet"), "--drop-incomplete",
                 "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "statistic 'peak'" in err and "left out" in err
    # without the option: one clear line, exit 2
    assert main(["compare", "--model", "configs/models/coulomb.yaml", "--data", "configs/reference/friction_seed000.csv",
                 "--out", str(tmp_path / "c2"), "--ledger", str(tmp_path / "l2.parquet")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "statistic" in err and "--drop-incomplete" in err


def test_skipped_candidates_are_listed_with_reasons(tmp_path):
    p = tmp_path / "case1.csv"
    p.write_text("# seed 000 Case 1, four published values\nspeed_mm_s,friction_mN,source\n0.2,7,a\n8,19.57,b\n"
                 "12,21.45,c\n12,23,d\n")
    d, k = read_measurements(p)
    r = run_diagnose(mk(COULOMB_FREE), d, k, str(p), tmp_path / "d", None, figures=False)
    reasons = {s["effect"]: s["reason"] for s in r["skipped_candidates"]}
    assert "no column position_mm" in reasons["circular_folds"]
    assert "more free parameters" in reasons["speed_power_law"]
    md = (tmp_path / "d" / "diagnosis.md").read_text()
    assert "circular_folds: the table has no column position_mm" in md
    assert r["verdict"]["outcome"] == "cannot_tell" and "nothing is missing" not in r["verdict"]["message"]


def test_diagnose_without_figures_writes_the_verdict_and_no_png(tmp_path):
    out = tmp_path / "d"
    assert main(["diagnose", "--model", "configs/models/coulomb.yaml", "--data", "configs/data/seed000_case1_friction.csv",
                 "--out", str(out), "--no-figures", "--quiet"]) == 0
    r = __import__("json").loads((out / "diagnosis.json").read_text())
    assert r["figures"] == [] and not list(out.glob("*.png"))
    assert r["verdict"]["message"] and (out / "diagnosis.md").is_file()


def test_a_gross_error_on_an_end_row_is_flagged_and_does_not_hide_a_speed_effect():
    """An end row is seen by the differences from one side only (matched filter 0.41 of the error): a gross
    error of 8-10 noise SDs on the first or last of 20 speeds went unflagged in most data sets, inflated the
    noise and turned a hidden viscous term into "not built in", "the data cannot tell" or "nothing is missing".
    The end rows are now tested against every model tried refitted without them (a mean shift, exact
    externally studentised residual; diagnose.edge_outliers). Measured on these 12 data sets: the end row
    flagged in 12, viscous named in 12 (before: flagged in 3, named in 6)."""
    truth = mk(fr(["viscous"], c_Ns_m=0.6))
    flagged = named = 0
    for seed in range(6):
        for row, err in ((0, 9.0), (19, -9.0)):
            df = synthesize(truth, pd.DataFrame({"speed_mm_s": SP20}), 1.0, 0.0, 1, 400 + seed)
            df.loc[row, "friction_mN"] += err
            r = diagnose_table(mk(COULOMB_FREE), df, "friction").result
            flagged += row in [o["row"] for o in r["outliers"]]
            named += r["verdict"]["missing_effect"] == "viscous"
            assert r["n_rows"] == 20
    assert flagged >= 11 and named >= 11, (flagged, named)
