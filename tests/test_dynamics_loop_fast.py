"""The dynamics loop in CI time (issue 12 item 7): small designs, the quick effort, a stated subset of candidates.

The full-candidate tests (all five built-in dynamics effects, the default budget) are in
tests/test_dynamics_loop*.py and are marked ``slow`` (``make test-slow``). Here each diagnose tries the
candidates listed in ``CANDIDATES`` (closed-form and cheap today; the verdict's Bonferroni factor counts
only those tried, diagnosis.json lists them as ``candidates_tried``) on a 6-condition design whose
responses are periodic for the base model and for the hidden effect (f 30-38 Hz, P_d 0.08-0.10 N,
P_f = 0.02 N: no chaos, so the numbers test the rule and the calibration, not luck in a chaotic region).
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import yaml

from capsule_cli.effects import registry
from capsule_cli.dynamics import system as dsys
from capsule_cli.effects.model import build_model
from capsule_cli.errors import InputError
from capsule_cli.steps import crossval
from capsule_cli.steps import dynamics_loop as DL
from capsule_cli.steps import verdict as V
from capsule_cli.steps.diagnose import all_effects


NOISE = 0.5  # generating noise SD [mm/s]
QUICK = DL.EFFORTS["quick"]
PROTO = {"start": "rest", "transient_periods": 40, "recorded_periods": 16}
DESIGN = pd.DataFrame({"f_Hz": np.tile([30.0, 34.0, 38.0], 2), "Pd_N": np.repeat([0.08, 0.10], 3)})
CANDIDATES = ["secondary_constraint", "viscous_drag"]
# ten conditions, periodic for the base model but one (36 Hz / 0.12 N: irregular, windows 0.5 mm/s apart) and
# away from a grazing point: (30 Hz, 0.10 N) of DESIGN sits on one (the velocity there jumps between 0 and 16 mm/s
# as P_f moves by 4e-4 N), so a fold that leaves it out may predict it badly: 26 of 162 null seeds on DESIGN ended
# in "the data cannot tell" (no finding); on this design none of 162 did (552736b, 2026-11-23; on 4aacb93, seeds
# 0-199: 3 of 100 on DESIGN, 2 of 100 on this one; benchmarks/dynamics_loop_calibration_result.json)
TEN_DESIGN = pd.DataFrame({"f_Hz": np.tile([30.0, 32.0, 34.0, 36.0, 38.0], 2), "Pd_N": np.repeat([0.08, 0.12], 5)})
ROLL_DESIGN = TEN_DESIGN
FREE_PF = {"value": 0.03, "free": True, "bounds": [0.001, 0.2]}


def _model(tmp_path, name, effects=(), params=None, kind="progression", protocol=PROTO):
    doc = {"kind": kind, "base": "one_sided", "effects": list(effects), "params": dict(params or {})}
    if protocol:
        doc["protocol"] = protocol
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return build_model(path)


def _progression_data(tmp_path, truth, design=DESIGN, seed=1, replicates=2):
    df = DL.synthesize_progression(truth, design, NOISE, replicates, seed)
    path = tmp_path / f"{truth.name}_synthetic.csv"
    df.to_csv(path, index=False)
    return df, str(path)


def _diagnose(tmp_path, truth, seed=1, candidates=CANDIDATES, design=DESIGN, replicates=2):
    base = _model(tmp_path, "base", params={"Pf_N": FREE_PF})
    df, path = _progression_data(tmp_path, truth, design, seed, replicates)
    return DL.run_diagnose(base, df, path, tmp_path / "diag", write_model=tmp_path / "new.yaml", k_folds=3,
                           seed=seed, figures=False, budget=QUICK, candidates=candidates)


def test_quick_effort_tolerance_is_far_below_the_noise():
    """The quick effort's looser adaptive tolerance (1e-8) moves the velocities by far less than the noise."""
    from capsule_cli.dynamics import system as dsys
    from capsule_cli.dynamics.model import EngineOptions

    sysm = dsys.build_system("one_sided", {"Pf_N": 0.02, "a_mN": 6.0, "n": 0.5}, ["speed_dependent_friction"])
    f, pdn = DESIGN["f_Hz"].to_numpy(), DESIGN["Pd_N"].to_numpy()
    proto = dsys.Protocol(**PROTO)
    ref = dsys.progression(sysm, f, pdn, protocol=proto)["velocity_mm_s"].to_numpy()
    quick = dsys.progression(sysm, f, pdn, protocol=proto,
                             options=EngineOptions(rk_rtol=QUICK.rk_rtol))["velocity_mm_s"].to_numpy()
    assert np.max(np.abs(quick - ref)) < 1e-3 * NOISE


def test_hidden_secondary_constraint_named_and_held_out_at_noise(tmp_path):
    truth = _model(tmp_path, "truth_sec", ["secondary_constraint"], {"Pf_N": 0.02, "gap_back_mm": 0.3})
    r = _diagnose(tmp_path, truth)
    v = r["verdict"]
    assert v["outcome"] == "missing_effect" and v["missing_effect"] == "secondary_constraint", v["message"]
    assert set(r["candidates_tried"]) == set(CANDIDATES)
    win = next(c for c in r["candidates"] if c["effect"] == "secondary_constraint")
    assert r["model_as_is"]["cv_rmse"] > 5 * NOISE
    assert win["cv_rmse_not_irregular"] <= 1.2 * NOISE
    assert win["passes"] and win["f_test_p_adjusted"] < 0.01
    doc = yaml.safe_load((tmp_path / "new.yaml").read_text())
    assert doc["effects"] == ["secondary_constraint"] and doc["protocol"] == PROTO


def test_nothing_missing_gives_a_null_verdict(tmp_path):
    truth = _model(tmp_path, "truth_null", params={"Pf_N": 0.02})
    r = _diagnose(tmp_path, truth, seed=3, design=TEN_DESIGN)
    v = r["verdict"]
    assert v["outcome"] == "nothing_missing" and v["missing_effect"] is None, v["message"]
    assert v["regime"] is None and v["message"].startswith("nothing is missing")
    assert not any(c["passes"] for c in r["candidates"])


# --------------------------------------------------------------------------- one speed per condition (no replicates)
# Differences between neighbouring conditions are not noise (the speed jumps as impacts appear and vanish: on
# TEN_DESIGN 5-25x the generating SD), so without replicates diagnose takes the noise from the best fit's
# standardised residuals (steps/dynamics_loop/noise.py: progression_noise) and says so.


def test_no_replicates_nothing_missing_noise_from_the_residuals(tmp_path):
    truth = _model(tmp_path, "truth_null1", params={"Pf_N": 0.02})
    r = _diagnose(tmp_path, truth, seed=3, design=TEN_DESIGN, replicates=1)
    assert r["noise"]["method"].startswith("residual SD of the best-fitting model"), r["noise"]["method"]
    # against the noise actually drawn (this seed's ten draws have SD 1.7 x the generating 0.5 mm/s)
    data, _ = _progression_data(tmp_path, truth, TEN_DESIGN, 3, 1)
    clean = DL.synthesize_progression(truth, TEN_DESIGN, 0.0, 1, 3)
    drawn = float(np.sqrt(np.sum((data["velocity_mm_s"] - clean["velocity_mm_s"]) ** 2) / (len(data) - 1)))
    assert 0.8 * drawn < r["noise"]["sd"] < 1.2 * drawn, (r["noise"], drawn)
    assert r["verdict"]["outcome"] == "nothing_missing", r["verdict"]["message"]


def test_no_replicates_hidden_effect_named_and_fitted_to_the_noise(tmp_path):
    truth = _model(tmp_path, "truth_sec1", ["secondary_constraint"], {"Pf_N": 0.02, "gap_back_mm": 0.3})
    r = _diagnose(tmp_path, truth, seed=1, design=TEN_DESIGN, replicates=1)
    v = r["verdict"]
    assert v["outcome"] == "missing_effect" and v["missing_effect"] == "secondary_constraint", v["message"]
    win = next(c for c in r["candidates"] if c["effect"] == "secondary_constraint")
    assert win["cv_rmse_not_irregular"] <= 1.5 * NOISE, win["cv_rmse_not_irregular"]
    assert r["noise"]["sd"] < 1.5 * NOISE, r["noise"]


def _outlier_ev(y, pred, k=1, cls=None, spread=None):
    """A progression evaluation as outlier_rows reads it (one row per reading)."""
    n = y.size
    sim = {"pred": pred, "cls": np.array(cls if cls is not None else ["one_impact"] * n),
           "spread": np.zeros(n) if spread is None else np.asarray(spread, float)}
    return SimpleNamespace(y=y, pred=pred, resid=y - pred, k=k, sim=sim,
                           bound=SimpleNamespace(kind="progression",
                                                 model=SimpleNamespace(effect_names=["effect"] if k > 1 else [])))


def test_a_reading_no_model_tried_accounts_for_is_an_outlier():
    """outlier_rows (no engine): generalized ESD on the best fit's standardised residuals, a row flagged
    only where that fit predicts no spread over windows and starts and no other model tried comes within the
    threshold. Two readings 12 noise SDs off in 40 are flagged (z against the SD of the rows not flagged, far
    above the Bonferroni threshold), also when the model as is is far off everywhere (an effect missing); a row
    another model accounts for is not; nor is a chaotic row (its error is the spread's); an irregular row
    without spread (a long period, the same in every window) is."""
    rng = np.random.default_rng(7)
    n, sd = 40, 0.5
    truth = rng.uniform(-20.0, 60.0, n)
    y = truth + rng.normal(0.0, sd, n)
    y[[7, 29]] += [6.0, -6.0]
    base, cand = _outlier_ev(y, truth), _outlier_ev(y, truth + 0.01, k=2)
    out = DL.outlier_rows([base, cand])
    assert [o["row"] for o in out] == [7, 29] and out[0]["model"] == "the model as is"
    assert all(o["z"] > 9.0 and 3.5 <= o["threshold"] < 4.5 for o in out), out
    # an effect missing: the model as is misses every row by 2-12 mm/s, the candidate fits; both readings flagged
    far = _outlier_ev(y, truth + rng.uniform(2.0, 12.0, n) * rng.choice([-1.0, 1.0], n))
    assert [o["row"] for o in DL.outlier_rows([far, cand])] == [7, 29]
    # row 7 is what a candidate describes: the model as is misses it, the candidate does not
    with_effect = truth.copy()
    with_effect[7] += 6.0
    assert [o["row"] for o in DL.outlier_rows([base, _outlier_ev(y, with_effect, k=2)])] == [29]
    # row 29 predicted chaotic with a spread of 4 mm/s by both: its error is the chaos's, not a gross one
    cls = ["one_impact"] * n
    cls[29] = "irregular"
    spread = np.zeros(n)
    spread[29] = 4.0
    chaotic = [_outlier_ev(y, truth, cls=cls, spread=spread), _outlier_ev(y, truth + 0.01, 2, cls, spread)]
    assert [o["row"] for o in DL.outlier_rows(chaotic)] == [7]
    # the same row irregular without spread (a long period): its error is the noise's, and it is flagged
    steady = [_outlier_ev(y, truth, cls=cls), _outlier_ev(y, truth + 0.01, 2, cls)]
    assert [o["row"] for o in DL.outlier_rows(steady)] == [7, 29]
    # Gaussian readings and a correct model: a flag is a false alarm, at most about OUTLIER_ALPHA = 2 % of tables
    # (measured: 7 of 400 tables, 1.75 %)
    flags = sum(bool(DL.outlier_rows([_outlier_ev(t + g.normal(0.0, sd, n), t)]))
                for g in (np.random.default_rng(s) for s in range(400)) for t in [g.uniform(-20.0, 60.0, n)])
    assert flags <= 12, flags


GRID = {"f_Hz": np.tile(np.arange(15.0, 43.0, 3.0), 4), "Pd_N": np.repeat([0.1, 0.15, 0.2, 0.25], 10)}


def test_readings_gathered_at_one_drive_are_an_effect_there_not_independent_outliers():
    """concentrated_rows (no engine): readings no model tried accounts for that gather at one value of a covariate
    (three of the four readings at 30 Hz in the 10 x 4 grid) are read as an effect acting there, not as independent
    gross errors. Measured with diagnose (full effort, friction 1.5 x at 30 Hz at every amplitude, noise 0.5 mm/s,
    seed 0): before, the three were left out as outliers and the verdict was "nothing is missing"."""
    from scipy.special import comb

    rng = np.random.default_rng(3)
    n, sd = 40, 0.5
    truth = rng.uniform(-20.0, 60.0, n)
    y = truth + rng.normal(0.0, sd, n)
    at30 = np.flatnonzero(GRID["f_Hz"] == 30.0)[1:]  # 0.15, 0.2, 0.25 N
    y[at30] += [15.0, -7.0, -7.0]
    out = DL.outlier_rows([_outlier_ev(y, truth)], GRID)
    assert [o["row"] for o in out] == list(at30), out
    at = out[0]["concentrated"]
    assert all(o["concentrated"] == at for o in out)
    assert (at["covariate"], at["value"], at["of"]) == ("f_Hz", 30.0, 4)
    # three of three at one of ten levels of four: 10 x C(4, 3) / C(40, 3), Bonferroni over the two covariates
    assert at["p"] == pytest.approx(2 * 10 * 4 / comb(40, 3), rel=1e-9)
    # the same three errors at rows of three frequencies and three amplitudes: independent outliers
    spread_out = y.copy()
    spread_out[at30] -= [15.0, -7.0, -7.0]
    spread_out[[2, 15, 28]] += [15.0, -7.0, -7.0]
    out = DL.outlier_rows([_outlier_ev(spread_out, truth)], GRID)
    assert [o["row"] for o in out] == [2, 15, 28] and not any("concentrated" in o for o in out), out
    # two of two at one frequency: p = 2 x 10 x C(4, 2) / C(40, 2) = 0.15, no grouping
    assert DL.concentrated_rows(at30[:2], GRID, np.ones(n, bool)) is None
    # independent gross errors at random rows read as gathered in at most ALPHA_STRUCTURE = 1 % of tables (the
    # union bound and Bonferroni make it less: three at one frequency 40 / C(40, 3) = 0.4 %; measured 12, 0 and
    # 5 of 4000 draws of 3, 4 and 5 rows)
    for m in (3, 4, 5):
        hits = sum(DL.concentrated_rows(g.choice(n, m, replace=False), GRID, np.ones(n, bool)) is not None
                   for g in (np.random.default_rng(s) for s in range(4000)))
        assert hits <= DL.ALPHA_STRUCTURE * 4000, (m, hits)


def test_a_verdict_reads_readings_gathered_at_one_drive_as_an_effect_there():
    """concentrated_verdict (no engine): "nothing is missing" on the other readings becomes an effect that is not
    built in acting at that value (the other readings' verdict kept in the message, where to measure again);
    "cannot tell" when the covariate moves with another; a finding already made, and "the data cannot tell",
    keep their outcome, with the readings as a caveat."""
    at = {"covariate": "f_Hz", "value": 30.0, "of": 4, "p": 0.0081}
    left = [{"row": r, "z": z, "threshold": 3.85, "concentrated": at} for r, z in ((15, 8.7), (25, 5.2), (35, 4.8))]
    left.append({"row": 3, "z": 9.0, "threshold": 3.85})  # an independent outlier beside them
    base = SimpleNamespace(y=np.zeros(36))
    null = {"outcome": "nothing_missing", "missing_effect": None, "covariate": None, "confounded": [],
            "message": "nothing is missing: held-out RMSE 0.413 mm/s"}
    covs = {"f_Hz": GRID["f_Hz"], "Pd_N": GRID["Pd_N"]}
    v = DL.concentrated_verdict(null, left, base, "mm/s", covs)
    assert (v["outcome"], v["covariate"], v["missing_effect"]) == ("not_built_in", "f_Hz", None), v
    assert v["message"].startswith("an effect that is not built in acts at f_Hz = 30: 3 of the 4 readings"), v
    assert "rows 15, 25, 35" in v["message"] and "4.8-8.7 noise SDs" in v["message"]
    assert "the other 36 readings say: nothing is missing: held-out RMSE 0.413" in v["message"]
    assert v["measure_where"] == {"covariate": "f_Hz", "from": 30.0, "to": 30.0}
    # the frequency moved with a temperature column: which of the two is not told
    covs_t = covs | {"temperature_C": 20.0 + 0.5 * GRID["f_Hz"]}
    v = DL.concentrated_verdict(null, left, base, "mm/s", covs_t)
    assert v["outcome"] == "cannot_tell" and v["confounded"] == ["f_Hz", "temperature_C"], v
    named = {"outcome": "missing_effect", "missing_effect": "viscous_drag", "covariate": None, "confounded": [],
             "message": "viscous_drag is missing"}
    v = DL.concentrated_verdict(named, left, base, "mm/s", covs)
    assert (v["outcome"], v["missing_effect"]) == ("missing_effect", "viscous_drag")
    assert v["message"].startswith("viscous_drag is missing. Besides, 3 of the 4 readings at f_Hz = 30"), v
    unsure = {**null, "outcome": "cannot_tell", "message": "the data cannot tell"}
    v = DL.concentrated_verdict(unsure, left, base, "mm/s", covs)
    assert v["outcome"] == "cannot_tell" and v["message"].startswith("the data cannot tell. Besides, 3 of"), v
    # independent outliers only: the verdict as it was
    assert DL.concentrated_verdict(null, left[3:], base, "mm/s", covs) is null


def _misfit_at_one_amplitude():
    """Return (readings, truth, rows at 0.2 N) of the 10 x 4 grid (GRID), noise 0.5 mm/s, with the shifts the
    engine gave the ten readings at 0.2 N under friction 1.3 x there (diagnose, full effort, seed 0) [mm/s]."""
    rng = np.random.default_rng(3)
    truth = rng.uniform(-20.0, 60.0, 40)
    y = truth + rng.normal(0.0, 0.5, 40)
    at02 = np.flatnonzero(GRID["Pd_N"] == 0.2)
    y[at02] += [-0.64, 0.2, -3.16, -3.54, -6.66, -4.37, 8.8, 8.16, 7.6, 7.12]
    return y, truth, at02


