"""The command line frame: version, help, exit codes of contract section 5."""
from __future__ import annotations

import re

from capsule_cli import __version__


def test_version(cli):
    r = cli("--version")
    assert r.returncode == 0
    assert r.stdout.strip() == f"capsule-cli {__version__}"


def test_help_lists_the_contract_commands(cli):
    r = cli("--help")
    assert r.returncode == 0
    listed = set(re.findall(r"^\W*([a-z][\w-]*)\s{2,}", r.stdout, flags=re.M))
    for name in ("contact", "relax", "friction", "synth", "compare", "diagnose", "effects", "ledger"):
        assert name in listed, f"'{name}' missing from capsule-cli --help"


def test_unknown_command_is_usage_error_exit_2(cli):
    r = cli("no-such-command")
    assert r.returncode == 2
    assert "No such command" in r.stderr
