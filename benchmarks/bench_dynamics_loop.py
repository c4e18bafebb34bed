"""Benchmark of the dynamics loop (issue 12 item 5 and item 7's false-alarm rate); not a test.

Usage:
    python benchmarks/bench_dynamics_loop.py time [--replicates 2] [--truth MODEL.yaml] [--out FILE.json]
        diagnose over the built-in dynamics candidates on the 40-condition progression design
        (configs/designs/progression_grid.csv: 10 frequencies x 4 amplitudes), hidden
        speed_dependent_friction (configs/models/progression_sdf_truth.yaml; --truth: another true model,
        e.g. one with a viscous drag), default budget; reports wall time, per-candidate time and budget.
        --replicates 1: one value per condition, so the noise is bounded from differences first and every
        fit is refined once the fits have revised it (dynamics_loop.refit_progression): the slower case.
    python benchmarks/bench_dynamics_loop.py false-alarms --seeds 20 [--conditions 12]
        null data (base model true) over seeds; reports how often diagnose names an effect.

Times depend on the machine's load: measure on a quiet machine.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from capsule_cli.effects.model import build_model  # noqa: E402
from capsule_cli.steps import dynamics_loop as DL  # noqa: E402
from capsule_cli.steps.synth import read_design  # noqa: E402

NOISE = 0.5


def bench_time(out: str | None, effort: str = "full", replicates: int = 2, truth_path: str | None = None) -> dict:
    truth = build_model(truth_path or ROOT / "configs/models/progression_sdf_truth.yaml")
    base = build_model(ROOT / "configs/models/progression_base.yaml")
    design = read_design(ROOT / "configs/designs/progression_grid.csv", "progression")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        df = DL.synthesize_progression(truth, design, NOISE, replicates, 0)
        t_synth = time.perf_counter() - t0
        path = Path(tmp) / "progression_synthetic.csv"
        df.to_csv(path, index=False)
        t0, c0 = time.perf_counter(), time.process_time()
        r = DL.run_diagnose(base, df, str(path), Path(tmp) / "diag", k_folds=5, seed=0, figures=False,
                            budget=DL.EFFORTS[effort], quiet=False)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rec = {"truth": str(truth_path or "configs/models/progression_sdf_truth.yaml"),
           "conditions": int(len(design)), "replicates": replicates, "rows": int(len(df)), "synth_s": t_synth, "diagnose_s": wall,
           "diagnose_cpu_s": cpu, "effort": effort, "budget": r["budget"], "verdict": r["verdict"],
           "candidates": [{k: c[k] for k in ("effect", "cv_rmse", "seconds", "evaluations", "passes")}
                          for c in r["candidates"]],
           "skipped": r["skipped_candidates"]}
    print(json.dumps(rec, indent=2, default=str))
    if out:
        Path(out).write_text(json.dumps(rec, indent=2, default=str))
    return rec


def bench_false_alarms(seeds: int, conditions: int) -> dict:
    import yaml

    f = np.linspace(26, 38, max(conditions // 2, 2))
    design = pd.DataFrame({"f_Hz": np.tile(f, 2), "Pd_N": np.repeat([0.15, 0.25], f.size)})
    alarms, t0 = [], time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        proto = {"start": "rest", "transient_periods": 40, "recorded_periods": 16}
        for name, params in (("truth", {"Pf_N": 0.02}),
                             ("base", {"Pf_N": {"value": 0.03, "free": True, "bounds": [0.001, 0.2]}})):
            doc = {"kind": "progression", "base": "one_sided", "effects": [], "params": params, "protocol": proto}
            (Path(tmp) / f"{name}.yaml").write_text(yaml.safe_dump(doc))
        truth, base = build_model(Path(tmp) / "truth.yaml"), build_model(Path(tmp) / "base.yaml")
        budget = DL.Budget(scan_per_param=4, starts=2, evals_per_param=20, fold_evals_per_param=8, bootstrap=0)
        for s in range(seeds):
            df = DL.synthesize_progression(truth, design, NOISE, 2, 1000 + s)
            path = Path(tmp) / f"null_{s}_synthetic.csv"
            df.to_csv(path, index=False)
            r = DL.run_diagnose(base, df, str(path), Path(tmp) / f"d{s}", k_folds=3, seed=s, figures=False,
                                budget=budget)
            alarms.append(r["verdict"]["missing_effect"])
            print(f"seed {s}: {r['verdict']['missing_effect']}", flush=True)
    n = sum(a is not None for a in alarms)
    rec = {"seeds": seeds, "false_alarms": n, "rate": n / seeds, "named": [a for a in alarms if a],
           "seconds": time.perf_counter() - t0}
    print(json.dumps(rec, indent=2))
    return rec


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=("time", "false-alarms"))
    ap.add_argument("--out", default=None)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--conditions", type=int, default=12)
    ap.add_argument("--effort", default="full", choices=sorted(DL.EFFORTS))
    ap.add_argument("--replicates", type=int, default=2)
    ap.add_argument("--truth", default=None, help="true model file of the timed data (default: hidden speed law)")
    a = ap.parse_args()
    if a.what == "time":
        bench_time(a.out, a.effort, a.replicates, a.truth)
    else:
        bench_false_alarms(a.seeds, a.conditions)


if __name__ == "__main__":
    main()
