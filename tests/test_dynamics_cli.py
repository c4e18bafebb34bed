"""capsule-cli simulate / sweep / magnify / dynamics-report: files, units, exit codes (contract sections 2, 5)."""
import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from capsule_cli.cli import main
from capsule_cli.tables import read_table


def test_simulate_writes_tables_with_units(tmp_path):
    out = tmp_path / "run"
    assert main(["simulate", "--out", str(out), "--f-Hz", "35", "--periods", "5", "--transient-periods", "20",
                 "--sample-rate-Hz", "2000", "--quiet"]) == 0
    for name in ("trajectory.parquet", "events.parquet", "periods.parquet", "summary.json"):
        assert (out / name).is_file()
    units = {f.name: (f.metadata or {}).get(b"unit", b"").decode() for f in pq.read_schema(out / "trajectory.parquet")}
    assert units["capsule_mm"] == "mm" and units["Fi_N"] == "N" and units["magnet_velocity_mm_s"] == "mm/s"
    tr = read_table(out / "trajectory.parquet")
    assert len(tr) == int(5 / 35 * 2000) + 1
    s = json.loads((out / "summary.json").read_text())
    assert s["impacts_per_period"] == 1.0 and abs(s["energy_balance"]["relative_residual"]) < 1e-10


def test_simulate_tables_equal_the_dataframe_run_and_skip_pandas(tmp_path):
    """The command's array path (issue 13 start-up) writes what simulate()'s DataFrames hold; no pandas import."""
    import subprocess
    import sys

    import numpy as np

    from capsule_cli.dynamics import Drive, friction_preset, load_model, simulate

    out = tmp_path / "run"
    code = ("import sys; from capsule_cli.cli import main; rc = main(sys.argv[1:]); "
            "assert 'pandas' not in sys.modules and 'matplotlib' not in sys.modules, 'heavy import'; "
            "sys.exit(rc)")
    r = subprocess.run([sys.executable, "-c", code, "simulate", "--out", str(out), "--f-Hz", "35", "--Pd-N", "0.15",
                        "--Pf-N", "0.0078", "--periods", "4", "--transient-periods", "10", "--quiet"],
                       capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1])
    assert r.returncode == 0, r.stderr
    m, _ = load_model("prototype_one_sided")
    res = simulate(m, Drive(0.15, 35.0), friction_preset("coulomb", 0.0078), periods=4, transient_periods=10,
                   sample_rate_Hz=5000.0)
    ev = res.events.copy()
    ev["kind"] = ev["kind"].astype("string")
    for name, df in (("trajectory", res.trajectory), ("events", ev), ("periods", res.periods)):
        got = read_table(out / f"{name}.parquet")
        assert list(got.columns) == list(df.columns) and len(got) == len(df) > 0
        for c in df.columns:
            assert np.array_equal(got[c].to_numpy(), df[c].to_numpy()), (name, c)
    s = json.loads((out / "summary.json").read_text())
    assert s["average_velocity_mm_s"] == res.average_velocity_mm_s
    assert s["n_events"] == len(res.events) and s["max_Fi_N"] == res.periods["max_Fi_N"].max()


def test_sweep_and_report(tmp_path):
    d = tmp_path / "sw"
    assert main(["sweep", "--out", str(d), "--start", "30", "--stop", "36", "--num", "4", "--protocol", "up",
                 "--transient-periods", "100", "--periods", "10", "--quiet"]) == 0
    pts = read_table(d / "points.parquet")
    assert list(pts["value"]) == [30.0, 32.0, 34.0, 36.0]
    assert (pts["impacts_per_period"] == 1).all()
    rep = tmp_path / "rep"
    assert main(["dynamics-report", "--out", str(rep), "--sweep", f"c:fig17:up:{d}", "--quiet"]) == 0
    lm = read_table(rep / "landmarks.parquet")
    assert set(lm["landmark"]) >= {"onset of forward progression"}
    assert (rep / "fig17_up.png").is_file()


