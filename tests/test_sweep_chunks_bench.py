"""bench --fig19 and the per-period / per-event figures of bench --json (issue 13 item 2), on tiny
grids: the record's numbers are consistent with each other and with magnify itself."""
import math

import numpy as np
import pytest

from capsule_cli.dynamics.bench import run_bench, run_fig19_bench
from capsule_cli.dynamics.model import load_model
from capsule_cli.steps.dynamics import load_fig19, magnify_table


def test_fig19_bench_record_on_a_subset():
    rec = run_fig19_bench(Pd_num=2, f_num=2, frictions=["0.17", "eq23"], sample_periods=2)
    cfg = load_fig19()
    nt, nr = cfg["transient_periods"], cfg["recorded_periods"]
    assert rec["grid"] == {"Pd_num": 2, "f_num": 2, "frictions": ["0.17", "eq23"], "full_grid": False}
    walls = rec["wall_s_per_friction"]
    assert math.isclose(rec["fig19_wall_s"], sum(walls.values()))
    assert math.isclose(rec["fig19_periods_per_s"], 2 * 2 * 2 * (nt + nr) / rec["fig19_wall_s"])
    full = cfg["Pd_num"] * cfg["f_num"] * len(cfg["frictions"])
    assert math.isclose(rec["fig19_wall_s_extrapolated"], rec["fig19_wall_s"] * full / 8)
    for s in rec["solve_ivp_sample"].values():
        assert s["engine_s"] > 0 and s["solve_ivp_s"] > 0
        assert math.isclose(s["solve_ivp_over_engine"], s["solve_ivp_s"] / s["engine_s"])
        assert s["solve_ivp_timed_out"] is False
    # the peaks are those of the same maps computed by magnify
    m, _ = load_model(cfg["model"])
    Pd = np.linspace(cfg["Pd_start_N"], cfg["Pd_stop_N"], 2)
    f = np.linspace(cfg["f_start_Hz"], cfg["f_stop_Hz"], 2)
    df = magnify_table(m, Pd, f, ["0.17", "eq23"], cfg["protocol"], nt, nr)
    for lab, pk in rec["max_Af_per_friction"].items():
        assert pk["max_Af"] == df[df["friction"] == lab]["Af"].max()


def test_fig19_bench_bounds_a_crawling_solve_ivp_sample():
    """A solve_ivp sample run past its wall-time budget is stopped and reported as a lower bound
    (at the full grid's centre, P_f = 0.17 N, solve_ivp took over a minute for 20 periods and the
    full bench did not finish)."""
    budget = 1e-3
    rec = run_fig19_bench(Pd_num=2, f_num=2, frictions=["2.5"], sample_periods=20, sample_budget_s=budget)
    s = rec["solve_ivp_sample"]["2.5"]
    assert s["solve_ivp_timed_out"] is True
    assert s["solve_ivp_s"] == budget and math.isclose(s["solve_ivp_over_engine"], budget / s["engine_s"])


def test_reference_run_stops_at_its_wall_time_budget():
    from capsule_cli.dynamics.model import Drive, friction_preset
    from capsule_cli.dynamics.reference import ReferenceTimeout, reference_run
    m, _ = load_model("prototype_one_sided")
    with pytest.raises(ReferenceTimeout) as ei:
        reference_run(m, Drive(0.2, 20.0), friction_preset("coulomb", 0.17), 50, max_wall_s=1e-3)
    assert ei.value.periods_done < 50 and ei.value.elapsed_s > 1e-3
    r = reference_run(m, Drive(0.2, 20.0), friction_preset("coulomb", 0.17), 2, max_wall_s=60.0)
    assert len(r.poincare) == 3  # a budget that is not reached changes nothing


def test_bench_reports_us_per_period_and_per_event():
    rec = run_bench(freqs=(30.0,), engine_periods=5, baseline_periods=3, accuracy_periods=1, transient_periods=20,
                    velocity_periods=2, methods=("RK45",), repeat=1, baseline_repeat=2)
    assert math.isclose(rec["us_per_period"], 1e6 / rec["periods_per_s"])
    # at 30 Hz the run impacts every period (contact on and off): at least two events per period
    assert rec["events"] >= 2 * 3
    assert math.isclose(rec["us_per_event"], rec["us_per_period"] * 3 / rec["events"])
    assert rec["baseline_repeat"] == 2
