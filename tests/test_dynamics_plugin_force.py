"""Dynamics plugins: an extra force of state and time registered with role="force" (issue 9 item 4, second sort).

The plugin forces are written as a user would, in a plugin file; they are compiled with numba and called by
the (cached) engine through a C function pointer (capsule_cli.dynamics.plugin_force). Cross-checks against
exactly known results: a spring between magnet and shell is the helical spring stiffened (the engine's
closed-form path), a drag on the shell is the built-in ``viscous_drag``, a constant force on the shell moves
the breakaway threshold, an attraction's work is minus the change of its potential.
"""
import math
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from capsule_cli.dynamics.model import Drive, friction_preset, load_model
from capsule_cli.dynamics.run import simulate
from capsule_cli.dynamics.system import Protocol, build_system, progression, trajectory
from capsule_cli.errors import InputError
from conftest import plugin_loaded


PLUGIN = textwrap.dedent('''
    import math
    from capsule_cli.effects import Param, register_effect

    for kind in ("progression", "trajectory"):
        @register_effect(name="extra_spring_t9f", kind=kind, role="force",
                         params=(Param("k_extra_N_m", 20.0, (0.0, 1000.0), off=0.0,
                                       description="stiffness of a second spring between magnet and shell"),),
                         description="A second spring between magnet and shell.", source="test")
        def extra_spring(t, x_m, v_m, x_c, v_c, p):
            F = -p[0] * (x_m - x_c)
            return F, -F

        @register_effect(name="shell_drag_t9f", kind=kind, role="force",
                         params=(Param("c_drag_Ns_m", 0.1, (0.0, 10.0), off=0.0, description="drag"),),
                         description="Viscous drag on the shell.", source="test")
        def shell_drag(t, x_m, v_m, x_c, v_c, p):
            return 0.0, -p[0] * v_c

        @register_effect(name="shell_push_t9f", kind=kind, role="force",
                         params=(Param("push_mN", 1.0, (-100.0, 100.0), off=0.0, description="push"),),
                         description="A constant force on the shell.", source="test")
        def shell_push(t, x_m, v_m, x_c, v_c, p):
            return 0.0, p[0]

        @register_effect(name="attraction_t9f", kind=kind, role="force",
                         params=(Param("attraction_mN", 5.0, (0.0, 100.0), off=0.0, description="at the gap"),
                                 Param("range_mm", 0.3, (0.01, 10.0), off=0.3, description="decay length")),
                         description="Magnet and shell attract, more as they approach.", source="test")
        def attraction(t, x_m, v_m, x_c, v_c, p):
            F = p[0] * math.exp(-(x_c + 1.6e-3 - x_m) / p[1])
            return F, -F

        @register_effect(name="raises_t9f", kind=kind, role="force",
                         params=(Param("k_N", 1.0, (0.0, 10.0), off=0.0),), description="raises", source="test")
        def raises(t, x_m, v_m, x_c, v_c, p):
            raise ValueError("coil burnt")

        @register_effect(name="nan_t9f", kind=kind, role="force",
                         params=(Param("k_N", 1.0, (0.0, 10.0), off=0.0),), description="NaN", source="test")
        def nan_force(t, x_m, v_m, x_c, v_c, p):
            return math.nan, 0.0

        @register_effect(name="dict_t9f", kind=kind, role="force",
                         params=(Param("k_N", 1.0, (0.0, 10.0), off=0.0),), description="a dict", source="test")
        def dict_force(t, x_m, v_m, x_c, v_c, p):
            d = {"F": object()}
            return d["F"], 0.0

        @register_effect(name="late_nan_t9f", kind=kind, role="force",
                         params=(Param("k_N", 1.0, (0.0, 10.0), off=0.0),), description="NaN later", source="test")
        def late_nan(t, x_m, v_m, x_c, v_c, p):
            if x_m - x_c > 1e-3:
                return math.inf, 0.0
            return 0.0, 0.0

        @register_effect(name="late_raise_t9f", kind=kind, role="force",
                         params=(Param("k_N", 1.0, (0.0, 10.0), off=0.0),), description="raises later",
                         source="test")
        def late_raise(t, x_m, v_m, x_c, v_c, p):
            if t > 0.05:
                raise ValueError("coil burnt later")
            return 0.0, 0.0
''')


@pytest.fixture(scope="module")
def plugin(tmp_path_factory):
    path = tmp_path_factory.mktemp("plugforce") / "forces_t9f.py"
    path.write_text(PLUGIN)
    with plugin_loaded(path):  # unregistered afterwards: later tests on this worker must not see these forces
        yield path


