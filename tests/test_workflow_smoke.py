"""End-to-end: the Snakemake study on configs/smoke.yaml (the CI smoke run), interrupted once and resumed."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from capsule_cli.tables import read_provenance

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.smoke
def test_smoke_workflow_builds_every_target(tmp_path):
    snakemake = Path(sys.executable).with_name("snakemake")
    # CI (.github/workflows/ci.yml) names a folder to keep the smoke figures as an artifact
    results = Path(os.environ.get("CAPSULE_SMOKE_RESULTS") or tmp_path / "results").resolve()
    # PATH as the user has it: the Snakefile itself must find the project's capsule-cli
    env = dict(os.environ)
    # --rerun-incomplete as in the Makefile: a run interrupted by Ctrl-C resumes without the user's help
    cmd = [str(snakemake), "-s", str(REPO / "workflow" / "Snakefile"), "--configfile",
           str(REPO / "configs" / "smoke.yaml"), "--config", f"results_dir={results}", "--cores", "2",
           "--directory", str(tmp_path), "--quiet", "--rerun-incomplete", "all"]
    # first run: Ctrl-C (SIGINT to the whole process group, as a terminal sends it) once work is under way
    first = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env,
                             start_new_session=True)
    deadline = time.monotonic() + 600
    while first.poll() is None and time.monotonic() < deadline:
        if results.is_dir() and sum(1 for p in results.rglob("*") if p.is_file()) >= 3:
            break
        time.sleep(0.5)
    interrupted = first.poll() is None
    if interrupted:
        os.killpg(first.pid, signal.SIGINT)
        # Snakemake's log handler drops a KeyboardInterrupt that lands while it writes a record
        # (snakemake/logging.py: `except (KeyboardInterrupt, SystemExit): pass`) and the run goes on: press again,
        # as a user would when the run does not stop
        for _ in range(3):
            try:
                first.wait(timeout=5)
                break
            except subprocess.TimeoutExpired:
                os.killpg(first.pid, signal.SIGINT)
    try:
        first.wait(timeout=300)
    except subprocess.TimeoutExpired:
        os.killpg(first.pid, signal.SIGKILL)
        raise
    if interrupted and first.returncode == 0:
        # every Ctrl-C was dropped and the run went on to the end: its success must be real (nothing left to do)
        dry = subprocess.run([a for a in cmd if a != "--quiet"][:-1] + ["-n", "all"], capture_output=True, text=True,
                             env=env, timeout=300)
        assert "Nothing to be done" in dry.stdout + dry.stderr, "an interrupted run must not report success"
    # second run: resumes and completes
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900)
    assert r.returncode == 0, r.stderr[-4000:]
    assert "IncompleteFilesException" not in r.stderr
    produced = sorted(p for p in results.rglob("*") if p.is_file())
    assert produced, "the smoke run produced nothing"
    # every Parquet table carries provenance and units
    for p in produced:
        if p.suffix == ".parquet":
            prov = read_provenance(p)
            assert prov.get("version"), f"{p} lacks provenance"
            fields = pq.read_schema(p)
            assert all(f.metadata and b"unit" in f.metadata for f in fields), f"{p} lacks unit metadata"
        if p.suffix == ".png":
            assert p.stat().st_size > 5000, f"{p} looks empty"
    # synthetic data is labelled as such in its name and metadata
    for p in produced:
        if p.suffix == ".parquet" and read_provenance(p).get("synthetic"):
            assert "synthetic" in p.name, f"{p} is synthetic but not named so"
