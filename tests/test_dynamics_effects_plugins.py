"""Dynamics plugins: a per-row drive transform registered with role="drive" (issue 9 item 4a)."""
import textwrap

import numpy as np
import pytest

from capsule_cli.dynamics.system import Protocol, build_system, progression, trajectory
from capsule_cli.effects.registry import load_plugins
from capsule_cli.errors import InputError

pytestmark = pytest.mark.xdist_group("dynamics")

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

        @register_effect(name="nan_coil_t9", kind=kind, role="drive",
                         params=(Param("k", 1.0, (0.0, 10.0), off=0.0),), description="NaN", source="test")
        def nan_coil(f_Hz, Pd_N, duty, p):
            return f_Hz, math.nan, duty
''')


@pytest.fixture(scope="module")
def plugin(tmp_path_factory):
    path = tmp_path_factory.mktemp("plug") / "coil_t9.py"
    path.write_text(PLUGIN)
    load_plugins([path], entry_points=False)
    return path


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
