"""docs/study.md maps each seed figure or table to its rule and output (issue 14): every output it names must
be made by the full study (`make study`), by the rule it names."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "study.md"


@pytest.fixture(scope="module")
def study_outputs(tmp_path_factory) -> dict[str, str]:
    """{output path: rule} of every job of the full study, from Snakemake's summary in an empty folder."""
    snakemake = Path(sys.executable).with_name("snakemake")
    cwd = tmp_path_factory.mktemp("study_dag")
    r = subprocess.run([str(snakemake), "-s", str(REPO / "workflow" / "Snakefile"), "--configfile",
                        str(REPO / "configs" / "study.yaml"), "--directory", str(cwd), "--summary"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    rows = [line.split("\t") for line in r.stdout.splitlines()[1:] if "\t" in line]
    return {row[0]: row[2] for row in rows}


def _named_outputs() -> list[tuple[str, str]]:
    """(rules, output) for every table row of docs/study.md that names a rule; outputs in backticks."""
    pairs = []
    for line in DOC.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 3 or not re.fullmatch(r"`[a-z0-9_]+`(, `[a-z0-9_]+`)*", cells[1]):
            continue
        rules = tuple(re.findall(r"`([a-z0-9_]+)`", cells[1]))
        for out in re.findall(r"`(results/[^`]+)`", cells[2]):
            pairs.append((rules, out))
    return pairs


def test_the_map_names_outputs():
    pairs = _named_outputs()
    assert len(pairs) >= 25, pairs
    # every figure of the study report appears in the map
    text = DOC.read_text()
    for fig in ("pressure_vs_speed.png", "hoop_vs_radius.png", "end_shape.png", "friction_vs_speed.png",
                "fig17_rest.png", "fig18_down.png", "magnify.png", "duty_map.png", "landmarks.md"):
        assert fig in text, fig


def test_every_output_named_is_a_study_target_of_its_rule(study_outputs):
    missing, wrong_rule = [], []
    for rules, out in _named_outputs():
        if out not in study_outputs:
            missing.append(out)
        elif study_outputs[out] not in rules:
            wrong_rule.append((out, rules, study_outputs[out]))
    assert not missing, f"docs/study.md names outputs the study does not make: {missing}"
    assert not wrong_rule, f"docs/study.md names the wrong rule: {wrong_rule}"


def test_links_point_at_the_named_outputs():
    """Each markdown link of the map leads (from docs/) to the output it shows."""
    for label, target in re.findall(r"\[`(results/[^`]+)`\]\(([^)]+)\)", DOC.read_text()):
        assert target == f"../{label}", (label, target)
