"""Start-up work of the commands (issue 10 item 10, issue 13 item 5): what they import and read.

The wall times themselves are benchmarks (benchmarks/diagnose_speed.py, `capsule-cli bench --startup`), not
asserted here; these tests pin the choices that make them short, and that the faster paths change nothing.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from capsule_cli.config import _FastStrictLoader, _StrictLoader, read_yaml
from capsule_cli.errors import InputError

REPO = Path(__file__).resolve().parents[1]


def test_diagnose_path_does_not_import_scipy_stats():
    """The diagnosis of a friction table needs no scipy.stats (its import costs about 0.3 s)."""
    code = ("import sys; import capsule_cli.steps.diagnose, capsule_cli.fitting, capsule_cli.steps.relax; "
            "print('scipy.stats' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("path", sorted(p.relative_to(REPO).as_posix() for p in (REPO / "configs").rglob("*.yaml")))
def test_fast_yaml_loader_reads_every_shipped_config_as_the_pure_python_one(path):
    """libyaml's parser (when PyYAML has it) gives the same content as the pure-Python parser."""
    text = (REPO / path).read_text(encoding="utf-8")
    assert yaml.load(text, Loader=_FastStrictLoader) == yaml.load(text, Loader=_StrictLoader)


@pytest.mark.parametrize("text, message", [
    ("kind: friction\nbase: [coulomb\n", "line 3: invalid YAML: expected ',' or ']', but got '<stream end>'"),
    ("a:\n\t- b\n", "line 2: invalid YAML: found character '\\t' that cannot start any token"),
    ("a: 1\nb: 2\na: 3\n", "duplicate key 'a' at line 3"),
])
def test_yaml_errors_read_as_the_pure_python_parser_words_them(tmp_path, text, message):
    """A file libyaml rejects is parsed again by the pure-Python parser, whose message names the character."""
    f = tmp_path / "bad.yaml"
    f.write_text(text, encoding="utf-8")
    with pytest.raises(InputError) as err:
        read_yaml(f)
    assert str(err.value) == f"{f}: {message}"


def test_dynamics_kinds_named_in_tables_are_the_engine_loops():
    """tables.DYNAMICS_KINDS (read without importing the engine) lists the kinds dynamics_loop handles."""
    from capsule_cli.steps import dynamics_loop
    from capsule_cli.tables import DYNAMICS_KINDS, MEASUREMENT_KINDS

    assert tuple(DYNAMICS_KINDS) == tuple(dynamics_loop.DYN_KINDS)
    assert set(DYNAMICS_KINDS) <= set(MEASUREMENT_KINDS)


def test_quasi_static_loop_commands_import_neither_the_engine_nor_scipy_stats(tmp_path):
    """synth, compare and diagnose of a friction table run without numba (the engine) or scipy.stats, and without
    matplotlib until a figure is drawn."""
    data = tmp_path / "friction_synthetic.csv"
    code = f"""
import sys
from capsule_cli.cli import main
for args in (["synth", "--model", "configs/models/friction_coulomb_eq17_truth.yaml", "--noise-sd", "1.5",
              "--seed", "1", "--out", {str(data)!r}, "--quiet"],
             ["diagnose", "--model", "configs/models/coulomb.yaml", "--data", {str(data)!r}, "--out",
              {str(tmp_path / 'diag')!r}, "--no-figures", "--quiet"],
             ["compare", "--model", "configs/models/coulomb.yaml", "--data", {str(data)!r}, "--out",
              {str(tmp_path / 'cmp')!r}, "--quiet"]):
    assert main(args) == 0, args
    heavy = [m for m in ("numba", "scipy.stats") + (("matplotlib",) if args[0] != "compare" else ())
             if m in sys.modules]
    assert not heavy, (args[0], heavy)
print("ok")
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]


def test_program_exit_freezes_the_collector_and_keeps_the_exit_code():
    """The console entry leaves the objects of its imports to the OS (gc.freeze) and exits with the code."""
    import gc

    from capsule_cli import cli

    assert gc.get_freeze_count() == 0
    try:
        with pytest.raises(SystemExit) as ex:
            cli._exit_without_collecting(2)
        assert ex.value.code == 2
        assert gc.get_freeze_count() > 1000  # every object alive at exit
    finally:
        gc.unfreeze()


def test_program_exit_code_and_streams_survive_the_fast_exit(tmp_path):
    """Bad input still prints its one line on stderr and exits 2; --version prints and exits 0."""
    ok = subprocess.run([sys.executable, "-m", "capsule_cli", "--version"], capture_output=True, text=True, cwd=REPO)
    assert ok.returncode == 0 and ok.stdout.startswith("capsule-cli ")
    bad = subprocess.run([sys.executable, "-m", "capsule_cli", "diagnose", "--model", str(tmp_path / "none.yaml"),
                          "--data", str(tmp_path / "none.csv"), "--out", str(tmp_path / "d")],
                         capture_output=True, text=True, cwd=REPO)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "none.yaml" in bad.stderr, bad.stderr
