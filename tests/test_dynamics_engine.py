"""The event-driven engine against a tight-tolerance solve_ivp reference (seed 000 eqs 19-23).

Reference: capsule_cli.dynamics.reference (independent code in X_m, X_c, V_m, V_c; DOP853,
rtol 1e-12, atol 1e-15 m / 1e-12 m/s, terminal events for every switch). Tolerances:
event times 1e-9 s (the issue's target) for the closed-form modes; 1e-8 s where the
speed-dependent slip is integrated by the engine's DOPRI5 (rtol 1e-11); states at phase 0
1e-9 of the gap G_1 and 1e-7 m/s.
"""
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq

from capsule_cli.dynamics import engine as E
from capsule_cli.dynamics import CapsuleModel, Drive, DynamicsError, friction_preset, load_model, simulate
from capsule_cli.dynamics.reference import reference_run
from capsule_cli.dynamics.sweep import period_number, run_sweep


@pytest.fixture(scope="module")
def one_sided():
    model, pf = load_model("prototype_one_sided")
    return model, pf


@pytest.fixture(scope="module")
def double_sided():
    model, _ = load_model("prototype_double_sided")
    return model


def _compare(model, drive, fr, periods, t_tol, x_tol=1.6e-12, v_tol=1e-7, state0=None):
    eng = simulate(model, drive, fr, periods=periods, state0=state0)
    ref = reference_run(model, drive, fr, periods, state0=state0)
    ee = [(t, k) for t, k in zip(eng.events["time_s"], eng.events["kind"]) if not k.startswith("drive")]
    rr = [(t, k) for t, k in ref.events if not k.startswith("drive")]
    assert [k for _, k in ee] == [k for _, k in rr], "event sequences differ"
    dt = max(abs(a - b) for (a, _), (b, _) in zip(ee, rr))
    assert dt < t_tol, f"max event-time error {dt:.3e} s"
    P = ref.poincare
    xr = P[:-1, 0] - P[:-1, 1]
    vr = P[:-1, 2] - P[:-1, 3]
    assert np.max(np.abs(xr - eng.periods["relative_mm"].to_numpy() * 1e-3)) < x_tol
    assert np.max(np.abs(vr - eng.periods["relative_velocity_mm_s"].to_numpy() * 1e-3)) < v_tol
    fin = eng.final_state
    assert abs(fin[2] - P[-1, 1]) < x_tol * 10  # capsule position after the run
    assert abs(fin[3] - P[-1, 3]) < v_tol
    return eng, ee


def test_free_flight_and_slip_match_reference_below_grazing(one_sided):
    # 10 Hz, P_d = 0.15 N, Coulomb 7.8 mN: no impact, the shell slips both ways (seed 000 Fig 17 left part)
    model, pf = one_sided
    d, fr = Drive(0.15, 10.0), friction_preset("coulomb", pf)
    settled = simulate(model, d, fr, periods=1, transient_periods=100).final_state
    s0 = [settled[0], settled[1], 0.0, settled[3]]
    eng, ev = _compare(model, d, fr, 6, 1e-9, state0=s0)
    assert not any(k.startswith("front_contact") for _, k in ev)
    assert any(k == "slip_backward" for _, k in ev)


@pytest.mark.parametrize("f_Hz", [30.0, 38.0])
def test_impacting_runs_match_reference(one_sided, f_Hz):
    model, pf = one_sided
    eng, ev = _compare(model, Drive(0.15, f_Hz), friction_preset("coulomb", pf), 6, 1e-9)
    assert sum(k == "front_contact_on" for _, k in ev) >= 4


def test_stick_and_slip_with_large_friction_match_reference(one_sided):
    # P_f = 2.5 N (seed 000 Fig 18): the shell sticks most of the time and slips forward on impacts
    model, _ = one_sided
    eng, ev = _compare(model, Drive(0.15, 15.0), friction_preset("coulomb", 2.5), 6, 1e-9)
    kinds = {k for _, k in ev}
    assert {"stick", "slip_forward", "front_contact_on"} <= kinds
    assert eng.periods["stick_fraction"].mean() > 0.5


