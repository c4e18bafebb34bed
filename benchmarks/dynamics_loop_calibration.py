"""False-alarm rate of the dynamics loop's verdict (issue 12 item 7); a benchmark, not a test.

Null progression data sets (the base model is the truth: one-sided Coulomb, P_f = 0.02 N, noise 0.5 mm/s,
2 replicates, or ``--replicates 1``) over many seeds and small designs, each given to ``diagnose`` with the base model (P_f free).
Counts the outcomes of :func:`capsule_cli.steps.verdict.decide_verdict` (the rule shared with the
quasi-static loop): a *finding* is a named effect (missing_effect) or a named covariate (not_built_in);
"cannot tell" names nothing and is counted apart. The rule's budget is ALPHA_EFFECT + ALPHA_STRUCTURE = 2 %.

Usage:
    python benchmarks/dynamics_loop_calibration.py --seeds 100 [--effort quick]
        [--candidates secondary_constraint,viscous_drag] [--out benchmarks/dynamics_loop_calibration_result.json]
        [--protocol rest|up|down] [--designs six,ten | sweep] [--kind trajectory --designs runs3,runs4]

The result JSON is rewritten after every seed, so an interrupted run still reports the seeds done.
Designs (alternating over seeds), responses periodic for the base model at P_f = 0.02 N (but one):
    six: f 30, 34, 38 Hz x P_d 0.08, 0.10 N (the CI tests' design)
    ten: f 30, 32, 34, 36, 38 Hz x P_d 0.08, 0.12 N (36 Hz / 0.12 N is irregular, its windows 0.1-0.5 mm/s apart:
         diagnose leaves its replicates out of the noise estimate, steps/dynamics_loop/noise.py:
         replicate_noise_without_chaos)
and, for a continuation protocol, where the sweep's history matters (the end state handed from one frequency to
the next decides the branch: one, several and irregular responses):
    sweep: f 15, 18, 21, 24, 27, 30 Hz x P_d 0.20, 0.25 N

``--kind trajectory``: null trajectories as a camera records them (every run from rest at drive phase 0, 100
frames per second, white position noise POS_NOISE), the runs of one design per seed:
    runs3: 24 Hz / 0.15 N, 32 Hz / 0.20 N, 40 Hz / 0.25 N, 0.6 s each
    runs4: 20 Hz / 0.15 N, 28 Hz / 0.15 N, 36 Hz / 0.20 N, 40 Hz / 0.25 N, 0.5 s each
    long3: 22 Hz / 0.15 N, 30 Hz / 0.20 N, 38 Hz / 0.25 N, 3 s each (``--designs long3``)
``--glitch-frames K``: K frames of each null trajectory set (drawn at random) moved by 2-5 mm either way, as a tracker
that lost the marker for a frame puts them: diagnose should flag and leave them out and say "nothing is missing".
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from capsule_cli.effects.model import build_model  # noqa: E402
from capsule_cli.steps import dynamics_loop as DL  # noqa: E402
from capsule_cli.steps.verdict import ALPHA_EFFECT, ALPHA_STRUCTURE  # noqa: E402

NOISE = 0.5  # generating noise SD [mm/s]
PROTO = {"start": "rest", "transient_periods": 40, "recorded_periods": 16}
DESIGNS = {
    "six": pd.DataFrame({"f_Hz": np.tile([30.0, 34.0, 38.0], 2), "Pd_N": np.repeat([0.08, 0.10], 3)}),
    "ten": pd.DataFrame({"f_Hz": np.tile([30.0, 32.0, 34.0, 36.0, 38.0], 2), "Pd_N": np.repeat([0.08, 0.12], 5)}),
    "sweep": pd.DataFrame({"f_Hz": np.tile([15.0, 18.0, 21.0, 24.0, 27.0, 30.0], 2),
                           "Pd_N": np.repeat([0.20, 0.25], 6)}),
}


POS_NOISE = 0.1  # generating position noise SD of trajectories [mm]
TRAJECTORY_DESIGNS = {
    "runs3": pd.DataFrame({"run": ["a", "b", "c"], "f_Hz": [24.0, 32.0, 40.0], "Pd_N": [0.15, 0.20, 0.25],
                           "duration_s": [0.6] * 3}),
    "runs4": pd.DataFrame({"run": ["a", "b", "c", "d"], "f_Hz": [20.0, 28.0, 36.0, 40.0],
                           "Pd_N": [0.15, 0.15, 0.20, 0.25], "duration_s": [0.5] * 4}),
    # few long runs: each held out is predicted by two others that pin the friction level down less
    "long3": pd.DataFrame({"run": ["a", "b", "c"], "f_Hz": [22.0, 30.0, 38.0], "Pd_N": [0.15, 0.20, 0.25],
                           "duration_s": [3.0] * 3}),
    # one 1.5-s run and two of four frames: held out, the long run is predicted with a friction level fitted to
    # eight frames, so a correct model is held out above the linear expectation and "nothing is missing" rests on
    # the design's own expectation (held_out_of_truth; tests/test_dynamics_loop_held_out.py)
    "long1short2": pd.DataFrame({"run": ["long", "s1", "s2"], "f_Hz": [30.0, 34.0, 38.0], "Pd_N": [0.2, 0.15, 0.15],
                                 "duration_s": [1.5, 0.03, 0.03]}),
}


def _models(tmp: Path, start: str = "rest", kind: str = "progression"):
    out = {}
    for name, params in (("truth", {"Pf_N": 0.02}),
                         ("base", {"Pf_N": {"value": 0.03, "free": True, "bounds": [0.001, 0.2]}})):
        doc = {"kind": kind, "base": "one_sided", "effects": [], "params": params}
        if kind == "progression":
            doc["protocol"] = PROTO | {"start": start}
        (tmp / f"{name}.yaml").write_text(yaml.safe_dump(doc))
        out[name] = build_model(tmp / f"{name}.yaml")
    return out["truth"], out["base"]


def with_glitches(df: pd.DataFrame, k: int, seed: int) -> tuple[pd.DataFrame, list[int]]:
    """Return the trajectory table with ``k`` frames (at random) moved by 2-5 mm either way, and their rows."""
    rng = np.random.default_rng(20_000 + seed)
    rows = sorted(int(i) for i in rng.choice(len(df), k, replace=False))
    df = df.copy()
    df.loc[rows, "capsule_mm"] += rng.choice([-1.0, 1.0], k) * rng.uniform(2.0, 5.0, k)
    return df, rows


def held_out_runs(r: dict) -> dict:
    """Return the models whose "held out if it were true" bootstrap ran in diagnosis ``r``: {name: {mean [unit],
    draws, as_high (draws at least the data's held-out RMSE)}}."""
    recs = {"as is": r["model_as_is"].get("held_out_if_true")}
    recs |= {c["effect"]: c.get("held_out_if_true") for c in r.get("candidates", [])}
    return {k: {"mean": v["mean"], "draws": v["draws"], "as_high": v["as_high"]} for k, v in recs.items() if v}


def run(seeds: int, effort: str, candidates: list[str] | None, out: str | None, first_seed: int = 0,
        replicates: int = 2, start: str = "rest", designs: tuple[str, ...] = ("six", "ten"),
        kind: str = "progression", position_noise_mm: float = POS_NOISE, glitch_frames: int = 0) -> dict:
    budget = DL.EFFORTS[effort]
    rows, t0 = [], time.perf_counter()
    rec: dict = {}
    traj = kind == "trajectory"
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        truth, base = _models(tmp, start, kind)
        for s in range(first_seed, first_seed + seeds):
            dname = designs[s % len(designs)]
            if traj:
                df = DL.synthesize_trajectory(truth, TRAJECTORY_DESIGNS[dname], position_noise_mm, 100.0, 10_000 + s)
                df, glitched = with_glitches(df, glitch_frames, s)
            else:
                df = DL.synthesize_progression(truth, DESIGNS[dname], NOISE, replicates, 10_000 + s)
            path = tmp / f"null_{s}_synthetic.csv"
            df.to_csv(path, index=False)
            t1 = time.perf_counter()
            r = DL.run_diagnose(base, df, str(path), tmp / f"d{s}", k_folds=3, seed=s, figures=False,
                                budget=budget, candidates=candidates)
            v = r["verdict"]
            rows.append({"seed": s, "design": dname, "outcome": v["outcome"], "missing_effect": v["missing_effect"],
                         "covariate": v["covariate"], "noise_sd": r["noise"]["sd"],
                         "cv_rmse": r["model_as_is"]["cv_rmse"], "seconds": time.perf_counter() - t1,
                         "held_out_if_true": held_out_runs(r)})
            if traj and glitch_frames:
                rows[-1] |= {"glitched_rows": glitched, "flagged_rows": sorted(o["row"] for o in r["outliers"])}
            print(f"seed {s} ({dname}): {v['outcome']} {v['missing_effect'] or v['covariate'] or ''}", flush=True)
            outcomes = Counter(x["outcome"] for x in rows)
            findings = sum(x["outcome"] in ("missing_effect", "not_built_in") for x in rows)
            n = len(rows)
            # exact (Clopper-Pearson) 95 % interval of the finding rate
            from scipy import stats
            lo = float(stats.beta.ppf(0.025, findings, n - findings + 1)) if findings else 0.0
            hi = float(stats.beta.ppf(0.975, findings + 1, n - findings)) if findings < n else 1.0
            what = {"what": f"false-alarm rate of the dynamics diagnose on null {kind} data",
                    "budget_rule": ALPHA_EFFECT + ALPHA_STRUCTURE, "effort": effort,
                    "candidates": candidates or "all applicable"}
            if traj:
                what |= {"position_noise_sd_mm": position_noise_mm, "frame_rate_Hz": 100.0,
                         "glitch_frames": glitch_frames,
                         "designs": {k: TRAJECTORY_DESIGNS[k].to_dict(orient="list") for k in designs}}
            else:
                what |= {"noise_sd_mm_s": NOISE, "replicates": replicates, "protocol": PROTO | {"start": start},
                         "designs": {k: DESIGNS[k].to_dict(orient="list") for k in designs}}
            rec = {**what,
                   "data_sets": n, "findings": findings, "finding_rate": findings / n, "finding_rate_ci95": [lo, hi],
                   "outcomes": dict(outcomes), "seconds": time.perf_counter() - t0, "runs": rows}
            if out:
                Path(out).write_text(json.dumps(rec, indent=1, default=str))
    print(json.dumps({k: v for k, v in rec.items() if k != "runs"}, indent=1, default=str))
    return rec


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--effort", default="quick", choices=sorted(DL.EFFORTS))
    ap.add_argument("--candidates", default="secondary_constraint,viscous_drag",
                    help="comma-separated effects to try ('' for all applicable)")
    ap.add_argument("--replicates", type=int, default=2,
                    help="values per condition (1: no replicates, the noise then comes from the fits' residuals)")
    ap.add_argument("--protocol", default="rest", choices=("rest", "up", "down"),
                    help="how the data were run (and the model file says so)")
    ap.add_argument("--kind", default="progression", choices=("progression", "trajectory"),
                    help="null progression speeds, or null trajectories (designs runs3,runs4)")
    ap.add_argument("--designs", default=None,
                    help=f"comma-separated, alternating over seeds: {sorted(DESIGNS)} (progression; default six,ten) "
                         f"or {sorted(TRAJECTORY_DESIGNS)} (trajectory; default runs3,runs4)")
    ap.add_argument("--position-noise-mm", type=float, default=POS_NOISE,
                    help=f"trajectories: generating position noise SD [mm] (default {POS_NOISE:g})")
    ap.add_argument("--glitch-frames", type=int, default=0,
                    help="trajectories: frames of each data set moved by 2-5 mm (a tracker's errors; default 0)")
    ap.add_argument("--out", default=None, help="result JSON (default benchmarks/dynamics_loop_calibration_result.json, "
                                                "_trajectory_result.json for --kind trajectory)")
    a = ap.parse_args()
    cands = [c for c in a.candidates.split(",") if c] or None
    table = TRAJECTORY_DESIGNS if a.kind == "trajectory" else DESIGNS
    default = ("runs3", "runs4") if a.kind == "trajectory" else ("six", "ten")
    designs = tuple(d for d in (a.designs or ",".join(default)).split(",") if d)
    if not designs or any(d not in table for d in designs):
        ap.error(f"--designs: choose from {sorted(table)}")
    traj_out = ("dynamics_loop_calibration_trajectory_glitch_result.json" if a.glitch_frames
                else "dynamics_loop_calibration_trajectory_result.json")
    out = a.out or str(ROOT / "benchmarks" / (traj_out if a.kind == "trajectory"
                                              else "dynamics_loop_calibration_result.json"))
    run(a.seeds, a.effort, cands, out, a.first_seed, a.replicates, a.protocol, designs, a.kind, a.position_noise_mm,
        a.glitch_frames)


if __name__ == "__main__":
    main()