def test_a_misfit_gathered_at_one_amplitude_is_not_read_as_noise():
    """scattered_level and scattered_verdict (no engine): without replicates the noise is bounded by the best
    fit's residual SD, which a misfit gathered at one value of a covariate inflates, and "nothing is missing" then
    holds against that bound. Measured with diagnose (full effort, friction 1.3 x at 0.2 N at every frequency of
    the 10 x 4 grid, noise 0.5 mm/s, seed 0): no model tried nor probe followed the ten readings there (-6.7 to
    +8.8 mm/s), the noise was bounded at 2.49 mm/s and the verdict was "nothing is missing". The residuals'
    sizes at each value are ranked against the others' (Mann-Whitney), Bonferroni over the values."""
    n, sd = 40, 0.5
    y, truth, at02 = _misfit_at_one_amplitude()
    ev = _outlier_ev(y, truth)
    at = DL.scattered_level(ev, GRID)
    assert (at["covariate"], at["value"], at["n"], at["tests"]) == ("Pd_N", 0.2, 10, 14), at
    assert at["p"] < 1e-3 and at["rms"] > 5.0 and at["rms_other"] < 0.6, at
    null = {"outcome": "nothing_missing", "missing_effect": None, "covariate": None, "confounded": [],
            "message": "nothing is missing"}
    bound = {"sd": 2.49, "residual_of": "the model as is"}
    v = DL.scattered_verdict(null, bound, [ev], GRID, "mm/s")
    assert (v["outcome"], v["covariate"]) == ("not_built_in", "Pd_N"), v
    assert v["message"].startswith("an effect that is not built in acts at Pd_N = 0.2: the best-fitting model"), v
    assert v["measure_where"] == {"covariate": "Pd_N", "from": 0.2, "to": 0.2}
    # the noise known from replicates, or another verdict: kept
    assert DL.scattered_verdict(null, {"sd": 0.5}, [ev], GRID, "mm/s") is null
    unsure = {**null, "outcome": "cannot_tell"}
    assert DL.scattered_verdict(unsure, bound, [ev], GRID, "mm/s") is unsure
    # the amplitude moved with a temperature column: which of the two is not told
    v = DL.scattered_verdict(null, bound, [ev], GRID | {"temperature_C": 20.0 + 40.0 * GRID["Pd_N"]}, "mm/s")
    assert v["outcome"] == "cannot_tell" and v["confounded"] == ["Pd_N", "temperature_C"], v
    # with nothing missing a table gets a finding in at most ALPHA_SCATTER = 0.5 % of cases, whatever the noise's
    # distribution (ranks; Fisher's F on the mean squares: 31 % with Student-t noise): measured 8 of 1000 Gaussian
    # and 4 of 1000 Student-t (3 dof) tables, against at most 11, the binomial 99 % quantile at 0.5 %
    from scipy.stats import binom

    most = binom.ppf(0.99, 1000, DL.ALPHA_SCATTER)
    for draw in (lambda g: g.normal(0.0, sd, n), lambda g: sd / np.sqrt(3) * g.standard_t(3, n)):
        hits = sum(DL.scattered_level(_outlier_ev(t + draw(g), t), GRID) is not None
                   for g in (np.random.default_rng(s) for s in range(1000)) for t in [g.uniform(-20.0, 60.0, n)])
        assert hits <= most, (hits, most)


def test_a_cannot_tell_says_where_the_misfit_gathers():
    """scattered_caveat (no engine): "the data cannot tell" keeps its outcome (a built-in effect fitted short of
    the noise also leaves its misfit where its effect is largest) but says where the best fit's misfit gathers.
    Measured with diagnose (friction 1.3 x at 0.2 N, the 40-condition grid x 2 replicates, full effort): "the data
    cannot tell", and nothing in the message pointed at the amplitude."""
    y, truth, _ = _misfit_at_one_amplitude()
    ev = _outlier_ev(y, truth)
    unsure = {"outcome": "cannot_tell", "missing_effect": None, "covariate": None, "confounded": [],
              "message": "the data cannot tell: held-out RMSE 2.58 mm/s exceeds the 0.524 mm/s expected"}
    v = DL.scattered_caveat(unsure, [ev], GRID, "mm/s")
    assert (v["outcome"], v["covariate"], v["missing_effect"]) == ("cannot_tell", None, None), v
    assert v["message"].startswith(unsure["message"] + ". Besides, the misfit gathers at Pd_N = 0.2: the "
                                   "best-fitting model tried (the model as is) misses the 10 readings there"), v
    assert v["message"].endswith("measure again at Pd_N = 0.2 and beside it"), v
    assert (v["scattered"]["covariate"], v["scattered"]["value"], v["scattered"]["n"]) == ("Pd_N", 0.2, 10)
    # other outcomes, a caveat already given, or no level standing out: as they were
    for other in ({**unsure, "outcome": "nothing_missing"}, {**unsure, "scattered": v["scattered"]}):
        assert DL.scattered_caveat(other, [ev], GRID, "mm/s") is other
    rng = np.random.default_rng(4)
    plain = _outlier_ev(truth + rng.normal(0.0, 0.5, 40), truth)
    assert DL.scattered_caveat(unsure, [plain], GRID, "mm/s") is unsure


def test_the_readings_where_a_misfit_gathers_are_left_out_and_the_others_speak_for_themselves():
    """scattered_rows and left_out_level_verdict (no engine): once the misfit of the best fit is found gathered at
    one value of a covariate against a noise bounded by that fit's residual SD, every reading at that value is
    left out and the others are diagnosed again, so that the noise and the errors beside the verdict are theirs.
    Before, the verdict named Pd_N = 0.2 but the report kept the bound the misfit held (2.49 mm/s against a
    generating 0.5; diagnose, full effort, friction 1.3 x at 0.2 N, 10 x 4 grid, seed 0) and measured every
    held-out error and the figure's band against it."""
    y, truth, at02 = _misfit_at_one_amplitude()
    ev = _outlier_ev(y, truth)
    null = {"outcome": "nothing_missing", "missing_effect": None, "covariate": None, "confounded": [],
            "message": "nothing is missing: held-out RMSE 0.47 mm/s"}
    at = DL.scattered_verdict(null, {"sd": 2.49, "residual_of": "the model as is"}, [ev], GRID, "mm/s")["scattered"]
    assert (at["model"], at["noise_bound"], at["collinear"]) == ("the model as is", 2.49, ["Pd_N"]), at
    rows = DL.scattered_rows(at, [ev], GRID, k_folds=5)
    assert [o["row"] for o in rows] == list(at02) and all(o["scattered"] == at for o in rows), rows
    assert [o["residual"] for o in rows] == pytest.approx(y[at02] - truth[at02])
    # z: |residual| in the fit's residual SDs (no error model beyond the noise here)
    assert rows[4]["z"] == pytest.approx(abs(y[at02[4]] - truth[at02[4]]) / DL.standardised_residual_sd(ev))
    # the others too few to diagnose: less than half the table, or than 3 rows per fold
    assert DL.scattered_rows({**at, "value": 0.2}, [ev], {"Pd_N": np.where(GRID["Pd_N"] < 0.15, 0.1, 0.2)}, 5) == []
    assert DL.scattered_rows(at, [ev], GRID, k_folds=11) == []
    # the other 30 readings at the noise: an effect that is not built in acts at 0.2 N, their noise beside the bound
    left = [{**o, "row": int(o["row"])} for o in rows]
    base = SimpleNamespace(y=np.zeros(30))
    rest = {c: x[GRID["Pd_N"] != 0.2] for c, x in GRID.items()}
    v = DL.left_out_level_verdict(null, left, base, {"sd": 0.47}, "mm/s", rest)
    assert (v["outcome"], v["covariate"], v["missing_effect"]) == ("not_built_in", "Pd_N", None), v
    assert v["message"].startswith("an effect that is not built in acts at Pd_N = 0.2: the best-fitting model tried "
                                   "(the model as is) missed the 10 readings at Pd_N = 0.2 (rows 20, 21,"), v
    assert "held the noise bound at 2.49 mm/s" in v["message"], v
    assert "the other 30 readings (noise 0.47 mm/s) say: nothing is missing: held-out RMSE 0.47" in v["message"]
    assert v["scattered"] == at and v["measure_where"] == {"covariate": "Pd_N", "from": 0.2, "to": 0.2}
    # collinear on the whole table, as the level was read (the rest's columns alone may not show it)
    both = {**at, "collinear": ["Pd_N", "temperature_C"]}
    v = DL.left_out_level_verdict(null, [{**o, "scattered": both} for o in left], base, {"sd": 0.47}, "mm/s", rest)
    assert v["outcome"] == "cannot_tell" and v["confounded"] == ["Pd_N", "temperature_C"], v
    # a finding on the others is kept, the level a caveat; no level left out: the verdict as it was
    named = {**null, "outcome": "missing_effect", "missing_effect": "viscous_drag", "message": "viscous_drag is missing"}
    v = DL.left_out_level_verdict(named, left, base, {"sd": 0.47}, "mm/s", rest)
    assert (v["outcome"], v["missing_effect"]) == ("missing_effect", "viscous_drag"), v
    assert v["message"].startswith("viscous_drag is missing. Besides, the best-fitting model tried"), v
    assert DL.left_out_level_verdict(null, [{"row": 3, "z": 9.0, "threshold": 3.85}], base, {"sd": 0.47}, "mm/s",
                                     rest) is null


TWENTY_DESIGN = pd.DataFrame({"f_Hz": np.tile(np.linspace(28.0, 40.0, 10), 2), "Pd_N": np.repeat([0.08, 0.12], 10)})


def test_a_gross_reading_is_left_out_and_the_noise_is_not_inflated(tmp_path):
    """Nothing missing, 20 conditions, one reading per condition, one of them 5 mm/s (10 noise SDs) off, as a
    mistyped or mis-tracked reading would be: diagnose flags it, leaves it out of every fit and diagnoses the
    rest. Before, no row was flagged and the noise (bounded by the best fit's residual SD) held the gross error:
    1.30 mm/s against the generating 0.5 (after: 0.58 at this seed, 0.30-0.41 at seeds 0-2)."""
    truth = _model(tmp_path, "truth_gross", params={"Pf_N": 0.02})
    df = DL.synthesize_progression(truth, TWENTY_DESIGN, NOISE, 1, 6)
    df.loc[13, "velocity_mm_s"] += 5.0
    path = tmp_path / "gross_synthetic.csv"
    df.to_csv(path, index=False)
    base = _model(tmp_path, "base", params={"Pf_N": FREE_PF})
    r = DL.run_diagnose(base, df, str(path), tmp_path / "diag", k_folds=3, seed=6, figures=False, budget=QUICK,
                        candidates=CANDIDATES)
    assert [o["row"] for o in r["outliers"]] == [13] and r["n"] == 19 and r["n_rows"] == 20
    assert r["outliers"][0]["velocity_mm_s"] == pytest.approx(df.loc[13, "velocity_mm_s"])
    assert r["outliers"][0]["z"] > r["outliers"][0]["threshold"]
    assert r["noise"]["sd"] < 1.3 * NOISE, r["noise"]
    assert r["verdict"]["outcome"] == "nothing_missing", r["verdict"]["message"]
    md = (tmp_path / "diag" / "diagnosis.md").read_text()
    assert "row 13" in md
    # the rule printed with the diagnosis says how readings are left out and when they are an effect instead
    assert DL.PROGRESSION_RULE.strip() in md and "hypergeometric" in md and "Mann-Whitney" in md

def _replicated_ev(y, pred, periodic, spread=8.0):
    """A progression evaluation as progression_noise reads it: six conditions x 2 replicates (rows 2i, 2i + 1),
    the conditions not in ``periodic`` predicted irregular with a spread of ``spread`` [mm/s]."""
    df = pd.DataFrame({"f_Hz": np.repeat([15.0, 18.0, 21.0, 24.0, 27.0, 30.0], 2), "Pd_N": 0.2,
                       "velocity_mm_s": y})
    reg = np.repeat(np.isin(np.arange(6), periodic), 2)
    sim = {"pred": pred, "cls": np.where(reg, "one_impact", "irregular"), "spread": np.where(reg, 0.0, spread)}
    return SimpleNamespace(bound=SimpleNamespace(df=df, response="velocity_mm_s",
                                                 model=SimpleNamespace(effect_names=["secondary_constraint"])),
                           y=y, pred=pred, resid=y - pred, sim=sim, k=2)


def test_replicate_noise_leaves_out_the_conditions_predicted_chaotic():
    """A replicate of a chaotic condition (another window of the run, as a lab's repeat) differs by the chaos
    too, which the error model's spread already holds: pooled with the periodic conditions' replicates it
    counted the chaos as noise (continuation up, 12 conditions x 2, a secondary constraint hidden: 7.2 mm/s
    against a generating 0.5). After the fits the estimate pools the conditions the best fit does not predict
    chaotic (irregular with a spread over windows and starts)."""
    rng = np.random.default_rng(0)
    clean = np.repeat([1.0, 5.0, -3.0, 8.0, 20.0, -15.0], 2)
    y = clean + NOISE * rng.standard_normal(12)
    y[6:] += [9.0, -7.0, -6.0, 11.0, 10.0, -12.0]  # three chaotic conditions: windows 6-23 mm/s apart
    from capsule_cli.steps.residual_tests import noise_estimate

    noise = noise_estimate(pd.DataFrame({"f_Hz": np.repeat(np.arange(6.0), 2), "velocity_mm_s": y}),
                           "velocity_mm_s")
    assert noise["method"].startswith("replicates") and noise["sd"] > 5.0  # the premise: chaos counted as noise
    out = DL.progression_noise(noise, [_replicated_ev(y, clean, [0, 1, 2])])
    pairs = y.reshape(6, 2)[:3]
    assert out["sd"] == pytest.approx(float(np.sqrt(np.mean(np.diff(pairs, axis=1) ** 2 / 2))), rel=1e-12)
    assert out["dof"] == 3 and out["reliable"] is True and out["outliers"] == []
    assert "3 chaotic conditions left out" in out["method"], out["method"]
    # every condition predicted periodic, or irregular without spread (a long period, the same in every
    # window, whose replicates differ by the noise only): the estimate stands as it is
    assert DL.progression_noise(noise, [_replicated_ev(y, clean, range(6))]) is noise
    assert DL.progression_noise(noise, [_replicated_ev(y, clean, [0, 1, 2], spread=0.0)]) is noise


def test_replicate_noise_bounded_by_the_fit_where_the_chaos_leaves_too_few_replicates():
    """One condition predicted periodic (1 degree of freedom of replicates): no estimate from it; the pooled
    replicate SD (which holds the chaos) and the fit's standardised residual SD are both upper bounds of the
    noise, and the smaller is used, as without replicates."""
    rng = np.random.default_rng(1)
    clean = np.repeat([1.0, 5.0, -3.0, 8.0, 20.0, -15.0], 2)
    y = clean + NOISE * rng.standard_normal(12) + np.r_[0.0, 0.0, 9.0 * rng.standard_normal(10)]
    noise = {"sd": 6.0, "se": 1.7, "dof": 6, "reliable": True, "method": "replicates: pooled within-group SD"}
    ev = _replicated_ev(y, clean, [0])
    out = DL.progression_noise(noise, [ev])
    assert out["sd"] == pytest.approx(DL.standardised_residual_sd(ev), rel=1e-12) and out["sd"] < 6.0
    assert out["method"].startswith("residual SD of the best-fitting model tried (secondary_constraint")
    assert "smaller than the pooled replicate estimate (6)" in out["method"], out["method"]
    assert out["residual_because"] == "too few replicates where the fits predict no chaos"


def test_no_replicates_difference_estimate_is_only_a_bound(tmp_path):
    truth = _model(tmp_path, "truth_null2", params={"Pf_N": 0.02})
    df, _ = _progression_data(tmp_path, truth, TEN_DESIGN, 3, 1)
    noise = DL.noise_of(DL.DynBound(truth, df))
    assert noise["reliable"] is False and "upper bound" in noise["method"]
    assert noise["sd"] > 3 * NOISE  # what the differences would have claimed


# --------------------------------------------------------------------------- a user's plugin, found by its covariate

PLUGIN = '''
from capsule_cli.effects import Param, register_effect


@register_effect(
    name="coil_rolloff", kind="progression", role="drive", covariates=("f_Hz",),
    params=(Param("rolloff", start=0.1, bounds=(0.0, 0.9), off=0.0,
                  description="relative loss of drive force per 10 Hz above 30 Hz"),),
    description="The coil's force falls with frequency (inductance): P_d (1 - r (f - 30 Hz) / 10 Hz).",
    source="test: a user's plugin")
def coil_rolloff(f_Hz, Pd_N, duty, p):
    return f_Hz, Pd_N * (1.0 - p["rolloff"] * (f_Hz - 30.0) / 10.0), duty
'''


def _register(path):
    registry.load_plugins([path], entry_points=False)


def _unregister(path):
    registry.unregister_effect("progression", "coil_rolloff")
    registry._LOADED_PLUGINS.discard(str(path.resolve()))


def test_plugin_effect_found_through_its_covariate_then_fitted_to_noise(tmp_path):
    plugin = tmp_path / "coil.py"
    plugin.write_text(PLUGIN)
    _register(plugin)
    try:
        truth = _model(tmp_path, "truth_roll", ["coil_rolloff"], {"Pf_N": 0.02, "rolloff": 0.3})
        df, path = _progression_data(tmp_path, truth, ROLL_DESIGN, seed=4)
    finally:
        _unregister(plugin)
    # the researcher has not written the plugin yet: no built-in fits, the verdict names the covariate
    base = _model(tmp_path, "base", params={"Pf_N": FREE_PF})
    r = DL.run_diagnose(base, df, path, tmp_path / "diag", k_folds=3, seed=4, figures=False, budget=QUICK,
                        candidates=CANDIDATES)
    v = r["verdict"]
    assert v["outcome"] == "not_built_in" and v["missing_effect"] is None, v["message"]
    assert v["covariate"] == "f_Hz", v["message"]
    # the plugin written and added: held-out error at the noise level, the roll-off recovered
    _register(plugin)
    try:
        fixed = _model(tmp_path, "with_plugin", ["coil_rolloff"],
                       {"Pf_N": FREE_PF, "rolloff": {"value": 0.1, "free": True, "bounds": [0.0, 0.9]}})
        met = DL.run_compare(fixed, df, path, tmp_path / "cmp", None, k_folds=3, seed=4, figures=False,
                             budget=QUICK)
    finally:
        _unregister(plugin)
    assert met["cv_rmse_not_irregular"] <= 1.2 * NOISE
    assert abs(met["params"]["rolloff"]["value"] - 0.3) < 0.05


# --------------------------------------------------------------------------- trajectories as a camera records them

POS_NOISE = 0.05  # [mm], sub-millimetre
# six runs from rest, 0.4 s each at 100 frames per second (41 frames a run)
TRAJ_DESIGN = pd.DataFrame({"run": list("abcdef"), "f_Hz": [30.0, 34.0, 38.0] * 2, "Pd_N": [0.08] * 3 + [0.10] * 3,
                            "duration_s": [0.4] * 6})


def _trajectory_diagnose(tmp_path, truth, seed):
    df = DL.synthesize_trajectory(truth, TRAJ_DESIGN, POS_NOISE, 100.0, seed)
    path = tmp_path / f"{truth.name}_synthetic.csv"
    df.to_csv(path, index=False)
    base = _model(tmp_path, "tbase", params={"Pf_N": FREE_PF}, kind="trajectory", protocol=None)
    return DL.run_diagnose(base, df, str(path), tmp_path / "tdiag", k_folds=3, seed=seed, figures=False,
                           budget=QUICK, candidates=CANDIDATES)


def test_trajectory_hidden_effect_named(tmp_path):
    truth = _model(tmp_path, "ttruth_sec", ["secondary_constraint"], {"Pf_N": 0.02, "gap_back_mm": 0.3},
                   kind="trajectory", protocol=None)
    r = _trajectory_diagnose(tmp_path, truth, 6)
    assert r["verdict"]["missing_effect"] == "secondary_constraint", r["verdict"]["message"]
    assert set(r["runs_compared_by"].values()) <= {"position", "average_velocity"}
    win = next(c for c in r["candidates"] if c["effect"] == "secondary_constraint")
    # calibrated on all runs it follows the frames to the position noise; held out (a whole run left out,
    # refitted on the other five) it is within a few noise SDs
    assert win["rmse"] <= 1.2 * POS_NOISE
    assert win["cv_rmse_not_irregular"] <= 4 * POS_NOISE
    assert r["model_as_is"]["cv_rmse"] > 20 * POS_NOISE