@pytest.mark.parametrize("law", ["eq22", "eq23"])
def test_stick_slip_with_speed_dependent_friction_matches_reference(one_sided, law):
    # well-posed eqs 22/23: the DOPRI5 segment (rtol 1e-11) limits the event accuracy to ~1e-9 s
    model, _ = one_sided
    eng, ev = _compare(model, Drive(0.15, 30.0), friction_preset(law), 6, 1e-8, x_tol=1e-10, v_tol=1e-6)
    assert any(k == "stick" for _, k in ev) or law == "eq23"


def test_square_wave_edges_double_sided_match_reference(double_sided):
    # seed 001 App. A square wave on the double-sided model, contact damping included
    eng, ev = _compare(double_sided, Drive(1.2, 30.0, "square", 0.2), friction_preset("coulomb", 1.5), 5, 1e-9)
    kinds = {k for _, k in ev}
    assert {"front_contact_on", "back_contact_on"} <= kinds
    edges = eng.events[eng.events["kind"] == "drive_off"]["time_s"].to_numpy()
    np.testing.assert_allclose(edges, (np.arange(5) + 0.2) / 30.0, rtol=0, atol=1e-15)


def test_brief_grazing_contact_is_found(one_sided):
    """A free oscillation whose peak exceeds G_1 by 0.1 nm: contact lasts ~4 us, ~700 times shorter
    than the bracketing grid; the extremum test must still find it, at the analytic time."""
    model, _ = one_sided
    M, k, c, G1 = model.mass_magnet_kg, model.spring_N_m, model.damping_Ns_m, model.gap_m
    sig = -c / (2 * M)
    wd = math.sqrt(k / M - sig ** 2)

    def x(t, v0):
        return math.exp(sig * t) * v0 / wd * math.sin(wd * t)

    def peak(v0):
        tp = math.atan2(wd, -sig) / wd  # first maximum of e^{sig t} sin(wd t)
        return x(tp, v0), tp

    delta = 1e-10
    v0 = brentq(lambda v: peak(v)[0] - (G1 + delta), 0.01, 1.0, xtol=1e-16, rtol=1e-15)
    tp = peak(v0)[1]
    t_on = brentq(lambda t: x(t, v0) - G1, 0.0, tp, xtol=1e-16, rtol=1e-15)
    drive = Drive(0.0, 1.0)  # no drive over a 1 s 'period'
    eng = simulate(model, drive, friction_preset("fixed"), periods=1, state0=[0.0, v0, 0.0, 0.0])
    ev = eng.events
    on = ev[ev["kind"] == "front_contact_on"]["time_s"].to_numpy()
    off = ev[ev["kind"] == "front_contact_off"]["time_s"].to_numpy()
    assert len(on) == 1 and len(off) == 1
    assert abs(on[0] - t_on) < 1e-9
    expected = 2 * (tp - t_on)  # contact time ~ symmetric about the peak (k_1 delta is negligible)
    assert off[0] - on[0] == pytest.approx(expected, rel=0.05)


def _v_rate_cell(c, h: float, kink: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return (g, g') on ``t`` in [0, h] for g' piecewise linear: g'(0) = c1, g'(kink h) = c2, g'(h) = c3 (a V or a
    tent), and g(0) = c0; g is the exact integral of g'."""
    tk = kink * h
    dg = np.where(t <= tk, c[1] + (c[2] - c[1]) * t / tk, c[2] + (c[3] - c[2]) * (t - tk) / (h - tk))
    g1 = c[1] * t + 0.5 * (c[2] - c[1]) * t ** 2 / tk
    gk = c[1] * tk + 0.5 * (c[2] - c[1]) * tk
    u = t - tk
    g2 = gk + c[2] * u + 0.5 * (c[3] - c[2]) * u ** 2 / (h - tk)
    return c[0] + np.where(t <= tk, g1, g2), dg


@settings(max_examples=300, deadline=None)
@given(c=st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4), h=st.floats(0.05, 2.0),
       kink=st.floats(0.02, 0.98), v_shape=st.booleans())