def _events(r):
    ev = r.events[~r.events["kind"].astype(str).str.startswith("drive")]
    return ev["time_s"].to_numpy(), ev["kind"].astype(str).to_numpy()


def _same_events(a, b, tol_s):
    ta, ka = _events(a)
    tb, kb = _events(b)
    assert list(ka) == list(kb)
    assert len(ta) > 3
    assert np.max(np.abs(ta - tb)) < tol_s
    return np.max(np.abs(ta - tb))


@pytest.mark.parametrize("Pf_N, f_Hz", [(0.0078, 20.0), (0.0078, 37.0), (2.5, 10.0), (math.inf, 30.0)])
def test_spring_plugin_equals_a_stiffer_helical_spring(plugin, Pf_N, f_Hz):
    """F = -k_e (x_m - x_c) on the magnet, +k_e (...) on the shell is the spring k + k_e: the adaptive
    path with the plugin against the engine's closed form, event times within 1e-8 s."""
    s = build_system("one_sided", {"k_extra_N_m": 20.0, "Pf_N": Pf_N}, ["extra_spring_t9f"])
    base = build_system("one_sided", {"spring_N_m": 62.0 + 20.0, "Pf_N": Pf_N})
    d = Drive(0.15, f_Hz)
    a = simulate(s.model, d, s.friction(), periods=10, sample_rate_Hz=0)
    b = simulate(base.model, d, base.friction(), periods=10, sample_rate_Hz=0)
    _same_events(a, b, 1e-8)
    np.testing.assert_allclose(a.final_state[:4], b.final_state[:4], rtol=0, atol=1e-8)
    # the plugin's work is counted: balance to ~1e-10, and it is minus the change of the extra spring energy
    assert abs(a.energy["relative_residual"]) < 2e-9, a.energy
    assert a.energy["plugin_work_J"] != 0.0
    xr0 = 0.0
    xr1 = a.final_state[0]
    assert a.energy["plugin_work_J"] == pytest.approx(-0.5 * 20.0 * (xr1 ** 2 - xr0 ** 2), rel=1e-6, abs=1e-13)


@pytest.mark.parametrize("effects, prm, law", [((), {}, "eq22"), (("secondary_constraint",), {}, None),
                                               (("tilt_friction",), {"kappa": -0.9}, None),
                                               (("substrate_compliance",), {}, None)])
def test_spring_plugin_with_other_effects(plugin, effects, prm, law):
    """The plugin force combines with the speed laws (fast slip), the back constraint, tilt (the held
    stick test with a tilt-scaled cone) and substrate compliance (the patch modes), to 1e-8 s."""
    s = build_system("one_sided", {**prm, "k_extra_N_m": 20.0}, [*effects, "extra_spring_t9f"])
    base = build_system("one_sided", {**prm, "spring_N_m": 82.0}, list(effects))
    fr = friction_preset(law) if law else s.friction()
    d = Drive(0.15, 25.0)
    a = simulate(s.model, d, fr, periods=8, sample_rate_Hz=0)
    b = simulate(base.model, d, fr, periods=8, sample_rate_Hz=0)
    _same_events(a, b, 1e-8)
    assert abs(a.energy["relative_residual"]) < 2e-9, a.energy


