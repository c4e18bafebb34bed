"""Dynamics plugins: a per-row drive transform registered with role="drive" (issue 9 item 4a)."""
import textwrap

import numpy as np
import pytest

from capsule_cli.dynamics.system import Protocol, build_system, progression, trajectory
from conftest import plugin_loaded
from capsule_cli.errors import InputError, PluginError


PLUGIN = textwrap.dedent('''
    import math
    from capsule_cli.effects import Param, register_effect

    for kind in ("progression", "trajectory"):
        @register_effect(name="coil_gain_t9", kind=kind, role="drive",
                         params=(Param("gain", 1.5, (0.1, 10.0), off=1.0, description="coil field gain"),),
                         description="The coil's force grows with the set amplitude.", source="test")
        def coil(f_Hz, Pd_N, duty, p):
            return f_Hz, Pd_N * p["gain"], duty

        @register_effect(name="broken_coil_t9", kind=kind, role="drive",
                         params=(Param("k", 1.0, (0.0, 10.0), off=0.0),), description="raises", source="test")
        def broken(f_Hz, Pd_N, duty, p):
            if Pd_N > 0.1:
                raise ValueError("coil saturated")
            return f_Hz, Pd_N, duty

        @register_effect(name="typo_coil_t9", kind=kind, role="drive",
                         params=(Param("offset_mN", 0.0, (0.0, 50.0), off=0.0),), description="typo", source="test")
        def typo(f_Hz, Pd_N, duty, p):
            return f_Hz, Pd_N + p["offset_mN"] * 1e-3, duty  # the key is "offset" (in N: SI, the unit stripped)

        @register_effect(name="nan_coil_t9", kind=kind, role="drive",
                         params=(Param("k", 1.0, (0.0, 10.0), off=0.0),), description="NaN", source="test")
        def nan_coil(f_Hz, Pd_N, duty, p):
            return f_Hz, math.nan, duty
''')


@pytest.fixture(scope="module")
def plugin(tmp_path_factory):
    path = tmp_path_factory.mktemp("plug") / "coil_t9.py"
    path.write_text(PLUGIN)
    with plugin_loaded(path):  # unregistered afterwards: later tests on this worker must not see these effects
        yield path


def test_drive_transform_plugin_equals_the_transformed_conditions(plugin):
    s = build_system("one_sided", {"gain": 2.0}, ["coil_gain_t9"])  # x2: exact in binary
    base = build_system("one_sided", {})
    prot = Protocol("rest", 20, 8)
    a = progression(s, [20.0, 30.0], [0.075, 0.0375], protocol=prot)
    b = progression(base, [20.0, 30.0], [0.15, 0.075], protocol=prot)
    pd_cols = ["velocity_mm_s", "impacts_per_period", "period_number", "response_class"]
    assert a[pd_cols].equals(b[pd_cols])
    ta = trajectory(s, 30.0, 0.075, np.array([0.01, 0.05]))
    tb = trajectory(base, 30.0, 0.15, np.array([0.01, 0.05]))
    np.testing.assert_array_equal(ta["capsule_mm"], tb["capsule_mm"])


def test_drive_transform_off_value_is_the_base(plugin):
    s = build_system("one_sided", {"gain": 1.0}, ["coil_gain_t9"])
    base = build_system("one_sided", {})
    prot = Protocol("rest", 10, 4)
    assert progression(s, 25.0, 0.15, protocol=prot).equals(progression(base, 25.0, 0.15, protocol=prot))


@pytest.mark.parametrize("name, msg", [("broken_coil_t9", "coil saturated"), ("nan_coil_t9", "non-finite")])
def test_failing_drive_transform_is_one_line_input_error(plugin, name, msg):
    s = build_system("one_sided", {}, [name])
    with pytest.raises(InputError, match=msg) as exc:
        progression(s, 25.0, 0.15, protocol=Protocol("rest", 2, 2))
    assert "\n" not in str(exc.value)


def test_simulate_refuses_a_model_file_with_a_drive_transform(plugin, tmp_path, capsys):
    """simulate / sweep / magnify take the drive as given: a drive transform in the model file is refused with
    one line and exit 2, never silently dropped (the transform acts on a data table's rows)."""
    from capsule_cli.cli import main

    mf = tmp_path / "m.yaml"
    mf.write_text("kind: progression\nbase: one_sided\neffects: [coil_gain_t9]\nparams: {gain: 2.0}\n")
    rc = main(["simulate", "--model", str(mf), "--plugins", str(plugin), "--periods", "2", "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert "coil_gain_t9" in err and "drive transform" in err and "\n" not in err
    assert not (tmp_path / "out").exists()


def test_a_drive_transform_with_a_bug_in_its_code_is_reported_not_taken_for_a_parameter_region(plugin, tmp_path,
                                                                                                 capsys):
    """A KeyError (the user reads p["offset_mN"]; the key is "offset", in N) is a PluginError, which the dynamics
    loop never swallows: before, the loop took every run of such a model as a region the model cannot run in,
    and `synth` said only "design row 1: the model cannot be run there" (a candidate would have been lost
    silently). An arithmetic failure at some drive (ValueError "coil saturated" above 0.1 N) may be the
    parameters': the loop still takes it as a run that fails, and `synth` now gives its reason."""
    from capsule_cli.cli import main
    from capsule_cli.effects.model import build_model
    from capsule_cli.steps import dynamics_loop as DL
    import pandas as pd

    s = build_system("one_sided", {}, ["typo_coil_t9"])
    with pytest.raises(PluginError, match=r"KeyError: 'offset_mN' \(p holds 'offset'\)"):
        progression(s, 25.0, 0.15, protocol=Protocol("rest", 2, 2))
    mf = tmp_path / "typo.yaml"
    mf.write_text("kind: progression\nbase: one_sided\neffects: [typo_coil_t9]\nparams: {Pf_N: 0.02}\n"
                  "protocol: {start: rest, transient_periods: 4, recorded_periods: 4}\n")
    df = pd.DataFrame({"f_Hz": [25.0, 30.0], "Pd_N": [0.05, 0.15], "velocity_mm_s": [0.0, 0.0]})
    with pytest.raises(PluginError):
        DL.DynBound(build_model(mf), df).simulate(None)
    design = tmp_path / "design.csv"
    df[["f_Hz", "Pd_N"]].to_csv(design, index=False)
    rc = main(["synth", "--model", str(mf), "--plugins", str(plugin), "--design", str(design), "--noise-sd", "0.5",
               "--out", str(tmp_path / "typo_synthetic.csv")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "KeyError: 'offset_mN' (p holds 'offset')" in err and "\n" not in err, err
    assert not (tmp_path / "typo_synthetic.csv").exists()
    mf.write_text(mf.read_text().replace("typo_coil_t9", "broken_coil_t9"))
    assert np.isnan(DL.DynBound(build_model(mf), df).simulate(None)["pred"]).all()  # a run that fails
    rc = main(["synth", "--model", str(mf), "--plugins", str(plugin), "--design", str(design), "--noise-sd", "0.5",
               "--out", str(tmp_path / "broken_synthetic.csv")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "cannot be run there" in err and "coil saturated" in err and "\n" not in err, err
