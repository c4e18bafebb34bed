"""Many near-grazing orbits: the engine finds every contact that reaches past the gap, at its analytic time,
and invents none (issue 13 item 3: event brackets without dense sampling, no grazing contact missed).

With the shell held (friction preset "fixed"), the magnet of seed 000's one-sided model (eq 19 without the
shell's equation) started on its steady forced orbit under F = P_d cos(2 pi f t) moves as
x_r(t) = X cos(Omega t - phi) until it first reaches the gap G_1: X = P_d |H|, phi = arg H with
H = 1 / (k - M Omega^2 + i c Omega). Choosing P_d so that X = G_1 + delta puts the orbit's peak delta past
the gap (delta > 0, a contact of depth delta) or short of it (delta < 0, none). The peaks fall at every
position within the engine's scan cells (1/8 of the fastest modal period) as f and delta vary.
"""
import cmath
import math

import numpy as np
import pytest

from capsule_cli.dynamics import Drive, friction_preset, load_model, simulate


# drive frequencies from just below the magnet's resonance (29.5 Hz) up, irregularly spaced against the cell grid:
# the orbit's peak then falls at |arg H| / Omega, from 0.9 ms to half a period after the start (below 25 Hz it
# falls within 0.2 ms of it, where a deep orbit would start in contact)
FREQS_HZ = np.linspace(25.3, 44.9, 14)
DEPTHS_M = [1e-12, 1e-11, 1e-10, 1e-9, 1e-8, 1e-7, 1e-6]  # how far the peak reaches past (or short of) G_1


@pytest.fixture(scope="module")
def model():
    return load_model("prototype_one_sided")[0]


def _orbit(model, f_Hz, delta_m):
    """P_d [N], the state at t = 0 on the steady orbit, and the first time [s] x_r reaches G_1 (or None)."""
    M, k, c, G1 = model.mass_magnet_kg, model.spring_N_m, model.damping_Ns_m, model.gap_m
    Om = 2 * math.pi * f_Hz
    H = 1.0 / complex(k - M * Om ** 2, c * Om)
    X = G1 + delta_m
    Pd = X / abs(H)
    phi = cmath.phase(H)
    x0, v0 = X * math.cos(phi), -X * Om * math.sin(phi)  # x = X cos(Om t + phi)
    assert x0 < G1 - 1e-6, "the orbit must start out of contact"
    if delta_m <= 0:
        return Pd, [x0, v0, 0.0, 0.0], None
    # x = X cos(Om t + phi): the first t >= 0 with Om t + phi = -acos(G1 / X) (mod 2 pi), on the rising side
    half = math.acos(G1 / X)  # half the angular width of the contact arc
    th = (-half - phi) % (2 * math.pi)
    return Pd, [x0, v0, 0.0, 0.0], th / Om


@pytest.mark.parametrize("f_Hz", FREQS_HZ)
def test_each_near_grazing_contact_is_found_at_its_time_and_no_miss_makes_one(model, f_Hz):
    fixed = friction_preset("fixed")
    for delta in DEPTHS_M:
        Pd, s0, t_on = _orbit(model, f_Hz, delta)
        ev = simulate(model, Drive(Pd, f_Hz), fixed, periods=1, state0=s0).events
        on = ev[ev["kind"] == "front_contact_on"]["time_s"].to_numpy()
        assert len(on) >= 1, f"f = {f_Hz:.3f} Hz: a contact {delta:.0e} m deep was missed"
        assert abs(on[0] - t_on) < 1e-9, f"f = {f_Hz:.3f} Hz, depth {delta:.0e} m: on at {on[0]!r}, not {t_on!r}"
        # the miss by as much: no contact in the period
        Pd, s0, _ = _orbit(model, f_Hz, -delta)
        ev = simulate(model, Drive(Pd, f_Hz), fixed, periods=1, state0=s0).events
        assert not (ev["kind"] == "front_contact_on").any(), \
            f"f = {f_Hz:.3f} Hz: an orbit {delta:.0e} m short of the gap made a contact"
