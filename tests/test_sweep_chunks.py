"""Chunked runs equal unchunked ones exactly (issue 13): the parallel runner, magnify chunks along P_d
gathered into one table, and the vectorised per-point summaries against the per-point reference."""
import numpy as np
import pandas as pd
import pytest

from capsule_cli.cli import main
from capsule_cli.dynamics import engine as E
from capsule_cli.dynamics.model import Drive, EngineOptions, friction_preset, load_model, pack_params
from capsule_cli.dynamics.parallel import period_numbers, run_points, summarize
from capsule_cli.dynamics.sweep import period_number
from capsule_cli.steps.dynamics import Pd_chunks, magnify_table, plan_magnify_jobs
from capsule_cli.tables import read_table


MODEL, _ = load_model("prototype_one_sided")


def _grid(fr, Pd=(0.05, 0.2, 0.4), f=(22.0, 30.0, 38.0)):
    return np.array([pack_params(MODEL, Drive(a, b), fr) for a in Pd for b in f])


@pytest.mark.parametrize("chunk", [1, 2, 4, None])
def test_run_points_chunking_is_exact(chunk):
    """Any chunk size (and the adaptive one) gives the single-call result bit for bit."""
    P = _grid(friction_preset("coulomb", 0.17))
    opts = EngineOptions(energy=False).pack()
    s0 = np.zeros((len(P), 4))
    st, per, _, fin = E.run_many(P, opts, s0, 40, 6)
    seen = []
    st2, per2, fin2 = run_points(P, opts, s0, 40, 6, progress=seen.append, chunk=chunk)
    assert np.array_equal(st, st2) and (st == E.STATUS_OK).all()
    assert np.array_equal(per, per2) and np.array_equal(fin, fin2)
    assert sum(seen) == len(P) and (chunk is None or max(seen) <= chunk)


def test_chunks_grow_at_most_twofold():
    """A rate measured on a few cheap points (2 points in 2 ms) asks for 200 points per 0.2 s chunk; point costs
    differ by tens of times across a map, so the next chunk is at most twice the last (one was 1468 points and
    5 s long: no interrupt, no progress meanwhile). Without a last chunk, and where the rate asks for fewer,
    the rate decides; never fewer than the threads, never more than what remains."""
    from capsule_cli.dynamics.parallel import _next_size
    assert _next_size(2, 0.002, 0.2, 10_000, 2, last=2) == 4
    assert _next_size(2, 0.002, 0.2, 10_000, 2) == 200
    assert _next_size(100, 1.0, 0.2, 10_000, 2, last=100) == 20
    assert _next_size(100, 100.0, 0.2, 10_000, 2, last=100) == 2
    assert _next_size(2, 0.002, 0.2, 3, 2, last=2) == 3
    assert _next_size(0, 0.0, 0.2, 10_000, 2) == 2


def test_run_many_dealt_to_threads_returns_points_in_order(monkeypatch):
    """The wrapper deals points i, i + T, ... to thread i and puts the results back: bit for bit the engine's
    own prange in the given order, for any number of points. T = 3 whatever the engine runs on (one thread per
    test worker, tests/conftest.py): the dealing and its inverse are what is tested."""
    from capsule_cli.dynamics import parallel
    from capsule_cli.dynamics.parallel import run_many
    monkeypatch.setattr(parallel.numba, "get_num_threads", lambda: 3)
    P = _grid(friction_preset("coulomb", 0.007), Pd=(0.05, 0.1, 0.2, 0.3, 0.4), f=(18.0, 26.0, 34.0))
    opts = EngineOptions(energy=False).pack()
    for n in (1, 2, 7, len(P)):
        s0 = np.zeros((n, 4))
        a = E.run_many(P[:n], opts, s0, 30, 4)
        b = run_many(P[:n], opts, s0, 30, 4)
        for x, y in zip(a, b):
            assert np.array_equal(x, y)


def test_summaries_match_the_per_point_functions():
    P = _grid(friction_preset("eq23"))
    opts = EngineOptions(energy=False).pack()
    st, per, _ = run_points(P, opts, np.zeros((len(P), 4)), 60, 12)
    Pd, f = P[:, E.I_PD], P[:, E.I_F]
    sm = summarize(per, Pd, f)
    for i in range(len(P)):
        r = per[i]
        assert sm["period_number"][i] == period_number(r[:, E.P_XR0], r[:, E.P_VR0])
        assert sm["velocity_mm_s"][i] == r[:, E.P_DISP].sum() / (len(r) * (1.0 / f[i])) * 1e3
        assert sm["Af"][i] == r[:, E.P_MAXF].max() / Pd[i]
    assert sm["impacts_per_period"].max() >= 1.0  # the grid has impacting points