def test_trajectory_nothing_missing_null(tmp_path):
    truth = _model(tmp_path, "ttruth_null", params={"Pf_N": 0.02}, kind="trajectory", protocol=None)
    r = _trajectory_diagnose(tmp_path, truth, 7)
    assert r["verdict"]["missing_effect"] is None and r["verdict"]["outcome"] == "nothing_missing", \
        r["verdict"]["message"]
    # frames undersample the motion: the noise comes from the best fit's residuals, near the generating SD
    assert 0.8 * POS_NOISE < r["noise"]["sd"] < 1.25 * POS_NOISE, r["noise"]["method"]


def _glitched_null_runs(tmp_path):
    """Six null runs (TRAJ_DESIGN, seed 7) with two frames put 3 and 4 mm off: (table, their rows, path, base)."""
    truth = _model(tmp_path, "ttruth_glitch", params={"Pf_N": 0.02}, kind="trajectory", protocol=None)
    df = DL.synthesize_trajectory(truth, TRAJ_DESIGN, POS_NOISE, 100.0, 7)
    bad = [int(np.flatnonzero(df["run"] == "b")[20]), int(np.flatnonzero(df["run"] == "e")[33])]
    df.loc[bad, "capsule_mm"] += [3.0, -4.0]
    path = tmp_path / "glitch_synthetic.csv"
    df.to_csv(path, index=False)
    return df, bad, path, _model(tmp_path, "tbase", params={"Pf_N": FREE_PF}, kind="trajectory", protocol=None)


def test_compare_says_what_the_frames_it_misses_grossly_do_to_its_numbers(tmp_path):
    """compare keeps every row in the numbers it reports (the ledger compares models on the same rows), but the
    rows its one model misses grossly (outlier_rows) are named with the held-out error and noise of the model
    refitted without them. Measured on these data before: held out at 0.322 mm against a noise bound of 0.322 mm
    ("within about 2 noise SDs ... in every response regime"; generating 0.05), nothing pointing at the two
    frames; now the same two numbers, and without the two frames 0.0469 against 0.0470."""
    df, bad, path, base = _glitched_null_runs(tmp_path)
    met = DL.run_compare(base, df, str(path), tmp_path / "gcmp", None, k_folds=3, seed=7, figures=False,
                         budget=QUICK)
    out = met["outliers"]
    assert [o["row"] for o in out["rows"]] == bad and out["n"] == met["n"] - 2
    assert met["noise_sd"] > 4 * POS_NOISE  # the numbers reported keep the two frames
    assert 0.8 * POS_NOISE < out["noise_sd"] < 1.25 * POS_NOISE and out["cv_rmse"] < 1.5 * POS_NOISE, out
    assert met["where_it_fails"].startswith(f"2 of the rows (row {bad[0]} (run b, t = {df['time_s'][bad[0]]:g} s)")
    # the same runs without the two errors: nothing flagged
    clean = df.copy()
    clean.loc[bad, "capsule_mm"] -= [3.0, -4.0]
    met = DL.run_compare(base, clean, str(path), tmp_path / "ccmp", None, k_folds=3, seed=7, figures=False,
                         budget=QUICK)
    assert met["outliers"] is None and met["noise_sd"] < 1.25 * POS_NOISE


def test_trajectory_frames_a_tracker_got_wrong_are_left_out_not_read_as_an_effect(tmp_path):
    """Two frames of six null runs put 3 and 4 mm off (a tracking error): diagnose flags them (generalized ESD on
    the best fit's frames, outlier_rows), reports them at their rows in the table, leaves them out and diagnoses
    the runs again. Measured on these data before: "adding viscous_drag cuts held-out RMSE from 0.322 to 0.317 mm
    (F test p = 0.00119)", a false finding, against a noise bound of 0.316 mm (generating 0.05) from the residuals
    the two frames inflated."""
    df, bad, path, base = _glitched_null_runs(tmp_path)
    r = DL.run_diagnose(base, df, str(path), tmp_path / "gdiag", k_folds=3, seed=7, figures=False, budget=QUICK,
                        candidates=CANDIDATES)
    assert r["verdict"]["outcome"] == "nothing_missing", r["verdict"]["message"]
    assert [o["row"] for o in r["outliers"]] == bad and r["n_rows"] == r["n"] + 2
    assert [o["time_s"] for o in r["outliers"]] == [df["time_s"][i] for i in bad]
    # the residual there under the model that flagged them: the tracking error, to the noise
    assert [round(o["residual"]) for o in r["outliers"]] == [3, -4]
    assert 0.8 * POS_NOISE < r["noise"]["sd"] < 1.25 * POS_NOISE, r["noise"]["method"]
    assert "a trajectory frame compared by position" in r["rule"]
    # diagnosis.md says where to look in the video
    md = (tmp_path / "gdiag" / "diagnosis.md").read_text()
    assert f"row {bad[0]} (run b, t = {df['time_s'][bad[0]]:g} s; " in md
    # runs from rest at phase 0: no progression protocol (transient and recorded periods) is said to apply
    assert "- Runs: each from rest at drive phase 0" in md and "- Protocol:" not in md


# the benchmark's runs3 design (benchmarks/dynamics_loop_calibration.py): its 24 Hz run's steady response is
# irregular for the model as is, and its path from rest unpredictable within 3 periods: one average-velocity row
RUNS3 = pd.DataFrame({"run": ["a", "b", "c"], "f_Hz": [24.0, 32.0, 40.0], "Pd_N": [0.15, 0.20, 0.25],
                      "duration_s": [0.6] * 3})


def _runs3_fit(tmp_path, df):
    """The model as is (P_f free) fitted to runs3 data, modes chosen as diagnose does: a SimpleNamespace fit."""
    base = _model(tmp_path, "tbase3", params={"Pf_N": FREE_PF}, kind="trajectory", protocol=None)
    b0 = DL.DynBound(base, df)
    fit = DL.calibrate(b0, b0.observed(), 0.1, None, None, QUICK, 0)
    b = DL.DynBound(base, df, modes=DL.choose_modes(b0, fit.theta))
    fit = DL.calibrate(b, b.observed(), 0.1, None, fit.theta, QUICK, 0)
    sim = b.simulate(fit.theta, starts=True)
    y = b.observed()
    return SimpleNamespace(y=y, pred=sim["pred"], resid=y - sim["pred"], k=1, sim=sim, bound=b, theta=fit.theta)


def test_a_frame_a_runs_drift_is_taken_from_is_flagged_when_a_tracker_got_it_wrong(tmp_path):
    """A run compared by its average velocity is one row, its drift x(T) - x(0), which only the frames around 0
    and T move, each by its full size (drift_weights). Those frames are compared with the model's path from rest
    (drift_frame_outliers): the first frame 3 mm off and one at T 2.5 mm off are flagged, at their table rows,
    with their errors; the same runs without them flag nothing. Before, no frame of such a run could be flagged:
    a first frame 2.6-3.7 mm off gave "not built in, time_s" in 2 of 40 null data sets
    (benchmarks/dynamics_loop_calibration_trajectory_glitch_result.json, session 34)."""
    truth = _model(tmp_path, "ttruth3", params={"Pf_N": 0.02}, kind="trajectory", protocol=None)
    df = DL.synthesize_trajectory(truth, RUNS3, 0.1, 100.0, 3)
    clean = _runs3_fit(tmp_path, df)
    assert clean.bound.modes["a"] == "average_velocity"
    assert DL.outlier_rows([clean]) == []
    a = np.flatnonzero(df["run"] == "a")
    w = DL.drift_weights(df.loc[a, "time_s"].to_numpy(float), 24.0)
    assert w[0] == -1.0 and np.count_nonzero(w) == 3  # T = 14 / 24 s between the frames at 0.58 and 0.59 s
    bad = [int(a[0]), int(a[np.flatnonzero(w)[-1]])]
    df.loc[bad, "capsule_mm"] += [3.0, -2.5]
    out = DL.outlier_rows([_runs3_fit(tmp_path, df)])
    assert [o["row"] for o in out] == bad and all(o["drift_frame"] for o in out)
    assert [o["residual"] for o in out] == pytest.approx([3.0, -2.5], abs=0.35)  # the error, to the noise
    assert all(o["z"] > 4 * o["threshold"] for o in out)


def test_a_frame_a_runs_drift_is_taken_from_is_left_out_not_read_as_an_effect(tmp_path):
    """The benchmark's null seed 18 (runs3, two frames off: the 24 Hz run's first by -3.70 mm, a frame of the
    32 Hz run compared by position by -4.33 mm). Measured before with these candidates: "the data cannot tell"
    (f_Hz or Pd_N), only the second frame flagged, noise 0.108 mm; with every candidate "an effect that is not
    built in depends on time_s". Now both are flagged and left out: nothing is missing. (In the benchmark's data
    set the frequency probe, which bends the 24 Hz run's drift to the first frame, fitted best; the frames around
    T it put off its path were not flagged, as the model as is with a shift at the first frame accounts for them.)
    """
    truth = _model(tmp_path, "ttruth3", params={"Pf_N": 0.02}, kind="trajectory", protocol=None)
    df = DL.synthesize_trajectory(truth, RUNS3, 0.1, 100.0, 10_018)
    bad = [0, 71]
    assert df.loc[bad, "run"].tolist() == ["a", "b"]
    df.loc[bad, "capsule_mm"] += [-3.696, -4.33]
    path = tmp_path / "glitch3_synthetic.csv"
    df.to_csv(path, index=False)
    base = _model(tmp_path, "tbase3", params={"Pf_N": FREE_PF}, kind="trajectory", protocol=None)
    r = DL.run_diagnose(base, df, str(path), tmp_path / "g3", k_folds=3, seed=18, figures=False, budget=QUICK,
                        candidates=CANDIDATES)
    assert r["verdict"]["outcome"] == "nothing_missing", r["verdict"]["message"]
    assert [o["row"] for o in r["outliers"]] == bad and [o.get("drift_frame", False) for o in r["outliers"]] == [
        True, False]
    assert 0.8 * 0.1 < r["noise"]["sd"] < 1.25 * 0.1, r["noise"]["method"]
    assert "takes its drift from" in r["rule"]
    md = (tmp_path / "g3" / "diagnosis.md").read_text()
    assert "row 0 (run a, t = 0 s, an end of its drift; " in md


def test_a_frame_left_out_is_drawn_against_the_model_the_other_frames_are_drawn_against(tmp_path):
    """drawn_left_out: the residual figure of diagnose draws the model as is's residuals; a frame left out as an
    outlier (flagged under another model) is drawn at its residual under the model as is, its run simulated from
    rest to the frame's time, the same value as the frame's residual when it is a comparison row (to 1e-9 mm).
    Before, it was drawn at the flagging model's residual (the tracking error alone): in a 4-run CLI diagnose a
    2.5 mm error sat at +2.7 mm beside the model as is's frames at +4.3 mm."""
    truth = _model(tmp_path, "ttruth_drawn", params={"Pf_N": 0.02}, kind="trajectory", protocol=None)
    df = DL.synthesize_trajectory(truth, TRAJ_DESIGN.iloc[:2], POS_NOISE, 100.0, 3)
    base = _model(tmp_path, "tbase", params={"Pf_N": FREE_PF}, kind="trajectory", protocol=None)
    theta = np.array([0.013])
    whole = DL.DynBound(base, df)
    residual = whole.observed() - whole.simulate(theta, classify=False)["pred"]
    left = [25, 60]  # a frame of run a, one of run b
    kept = DL.DynBound(base, df.drop(index=left).reset_index(drop=True))
    recs = [{"row": i, "residual": 3.0, **df.iloc[i].to_dict()} for i in left]
    drawn = DL.drawn_left_out(SimpleNamespace(bound=kept, theta=theta), recs)
    assert [o["residual"] for o in drawn] == pytest.approx(residual[left], abs=1e-9)
    assert np.all(np.abs(residual[left] - 3.0) > 0.5)  # not the flagging model's
    # a progression reading run from rest: its condition simulated alone, the value it has in the whole table; a
    # reading of a continuation sweep keeps the residual it was flagged with (its condition has a history)
    truth_p = _model(tmp_path, "ptruth_drawn", params={"Pf_N": 0.02})
    dp = DL.synthesize_progression(truth_p, DESIGN, NOISE, 1, 3)
    for start, drawn_at in (("rest", "model"), ("up", "flagged")):
        model = _model(tmp_path, f"pbase_{start}", params={"Pf_N": FREE_PF}, protocol=PROTO | {"start": start})
        whole = DL.DynBound(model, dp)
        residual = whole.observed() - whole.simulate(theta, classify=False)["pred"]
        kept = DL.DynBound(model, dp.drop(index=[1, 4]).reset_index(drop=True))
        recs = [{"row": i, "residual": -9.0, **dp.iloc[i].to_dict()} for i in (1, 4)]
        drawn = [o["residual"] for o in DL.drawn_left_out(SimpleNamespace(bound=kept, theta=theta), recs)]
        assert drawn == (pytest.approx(residual[[1, 4]], abs=1e-9) if drawn_at == "model" else [-9.0, -9.0])


def test_only_frames_compared_by_position_can_be_flagged():
    """outlier_rows on a trajectory fit (no engine): a frame's comparison row is reported at its row in the table
    (bound.rows), and a run's average-velocity row, which holds every frame of that run, is never flagged."""
    rng = np.random.default_rng(2)
    n = 60
    y = rng.normal(0.0, 0.1, n + 1)
    pred = np.zeros(n + 1)
    y[[10, n]] += [2.0, 2.0]  # a frame, and the drift row of run b
    rows = [("position", "a", 100 + i) for i in range(n)] + [("average_velocity", "b", 500)]
    sim = {"pred": pred, "cls": np.array(["one_impact"] * (n + 1)), "spread": np.zeros(n + 1),
           "noise_factor": np.ones(n + 1)}
    ev = SimpleNamespace(y=y, pred=pred, resid=y - pred, k=1, sim=sim,
                         bound=SimpleNamespace(kind="trajectory", rows=rows, model=SimpleNamespace(effect_names=[])))
    assert [o["row"] for o in DL.outlier_rows([ev])] == [110]
    assert DL.flaggable(ev, 0.1).tolist() == [True] * n + [False]


def test_a_dynamics_plugin_registered_for_one_kind_is_an_effect_of_both(tmp_path):
    # progression speeds and trajectories share the equations of motion (as the built-in effects are, a plugin
    # is registered for both): before, a plugin of kind "trajectory" failed in every trajectory model (the
    # system looked it up as a progression effect) and one of kind "progression" in every trajectory model file
    plugin = tmp_path / "coil_t.py"
    plugin.write_text(PLUGIN.replace('kind="progression"', 'kind="trajectory"'))
    _register(plugin)
    try:
        for kind in ("progression", "trajectory"):
            eff = registry.get_effect(kind, "coil_rolloff")
            assert eff.kind == kind and eff.origin == "plugin coil_t.py"
        truth = _model(tmp_path, "truth_t", ["coil_rolloff"], {"Pf_N": 0.02, "rolloff": 0.3}, kind="trajectory",
                       protocol=None)
        df = DL.synthesize_trajectory(truth, TRAJ_DESIGN.iloc[:2], 0.0, 100.0, 0)
        plain = DL.synthesize_trajectory(_model(tmp_path, "plain_t", (), {"Pf_N": 0.02}, kind="trajectory",
                                                protocol=None), TRAJ_DESIGN.iloc[:2], 0.0, 100.0, 0)
        # at 30 Hz the roll-off is zero (the same track), at 34 Hz the drive is 12 % weaker
        a, b = df["run"] == "a", df["run"] == "b"
        np.testing.assert_allclose(df.loc[a, "capsule_mm"], plain.loc[a, "capsule_mm"], atol=1e-12)
        assert np.abs(df.loc[b, "capsule_mm"] - plain.loc[b, "capsule_mm"]).max() > 0.1
    finally:
        registry.unregister_effect("trajectory", "coil_rolloff")
        registry._LOADED_PLUGINS.discard(str(plugin.resolve()))
    assert all((k, "coil_rolloff") not in registry._EFFECTS for k in ("progression", "trajectory"))


def test_trajectory_effect_not_built_in_named_by_its_covariate_then_fitted_to_noise(tmp_path):
    # a coil whose force rolls off with frequency, not built in: no built-in candidate explains the runs (a
    # secondary constraint came closest: held-out 1.31 -> 0.89 mm against the 0.05 mm noise, and was named as
    # the missing effect before the probes were fitted on trajectories); the drive probe on f_Hz names the
    # covariate. Seeds 0-3: named f_Hz, probe held out 0.20-0.22 mm; with the plugin 0.044-0.054 mm.
    plugin = tmp_path / "coil.py"
    plugin.write_text(PLUGIN)
    _register(plugin)
    try:
        truth = _model(tmp_path, "ttruth_roll", ["coil_rolloff"], {"Pf_N": 0.02, "rolloff": 0.3}, kind="trajectory",
                       protocol=None)
        df = DL.synthesize_trajectory(truth, TRAJ_DESIGN, POS_NOISE, 100.0, 2)
    finally:
        _unregister(plugin)
    path = tmp_path / "roll_synthetic.csv"
    df.to_csv(path, index=False)
    base = _model(tmp_path, "tbase", params={"Pf_N": FREE_PF}, kind="trajectory", protocol=None)
    r = DL.run_diagnose(base, df, str(path), tmp_path / "tdiag", k_folds=3, seed=2, figures=False, budget=QUICK,
                        candidates=CANDIDATES)
    v = r["verdict"]
    assert v["outcome"] == "not_built_in" and v["missing_effect"] is None and v["covariate"] == "f_Hz", v["message"]
    probe = next(p for p in r["covariate_probes"] if p["covariate"] == "f_Hz")
    assert probe["passes"] and probe["cv_rmse"] < 0.5 * min(c["cv_rmse"] for c in r["candidates"])
    # the plugin written and added: the runs held out at the position noise, the roll-off recovered
    _register(plugin)
    try:
        fixed = _model(tmp_path, "twith_plugin", ["coil_rolloff"],
                       {"Pf_N": FREE_PF, "rolloff": {"value": 0.1, "free": True, "bounds": [0.0, 0.9]}},
                       kind="trajectory", protocol=None)
        met = DL.run_compare(fixed, df, str(path), tmp_path / "tcmp", None, k_folds=3, seed=2, figures=False,
                             budget=QUICK)
    finally:
        _unregister(plugin)
    assert met["cv_rmse_not_irregular"] <= 1.2 * POS_NOISE
    assert abs(met["params"]["rolloff"]["value"] - 0.3) < 0.02


def _runs_with_friction_by_temperature(tmp_path, slope_per_C, seed):
    """TRAJ_DESIGN's runs, each recorded at its own tissue temperature, the friction level
    P_f = 0.02 N (1 + slope (T - 37 C)) run by run: an effect that is not built in (each run synthesised with its
    own P_f, the column added as a lab's table would carry it)."""
    temps = [33.0, 41.0, 37.0, 39.0, 35.0, 36.0]
    parts = []
    for k, temp in enumerate(temps):
        truth = _model(tmp_path, f"t_run{k}", params={"Pf_N": 0.02 * (1 + slope_per_C * (temp - 37.0))},
                       kind="trajectory", protocol=None)
        d = DL.synthesize_trajectory(truth, TRAJ_DESIGN.iloc[[k]], POS_NOISE, 100.0, 100 * seed + k)
        parts.append(d.assign(temperature_C=temp))
    df = pd.concat(parts, ignore_index=True)
    path = tmp_path / "temperature_synthetic.csv"
    df.to_csv(path, index=False)
    return df, str(path)


