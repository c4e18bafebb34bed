"""Shared test helpers."""
from __future__ import annotations

import contextlib
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


def cli_command(*args) -> tuple[list[str], dict]:
    """Return (argv, environment) that run ``capsule-cli args`` from this checkout (the console entry point)."""
    exe = Path(sys.executable).with_name("capsule-cli")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "capsule_cli"]
    return [*cmd, *map(str, args)], {**os.environ, "PYTHONPATH": str(REPO)}


def run_cli(*args: str, cwd: str | os.PathLike | None = None) -> subprocess.CompletedProcess:
    """Run ``capsule-cli`` in a subprocess (the real console entry point) and capture its output."""
    argv, env = cli_command(*args)
    return subprocess.run(argv, capture_output=True, text=True, cwd=cwd, env=env)


@pytest.fixture
def cli():
    """The ``run_cli`` helper as a fixture."""
    return run_cli


@contextlib.contextmanager
def plugin_loaded(path: Path):
    """Load the plugin file ``path`` for the block, then unregister every effect it added.

    A module fixture that leaves its plugin's effects registered hands them to every later test on its xdist
    worker: the dynamics loop's plugin-force test, run after tests/test_dynamics_plugin_force.py, named that
    module's attraction_t9f instead of its own magnet attraction."""
    from capsule_cli.effects import registry

    before = {(e.kind, e.name) for e in registry.effects()}
    registry.load_plugins([path], entry_points=False)
    try:
        yield path
    finally:
        for e in registry.effects():
            if (e.kind, e.name) not in before:
                registry.unregister_effect(e.kind, e.name)
        registry._LOADED_PLUGINS.discard(str(Path(path).resolve()))
