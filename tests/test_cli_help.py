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


# ---------------------------------------------------------------------------
# the rendered text (issue 14): what a user reads in `--help` must keep every unit, show flags as
# flags, and cut nothing off. Compared with whitespace removed, since the text wraps at the terminal.

from typer.testing import CliRunner  # noqa: E402

def _groups(cmd, path=()):
    if getattr(cmd, "commands", None):
        yield " ".join(path), cmd
        for name, sub in cmd.commands.items():
            yield from _groups(sub, path + (name,))


GROUPS = dict(_groups(typer.main.get_command(app)))


def _squash(text: str) -> str:
    return "".join(text.split())


def _render(name: str, width: int = 80) -> str:
    res = CliRunner().invoke(app, [*name.split(), "--help"], terminal_width=width, env={"COLUMNS": str(width)})
    assert res.exit_code == 0, res.output
    return res.output


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_rendered_help_keeps_units_and_flags_and_cuts_nothing(name):
    text = _render(name)
    flat = _squash(text)
    assert "<bool>" not in text and "<list[" not in text, f"'{name}': a type shown instead of a value:\n{text}"
    for p in COMMANDS[name].params:
        if p.name == "help":
            continue
        # the whole help text is there, square-bracketed units included (rich markup used to eat "[mm]")
        assert _squash(p.help) in flat, f"'{name}' --{p.name}: help text missing or cut in\n{text}"
        for unit in re.findall(r"\[[^\]]+\]", p.help):
            assert unit in text.replace("\n", " ") or _squash(unit) in flat, (name, p.name, unit)
        if getattr(p, "is_flag", False) and not getattr(p, "count", False):
            longest = max(p.opts, key=len)
            # a flag is followed by its help or another option name, never by a value placeholder
            assert re.search(re.escape(longest) + r"(?:\s{2,}|\n|, |/)", text), f"'{name}': flag {longest}:\n{text}"
            assert not re.search(re.escape(longest) + r" <", text), f"'{name}': flag {longest} shows a value"


@pytest.mark.parametrize("group", sorted(GROUPS))
def test_rendered_command_lists_are_not_cut_off(group):
    text = _render(group)
    assert "..." not in text.split("Commands:")[-1].replace("<path> ...", ""), text
    for sub_name, sub in GROUPS[group].commands.items():
        summary = (sub.short_help or sub.help or "").split("\n\n")[0]
        assert _squash(summary) in _squash(text), f"'{group}': summary of '{sub_name}' cut off:\n{text}"


def test_units_in_brackets_survive_rendering():
    """The case of the issue: '[mm/s]' rendered as nothing ('speed  below which')."""
    text = _render("simulate", width=100)
    assert "speed [mm/s] below which" in " ".join(text.split())
    assert "--literal " in text and "--literal <" not in text