def test_a_runs_friction_probe_scales_that_runs_friction_level_only(tmp_path):
    from capsule_cli.effects.dynamics import column_friction_probe

    df, _ = _runs_with_friction_by_temperature(tmp_path, 0.0, 0)
    base = _model(tmp_path, "tbase_fr", params={"Pf_N": FREE_PF}, kind="trajectory", protocol=None)
    probe = column_friction_probe("temperature_C", 37.0, 4.0)
    b = DL.DynBound(base.with_effect(probe), df)
    theta = np.array([0.02, 0.5])  # P_f at 37 C, slope b per 4 C
    sysm = b.system(theta)
    def pf(temp):
        return float(0.02 * np.exp(0.5 * (temp - 37.0) / 4.0))

    for run, temp in (("a", 33.0), ("b", 41.0), ("c", 37.0)):
        assert b.run_system(sysm, theta, run).Pf_N == pytest.approx(pf(temp), rel=1e-12)
    # the runs' paths are the base model's at each run's friction level
    pred = b.simulate(theta, classify=False)["pred"]
    rows = b.row_frame()
    for run, temp in (("b", 41.0), ("e", 35.0)):
        alone = _model(tmp_path, f"alone_{run}", params={"Pf_N": pf(temp)}, kind="trajectory", protocol=None)
        ref = DL.DynBound(alone, df[df["run"] == run]).simulate(None, classify=False)["pred"]
        np.testing.assert_allclose(pred[(rows["run"] == run).to_numpy()], ref, atol=1e-9)
    # a column that changes within a run is no run's friction level
    bad = df.assign(temperature_C=np.arange(len(df), dtype=float))
    with pytest.raises(InputError, match="changes within a run"):
        DL.DynBound(base.with_effect(probe), bad)


def test_trajectory_friction_set_by_a_run_column_names_that_column(tmp_path):
    # the runs' friction level rises by 4 % per degree of the tissue temperature recorded beside each run; no
    # built-in candidate explains it (held out 0.59-0.60 mm against the model as is's 0.50). Before the probes
    # were fitted on trajectories the verdict was "the data cannot tell", the misfit put down to correlated
    # sensor noise (noise bound 0.44 mm against the generating 0.05); now the temperature's friction probe is
    # named and held out at 0.062 mm (seed 0; seeds 1-3: 0.067, 0.058, 0.070, slope 0.152-0.156)
    df, path = _runs_with_friction_by_temperature(tmp_path, 0.04, 0)
    base = _model(tmp_path, "tbase_t", params={"Pf_N": FREE_PF}, kind="trajectory", protocol=None)
    r = DL.run_diagnose(base, df, path, tmp_path / "tdiag_t", k_folds=3, seed=0, figures=False, budget=QUICK,
                        candidates=CANDIDATES)
    v = r["verdict"]
    assert v["outcome"] == "not_built_in" and v["covariate"] == "temperature_C", v["message"]
    probe = next(p for p in r["covariate_probes"] if p["covariate"] == "temperature_C")
    assert probe["cv_rmse"] <= 1.5 * POS_NOISE and r["noise"]["sd"] <= 1.2 * POS_NOISE
    # the probe's level is exp(b (T - 36.5 C) / 4 C) (the runs' median and half range); the truth's log level rises
    # by ln(1.16) = 0.148 from 37 to 41 C and by ln(1 / 0.84) = 0.174 from 33 to 37 C (seeds 0-3: b 0.152-0.156)
    assert 0.13 < probe["params"]["friction_temperature_slope"]["value"] < 0.19


def test_unknown_candidate_is_bad_input(tmp_path):
    from capsule_cli.errors import InputError

    base = _model(tmp_path, "base", params={"Pf_N": FREE_PF})
    df = pd.DataFrame({"f_Hz": [30.0, 34.0], "Pd_N": [0.08, 0.08], "velocity_mm_s": [0.0, 17.0]})
    with pytest.raises(InputError, match="not applicable"):  # before any calibration
        DL.run_diagnose(base, df, "x.csv", tmp_path / "d", k_folds=2, figures=False, budget=QUICK,
                        candidates=["no_such_effect"])
    assert not (tmp_path / "d").exists()


def test_axis_scan_moves_one_parameter_at_a_time():
    u0 = np.array([0.3, 0.7, 0.1])
    pts = DL.axis_scan(u0, 3, 4)
    assert len(pts) == 12
    for i, u in enumerate(pts):
        moved = np.flatnonzero(u != u0)
        assert set(moved) <= {i // 4}  # only parameter i // 4 moves
        assert u[i // 4] == pytest.approx((i % 4 + 0.5) / 4)


def test_box_map_is_logarithmic_above_log_from_and_unchanged_for_the_others():
    """A parameter with ``log_from`` r: equal steps of the box coordinate multiply theta - lo + r by the same
    factor (every decade above r alike); the others keep theta = lo + span u^2 (non-negative, a decade or more)
    or the linear map; to_u inverts to_theta."""
    par = lambda lf=None: SimpleNamespace(log_from=lf)  # noqa: E731
    bound = SimpleNamespace(bounds=(np.array([0.0, 0.05, -2.0]), np.array([5000.0, 1.25, 2.0])),
                            free=[SimpleNamespace(param=par(1.0)), SimpleNamespace(param=par()),
                                  SimpleNamespace(param=par())])
    to_theta, to_u = DL.box_map(bound)
    us = np.linspace(0.0, 1.0, 11)
    th = np.array([to_theta(np.full(3, u)) for u in us])
    assert th[0] == pytest.approx([0.0, 0.05, -2.0]) and th[-1] == pytest.approx([5000.0, 1.25, 2.0])
    ratios = (th[1:, 0] + 1.0) / (th[:-1, 0] + 1.0)
    assert ratios == pytest.approx(np.full(10, 5001.0 ** 0.1), rel=1e-12)
    assert th[:, 1] == pytest.approx(0.05 + 1.2 * us ** 2, rel=1e-14)
    assert th[:, 2] == pytest.approx(-2.0 + 4.0 * us, abs=1e-14)
    x = np.array([8.778, 0.25, 0.3])
    assert to_theta(to_u(x)) == pytest.approx(x, rel=1e-12)


def test_speed_law_box_holds_the_seeds_laws_and_the_nested_drag_inside():
    """The speed law's box holds seed 000's Case 1 and Case 4 fits (eqs 17-18: a = 8.778 and 1539 mN, n = 0.25),
    the viscous drag it nests at n = 1 and a steeper law (n = 1.5, named with the box to 2 and not with a box to
    1.25: session 23) strictly inside (an edge would rank the fit as strained), and its rise a is mapped
    logarithmically from below Case 1's rise (configs/params/friction_laws_dynamics.yaml)."""
    for kind in ("progression", "trajectory"):
        eff = registry.get_effect(kind, "speed_dependent_friction")
        a, n = (next(p for p in eff.params if p.name == nm) for nm in ("a_mN", "n"))
        assert a.bounds[0] == 0.0 and a.bounds[1] > 1539.0 and a.log_from is not None and 0 < a.log_from < 8.778
        assert n.bounds[0] < 0.25 and n.bounds[1] > 1.5


# four 1 s runs (the design of configs/designs/trajectory_runs.csv)
FOUR_RUNS = pd.DataFrame({"run": ["r1", "r2", "r3", "r4"], "f_Hz": [25.0, 30.0, 35.0, 38.0],
                          "Pd_N": [0.15, 0.15, 0.2, 0.2], "duration_s": [1.0] * 4})


def _speed_law_trajectories(tmp_path):
    """Return (data, base model with P_f free, truth): a speed law a = 4 mN, n = 0.7 hidden in FOUR_RUNS at
    100 frames/s with 0.1 mm noise."""
    truth = _model(tmp_path, "tsdf", ["speed_dependent_friction"], {"Pf_N": 0.02, "a_mN": 4.0, "n": 0.7},
                   kind="trajectory", protocol=None)
    df = DL.synthesize_trajectory(truth, FOUR_RUNS, 0.1, 100.0, 5)
    return df, _model(tmp_path, "tbase", params={"Pf_N": FREE_PF}, kind="trajectory", protocol=None), truth


def test_trajectory_speed_law_fit_finds_its_valley(tmp_path):
    """A hidden speed law a = 4 mN, n = 0.7 (four 1 s runs at 100 frames/s, 0.1 mm noise; the design of
    configs/designs/trajectory_runs.csv): its fit from the effect's start (a = 8.778 mN, n = 0.25) follows the
    long valley of equal force over the measured speeds; before the one-at-a-time scan through the start it
    ended at the box edge n = 0.05 (RMSE 2.3 mm). Now at the truth and the noise (measured 0.100 mm)."""
    df, base, _ = _speed_law_trajectories(tmp_path)
    eff = next(e for e in all_effects("trajectory") if e.name == "speed_dependent_friction")
    b = DL.DynBound(base.with_effect(eff), df)
    y = b.observed()
    fit = DL.calibrate(b, y, 0.1, None, None, DL.EFFORTS["full"], 0, extra_starts=[[0.03, 0.0, 0.25]])
    r = y - b.simulate(fit.theta)["pred"]
    assert float(np.sqrt(np.nanmean(r ** 2))) < 0.12  # noise 0.1 mm
    assert fit.theta[2] == pytest.approx(0.7, abs=0.03) and fit.theta[1] == pytest.approx(4.0, rel=0.1)


def test_trajectory_modes_follow_the_best_fitting_model(tmp_path):
    """Whether a run is compared by positions or by its average velocity is a property of the measured
    run, taken from the best-fitting model tried, not from the model as is: a one-sided base at P_f = 0.01 N
    is irregular at three of the four runs of configs/designs/trajectory_runs.csv, while the speed law that
    made the data (a = 4 mN, n = 0.7) is periodic at all four (the base fitted in position mode to these
    data ended irregular at every run: one average-velocity row per run, and diagnose named viscous drag).
    Of the base's three irregular runs, r3's path from rest is predictable over its second (starts 1-10 um
    from rest stay within 0.015 mm of it, measured) and is compared by position; r1 and r4 part by 6.6 and
    0.16 mm (r4 keeps its frames up to its predictability horizon)."""
    df, base, truth = _speed_law_trajectories(tmp_path)
    bb = DL.DynBound(base, df)
    summ = bb.run_summary(np.array([0.01]))
    assert [r for r, s in summ.items() if s["response_class"] == "irregular"] == ["r1", "r3", "r4"]
    assert bb.start_spread_mm(np.array([0.01]), "r3") < DL.PREDICTABLE_SPREAD_MM
    assert bb.start_spread_mm(np.array([0.01]), "r4") > 2 * DL.PREDICTABLE_SPREAD_MM
    # r4's path stays predictable for its first 0.09 s (3.4 periods at 38 Hz): those frames are compared by position,
    # with its average velocity; r1's starts part within 3 periods: its average velocity only
    irregular = {"r1": "average_velocity", "r4": DL.position_until(0.09), "r2": "position", "r3": "position"}
    assert DL.choose_modes(bb, np.array([0.01])) == irregular
    sp, t4 = bb.start_spread_path(np.array([0.01]), "r4"), dict(bb.runs)["r4"]["time_s"].to_numpy()
    assert np.all(sp[t4 <= 0.09 + 1e-9] <= DL.PREDICTABLE_SPREAD_MM) and sp[t4 > 0.09 + 1e-9][0] > DL.PREDICTABLE_SPREAD_MM
    bt = DL.DynBound(truth, df)
    y = bt.observed()

    def ev(bound, theta):
        pred = bound.simulate(theta)["pred"]
        return SimpleNamespace(bound=bound, theta=theta, pred=pred, resid=y - pred)

    e_base, e_truth = ev(bb, np.array([0.01])), ev(bt, None)
    modes, who = DL.modes_of_best(e_base, [{"effect": SimpleNamespace(name="speed_dependent_friction"), "ev": e_truth}])
    assert who == "speed_dependent_friction" and set(modes.values()) == {"position"}
    # and the other way round: the best model decides, whichever it is
    modes, who = DL.modes_of_best(e_truth, [{"effect": SimpleNamespace(name="x"), "ev": e_base}])
    assert who == "the model as is" and set(modes.values()) == {"position"}
    modes, who = DL.modes_of_best(e_base, [])
    assert who == "the model as is" and modes == irregular
    # two fits the data cannot rank (equal residuals): a run is compared by position if either is periodic there
    tie = SimpleNamespace(bound=bb, theta=np.array([0.01]), pred=e_truth.pred, resid=e_truth.resid)
    modes, who = DL.modes_of_best(tie, [{"effect": SimpleNamespace(name="speed_dependent_friction"), "ev": e_truth}])
    assert set(modes.values()) == {"position"} and "speed_dependent_friction" in who and "model as is" in who


def test_trajectory_noise_replicates_only_between_runs_at_one_drive(tmp_path):
    """Frames at the same time in runs at other drives are not replicates (before: 4 runs at 4 drives,
    0.1 mm noise, gave 'replicates' and 8.5 mm, the spread of four different motions); two runs at one drive
    from rest are (the same motion, the camera's noise apart). Without replicates the difference-based
    estimate is only a bound (frames undersample the motion) and says so."""
    truth = _model(tmp_path, "tnull", params={"Pf_N": 0.02}, kind="trajectory", protocol=None)
    four = FOUR_RUNS
    df = DL.synthesize_trajectory(truth, four, 0.1, 100.0, 5)
    noise = DL.noise_of(DL.DynBound(truth, df))
    assert not noise["method"].startswith("replicates") and noise["reliable"] is False
    twice = pd.concat([four, four.assign(run=["s1", "s2", "s3", "s4"])], ignore_index=True)
    df2 = DL.synthesize_trajectory(truth, twice, 0.1, 100.0, 5)
    noise2 = DL.noise_of(DL.DynBound(truth, df2))
    assert noise2["method"].startswith("replicates") and noise2["reliable"] is True
    assert noise2["sd"] == pytest.approx(0.1, rel=0.1)  # 404 pairs: SE about 3.5 %


def _fake_ev(y, pred, cv_pred, k, groups, values=None):
    """An evaluation as probe_verdict reads it: rss, k, y, cv_sq, cv_rmse, groups, bound.values."""
    cv_sq = (y - cv_pred) ** 2
    cv, se = crossval.cv_rmse(cv_sq, groups)
    return SimpleNamespace(y=y, k=k, rss=float(np.sum((y - pred) ** 2)), cv_sq=cv_sq, groups=groups,
                           cv_rmse=cv, cv_rmse_se=se, folds=np.asarray(groups) % 5, theta=None,
                           bound=SimpleNamespace(values=lambda th: dict(values or {})))


def test_probe_verdict_names_the_covariate_only_when_the_probe_beats_every_built_in():
    """probe_verdict (no engine): a probe that passes its F test and beats the best built-in by more than
    PROBE_Z standard errors turns the verdict into 'not built in, depends on <covariate>'; one that is better
    by less, or whose F test fails, leaves the verdict as it was."""
    rng = np.random.default_rng(3)
    n = 40
    groups = np.arange(n)
    y = rng.normal(0.0, 1.0, n)
    miss = 5.0 * np.sin(np.arange(n))  # what the model as is misses
    yy = y + miss
    base = _fake_ev(yy, np.zeros(n), np.zeros(n), 1, groups)
    builtin = _fake_ev(yy, 0.5 * miss, 0.5 * miss, 2, groups)
    verdict = {"outcome": "missing_effect", "missing_effect": "viscous_drag", "covariate": None, "where": "w"}
    eff_f = SimpleNamespace(name="probe_f_Hz", covariates=("f_Hz",),
                            params=(SimpleNamespace(name="drive_f_scale"), SimpleNamespace(name="drive_f_exponent")))
    vals = {"drive_f_scale": 0.8, "drive_f_exponent": -0.4}
    cands = [{"effect": SimpleNamespace(name="viscous_drag"), "ev": builtin}]
    good = {"effect": eff_f, "ev": _fake_ev(yy, miss, miss, 3, groups, vals)}
    v = DL.probe_verdict(base, cands, [good], verdict, "mm/s")
    assert v["outcome"] == "not_built_in" and v["covariate"] == "f_Hz" and v["missing_effect"] is None
    assert v["closest"] == "viscous_drag" and "probe" in v["message"] and good["passes"] is True
    # barely better than the built-in: within PROBE_Z standard errors, the verdict stands
    wobble = 0.5 * miss + np.random.default_rng(1).normal(0.0, 0.3, n)
    near = {"effect": eff_f, "ev": _fake_ev(yy, wobble, wobble, 3, groups, vals)}
    d, se = crossval.paired_difference(builtin.cv_sq, near["ev"].cv_sq, groups)
    assert 0 < d < DL.PROBE_Z * se  # the premise: better, by less than PROBE_Z standard errors
    assert DL.probe_verdict(base, cands, [near], verdict, "mm/s") is verdict and near["passes"] is False
    # no better than the model as is (F test fails): the verdict stands
    none = {"effect": eff_f, "ev": _fake_ev(yy, np.zeros(n), np.zeros(n), 3, groups, vals)}
    assert DL.probe_verdict(base, [], [none], verdict, "mm/s") is verdict and none["passes"] is False


def test_probe_verdict_names_collinear_covariates_together_and_cannot_tell_which():
    """probe_verdict (no engine): when the winning probe's covariate moves with another in the data (|r| >=
    COLLINEAR_R, as the rule says for every covariate it names), the data cannot tell which one the missing
    effect depends on: outcome cannot_tell, both in ``confounded``, no covariate, and the message says what to
    measure. The same probe with a column that does not move with f_Hz names f_Hz, as before."""
    rng = np.random.default_rng(3)
    n = 40
    groups = np.arange(n)
    f = np.tile(np.linspace(15.0, 42.0, 10), 4)
    yy = rng.normal(0.0, 1.0, n) + 5.0 * np.sin(np.arange(n))
    miss = yy - rng.normal(0.0, 1.0, n)
    base = _fake_ev(yy, np.zeros(n), np.zeros(n), 1, groups)
    cands = [{"effect": SimpleNamespace(name="tilt_friction"), "ev": _fake_ev(yy, 0.5 * miss, 0.5 * miss, 2, groups)}]
    verdict = {"outcome": "nothing_missing", "missing_effect": None, "covariate": None, "where": "w",
               "confounded": []}
    eff = SimpleNamespace(name="probe_friction_f_Hz", covariates=("f_Hz",), role="friction",
                          params=(SimpleNamespace(name="friction_f_exponent"),))
    probe = {"effect": eff, "ev": _fake_ev(yy, miss, miss, 2, groups, {"friction_f_exponent": 0.55})}
    coil = 30.0 + 0.5 * (f - 15.0)  # a coil that warms as the frequency is stepped up
    v = DL.probe_verdict(base, cands, [probe], verdict, "mm/s",
                         covariates={"f_Hz": f, "coil_temperature_C": coil})
    assert probe["passes"] is True
    assert v["outcome"] == "cannot_tell" and v["covariate"] is None and v["missing_effect"] is None
    assert v["confounded"] == ["f_Hz", "coil_temperature_C"] and v["closest"] == "tilt_friction"
    assert "f_Hz or coil_temperature_C" in v["message"]
    assert "Measure with coil_temperature_C varied at fixed f_Hz" in v["message"]
    # nearly collinear counts too (r = 0.97), a column that does not move with f does not
    wobbly = coil + np.random.default_rng(0).normal(0.0, 1.0, n)
    assert 0.95 < np.corrcoef(f, wobbly)[0, 1] < 0.99
    v2 = DL.probe_verdict(base, cands, [probe], verdict, "mm/s", covariates={"f_Hz": f, "coil_temperature_C": wobbly})
    assert v2["outcome"] == "cannot_tell" and v2["confounded"] == ["f_Hz", "coil_temperature_C"]
    apart = np.random.default_rng(1).uniform(30.0, 40.0, n)
    assert abs(np.corrcoef(f, apart)[0, 1]) < 0.5
    v3 = DL.probe_verdict(base, cands, [probe], verdict, "mm/s", covariates={"f_Hz": f, "coil_temperature_C": apart})
    assert v3["outcome"] == "not_built_in" and v3["covariate"] == "f_Hz" and v3["confounded"] == []

def test_bootstrap_interval_is_the_fit_plus_t_standard_errors_in_box_coordinates(monkeypatch):
    """bootstrap_intervals with the refits stubbed (no engine): 5 resamples give the fit +- t(0.975, 4) = 2.776
    SDs of the refits, not their 2.5-97.5 percentiles (too narrow: they held a true coil roll-off in 8 of 12 noise
    seeds, the t interval in 12 of 12; bootstrap_intervals' docstring); inside the bounds; multiplicative for a
    parameter whose box is logarithmic (log_from)."""
    from scipy.stats import t as student_t

    lin = SimpleNamespace(key="rolloff", bounds=(-1.0, 1.0), param=SimpleNamespace(log_from=None))
    edge = SimpleNamespace(key="g", bounds=(-1.0, 1.0), param=SimpleNamespace(log_from=None))
    log = SimpleNamespace(key="a_mN", bounds=(0.0, 5000.0), param=SimpleNamespace(log_from=1.0))
    free = [lin, edge, log]
    bound = SimpleNamespace(free=free, bounds=(np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 5000.0])),
                            kind="progression")
    theta = np.array([0.3, 0.99, 100.0])
    rolloff = np.array([0.29, 0.30, 0.31, 0.30, 0.305])
    g = np.array([0.98, 0.99, 1.0, 0.97, 0.99])
    a = 100.0 * np.exp(np.array([-0.2, 0.1, 0.0, 0.2, -0.1]))  # spread by +-20 %
    draws = iter(np.column_stack([rolloff, g, a]))
    monkeypatch.setattr(DL.evaluation, "calibrate", lambda *args, **kw: SimpleNamespace(theta=next(draws)))
    groups = np.repeat(np.arange(6), 3)
    ev = SimpleNamespace(groups=groups, bound=bound, y=np.zeros(groups.size), sigma=1.0, theta=theta, k=3,
                         resid=np.zeros(groups.size),
                         fit=SimpleNamespace(weights=None),
                         sim={"pred": np.zeros(groups.size), "spread": np.zeros(groups.size),
                              "cls": np.array(["period_1"] * groups.size)})
    ci, se, how = DL.bootstrap_intervals(ev, 5, QUICK, 0)
    assert how.startswith("95 %: the fit +- t(0.975, n - 1) SDs of n = 5 parametric bootstrap refits")
    q = student_t.ppf(0.975, 4)
    assert q == pytest.approx(2.776, abs=1e-3)
    assert se["rolloff"] == pytest.approx(np.std(rolloff, ddof=1), rel=1e-12)
    assert ci["rolloff"] == pytest.approx([0.3 - q * se["rolloff"], 0.3 + q * se["rolloff"]], rel=1e-9)
    assert ci["rolloff"][0] < rolloff.min() and ci["rolloff"][1] > rolloff.max()  # wider than the percentiles
    assert ci["g"][1] == pytest.approx(1.0) and ci["g"][0] == pytest.approx(0.99 - q * np.std(g, ddof=1), rel=1e-9)
    # logarithmic box: u = log1p(a) / log1p(5000), so the interval is about 100 x exp(+-q x 0.158) for a's
    # log-SD 0.158, asymmetric in mN and above zero however wide
    lo, hi = ci["a_mN"]
    sd_log = np.std(np.log1p(a), ddof=1)
    assert np.log1p(lo) == pytest.approx(np.log1p(100.0) - q * sd_log, rel=1e-9)
    assert np.log1p(hi) == pytest.approx(np.log1p(100.0) + q * sd_log, rel=1e-9)
    assert 0 < lo and 100.0 - lo < hi - 100.0
    assert DL.bootstrap_intervals(ev, 1, QUICK, 0) == ({}, {}, "")