def test_twin_reach_bounds_the_minimum_of_a_cell_with_monotone_g2(c, h, kink, v_shape):
    """twin_reach (the scan's test for a maximum and a minimum of an event function in one cell) is a lower
    bound of g over the cell wherever g'' is monotone and g' has one sign at both ends and the other inside
    (without that, g's minimum is at an end). Cubics g = c0 + c1 t + c2 t^2 + c3 t^3 on [0, h], and the
    extreme case of the bound: g' a V (or a tent), g'_a = c1, g'(kink h) = c2, g'_b = c3, g(0) = c0."""
    t = np.linspace(0.0, h, 4001)
    if v_shape:
        g, dg = _v_rate_cell(c, h, kink, t)
    else:
        g = c[0] + c[1] * t + c[2] * t ** 2 + c[3] * t ** 3
        dg = c[1] + 2 * c[2] * t + 3 * c[3] * t ** 2
    assume(dg[0] * dg[-1] > 0.0)
    reach = E.twin_reach(g[0], g[-1], dg[0], dg[-1], h)
    # g' takes the other sign inside, by more than its rounding: g has a maximum and a minimum there. A g' that
    # only touches zero (a V whose tip is 0 evaluates to -5.6e-17 at a grid point) leaves g monotone, its minimum
    # at an end, and no interior dip to bound (hypothesis found that case: session 26; the test below)
    if np.any(dg * np.sign(dg[0]) < -1e-12 * np.abs(dg).max()):
        assert reach <= g.min() + 1e-12 * (1 + abs(g).max())


def test_twin_reach_is_silent_where_the_rate_only_touches_zero():
    """g' a V from 0.484 down to 0 at 2 % of the cell and back to 0.484 (the case hypothesis found): g rises
    monotonically from g(0) = 0, the only zero of g' is its tip, and twin_reach reports no dip (+inf); the tip
    evaluates to -5.6e-17 on a grid, a rounding the property test above must not read as a sign change."""
    h = 0.9041703694047741
    t = np.linspace(0.0, h, 4001)
    g, dg = _v_rate_cell([0.0, 0.484375, 0.0, 0.484375], h, 0.02, t)
    assert np.all(np.diff(g) >= 0.0) and g.min() == g[0] == 0.0
    assert dg.min() > -1e-15  # zero up to rounding only
    assert E.twin_reach(g[0], g[-1], dg[0], dg[-1], h) == np.inf


def test_twin_reach_is_below_the_surface_for_a_dip_and_silent_without_one():
    """g' = 1 - 1.55 sin(pi t): g = 0 at t = 0 rises, falls below zero and comes back with g' > 0 at both ends
    of [0, 1]; with g' = 1 - 0.5 sin(pi t) (g' >= 1/2: D = 1/pi, 2 D / h < min g') the bound is +inf."""
    for amp, dips in ((1.55, True), (0.5, False)):
        t = np.linspace(0.0, 1.0, 20001)
        g = t - amp * (1.0 - np.cos(np.pi * t)) / np.pi
        assert (g.min() < -1e-3) == dips
        reach = E.twin_reach(0.0, g[-1], 1.0, 1.0, 1.0)
        assert (reach < g.min() + 1e-12 if dips else math.isinf(reach)), (amp, reach, g.min())


def test_energy_balance_residual_is_tiny(one_sided, double_sided):
    model, pf = one_sided
    for fr, tol in ((friction_preset("coulomb", pf), 1e-11), (friction_preset("coulomb", 2.5), 1e-11),
                    (friction_preset("eq22"), 1e-7)):
        r = simulate(model, Drive(0.15, 30.0), fr, periods=20, transient_periods=5)
        e = r.energy
        assert e["drive_work_J"] > 0 and e["friction_J"] > 0
        assert abs(e["relative_residual"]) < tol, (fr.kind, e)
    r = simulate(double_sided, Drive(1.2, 20.0, "square", 0.35), friction_preset("coulomb", 1.5), periods=10)
    assert r.energy["contact_damping_J"] > 0
    assert abs(r.energy["relative_residual"]) < 1e-11


