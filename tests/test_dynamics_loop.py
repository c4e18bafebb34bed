"""The dynamics loop (issue 12): model files with protocol, synth, compare and diagnose on small designs.

Designs are small (6 conditions x 2 replicates, 40 transient + 16 recorded periods) so the tests stay
within the CI budget; the 40-condition case is in benchmarks/bench_dynamics_loop.py.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from capsule_cli.config import load_model_file
from capsule_cli.dynamics import system as dsys
from capsule_cli.effects.model import build_model
from capsule_cli.errors import InputError
from capsule_cli.steps import dynamics_loop as DL

# The diagnoses over all five candidates (marked slow) take minutes of
# engine time each on the opened engine: run by `make test-slow`, not by CI's `make test`; the rest is cheap.
# The CI-time loop tests are in tests/test_dynamics_loop_fast.py.

NOISE = 0.5  # generating noise SD [mm/s]
BUDGET = DL.Budget(scan_per_param=4, starts=2, evals_per_param=40, fold_evals_per_param=8, bootstrap=0)
PROTO = {"start": "rest", "transient_periods": 40, "recorded_periods": 16}
DESIGN = pd.DataFrame({"f_Hz": np.tile([30.0, 34.0, 38.0], 2), "Pd_N": np.repeat([0.15, 0.25], 3)})


def _model(tmp_path, name, effects=(), params=None, free_pf=True):
    p = dict(params or {})
    if free_pf:
        p["Pf_N"] = {"value": 0.03, "free": True, "bounds": [0.001, 0.2]}
    doc = {"kind": "progression", "base": "one_sided", "effects": list(effects), "params": p, "protocol": PROTO}
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return build_model(path)


def _unavailable(effect: str) -> bool:
    try:
        dsys.build_system("one_sided", {}, [effect])
    except NotImplementedError:
        return True
    return False


def _data(tmp_path, truth, seed=1):
    df = DL.synthesize_progression(truth, DESIGN, NOISE, 2, seed)
    path = tmp_path / f"{truth.name}_synthetic.csv"
    df.to_csv(path, index=False)
    return df, str(path)


def _diagnose(tmp_path, truth, seed=1):
    base = _model(tmp_path, "base")
    df, path = _data(tmp_path, truth, seed)
    return DL.run_diagnose(base, df, path, tmp_path / "diag", write_model=tmp_path / "new.yaml", k_folds=3,
                           seed=seed, figures=False, budget=BUDGET)


def test_model_file_protocol_defaults_and_errors(tmp_path):
    p = tmp_path / "m.yaml"
    p.write_text("kind: progression\nbase: one_sided\nparams:\n  Pf_N: {value: 0.0078, free: true, "
                 "bounds: [0.0, 0.5]}\n")
    m = build_model(p)
    assert DL.protocol_of(m) == dsys.Protocol("rest", 120, 60)
    p.write_text("kind: progression\nbase: one_sided\nprotocol: {start: up, recorded_periods: 30}\n")
    assert DL.protocol_of(build_model(p)) == dsys.Protocol("up", 120, 30)
    p.write_text("kind: progression\nbase: one_sided\nprotocol: {start: sideways}\n")
    with pytest.raises(InputError, match="start"):
        load_model_file(p)
    p.write_text("kind: friction\nbase: coulomb\nprotocol: {start: rest}\n")
    with pytest.raises(InputError, match="protocol"):
        build_model(p)
    p.write_text("kind: progression\nbase: one_sided\nprotocol: {transient: 3}\n")
    with pytest.raises(InputError, match="transient"):
        load_model_file(p)


def test_protocol_changes_the_model_hash(tmp_path):
    a = _model(tmp_path, "a")
    doc = yaml.safe_load((tmp_path / "a.yaml").read_text())
    doc["protocol"]["recorded_periods"] = 20
    (tmp_path / "b.yaml").write_text(yaml.safe_dump(doc))
    assert build_model(tmp_path / "b.yaml").hash != a.hash


def test_synth_progression_replicates_and_noise(tmp_path):
    truth = _model(tmp_path, "truth", params={"Pf_N": 0.02}, free_pf=False)
    clean = DL.synthesize_progression(truth, DESIGN, 0.0, 1, 0)
    noisy = DL.synthesize_progression(truth, DESIGN, NOISE, 3, 0)
    assert len(noisy) == 3 * len(DESIGN)
    sysm = dsys.build_system("one_sided", {"Pf_N": 0.02})
    ref = dsys.progression(sysm, DESIGN["f_Hz"], DESIGN["Pd_N"], protocol=dsys.Protocol(**PROTO))
    np.testing.assert_allclose(clean["velocity_mm_s"], ref["velocity_mm_s"], rtol=0, atol=1e-9)
    # replicates at periodic conditions differ only by the noise: pooled SD near 0.5 mm/s
    per = ref["response_class"].to_numpy() != "irregular"
    g = noisy.groupby(["f_Hz", "Pd_N"])["velocity_mm_s"].std(ddof=1).to_numpy()[per[np.argsort(
        DESIGN.groupby(["f_Hz", "Pd_N"]).ngroup().to_numpy())]]
    assert 0.2 < float(np.sqrt(np.mean(g ** 2))) < 0.9


def test_progression_classes_and_window_spread():
    sysm = dsys.build_system("one_sided", {"Pf_N": 0.0078})
    out = dsys.progression(sysm, [10.0, 34.0], [0.05, 0.15], protocol=dsys.Protocol("rest", 120, 60))
    assert list(out["response_class"]) == ["no_impact", "one_impact"]
    assert out["window_sd_mm_s"].max() < 1e-3  # periodic: windows agree (transient decay only)
    assert abs(out["velocity_mm_s"].iloc[0]) < 1e-6


def test_batch_summary_is_each_conditions_own_to_the_last_bit():
    """summarize_batch (all conditions at once) gives, bit for bit, what each condition's records give alone,
    written out here one condition at a time (the average velocity, the mean impacts, np.array_split's four
    windows and their SD with ddof 1, the smallest repeating period): the engine's records of no-impact,
    periodic, multi-impact and irregular responses, 13 recorded periods (windows of 4, 3, 3, 3)."""
    from capsule_cli.dynamics import engine as E
    from capsule_cli.dynamics.parallel import run_many
    from capsule_cli.dynamics.model import EngineOptions
    sysm = dsys.build_system("one_sided", {"Pf_N": 0.02, "gap_back_mm": 0.3}, ["secondary_constraint"])
    f = np.tile([10.0, 24.0, 30.0, 34.0, 38.0], 2)
    pd_ = np.r_[0.01, np.full(4, 0.08), np.full(5, 0.15)]
    _, _, _, drives = dsys._conditions(f, pd_, None, "harmonic", sysm)
    P = np.stack([sysm.params_row(d) for d in drives])
    st, per, _, _ = run_many(P, EngineOptions(energy=False).pack(), np.zeros((f.size, 4)), 40, 13)
    assert (st == E.STATUS_OK).all()
    cols = dsys.summarize_batch(per, f)
    assert set(cols["response_class"]) == {"no_impact", "one_impact", "multi_impact", "irregular"}
    for i in range(f.size):
        r, T = per[i], 1.0 / f[i]
        disp, hits = r[:, E.P_DISP], r[:, E.P_NFRONT] + r[:, E.P_NBACK]
        xr, vr = r[:, E.P_XR0], r[:, E.P_VR0]
        sx = max(float(np.ptp(xr)), 1e-6, float(np.max(np.abs(xr))) * 1e-3)
        sv = max(float(np.ptp(vr)), 1e-3, float(np.max(np.abs(vr))) * 1e-3)
        pn = next((p for p in range(1, 9) if max(np.abs(xr[p:] - xr[:-p]).max() / sx,
                                                 np.abs(vr[p:] - vr[:-p]).max() / sv) < 1e-5), 0)
        wv = np.array([w.sum() / (w.size * T) for w in np.array_split(disp, 4)]) * 1e3
        cls = ("no_impact" if hits.sum() == 0 else "irregular" if pn == 0
               else "one_impact" if np.all(hits == 1) else "multi_impact")
        assert cols["velocity_mm_s"][i] == disp.sum() / (13 * T) * 1e3
        assert cols["impacts_per_period"][i] == hits.mean()
        assert cols["period_number"][i] == pn and cols["response_class"][i] == cls
        assert cols["window_sd_mm_s"][i] == np.std(wv, ddof=1)
        assert dsys.summarize_periods(r, f[i]) == {k: v[i] for k, v in cols.items()}


def test_a_point_asked_for_again_reruns_only_the_conditions_not_run_there(tmp_path, monkeypatch):
    """A progression bound keeps the conditions run at a parameter point: asked again (a fold's refit from the
    full fit, the polish from the best start) they are not run again and give the same numbers; a fold's
    conditions not run at that point are run, alone; another point runs again; rows not asked for stay NaN."""
    truth = _model(tmp_path, "truth", free_pf=False, params={"Pf_N": 0.02})
    df = DL.synthesize_progression(truth, DESIGN, NOISE, 2, 1)
    b = DL.DynBound(_model(tmp_path, "base"), df)
    runs = []
    real = dsys.run_many

    def counting(P, *a, **k):
        runs.append(P.shape[0])
        return real(P, *a, **k)

    monkeypatch.setattr(dsys, "run_many", counting)
    fold = np.flatnonzero(b.cond_index < 2)  # the readings of two of the six conditions
    part = b.simulate([0.02], rows=fold)
    assert runs == [2] and np.isnan(part["pred"]).sum() == len(df) - fold.size
    whole = b.simulate([0.02])
    assert runs == [2, 4]  # the four conditions not run there yet
    again = b.simulate([0.02], rows=fold)
    assert runs == [2, 4]
    np.testing.assert_array_equal(again["pred"][fold], part["pred"][fold])
    np.testing.assert_array_equal(np.isnan(again["pred"]), np.isnan(part["pred"]))
    fresh = DL.DynBound(_model(tmp_path, "base"), df).simulate([0.02])
    np.testing.assert_array_equal(whole["pred"], fresh["pred"])  # the merged runs are the runs of one batch
    assert list(whole["cls"]) == list(fresh["cls"])
    b.simulate([0.021], rows=fold)
    assert runs[2:] == [6, 2]  # the fresh bound's batch of six, then another point: run


def test_a_trajectory_point_asked_for_again_with_the_same_rows_is_not_run_again(tmp_path, monkeypatch):
    """A trajectory bound keeps its predictions by parameter point and rows: the same point and rows again run
    no engine and give the same numbers in new arrays (a caller's change to them does not reach the next
    caller); other rows or another point run."""
    doc = {"kind": "trajectory", "base": "one_sided", "effects": [], "params": {"Pf_N": 0.02}}
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(doc))
    truth = build_model(tmp_path / "t.yaml")
    design = pd.DataFrame({"run": ["a", "b"], "f_Hz": [30.0, 34.0], "Pd_N": [0.08, 0.10], "duration_s": [0.2, 0.2]})
    df = DL.synthesize_trajectory(truth, design, 0.05, 100.0, 1)
    doc["params"] = {"Pf_N": {"value": 0.03, "free": True, "bounds": [0.001, 0.2]}}
    (tmp_path / "b.yaml").write_text(yaml.safe_dump(doc))
    b = DL.DynBound(build_model(tmp_path / "b.yaml"), df)
    runs = []
    real = dsys.trajectory

    def counting(*a, **k):
        runs.append(1)
        return real(*a, **k)

    monkeypatch.setattr(dsys, "trajectory", counting)
    first = b.simulate([0.02], rows=np.arange(10))
    n = len(runs)
    assert n >= 1
    again = b.simulate([0.02], rows=np.arange(10))
    assert len(runs) == n
    np.testing.assert_array_equal(again["pred"], first["pred"])
    again["pred"][:] = 0.0
    assert np.array_equal(b.simulate([0.02], rows=np.arange(10))["pred"], first["pred"], equal_nan=True)
    assert len(runs) == n
    b.simulate([0.02])
    assert len(runs) > n
    m = len(runs)
    b.simulate([0.021], rows=np.arange(10))
    assert len(runs) > m
    # the rows asked for are the observed ones to the noise (the truth's point)
    assert np.nanmax(np.abs(first["pred"][:10] - b.observed()[:10])) < 5 * 0.05


@pytest.fixture(scope="module")
def hidden_sdf(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sdf")
    truth = _model(tmp, "truth_sdf", ["speed_dependent_friction"], {"Pf_N": 0.02, "a_mN": 6.0, "n": 0.5},
                   free_pf=False)
    return _diagnose(tmp, truth), tmp


@pytest.mark.slow
def test_hidden_speed_dependent_friction_is_named_and_fits_to_noise(hidden_sdf):
    r, tmp = hidden_sdf
    v = r["verdict"]
    assert v["missing_effect"] == "speed_dependent_friction", v["message"]
    win = next(c for c in r["candidates"] if c["effect"] == "speed_dependent_friction")
    assert win["cv_rmse_not_irregular"] <= 1.2 * NOISE
    assert r["model_as_is"]["cv_rmse"] > 5 * NOISE
    three = ("viscous_drag", "substrate_compliance", "tilt_friction")
    assert {s["effect"] for s in r["skipped_candidates"]} == {e for e in three if _unavailable(e)}
    # --write-model: the effect added, protocol kept, calibrated values as free starts
    doc = yaml.safe_load((tmp / "new.yaml").read_text())
    assert doc["effects"] == ["speed_dependent_friction"] and doc["protocol"] == PROTO
    assert doc["params"]["a_mN"]["free"] is True


SOFT_SECONDARY_MISS = pytest.mark.xfail(strict=True, reason=(
    "known miss (issue 12): a soft secondary constraint, k_b = 2000 N/m, 50x below the effect's start value, is "
    "named but not calibrated: from the model as is the multi-start fit ends in another basin (held-out 10-14 "
    "mm/s against the noise 0.5; at the true values 0.3); larger Sobol scans (64-128 points) and a third start "
    "did not find it either (measured, session 7)"))


@pytest.fixture(scope="module")
def hidden_secondary(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sec")
    truth = _model(tmp, "truth_sec", ["secondary_constraint"],
                   {"Pf_N": 0.02, "gap_back_mm": 0.2, "constraint_back_N_m": 2000.0}, free_pf=False)
    return _diagnose(tmp, truth), tmp


@pytest.mark.slow
@SOFT_SECONDARY_MISS
def test_hidden_secondary_constraint_is_named_and_fits_to_noise(hidden_secondary):
    r, _ = hidden_secondary
    assert r["verdict"]["missing_effect"] == "secondary_constraint", r["verdict"]["message"]
    win = next(c for c in r["candidates"] if c["effect"] == "secondary_constraint")
    assert win["rmse"] <= 1.2 * NOISE  # calibrated on all conditions: at the noise level
    assert win["cv_rmse_not_irregular"] < 0.1 * r["model_as_is"]["cv_rmse"]


@pytest.mark.slow
@SOFT_SECONDARY_MISS
def test_hidden_secondary_constraint_held_out_at_noise(hidden_secondary):
    # fold refits on 4 of 6 conditions; warm-started, a local refinement of the full fit
    r, _ = hidden_secondary
    win = next(c for c in r["candidates"] if c["effect"] == "secondary_constraint")
    assert win["cv_rmse_not_irregular"] <= 1.2 * NOISE


@pytest.mark.slow
def test_null_data_gives_a_null_verdict(tmp_path):
    truth = _model(tmp_path, "truth_null", params={"Pf_N": 0.02}, free_pf=False)
    r = _diagnose(tmp_path, truth, seed=3)
    assert r["verdict"]["missing_effect"] is None, r["verdict"]["message"]
    assert r["verdict"]["regime"] is None
    assert r["verdict"]["message"].startswith("nothing is missing")
    assert all(not c["passes"] for c in r["candidates"])


@pytest.mark.slow
@pytest.mark.parametrize("effect,params", [
    ("viscous_drag", {"drag_Ns_m": 0.02}),
    ("substrate_compliance", {"compliance_mm_N": 0.5}),
    ("tilt_friction", {"kappa": 0.5}),
])
def test_unavailable_effects_named_once_the_engine_has_them(tmp_path, effect, params):
    if _unavailable(effect):
        pytest.skip(f"{effect} needs the opened engine of issue 9 (NotImplementedError on today's engine)")
    truth = _model(tmp_path, f"truth_{effect}", [effect], {"Pf_N": 0.02, **params}, free_pf=False)
    r = _diagnose(tmp_path, truth)
    assert r["verdict"]["missing_effect"] == effect, r["verdict"]["message"]
    win = next(c for c in r["candidates"] if c["effect"] == effect)
    assert win["cv_rmse_not_irregular"] <= 1.2 * NOISE


def _prototype_secondary_forty():
    """Return (base, truth, design): the demo's base (P_f free, its protocol), it + a secondary constraint at
    the effect's start values (the prototype's, seed 002 Table 2) and the 40-condition design."""
    from capsule_cli.steps.diagnose import all_effects
    from capsule_cli.steps.synth import read_design

    root = Path(__file__).resolve().parents[1]
    base = build_model(root / "configs/models/progression_base.yaml")
    eff = next(e for e in all_effects("progression") if e.name == "secondary_constraint")
    design = read_design(root / "configs/designs/progression_grid.csv", "progression")
    return base, base.with_effect(eff).with_values({}), design


def _diagnose_secondary(tmp_path, base, df):
    """Return diagnose (full effort, the secondary constraint the one candidate) of ``base`` on ``df``."""
    path = tmp_path / "sec40_synthetic.csv"
    df.to_csv(path, index=False)
    return DL.run_diagnose(base, df, str(path), tmp_path / "d", k_folds=5, seed=0, figures=False,
                           budget=DL.EFFORTS["full"], candidates=["secondary_constraint"])


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "known miss (issue 12), a needle: data made by this engine from exact rest repeat its own chaotic paths, "
    "so only the exact truth fits the 11 irregular conditions (Cauchy loss 10 there, 110-200 at 0.1 % from "
    "it in any parameter); the fit stops at G_2 = 0.106 mm, k_b = 1.01e5 N/m, held-out 1.54 mm/s on the "
    "predictable conditions against the noise 0.5. Data from an independent simulator (its own rounding) do "
    "not repeat those paths: the test below"))
def test_prototype_secondary_constraint_on_forty_conditions_fits_to_noise(tmp_path):
    """A secondary constraint at the prototype's values (G_2 = 0.1 mm, k_b = 97.06 N/mm, c_b = 0.35 N s/m;
    seed 002 Table 2), hidden in the 40-condition design (configs/designs/progression_grid.csv), one value per
    condition, full effort. Before the base re-fit start (P_f by the median absolute residual, the effect at its
    start values) and the starting-state spread on periodic conditions, the fit stopped at G_2 = 0.139 mm and
    k_b = 2.7e5 N/m (held-out 12.2 mm/s on the conditions that are not irregular); now at the truth, held-out
    0.55 against the noise 0.5 (measured, session 8: 37 s of one candidate)."""
    base, truth, design = _prototype_secondary_forty()
    r = _diagnose_secondary(tmp_path, base, DL.synthesize_progression(truth, design, NOISE, 1, 4))
    assert r["verdict"]["missing_effect"] == "secondary_constraint", r["verdict"]["message"]
    win = r["candidates"][0]
    assert win["params"]["gap_back_mm"]["value"] == pytest.approx(0.1, rel=0.05)
    assert win["params"]["constraint_back_N_m"]["value"] == pytest.approx(97060.0, rel=0.05)
    assert win["cv_rmse_not_irregular"] <= 1.2 * NOISE


@pytest.mark.slow
def test_prototype_secondary_constraint_from_an_independent_rest_fits_to_noise(tmp_path):
    """The same hidden secondary constraint (seed 002 Table 2) and 40-condition design, the data run from a start
    1 nm from rest, as an independent simulator's rounding would (its chaotic conditions take other paths than
    this engine's; the periodic ones are the same), one value per condition: named, G_2 recovered and held-out
    error at the noise on the predictable conditions (issue 12 item 7). Before the robust stage took its scale
    and weights from the start (calibrate), held-out 16.7, 0.76, 4.5 and 0.49 mm/s on noise seeds 0-3 (G_2
    0.103-0.113 mm); now 0.40, 0.38, 0.52, 0.46 (G_2 0.1003-0.1032 mm, k_b 2-8 % from the truth)."""
    base, truth, design = _prototype_secondary_forty()
    b = DL.DynBound(truth, design.assign(velocity_mm_s=0.0), where="design")
    c = b.conditions
    run = dsys.progression(b.system(None), c["f_Hz"].to_numpy(float), c["Pd_N"].to_numpy(float),
                           protocol=b.protocol, options=b.options, start_offset_m=np.full(len(c), 1e-9))
    rng = np.random.default_rng(0)
    df = design.assign(velocity_mm_s=run["velocity_mm_s"].to_numpy(float)[b.cond_index]
                       + NOISE * rng.standard_normal(len(design)))
    r = _diagnose_secondary(tmp_path, base, df)
    assert r["verdict"]["missing_effect"] == "secondary_constraint", r["verdict"]["message"]
    win = r["candidates"][0]
    assert win["params"]["gap_back_mm"]["value"] == pytest.approx(0.1, rel=0.05)
    assert win["cv_rmse_not_irregular"] <= 1.2 * NOISE
