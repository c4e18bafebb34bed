"""Starting-state spread of progression conditions (issue 12 item 3: "where the response is irregular
(chaotic or multistable), its spread over windows and starting states is estimated and enters the error model").

The case: the one-sided base with a secondary constraint at G_2 = 0.3 mm (P_f = 0.02 N, k_b and c_b at seed 002
Table 2's values), the 40-condition design of the benchmark (configs/designs/progression_grid.csv: 10 frequencies
15-42 Hz x P_d 0.10-0.25 N), 60 + 24 periods from rest. Many of its conditions are irregular, and some of them
settle on a different attractor when the magnet starts 1 um away from rest, although the four windows of one run
agree (window SD 0): the window term alone would call those conditions exact.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from capsule_cli.dynamics import system as dsys
from capsule_cli.steps import dynamics_loop as DL
from capsule_cli.steps.synth import read_design

ROOT = Path(__file__).resolve().parents[1]
PROTO = dsys.Protocol("rest", 60, 24)
PARAMS = {"Pf_N": 0.02, "gap_back_mm": 0.3}


@pytest.fixture(scope="module")
def case():
    import yaml

    from capsule_cli.effects.model import build_model

    design = read_design(ROOT / "configs/designs/progression_grid.csv", "progression")
    path = Path(__file__).parent / "_starts_truth.yaml"
    doc = {"kind": "progression", "base": "one_sided", "effects": ["secondary_constraint"], "params": PARAMS,
           "protocol": {"start": "rest", "transient_periods": PROTO.transient_periods,
                        "recorded_periods": PROTO.recorded_periods}}
    path.write_text(yaml.safe_dump(doc))
    try:
        model = build_model(path)
    finally:
        path.unlink()
    bound = DL.DynBound(model, design.assign(velocity_mm_s=0.0), where="design")
    return bound, bound.simulate(None), bound.simulate(None, starts=True)


def test_zero_offset_is_exact_rest_and_a_continuation_offset_moves_each_condition_start():
    """rest: offset 0 is exact rest. up: the offset is added to the state each condition of the sweep starts
    from, so an offset at the second frequency only leaves the first condition bit for bit as it was."""
    sysm = dsys.build_system("one_sided", PARAMS, ["secondary_constraint"])
    f, pdn = np.array([27.0, 36.0]), np.array([0.2, 0.2])
    rest = dsys.progression(sysm, f, pdn, protocol=PROTO)
    zero = dsys.progression(sysm, f, pdn, protocol=PROTO, start_offset_m=0.0)
    assert np.array_equal(rest["velocity_mm_s"].to_numpy(), zero["velocity_mm_s"].to_numpy())
    up = dsys.Protocol("up", 20, 8)
    plain = dsys.progression(sysm, f, pdn, protocol=up)["velocity_mm_s"].to_numpy()
    assert np.array_equal(plain, dsys.progression(sysm, f, pdn, protocol=up, start_offset_m=0.0)
                          ["velocity_mm_s"].to_numpy())
    second = dsys.progression(sysm, f, pdn, protocol=up, start_offset_m=[0.0, 1e-4])["velocity_mm_s"].to_numpy()
    first = dsys.progression(sysm, f, pdn, protocol=up, start_offset_m=[1e-4, 0.0])["velocity_mm_s"].to_numpy()
    assert second[0] == plain[0] and second[1] != plain[1]
    assert first[0] != plain[0]


def test_start_spread_on_every_condition_and_never_below_the_window_term(case):
    """Every condition is rerun from the starting states (a periodic response can coexist with another
    attractor); where the starts settle on one periodic orbit they agree far below any noise (measured here:
    20 conditions within 1.6e-5 mm/s). One condition sits on the edge: rounding-level changes of the engine
    (session 12's root refinement) flip its rest run between irregular and a periodic class, and its starts
    spread over 17 mm/s; wherever the rest run looks periodic but the starts land elsewhere, the spread
    must cover the difference."""
    _, plain, starts = case
    irregular = plain["cls"].astype(str) == "irregular"
    assert 8 <= irregular.sum() < 40  # the case has both kinds
    one_orbit = ~irregular & (starts["spread"] < 1e-4)
    assert one_orbit.sum() >= 18
    assert np.all(np.abs(plain["pred"][one_orbit] - starts["pred"][one_orbit]) < 1e-4)
    other = ~irregular & ~one_orbit
    assert np.all(np.abs(plain["pred"][other] - starts["pred"][other]) <= 10 * starts["spread"][other] + 1e-9)
    # the starting-state term only adds to the window term
    assert np.all(starts["spread"] >= plain["spread"] - 1e-12)


def test_start_spread_finds_coexisting_attractors_the_window_sd_misses(case):
    _, plain, starts = case
    irregular = plain["cls"].astype(str) == "irregular"
    # conditions where other starts land far from what the window term allows: a start spread over 10 mm/s and
    # ten times the window spread. Which conditions of this chaotic case qualify moves with rounding-level
    # changes of the engine (its chaotic runs diverge from there): measured 0.21 -> 79.8 mm/s on session 12's
    # engine, 1.69 -> 78.1 on session 13's (basis advanced cell to cell), where fixed thresholds (window under
    # 1 mm/s, starts over 3) had found 2 conditions and then none
    hidden = irregular & (starts["spread"] > 10.0) & (starts["spread"] > 10.0 * plain["spread"])
    assert hidden.sum() >= 1, np.c_[plain["spread"], starts["spread"]][irregular]
    # the prediction there is the mean over the starts (rest included): it moved off the rest run
    assert np.all(starts["pred"][hidden] != plain["pred"][hidden])
    # and the spread is about the SD of a new run's average: one start cannot be 10 spreads from the mean
    assert np.all(np.abs(plain["pred"][irregular] - starts["pred"][irregular])
                  <= 10 * starts["spread"][irregular] + 1e-9)


def test_box_edges_count_a_zero_floor_within_rounding_as_zero(monkeypatch):
    """A coefficient whose box starts at 0 and that the fit left within the at-bound tolerance of it (a
    substrate damping of 1e-5 N s/m in [0, 10], found on data with a hidden compliance of 1 mm/N, which
    otherwise ranked the right candidate last) is a zero term, not a box edge; the other edges still are."""
    table = {
        "substrate_damping_Ns_m": {"owner": "substrate_compliance", "at_bound": True, "bounds": [0.0, 10.0],
                                   "value": 9.9e-6},
        "compliance_mm_N": {"owner": "substrate_compliance", "at_bound": True, "bounds": [1e-3, 100.0],
                            "value": 1e-3},
        "drag_Ns_m": {"owner": "viscous_drag", "at_bound": True, "bounds": [0.0, 1.0], "value": 1.0},
        "kappa": {"owner": "tilt_friction", "at_bound": False, "bounds": [-2.0, 2.0], "value": 0.1},
    }
    monkeypatch.setattr(DL.report, "param_table", lambda ev: table)
    assert DL.box_edges(None, "substrate_compliance") == ["compliance_mm_N"]
    table["compliance_mm_N"]["at_bound"] = False
    assert DL.box_edges(None, "substrate_compliance") == []
    assert DL.box_edges(None, "viscous_drag") == ["drag_Ns_m"]
    assert DL.box_edges(None, "tilt_friction") == []
