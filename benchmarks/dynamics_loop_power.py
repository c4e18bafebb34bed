"""Power of the dynamics loop's verdict on data shaped like issue 12's checks (a benchmark, not a test).

Each data set is made by a true model (the contract's one-sided Coulomb base, P_f = 7.8 mN, with one effect more,
or none) and given to ``diagnose`` with the base model (P_f free, bounds 0-0.5 N) and every built-in candidate,
at the effort the CLI uses by default (``--effort full``). Recorded per data set: the outcome, the effect or
covariate named, the noise estimate and the held-out RMSE of each candidate.

    trajectory: configs/designs/trajectory_runs.csv (four 1-s runs from rest: 25/0.15, 30/0.15, 35/0.2,
        38/0.2 Hz/N), 100 frames per second, position noise ``--noise`` (default 0.3 mm)
    progression: configs/designs/progression_grid.csv (10 frequencies x 4 amplitudes), one value per condition,
        protocol rest 120/60 periods (``--protocol up`` or ``down``: continuation in frequency), noise 0.5 mm/s

Cases (``--cases``, default all of the kind): ``null``, each built-in effect at the values in CASES, and (progression
only) two drive effects that are not built in, written as a user's plugins (a coil low-pass in f_Hz and a saturation
in P_d_N), where the verdict should name the covariate.

Usage:
    python benchmarks/dynamics_loop_power.py --kind trajectory [--seeds 2] [--cases null,viscous_drag]
        [--effort full] [--design RUNS.csv] [--noise 0.5] [--protocol up]
        [--out benchmarks/dynamics_loop_power_trajectory_result.json]

Recorded per data set besides the verdict: each candidate's held-out RMSE (``cv_rmse``: standardised by the
noise and, where the response is irregular, the model's spread) and on the rows the fit predicts neither
irregular nor multistable (``cv_rmse_not_irregular``, plain: issue 12 item 7's measure), and its seconds.

The result JSON is rewritten after every data set. Minutes of CPU per data set (progression 3-8, trajectory 1-3).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from capsule_cli.effects import registry  # noqa: E402
from capsule_cli.effects.model import build_model  # noqa: E402
from capsule_cli.steps import dynamics_loop as DL  # noqa: E402

sys.path.insert(0, str(ROOT / "benchmarks"))
from dynamics_loop_calibration import held_out_runs  # noqa: E402

PF_N = 0.0078  # the contract's base friction level (physics.md section 3, seed 000 section 5.3)
PROTOCOL = {"start": "rest", "transient_periods": 120, "recorded_periods": 60}
PROGRESSION_NOISE = 0.5  # mm/s
CASES = {  # effect values: physics.md section 3 readings, sizes a lab would see (several noise SDs)
    "null": ([], {}),
    "speed_dependent_friction": (["speed_dependent_friction"], {"a_mN": 3.0, "n": 0.6}),
    "secondary_constraint": (["secondary_constraint"], {"gap_back_mm": 0.1, "constraint_back_N_m": 97060.0,
                                                        "constraint_back_damping_Ns_m": 0.35}),
    "viscous_drag": (["viscous_drag"], {"drag_Ns_m": 0.03}),
    "tilt_friction": (["tilt_friction"], {"kappa": 0.3}),
    "substrate_compliance": (["substrate_compliance"], {"compliance_mm_N": 0.5}),
    "coil_lowpass": (["coil_lowpass"], {"corner_Hz": 40.0}),
    "coil_saturation": (["coil_saturation"], {"saturation_N": 0.2}),
}
NOT_BUILT_IN = {"coil_lowpass": "f_Hz", "coil_saturation": "Pd_N"}
PLUGIN = '''
import math
from capsule_cli.effects import Param, register_effect


@register_effect(name="coil_lowpass", kind="progression", role="drive", covariates=("f_Hz",),
                 params=(Param("corner_Hz", 40.0, (1.0, 1000.0), off=1000.0, description="corner frequency"),),
                 description="The coil's force falls as a first-order low-pass: P_d / sqrt(1 + (f / f_c)^2).",
                 source="benchmark: a user's plugin")
def coil_lowpass(f_Hz, Pd_N, duty, p):
    return f_Hz, Pd_N / math.sqrt(1.0 + (f_Hz / p["corner"]) ** 2), duty


@register_effect(name="coil_saturation", kind="progression", role="drive", covariates=("Pd_N",),
                 params=(Param("saturation_N", 0.2, (0.01, 10.0), off=10.0, description="saturation force"),),
                 description="The coil saturates: P_s tanh(P_d / P_s).", source="benchmark: a user's plugin")
def coil_saturation(f_Hz, Pd_N, duty, p):
    return f_Hz, p["saturation"] * math.tanh(Pd_N / p["saturation"]), duty
'''


def _model(tmp: Path, name: str, kind: str, effects, params, start: str = "rest") -> object:
    doc = {"kind": kind, "base": "one_sided", "effects": list(effects), "params": params}
    if kind == "progression":
        doc["protocol"] = {**PROTOCOL, "start": start}
    (tmp / f"{name}.yaml").write_text(yaml.safe_dump(doc))
    return build_model(tmp / f"{name}.yaml")


def parse_case(spec: str) -> tuple[str, dict]:
    """Split a case spec ``name`` or ``name@param=value+param=value`` (values overriding CASES[name]'s)."""
    name, _, rest = spec.partition("@")
    over = {}
    for item in filter(None, rest.split("+")):
        key, _, val = item.partition("=")
        over[key] = float(val)
    return name, over


def data_set(tmp: Path, kind: str, case: str, seed: int, noise: float, design: str | None = None,
             start: str = "rest", pf_N: float = PF_N) -> pd.DataFrame:
    """Return the synthetic table of ``case`` (a spec as parse_case reads it; a plugin case's effect is registered
    only while it is made) on ``design`` (a design CSV; None: the kind's default, above), progression run by
    protocol ``start``, the truth's Coulomb level ``pf_N`` [N]."""
    case, over = parse_case(case)
    effects, params = CASES[case]
    unknown = set(over) - set(params)
    if unknown:
        raise SystemExit(f"case {case!r}: no parameter {sorted(unknown)} (it has {sorted(params)})")
    params = {**params, **over}
    plug = tmp / "coil_plugins.py"
    if case in NOT_BUILT_IN:
        plug.write_text(PLUGIN)
        registry.load_plugins([plug], entry_points=False)
    try:
        truth = _model(tmp, f"truth_{case}", kind, effects, {"Pf_N": pf_N, **params}, start)
        if kind == "trajectory":
            runs = pd.read_csv(design or ROOT / "configs" / "designs" / "trajectory_runs.csv")
            return DL.synthesize_trajectory(truth, runs, noise, 100.0, 1000 + seed)
        grid = pd.read_csv(design or ROOT / "configs" / "designs" / "progression_grid.csv")
        return DL.synthesize_progression(truth, grid, noise, 1, 2000 + seed)
    finally:
        if case in NOT_BUILT_IN:
            for name in NOT_BUILT_IN:
                registry.unregister_effect("progression", name)
            registry._LOADED_PLUGINS.discard(str(plug.resolve()))


def with_origin(df: pd.DataFrame, origin: str) -> pd.DataFrame:
    """Return trajectory table ``df`` with its positions as ``origin`` says (see --origin); others unchanged."""
    if origin == "rest" or "run" not in df.columns or "time_s" not in df.columns:
        return df
    df = df.copy()
    for col in ("capsule_mm", "magnet_mm"):
        if col in df.columns:
            if origin == "first_frame":
                df[col] = df[col] - df.groupby("run")[col].transform("first")
            else:
                df.loc[df["time_s"].abs() <= 1e-12, col] = 0.0
    return df


def expected(case: str) -> str:
    case = parse_case(case)[0]
    return "nothing_missing" if case == "null" else NOT_BUILT_IN.get(case, case)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kind", default="trajectory", choices=("trajectory", "progression"))
    ap.add_argument("--cases", default="", help="comma-separated (default: every case of the kind); a case may "
                    "override its effect's values: speed_dependent_friction@a_mN=1.5+n=0.9")
    ap.add_argument("--base-pf", type=float, default=PF_N, help="the truth's Coulomb level P_f [N] (and the base "
                    "model's start value; default the contract's 7.8 mN)")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--noise", type=float, default=None, help="trajectory: position noise SD [mm] (default 0.3)")
    ap.add_argument("--protocol", default="rest", choices=("rest", "up", "down"),
                    help="progression: how each condition is run (truth and base model file alike)")
    ap.add_argument("--design", default=None, help="a design CSV (default: the kind's, above)")
    ap.add_argument("--origin", default="rest", choices=("rest", "first_frame", "exact_rest"),
                    help="trajectory: positions as synth writes them (rest: the noise at every frame), each run "
                    "zeroed at its first frame (first_frame: a tracker's positions minus the first frame's), or "
                    "the frame at t = 0 written as exactly 0 (exact_rest: a simulator that records rest there)")
    ap.add_argument("--effort", default="full", choices=sorted(DL.EFFORTS))
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    cases = [c for c in a.cases.split(",") if c] or [c for c in CASES if a.kind == "progression"
                                                     or c not in NOT_BUILT_IN]
    names = {parse_case(c)[0] for c in cases}
    if names - set(CASES) or (a.kind == "trajectory" and names & set(NOT_BUILT_IN)):
        ap.error(f"--cases: choose from {sorted(CASES)} (plugin cases: progression only)")
    noise = a.noise if a.noise is not None else (0.3 if a.kind == "trajectory" else PROGRESSION_NOISE)
    out = Path(a.out or ROOT / "benchmarks" / f"dynamics_loop_power_{a.kind}_result.json")
    rows, t0 = [], time.perf_counter()
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        base = _model(tmp, "base", a.kind, [], {"Pf_N": {"value": a.base_pf, "free": True, "bounds": [0.0, 0.5]}},
                      a.protocol)
        for seed in range(a.first_seed, a.first_seed + a.seeds):
            for case in cases:
                df = with_origin(data_set(tmp, a.kind, case, seed, noise, a.design, a.protocol, a.base_pf),
                                 a.origin)
                path = tmp / f"{parse_case(case)[0]}_{len(rows)}_{seed}_synthetic.csv"
                df.to_csv(path, index=False)
                t1 = time.perf_counter()
                r = DL.run_diagnose(base, df, str(path), tmp / f"d_{len(rows)}_{seed}", k_folds=5, seed=0,
                                    figures=False, budget=DL.EFFORTS[a.effort])
                v = r["verdict"]
                said = (v["missing_effect"] or v["covariate"] if v["outcome"] in ("missing_effect", "not_built_in")
                        else v["outcome"])
                rows.append({"case": case, "seed": seed, "outcome": v["outcome"],
                             "missing_effect": v["missing_effect"], "covariate": v["covariate"],
                             "alternatives": v.get("alternatives", []), "right": said == expected(case),
                             "noise_sd": r["noise"]["sd"], "cv_rmse_as_is": r["model_as_is"]["cv_rmse"],
                             "cv_rmse": {c["effect"]: c["cv_rmse"] for c in r.get("candidates", [])},
                             "cv_rmse_not_irregular": {c["effect"]: c["cv_rmse_not_irregular"]
                                                       for c in r.get("candidates", [])},
                             "candidate_seconds": {c["effect"]: round(c["seconds"], 1)
                                                   for c in r.get("candidates", [])},
                             "held_out_if_true": held_out_runs(r),
                             "message": v["message"], "seconds": round(time.perf_counter() - t1, 1)})
                print(f"{case} seed {seed}: {said} ({'right' if rows[-1]['right'] else 'WRONG'})", flush=True)
                rec = {"what": f"power of the dynamics diagnose on {a.kind} data shaped like issue 12's checks",
                       "design": a.design or "default",
                       "design_rows": pd.read_csv(a.design).to_dict("records") if a.design else None,
                       "protocol": a.protocol, "origin": a.origin, "noise": noise, "effort": a.effort,
                       "base_Pf_N": a.base_pf,
                       "cases": {c: (CASES[parse_case(c)[0]][0], {**CASES[parse_case(c)[0]][1],
                                                                   **parse_case(c)[1]}) for c in cases},
                       "data_sets": len(rows), "right": sum(x["right"] for x in rows),
                       "seconds": round(time.perf_counter() - t0, 1), "runs": rows}
                out.write_text(json.dumps(rec, indent=1, default=str))
    print(json.dumps({k: v for k, v in rec.items() if k != "runs"}, indent=1, default=str))


if __name__ == "__main__":
    main()