def test_an_interval_drawn_at_an_estimated_noise_allows_for_the_estimates_degrees_of_freedom(monkeypatch):
    """The bootstrap's draws are made at a noise SD that is itself estimated, and the SE scales with it: the t
    quantile takes nu from both (1 / nu = 1 / (n - 1) + 1 / noise_dof, Satterthwaite; interval_dof). Six
    conditions without replicates and one free parameter leave the noise 5 degrees of freedom: with 20 refits nu
    is 4.0 and t 2.78, not the refits' 2.09. Known noise (inf): the refits' n - 1 alone, as before. The fit's own
    residual SD, when it is above the noise estimate, has the rows less the parameters."""
    from scipy.stats import t as student_t

    assert DL.interval_dof(20, np.inf) == 19.0
    assert DL.interval_dof(20, 5.0) == pytest.approx(1.0 / (1.0 / 19.0 + 1.0 / 5.0), rel=1e-12)  # 3.96
    assert DL.interval_dof(20, 37.0) == pytest.approx(12.55, abs=0.01)  # the 40-condition grid, 3 parameters
    assert float(student_t.ppf(0.975, DL.interval_dof(20, 5.0))) == pytest.approx(2.78, abs=0.01)
    spec = SimpleNamespace(key="rolloff", bounds=(-1.0, 1.0), param=SimpleNamespace(log_from=None))
    bound = SimpleNamespace(free=[spec], bounds=(np.array([-1.0]), np.array([1.0])), kind="progression")
    rolloff = np.array([0.29, 0.30, 0.31, 0.30, 0.305])
    n_rows = 12

    def stub(resid):
        draws = iter(rolloff[:, None])
        monkeypatch.setattr(DL.evaluation, "calibrate", lambda *args, **kw: SimpleNamespace(theta=next(draws)))
        return SimpleNamespace(groups=np.arange(n_rows), bound=bound, y=np.zeros(n_rows), sigma=1.0,
                               theta=np.array([0.3]), k=1, resid=resid, fit=SimpleNamespace(weights=None),
                               sim={"pred": np.zeros(n_rows), "spread": np.zeros(n_rows),
                                    "cls": np.array(["period_1"] * n_rows)})

    sd = np.std(rolloff, ddof=1)
    for noise_dof, nu in ((np.inf, 4.0), (5.0, 1.0 / (1.0 / 4.0 + 1.0 / 5.0))):
        ci, _, how = DL.bootstrap_intervals(stub(np.zeros(n_rows)), 5, QUICK, 0, noise_dof=noise_dof)
        q = float(student_t.ppf(0.975, nu))
        assert ci["rolloff"] == pytest.approx([0.3 - q * sd, 0.3 + q * sd], rel=1e-9)
        assert ("t(0.975, n - 1) SDs" in how) == (noise_dof == np.inf)
    assert "t(0.975, 2.22) (the refits' n - 1 = 4 and the noise SD's 5 degrees of freedom combined)" in how
    # the fit misses the data (residual SD 2 against the noise estimate's 1): drawn at its own residual SD, whose
    # degrees of freedom are the 12 rows less 1 parameter, whatever the noise estimate's
    ci, _, how = DL.bootstrap_intervals(stub(np.full(n_rows, 2.0)), 5, QUICK, 0, noise_dof=np.inf)
    q = float(student_t.ppf(0.975, 1.0 / (1.0 / 4.0 + 1.0 / 11.0)))
    assert ci["rolloff"] == pytest.approx([0.3 - q * sd, 0.3 + q * sd], rel=1e-9)
    assert "the noise SD's 11 degrees of freedom" in how and "the fit's residual SD, above the noise estimate" in how


def test_intervals_come_from_the_fit_plus_the_noise(monkeypatch):
    """The refits (four runs here) are to the fit's predictions plus noise of each row's SD (a frame's noise; a
    drift's, its noise factor and the model's spread), not to resampled runs (whose SEs varied 200-fold over noise
    seeds: bootstrap_intervals' docstring), on the rows the fit predicts (an irregular run's drift, whose
    prediction is not smooth in the parameters, left out of the refits). With rho the noise of each run's frames
    compared by position is AR(1) along time."""
    rng = np.random.default_rng(0)
    n_run, m = 4, 400
    runs = np.repeat(np.array(["a", "b", "c", "d"]), m)
    rf = pd.DataFrame({"run": np.append(runs, "d"), "time_s": np.append(np.tile(np.arange(m) / 100.0, n_run), 4.0),
                       "compared": ["position"] * (n_run * m) + ["average_velocity"]})
    rf = rf.sample(frac=1.0, random_state=1).reset_index(drop=True)  # rows in any order: AR(1) along time
    drift = int(np.flatnonzero(rf["compared"] == "average_velocity")[0])
    n = len(rf)
    pred = rng.normal(0.0, 5.0, n)
    factor, spread, cls = np.ones(n), np.zeros(n), np.array(["period_1"] * n, dtype=object)
    factor[drift], spread[drift], cls[drift] = math.sqrt(2.0), 3.0, "irregular"
    sim = {"pred": pred, "spread": spread, "noise_factor": factor, "cls": cls}
    lin = SimpleNamespace(key="Pf_N", bounds=(0.0, 1.0), param=SimpleNamespace(log_from=None))
    bound = SimpleNamespace(free=[lin], bounds=(np.array([0.0]), np.array([1.0])), row_frame=lambda: rf,
                            kind="trajectory")
    ev = SimpleNamespace(groups=pd.factorize(rf["run"])[0], bound=bound, y=pred.copy(), sigma=0.3, k=1,
                         resid=rng.normal(0.0, 0.25, n), theta=np.array([0.5]), fit=SimpleNamespace(weights=None),
                         sim=sim)
    seen = []

    def refit(bound_, y, sigma, rows, *args, **kw):
        seen.append((np.asarray(y) - pred, rows))
        return SimpleNamespace(theta=np.array([0.5 + 0.01 * len(seen)]))

    monkeypatch.setattr(DL.evaluation, "calibrate", refit)
    ci, se, how = DL.bootstrap_intervals(ev, 5, QUICK, 0)
    assert "parametric" in how and "AR(1)" not in how and "SD 0.3 mm" in how
    assert "without the 1 row whose response is irregular or multistable at the fit" in how
    assert se["Pf_N"] == pytest.approx(np.std(0.5 + 0.01 * np.arange(1, 6), ddof=1))
    noise = np.array([e for e, _ in seen])
    frames = np.arange(n) != drift
    assert np.std(noise[:, frames]) == pytest.approx(0.3, rel=0.03)
    assert all(rows is not None and drift not in rows and len(rows) == n - 1 for _, rows in seen)
    # the drift row's draw: SD sqrt(0.3^2 x 2 + 3^2) = 3.03; white along time
    assert np.std(noise[:, drift]) > 1.0
    pos = rf.index[frames]
    order = rf.loc[pos].sort_values(["run", "time_s"]).index.to_numpy()
    lag1 = np.mean([np.corrcoef(e[order][:-1], e[order][1:])[0, 1] for e in noise])
    assert abs(lag1) < 0.05
    # AR(1) at 0.8 from frame to frame within each run, the same SD
    seen.clear()
    _, _, how = DL.bootstrap_intervals(ev, 5, QUICK, 0, rho=0.8)
    assert "AR(1) from frame to frame at 0.8" in how
    noise = np.array([e for e, _ in seen])
    assert np.std(noise[:, frames]) == pytest.approx(0.3, rel=0.1)
    within = [np.corrcoef(e[idx][:-1], e[idx][1:])[0, 1] for e in noise
              for idx in (order[k * m:(k + 1) * m] for k in range(n_run))]
    assert np.mean(within) == pytest.approx(0.8, abs=0.03)
    # a fit whose residuals exceed the noise estimate (a model that misses the data, the noise from replicates)
    # draws its noise at its own residual SD, so its intervals are not those of a right model
    ev.resid = rng.normal(0.0, 3.0, n)
    seen.clear()
    _, _, how = DL.bootstrap_intervals(ev, 5, QUICK, 0)
    s_fit = DL.standardised_residual_sd(ev)
    assert s_fit == pytest.approx(3.0, rel=0.05) and "the fit's residual SD, above the noise estimate" in how
    assert np.std(np.array([e for e, _ in seen])[:, frames]) == pytest.approx(s_fit, rel=0.03)


def test_bootstrap_draws_are_the_same_for_the_same_data_and_independent_between_data_sets(monkeypatch):
    """The bootstrap's noise comes from a stream seeded by the seed and the data (data_stream): the same data and
    seed give the same draws (reproducible), another data set (one value changed) independent ones. Seeded by the
    seed alone every data set drew the same 20 vectors, and a viscous drag's standard errors were 18 % low on
    all of them alike (218 of 240 intervals held the truth; data_stream's docstring)."""
    n = 200
    pred = np.linspace(-1.0, 1.0, n)
    lin = SimpleNamespace(key="Pf_N", bounds=(0.0, 1.0), param=SimpleNamespace(log_from=None))
    bound = SimpleNamespace(free=[lin], bounds=(np.array([0.0]), np.array([1.0])), kind="progression")
    seen = []

    def refit(bound_, y, *args, **kw):
        seen.append(np.asarray(y) - pred)
        return SimpleNamespace(theta=np.array([0.5 + 0.01 * len(seen)]))

    monkeypatch.setattr(DL.evaluation, "calibrate", refit)

    def draws(y, seed=0):
        ev = SimpleNamespace(groups=np.arange(n), bound=bound, y=y, sigma=0.5, k=1, resid=np.zeros(n),
                             theta=np.array([0.5]), fit=SimpleNamespace(weights=None),
                             sim={"pred": pred, "spread": np.zeros(n), "cls": np.array(["period_1"] * n)})
        seen.clear()
        DL.bootstrap_intervals(ev, 5, QUICK, seed)
        return np.array(seen)

    _assert_seeded_by_the_data(draws, pred + 0.5 * np.random.default_rng(3).standard_normal(n), 0.5, rel=0.05)


def _assert_seeded_by_the_data(draws, y, sd, rel):
    """Assert what data_stream promises of a bootstrap's noise draws (``draws(y, seed)``: the draws as rows):
    the same data and seed give the same draws, of SD ``sd`` (to ``rel``); one value changed by 1e-9 gives
    independent draws (|r| ~ 1 / sqrt(size); one shared stream gives 1); another seed gives other draws.
    Returns the draws on ``y`` at seed 0."""
    first, again = draws(y), draws(y.copy())
    assert np.array_equal(first, again)
    assert np.std(first) == pytest.approx(sd, rel=rel)
    y2 = y.copy()
    y2[7] += 1e-9
    r = np.corrcoef(first.ravel(), draws(y2).ravel())[0, 1]
    assert abs(r) < 4.0 / math.sqrt(first.size)
    assert not np.array_equal(draws(y, seed=1), first)
    return first


def _stub_bootstrap(monkeypatch, n):
    """Return (pred, make_ev(y, cv_sq), seen): held_out_of_truth with its refits stubbed (every fit at the
    truth, so a draw's held-out RMSE is its noise's RMS); ``seen`` collects each draw's noise."""
    pred = np.linspace(-1.0, 1.0, n)
    lin = SimpleNamespace(key="Pf_N", bounds=(0.0, 1.0), param=SimpleNamespace(log_from=None))
    seen = []

    def refit(bound_, y, sigma, train, *args, **kw):
        if train is None:  # the all-rows refit of each draw (the folds' refits follow warm from it)
            seen.append(np.asarray(y) - pred)
        return SimpleNamespace(theta=np.array([0.5]))

    monkeypatch.setattr(DL.evaluation, "calibrate", refit)
    bound = SimpleNamespace(free=[lin], kind="trajectory",
                            simulate=lambda th, rows, classify=False, y=None: {"pred": pred})

    def make_ev(y, cv_sq):
        return SimpleNamespace(bound=bound, y=y, sigma=0.5, theta=np.array([0.5]), fit=SimpleNamespace(weights=None),
                               folds=np.arange(n) % 3, cv_spread=None, sim={"pred": pred, "spread": np.zeros(n)},
                               cv_sq=cv_sq, cv_rmse=math.sqrt(float(np.mean(cv_sq))))
    return pred, make_ev, seen


def test_held_out_if_true_draws_are_the_same_for_the_same_data_and_independent_between_data_sets(monkeypatch):
    """The "held out if it were true" bootstrap (held_out_of_truth) draws from data_stream too: the same data and
    seed give the same draws, another data set independent ones. Seeded by ``seed + 7`` alone, every data set of a
    benchmark (the power benchmark passes seed 0 to all) drew the same 12 vectors, and with them the same error
    in the expectation its verdict is weighed against."""
    n = 120
    pred, make_ev, seen = _stub_bootstrap(monkeypatch, n)

    def draws(y, seed=0):
        seen.clear()  # the data held out below every draw: no more than the 6 asked for
        assert DL.held_out_of_truth(make_ev(y, np.zeros(n)), QUICK, seed, draws=6).draws == 6 and len(seen) == 6
        return np.array(seen)

    y = pred + 0.5 * np.random.default_rng(5).standard_normal(n)
    first = _assert_seeded_by_the_data(draws, y, 0.5, rel=0.1)  # 720 draws: the SD is known to 2.6 %
    # its own stream, not the intervals' (another salt) on the same data and seed
    assert np.allclose(first, DL.data_stream(0, y, 7).standard_normal((6, n)) * 0.5)
    assert not np.allclose(first, DL.data_stream(0, y, 1).standard_normal((6, n)) * 0.5)


def test_held_out_if_true_draws_on_while_the_data_are_above_every_draw(monkeypatch):
    """held_out_of_truth makes HELD_OUT_DRAWS draws, then more, up to MC_DRAWS (43) in all, only while the data's
    held-out RMSE is above every draw: the Monte Carlo test (verdict.design_excess) calls it an excess only above
    all 43, and the first draw as high settles that it is not. The first draws are the same however many follow."""
    n = 120
    pred, make_ev, seen = _stub_bootstrap(monkeypatch, n)
    y = pred + 0.5 * np.random.default_rng(6).standard_normal(n)
    far = DL.held_out_of_truth(make_ev(y, np.full(n, 1.0)), QUICK, 0)  # held out at 1 against draws near 0.5
    assert V.MC_DRAWS == 43 and far.draws == 43 and far.as_high(1.0) == 0
    assert far.p_value(1.0) == pytest.approx(1 / 44) and V.design_excess(far, 1.0)[0]
    v = np.array(far.values)
    assert np.allclose(v, np.sqrt(np.mean(np.array(seen) ** 2, axis=1)), rtol=1e-12)  # each draw's noise RMS
    assert 0.4 < v.min() and v.max() < 0.6
    # held out within the first 12 draws' range: those 12 only
    mid = float(np.median(v[:12]))
    assert DL.held_out_of_truth(make_ev(y, np.full(n, mid ** 2)), QUICK, 0).values == far.values[:12]
    # above the first 12, below a later one: on to the first draw as high, no further
    j = next(i for i in range(12, 43) if v[i] > v[:i].max())  # a later draw above all before it
    cv = 0.5 * (v[:j].max() + v[j])
    got = DL.held_out_of_truth(make_ev(y, np.full(n, cv ** 2)), QUICK, 0)
    assert got.values == far.values[:j + 1] and got.as_high(cv) == 1 and not V.design_excess(got, cv)[0]