def test_period_numbers_known_sequences():
    t = np.arange(12)
    xr = np.vstack([np.full(12, 1e-3), 1e-3 * (t % 2), 1e-3 * (t % 3), 1e-3 * np.sin(t * 1.234)])
    assert list(period_numbers(xr, xr)) == [1, 2, 3, 0]


def test_Pd_chunks_cover_the_grid():
    assert Pd_chunks(10, 3) == [(0, 3), (3, 7), (7, 10)]
    assert Pd_chunks(2, 5) == [(0, 1), (1, 2)]
    assert Pd_chunks(7, 1) == [(0, 7)]


@pytest.mark.parametrize("protocol", ["rest", "up"])
def test_magnify_chunks_gathered_equal_unchunked(tmp_path, protocol):
    """Chunks along P_d (each running the whole f axis) joined by --gather equal one unchunked run,
    for every-point-from-rest and for continuation in f."""
    common = ["--law", "eq22", "--Pf-N", "inf", "--Pd-num", "3", "--f-start-Hz", "20", "--f-stop-Hz", "36",
              "--f-num", "4", "--transient-periods", "40", "--periods", "6", "--protocol", protocol, "--quiet"]
    full = tmp_path / "full.parquet"
    assert main(["magnify", "--out", str(full), *common]) == 0
    parts = []
    for a, b in Pd_chunks(3, 2):
        p = tmp_path / f"c{a}.parquet"
        assert main(["magnify", "--out", str(p), "--Pd-rows", f"{a}:{b}", *common]) == 0
        parts.append(p)
    g = tmp_path / "gathered.parquet"
    assert main(["magnify", "--out", str(g), "--gather", str(parts[1]), "--gather", str(parts[0]), "--quiet"]) == 0
    A, B = read_table(full), read_table(g)
    pd.testing.assert_frame_equal(A, B, check_exact=True)
    assert list(A["friction"].unique()) == ["inf", "eq22"] and set(A["protocol"]) == {protocol}
    assert len(A) == 2 * 3 * 4 and np.isnan(A[A["friction"] == "eq22"]["Pf_N"]).all()
    # overlapping chunks are refused, exit 2
    assert main(["magnify", "--out", str(tmp_path / "x.parquet"), "--gather", str(parts[0]), "--gather",
                 str(parts[0]), "--quiet"]) == 2


def test_magnify_table_rows_equal_the_sweep_points():
    """A magnify row is the same computation as a sweep point over f from rest (same engine calls and
    options: the maps' settled-transient tolerance)."""
    from capsule_cli.dynamics.model import STEADY_SETTLE_TOL, EngineOptions
    from capsule_cli.dynamics.sweep import run_sweep

    f = np.array([24.0, 30.0, 36.0])
    df = magnify_table(MODEL, [0.15], f, ["2.5"], "rest", 50, 8)
    sw = run_sweep(MODEL, Drive(0.15, 24.0), friction_preset("coulomb", 2.5), "f_Hz", f, "rest", 50, 8,
                   options=EngineOptions(settle_tol=STEADY_SETTLE_TOL))
    assert np.array_equal(df["Af"].to_numpy(), sw.points["Af"].to_numpy())
    assert np.array_equal(df["velocity_mm_s"].to_numpy(), sw.points["velocity_mm_s"].to_numpy())


def test_magnify_bad_inputs_exit_2(tmp_path):
    out = str(tmp_path / "m.parquet")
    assert main(["magnify", "--out", out, "--law", "eq24", "--Pd-num", "1", "--f-num", "1", "--quiet"]) == 2
    assert main(["magnify", "--out", out, "--Pd-rows", "2:1", "--Pd-num", "3", "--f-num", "1", "--quiet"]) == 2
    assert main(["magnify", "--out", out, "--Pf-N", "-1", "--Pd-num", "1", "--f-num", "1", "--quiet"]) == 2
    assert not (tmp_path / "m.parquet").exists()