@pytest.mark.parametrize("args", [
    ["simulate", "--friction", "eq22", "--literal", "--periods", "3"],
    ["simulate", "--f-Hz", "-1"],
    ["simulate", "--set", "bogus_mm=1"],
    ["sweep", "--start", "1", "--stop", "2", "--param", "nonsense"],
    ["simulate", "--model", "no_such_set"],
])
def test_bad_input_exits_2_and_writes_nothing(tmp_path, args, capsys):
    out = tmp_path / "x"
    assert main(args + ["--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("capsule-cli: error:")
    assert not out.exists() or not any(out.iterdir())


def test_schema_defaults_validate():
    from capsule_cli.schemas.dynamics import DynamicsStudy
    s = DynamicsStudy()
    assert {c.label for c in s.frequency_sweeps.cases} == {"coulomb_7p8mN", "eq22", "eq22_V_in_m_s",
                                                             "coulomb_2p5N", "eq23", "eq23_V_in_m_s"}
    with pytest.raises(Exception):
        DynamicsStudy.model_validate({"frequency_sweep": {}})


def test_bench_json_reports_contract_keys_and_accuracy(capsys):
    """contract section 6: one JSON object; accuracy targets of issue 4 (event times 1e-9 s, average
    velocity 1e-6 relative on period-1 runs). Timing ratios are not asserted (benchmarks, not tests)."""
    assert main(["bench", "--json", "--engine-periods", "20", "--baseline-periods", "2"]) == 0
    rec = json.loads(capsys.readouterr().out)
    for key in ("periods_per_s", "baseline_periods_per_s", "speedup", "max_event_time_error_s", "max_state_error"):
        assert isinstance(rec[key], float), key
    assert rec["max_event_time_error_s"] < 1e-9
    assert rec["period1_runs"] >= 1 and rec["period1_velocity_max_rel_error"] < 1e-6
    assert all(r["event_sequence_matches"] for r in rec["per_frequency"])
    assert any(r["impacting"] for r in rec["per_frequency"]) and any(not r["impacting"] for r in rec["per_frequency"])


def test_magnify_writes_table_and_figure(tmp_path):
    out = tmp_path / "mag.parquet"
    fig = tmp_path / "mag.png"
    assert main(["magnify", "--out", str(out), "--figure", str(fig), "--Pf-N", "0.007", "--Pf-N", "inf",
                 "--Pd-num", "2", "--f-start-Hz", "28", "--f-stop-Hz", "32", "--f-num", "3",
                 "--transient-periods", "50", "--periods", "5", "--quiet"]) == 0
    df = read_table(out)
    assert len(df) == 2 * 2 * 3 and set(df["Pf_N"]) == {0.007, float("inf")}
    assert (df["Af"] == df["max_Fi_N"] / df["Pd_N"]).all()
    assert fig.stat().st_size > 5000


def test_magnify_without_a_friction_takes_the_model_files_level(tmp_path):
    """simulate and sweep take the model's P_f when no --Pf-N is given; so does magnify (it took Fig 19's
    0.007 N whatever the model file said). Same model file, same point: A_f equals simulate's."""
    mf = tmp_path / "m.yaml"
    mf.write_text("kind: progression\nbase: one_sided\neffects: [viscous_drag]\n"
                  "params:\n  Pf_N: {value: 0.02}\n  drag_Ns_m: 0.05\n")
    out = tmp_path / "mag.parquet"
    assert main(["magnify", "--model", str(mf), "--out", str(out), "--Pd-start-N", "0.15", "--Pd-num", "1",
                 "--f-start-Hz", "30", "--f-num", "1", "--transient-periods", "0", "--periods", "5",
                 "--settle-tol", "0", "--quiet"]) == 0
    df = read_table(out)
    assert list(df["Pf_N"]) == [0.02]
    assert main(["simulate", "--model", str(mf), "--out", str(tmp_path / "s"), "--Pd-N", "0.15", "--f-Hz", "30",
                 "--periods", "5", "--quiet"]) == 0
    s = json.loads((tmp_path / "s" / "summary.json").read_text())
    assert df["Af"].iloc[0] == pytest.approx(s["Af"], rel=1e-12)


def test_contract_dynamics_model_file_runs_as_written(tmp_path):
    """contract section 4: the progression model file is accepted as written; it is the seed 000
    Table 2 model with P_f = 7.8 mN, so it must reproduce the parameter-set run exactly."""
    a, b = tmp_path / "a", tmp_path / "b"
    common = ["--f-Hz", "35", "--periods", "5", "--transient-periods", "50", "--sample-rate-Hz", "0", "--quiet"]
    assert main(["simulate", "--model", str(Path(__file__).resolve().parents[1] / "configs/models/progression_one_sided.yaml"), "--out", str(a)] + common) == 0
    assert main(["simulate", "--model", "prototype_one_sided", "--out", str(b)] + common) == 0
    sa = json.loads((a / "summary.json").read_text())
    sb = json.loads((b / "summary.json").read_text())
    assert sa["average_velocity_mm_s"] == sb["average_velocity_mm_s"] != 0.0
    bad = tmp_path / "bad.yaml"
    bad.write_text("kind: progression\nbase: three_sided\neffects: []\nparams: {}\n")
    assert main(["simulate", "--model", str(bad), "--out", str(tmp_path / "c"), "--quiet"]) == 2


def test_simulate_figure(tmp_path, capsys):
    """--figure draws the run (time series with events, phase portrait); bad figure paths exit 2."""
    out, fig = tmp_path / "run", tmp_path / "run.png"
    assert main(["simulate", "--f-Hz", "35", "--periods", "4", "--transient-periods", "20", "--out", str(out),
                 "--figure", str(fig), "--figure-periods", "2", "--quiet"]) == 0
    assert fig.is_file() and fig.stat().st_size > 20000
    from matplotlib.image import imread
    img = imread(fig)
    assert img.shape[1] > img.shape[0] > 500  # a page-wide figure
    assert main(["simulate", "--periods", "2", "--out", str(tmp_path / "r2"), "--figure",
                 str(tmp_path / "run.txt"), "--quiet"]) == 2
    assert main(["simulate", "--periods", "2", "--out", str(tmp_path / "r3"), "--figure", str(fig),
                 "--sample-rate-Hz", "0", "--quiet"]) == 2
    assert not (tmp_path / "r2").exists() and not (tmp_path / "r3").exists()