def test_spring_plugin_trajectory_and_progression_match(plugin):
    s = build_system("one_sided", {"k_extra_N_m": 20.0}, ["extra_spring_t9f"])
    base = build_system("one_sided", {"spring_N_m": 82.0})
    t = np.linspace(0.0, 0.3, 31)
    ta = trajectory(s, 30.0, 0.15, t)
    tb = trajectory(base, 30.0, 0.15, t)
    np.testing.assert_allclose(ta["capsule_mm"], tb["capsule_mm"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(ta["magnet_mm"], tb["magnet_mm"], rtol=0, atol=1e-6)
    prot = Protocol("rest", 20, 8)
    pa = progression(s, [22.0, 32.0], 0.15, protocol=prot)
    pb = progression(base, [22.0, 32.0], 0.15, protocol=prot)
    np.testing.assert_allclose(pa["velocity_mm_s"], pb["velocity_mm_s"], rtol=1e-7)
    assert list(pa["impacts_per_period"]) == list(pb["impacts_per_period"])


def test_drag_plugin_equals_the_builtin_viscous_drag(plugin):
    """A plugin force equal to a built-in effect gives the built-in's trajectory (issue 9 item 6)."""
    s = build_system("one_sided", {"c_drag_Ns_m": 0.1}, ["shell_drag_t9f"])
    b = build_system("one_sided", {"drag_Ns_m": 0.1}, ["viscous_drag"])
    d = Drive(0.15, 30.0)
    ra = simulate(s.model, d, s.friction(), periods=10, sample_rate_Hz=0)
    rb = simulate(b.model, d, b.friction(), periods=10, sample_rate_Hz=0)
    _same_events(ra, rb, 1e-8)
    # the built-in counts the drag as friction dissipation, the plugin as (negative) plugin work
    assert ra.energy["plugin_work_J"] < 0
    assert -ra.energy["plugin_work_J"] + ra.energy["friction_J"] == pytest.approx(rb.energy["friction_J"], rel=1e-7)
    assert abs(ra.energy["relative_residual"]) < 2e-9


def test_constant_shell_force_shifts_the_breakaway_exactly(plugin):
    """A constant force F0 on the shell moves the stick test's cone: the shell stays stuck while
    F_i + F0 < P_f (so it breaks forward first when F_i reaches P_f - F0, as with a level P_f - F0)."""
    d = Drive(0.01, 10.0)
    fr = friction_preset("coulomb", 0.05)
    # F0 = 30 mN: F_i (below 20 mN here) + F0 stays inside the cone: stuck throughout, X_c == 0 exactly
    s = build_system("one_sided", {"push_mN": 30.0, "Pf_N": 0.05}, ["shell_push_t9f"])
    r = simulate(s.model, d, fr, periods=5, sample_rate_Hz=0)
    assert r.periods["stick_fraction"].min() == 1.0
    assert (r.trajectory.empty or np.all(r.trajectory["capsule_mm"] == 0.0))
    assert r.final_state[2] == 0.0 and r.final_state[3] == 0.0
    # the base with the level P_f - F0 = 20 mN stays stuck too (F_i < 20 mN)
    base = simulate(load_model("prototype_one_sided")[0], d, friction_preset("coulomb", 0.02), periods=5)
    assert base.periods["stick_fraction"].min() == 1.0
    # F0 = 45 mN: the first breakaway (forward) is the base's with the level P_f - F0 = 5 mN
    s2 = build_system("one_sided", {"push_mN": 45.0, "Pf_N": 0.05}, ["shell_push_t9f"])
    r2 = simulate(s2.model, d, fr, periods=1, sample_rate_Hz=0)
    b2 = simulate(load_model("prototype_one_sided")[0], d, friction_preset("coulomb", 0.005), periods=1)
    t2, k2 = _events(r2)
    tb, kb = _events(b2)
    assert k2[0] == kb[0] == "slip_forward"
    assert abs(t2[0] - tb[0]) < 1e-9
    # ... and it slides back later only under a force 2 F0 larger than the base's (asymmetric cone)
    assert "slip_backward" not in list(k2)


def test_attraction_work_is_minus_its_potential_change(plugin):
    """An internal attraction F(x_r) = A exp(-(G_1 - x_r)/lambda), (F, -F): its integrated work is
    -Delta U with U = -A lambda exp(-(G_1 - x_r)/lambda), and the balance closes to ~1e-10."""
    A, lam, G1 = 5e-3, 0.3e-3, 1.6e-3
    s = build_system("one_sided", {"attraction_mN": 5.0, "range_mm": 0.3}, ["attraction_t9f"])
    r = simulate(s.model, Drive(0.15, 30.0), s.friction(), periods=12, sample_rate_Hz=0)
    U = lambda xr: -A * lam * math.exp(-(G1 - xr) / lam)  # noqa: E731
    W = r.energy["plugin_work_J"]
    assert W == pytest.approx(-(U(r.final_state[0]) - U(0.0)), rel=1e-7)
    assert abs(r.energy["relative_residual"]) < 2e-9, r.energy
    # it changes the motion (it is not a no-op) and its off value is the base
    base = build_system("one_sided", {})
    rb = simulate(base.model, Drive(0.15, 30.0), base.friction(), periods=12, sample_rate_Hz=0)
    assert abs(r.average_velocity_mm_s - rb.average_velocity_mm_s) > 1e-3
    off = build_system("one_sided", {"attraction_mN": 0.0}, ["attraction_t9f"])
    ro = simulate(off.model, Drive(0.15, 30.0), off.friction(), periods=12, sample_rate_Hz=0)
    _same_events(ro, rb, 1e-8)


@pytest.mark.parametrize("name, msg", [("raises_t9f", "raised ValueError: coil burnt"),
                                       ("nan_t9f", "non-finite"), ("dict_t9f", "does not compile with numba")])
def test_bad_plugin_is_one_line_input_error_at_build(plugin, name, msg):
    with pytest.raises(InputError, match=msg) as exc:
        build_system("one_sided", {}, [name])
    assert "\n" not in str(exc.value)
    assert name in str(exc.value)


@pytest.mark.parametrize("name", ["late_nan_t9f", "late_raise_t9f"])
def test_plugin_failing_during_the_run_stops_with_one_line(plugin, name):
    s = build_system("one_sided", {}, [name])  # fine at the trial states
    with pytest.raises(InputError, match=f"plugin force '{name}' raised or returned a non-finite") as exc:
        simulate(s.model, Drive(0.15, 30.0), s.friction(), periods=20, sample_rate_Hz=0)
    assert "\n" not in str(exc.value)
    with pytest.raises(InputError, match="non-finite"):
        progression(s, [30.0, 31.0], 0.15, protocol=Protocol("rest", 10, 10))


def test_force_role_registration_rules():
    from capsule_cli.effects.registry import Param, register_effect

    with pytest.raises(ValueError, match="progression or trajectory"):
        register_effect(name="bad_kind_t9f", kind="friction", role="force", params=(Param("k_N", 1.0, (0, 2), 0.0),),
                        description="x", source="t")(lambda t, xm, vm, xc, vc, p: (0.0, 0.0))
    with pytest.raises(ValueError, match="repeatable"):
        register_effect(name="bad_rep_t9f", kind="progression", role="force", repeatable=True,
                        params=(Param("k_N", 1.0, (0, 2), 0.0),), description="x",
                        source="t")(lambda t, xm, vm, xc, vc, p: (0.0, 0.0))


def _cli(*args, cwd):
    code = "from capsule_cli.cli import main; main()"
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=cwd)


def test_cli_simulate_and_sweep_with_a_plugin_force(plugin, tmp_path):
    doc = {"kind": "progression", "base": "one_sided", "effects": ["extra_spring_t9f"],
           "params": {"Pf_N": 0.0078, "k_extra_N_m": 20.0}}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    r = _cli("simulate", "--model", "m.yaml", "--plugins", str(plugin), "--out", "sim", "--periods", "10",
             "--f-Hz", "30", "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    b = _cli("simulate", "--set", "spring_N_m=82", "--out", "base", "--periods", "10", "--f-Hz", "30", "-q",
             cwd=tmp_path)
    assert b.returncode == 0, b.stderr
    import json
    sa = json.loads((tmp_path / "sim" / "summary.json").read_text())
    sb = json.loads((tmp_path / "base" / "summary.json").read_text())
    assert sa["average_velocity_mm_s"] == pytest.approx(sb["average_velocity_mm_s"], rel=1e-8)
    assert sa["energy_balance"]["plugin_work_J"] != 0.0
    assert abs(sa["energy_balance"]["relative_residual"]) < 2e-9
    assert sa["provenance"]["model"]["plugin_forces"] == [["progression", "extra_spring_t9f", [20.0]]]
    w = _cli("sweep", "--model", "m.yaml", "--plugins", str(plugin), "--out", "sw", "--param", "f_Hz", "--start",
             "25", "--stop", "30", "--num", "2", "--transient-periods", "5", "--periods", "5", "-q", cwd=tmp_path)
    assert w.returncode == 0, w.stderr
    # magnify loads the plugins before it reads the model file, and takes the file's P_f
    g = _cli("magnify", "--model", "m.yaml", "--plugins", str(plugin), "--out", "mg.parquet", "--Pd-num", "1",
             "--f-start-Hz", "30", "--f-num", "1", "--transient-periods", "5", "--periods", "3", "-q", cwd=tmp_path)
    assert g.returncode == 0, g.stderr
    assert list(pd.read_parquet(tmp_path / "mg.parquet")["Pf_N"]) == [0.0078]
    # without --plugins the effect is unknown: one line, exit 2
    n = _cli("simulate", "--model", "m.yaml", "--out", "sim2", "--periods", "2", "-q", cwd=tmp_path)
    assert n.returncode == 2 and n.stderr.count("\n") == 1 and "extra_spring_t9f" in n.stderr


@pytest.mark.parametrize("name", ["dict_t9f", "late_nan_t9f"])
def test_cli_bad_plugin_exit_2_one_line(plugin, tmp_path, name):
    doc = {"kind": "progression", "base": "one_sided", "effects": [name], "params": {"Pf_N": 0.0078}}
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    r = _cli("simulate", "--model", "m.yaml", "--plugins", str(plugin), "--out", "sim", "--periods", "20", "-q",
             cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and name in r.stderr
    assert not (Path(tmp_path) / "sim" / "summary.json").exists()
