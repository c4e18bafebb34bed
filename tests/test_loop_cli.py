"""The README's worked example end to end through the real console entry point, and bad model files."""
from __future__ import annotations

import json

import pytest

from capsule_cli.tables import read_table


def test_worked_example_error_falls_to_noise(tmp_path, cli):
    d, led = tmp_path / "case1_synthetic.csv", tmp_path / "ledger.parquet"
    steps = [
        ["synth", "--model", "configs/models/friction_coulomb_eq17_truth.yaml", "--noise-sd", "1.5", "--replicates", "4",
         "--seed", "1", "--out", d],
        ["compare", "--model", "configs/models/coulomb.yaml", "--data", d, "--out", tmp_path / "cmp0",
         "--ledger", led],
        ["diagnose", "--model", "configs/models/coulomb.yaml", "--data", d, "--out", tmp_path / "diag",
         "--write-model", tmp_path / "coulomb_plus.yaml"],
        ["compare", "--model", tmp_path / "coulomb_plus.yaml", "--data", d, "--out", tmp_path / "cmp1",
         "--ledger", led],
        ["ledger", "plot", "--ledger", led, "--out", tmp_path / "ledger.png"],
    ]
    said = {}
    for args in steps:
        # the improved model's compare is run as a user would, its summary on the terminal
        loud = args[0] == "ledger" or args[2] == tmp_path / "coulomb_plus.yaml"
        r = cli(*args) if loud else cli(*args, "--quiet")
        assert r.returncode == 0, r.stderr
        said[args[0]] = r.stderr
    # each free parameter with its 95 % interval, as metrics.json has them
    params = json.loads((tmp_path / "cmp1" / "metrics.json").read_text())["params"]
    free = {k: p for k, p in params.items() if p.get("free")}
    assert len(free) >= 2
    for key, p in free.items():
        lo, hi = p["ci95"]
        assert f"  {key} = {p['value']:.4g} [{lo:.4g}, {hi:.4g}] (95 %)" in said["compare"].splitlines()
    diag = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    assert diag["verdict"]["missing_effect"] == "speed_power_law"
    led_df = read_table(led)
    assert list(led_df["effects"]) == ["", "speed_power_law"]
    assert led_df["cv_rmse"].iloc[1] < 0.5 * led_df["cv_rmse"].iloc[0]
    assert led_df["cv_rmse"].iloc[1] <= 1.2 * 1.5
    assert (tmp_path / "ledger.png").stat().st_size > 1000
    show = cli("ledger", "show", "--ledger", led)
    assert show.returncode == 0 and "speed_power_law" in show.stdout


@pytest.mark.parametrize("text, what", [
    ("kind: friction\nbase: coulomb\neffects: [viscus]\n", "did you mean 'viscous'"),
    ("kind: friction\nbase: coulomb\nparams:\n  mu: {value: 0.2, fre: true}\n", "unknown key 'fre'"),
    ("kind: friction\nbase: coulomb\nparams:\n  a_mN: 3\n", "params.a_mN"),
    ("kind: frictions\nbase: coulomb\n", "kind"),
    ("kind: friction\nbase: [coulomb\n", "invalid YAML"),
])
def test_bad_model_files_exit_2_with_one_line(tmp_path, capsys, text, what):
    from capsule_cli.cli import main

    m = tmp_path / "bad_model.yaml"
    m.write_text(text)
    code = main(["compare", "--model", str(m), "--data", "configs/data/seed000_case1_friction.csv", "--out",
                 str(tmp_path / "o"), "--ledger", str(tmp_path / "l.parquet")])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad_model.yaml" in err and what in err, err
    assert not (tmp_path / "o").exists()


def test_the_ledger_axis_is_logarithmic_when_the_errors_span_decades(tmp_path, monkeypatch):
    """A model held out at 37.7 mm/s beside its revision at 0.59 and a noise of 0.45 (the study's dynamics demo):
    on a linear axis the revision cannot be told from the noise band, so the axis is logarithmic there; a friction
    ledger (3.43 -> 1.47 mN, noise 1.4) stays linear from zero."""
    import matplotlib.axes
    import pandas as pd

    from capsule_cli.plots.loop import ledger_log_scale, plot_ledger

    assert ledger_log_scale([37.7, 0.592, 35.8, 0.44, 0.454])
    assert not ledger_log_scale([3.43, 1.47, 3.4, 1.36, 1.4])
    assert not ledger_log_scale([5.0, float("nan"), 0.0, -1.0])  # one positive value: nothing to span
    scales = []
    orig = matplotlib.axes.Axes.set_yscale
    monkeypatch.setattr(matplotlib.axes.Axes, "set_yscale",
                        lambda self, v, **k: (scales.append(v), orig(self, v, **k))[1])
    hist = pd.DataFrame({"model": ["base", "base+sdf"], "effects": ["", "speed_dependent_friction"],
                         "cv_rmse": [37.7, 0.592], "cv_rmse_se": [6.8, 0.1], "rmse": [35.8, 0.44],
                         "noise_sd": [0.454, 0.454], "noise_sd_se": [0.072, 0.072], "unit": ["mm/s"] * 2})
    plot_ledger(hist, tmp_path / "log.png")
    assert scales == ["log"]
    plot_ledger(hist.assign(cv_rmse=[3.43, 1.47], rmse=[3.4, 1.36], noise_sd=1.4), tmp_path / "lin.png")
    assert scales == ["log"]  # the second stays linear


def test_a_logarithmic_ledger_axis_is_labelled_in_plain_numbers(tmp_path, monkeypatch):
    """The log axis of the study's dynamics ledger (37.7 -> 0.592 mm/s, noise 0.454) reads 0.4, 0.6, 1, 10, 40,
    as the values written beside the points do, not 4 x 10^-1 or 4e-01 (matplotlib's default and its plain
    LogFormatter)."""
    import pandas as pd

    import capsule_cli.plots.loop as loop_plots

    figs = []
    monkeypatch.setattr(loop_plots, "save_figure", lambda fig, path: figs.append(fig) or path)
    hist = pd.DataFrame({"model": ["base", "base+sdf"], "effects": ["", "speed_dependent_friction"],
                         "cv_rmse": [37.7, 0.592], "cv_rmse_se": [6.8, 0.1], "rmse": [35.8, 0.44],
                         "noise_sd": [0.454, 0.454], "noise_sd_se": [0.072, 0.072], "unit": ["mm/s"] * 2})
    loop_plots.plot_ledger(hist, tmp_path / "log.png")
    ax = figs[0].axes[0]
    figs[0].canvas.draw()
    assert ax.get_yscale() == "log"
    major = [t.get_text() for t in ax.get_yticklabels() if t.get_text()]
    minor = [t.get_text() for t in ax.get_yticklabels(minor=True) if t.get_text()]
    assert {"1", "10"} <= set(major)
    assert {"0.4", "0.6", "2", "40"} <= set(minor)
    assert not [s for s in major + minor if "e" in s or "times" in s or "^" in s]
