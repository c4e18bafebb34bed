"""Benchmark (issue 11 item 5): how ``capsule-cli friction fit`` and ``compare`` grow from 1e4 to 1e6 rows.

For each size a design of speeds (0.1..50 mm/s, an even grid) is written, ``capsule-cli synth`` makes the
synthetic table from seed 000 eq 17 (configs/models/friction_seed000_eq17.yaml) with 1 mN noise, and then
the commands run as a user runs them, each in its own process: wall time and peak resident memory (sampled
every 20 ms with psutil, the process and its children) are reported as JSON on stdout.

    python benchmarks/friction_fit_scaling.py                 # 1e4, 1e5, 1e6 rows, friction fit only
    python benchmarks/friction_fit_scaling.py --compare       # also compare (coulomb + speed_power_law)
    python benchmarks/friction_fit_scaling.py --sizes 10000 1000000 --workdir /tmp/bench

Targets (issue 11): 1e6 rows fit in < 20 s and < 1 GB; compare in < 60 s. A benchmark, not a test: it takes
minutes and its times depend on the machine.
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil

REPO = Path(__file__).resolve().parents[1]
TRUTH = REPO / "configs" / "models" / "friction_seed000_eq17.yaml"
FIT_MODEL = """kind: friction
base: coulomb
effects: [speed_power_law]
params:
  mu: {value: 0.1, free: true, bounds: [0.0, 1.0]}
  mass_g: 3.462
"""


def cli() -> list[str]:
    exe = Path(sys.executable).with_name("capsule-cli")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "capsule_cli"]


def measure(cmd: list[str], cwd: Path) -> dict:
    """Run ``cmd``; return exit code, wall time [s] and peak RSS [MB] of the process tree."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    ps = psutil.Process(proc.pid)
    peak = 0
    while proc.poll() is None:
        try:
            rss = ps.memory_info().rss + sum(c.memory_info().rss for c in ps.children(recursive=True))
            peak = max(peak, rss)
        except psutil.Error:
            pass
        time.sleep(0.02)
    wall = time.perf_counter() - t0
    err = proc.stderr.read()
    return {"exit_code": proc.returncode, "wall_s": round(wall, 2), "peak_rss_MB": round(peak / 2**20, 1),
            **({"stderr": err.strip()[-300:]} if proc.returncode else {})}


def run(sizes: list[int], workdir: Path, with_compare: bool) -> dict:
    rows = []
    for n in sizes:
        d = workdir / f"n{n}"
        d.mkdir(parents=True, exist_ok=True)
        design = d / "design.csv"
        np.savetxt(design, np.linspace(0.1, 50.0, n), header="speed_mm_s", comments="", fmt="%.6f")
        data = d / f"friction_{n}_synthetic.parquet"
        syn = measure([*cli(), "synth", "--model", str(TRUTH), "--design", str(design), "--noise-sd", "1.0",
                       "--seed", "1", "--out", str(data), "-q"], d)
        rec = {"rows": n, "synth": syn}
        rec["friction_fit"] = measure([*cli(), "friction", "fit", "--data", str(data), "--out", str(d / "fit"),
                                       "-q"], d)
        if with_compare:
            (d / "model.yaml").write_text(FIT_MODEL)
            rec["compare"] = measure([*cli(), "compare", "--model", str(d / "model.yaml"), "--data", str(data),
                                      "--out", str(d / "cmp"), "--ledger", str(d / "ledger.parquet"), "-q"], d)
        rows.append(rec)
        print(json.dumps(rec), file=sys.stderr)
    out = {"benchmark": "friction fit / compare scaling", "rows": rows}
    if len(rows) >= 2:
        a, b = rows[0], rows[-1]
        out["growth"] = {k: {"rows_ratio": b["rows"] / a["rows"],
                             "time_ratio": round(b[k]["wall_s"] / max(a[k]["wall_s"], 1e-9), 2),
                             "memory_ratio": round(b[k]["peak_rss_MB"] / max(a[k]["peak_rss_MB"], 1e-9), 2)}
                         for k in ("friction_fit", "compare") if k in a}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    ap.add_argument("--compare", action="store_true", help="also time compare")
    ap.add_argument("--workdir", type=Path, default=None, help="keep the tables here (default: a temp folder)")
    args = ap.parse_args()
    work = args.workdir or Path(tempfile.mkdtemp(prefix="capsule-bench-"))
    try:
        print(json.dumps(run(args.sizes, work, args.compare), indent=2))
    finally:
        if args.workdir is None:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
