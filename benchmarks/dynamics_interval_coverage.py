"""Coverage of compare's 95 % parameter intervals on dynamics data (issue 12 item 3; a benchmark, not a test).

Each data set is made by a true model (the contract's one-sided Coulomb base, P_f = 7.8 mN, with one effect) and
given to ``compare`` with the same model, every parameter free and started at the truth, at the CLI's default
effort (``--effort full``: 20 bootstrap refits). Recorded per data set: each free parameter's fit, 95 % interval and
standard error, and whether the interval holds the truth; in the summary, per parameter, how many intervals hold
it (with a Clopper-Pearson 95 % interval of the rate), the SD of the fits over the data sets against the mean
standard error reported, and the RMS of (fit - truth) / SE (about 1.06 when the SEs are right: t with 19 degrees
of freedom).

    drag_traj: a viscous drag of 0.03 N s/m, configs/designs/trajectory_runs.csv (four 1-s runs from rest),
        100 frames per second, position noise 0.3 mm
    speed_progression: a speed law (a 3 mN, n 0.6), configs/designs/progression_grid.csv (10 frequencies x 4
        amplitudes), one value per condition, protocol rest 120/60 periods, noise 0.5 mm/s
    base_small: the base alone (P_f the one free parameter), configs/designs/progression_periodic_small.csv (six
        conditions), one value per condition, rest 120/60, noise 0.5 mm/s: a small design, whose noise estimate
        has 5 degrees of freedom (dynamics_loop.interval_dof)

Usage:
    python benchmarks/dynamics_interval_coverage.py --case drag_traj [--seeds 40] [--first-seed 0]
        [--effort full] [--out benchmarks/dynamics_interval_coverage_drag_traj_result.json]

The result JSON is rewritten after every data set. Seconds per data set: drag_traj 10-30, speed_progression
90-150.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from scipy.stats import beta

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from capsule_cli.effects.model import build_model  # noqa: E402
from capsule_cli.steps import dynamics_loop as DL  # noqa: E402

PF_N = 0.0078  # the contract's base friction level (physics.md section 3, seed 000 section 5.3)
PROTOCOL = {"start": "rest", "transient_periods": 120, "recorded_periods": 60}
CASES = {  # kind, effects, effect values, noise (mm or mm/s), design
    "drag_traj": ("trajectory", ["viscous_drag"], {"drag_Ns_m": 0.03}, 0.3, "trajectory_runs.csv"),
    "speed_progression": ("progression", ["speed_dependent_friction"], {"a_mN": 3.0, "n": 0.6}, 0.5,
                          "progression_grid.csv"),
    "base_small": ("progression", [], {}, 0.5, "progression_periodic_small.csv"),
}


def _model(tmp: Path, name: str, kind: str, effects, params) -> object:
    doc = {"kind": kind, "base": "one_sided", "effects": list(effects), "params": params}
    if kind == "progression":
        doc["protocol"] = PROTOCOL
    (tmp / f"{name}.yaml").write_text(yaml.safe_dump(doc))
    return build_model(tmp / f"{name}.yaml")


def clopper_pearson(k: int, n: int) -> list[float]:
    """Return the exact 95 % interval of a rate from k successes in n trials."""
    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(0.975, k + 1, n - k))
    return [lo, hi]


def summary(rows: list[dict]) -> dict:
    out = {}
    for key in rows[0]["params"]:
        recs = [r["params"][key] for r in rows if r["params"][key]["ci95"]]
        held = sum(bool(p["holds"]) for p in recs)
        fits = np.array([p["fit"] for p in recs])
        se = np.array([p["se"] for p in recs])
        z = (fits - np.array([p["truth"] for p in recs])) / se
        out[key] = {"held": held, "of": len(recs), "rate": held / len(recs) if recs else None,
                    "rate_ci95": clopper_pearson(held, len(recs)) if recs else None,
                    "sd_of_fits": float(np.std(fits, ddof=1)) if fits.size > 1 else None,
                    "mean_se": float(se.mean()) if se.size else None,
                    "rms_z": float(math.sqrt(np.mean(z ** 2))) if z.size else None}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", default="drag_traj", choices=sorted(CASES))
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--effort", default="full", choices=sorted(DL.EFFORTS))
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    kind, effects, values, noise, design = CASES[a.case]
    truth_values = {"Pf_N": PF_N, **values}
    out = Path(a.out or ROOT / "benchmarks" / f"dynamics_interval_coverage_{a.case}_result.json")
    rows, t0 = [], time.perf_counter()
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        truth = _model(tmp, "truth", kind, effects, truth_values)
        fitted = _model(tmp, "fit", kind, effects, {"Pf_N": {"value": PF_N, "free": True, "bounds": [0.0, 0.5]},
                                                     **{k: {"value": v, "free": True} for k, v in values.items()}})
        grid = pd.read_csv(ROOT / "configs" / "designs" / design)
        for seed in range(a.first_seed, a.first_seed + a.seeds):
            if kind == "trajectory":
                df = DL.synthesize_trajectory(truth, grid, noise, 100.0, 1000 + seed)
            else:
                df = DL.synthesize_progression(truth, grid, noise, 1, 2000 + seed)
            path = tmp / f"{a.case}_{seed}_synthetic.csv"
            df.to_csv(path, index=False)
            t1 = time.perf_counter()
            met = DL.run_compare(fitted, df, str(path), tmp / f"c_{seed}", k_folds=5, seed=0, figures=False,
                                 budget=DL.EFFORTS[a.effort])
            params = {}
            for key, rec in met["params"].items():
                if rec.get("free"):
                    ci = rec.get("ci95")
                    params[key] = {"truth": truth_values[key], "fit": rec["value"], "ci95": ci, "se": rec["stderr"],
                                   "holds": bool(ci[0] <= truth_values[key] <= ci[1]) if ci else None}
            rows.append({"seed": seed, "params": params, "cv_rmse": met["cv_rmse"], "intervals": met["intervals"],
                         "seconds": round(time.perf_counter() - t1, 1)})
            print(f"seed {seed}: " + ", ".join(f"{k} {'holds' if p['holds'] else 'MISSES'}" for k, p in params.items()),
                  flush=True)
            rec = {"what": "coverage of compare's 95 % parameter intervals on dynamics data",
                   "case": a.case, "kind": kind, "effects": effects, "truth": truth_values, "noise": noise,
                   "design": design, "effort": a.effort, "data_sets": len(rows),
                   "summary": summary(rows), "seconds": round(time.perf_counter() - t0, 1), "runs": rows}
            out.write_text(json.dumps(rec, indent=1, default=str))
    print(json.dumps({k: v for k, v in rec.items() if k != "runs"}, indent=1, default=str))


if __name__ == "__main__":
    main()