def test_infinite_friction_keeps_the_shell_fixed(one_sided):
    model, _ = one_sided
    r = simulate(model, Drive(0.15, 30.0), friction_preset("fixed"), periods=10, sample_rate_Hz=3000.0)
    assert (r.trajectory["capsule_mm"] == 0).all() and (r.trajectory["capsule_velocity_mm_s"] == 0).all()
    assert r.trajectory["stick"].all()
    assert r.periods["impacts"].sum() >= 5  # the magnet still hits the constraint
    assert r.periods["displacement_mm"].abs().max() == 0.0


def test_no_impact_and_symmetric_friction_give_no_drift(one_sided):
    # below the first grazing the response is symmetric: no net progression once the start-up has decayed
    model, pf = one_sided
    r = simulate(model, Drive(0.15, 15.0), friction_preset("coulomb", pf), periods=20, transient_periods=150)
    assert r.periods["impacts"].sum() == 0
    assert abs(r.average_velocity_mm_s) < 1e-6  # mm/s; the shell itself moves ~+-1 mm per period
    assert r.periods["displacement_mm"].abs().max() < 1e-6


def test_literal_eq22_stops_with_a_clear_error(one_sided):
    # static 2.5 mN < kinetic 2.518 mN at 0+: no solution can stick or slip (Zeno loop); must not hang
    model, _ = one_sided
    with pytest.raises(DynamicsError, match="ill-posed"):
        simulate(model, Drive(0.15, 30.0), friction_preset("eq22", literal=True), periods=5)


def test_regularised_eq22_behaves_like_coulomb_8p4_mN(one_sided):
    # physics.md section 3: breakaway = law held at V_min = 0.2 mm/s = 8.388 mN
    fr = friction_preset("eq22")
    pb, l0, vmin = fr.levels()
    assert pb == pytest.approx(1e-3 * (8.778 * 0.2 ** 0.25 + 2.518))
    assert pb == pytest.approx(8.388e-3, abs=1e-6) and l0 == pb and vmin == pytest.approx(2e-4)


def test_first_grazing_near_21p9_Hz(one_sided):
    """physics.md section 1 check of the Table 2 reading: P_d = 150 mN, Coulomb 7.8 mN, from rest,
    first impact near 21.9 Hz (seed 000 section 5.3). Grid 0.05 Hz; tolerance +-0.15 Hz (the paper
    quotes one decimal and its protocol/transient are not stated)."""
    model, pf = one_sided
    f = np.round(np.arange(21.0, 23.0001, 0.05), 4)
    res = run_sweep(model, Drive(0.15, 20.0), friction_preset("coulomb", pf), "f_Hz", f, "rest", 200, 20)
    pts = res.points
    first = pts[pts["impacts_per_period"] > 0]["value"].min()
    assert abs(first - 21.9) <= 0.15, first
    assert (pts[pts["value"] < first]["impacts_per_period"] == 0).all()


def test_continuation_matches_rest_where_the_response_is_unique(one_sided):
    model, pf = one_sided
    f = np.array([34.0, 35.0, 36.0])
    a = run_sweep(model, Drive(0.15, 30.0), friction_preset("coulomb", pf), "f_Hz", f, "rest", 300, 10).points
    b = run_sweep(model, Drive(0.15, 30.0), friction_preset("coulomb", pf), "f_Hz", f, "down", 300, 10).points
    np.testing.assert_allclose(a["velocity_mm_s"], b["velocity_mm_s"], rtol=1e-6)
    assert (a["period_number"] == 1).all() and (a["impacts_per_period"] == 1).all()
    assert list(b.sort_values("order")["value"]) == [36.0, 35.0, 34.0]


def test_period_number_detects_period_two():
    x = np.tile([1e-3, 2e-3], 10)
    v = np.tile([0.1, -0.1], 10)
    assert period_number(x, v) == 2
    assert period_number(np.full(10, 1e-3), np.full(10, 0.2)) == 1
    rng = np.random.default_rng(1)
    assert period_number(rng.normal(size=30) * 1e-3, rng.normal(size=30)) == 0


