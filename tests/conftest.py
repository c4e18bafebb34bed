"""Shared test helpers."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# Under pytest-xdist (make test: one worker per core) each worker's engine runs its parallel batches on one thread:
# two workers of two OpenMP threads each on two cores only wait for each other. Measured on a 2-core machine beside
# a busy process: a ten-condition progression diagnose (tests/test_dynamics_loop_each_effect.py's secondary
# constraint) 61.2 s on one thread, 66.2 s on two, the same diagnosis. Set before any test imports numba; the
# subprocesses the tests start inherit it.
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")


def run_cli(*args: str, cwd: str | os.PathLike | None = None) -> subprocess.CompletedProcess:
    """Run ``capsule-cli`` in a subprocess (the real console entry point) and capture its output."""
    exe = Path(sys.executable).with_name("capsule-cli")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "capsule_cli"]
    return subprocess.run([*cmd, *map(str, args)], capture_output=True, text=True, cwd=cwd,
                          env={**os.environ, "PYTHONPATH": str(REPO)})


@pytest.fixture
def cli():
    """The ``run_cli`` helper as a fixture."""
    return run_cli
