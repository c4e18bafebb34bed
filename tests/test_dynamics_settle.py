"""Settled transient (issue 13): a map or sweep point ends its transient early, by whole orbits, once
its state at phase 0 repeats after 1-8 periods (EngineOptions.settle_tol). The recorded periods must be
those of the full transient up to that tolerance, for period-1 and longer orbits, Coulomb, speed-law and
effect modes; points that have not settled run every period."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from capsule_cli.cli import main
from capsule_cli.dynamics import engine as E
from capsule_cli.dynamics.model import Drive, EngineOptions, friction_preset, load_model, pack_params
from capsule_cli.tables import read_table

MODEL, _ = load_model("prototype_one_sided")
NT, NR = 200, 30  # magnify's defaults (seed 000 Fig 19)
GRID = [(Pd, f) for Pd in (0.05, 0.2, 0.4) for f in (8.0, 20.0, 32.0)]


def _run(model, friction, Pd, f, settle_tol, nt=NT):
    p = pack_params(model, Drive(Pd, f), friction)
    o = EngineOptions(energy=False, rk_rtol=1e-9, settle_tol=settle_tol).pack()
    st, _, _, _, _, _, per, _, fin = E.run_core(p, o, np.zeros(4), nt, NR, 1.0, 0, 0)
    assert st == E.STATUS_OK
    return per, fin


@pytest.mark.parametrize("friction,model", [
    (friction_preset("coulomb", 2.5), MODEL),
    (friction_preset("coulomb", 0.17), MODEL),
    (friction_preset("coulomb", 0.02), dataclasses.replace(MODEL, drag_Ns_m=0.05, tilt_kappa=0.1)),
], ids=["coulomb_2.5", "coulomb_0.17", "drag_tilt"])
def test_settled_transient_records_the_full_transients_periods(friction, model):
    """Exact (closed-form) modes. Per recorded period: peak |F_i| within 1e-9 relative; displacement
    within 1e-8 mm (exact modes agree to ~1e-12 mm); the shell's position at the period's start, where
    the skipped orbits' drift is added, within 1e-8 mm per skipped period plus 1e-10 relative (it travels
    up to 0.5 m). At least one point of the grid skips periods; the recorded periods after the first
    orbit are filled from it (maps record no samples, events or energy)."""
    integrated = []
    for Pd, f in GRID:
        full, fin0 = _run(model, friction, Pd, f, 0.0)
        cut, fin1 = _run(model, friction, Pd, f, 1e-12)
        assert fin0[6] == NT + NR
        integrated.append(fin1[6])
        np.testing.assert_allclose(cut[:, E.P_MAXF], full[:, E.P_MAXF], rtol=1e-9, atol=0)
        np.testing.assert_allclose(cut[:, E.P_DISP], full[:, E.P_DISP], rtol=0, atol=1e-11)
        skipped = NT + NR - fin1[6]
        np.testing.assert_allclose(cut[:, E.P_XC0], full[:, E.P_XC0], rtol=1e-10, atol=1e-11 * (skipped + 1))
        np.testing.assert_array_equal(cut[:, E.P_NFRONT], full[:, E.P_NFRONT])
    assert min(integrated) < NT  # settled points were cut short
    assert max(integrated) <= NT + NR


def test_settled_speed_law_is_as_accurate_as_its_full_transient():
    """A speed law (eq 22) integrates its slips on the adaptive path at rk_rtol 1e-9, whose error per
    period keeps the phase-0 state from repeating more closely than about rk_rtol: its settled-transient
    test works at max(settle_tol, SETTLE_RTOL_FRACTION x rk_rtol) (engine.py). Against a tight run
    (rk_rtol 1e-12, every period), the cut run must be as accurate as the full run at the same rk_rtol,
    point by point: its error within 5 times the full run's plus rk_rtol (peak |F_i|, relative),
    plus 1e-13 m (displacement per period) or plus rk_rtol relative (position at a period's start).
    (Measured on this grid: the cut runs' errors are 0.9-2.7 times the full runs'; the full runs
    themselves err by up to 7e-8 in the peak force.)"""
    fr = friction_preset("eq22")
    integrated = []
    for Pd, f in GRID:
        p = pack_params(MODEL, Drive(Pd, f), fr)
        o = EngineOptions(energy=False, rk_rtol=1e-12, settle_tol=0.0).pack()
        ref = E.run_core(p, o, np.zeros(4), NT, NR, 1.0, 0, 0)[6]
        full, fin0 = _run(MODEL, fr, Pd, f, 0.0)
        cut, fin1 = _run(MODEL, fr, Pd, f, 1e-12)
        assert fin0[6] == NT + NR
        integrated.append(fin1[6])
        for col, rel, floor in ((E.P_MAXF, True, 1e-9), (E.P_DISP, False, 1e-13), (E.P_XC0, True, 1e-9)):
            scale = np.abs(ref[:, col]) if rel else 1.0
            e_full = np.max(np.abs(full[:, col] - ref[:, col]) / scale)
            e_cut = np.max(np.abs(cut[:, col] - ref[:, col]) / scale)
            assert e_cut <= 5.0 * e_full + floor, (Pd, f, col, e_cut, e_full)
        np.testing.assert_array_equal(cut[:, E.P_NFRONT], full[:, E.P_NFRONT])
    assert min(integrated) < NT // 2  # settled points were cut short, their recorded periods too
    assert max(integrated) <= NT + NR


def test_recorded_periods_are_filled_only_after_one_whole_orbit():
    """A settled period-1 point integrates its remaining transient and one recorded period, then fills
    the other recorded periods from it: same peak and displacement, the start position advanced by the
    displacement, the peak's time by one period. A run that records samples integrates every recorded
    period (nothing filled)."""
    fr = friction_preset("coulomb", 0.17)
    Pd, f = 0.3, 30.0
    cut, fin = _run(MODEL, fr, Pd, f, 1e-12)
    assert fin[6] < NT  # settled and cut
    np.testing.assert_array_equal(cut[1:, E.P_MAXF], cut[0, E.P_MAXF])
    np.testing.assert_array_equal(cut[1:, E.P_DISP], cut[0, E.P_DISP])
    np.testing.assert_allclose(np.diff(cut[:, E.P_XC0]), cut[0, E.P_DISP], rtol=1e-12)
    np.testing.assert_allclose(np.diff(cut[:, E.P_TMAXF]), 1.0 / f, rtol=1e-12)
    p = pack_params(MODEL, Drive(Pd, f), fr)
    o = EngineOptions(energy=False, settle_tol=1e-12).pack()
    res = E.run_core(p, o, np.zeros(4), NT, NR, 1e-3, 10, 0)
    assert res[8][6] == NT + NR - (NT - fin[6] + 1)  # only the transient was cut (1 recorded period)
    np.testing.assert_allclose(res[6][:, E.P_MAXF], cut[:, E.P_MAXF], rtol=1e-12)


def test_orbits_longer_than_one_period_are_cut_by_whole_orbits():
    """A period-2 (or longer) response keeps its phase: the recorded sequence of peak forces alternates
    as in the full run (not shifted by one period)."""
    fr = friction_preset("coulomb", 2.5)
    found = 0
    for Pd in np.linspace(0.05, 0.5, 10):
        for f in np.linspace(5.0, 40.0, 8):
            full, _ = _run(MODEL, fr, Pd, f, 0.0)
            mx = full[:, E.P_MAXF]
            if abs(mx[0] - mx[1]) > 1e-6 * mx[0] and abs(mx[0] - mx[2]) < 1e-9 * mx[0]:  # period 2
                cut, fin = _run(MODEL, fr, Pd, f, 1e-12)
                if fin[6] < NT:
                    found += 1
                    np.testing.assert_allclose(cut[:, E.P_MAXF], mx, rtol=1e-9)
    assert found >= 1


def test_no_settling_when_off_or_far_from_steady():
    """settle_tol = 0 runs every period; a short transient that has not settled is not cut."""
    fr = friction_preset("coulomb", 0.17)
    _, fin = _run(MODEL, fr, 0.3, 30.0, 0.0)
    assert fin[6] == NT + NR
    _, fin = _run(MODEL, fr, 0.3, 30.0, 1e-12, nt=3)
    assert fin[6] == 3 + NR


def test_magnify_records_settle_tol_and_refuses_a_bad_one(tmp_path):
    out = tmp_path / "m.parquet"
    args = ["magnify", "--Pf-N", "2.5", "--Pd-num", "2", "--f-num", "2", "--quiet"]
    assert main([*args, "--out", str(out), "--settle-tol", "-1"]) == 2
    assert main([*args, "--out", str(out), "--settle-tol", "0.1"]) == 2
    assert not out.exists()
    assert main([*args, "--out", str(out)]) == 0
    assert read_table(out).attrs.get("provenance", {}).get("settle_tol") == 1e-12
    off = tmp_path / "off.parquet"
    assert main([*args, "--out", str(off), "--settle-tol", "0"]) == 0
    a, b = read_table(out), read_table(off)
    np.testing.assert_allclose(a["Af"].to_numpy(), b["Af"].to_numpy(), rtol=1e-9)