def test_bad_inputs_are_input_errors(one_sided):
    from capsule_cli.errors import InputError
    model, pf = one_sided
    with pytest.raises(InputError):
        simulate(model, Drive(0.15, -1.0), friction_preset("coulomb", pf))
    with pytest.raises(InputError):
        friction_preset("coulomb", 0.0)
    with pytest.raises(InputError):
        CapsuleModel.from_params({"mass_magnet_g": 1.8, "nonsense_mm": 1.0})


# ---------------------------------------------------------------------------
# the paper's landmarks (seed 000 section 5.3; physics.md section 3), found by find_landmarks


def _landmarks(model, fr, f, protocol, Pd=0.15):
    from capsule_cli.steps.dynamics import find_landmarks
    res = run_sweep(model, Drive(Pd, float(f[0])), fr, "f_Hz", f, protocol, 300, 60)
    return find_landmarks(res.points)


def test_fig17_switch_and_forward_onset(one_sided):
    """Coulomb 7.8 mN: 'one impact per period from 28.66 Hz, forward progression from 31.76 Hz'.

    The 2 -> 1 impact switch is hysteretic (coexisting responses, physics.md section 3): the
    paper's 28.66 Hz must lie between the switch found sweeping down and sweeping up (0.1 Hz grid),
    and from rest within 0.35 Hz of it. Forward progression: within 0.15 Hz (paper 2 decimals,
    grid 0.1 Hz)."""
    model, pf = one_sided
    f = np.round(np.arange(27.0, 33.0001, 0.1), 4)
    fr = friction_preset("coulomb", pf)
    rest, up, down = (_landmarks(model, fr, f, p) for p in ("rest", "up", "down"))
    key = "two impacts -> one impact per period"
    assert down[key] - 0.1 <= 28.66 <= up[key] + 0.1, (down[key], up[key])
    assert abs(rest[key] - 28.66) <= 0.35
    for lm in (rest, up, down):
        assert abs(lm["onset of forward progression"] - 31.76) <= 0.15


def test_fig18_switch_and_progression_onset(one_sided):
    """P_f = 2.5 N: 'no significant forward progression until 13.32 Hz', 'one impact per period
    from 23.4 Hz' (seed 000 section 5.3). From rest, grid 0.1 Hz, tolerance 0.15 Hz."""
    model, _ = one_sided
    f = np.round(np.arange(12.5, 24.5001, 0.1), 4)
    lm = _landmarks(model, friction_preset("coulomb", 2.5), f, "rest")
    assert abs(lm["onset of forward progression"] - 13.32) <= 0.15
    assert abs(lm["two impacts -> one impact per period"] - 23.4) <= 0.15
    assert math.isnan(lm["first grazing (impacts from here on)"])  # impacts at every f (physics.md)


def test_magnification_continuation_high_branch_fixed_shell(one_sided):
    """physics.md section 3: with the shell fixed, continuation up in f at P_d = 0.01 N follows a
    high branch to A_f ~ 276 at 40 Hz; from rest the same points stay below ~100, and every A_f is
    below the bound sqrt(k_1 M_m)/c. Tolerance 2 % on 276 (the spec quotes 3 digits, 'about')."""
    model, _ = one_sided
    f = np.arange(26.0, 40.0001, 1.0)
    up = run_sweep(model, Drive(0.01, 26.0), friction_preset("fixed"), "f_Hz", f, "up", 200, 30).points
    rest = run_sweep(model, Drive(0.01, 26.0), friction_preset("fixed"), "f_Hz", f, "rest", 200, 30).points
    assert up["Af"].iloc[-1] == pytest.approx(276.0, rel=0.02)
    assert rest["Af"].max() < 100.0
    bound = math.sqrt(model.constraint_N_m * model.mass_magnet_kg) / model.damping_Ns_m
    assert up["Af"].max() < bound


