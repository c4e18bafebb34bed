"""The CI smoke workflow (.github/workflows/ci.yml) and .ci/run run the same test command (issue 14),
and the workflow does what users of a public repository expect: runs on push and pull request, caches pip
and the compiled numba code, uploads the smoke study's figures."""
from __future__ import annotations

import re
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
WORKFLOW = REPO / ".github" / "workflows" / "ci.yml"


def _ci_run_commands() -> list[str]:
    """The commands of .ci/run, without comments, shell options and the cd to the repository."""
    cmds = []
    for line in (REPO / ".ci" / "run").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if not line or line.startswith(("set ", "cd ")):
            continue
        cmds.append(line)
    return cmds


def _workflow() -> dict:
    wf = yaml.safe_load(WORKFLOW.read_text())
    wf["on"] = wf.pop(True, wf.get("on"))  # YAML 1.1 reads the key 'on' as True
    return wf


def _run_steps(wf) -> list[str]:
    return [s["run"].strip() for job in wf["jobs"].values() for s in job["steps"] if "run" in s]


def test_ci_workflow_runs_the_command_of_ci_run():
    ci_run = _ci_run_commands()
    assert ci_run == ["make test"], ci_run  # the README's test command
    steps = _run_steps(_workflow())
    assert steps == ci_run, f"ci.yml runs {steps}, .ci/run runs {ci_run}"


def test_ci_workflow_triggers_caches_and_uploads():
    wf = _workflow()
    assert {"push", "pull_request"} <= set(wf["on"])
    steps = [s for job in wf["jobs"].values() for s in job["steps"]]
    uses = {s.get("uses", "").split("@")[0]: s for s in steps}
    assert uses["actions/setup-python"]["with"]["cache"] == "pip"
    assert uses["actions/setup-python"]["with"]["python-version"] == "3.11"
    env = {k: v for job in wf["jobs"].values() for k, v in job.get("env", {}).items()}
    # the numba cache folder is the one the cache step saves
    assert Path(uses["actions/cache"]["with"]["path"]).name == Path(env["NUMBA_CACHE_DIR"]).name
    # the smoke study writes where the upload step looks
    upload = uses["actions/upload-artifact"]["with"]["path"]
    assert re.match(re.escape(Path(env["CAPSULE_SMOKE_RESULTS"]).name) + r"/", upload) and upload.endswith(".png")


def test_smoke_test_honours_the_ci_results_folder():
    text = (REPO / "tests" / "test_workflow_smoke.py").read_text()
    assert "CAPSULE_SMOKE_RESULTS" in text