def test_residual_figure_draws_a_drift_row_apart_from_the_frames(tmp_path):
    """A trajectory run compared by its drift over whole periods has one residual (35.8 mm here) that is not a
    frame's: the figure draws it in a panel of its own, so the frames' axis keeps the position residuals only."""
    t = np.arange(0.0, 0.5, 0.01)
    res = pd.DataFrame({"run": ["r1"] * t.size + ["r2"], "time_s": list(t) + [1.0],
                        "residual_capsule_mm": list(0.1 * np.sin(40 * t)) + [35.8],
                        "response_class": ["one_impact"] * t.size + ["irregular"],
                        "compared": ["position"] * t.size + ["average_velocity"]})
    fig = DL._plot_residuals(res, SimpleNamespace(bound=SimpleNamespace(kind="trajectory"), sigma=0.1),
                             tmp_path / "r.png", "test")
    frames_ax, drift_ax = fig.axes  # one run by position: no per-run row
    frame_y = np.concatenate([ln.get_ydata() for ln in frames_ax.get_lines()])
    assert np.max(np.abs(frame_y)) < 0.11
    assert [list(ln.get_ydata()) for ln in drift_ax.get_lines()][0] == [35.8]
    assert "drift" in drift_ax.get_ylabel() and "[mm]" in drift_ax.get_ylabel()
    # the run's drift in the irregular class's colour, as its frames are drawn (it was a fixed colour: that of
    # one_impact in a figure with both classes)
    from capsule_cli.plots.loop import _class_colours

    colour = _class_colours(DL.RESPONSE_CLASSES)
    one = [ln for ln in frames_ax.get_lines() if ln.get_label() == "one_impact"]
    assert one and one[0].get_color() == colour["one_impact"] != colour["irregular"]
    assert drift_ax.get_lines()[0].get_color() == colour["irregular"]
    assert (tmp_path / "r.png").stat().st_size > 0


def test_trajectory_residual_figure_has_a_row_of_run_drift_rates_by_drive_and_the_covariate_named(tmp_path):
    """The verdict names a run's drive or a column recorded per run; the figure shows each run's residual drift
    rate (the slope of its position residual over time) against f, P_d and that column, so the dependence it
    names is seen: here the model falls behind by 0.5 mm/s per Hz above 30 Hz."""
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 0.41, 0.01)
    runs = pd.DataFrame({"run": list("abcdef"), "f_Hz": [30.0, 34.0, 38.0] * 2, "Pd_N": [0.08] * 3 + [0.1] * 3,
                         "temperature_C": [33.0, 41.0, 37.0, 39.0, 35.0, 36.0]})
    parts = []
    for _, r in runs.iterrows():
        rate = 0.5 * (r["f_Hz"] - 30.0)  # [mm/s]
        parts.append(pd.DataFrame({"time_s": t, "residual_capsule_mm": 0.2 + rate * t + rng.normal(0, 0.05, t.size),
                                   "response_class": "one_impact", "compared": "position"}).assign(**r.to_dict()))
    res = pd.concat(parts, ignore_index=True)
    per_run = DL.run_residual_rates(res, "residual_capsule_mm", 0.05)
    assert list(per_run["run"]) == list("abcdef") and "time_s" not in per_run.columns
    assert list(per_run["temperature_C"]) == list(runs["temperature_C"])
    se = 0.05 / np.sqrt(np.sum((t - t.mean()) ** 2))
    assert np.allclose(per_run["rate_se_mm_s"], se) and se == pytest.approx(0.066, abs=0.001)
    assert np.all(np.abs(per_run["rate_mm_s"] - 0.5 * (per_run["f_Hz"] - 30.0)) < 4 * se)
    ev = SimpleNamespace(bound=SimpleNamespace(kind="trajectory"), sigma=0.05)
    fig = DL._plot_residuals(res, ev, tmp_path / "r.png", "test", covariate="temperature_C")
    assert [ax.get_xlabel() for ax in fig.axes] == ["time [s]", "f [Hz] of the run", "$P_d$ [N] of the run",
                                                    "temperature [°C] of the run"]
    assert all("[mm/s]" in ax.get_ylabel() for ax in fig.axes[1:]) and "[mm]" in fig.axes[0].get_ylabel()
    f_ax = fig.axes[1]
    pts = f_ax.containers[0].lines[0]  # the runs' rates (their error bars' data line)
    assert list(pts.get_xdata()) == list(runs["f_Hz"]) and np.allclose(pts.get_ydata(), per_run["rate_mm_s"])
    # each run named with its drive right of the frames' panel, joined to where its residual ends (the median of
    # its last 5 frames), the labels in the order of those ends and at least 7 % of the axis apart
    texts = fig.axes[0].texts
    ends = {tx.get_text(): tx.xy for tx in texts}
    assert sorted(ends) == ["a (30 Hz, 0.08 N)", "b (34 Hz, 0.08 N)", "c (38 Hz, 0.08 N)", "d (30 Hz, 0.1 N)",
                            "e (34 Hz, 0.1 N)", "f (38 Hz, 0.1 N)"]
    tail = res.groupby("run")["residual_capsule_mm"].apply(lambda r: np.median(r.to_numpy()[-5:]))
    assert all(xy == pytest.approx((0.4, tail[k[0]])) for k, xy in ends.items())
    placed = sorted((tx.xyann[1], tail[tx.get_text()[0]]) for tx in texts)
    assert [e for _, e in placed] == sorted(tail) and np.all(np.diff([f for f, _ in placed]) >= 0.07 - 1e-12)
    assert 0.0 <= placed[0][0] and placed[-1][0] <= 1.0
    fig = DL._plot_residuals(res, ev, tmp_path / "r2.png", "test", covariate="f_Hz")
    assert [ax.get_xlabel() for ax in fig.axes][1:] == ["f [Hz] of the run", "$P_d$ [N] of the run"]
    assert (tmp_path / "r2.png").stat().st_size > 0


def test_where_a_trajectory_model_fails_is_said_run_by_run_as_falling_behind_or_running_ahead():
    """plain_summary of a trajectory (no engine): runs whose position residual drifts are named by the sign of the
    drift, with their drives and classes; a run that drifts by less than RUN_DRIFT_Z standard errors, and the
    frames of a fit at the noise, are not."""
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 0.41, 0.01)
    drives = {"a": (30.0, 0.08, 4.0, "no_impact"), "b": (30.0, 0.1, 6.0, "no_impact"),
              "c": (34.0, 0.08, -8.0, "multi_impact"), "d": (38.0, 0.1, -10.0, "multi_impact"),
              "e": (34.0, 0.1, 0.1, "one_impact")}  # mm/s; e: 1.5 SE, not a drift
    rows, resid, cls = [], [], []
    for run, (f, pd_n, rate, c) in drives.items():
        for ti in t:
            rows.append({"run": run, "f_Hz": f, "Pd_N": pd_n, "time_s": ti, "compared": "position"})
            resid.append(rate * ti + rng.normal(0.0, 0.05))
            cls.append(c)
    rf = pd.DataFrame(rows)
    ev = SimpleNamespace(bound=SimpleNamespace(kind="trajectory", row_frame=lambda: rf.copy()), resid=np.array(resid),
                         sim={"cls": np.array(cls), "spread": np.zeros(len(rf))})
    words = DL.plain_summary(ev, 0.05)
    slow, fast = words.split("; ")
    assert slow.startswith("the model's capsule falls behind the measured one in 2 of 5 runs")
    assert "(f 30 Hz, P_d 0.08-0.1 N)" in slow and "the shell is not hit" in slow
    assert float(slow.split("lower by ")[1].split(" mm/s")[0]) == pytest.approx(5.0, abs=0.3)
    assert fast.startswith("the model's capsule runs ahead of the measured one in 2 of 5 runs")
    assert "(f 34-38 Hz, P_d 0.08-0.1 N)" in fast and "more than once per period" in fast
    assert float(fast.split("higher by ")[1].split(" mm/s")[0]) == pytest.approx(9.0, abs=0.3)
    # a run whose frames are off without a drift (an oscillating misfit: impacts out of phase) is said apart
    ev.resid[rf["run"].to_numpy() == "e"] = 0.5 * np.sin(2 * np.pi * 34.0 * t)
    words = DL.plain_summary(ev, 0.05)
    assert words.split("; ")[:2] == [slow, fast]
    assert words.split("; ")[2].startswith("the frames of 1 more run (f 34 Hz, P_d 0.1 N) are off by ")
    assert words.endswith("noise SDs (RMS) without such a drift")
    # the numbers behind the words, as the reports list them
    recs = {q["run"]: q for q in DL.run_drift_records(DL.run_drift_table(ev, 0.05))}
    assert [recs[r]["drifts"] for r in "abcde"] == [True, True, True, True, False]
    assert abs(recs["e"]["rate_mm_s"]) < 3 * recs["e"]["rate_se_mm_s"]
    assert recs["d"]["f_Hz"] == 38.0 and recs["d"]["response_class"] == "multi_impact" and recs["d"]["frames"] == 41
    assert recs["d"]["rms_standardised_residual"] > 10
    assert recs["e"]["rms_standardised_residual"] == pytest.approx(0.5 / np.sqrt(2) / 0.05, rel=0.05)
    # a fit at the noise: no run drifts, the rows are within 2 noise SDs
    ev.resid = rng.normal(0.0, 0.05, len(rf))
    assert DL.plain_summary(ev, 0.05) == "the model is within about 2 noise SDs of the data in every response regime"


def test_a_runs_drift_rate_se_allows_for_frame_to_frame_correlated_noise(tmp_path):
    """run_residual_rates / slope_se (no engine): a video track's position noise is often correlated from frame to
    frame. On 400 null runs (100 frames, AR(1) noise of lag-1 correlation 0.8, SD 0.1 mm) the white-noise SE of
    each run's drift rate was 2.8x too small (the rates' RMS in SEs 2.8; in a null diagnose of four 1-s runs,
    measured session 30, rates of -0.215 +- 0.034 mm/s: 6.3 SEs, 6 of 24 runs beyond 3 SEs). With the correlation
    the SE is the slope's exact SD under AR(1) noise: the rates' RMS in SEs is 1, and the figure says so."""
    rng = np.random.default_rng(4)
    t = np.arange(100) / 100.0
    rho, sd = 0.8, 0.1
    sxx = np.sum((t - t.mean()) ** 2)
    assert DL.slope_se(t, sd) == pytest.approx(sd / np.sqrt(sxx), rel=1e-12)
    w = (t - t.mean()) / sxx
    cov = sd ** 2 * rho ** np.abs(np.subtract.outer(np.arange(100), np.arange(100)))
    assert DL.slope_se(t[::-1], sd, rho) == pytest.approx(np.sqrt(w @ cov @ w), rel=1e-9)
    assert DL.slope_se(t, sd, rho) / DL.slope_se(t, sd) == pytest.approx(2.79, abs=0.01)
    parts = []
    for k in range(400):
        e = np.zeros(t.size)
        e[0] = sd * rng.standard_normal()  # stationary from the first frame
        for j in range(1, t.size):
            e[j] = rho * e[j - 1] + sd * np.sqrt(1 - rho ** 2) * rng.standard_normal()
        parts.append(pd.DataFrame({"run": f"r{k}", "f_Hz": 30.0 + k % 4, "Pd_N": 0.2, "time_s": t, "r": e,
                                   "response_class": "one_impact", "compared": "position"}))
    frames = pd.concat(parts, ignore_index=True)
    white = DL.run_residual_rates(frames, "r", sd)
    red = DL.run_residual_rates(frames, "r", sd, rho)
    z_white = np.sqrt(np.mean((white["rate_mm_s"] / white["rate_se_mm_s"]) ** 2))
    z_red = np.sqrt(np.mean((red["rate_mm_s"] / red["rate_se_mm_s"]) ** 2))
    assert z_white > 2.5 and 0.9 < z_red < 1.1, (z_white, z_red)
    assert np.mean(np.abs(red["rate_mm_s"] / red["rate_se_mm_s"]) > 3) < 0.01
    ev = SimpleNamespace(bound=SimpleNamespace(kind="trajectory"), sigma=sd)
    four = frames[frames["run"].isin(["r0", "r1", "r2", "r3"])].rename(columns={"r": "residual_capsule_mm"})
    fig = DL._plot_residuals(four, ev, tmp_path / "r.png", "test", rho=rho)
    assert fig.axes[1].get_title().endswith("frame-to-frame correlation 0.8)")
    bars = fig.axes[1].containers[0]  # the four runs' rates and their error bars (+- 1 SE)
    assert np.allclose(bars.lines[0].get_ydata().astype(float), red["rate_mm_s"][:4])
    half = [abs(seg[1, 1] - seg[0, 1]) / 2 for seg in bars.lines[2][0].get_segments()]
    assert np.allclose(half, red["rate_se_mm_s"][:4])
    assert np.all(red["rate_se_mm_s"][:4] > 2.7 * white["rate_se_mm_s"][:4])


def test_compare_reads_the_frames_noise_correlation_about_each_runs_drift_line():
    """compare has one model: the lag-1 correlation its per-run drift SEs allow for is read from the residuals
    about each run's drift line (detrended_by_run), not from the residuals themselves. A model that falls behind
    at a steady rate in white noise (10-16 mm/s over 1 s, noise 0.1 mm) has residuals with a lag-1 correlation of
    nearly 1, which widened the SEs it was to be judged by (a hidden viscous drag, measured session 30: rho 0.93,
    SEs 1.6-4.1 mm/s instead of 0.4-1.4); about the drift lines none is found. AR(1) noise (0.8) is still
    found, near its value; a row compared by average velocity is left as it is."""
    from capsule_cli.steps.residual_tests import serial_correlation

    rng = np.random.default_rng(2)
    t = np.arange(101) / 100.0
    rf = pd.concat([pd.DataFrame({"run": run, "time_s": t, "compared": "position"}) for run in "abcd"]
                   + [pd.DataFrame({"run": ["e"], "time_s": [1.0], "compared": ["average_velocity"]})],
                   ignore_index=True)
    rate = rf["run"].map({"a": 10.0, "b": 12.0, "c": 14.0, "d": 16.0, "e": 0.0}).to_numpy()
    white = rate * rf["time_s"].to_numpy() + rng.normal(0.0, 0.1, len(rf))
    assert serial_correlation(rf, white, ["time_s"])["rho"] > 0.9
    flat = DL.detrended_by_run(rf, white)
    assert serial_correlation(rf, flat, ["time_s"]) is None
    assert flat[-1] == white[-1]
    red = np.zeros(len(rf))
    for run in "abcd":
        i = np.flatnonzero(rf["run"].to_numpy() == run)
        red[i[0]] = 0.1 * rng.standard_normal()
        for j in i[1:]:
            red[j] = 0.8 * red[j - 1] + 0.1 * 0.6 * rng.standard_normal()
    found = serial_correlation(rf, DL.detrended_by_run(rf, red + rate * rf["time_s"].to_numpy()), ["time_s"])
    assert found is not None and 0.65 < found["rho"] < 0.9, found


def test_progression_residual_figure_has_a_panel_per_drive_covariate_and_the_one_named(tmp_path):
    """Residuals against f and P_d, and against the covariate a verdict names when it is another column, so
    that the reader sees the dependence the verdict speaks of."""
    res = pd.DataFrame({"f_Hz": [30.0, 34.0, 38.0, 30.0], "Pd_N": [0.1, 0.1, 0.2, 0.2],
                        "temperature_C": [35.0, 36.0, 37.0, 38.0], "residual_velocity_mm_s": [0.1, -2.0, 3.0, 0.4],
                        "response_class": ["one_impact"] * 4})
    ev = SimpleNamespace(bound=SimpleNamespace(kind="progression"), sigma=0.5)
    fig = DL._plot_residuals(res, ev, tmp_path / "r.png", "test", covariate="temperature_C")
    assert [ax.get_xlabel() for ax in fig.axes] == ["f [Hz]", "$P_d$ [N]", "temperature [°C]"]
    assert all("[mm/s]" in ax.get_ylabel() for ax in fig.axes)
    assert list(fig.axes[2].get_lines()[0].get_ydata()) == [0.1, -2.0, 3.0, 0.4]
    fig = DL._plot_residuals(res, ev, tmp_path / "r2.png", "test", covariate="Pd_N")
    assert [ax.get_xlabel() for ax in fig.axes] == ["f [Hz]", "$P_d$ [N]"]
    # a reading left out as an outlier is drawn at its residual in every panel, not silently dropped
    gross = {"row": 4, "z": 12.0, "threshold": 3.8, "model": "the model as is", "residual": 6.0, "f_Hz": 34.0,
             "Pd_N": 0.2, "velocity_mm_s": 60.0}
    fig = DL._plot_residuals(res, ev, tmp_path / "r3.png", "test", outliers=[gross])
    for ax, x in zip(fig.axes, (34.0, 0.2)):
        cross = [ln for ln in ax.get_lines() if ln.get_marker() == "x"]
        assert len(cross) == 1 and list(cross[0].get_xdata()) == [x] and list(cross[0].get_ydata()) == [6.0]
    assert "left out (outlier)" in [t.get_text() for t in fig.legends[0].get_texts()]
    assert all(ax.get_legend() is None for ax in fig.axes)  # below the figure, never on a panel's points
    # readings gathered at one drive (read as an effect there) are diamonds, labelled with the value
    at = {"covariate": "f_Hz", "value": 30.0, "of": 4, "p": 0.008}
    gathered = [{**gross, "row": r, "residual": e, "f_Hz": 30.0, "Pd_N": pd_, "concentrated": at}
                for r, e, pd_ in ((1, 5.0, 0.15), (2, -4.0, 0.25))]
    fig = DL._plot_residuals(res, ev, tmp_path / "r4.png", "test", outliers=[gross] + gathered)
    marks = {ln.get_marker(): list(ln.get_ydata()) for ln in fig.axes[0].get_lines() if ln.get_marker() in "xD"}
    assert marks == {"x": [6.0], "D": [5.0, -4.0]}, marks
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "left out (outlier)" in texts and "left out (gathered at f = 30 Hz)" in texts, texts
    # the readings at the value where a misfit gathered (scattered_rows): diamonds of their own
    level = [{**gross, "row": r, "residual": e, "f_Hz": f, "Pd_N": 0.3,
              "scattered": {"covariate": "Pd_N", "value": 0.3}} for r, e, f in ((5, 3.5, 30.0), (6, -2.5, 38.0))]
    fig = DL._plot_residuals(res, ev, tmp_path / "r5.png", "test", outliers=[gross] + level)
    marks = {ln.get_marker(): list(ln.get_ydata()) for ln in fig.axes[0].get_lines() if ln.get_marker() in "xD"}
    assert marks == {"x": [6.0], "D": [3.5, -2.5]}, marks
    assert "left out (misfit gathered at Pd = 0.3 N)" in [t.get_text() for t in fig.legends[0].get_texts()]
    # every reading at 0.3 N left out: the value keeps its tick
    assert [t.get_text() for t in fig.axes[1].get_xticklabels()] == ["0.1", "0.2", "0.3"]


