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


#: modules whose tests run the engine for seconds to a minute each (the dynamics loop's diagnoses, the smoke
#: workflow); under pytest-xdist they go first in every worker's share (:func:`pytest_collection_modifyitems`)
HEAVY_MODULES = ("test_workflow_smoke.py", "test_dynamics_loop_each_effect.py", "test_dynamics_loop_fast.py",
                 "test_dynamics_loop_trajectory.py")


@pytest.hookimpl(trylast=True)  # after -m and -k have deselected: the shares are of the tests that run
def pytest_collection_modifyitems(config, items):
    """Under pytest-xdist, deal the heavy modules' tests round-robin to the front of each worker's first share.

    pytest-xdist's worksteal gives worker i the next len(pending) // (workers - i) tests of the collection order,
    then lets a worker that runs dry take the back half of another's queue. In file order the heavy tests sat
    together in one share and the smoke run (one test of 50 s or more) came last: one worker still ran heavy
    tests while the other had nothing left to take. Heavy tests first in every share leave light ones at the
    backs of the queues, the ones a worker that runs dry takes. Every worker reorders alike (a deterministic
    order: xdist checks that the collections agree)."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers < 2 or len(items) < 2 * workers:
        return
    heavy = [it for it in items if it.path.name in HEAVY_MODULES]
    light = [it for it in items if it.path.name not in HEAVY_MODULES]
    shares, left = [], len(items)
    for i in range(workers):
        size = left // (workers - i)
        shares.append(size)
        left -= size
    out = []
    for i, size in enumerate(shares):
        mine = heavy[i::workers][:size]
        out += mine + light[:size - len(mine)]
        light = light[size - len(mine):]
    dealt = set(map(id, out))
    out += light + [it for it in heavy if id(it) not in dealt]
    assert len(out) == len(items) and len(set(map(id, out))) == len(items)
    items[:] = out
