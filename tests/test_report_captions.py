"""make report (issue 14): every figure the study writes is flagged for the Snakemake report with a caption,
and every caption file exists and says what, which seed result, and where the data come from."""
from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RULES = sorted((REPO / "workflow" / "rules").glob("*.smk"))
REPORT = REPO / "workflow" / "report"


def _output_lines():
    """(file, line) of every line inside a rule's ``output:`` block."""
    for path in RULES:
        section = None
        for line in path.read_text().splitlines():
            m = re.match(r"^    (\w+):\s*$", line)
            if m:
                section = m.group(1)
                continue
            if re.match(r"^\S", line):
                section = None
            if section == "output":
                yield path.name, line


def test_every_figure_output_is_captioned():
    figures = [(f, line) for f, line in _output_lines() if re.search(r"/[^\"]*\.(png|pdf)\"", line)]
    assert len(figures) >= 10, figures
    bare = [(f, line.strip()) for f, line in figures if "captioned(" not in line]
    assert not bare, f"figure outputs without a report caption: {bare}"


def test_caption_files_exist_and_say_where_the_data_come_from():
    named = set()
    for path in RULES + [REPO / "workflow" / "Snakefile"]:
        named |= set(re.findall(r"captioned\([^,]+,\s*\"(\w+)\"", path.read_text().replace("\n", " ")))
    assert named, "no captioned outputs"
    for name in named:
        cap = REPORT / f"{name}.rst"
        assert cap.is_file(), f"caption {cap} missing"
        text = cap.read_text()
        assert re.search(r"seed 00\d|seed figure|published|synthetic", text), f"{cap}: which seed result?"
        assert re.search(r"[Ss]imulated|synthetic|FE|experiment|published", text), f"{cap}: data origin?"
    assert (REPORT / "workflow.rst").is_file()


def test_make_report_target():
    text = (REPO / "Makefile").read_text()
    m = re.search(r"^report:.*\n((?:\t.*\n)+)", text, re.M)
    assert m and "--report" in m.group(1) and "configs/study.yaml" in m.group(1)