def test_a_continuation_sweep_is_simulated_whole_for_a_subset_of_conditions(tmp_path):
    """Protocol up: each frequency starts from the previous one's end state, so the conditions a fold holds
    out (or trains on) are predicted within the whole sweep. Before, a subset was simulated as a sweep of its
    own: with nothing missing, 40 conditions, the 18 Hz / 0.2 N condition held out was predicted at -55.4 mm/s
    against -35.3 in the whole sweep (measured -34.6)."""
    from capsule_cli.dynamics import system as dsys

    up = {"start": "up", "transient_periods": 20, "recorded_periods": 8}
    m = _model(tmp_path, "up", params={"Pf_N": 0.02}, protocol=up)
    design = pd.DataFrame({"f_Hz": [15.0, 18.0, 21.0, 24.0, 27.0, 30.0] * 2, "Pd_N": [0.2] * 6 + [0.25] * 6})
    b = DL.DynBound(m, design.assign(velocity_mm_s=0.0), where="design")
    whole = b.simulate(None, classify=False)["pred"]
    rows = np.array([1, 4, 9])
    part = b.simulate(None, rows, classify=False)["pred"]
    np.testing.assert_array_equal(part[rows], whole[rows])
    alone = dsys.progression(b.system(None), design["f_Hz"].to_numpy()[rows], design["Pd_N"].to_numpy()[rows],
                             protocol=b.protocol)["velocity_mm_s"].to_numpy()
    assert np.max(np.abs(alone - whole[rows])) > 1.0  # a sweep of its own has another history here


UP = {"start": "up", "transient_periods": 40, "recorded_periods": 16}
UP_DESIGN = pd.DataFrame({"f_Hz": np.tile([15.0, 18.0, 21.0, 24.0, 27.0, 30.0], 2), "Pd_N": np.repeat([0.2, 0.25], 6)})


def _continuation_diagnose(tmp_path, hidden, params, seed):
    """diagnose of data run by continuation up over UP_DESIGN (2 replicates), ``hidden`` (or nothing) added to
    the base with ``params``; the model file says how the data were run."""
    truth = _model(tmp_path, f"truth_up_{seed}", [hidden] if hidden else [], {"Pf_N": 0.02} | params, protocol=UP)
    base = _model(tmp_path, "base_up", params={"Pf_N": FREE_PF}, protocol=UP)
    df, path = _progression_data(tmp_path, truth, UP_DESIGN, seed=seed, replicates=2)
    return DL.run_diagnose(base, df, path, tmp_path / f"diag{seed}", k_folds=3, seed=0, figures=False,
                           budget=QUICK, candidates=CANDIDATES)


def test_continuation_protocol_loop_nothing_missing(tmp_path):
    """Data run by continuation up in frequency (each frequency from the previous one's end state), the model
    file saying so, nothing missing: the verdict is null and the model as is is held out at the noise. Before
    held-out conditions were predicted within their whole sweep, a fold's conditions ran as a sweep of their own
    (another history): the verdict was "the data cannot tell"."""
    r = _continuation_diagnose(tmp_path, None, {}, seed=2)
    assert r["verdict"]["outcome"] == "nothing_missing", r["verdict"]["message"]
    assert r["model_as_is"]["cv_rmse"] <= 1.2 * NOISE


def test_continuation_protocol_hidden_constraint_named_and_noise_without_the_chaos(tmp_path):
    """The same sweep with a secondary constraint at the prototype's values hidden (seed 002 Table 2; at the
    truth 10 of the 12 conditions respond irregularly, most of them chaotically): named, and the noise is
    estimated from the replicates of the conditions the best fit does not predict chaotic, or bounded by that
    fit where they are too few. Before, the replicates of every condition were pooled (synth makes a chaotic
    condition's replicate from a later window, as a lab's repeat would differ): 7.2 mm/s against the
    generating 0.5 (noise seeds 0-3: 7.08-7.27), so every standardised error was 14x too small; now 0.21, 0.26,
    0.34 and 0.53 mm/s on seeds 0-3. Held out at the noise once added, on seeds 0-3 (far from the effect's
    start gap a known miss): test_continuation_constraint_held_out_at_noise (slow)."""
    r = _continuation_diagnose(tmp_path, "secondary_constraint", {}, seed=2)
    assert r["verdict"]["missing_effect"] == "secondary_constraint", r["verdict"]["message"]
    assert r["noise"]["sd"] < 1.5 * NOISE, r["noise"]
    assert "does not predict chaotic" in r["noise"]["method"] or r["noise"]["method"].startswith("residual SD"), \
        r["noise"]


@pytest.mark.slow
@pytest.mark.parametrize("gap_mm", [0.1, pytest.param(0.3, marks=pytest.mark.xfail(strict=True, reason=(
    "known miss (issue 12): far from the effect's start gap (0.3 mm) the secondary constraint is named on "
    "every seed but held out at 0.81, 4.33, 0.36 and 0.41 mm/s on the predictable conditions on noise seeds "
    "0-3 (session 48; session 27: 0.81, 2.44, 0.52, 1.22), fitted in the curved (G_2, k_b) valley, k_b "
    "1.8e5-2.4e5 N/m against 97,060 (docs/notes_issue12_secondary_far_gap.md)")))])
def test_continuation_constraint_held_out_at_noise(tmp_path, gap_mm):
    """A secondary constraint hidden in the 12-condition continuation sweep, most of whose conditions respond
    chaotically: named on noise seeds 0-3 and, once added, held out within 1.2x the noise on the predictable
    conditions. At the prototype's gap (0.1 mm), quick effort: 0.13, 0.15, 0.35, 0.43 mm/s (session 48, the
    polish's error model at the polished conditions' residual SD; before, seed 3 was at 0.604 (G_2 0.1108 mm,
    k_b 1.51e5 N/m), now G_2 0.1053 mm, k_b 1.27e5; session 27: 1.21, 0.31, 0.35, 0.81)."""
    for seed in range(4):
        r = _continuation_diagnose(tmp_path, "secondary_constraint", {"gap_back_mm": gap_mm}, seed=seed)
        assert r["verdict"]["missing_effect"] == "secondary_constraint", r["verdict"]["message"]
        win = next(c for c in r["candidates"] if c["effect"] == "secondary_constraint")
        assert win["cv_rmse_not_irregular"] <= 1.2 * NOISE, (seed, win["cv_rmse_not_irregular"])


def test_probe_at_the_noise_where_the_best_built_in_is_not_names_the_covariate():
    """probe_verdict (no engine), rule (b'): the best built-in fits the smooth part of the misfit but leaves four
    conditions 4-40 noise SDs off (a response that the missing effect moves to another branch there); the probe
    fits them all. The paired difference of held-out RMSE has a large standard error (the misfit sits in four
    of 40 conditions), so (b) alone keeps the built-in; with the noise known, the probe is at the noise level
    and the built-in is not, and the covariate is named. Without the noise the verdict stands."""
    rng = np.random.default_rng(5)
    n = 40
    groups = np.arange(n)
    smooth = 3.0 * np.sin(np.arange(n))
    spikes = np.zeros(n)
    spikes[[3, 11, 24, 37]] = (40.0, 20.0, 8.0, 4.0)
    yy = rng.normal(0.0, 1.0, n) + smooth + spikes
    base = _fake_ev(yy, np.zeros(n), np.zeros(n), 1, groups)
    builtin = _fake_ev(yy, smooth, smooth, 3, groups)
    eff = SimpleNamespace(name="probe_Pd_N", covariates=("Pd_N",),
                          params=(SimpleNamespace(name="drive_Pd_scale"), SimpleNamespace(name="drive_Pd_exponent")))
    probe = {"effect": eff, "ev": _fake_ev(yy, smooth + spikes, smooth + spikes, 3, groups,
                                           {"drive_Pd_scale": 0.55, "drive_Pd_exponent": -0.43})}
    d, se = crossval.paired_difference(builtin.cv_sq, probe["ev"].cv_sq, groups)
    assert 0 < d < DL.PROBE_Z * se  # the premise: (b) does not decide
    cands = [{"effect": SimpleNamespace(name="substrate_compliance"), "ev": builtin}]
    verdict = {"outcome": "missing_effect", "missing_effect": "substrate_compliance", "covariate": None}
    assert DL.probe_verdict(base, cands, [probe], verdict, "mm/s") is verdict
    v = DL.probe_verdict(base, cands, [probe], verdict, "mm/s", noise={"sd": 1.0, "se": 0.11, "reliable": True})
    assert v["outcome"] == "not_built_in" and v["covariate"] == "Pd_N" and v["closest"] == "substrate_compliance"
    assert "at the noise level where the built-in is not" in v["message"]
    # the noise only bounded (not reliable): no (b')
    assert DL.probe_verdict(base, cands, [probe], verdict, "mm/s",
                            noise={"sd": 1.0, "se": 0.11, "reliable": False}) is verdict


def test_progression_folds_hold_out_conditions_whatever_the_run_label(tmp_path):
    """Two replicate sweeps labelled by ``run`` (each over every condition): grouped by run, a fold would predict
    each condition from its own replicate in the other sweep, which is no test over conditions. The groups are the
    conditions, the readings at one drive together."""
    m = _model(tmp_path, "m", params={"Pf_N": 0.02})
    design = pd.DataFrame({"f_Hz": [30.0, 34.0, 38.0] * 2, "Pd_N": [0.15] * 3 + [0.25] * 3})
    df = pd.concat([design.assign(run="r1"), design.assign(run="r2")], ignore_index=True).assign(velocity_mm_s=1.0)
    groups, how = DL.DynBound(m, df, where="t").groups()
    np.testing.assert_array_equal(groups, np.tile(np.arange(6), 2))
    assert how.startswith("by condition")
    folds = crossval.assign_folds(groups, 3, 0)
    assert all(np.unique(df["run"][folds == k]).size == 2 for k in range(3))  # every fold holds both sweeps' readings


def test_a_condition_holding_most_of_the_held_out_error_is_named():
    """One reading far off (a misread, or a knife edge) can carry a held-out RMSE: the verdict names the condition
    and gives the held-out RMSE without it (dominant_group); under noise alone no condition is named."""
    rng = np.random.default_rng(3)
    design = pd.DataFrame({"f_Hz": np.tile([15.0, 20.0, 25.0, 30.0, 35.0], 4), "Pd_N": np.repeat([0.1, 0.15, 0.2, 0.25], 5)})
    groups = np.arange(20)
    sq = rng.standard_normal(20) ** 2
    ev = SimpleNamespace(cv_sq=sq, groups=groups, bound=SimpleNamespace(kind="progression", df=design))
    assert DL.dominant_group(ev) is None
    sq[7] = 16.0 ** 2  # 16 noise SDs
    d = DL.dominant_group(SimpleNamespace(cv_sq=sq, groups=groups, bound=ev.bound))
    assert d["group"] == "f_Hz = 25, Pd_N = 0.15" and d["share"] > 0.8  # 256 against about 31 from the others
    assert d["cv_rmse"] == pytest.approx(np.sqrt(sq.mean()))
    assert d["cv_rmse_without"] == pytest.approx(np.sqrt(np.delete(sq, 7).mean()))


def test_a_covariate_measured_in_blocks_is_named_with_the_drift_it_cannot_be_told_from():
    """A progression table with one P_d level after another cannot tell a dependence on P_d from a drift over the
    session (AR(1) noise along the rows named Pd_N in 2 of 2 seeds): the verdict says so; a shuffled order or
    interleaved replicates do not get the caveat, nor a table with a time column."""
    v = {"outcome": "not_built_in", "covariate": "Pd_N", "message": "an effect that is not built in depends on Pd_N"}
    blocks = pd.DataFrame({"f_Hz": np.tile([15.0, 20.0, 25.0], 3), "Pd_N": np.repeat([0.1, 0.2, 0.3], 3)})
    out = DL.blocked_caveat(v, blocks)
    assert out["blocked_in_row_order"] and "drift over the session" in out["message"]
    assert "blocked_in_row_order" not in DL.blocked_caveat(v, pd.concat([blocks, blocks], ignore_index=True))
    assert "blocked_in_row_order" not in DL.blocked_caveat(v, blocks.assign(time_s=np.arange(9.0)))
    assert "blocked_in_row_order" not in DL.blocked_caveat({**v, "outcome": "missing_effect"}, blocks)
    assert DL.blocked_in_row_order([1, 1, 2, 2]) and not DL.blocked_in_row_order([1, 2, 1, 2])
    assert not DL.blocked_in_row_order([1, 1, 1])


def test_a_fit_the_engine_could_not_simulate_is_no_noise_estimate():
    """A candidate whose fitted model fails on every row (no prediction: NaN) left no residuals, and the noise
    bound took it as the best fit, a residual SD of 0 ('held-out RMSE 0.102 mm exceeds the 0 mm expected from
    the noise', null trajectories, a vanishing drag the engine stopped as Zeno before EIG_SLOW_REL). Only
    models simulated on every row bound the noise."""
    rng = np.random.default_rng(0)
    n, sd = 60, 0.1
    y = sd * rng.standard_normal(n)
    bound = SimpleNamespace(rows=[("position", 0, 0.0)] * n, model=SimpleNamespace(effect_names=["tilt_friction"]))

    def ev(pred):
        return SimpleNamespace(bound=bound, y=y, pred=pred, resid=y - pred, k=2)

    ok, failed = ev(np.zeros(n)), ev(np.full(n, np.nan))
    noise = {"sd": 1.6, "se": 0.1, "method": "difference-based", "reliable": False}
    out = DL.trajectory_noise(noise, [failed, ok])
    assert out["sd"] == pytest.approx(np.sqrt(np.sum(y ** 2) / (n - 2)), rel=1e-12)
    assert "tilt_friction" in out["method"]
    assert DL.trajectory_noise(noise, [failed]) == noise  # nothing simulated: the difference bound stands
    assert DL.simulated_everywhere([failed, ok]) == [ok]


def test_a_drift_row_is_taken_from_the_model_at_the_frames_as_from_the_data(tmp_path):
    """An irregular run compared by its drift over whole periods: the data's drift is interpolated between the
    frames around T = k / f (14 / 24 s here, between the frames at 0.58 and 0.59 s), so the model's must be too.
    Before run_drift the model's was exact at T: noise-free data from the model itself were 0.124 mm off (the
    capsule steps between frames), 1.2 noise SDs of the null benchmark's 0.1 mm in every data set."""
    truth = _model(tmp_path, "truth", params={"Pf_N": 0.02}, kind="trajectory", protocol=None)
    design = pd.DataFrame({"run": ["a"], "f_Hz": [24.0], "Pd_N": [0.15], "duration_s": [0.6]})
    df = DL.synthesize_trajectory(truth, design, 0.0, 100.0, 0)
    b = DL.DynBound(truth, df, where="test", modes={"a": "average_velocity"})
    assert [m for m, _, _ in b.rows] == ["average_velocity"]
    sim = b.simulate(None, classify=False)
    assert abs(b.observed()[0] - sim["pred"][0]) < 1e-9
    t = df["time_s"].to_numpy(float)
    T, drift = DL.run_drift(t[::-1], df["capsule_mm"].to_numpy(float)[::-1], 24.0)  # frames in any order
    assert T == pytest.approx(14 / 24.0, rel=1e-15) and drift == pytest.approx(b.observed()[0], rel=1e-15)
# --------------------------------------------------------------------------- a friction level set by the drive


# nine conditions, three amplitudes (a probe needs three levels of its covariate), periodic for these models
PD3_DESIGN = pd.DataFrame({"f_Hz": np.tile([30.0, 34.0, 38.0], 3), "Pd_N": np.repeat([0.08, 0.10, 0.12], 3)})


def test_a_friction_level_given_per_condition_is_simulated_in_one_batch_as_one_system_each():
    """dsys.progression with P_f per condition equals each condition run with its own system (exact)."""
    sysm = dsys.build_system("one_sided", {"Pf_N": 0.02})
    f, pd_ = PD3_DESIGN["f_Hz"].to_numpy(), PD3_DESIGN["Pd_N"].to_numpy()
    pfs = 0.02 * (pd_ / 0.1) ** 0.7
    proto = dsys.Protocol(**PROTO)
    one = dsys.progression(sysm, f, pd_, protocol=proto, Pf_N=pfs)["velocity_mm_s"].to_numpy()
    each = [dsys.progression(dsys.build_system("one_sided", {"Pf_N": float(p)}), [fi], [pi],
                             protocol=proto)["velocity_mm_s"].iloc[0] for fi, pi, p in zip(f, pd_, pfs)]
    assert np.max(np.abs(one - np.array(each))) < 1e-12
    assert np.ptp(one) > 5.0  # the levels matter: the speeds differ by more than noise
    with pytest.raises(InputError, match="Pf_N per condition"):
        dsys.progression(sysm, f, pd_, protocol=proto, Pf_N=np.r_[pfs[:-1], -1.0])


def _diagnose_friction_given(tmp_path, design, replicates, **columns):
    """Diagnose (base model, P_f free; quick, seed 5) data made with the friction level of the design's Pf_N
    column, the column dropped (an effect that is not built in) and ``columns`` added."""
    truth = _model(tmp_path, "truth_pf", params={"Pf_N": 0.02})
    df = DL.synthesize_progression(truth, design, NOISE, replicates, 5).drop(columns=["Pf_N"]).assign(**columns)
    path = tmp_path / "pf_synthetic.csv"
    df.to_csv(path, index=False)
    base = _model(tmp_path, "base", params={"Pf_N": FREE_PF})
    return DL.run_diagnose(base, df, str(path), tmp_path / "diag", k_folds=3, seed=5, figures=False, budget=QUICK,
                           candidates=CANDIDATES)


def test_a_friction_level_that_depends_on_the_drive_amplitude_is_named_by_its_covariate(tmp_path):
    """P_f rising as P_d^0.7 (not built in; data made through a Pf_N column, then the column dropped): no built-in
    explains it, nor does the drive probe on P_d (the gap makes the dynamics other than scale-free); the
    friction probe does, and the verdict names Pd_N."""
    r = _diagnose_friction_given(tmp_path, PD3_DESIGN.assign(Pf_N=0.02 * (PD3_DESIGN["Pd_N"] / 0.1) ** 0.7), 2)
    v = r["verdict"]
    assert v["outcome"] == "not_built_in" and v["covariate"] == "Pd_N", v["message"]
    assert v["probe"] == "probe_friction_Pd_N" and "friction level scaled" in v["message"]
    fric = next(p for p in r["covariate_probes"] if p["probe"] == "probe_friction_Pd_N")
    assert fric["cv_rmse"] <= 1.2 * NOISE  # held out at the noise level (0.447 mm/s at this seed)
    assert abs(fric["params"]["friction_Pd_exponent"]["value"] - 0.7) < 0.1


def test_a_drive_dependence_confounded_with_a_column_is_not_pinned_on_either(tmp_path):
    """The friction level rises with P_d (as in the test above) and the table brings the coil's temperature,
    which rose with the drive current (T = 25 C + 100 C/N P_d): the two move together, so the verdict cannot
    say which one the missing effect depends on. Before, the P_d probe won on the probes' forms and the verdict
    named Pd_N alone, although the rule printed in the same report says collinear covariates are never named
    alone. The residual figure gets a panel for the column."""
    design = PD3_DESIGN.assign(Pf_N=0.02 * (PD3_DESIGN["Pd_N"] / 0.1) ** 0.7)
    r = _diagnose_friction_given(tmp_path, design, 2, coil_temperature_C=lambda d: 25.0 + 100.0 * d["Pd_N"])
    v = r["verdict"]
    assert v["outcome"] == "cannot_tell" and v["covariate"] is None, v["message"]
    assert sorted(v["confounded"]) == ["Pd_N", "coil_temperature_C"], v["message"]
    assert r["collinear_covariates"] == [["Pd_N", "coil_temperature_C"]]
    fric = next(p for p in r["covariate_probes"] if p["probe"] == "probe_friction_Pd_N")
    assert fric["passes"] and fric["cv_rmse"] <= 1.2 * NOISE  # the probe still fits: the effect is there
    assert "collinear, not separable by these data" in (tmp_path / "diag" / "diagnosis.md").read_text()