def test_law_speed_unit_sensitivity_case_evaluates_V_in_m_s():
    """--law-speed-unit m/s evaluates eq 22 as F[mN] = 8.778 V[m/s]^0.25 + 2.518 (docs/dynamics.md)."""
    si = friction_preset("eq22", speed_unit="m/s")
    mm = friction_preset("eq22")
    assert si.kinetic_N(0.1) == pytest.approx(1e-3 * (8.778 * 0.1 ** 0.25 + 2.518), rel=1e-12)
    assert mm.kinetic_N(0.1) == pytest.approx(1e-3 * (8.778 * 100.0 ** 0.25 + 2.518), rel=1e-12)
    # breakaway: the law at V_min = 0.2 mm/s = 2e-4 m/s, above the static 2.5 mN
    assert si.levels()[0] == pytest.approx(1e-3 * (8.778 * 2e-4 ** 0.25 + 2.518), rel=1e-12)
    from capsule_cli.errors import InputError
    with pytest.raises(InputError):
        friction_preset("eq22", speed_unit="km/h")


def test_random_parameter_sets_match_reference():
    """Not tuned to Table 2: 12 random one/double-sided models, harmonic and square drives, Coulomb
    or fixed shells (seeded). Same event sequence as the solve_ivp reference over 4 periods, event
    times within 1e-9 s, energy residual below 1e-9 relative."""
    rng = np.random.default_rng(20261121)
    n_events = 0
    for _ in range(12):
        ds = rng.random() < 0.4
        params = {"mass_magnet_g": rng.uniform(0.5, 5), "mass_capsule_g": rng.uniform(0.5, 5),
                  "gap_mm": rng.uniform(0.1, 3), "spring_N_m": rng.uniform(10, 200),
                  "damping_Ns_m": rng.uniform(0.0, 0.05), "constraint_N_m": 10 ** rng.uniform(3, 4.5),
                  "constraint_damping_Ns_m": rng.uniform(0, 0.3)}
        if ds:
            params.update({"gap_back_mm": rng.uniform(0.05, 2), "constraint_back_N_m": 10 ** rng.uniform(3, 4.5),
                           "constraint_back_damping_Ns_m": rng.uniform(0, 0.3)})
        model = CapsuleModel.from_params(params, double_sided=ds)
        drive = Drive(10 ** rng.uniform(-2, 0), rng.uniform(2, 50), "square" if rng.random() < 0.4 else "harmonic",
                      rng.uniform(0.1, 0.9))
        fr = friction_preset("coulomb", 10 ** rng.uniform(-3, 0.5)) if rng.random() < 0.8 else friction_preset("fixed")
        eng = simulate(model, drive, fr, periods=4)
        ref = reference_run(model, drive, fr, 4)
        ee = [(t, k) for t, k in zip(eng.events["time_s"], eng.events["kind"]) if not k.startswith("drive")]
        rr = [(t, k) for t, k in ref.events if not k.startswith("drive")]
        assert [k for _, k in ee] == [k for _, k in rr], (params, drive, fr)
        assert max([abs(a - b) for (a, _), (b, _) in zip(ee, rr)] or [0.0]) < 1e-9
        assert abs(eng.energy["relative_residual"]) < 1e-9
        n_events += len(ee)
    assert n_events > 100  # the cases exercise contacts and stick-slip, not just free flight


def test_distinct_static_and_kinetic_coulomb_levels_match_reference(one_sided):
    """Static 20 mN > kinetic 10 mN (set-valued law with two levels): same events as the reference;
    a static level below the kinetic one is held at the kinetic level (well posed) unless literal."""
    model, _ = one_sided
    fr = friction_preset("coulomb", 0.01, static_N=0.02)
    eng, ev = _compare(model, Drive(0.15, 25.0), fr, 6, 1e-9)
    assert {"stick", "slip_forward", "slip_backward"} <= {k for _, k in ev}
    assert friction_preset("coulomb", 0.01, static_N=0.005).levels()[0] == 0.01
    with pytest.raises(DynamicsError, match="ill-posed"):
        simulate(model, Drive(0.15, 25.0), friction_preset("coulomb", 0.01, static_N=0.005, literal=True), periods=5)


