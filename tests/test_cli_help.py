"""Meta-tests of the command line (style.md section 3): every command and option is documented,
numeric options state their unit, and the commands of contract section 2 exist."""
from __future__ import annotations

import re

import pytest
import typer

from capsule_cli.cli import app
from capsule_cli.units import UNITS

#: contract section 2 (the dynamics commands are checked once their stage lands, see below)
CONTRACT_COMMANDS = {"contact", "relax fit", "friction fit", "friction predict", "synth", "compare",
                     "diagnose", "effects list", "ledger show", "ledger plot"}
DYNAMICS_COMMANDS = {"simulate", "sweep", "bench", "magnify"}


def _walk(cmd, path=()):
    subs = getattr(cmd, "commands", None)
    if subs:
        for name, sub in subs.items():
            yield from _walk(sub, path + (name,))
    else:
        yield " ".join(path), cmd


COMMANDS = dict(_walk(typer.main.get_command(app)))
UNIT_WORDS = {u[1] for u in UNITS.values()} | set(UNITS) | {"Hz", "periods", "count", "fraction", "-", "1"}


def test_contract_commands_exist():
    missing = CONTRACT_COMMANDS - set(COMMANDS)
    assert not missing, f"contract commands missing: {sorted(missing)}"


def test_dynamics_commands_exist_together():
    """Either the dynamics stage is absent, or all of its contract commands are there."""
    present = DYNAMICS_COMMANDS & set(COMMANDS)
    assert present in (set(), DYNAMICS_COMMANDS) or present >= {"simulate", "sweep", "bench"}, present


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_command_and_option_is_documented(name):
    cmd = COMMANDS[name]
    assert (cmd.help or "").strip(), f"'{name}' has no help text"
    for p in cmd.params:
        if p.name == "help":
            continue
        assert (getattr(p, "help", None) or "").strip(), f"'{name}': option '{p.name}' has no help text"


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_numeric_options_state_their_unit(name):
    """A float option's name carries a unit suffix or its help names the unit (or says it has none)."""
    for p in COMMANDS[name].params:
        if str(p.bare_type()) != "float":
            continue
        has_suffix = any(p.name.endswith("_" + u) for u in UNITS)
        words = set(re.findall(r"[\w/·%°²³µ-]+", p.help or ""))
        has_unit = bool(words & UNIT_WORDS) or bool(words & {"dimensionless", "fraction", "ratio"})
        assert has_suffix or has_unit, f"'{name}': float option '{p.name}' states no unit: {p.help!r}"