def test_a_table_column_beside_the_drive_is_a_covariate_and_gets_its_own_probe(tmp_path):
    """A friction level that rises with a temperature recorded beside the drive (not built in; a column of the
    table, random over the readings): the residuals are tested against the column, no built-in nor drive probe
    explains the data, the column's friction probe exp(b (T - median) / half-range) does, and the verdict names
    temperature_C. The columns the loop reads as covariates: the drive first, then the table's own, never the
    responses or a given friction level."""
    rf = pd.DataFrame({"f_Hz": [30.0, 34.0, 38.0], "Pd_N": [0.1] * 3, "velocity_mm_s": [1.0, 2.0, 3.0],
                       "temperature_C": [35.0, 36.0, 37.0], "Pf_N": [0.01, 0.02, 0.03], "run": ["a", "b", "c"],
                       "magnet_mm": [0.1, 0.2, 0.3], "mucus_mm": [0.2, 0.2, 0.2]})
    assert DL.dynamics_covariates(rf, "velocity_mm_s") == ["f_Hz", "temperature_C"]
    rows = PD3_DESIGN.loc[PD3_DESIGN.index.repeat(2)].reset_index(drop=True)
    temp = np.random.default_rng(5).uniform(33.0, 39.0, len(rows)).round(1)
    r = _diagnose_friction_given(tmp_path, rows.assign(Pf_N=0.02 * np.exp(0.25 * (temp - 36.0) / 3.0)), 1,
                                 temperature_C=temp)
    v = r["verdict"]
    assert v["outcome"] == "not_built_in" and v["covariate"] == "temperature_C", v["message"]
    assert v["probe"] == "probe_friction_temperature_C"
    assert {s["covariate"] for s in r["residual_structure"]} >= {"f_Hz", "Pd_N", "temperature_C"}
    probe = [p for p in r["covariate_probes"] if p["probe"] == "probe_friction_temperature_C"]
    assert len(probe) == 1  # one probe per column, also when an earlier table left one in the registry
    # the median and half-range of this draw make the truth's slope b = 0.25 x (half-range / 3 C), ~0.25
    assert abs(probe[0]["params"]["friction_temperature_slope"]["value"] - 0.25) < 0.05
    # held out 0.71 mm/s at this seed, the model as is 2.65 and the other probes 2.4-3.0 (the model as is was 12.3
    # while a condition irregular at its fit, 38 Hz / 0.12 N, was held out as certain where a fold's starts agreed)
    others = [p["cv_rmse"] for p in r["covariate_probes"] if p["probe"] != "probe_friction_temperature_C"]
    assert probe[0]["cv_rmse"] < min([r["model_as_is"]["cv_rmse"]] + others) / 3


def test_a_fit_made_with_the_inflated_noise_bound_is_refined_once_the_noise_is_revised(tmp_path):
    """Without replicates the fits start from the difference-based noise bound (tens of mm/s where the speed
    jumps between conditions) and the robust stage's loss is as wide; refit_with_noise refines a fit from its
    own point with the revised noise's loss, and never keeps a worse one (dynamics_loop.REFIT_NOISE_RATIO)."""
    from dataclasses import replace

    truth = _model(tmp_path, "truth", params={"Pf_N": 0.02})
    df, path = _progression_data(tmp_path, truth, TEN_DESIGN, seed=3, replicates=1)
    model = _model(tmp_path, "m", params={"Pf_N": {**FREE_PF, "value": 0.04}})
    bound = DL.DynBound(model, df, where=path, rk_rtol=QUICK.rk_rtol)
    groups, _ = bound.groups()
    folds = crossval.assign_folds(groups, 3, 0)
    best = DL.evaluate(bound, NOISE, folds, groups, budget=QUICK)  # the fit made with the noise known
    # a fit stopped early at the inflated bound: one start, three evaluations, no polish
    rough = DL.evaluate(bound, 20.0, folds, groups,
                        budget=replace(QUICK, starts=1, evals_per_param=3, polish_evals_per_param=0))
    assert rough.rmse > 4 * best.rmse
    kept = DL.refit_with_noise(rough, 0.6 * 20.0, QUICK, 0)  # not below REFIT_NOISE_RATIO x 20: not refitted
    assert np.array_equal(kept.theta, rough.theta) and kept.sigma == 12.0
    fine = DL.refit_with_noise(rough, NOISE, QUICK, 0)
    assert fine.sigma == NOISE
    assert fine.rss < rough.with_sigma(NOISE).rss
    assert fine.rmse == pytest.approx(best.rmse, rel=1e-3)
    assert fine.theta[0] == pytest.approx(best.theta[0], rel=1e-3) and abs(fine.theta[0] - 0.02) < 5e-4
    assert fine.seconds > rough.seconds  # the refit's time is added to the first fit's
    # a fit the refinement cannot better by one noise variance's worth is kept as it is, held-out errors and all
    again = DL.refit_with_noise(best, 0.2, QUICK, 0)
    assert np.array_equal(again.theta, best.theta) and again.sigma == 0.2
    assert np.array_equal(again.cv_pred, best.cv_pred)


def test_a_richer_candidate_starts_where_it_reduces_to_the_fitted_effect_it_contains(tmp_path):
    """The speed law a|V|^n at n = 1 is a viscous drag with c_v = a (Effect.nest_starts): the drag is fitted first
    and the speed law's calibration starts at its fit, P_f and all, so the richer fit is never worse."""
    from capsule_cli.steps.diagnose import all_effects

    pool = [e for e in all_effects("progression")]
    order = [e.name for e in DL.nested_first(pool)]
    assert order.index("viscous_drag") < order.index("speed_dependent_friction")
    assert sorted(order) == sorted(e.name for e in pool)
    law = next(e for e in pool if e.name == "speed_dependent_friction")
    model = _model(tmp_path, "m", params={"Pf_N": FREE_PF})
    m2 = model.with_effect(law)
    drag = SimpleNamespace(theta=np.array([0.0123, 0.047]),
                           bound=SimpleNamespace(values=lambda th: {"Pf_N": th[0], "drag_Ns_m": th[1]}))
    free = [s.key for s in m2.specs if s.free]
    (start,) = DL.nested_starts(m2, law, {"viscous_drag": drag})
    got = dict(zip(free, start))
    assert got == {"Pf_N": 0.0123, "a_mN": 0.047, "n": 1.0}
    assert DL.nested_starts(m2, law, {}) == []  # nothing fitted to start from
    odd = SimpleNamespace(theta=np.array([0.0123]), bound=SimpleNamespace(values=lambda th: {"Pf_N": th[0]}))
    assert DL.nested_starts(m2, law, {"viscous_drag": odd}) == []  # the fit lacks the named parameter


def test_a_start_two_orders_of_magnitude_behind_stops_and_the_others_end_as_uninterrupted(monkeypatch):
    """The multi-start race (DL.RACE_FIRST, DL.RACE_DROP): a Nelder-Mead start whose cost, half-way through its
    evaluations, is above RACE_DROP x the best start's stops there; every other start resumes
    from its simplex and ends bitwise where one uninterrupted run ends, with the same number of evaluations."""
    a, b = np.array([0.3, 0.7, 0.5]), np.array([0.8, 0.2, 0.9])
    M = 90  # evaluations per start: the full effort's 30 per parameter

    def cost(u):  # two basins: the global one at a (cost 1e-4) and a local one at b (cost 0.0501)
        calls.append(1)
        return float(min(np.sum((u - a) ** 2), 0.05 + np.sum((u - b) ** 2)) + 1e-4)

    starts = [a + 0.1, b - 0.05, a - 0.12]
    calls: list = []
    plain_runs: list = []
    plain = DL._nelder_mead(cost, starts, M, 0.15, 1e-3, plain_runs)
    n_plain = len(calls)
    calls.clear()
    race_runs: list = []
    raced = DL._nelder_mead(cost, starts, M, 0.15, 1e-3, race_runs, race=True)
    n_race = len(calls)
    assert raced[1] == plain[1] and np.array_equal(raced[0], plain[0])
    assert race_runs[0][0] == plain_runs[0][0] and race_runs[2][0] == plain_runs[2][0]
    assert np.array_equal(race_runs[0][1], plain_runs[0][1])
    # the start in the local basin stopped above 0.05 (> 100 x the lead's ~1e-4) half-way
    assert 0.05 < race_runs[1][0] < 0.06 and plain_runs[1][0] < race_runs[1][0]
    calls.clear()
    DL._nelder_mead(cost, starts[1:2], M, 0.15, 1e-3)
    alone = len(calls)  # the stopped start's evaluations without the race
    pause = int(np.ceil(DL.RACE_FIRST * M))
    most = a.size + 2  # one Nelder-Mead iteration: a reflection, a contraction and a shrink of k vertices
    assert alone > pause + most and pause <= n_race - (n_plain - alone) <= pause + most  # to the pause's iteration
    # no start dropped: every run as without the race, evaluation for evaluation
    monkeypatch.setattr(DL.calibration, "RACE_DROP", np.inf)
    calls.clear()
    all_runs: list = []
    same = DL._nelder_mead(cost, starts, M, 0.15, 1e-3, all_runs, race=True)
    assert len(calls) == n_plain and same[1] == plain[1]
    assert [r[0] for r in all_runs] == [r[0] for r in plain_runs]


def test_a_response_multistable_at_the_fit_keeps_its_spread_held_out(monkeypatch):
    """A condition whose starts reach two attractors at the fit (-0.5 and 112 mm/s: mean 56, spread 56) may be
    predicted by a fold refit whose starts all reach one of them (112, spread 0): held out it is standardised by
    the fit's spread, not as a certain prediction. Measured (40 conditions, a hidden secondary constraint, data
    from 1 nm off rest): that one condition held the whole held-out error, 17.9 mm/s against 0.60 without it."""
    n, sigma = 10, 0.5
    rng = np.random.default_rng(0)
    y = rng.normal(0.0, sigma, n)
    y[7] = -0.25  # the data took the -0.5 mm/s attractor

    def simulate(theta, rows=None, starts=False, classify=True, **_):
        pred, spread = np.zeros(n), np.zeros(n)
        pred[7], spread[7] = (56.0, 56.0) if theta[0] == 1.0 else (112.0, 0.0)  # the fit; a fold's refit
        return {"pred": pred, "spread": spread, "cls": np.array(["one_impact"] * n)}

    bound = SimpleNamespace(kind="progression", free=[SimpleNamespace(key="p")], bounds=([0.0], [2.0]),
                            observed=lambda: y, simulate=simulate)
    monkeypatch.setattr(DL.evaluation, "calibrate", lambda *a, **k: DL.Fit(np.array([1.0 + 1e-3]), 0.0, 1, 1))
    fit = DL.Fit(np.array([1.0]), 0.0, 1, 1)
    groups = np.arange(n)
    folds = groups % 5
    ev = DL.evaluate(bound, sigma, folds, groups, fit=fit)
    assert ev.cv_pred[7] == 112.0
    assert ev.cv_spread[7] == 56.0
    # (112 + 0.25)^2 sigma^2 / (sigma^2 + 56^2) = 1.0 (mm/s)^2 at that row (a 2-SD error), not 12,600 (mm/s)^2
    # (a 225-SD error)
    assert ev.cv_sq[7] == pytest.approx(112.25 ** 2 * sigma ** 2 / (sigma ** 2 + 56.0 ** 2))
    assert ev.cv_rmse < 2 * sigma
    # were it still to hold the held-out error, the verdict would say the model is multistable there
    sq = np.ones(n)
    sq[7] = 400.0
    dom = DL.dominant_group(SimpleNamespace(cv_sq=sq, groups=groups, sim=ev.sim,
                                            bound=SimpleNamespace(kind="progression", df=pd.DataFrame(
                                                {"f_Hz": np.arange(n) + 20.0, "Pd_N": 0.2}))))
    assert dom["group"] == "f_Hz = 27, Pd_N = 0.2" and dom["model_spread"] == 56.0


def _jumpy_bound(jump):
    """A stand-in for a bound (no engine): 7 conditions whose velocity 2 x_i theta moves smoothly with the one
    parameter theta (predictable: one impact per period, no spread), measured with the noise JUMPY_NOISE
    (orthogonal to x, so that the least-squares theta is the true 0.3; residual SD at the fit
    sqrt(4 / 6) = 0.816), and 3 chaotic ones (spread 5 mm/s) whose velocity ``jump(theta)`` adds to the
    data's."""
    x = np.arange(1.0, 8.0)
    y = np.concatenate([2.0 * x * 0.3 + JUMPY_NOISE, [10.0, -20.0, 30.0]])

    def simulate(theta, rows=None, classify=True, starts=False, **_):
        th = float(np.asarray(theta).ravel()[0])
        return {"pred": np.concatenate([2.0 * x * th, y[7:] + jump(th)]),
                "spread": np.array([0.0] * 7 + [5.0] * 3),
                "cls": np.array(["one_impact"] * 7 + ["irregular"] * 3)}

    return SimpleNamespace(simulate=simulate), y


JUMPY_NOISE = np.array([1.0, 0.0, -1.0, 0.0, -1.0, 0.0, 1.0])


def _predictable_polish_from(theta0, jump, s=1.0):
    bound, y = _jumpy_bound(jump)
    idx = np.arange(y.size)

    def raw(u):
        return y - bound.simulate(u)["pred"]

    nfev = [0]
    u0 = np.array([theta0])
    c0 = float(np.sum(raw(u0) ** 2))
    return DL.calibration._predictable_polish(bound, y, None, idx, raw, lambda u: np.asarray(u, float), u0, c0,
                                              None, s, 40, nfev)


def test_a_progression_fit_ends_with_a_polish_on_the_conditions_it_predicts():
    """_predictable_polish: the chaotic conditions' velocities jump with the parameter (a needle in the sum of
    squares), the predictable ones' do not; from theta 0.2 (true 0.3) the polish on the predictable conditions
    reaches the least-squares theta (the truth) to 1e-6, lowers the error model's chi-square and returns their
    indicator as the weights (fold and bootstrap refits minimise the same sum)."""
    u, c, w = _predictable_polish_from(0.2, lambda th: 3.0 * np.sin(1e4 * th) * np.ones(3))
    assert u[0] == pytest.approx(0.3, abs=1e-6)
    assert c == pytest.approx(4.0, rel=1e-9)  # the noise's sum of squares
    assert w.tolist() == [1.0] * 7 + [0.0] * 3


def test_a_polish_on_the_predicted_conditions_is_kept_only_when_the_error_model_fits_better():
    """The same, but every chaotic condition jumps 100 mm/s once theta leaves its start: the error model's
    chi-square at the polished conditions' residual SD s_c = 0.816 (each chaotic row weighs
    s_c^2 / (s_c^2 + 5^2) = 0.026) rises by 3 x 100^2 x 0.026 = 779 against the 7 predictable rows' gain of 5.6
    (residuals 0.2 x_i + noise at theta 0.2), so the fit and its weights stay as they were. Nor is a gain below
    one degree of freedom's worth (s^2 = 1) kept: from theta 0.29, 0.056."""
    x = np.arange(1.0, 8.0)
    u, c, w = _predictable_polish_from(0.2, lambda th: 0.0 if th == 0.2 else 100.0)
    assert u[0] == 0.2 and w is None
    assert c == pytest.approx(float(np.sum((0.2 * x + JUMPY_NOISE) ** 2)), rel=1e-12)
    u, c, w = _predictable_polish_from(0.29, lambda th: 0.0)
    assert u[0] == 0.29 and w is None
    assert c == pytest.approx(float(np.sum((0.02 * x + JUMPY_NOISE) ** 2)), rel=1e-12)
    u, c, w = _predictable_polish_from(0.2, lambda th: 0.0)  # the same start, nothing jumps: kept
    assert u[0] == pytest.approx(0.3, abs=1e-6) and w.tolist() == [1.0] * 7 + [0.0] * 3


def test_the_polish_weighs_the_chaotic_conditions_at_the_polished_conditions_noise_not_the_fits_misfit():
    """The residual scale s handed to the polish comes from the median residual at the fit and holds its misfit
    (here 1.5, against the polished conditions' residual SD s_c = 0.816). Every chaotic condition jumps by its
    spread (5 mm/s) once theta leaves its start: at s = 1.5 each weighs 2.25 / 27.25, and the chi-square would rise
    by 3 x 25 x 0.083 = 6.19 against the gain 5.6 and refuse the step; at s_c the rise is 1.96, the net gain 3.64
    is above s^2 = 2.25, the step is kept and theta reaches the truth (a secondary constraint at G_2 = 0.2 mm,
    40 conditions, noise seed 1: refused at s = 1.25 mm/s, held out 1.78 mm/s against the noise 0.5; kept at
    s_c = 0.38, 0.42 mm/s). The threshold stays s^2 (s_c, from the polished conditions themselves, rests on few
    degrees of freedom in a small design): from theta 0.25, nothing jumping, the gain 1.4 is above s_c^2 = 0.667
    but below s^2, and the fit stays."""
    u, c, w = _predictable_polish_from(0.2, lambda th: 0.0 if th == 0.2 else 5.0, s=1.5)
    assert u[0] == pytest.approx(0.3, abs=1e-6) and w.tolist() == [1.0] * 7 + [0.0] * 3
    # a jump of 20 spreads is still refused at s_c
    u, c, w = _predictable_polish_from(0.2, lambda th: 0.0 if th == 0.2 else 100.0, s=1.5)
    assert u[0] == 0.2 and w is None
    u, c, w = _predictable_polish_from(0.25, lambda th: 0.0, s=1.5)
    assert u[0] == 0.25 and w is None


def test_two_conditions_say_the_data_cannot_tell_and_claim_no_fit_within_the_noise(tmp_path):
    """Two measured conditions without replicates cannot estimate the noise (the data's spread only bounds it):
    the verdict is "the data cannot tell", and the words on where the model fails do not say it is "within about
    2 noise SDs" of the data (they said so before), which the data cannot show: only that no regime is off by
    more than 2 times the noise's upper bound."""
    truth = _model(tmp_path, "truth_two", params={"Pf_N": 0.03})
    df, path = _progression_data(tmp_path, truth, TEN_DESIGN.iloc[:2], seed=0, replicates=1)
    base = _model(tmp_path, "base", params={"Pf_N": FREE_PF})
    r = DL.run_diagnose(base, df, path, tmp_path / "diag", k_folds=3, seed=0, figures=False, budget=QUICK,
                        candidates=CANDIDATES)
    v = r["verdict"]
    assert v["outcome"] == "cannot_tell", v["message"]
    assert "with 2 points and no replicates" in v["message"] and r["noise"]["reliable"] is False
    bound = float(r["where_it_fails"].split("upper bound (")[1].split(" mm/s)")[0])
    assert bound == pytest.approx(r["noise"]["sd"], rel=1e-3)
    assert r["where_it_fails"].startswith("no response regime is off by more than 2 times the noise's upper bound (")
    assert "within about 2 noise SDs" not in v["message"]
