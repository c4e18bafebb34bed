"""Speed of ``capsule-cli diagnose`` on a 20-point friction table (issue 10 item 10; target < 2 s end to end).

    python benchmarks/diagnose_speed.py [--repeat 7]

Prints JSON: the end-to-end wall time of the command (a fresh process each, figures on, and with --no-figures;
the median of --repeat runs, the two variants interleaved so that a change in the machine's load hits both;
the best and all runs too) and,
in one process, where the time goes: imports, reading, fits + tests + verdict (diagnose_table), matplotlib
import, writing tables and figures. The table is made by capsule-cli synth (seed 000 eq 17 + noise).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    a = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp())
    design = tmp / "design.csv"
    design.write_text("speed_mm_s\n" + "\n".join(f"{0.2 * (60 ** (i / 19)):.4g}" for i in range(20)) + "\n")
    data = tmp / "friction_synthetic.csv"
    cli = [sys.executable, "-m", "capsule_cli"]
    subprocess.run(cli + ["synth", "--model", str(ROOT / "configs/models/friction_seed000_eq17.yaml"), "--design",
                          str(design), "--noise-sd", "1.5", "--seed", "1", "--out", str(data), "--quiet"],
                   check=True, cwd=ROOT)
    walls, walls_nofig = [], []
    for i in range(a.repeat):
        for extra, dest, tag in (([], walls, "d"), (["--no-figures"], walls_nofig, "n")):
            t = time.perf_counter()
            subprocess.run(cli + ["diagnose", "--model", str(ROOT / "configs/models/coulomb.yaml"), "--data",
                                  str(data), "--out", str(tmp / f"{tag}{i}"), "--quiet", *extra], check=True, cwd=ROOT)
            dest.append(time.perf_counter() - t)
    split = subprocess.run([sys.executable, "-c", f"""
import time, json
t0 = time.perf_counter()
from capsule_cli.cli import main
from capsule_cli.effects.model import build_model
from capsule_cli.tables import read_measurements
from capsule_cli.steps.diagnose import diagnose_table, run_diagnose
t1 = time.perf_counter()
m = build_model({str(ROOT / 'configs/models/coulomb.yaml')!r}); d, k = read_measurements({str(data)!r})
t2 = time.perf_counter()
diagnose_table(m, d, k, 'x')
t3 = time.perf_counter()
import capsule_cli.plots.loop
t4 = time.perf_counter()
run_diagnose(m, d, k, {str(data)!r}, {str(tmp / 'split')!r}, figures=True)
t5 = time.perf_counter()
print(json.dumps({{"imports_s": t1 - t0, "read_s": t2 - t1, "fits_tests_verdict_s": t3 - t2,
                  "matplotlib_import_s": t4 - t3, "run_diagnose_with_figures_s": t5 - t4}}))
"""], check=True, cwd=ROOT, capture_output=True, text=True)
    print(json.dumps({"n_points": 20, "end_to_end_wall_s": statistics.median(walls), "best_wall_s": min(walls),
                      "all_wall_s": walls, "end_to_end_no_figures_wall_s": statistics.median(walls_nofig),
                      "best_no_figures_wall_s": min(walls_nofig), "all_no_figures_wall_s": walls_nofig,
                      "target_s": 2.0, "repeat": a.repeat,
                      "pythondontwritebytecode": bool(os.environ.get("PYTHONDONTWRITEBYTECODE")),
                      "in_process_split": json.loads(split.stdout)}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