def test_plan_splits_costly_maps_and_groups_tiny_ones():
    cost = {"coulomb": 10.0, "fixed": 10.0, "eq22": 1000.0, "eq23": 1000.0}
    jobs = plan_magnify_jobs(["0.007", "2.5", "inf", "eq22"], 10, 10, 100, cost, target_job_s=0.5, threads=2)
    # Coulomb/fixed maps: 10*10*100*10e-6/2 = 0.05 s each -> one job; eq22: 5 s -> 10 chunks of 1 row
    assert jobs[0]["frictions"] == ["0.007", "2.5", "inf"] and jobs[0]["rows"] == (0, 10)
    eq = [j for j in jobs if j["frictions"] == ["eq22"]]
    assert [j["rows"] for j in eq] == [(i, i + 1) for i in range(10)]
    assert abs(sum(j["est_s"] for j in jobs) - (3 * 0.05 + 5.0)) < 1e-9
    assert len({j["name"] for j in jobs}) == len(jobs)


def test_planned_jobs_gathered_equal_the_unchunked_map(tmp_path):
    """The Snakemake path: jobs from the cost plan (a split speed-law map, grouped Coulomb maps),
    continuation protocol, gathered in the config's friction order == one unchunked call."""
    fr = ["0.17", "eq23", "inf"]
    grid = ["--Pd-num", "4", "--f-start-Hz", "24", "--f-stop-Hz", "36", "--f-num", "3", "--transient-periods", "30",
            "--periods", "5", "--protocol", "down", "--quiet"]
    fargs = ["--Pf-N", "0.17", "--law", "eq23", "--Pf-N", "inf"]
    cost = {"coulomb": 10.0, "fixed": 10.0, "eq22": 1000.0, "eq23": 1000.0}
    jobs = plan_magnify_jobs(fr, 4, 3, 35, cost, target_job_s=0.05)
    assert len(jobs) == 5  # Coulomb + fixed grouped; eq23 (0.42 s > 0.05 s) in 4 chunks of one P_d row
    parts = []
    for j in jobs:
        p = tmp_path / f"{j['name']}.parquet"
        ja = []
        for x in j["frictions"]:
            ja += ["--law", x] if x.startswith("eq") else ["--Pf-N", x]
        assert main(["magnify", "--out", str(p), *ja, "--Pd-rows", "{}:{}".format(*j["rows"]), *grid]) == 0
        parts.append(p)
    g = tmp_path / "g.parquet"
    assert main(["magnify", "--out", str(g), *fargs, *sum((["--gather", str(p)] for p in parts[::-1]), []),
                 "--quiet"]) == 0
    full = tmp_path / "full.parquet"
    assert main(["magnify", "--out", str(full), *fargs, *grid]) == 0
    pd.testing.assert_frame_equal(read_table(full), read_table(g), check_exact=True)
    # a missing chunk is an incomplete map: exit 2
    assert main(["magnify", "--out", str(tmp_path / "x.parquet"), *fargs,
                 *sum((["--gather", str(p)] for p in parts[:-1]), []), "--quiet"]) == 2


def test_slurm_profile_dry_run_lists_chunked_jobs():
    """`snakemake -n --profile workflow/profiles/slurm` works without a cluster and lists the map jobs
    of the cost plan and the grouped small jobs (--forceall: the same listing after `make study` has run)."""
    import os
    import re
    import subprocess
    import sys
    from pathlib import Path

    from capsule_cli.config import validate_study_config, read_yaml

    repo = Path(__file__).resolve().parents[1]
    snk = Path(sys.executable).with_name("snakemake")
    r = subprocess.run([str(snk), "-n", "--forceall", "--profile", "workflow/profiles/slurm"], cwd=repo,
                       capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(repo)}, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    mg = validate_study_config(read_yaml(repo / "configs/study.yaml")).dynamics.magnify
    plan = plan_magnify_jobs([f"{p:g}" for p in mg.Pf_N] + list(mg.laws), mg.Pd_num, mg.f_num,
                             mg.transient_periods + mg.recorded_periods, mg.cost_us_per_period, mg.target_job_s,
                             mg.threads_per_job)
    out = r.stdout + r.stderr
    n = re.search(r"dynamics_magnify_chunk\s+(\d+)", out)
    assert n and int(n.group(1)) == len(plan) > 1
    assert "Group job small" in out
