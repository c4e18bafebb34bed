"""Shared test helpers."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


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