def test_fixed_initial_condition_of_a_sweep(one_sided):
    """A sweep from a given state: with no transient, the first Poincare point is that state."""
    model, pf = one_sided
    s0 = [1.0e-3, 0.2, -0.05]
    res = run_sweep(model, Drive(0.15, 30.0), friction_preset("coulomb", pf), "f_Hz", [30.0, 31.0], "rest", 0, 3,
                    state0=s0).poincare
    first = res[res["period"] == 0]
    np.testing.assert_allclose(first["relative_mm"], 1.0, rtol=1e-12)
    np.testing.assert_allclose(first["relative_velocity_mm_s"], 200.0, rtol=1e-12)


@pytest.mark.parametrize("Pf_N", [0.03, 0.08, 0.3])
def test_stick_slip_has_no_chattering(one_sided, Pf_N):
    """Set-valued Coulomb law (eq 21) over 50 steady periods at 10, 20 and 30 Hz: a handful of
    stick/slip switches per period (at most 12), never closer than 10 us (no chattering); the
    stick-dominated case (0.3 N, 10 Hz, ~10 switches per period) matches the reference."""
    model, _ = one_sided
    fr = friction_preset("coulomb", Pf_N)
    for f in (10.0, 20.0, 30.0):
        r = simulate(model, Drive(0.15, f), fr, periods=50, transient_periods=100)
        t = r.events[r.events["kind"].isin(["stick", "slip_forward", "slip_backward"])]["time_s"].to_numpy()
        assert 0 < len(t) <= 12 * 50
        assert np.diff(t).min() > 1e-5
    if Pf_N == 0.3:
        settled = simulate(model, Drive(0.15, 10.0), fr, periods=1, transient_periods=100).final_state
        _compare(model, Drive(0.15, 10.0), fr, 3, 1e-9, state0=[settled[0], settled[1], 0.0, settled[3]])


def test_a_run_that_fills_its_event_list_is_repeated_with_room_and_loses_nothing():
    """run_core_at with ev_cap < 0 records every event: it repeats a run that fills its list with room for
    the rate it saw (the list is not grown in place: an array rebound in the segment loop cost numba a
    reference-count pair per segment). A secondary constraint 0.52 mm behind the magnet at 10.8 Hz makes
    169 events in 4 periods; started with room for 40 (ev_cap = -40), the run fills it and is repeated: the
    events, periods and final state equal those of a run given room for all at once, and the reference's."""
    from capsule_cli.dynamics.model import EngineOptions, pack_params
    from capsule_cli.dynamics.system import build_system
    s = build_system("one_sided", {"Pf_N": 0.1463739767981198, "gap_back_mm": 0.5232165070505865},
                     ["secondary_constraint"])
    d, fr = Drive(0.37138317016706685, 10.797632034027917), s.friction()
    p, opts = pack_params(s.model, d, fr), EngineOptions().pack()
    grown = E.run_core(p, opts, np.zeros(4), 0, 4, 1.0, 0, -40)
    default = E.run_core(p, opts, np.zeros(4), 0, 4, 1.0, 0, -1)
    roomy = E.run_core(p, opts, np.zeros(4), 0, 4, 1.0, 0, 1000)
    assert grown[0] == roomy[0] == E.STATUS_OK
    n = int(grown[5])
    assert n == int(roomy[5]) == int(default[5]) and n > 40
    np.testing.assert_array_equal(grown[4][:n], roomy[4][:n])
    np.testing.assert_array_equal(default[4][:n], roomy[4][:n])
    np.testing.assert_array_equal(grown[6], roomy[6])
    np.testing.assert_array_equal(grown[8], roomy[8])
    capped = E.run_core(p, opts, np.zeros(4), 0, 4, 1.0, 0, 100)
    assert capped[0] == E.STATUS_EVCAP and int(capped[5]) == 100
    ref = reference_run(s.model, d, fr, 4)
    kinds = [k for k in simulate(s.model, d, fr, periods=4).events["kind"] if not k.startswith("drive")]
    assert kinds == [k for _, k in ref.events if not k.startswith("drive")]
