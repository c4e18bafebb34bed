"""Event-driven, closed-form engine of the vibro-impact capsule (numba-compiled).

Model (seed 000 eqs 19-21; seed 001 Appendix A; physics.md section 3), forward +x,
``x_r = X_m - X_c``::

    M_m X_m'' = F_e - F_i,   M_c X_c'' = F_f + F_i,
    F_i = K x_r + C v_r + F_0      (K, C, F_0 depend on the contact state)

with no contact ``K = k, C = c, F_0 = 0``; front contact (x_r >= G_1)
``K = k + k_1, C = c + c_1, F_0 = -k_1 G_1``; back contact (x_r <= -G_2)
``K = k + k_b, C = c + c_b, F_0 = k_b G_2``.

Why every mode is closed form
-----------------------------
* shell stuck (V_c = 0): ``M_m x_r'' = F_e - F_i`` -- a damped linear oscillator;
* shell slipping with a constant friction level L (Coulomb, or a speed law held
  constant below V_min): the relative motion is the oscillator of the reduced
  mass ``mu = M_m M_c / (M_m + M_c)``,
  ``x_r'' = F_e/M_m - F_i/mu + s L / M_c`` (s = slip direction),
  and the centre of mass obeys ``(M_m + M_c) X_cm'' = F_e - s L`` (an explicit
  quadrature); ``X_c = X_cm - M_m/(M_m+M_c) x_r``.

So in every linear mode each state component and every event function is a
linear combination of the seven basis functions of the segment time tau::

    B = [e^{sig tau} C(tau), e^{sig tau} S(tau), cos(Om s), sin(Om s), 1, tau, tau^2]

(``s = s0 + tau`` is the time since the period's start; C, S are cos/sin,
cosh/sinh or 1/tau by the sign of the discriminant). Derivatives are the same
basis with a linear map of the coefficients, so events, their extrema (grazing)
and extrema of F_i are located by bracketing on a grid of 1/NPER of the fastest
modal period plus Newton-bisection to ~1e-16 s on the exact expressions.

Where the time goes, and what keeps it small (the bench's runs: about 4 segments, 36 scan cells and
7 root searches per excitation period):
* the scan moves from cell to cell by the exact 2 x 2 maps of each modal pair and of the drive's
  cos, sin over one cell (:func:`basis_factors`, :func:`basis_advance`: e^{lambda h} products, no
  transcendental function), evaluating the basis afresh every SCAN_ANCHOR cells and at a segment's
  end; at a segment's start only the drive's phase needs cos, sin (:func:`basis_start`);
* a root search starts from the cubic Hermite interpolant of g, g' at the cell's ends, which the
  scan has (:func:`hermite_guess`): one fresh basis evaluation, then Newton iterates 1e-5 to 1e-12
  of a cell apart, each advanced from the last by short Taylor series (:func:`basis_step`); the
  basis at the root is handed back for the segment's end state (:func:`mode_state`);
* libm's sincos and exp were 45 % of the engine's time before this (session 13): 90 basis
  evaluations per period, now about 17.

Dynamics effects that keep the modes linear (viscous drag c_v V_c, the tilt level
L0 (1 + kappa x_r / G_1), substrate compliance: a presliding spring k_s and damper c_s
to a massless contact patch) make *general linear modes*: ``u' = A u + b0 + bc cos(Om s)``
with u = [x_r, v_r, X_c, V_c, d]. Each is split into a nonsingular core, solved exactly
from the eigen-decomposition of its matrix (computed once per mode per run) plus the
particular solutions of the constant and harmonic forcing, and quadratures (X_c; V_c
without drag; a constant d) integrated exactly. They are written on a nine-function
basis (a second modal slot, which may also hold real exponentials); their events
(slip end, patch breakaway and stop, the tilt level's zero) are root-found the same way,
on cells that grow from a fast real mode's time scale to the oscillatory one's.

Slip with a speed-dependent law above V_min (eqs 22-23) is the only nonlinear
mode: a compiled Dormand-Prince 8(5,3) (DOP853) with dense output integrates that segment
alone, with the same events (and a general mode whose eigenvectors are nearly
defective, as a fallback).

Time is kept as (period index, time within the period) so that the phase of the
drive and the Poincare section at phase 0 are exact for any run length.

Kernels (each compiled, one job)
--------------------------------
* :func:`run_core_at` / :func:`run_segments`: the driver. Per segment it picks the mode (contact x
  shell state x effects), runs it to its first event or the segment's end, applies the transition
  and keeps the period's bookkeeping. The event list is never grown in place (an array variable
  rebound inside the loop cost an atomic reference-count pair per segment, 8 % of the bench): a run
  that fills it is repeated with room for the rate it saw.
* exact segments, one kernel per job: :func:`mode_path` (which path a shell state takes: base
  closed form, general linear mode, or adaptive), :func:`setup_linear` / :func:`setup_general`
  (the closed forms), :func:`mode_events` (the mode's event functions on its basis) and
  :func:`event_derivatives` (their time derivatives), the event scan :func:`locate_event` with
  :func:`mode_root_ends` / :func:`refine_from` (on the seven-function basis for a base mode),
  :func:`mode_state` (the end state), :func:`mode_samples` (trajectory samples) and :func:`gl_energy` /
  :func:`gl_friction` (the energy balance). Kernels are compiled without reference counting (``kernel``), so a call
  costs little: split this way the bench's period took 1-4 % longer (6.11-6.34 against 6.30-6.46
  us, alternated; session 10), where one kernel taking some 45 arrays had cost 8.3-8.7 against 5.9
  (session 9) and numba's IR-level inlining (``inline='always'``) 7.2-7.8.
* :func:`adaptive_segment`: the nonlinear mode (DOP853 :func:`dop853_step`,
  :func:`dop853_error`, dense output :func:`dop853_dense`; events on the dense output).
* :func:`shell_transition`: the set-valued friction law at an event (stick or slip from the
  net force, :func:`decide_shell` / :func:`decide_patch`) and the jumps it implies.
* :func:`open_period` / :func:`close_period`: the rows of the period table; :func:`settled_orbit`
  and :func:`fill_orbit`: the settled transient and the recorded periods filled from its orbit.

Status codes returned by :func:`run_core`: see ``STATUS_*``.
"""
from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, objmode, prange, types
from numba.extending import intrinsic

# Compiled kernels that allocate nothing are built without numba's reference counting (NRT).
# With it, every call of a kernel that takes an array (the parameter row, the state, the work
# arrays) does an atomic increment and decrement of that array's reference count through two
# external calls, which LLVM cannot remove even where it inlines the kernel: about 15 ns per
# call, 80 % of the right-hand side of the adaptive segment (measured: contact_terms in a loop,
# 16.3 ns with NRT, 0.6 ns without; the eq 22 map point 287 -> 139 us per period, outputs
# bit-identical on 35 runs). The arrays such a kernel receives are owned by its caller
# (run_core_at, which keeps NRT because it allocates), so nothing is freed under it.
# ``_nrt`` is numba's own flag for this (numba.core.options, pinned numba 0.68.1); a kernel
# built with it that tried to allocate would fail to compile, not misbehave.
kernel = njit(cache=True, _nrt=False)

# ---------------------------------------------------------------------------
# parameter vector (SI), built by capsule_cli.dynamics.model.pack_params
I_MM, I_MC, I_K, I_C, I_G1, I_K1, I_C1, I_G2, I_KB, I_CB, I_BACK = range(11)
I_PD, I_F, I_WAVE, I_DUTY = 11, 12, 13, 14
I_PB, I_L0, I_VMIN, I_LA, I_LN, I_LB, I_LAW = 15, 16, 17, 18, 19, 20, 21
I_XS, I_VS, I_FS = 22, 23, 24
# dynamics effects (physics.md section 3, "Dynamics effects"); 0 = off
I_CV, I_KAP, I_VFAST = 25, 26, 27
# substrate compliance: k_s = 1/compliance (0: rigid wall, off), c_s
I_KS, I_CS = 28, 29
# user plugin forces (capsule_cli.dynamics.plugin_force, issue 9 item 4): I_PLUG 1 = active (every mode then
# goes through the adaptive segment); I_PLUG_FN the address of the compiled force (a C function pointer,
# exact in a float64: addresses are below 2**53); I_PLUG_NP its number of parameters, stored from I_PLUG_P0
I_PLUG, I_PLUG_FN, I_PLUG_NP, I_PLUG_P0 = 30, 31, 32, 33
MAX_PLUG_PARAMS = 16
N_PARAMS = I_PLUG_P0 + MAX_PLUG_PARAMS

# options vector
O_NPER, O_ENERGY, O_RTOL, O_ZENO, O_MAXSTEPS, O_EXACT, O_SETTLE = 0, 1, 2, 3, 4, 5, 6
N_OPTS = 7
N_FINAL = 7  # final-state record: x_r, v_r, X_c, V_c, contact, shell, periods integrated
SETTLE_ORBIT_MAX = 8  # longest periodic orbit [excitation periods] the settled-transient test recognises
# a run with a speed law integrates its slips on the adaptive path, whose error per period is about rk_rtol:
# its phase-0 state cannot repeat more closely than that, so its settled-transient test uses at least this
# fraction of rk_rtol (measured on a 20 x 20 subset of the eq 22 Fig 19 grid at rk_rtol 1e-9: 76 % of the
# points settle at 1e-12, 88 % at 1e-10; at 1e-10 one point still converging in alternation was taken for
# a period-2 orbit, its displacement 13 times less accurate than the full run's; at 1e-11 the cut runs
# are as accurate as the full ones, docs/dynamics.md)
SETTLE_RTOL_FRACTION = 0.01

# shell states
STICK, SLIP_POS, SLIP_NEG, FAST_POS, FAST_NEG = 0, 1, 2, 3, 4
# substrate compliance: contact patch stuck (the shell moves on the presliding spring k_s, c_s);
# patch sliding uses FAST_POS / FAST_NEG
PATCH_STICK = 5

# event codes (root events inside a mode)
EV_NONE = -1
EV_FRONT_ON, EV_BACK_ON, EV_FRONT_OFF, EV_BACK_OFF = 1, 2, 3, 4
EV_BREAK_POS, EV_BREAK_NEG, EV_SLIP_END, EV_FAST_ON, EV_FAST_OFF = 5, 6, 7, 8, 9
EV_TILT = 10  # the tilt factor of the friction level crosses zero (a general linear mode ends)
TOL_V_REL = 1e-13  # velocity root tolerance and zero test, relative to the velocity scale p[I_VS]
# recorded kinds (the event list)
K_FRONT_ON, K_FRONT_OFF, K_BACK_ON, K_BACK_OFF = 1, 2, 3, 4
K_STICK, K_SLIP_FWD, K_SLIP_BWD, K_DRIVE_ON, K_DRIVE_OFF = 5, 6, 7, 8, 9
EVENT_KIND_NAMES = {1: "front_contact_on", 2: "front_contact_off", 3: "back_contact_on",
                    4: "back_contact_off", 5: "stick", 6: "slip_forward", 7: "slip_backward",
                    8: "drive_on", 9: "drive_off"}

STATUS_OK, STATUS_ZENO, STATUS_ILLPOSED, STATUS_RKFAIL, STATUS_EVCAP = 0, 1, 2, 3, 4
STATUS_PLUGIN = 5  # a user plugin force raised or returned a non-finite value
STATUS_EVGROW = 6  # internal (run_segments): the event list is full; run_core_at repeats the run with more room
# the event list of a run that records all its events (run_core_at, ev_cap < 0): its first capacity
EV_CAP_START, EV_CAP_PER_PERIOD, EV_CAP_FIRST_MAX = 64, 64, 1 << 18

# sample columns
S_T, S_XM, S_XC, S_VM, S_VC, S_XR, S_CONTACT, S_STICK, S_FI = range(9)
N_SAMPLE_COLS = 9
# period columns
P_DISP, P_NFRONT, P_NBACK, P_MAXF, P_XR0, P_VR0, P_STICK, P_XC0, P_TMAXF, P_NSTICK, P_VM0, P_VC0 = range(12)
N_PERIOD_COLS = 12
# energy entries
E_DRIVE, E_DAMP, E_CONTACT, E_FRIC, E_START, E_END = range(6)
E_PLUGIN = 6  # work done by the user plugin forces [J]
N_ENERGY = 7

# basis of a linear mode (:func:`basis`): modal slot 1, drive cos/sin, 1, tau, tau^2, modal slot 2
NB = 9
B_M1, B_COS, B_SIN, B_ONE, B_T, B_T2, B_M2 = 0, 2, 3, 4, 5, 6, 7
MODE_OSC, MODE_REAL, MODE_NONE = 0, 1, 2
# the scan advances the basis cell to cell by exact maps (basis_advance) and evaluates it afresh every
# SCAN_ANCHOR cells, so that rounding (about an ulp per step) stays within a few ulp
SCAN_ANCHOR = 16
# |argument| [rad] up to which a Newton step's exp, sin and cos are taken from short Taylor series
# (tiny_pair: truncation below 1e-19 there)
TINY_ARG = 2e-3
# locate_event's work space: maps and keys (24), root searches (3 NB), six bases, g and g' per event (12)
LOCATE_WORK = 24 + 9 * NB + 12
# coefficient rows of a linear mode's state
R_XR, R_VR, R_XC, R_VC, R_D = 0, 1, 2, 3, 4
N_ROWS = 5
TWO_PI = 2.0 * math.pi
EPS = 2.220446049250313e-16

# Gauss-Legendre 5 points on [-1, 1]
GL_X = np.array([-0.9061798459386640, -0.5384693101056831, 0.0, 0.5384693101056831, 0.9061798459386640])
GL_W = np.array([0.2369268850561891, 0.4786286704993665, 0.5688888888888889, 0.4786286704993665,
                 0.2369268850561891])


# ---------------------------------------------------------------------------
# small helpers


@kernel
def contact_terms(p, contact):
    """Return (K, C, F0) of F_i = K x_r + C v_r + F0 in a contact state (eq 20; seed 001 App. A)."""
    K = p[I_K]
    C = p[I_C]
    F0 = 0.0
    if contact == 1:
        K += p[I_K1]
        C += p[I_C1]
        F0 = -p[I_K1] * p[I_G1]
    elif contact == 2:
        K += p[I_KB]
        C += p[I_CB]
        F0 = p[I_KB] * p[I_G2]
    return K, C, F0


@kernel
def contact_of(p, xr):
    """Return the contact state of a relative displacement (0 none, 1 front, 2 back)."""
    if xr >= p[I_G1]:
        return 1
    if p[I_BACK] > 0.5 and xr <= -p[I_G2]:
        return 2
    return 0


@kernel
def tilt_factor(p, xr):
    """Return the tilt scaling max(0, 1 + kappa x_r / G_1) of the friction levels (effect
    ``tilt_friction``, physics.md section 3; seed 002 Fig 5); exactly 1 when kappa = 0."""
    if p[I_KAP] == 0.0:
        return 1.0
    fac = 1.0 + p[I_KAP] * xr / p[I_G1]
    return fac if fac > 0.0 else 0.0


@kernel
def friction_level(p, V, xr):
    """Return the friction level [N] at slip speed V >= 0 [m/s] and relative displacement x_r [m]:
    Coulomb, or the speed law of eqs 22-23 held below V_min, scaled by the tilt factor."""
    if p[I_LAW] < 0.5 or V < p[I_VMIN]:
        L = p[I_L0]
    else:
        L = speed_law(p, V)
    if p[I_KAP] != 0.0:
        L *= tilt_factor(p, xr)
    return L


@kernel
def speed_law(p, V):
    """The kinetic law a V^n + b [N] of eqs 22-23 at slip speed V > 0 [m/s] (p in SI: a [N (s/m)^n])."""
    if p[I_LN] == 0.25:
        # the exponent of eqs 22 and 23: two square roots cost 4 ns against 14 ns for the general
        # power (the right-hand side of a speed-law slip, 13 times per DOP853 step, issue 13)
        return p[I_LA] * math.sqrt(math.sqrt(V)) + p[I_LB]
    return p[I_LA] * V ** p[I_LN] + p[I_LB]


@kernel
def slip_level(p, V, xr, cont):
    """The friction level [N] in the right-hand side of an adaptive slip at speed V >= 0 [m/s]:
    :func:`friction_level`, or with ``cont`` (a slip above V_min, which ends at its V_min event) the
    speed law continued below V_min. The step that carries the slip across V_min then sees a smooth
    right-hand side, not the held level's kink, which its error estimate rejected step after step;
    the event is located on the dense output and nothing past it is kept, so the slip itself is
    unchanged (issue 13)."""
    if cont and V > 0.0:
        L = speed_law(p, V)
        if p[I_KAP] != 0.0:
            L *= tilt_factor(p, xr)
        return L
    return friction_level(p, V, xr)


@kernel
def kinetic_level(p, V, xr):
    """Return the resisting force [N] on a shell slipping at speed |V| [m/s] with relative
    displacement x_r [m]: :func:`friction_level` plus viscous drag c_v |V| (``viscous_drag``)."""
    return friction_level(p, V, xr) + p[I_CV] * V


@kernel
def drive_force(p, s, fe_level):
    """Return F_e at time s within the period (harmonic) or the square-wave level."""
    if p[I_WAVE] < 0.5:
        return p[I_PD] * math.cos(TWO_PI * p[I_F] * s)
    return fe_level


@kernel
def stored_energy(p, xr, vr, Vc):
    """Return kinetic + spring + contact-spring energy [J]."""
    Vm = Vc + vr
    E = 0.5 * p[I_MM] * Vm * Vm + 0.5 * p[I_MC] * Vc * Vc + 0.5 * p[I_K] * xr * xr
    if xr > p[I_G1]:
        d = xr - p[I_G1]
        E += 0.5 * p[I_K1] * d * d
    if p[I_BACK] > 0.5 and xr < -p[I_G2]:
        d = xr + p[I_G2]
        E += 0.5 * p[I_KB] * d * d
    return E


@kernel
def decide_shell(p, contact, xr, vr, fe, Fm, Fc, dFc):
    """Return the shell state at V_c = 0 by the set-valued law (eqs 21-23).

    Sticks while |F_i + F_c| < P_break; slips in the direction of F_i + F_c when it is above;
    at the threshold, sticks when that force is moving back inside. F_m, F_c [N] are the user
    plugin forces on the magnet and the shell at this instant and dFc [N/s] the rate of F_c along
    the stuck motion (all 0 without a plugin: :func:`plugin_stick_terms`). Returns -1 when the
    shell cannot stick and cannot slip either (breakaway below the kinetic level at
    0+: the literal eq 22, a Zeno stick-slip loop).
    """
    Pb = p[I_PB]
    if Pb == np.inf:
        return STICK
    tilt = p[I_KAP] != 0.0
    if tilt:
        Pb *= tilt_factor(p, xr)
    K, C, F0 = contact_terms(p, contact)
    Fi = K * xr + C * vr + F0
    F = Fi + Fc
    tol = 1e-12 * p[I_FS]
    aF = abs(F)
    if aF < Pb - tol:
        return STICK
    sgn = 1.0 if F > 0.0 else -1.0
    if aF <= Pb + tol:
        ar = (fe - Fi + Fm) / p[I_MM]
        Fdot = K * vr + C * ar + dFc
        if tilt:
            # the threshold moves with x_r: stick when |F_i| - P_b(x_r) is not increasing
            dPb = p[I_PB] * p[I_KAP] / p[I_G1] * vr if Pb > 0.0 else 0.0
            if sgn * Fdot - dPb <= 0.0:
                return STICK
        elif F * Fdot <= 0.0:
            return STICK
    L0 = kinetic_level(p, 0.0, xr)  # level at 0+ (held value, or the literal law's b)
    if aF - L0 < -tol:
        return -1
    fast = p[I_VFAST] <= 0.0
    if sgn > 0:
        return FAST_POS if fast else SLIP_POS
    return FAST_NEG if fast else SLIP_NEG


# ---------------------------------------------------------------------------
# closed-form segments


@kernel
def basis(tau, s0, md, Om, B):
    """Fill B with the NB basis functions of a linear mode at segment time tau.

    Layout: [slot 1 (2), cos(Om s), sin(Om s), 1, tau, tau^2, slot 2 (2)] with s = s0 + tau; the
    slots are described by md = [kind1, a1, b1, c1, kind2, a2, b2, c2]: kind MODE_OSC
    ``e^{a tau} C(tau), e^{a tau} S(tau)`` with a = sigma, b = discriminant, c = sqrt|b| (C, S =
    cos, sin/c; cosh, sinh/c; 1, tau by the sign of b); MODE_REAL ``e^{a tau}, e^{b tau}`` (two real
    eigenvalues); MODE_NONE zeros. A leaf function (no calls with array arguments, which cost
    reference counting) so that it inlines into the scan: the hot path.
    """
    k = md[0]
    if k == MODE_OSC:
        e = math.exp(md[1] * tau)
        disc = md[2]
        w = md[3]
        if disc < 0.0:
            B[0] = e * math.cos(w * tau)
            B[1] = e * math.sin(w * tau) / w
        elif disc > 0.0:
            B[0] = e * math.cosh(w * tau)
            B[1] = e * math.sinh(w * tau) / w
        else:
            B[0] = e
            B[1] = e * tau
    elif k == MODE_REAL:
        B[0] = math.exp(md[1] * tau)
        B[1] = math.exp(md[2] * tau)
    else:
        B[0] = 0.0
        B[1] = 0.0
    ph = Om * (s0 + tau)
    B[2] = math.cos(ph)
    B[3] = math.sin(ph)
    B[4] = 1.0
    B[5] = tau
    B[6] = tau * tau
    k = md[4]
    if k == MODE_OSC:
        e = math.exp(md[5] * tau)
        disc = md[6]
        w = md[7]
        if disc < 0.0:
            B[7] = e * math.cos(w * tau)
            B[8] = e * math.sin(w * tau) / w
        elif disc > 0.0:
            B[7] = e * math.cosh(w * tau)
            B[8] = e * math.sinh(w * tau) / w
        else:
            B[7] = e
            B[8] = e * tau
    elif k == MODE_REAL:
        B[7] = math.exp(md[5] * tau)
        B[8] = math.exp(md[6] * tau)
    else:
        B[7] = 0.0
        B[8] = 0.0


@kernel
def basis_start(base, s0, md, Om, B):
    """:func:`basis` (or :func:`basis_base`) at tau = 0, where only the drive's phase needs cos and sin: the
    same values, without exp and the mode's cos, sin."""
    for i in range(2):
        k = 4 * i
        j = 0 if i == 0 else 7
        if i == 1 and base:
            break
        kind = md[k]
        B[j] = 0.0 if kind == MODE_NONE else 1.0
        B[j + 1] = 1.0 if kind == MODE_REAL else 0.0
    ph = Om * s0
    B[2] = math.cos(ph)
    B[3] = math.sin(ph)
    B[4] = 1.0
    B[5] = 0.0
    B[6] = 0.0


@kernel
def copy_basis(src, dst):
    """dst[:NB] = src[:NB] (a kernel cannot assign slices: that needs numba's reference counting)."""
    for j in range(NB):
        dst[j] = src[j]


@kernel
def dot9(c, B):
    """Value of the basis combination with coefficients c (all NB functions)."""
    return (c[0] * B[0] + c[1] * B[1] + c[2] * B[2] + c[3] * B[3] + c[4] * B[4] + c[5] * B[5] + c[6] * B[6]
            + c[7] * B[7] + c[8] * B[8])


@kernel
def basis_base(tau, s0, md, Om, B):
    """:func:`basis` for a base mode (one oscillator slot, slot 2 unused: B[7], B[8] stay 0)."""
    e = math.exp(md[1] * tau)
    disc = md[2]
    w = md[3]
    if disc < 0.0:
        C = math.cos(w * tau)
        S = math.sin(w * tau) / w
    elif disc > 0.0:
        C = math.cosh(w * tau)
        S = math.sinh(w * tau) / w
    else:
        C = 1.0
        S = tau
    B[0] = e * C
    B[1] = e * S
    ph = Om * (s0 + tau)
    B[2] = math.cos(ph)
    B[3] = math.sin(ph)
    B[4] = 1.0
    B[5] = tau
    B[6] = tau * tau


@kernel
def dot_base(c, B):
    """:func:`dot9` over the first seven functions (a base mode)."""
    return c[0] * B[0] + c[1] * B[1] + c[2] * B[2] + c[3] * B[3] + c[4] * B[4] + c[5] * B[5] + c[6] * B[6]


@kernel
def mode_absdot(base, c, B):
    """sum |c_j B_j| over the mode's basis functions: the scale of g = c.B's rounding."""
    n = 7 if base else NB
    t = 0.0
    for j in range(n):
        t += abs(c[j] * B[j])
    return t


@kernel
def mode_basis(base, tau, s0, md, Om, B):
    """:func:`basis_base` (a base mode: seven functions) or :func:`basis` (a general mode)."""
    if base:
        basis_base(tau, s0, md, Om, B)
    else:
        basis(tau, s0, md, Om, B)


@kernel
def mode_dot(base, c, B):
    """:func:`dot_base` (a base mode) or :func:`dot9` (a general mode)."""
    if base:
        return dot_base(c, B)
    return dot9(c, B)


@kernel
def deriv_base(c, md, Om, out):
    """:func:`deriv_coefs` for a base mode (one oscillator slot)."""
    out[0] = md[1] * c[0] + c[1]
    out[1] = md[2] * c[0] + md[1] * c[1]
    out[2] = Om * c[3]
    out[3] = -Om * c[2]
    out[4] = c[5]
    out[5] = 2.0 * c[6]
    out[6] = 0.0


@kernel
def deriv_coefs(c, md, Om, out):
    """Coefficients of d/dtau of a basis combination (a leaf function: slots written out)."""
    k = md[0]
    if k == MODE_OSC:
        out[0] = md[1] * c[0] + c[1]
        out[1] = md[2] * c[0] + md[1] * c[1]
    elif k == MODE_REAL:
        out[0] = md[1] * c[0]
        out[1] = md[2] * c[1]
    else:
        out[0] = 0.0
        out[1] = 0.0
    out[B_COS] = Om * c[B_SIN]
    out[B_SIN] = -Om * c[B_COS]
    out[B_ONE] = c[B_T]
    out[B_T] = 2.0 * c[B_T2]
    out[B_T2] = 0.0
    k = md[4]
    if k == MODE_OSC:
        out[7] = md[5] * c[7] + c[8]
        out[8] = md[6] * c[7] + md[5] * c[8]
    elif k == MODE_REAL:
        out[7] = md[5] * c[7]
        out[8] = md[6] * c[8]
    else:
        out[7] = 0.0
        out[8] = 0.0


@kernel
def _slot_antideriv(kind, a, b, c, out, i):
    if kind == MODE_OSC:
        det = a * a - b  # = omega_0^2 > 0 for a nonsingular mode
        d0 = (a * c[i] - c[i + 1]) / det
        out[i] = d0
        out[i + 1] = c[i] - a * d0
    elif kind == MODE_REAL:
        out[i] = c[i] / a
        out[i + 1] = c[i + 1] / b if c[i + 1] != 0.0 else 0.0
    else:
        out[i] = 0.0
        out[i + 1] = 0.0


@kernel
def antideriv_coefs(c, md, Om, s0, value0, out):
    """Coefficients of the antiderivative of a basis combination c that equals value0 at tau = 0.

    c must have no tau^2 term (the quadratures of a linear mode never do); the modal slots are
    nonsingular (no zero eigenvalue), and a drive term needs Om > 0.
    """
    _slot_antideriv(md[0], md[1], md[2], c, out, B_M1)
    _slot_antideriv(md[4], md[5], md[6], c, out, B_M2)
    if Om > 0.0:
        out[B_COS] = -c[B_SIN] / Om
        out[B_SIN] = c[B_COS] / Om
    else:
        out[B_COS] = 0.0
        out[B_SIN] = 0.0
    out[B_T2] = 0.5 * c[B_T]
    out[B_T] = c[B_ONE]
    out[B_ONE] = 0.0
    # value at tau = 0 of everything but the constant
    v = out[B_COS] * math.cos(Om * s0) + out[B_SIN] * math.sin(Om * s0)
    if md[0] != MODE_NONE:
        v += out[B_M1]
        if md[0] == MODE_REAL:
            v += out[B_M1 + 1]
    if md[4] != MODE_NONE:
        v += out[B_M2]
        if md[4] == MODE_REAL:
            v += out[B_M2 + 1]
    out[B_ONE] = value0 - v


@kernel
def setup_linear(p, contact, shell, s0, xr0, vr0, Xc0, Vc0, fe_level, coef, md):
    """Fill coef rows (x_r, v_r, X_c, V_c) and the mode descriptor md of a base linear mode (one
    modal slot, closed form); return (wmax, Om).

    ``shell`` is STICK, SLIP_POS or SLIP_NEG (constant friction level p[I_L0]).
    """
    Mm = p[I_MM]
    Mc = p[I_MC]
    Mt = Mm + Mc
    mu = Mm * Mc / Mt
    K, C, F0 = contact_terms(p, contact)
    harmonic = p[I_WAVE] < 0.5
    Om = TWO_PI * p[I_F] if harmonic else 0.0
    sgn = 0.0
    if shell == STICK:
        me = Mm
        q0 = -F0 / Mm
    else:
        sgn = 1.0 if shell == SLIP_POS else -1.0
        me = mu
        q0 = -F0 / mu + sgn * p[I_L0] / Mc
    w02 = K / me
    gam = C / me
    sig = -0.5 * gam
    disc = sig * sig - w02
    w = math.sqrt(abs(disc))
    if harmonic:
        dr = w02 - Om * Om
        di = Om * gam
        den = dr * dr + di * di
        amp = p[I_PD] / Mm
        Zr = amp * dr / den
        Zi = -amp * di / den
        xc = q0 / w02
        c2 = math.cos(Om * s0)
        s2 = math.sin(Om * s0)
    else:
        Zr = 0.0
        Zi = 0.0
        xc = (q0 + fe_level / Mm) / w02
        c2 = 1.0
        s2 = 0.0
    xp0 = Zr * c2 - Zi * s2 + xc
    vp0 = -Om * Zr * s2 - Om * Zi * c2
    d0 = xr0 - xp0
    d1 = vr0 - vp0
    for i in range(N_ROWS):
        for j in range(NB):
            coef[i, j] = 0.0
    md[0] = MODE_OSC
    md[1] = sig
    md[2] = disc
    md[3] = w
    md[4] = MODE_NONE
    coef[0, 0] = d0
    coef[0, 1] = d1 - sig * d0
    coef[0, 2] = Zr
    coef[0, 3] = -Zi
    coef[0, 4] = xc
    coef[1, 0] = d1
    coef[1, 1] = -w02 * d0 + sig * d1
    coef[1, 2] = -Om * Zi
    coef[1, 3] = -Om * Zr
    if shell == STICK:
        coef[2, 4] = Xc0
    else:
        Ff = -sgn * p[I_L0]
        r = Mm / Mt
        Vcm0 = Vc0 + r * vr0
        Xcm0 = Xc0 + r * xr0
        if harmonic:
            a = p[I_PD] / (Mt * Om)
            # V_cm
            coef[3, 3] = a
            coef[3, 4] = Vcm0 - a * s2
            coef[3, 5] = Ff / Mt
            # X_cm
            coef[2, 2] = -a / Om
            coef[2, 4] = Xcm0 + a * c2 / Om
            coef[2, 5] = Vcm0 - a * s2
            coef[2, 6] = 0.5 * Ff / Mt
        else:
            acc = (Ff + fe_level) / Mt
            coef[3, 4] = Vcm0
            coef[3, 5] = acc
            coef[2, 4] = Xcm0
            coef[2, 5] = Vcm0
            coef[2, 6] = 0.5 * acc
        for j in range(NB):
            coef[2, j] -= r * coef[0, j]
            coef[3, j] -= r * coef[1, j]
    wmax = math.sqrt(w02)
    if disc > 0.0:
        wmax = max(wmax, abs(sig) + w)
    wmax = max(wmax, Om)
    return wmax, Om


# ---------------------------------------------------------------------------
# general linear modes (dynamics effects): exact solution from the eigen-decomposition

# kinds of general linear mode
GM_SLIP, GM_PSTICK, GM_PSLIDE = 0, 1, 2
N_GM_KEYS = 30  # 3 contacts x 5 (slip +/-, patch stick, patch slide +/-) x 2 (tilt level on / held at 0)
EIG_COND_MAX = 1e8  # eigenvector condition above which a mode is integrated on the adaptive path
#: a core eigenvalue below EIG_SLOW_REL x the oscillatory scale (the largest |eigenvalue| of a complex pair) sends
#: the mode to the adaptive path. The exact solution adds the particular solution of the constant forcing,
#: ~ b0 / lambda in V_c and ~ b0 / lambda^2 in X_c, to a homogeneous part that cancels it; near lambda = 0 the
#: rounding of that cancellation is the error. A
#: vanishing viscous drag makes such a mode (lambda = -c_v / M_c): at c_v = 1e-9-3e-6 N s/m the shell position
#: was off the solve_ivp reference by 2e-6 to 3e-2 m after 12-20 periods, slip ends by up to 4e-5 s, and some runs
#: stopped as Zeno (c_v = 3e-8 N s/m at 24 Hz); on the adaptive path 1e-12 m (measured, session 19). At the
#: threshold (lambda ~ 0.3 1/s against the free oscillator's 267 rad/s) the cancellation costs ~ eps 1e6.
EIG_SLOW_REL = 1e-3


@kernel
def friction_row(p, tilt_on):
    """Return (L0, L1) of the constant-level friction force L0 + L1 x_r [N] of a slip (Coulomb, or a
    speed law held below V_min), with the tilt factor 1 + kappa x_r / G_1 (``tilt_friction``) active
    (tilt_on) or held at zero."""
    if p[I_KAP] == 0.0:
        return p[I_L0], 0.0
    if tilt_on:
        return p[I_L0], p[I_L0] * p[I_KAP] / p[I_G1]
    return 0.0, 0.0


@kernel
def mode_system(p, contact, gm, sg, tilt_on, fe_level, A, b0, bc):
    """Fill the linear system u' = A u + b0 + bc cos(Om s) of a general linear mode.

    u = [x_r, v_r, X_c, V_c, d] (rows R_*; d = presliding spring extension of substrate_compliance).
    Magnet ``M_m X_m'' = F_e - F_i``; shell ``M_c X_c'' = F_i - F_s - c_v V_c`` with F_s the
    substrate force: slip (gm GM_SLIP) or patch slide (GM_PSLIDE) ``sg (L0 + L1 x_r)``; patch stuck
    (GM_PSTICK) ``k_s d + c_s V_c`` (physics.md section 3, dynamics effects; seed 000 eqs 19-21).
    """
    for i in range(N_ROWS):
        b0[i] = 0.0
        bc[i] = 0.0
        for j in range(N_ROWS):
            A[i, j] = 0.0
    K, C, F0 = contact_terms(p, contact)
    Mm = p[I_MM]
    Mc = p[I_MC]
    L0, L1 = friction_row(p, tilt_on)
    # shell acceleration a_c
    A[R_VC, R_XR] = K / Mc
    A[R_VC, R_VR] = C / Mc
    A[R_VC, R_VC] = -p[I_CV] / Mc
    b0[R_VC] = F0 / Mc
    if gm == GM_PSTICK:
        A[R_VC, R_D] = -p[I_KS] / Mc
        A[R_VC, R_VC] -= p[I_CS] / Mc
        A[R_D, R_VC] = 1.0
    else:
        A[R_VC, R_XR] -= sg * L1 / Mc
        b0[R_VC] -= sg * L0 / Mc
        if gm == GM_PSLIDE and p[I_CS] > 0.0:
            A[R_D, R_XR] = sg * L1 / p[I_CS]
            A[R_D, R_D] = -p[I_KS] / p[I_CS]
            b0[R_D] = sg * L0 / p[I_CS]
        elif gm == GM_PSLIDE:
            # c_s = 0: the massless patch's balance k_s d = sg (L0 + L1 x_r) holds throughout
            A[R_D, R_VR] = sg * L1 / p[I_KS]
    # relative acceleration (F_e - F_i) / M_m - a_c
    A[R_XR, R_VR] = 1.0
    A[R_VR, R_XR] = -K / Mm - A[R_VC, R_XR]
    A[R_VR, R_VR] = -C / Mm - A[R_VC, R_VR]
    A[R_VR, R_VC] = -A[R_VC, R_VC]
    A[R_VR, R_D] = -A[R_VC, R_D]
    b0[R_VR] = -F0 / Mm - b0[R_VC]
    if p[I_WAVE] < 0.5:
        bc[R_VR] = p[I_PD] / Mm
    else:
        b0[R_VR] += fe_level / Mm
    A[R_XC, R_VC] = 1.0


@njit(cache=True)
def mode_decompose(A, core, quad, lam, V, Vi, mdt, fn_eig):
    """Split a general linear mode into its core (a nonsingular block) and quadratures, and
    eigen-decompose the core; return (n_core, n_quad, ok, wmax_modal).

    A variable is a quadrature when no variable outside the quadratures found so far depends on it
    (X_c always; V_c without drag or patch; d when constant). quad lists them in the order they
    must be integrated. mdt: the modal slots of :func:`basis`; fn_eig[i]: the eigenvalue of slot
    function i (-1 unused). ok is False for a singular or nearly defective core (eigenvector
    condition above EIG_COND_MAX, or an eigenvalue below EIG_SLOW_REL of the oscillatory scale): the mode
    then goes to the adaptive path. wmax_modal is the
    largest |eigenvalue|; a fifth value, the slow scale, ignores the faster real eigenvalues.
    """
    n = A.shape[0]
    inq = np.zeros(n, dtype=np.bool_)
    nq = 0
    order = np.zeros(n, dtype=np.int64)
    changed = True
    while changed:
        changed = False
        for j in range(n):
            if inq[j]:
                continue
            dep = False
            for i in range(n):
                if not inq[i] and A[i, j] != 0.0:
                    dep = True
                    break
            if not dep:
                inq[j] = True
                order[nq] = j
                nq += 1
                changed = True
    for k in range(nq):  # integrate in reverse order of discovery
        quad[k] = order[nq - 1 - k]
    nc = 0
    for j in range(n):
        if not inq[j]:
            core[nc] = j
            nc += 1
    for i in range(8):
        mdt[i] = 0.0
    mdt[0] = MODE_NONE
    mdt[4] = MODE_NONE
    for i in range(4):
        fn_eig[i] = -1
    if nc == 0 or nc > 4:
        return nc, nq, False, 0.0, 0.0
    Ac = np.zeros((nc, nc))
    for a in range(nc):
        for b in range(nc):
            Ac[a, b] = A[core[a], core[b]]
    # LAPACK through numpy in object mode: np.linalg in nopython mode would keep the engine from
    # being cached (its LAPACK pointers are dynamic globals); once per mode per run
    with objmode(w='complex128[:]', vec='complex128[:,:]', vinv='complex128[:,:]'):
        w, vec = np.linalg.eig(Ac)
        vinv = np.linalg.inv(vec)
        w = np.ascontiguousarray(w, dtype=np.complex128)
        vec = np.ascontiguousarray(vec, dtype=np.complex128)
        vinv = np.ascontiguousarray(vinv, dtype=np.complex128)
    scale = 0.0
    for k in range(nc):
        scale = max(scale, abs(w[k]))
    ok = scale > 0.0
    # the oscillatory scale (the largest |eigenvalue| of a complex pair; the largest of all if none): a slow
    # real eigenvalue is judged against it, not against a fast real one (a stiff patch damper's)
    osc = 0.0
    for k in range(nc):
        if abs(w[k].imag) > 1e-12 * scale:
            osc = max(osc, abs(w[k]))
    if osc == 0.0:
        osc = scale
    for k in range(nc):
        if abs(w[k]) <= 1e-9 * scale or abs(w[k]) <= EIG_SLOW_REL * osc:
            ok = False
        c1 = 0.0
        c2 = 0.0
        for a in range(nc):
            c1 += abs(vec[a, k]) ** 2
            c2 += abs(vinv[k, a]) ** 2
        if math.sqrt(c1 * c2) > EIG_COND_MAX:
            ok = False
    for a in range(4):
        lam[a] = 0.0
        for b in range(4):
            V[a, b] = 0.0
            Vi[a, b] = 0.0
    for a in range(nc):
        lam[a] = w[a]
        for b in range(nc):
            V[a, b] = vec[a, b]
            Vi[a, b] = vinv[a, b]
    # slots: a complex pair (Im > 0 taken) fills an oscillator slot; real eigenvalues pair up
    slot = 0
    reals = np.zeros(4, dtype=np.int64)
    nr = 0
    for k in range(nc):
        im = w[k].imag
        if abs(im) > 1e-12 * scale:
            if im > 0.0:
                if slot > 1:
                    return nc, nq, False, scale, scale
                o = 4 * slot
                mdt[o] = MODE_OSC
                mdt[o + 1] = w[k].real
                mdt[o + 2] = -im * im
                mdt[o + 3] = im
                fn_eig[2 * slot] = k
                fn_eig[2 * slot + 1] = k
                slot += 1
        else:
            reals[nr] = k
            nr += 1
    r = 0
    while r < nr:
        if slot > 1:
            return nc, nq, False, scale, scale
        o = 4 * slot
        mdt[o] = MODE_REAL
        mdt[o + 1] = w[reals[r]].real
        fn_eig[2 * slot] = reals[r]
        if r + 1 < nr:
            mdt[o + 2] = w[reals[r + 1]].real
            fn_eig[2 * slot + 1] = reals[r + 1]
        else:
            mdt[o + 2] = mdt[o + 1]
        slot += 1
        r += 2
    # the slow scale: the fastest oscillatory mode (or the slowest real one if none oscillates); a
    # faster real mode only shapes the start of a segment: the scan's cells grow from the fast
    # scale to the slow one
    slow = 0.0
    rmin = np.inf
    for k in range(nc):
        if abs(w[k].imag) > 1e-12 * scale:
            slow = max(slow, abs(w[k]))
        else:
            rmin = min(rmin, abs(w[k]))
    if slow == 0.0:
        slow = rmin
    return nc, nq, ok, scale, slow


@kernel
def _add_modal(coef, core, nc, V, alpha, lam, mdt, fn_eig):
    """Add the modal part ``V diag(e^{lambda tau}) alpha`` to the core rows of coef, written on the
    real slot functions (a complex pair: 2 Re and -2 Im omega on e^{sigma tau} cos, sin/omega)."""
    for f in range(4):
        k = fn_eig[f]
        if k < 0:
            continue
        col = B_M1 + f if f < 2 else B_M2 + f - 2
        osc = mdt[0] == MODE_OSC if f < 2 else mdt[4] == MODE_OSC
        for a in range(nc):
            beta = V[a, k] * alpha[k]
            if osc:
                if f % 2 == 0:
                    coef[core[a], col] += 2.0 * beta.real
                else:
                    coef[core[a], col] += -2.0 * beta.imag * lam[k].imag
            else:
                coef[core[a], col] += beta.real


@njit(cache=True)
def setup_general(A, b0, bc, Om, s0, u0, core, nc, quad, nq, lam, V, Vi, mdt, fn_eig, coef, md, work):
    """Fill coef (rows R_*) and md of a general linear mode from its decomposition
    (:func:`mode_decompose`) and the start state u0 = [x_r, v_r, X_c, V_c, d] at time s0 in the
    period: the core is the particular solution of the constant and harmonic forcing plus
    ``V e^{Lambda tau} V^-1 delta_0``; each quadrature is the exact antiderivative of its row."""
    for i in range(8):
        md[i] = mdt[i]
    for i in range(N_ROWS):
        for j in range(NB):
            coef[i, j] = 0.0
    # particular solution on the core: P0 = -A^-1 b0, Z = (i Om - A)^-1 bc  (z_p = P0 + Re(Z e^{i Om s}))
    cb0 = np.zeros(4, dtype=np.complex128)
    cbc = np.zeros(4, dtype=np.complex128)
    for k in range(nc):
        t0 = 0.0 + 0.0j
        t1 = 0.0 + 0.0j
        for a in range(nc):
            t0 += Vi[k, a] * b0[core[a]]
            t1 += Vi[k, a] * bc[core[a]]
        cb0[k] = -t0 / lam[k]
        cb1 = t1 / (1j * Om - lam[k]) if t1 != 0.0 else 0.0j
        cbc[k] = cb1
    ph = Om * s0
    e0 = math.cos(ph) + 1j * math.sin(ph)
    delta = np.zeros(4, dtype=np.complex128)
    for a in range(nc):
        P0 = 0.0
        Z = 0.0j
        for k in range(nc):
            P0 += (V[a, k] * cb0[k]).real
            Z += V[a, k] * cbc[k]
        i = core[a]
        coef[i, B_ONE] = P0
        coef[i, B_COS] = Z.real
        coef[i, B_SIN] = -Z.imag
        delta[a] = u0[i] - (P0 + (Z * e0).real)
    alpha = np.zeros(4, dtype=np.complex128)
    for it in range(2):
        # second pass: one step of iterative refinement on the start values, so that the rows start
        # at u0 to rounding (an event surface the mode starts on is then seen as such)
        for k in range(nc):
            t = 0.0j
            for a in range(nc):
                t += Vi[k, a] * delta[a]
            alpha[k] = t
        _add_modal(coef, core, nc, V, alpha, lam, mdt, fn_eig)
        for a in range(nc):
            i = core[a]
            v0 = coef[i, B_ONE] + coef[i, B_COS] * e0.real + coef[i, B_SIN] * e0.imag + coef[i, B_M1]
            if mdt[0] == MODE_REAL:
                v0 += coef[i, B_M1 + 1]
            if mdt[4] != MODE_NONE:
                v0 += coef[i, B_M2]
                if mdt[4] == MODE_REAL:
                    v0 += coef[i, B_M2 + 1]
            delta[a] = u0[i] - v0
    # quadratures
    for q in range(nq):
        i = quad[q]
        for j in range(NB):
            work[j] = 0.0
        for jv in range(N_ROWS):
            a = A[i, jv]
            if a != 0.0:
                for j in range(NB):
                    work[j] += a * coef[jv, j]
        work[B_ONE] += b0[i]
        work[B_COS] += bc[i]
        antideriv_coefs(work, md, Om, s0, u0[i], coef[i])


@kernel
def general_events(p, gm, sg, tilt_on, coef, md, Om, evc, evcode, evtol, ne, tol_v, tol_F, work):
    """Append the shell/patch event functions of a general linear mode to evc (inside-positive,
    exact basis combinations); return the new count.

    Slip: its end ``sg V_c = 0`` and, with a held speed law, ``|V_c| = V_min``. Stuck patch: the
    breakaway ``|k_s d + c_s V_c| = P_b (1 + kappa x_r / G_1)``. Sliding patch: its stop, patch speed
    ``V_p = V_c - d' = 0``. With tilt, the level's factor crossing zero (EV_TILT: the level is held
    at zero beyond it, physics.md section 3)."""
    G1 = p[I_G1]
    if gm == GM_PSTICK:
        if p[I_PB] < np.inf:
            kq = p[I_PB] * p[I_KAP] / G1
            for j in range(NB):
                F = p[I_KS] * coef[R_D, j] + p[I_CS] * coef[R_VC, j]
                evc[ne, j] = -F + kq * coef[R_XR, j]
                evc[ne + 1, j] = F + kq * coef[R_XR, j]
            evc[ne, B_ONE] += p[I_PB]
            evc[ne + 1, B_ONE] += p[I_PB]
            evcode[ne] = EV_BREAK_POS
            evcode[ne + 1] = EV_BREAK_NEG
            evtol[ne] = tol_F
            evtol[ne + 1] = tol_F
            ne += 2
        return ne
    if gm == GM_PSLIDE and (p[I_CS] > 0.0 or p[I_KAP] != 0.0):
        deriv_coefs(coef[R_D], md, Om, work)
        for j in range(NB):
            evc[ne, j] = sg * (coef[R_VC, j] - work[j])
    else:
        for j in range(NB):
            evc[ne, j] = sg * coef[R_VC, j]
    evcode[ne] = EV_SLIP_END
    evtol[ne] = tol_v
    ne += 1
    if gm == GM_SLIP and p[I_VFAST] < np.inf:
        for j in range(NB):
            evc[ne, j] = -sg * coef[R_VC, j]
        evc[ne, B_ONE] += p[I_VFAST]
        evcode[ne] = EV_FAST_ON
        evtol[ne] = tol_v
        ne += 1
    if p[I_KAP] != 0.0:
        side = 1.0 if tilt_on else -1.0
        for j in range(NB):
            evc[ne, j] = side * p[I_KAP] / G1 * coef[R_XR, j]
        evc[ne, B_ONE] += side
        evcode[ne] = EV_TILT
        evtol[ne] = 1e-13
        ne += 1
    return ne


@kernel
def gl_graded_count(tau1, h, h_slow):
    """Number of quadrature pieces over [0, tau1] starting at h and doubling up to h_slow."""
    n = 0
    a = 0.0
    dt = h
    while a < tau1:
        a += dt
        dt = min(2.0 * dt, h_slow)
        n += 1
    return max(n, 1)


@kernel
def gl_friction(p, coef, md, Om, s0, tau1, h, h_slow, gm, sg, tilt_on, dd, B, acc):
    """Add the substrate's dissipation over [0, tau1] of a general linear mode (Gauss-Legendre):
    friction ``(L0 + L1 x_r) |V_p|``, drag ``c_v V_c^2`` and the patch damper ``c_s (V_c - V_p)^2``
    (V_p = V_c on a rigid wall; 0 for a stuck patch)."""
    if tau1 <= 0.0:
        return
    L0, L1 = friction_row(p, tilt_on)
    cv = p[I_CV]
    cs = p[I_CS]
    slide_damped = gm == GM_PSLIDE and (cs > 0.0 or p[I_KAP] != 0.0)
    if slide_damped:
        deriv_coefs(coef[R_D], md, Om, dd)
    # pieces of h, or growing from h to h_slow (a fast real mode)
    graded = h_slow > h
    npieces = int(math.ceil(tau1 / h))
    if npieces < 1:
        npieces = 1
    dt = tau1 / npieces
    if graded:
        npieces = gl_graded_count(tau1, h, h_slow)
        dt = h
    a = 0.0
    for k in range(npieces):
        if graded:
            if k > 0:
                a += dt
                dt = min(2.0 * dt, h_slow)
            if k == npieces - 1:
                dt = tau1 - a
        else:
            a = k * dt
        for q in range(5):
            t = a + 0.5 * dt * (GL_X[q] + 1.0)
            basis(t, s0, md, Om, B)
            Vc = dot9(coef[R_VC], B)
            x = dot9(coef[R_XR], B)
            wq = 0.5 * dt * GL_W[q]
            if gm == GM_PSTICK:
                dis = (cs + cv) * Vc * Vc
            else:
                Vp = Vc
                if slide_damped:
                    Vp = Vc - dot9(dd, B)
                dis = (L0 + L1 * x) * sg * Vp + cv * Vc * Vc + cs * (Vc - Vp) * (Vc - Vp)
            acc[E_FRIC] += wq * dis


@kernel
def tiny_pair(a, w, d, b0, b1):
    """A modal pair (e^{a t} cos w t, e^{a t} sin(w t) / w) at t + d [s] from its values b0, b1 at t, for a
    tiny step (|a d|, |w d| <= TINY_ARG): exp, sin and cos from short Taylor series (truncation below 1e-19)."""
    ad = a * d
    e = 1.0 + ad * (1.0 + ad * (0.5 + ad * (1.0 / 6.0 + ad * (1.0 / 24.0 + ad * (1.0 / 120.0)))))
    z = (w * d) * (w * d)
    Sw = d * (1.0 - z * (1.0 / 6.0 - z * (1.0 / 120.0)))  # sin(w d) / w
    C = 1.0 - z * (0.5 - z * (1.0 / 24.0 - z * (1.0 / 720.0)))
    return e * (C * b0 - Sw * w * w * b1), e * (Sw * b0 + C * b1)


@kernel
def tiny_ok(kind, a, disc, w, d):
    """True if a modal slot (md's kind, a, disc, w) can take the step d [s] by :func:`tiny_pair`."""
    return kind == MODE_OSC and disc < 0.0 and abs(a * d) <= TINY_ARG and abs(w * d) <= TINY_ARG


@kernel
def basis_step(base, x, xb, Bx, s0, md, Om, B):
    """B = the basis at x [s], given Bx, the basis at xb: advanced from Bx over the tiny step d = x - xb
    (a Newton step near a root moves by 1e-5 to 1e-12 of the scan cell) if every argument is at
    most TINY_ARG: short Taylor series of exp, sin and cos instead of libm's exp and two sincos, which were
    45 % of the engine's time; each step adds an ulp or two of rounding. Else evaluated afresh. B must
    not be Bx."""
    d = x - xb
    if abs(Om * d) <= TINY_ARG and tiny_ok(md[0], md[1], md[2], md[3], d) and (
            base or md[4] == MODE_NONE or tiny_ok(md[4], md[5], md[6], md[7], d)):
        B[0], B[1] = tiny_pair(md[1], md[3], d, Bx[0], Bx[1])
        B[2], B[3] = tiny_pair(0.0, 1.0, Om * d, Bx[2], Bx[3])
        B[4] = 1.0
        B[5] = x
        B[6] = x * x
        if not base:
            if md[4] == MODE_NONE:
                B[7] = 0.0
                B[8] = 0.0
            else:
                B[7], B[8] = tiny_pair(md[5], md[7], d, Bx[7], Bx[8])
    else:
        mode_basis(base, x, s0, md, Om, B)


@kernel
def bracket_across(base, c, x, g, tolx, a, b, s0, md, Om, Bx, B):
    """Close a Newton bracket [a, b] of g = c.B at its iterate x (g = g(x), the next step below tolx [s]) from
    the side Newton converged on: test a point 2 tolx across the root. Return (a, b, closed). (Closed from
    inside only, a call converging from outside, g < 0, shrank its bracket by bisection alone: 20-50 basis
    evaluations instead of 6-8 in one call of seven.) Bx: the basis at x; B: work space (:func:`basis_step`)."""
    if g >= 0.0:
        xo = x + 2.0 * tolx
        if xo < b:
            basis_step(base, xo, x, Bx, s0, md, Om, B)
            if mode_dot(base, c, B) < 0.0:
                return a, xo, True
    else:
        xo = x - 2.0 * tolx
        if xo > a:
            basis_step(base, xo, x, Bx, s0, md, Om, B)
            if mode_dot(base, c, B) >= 0.0:
                return xo, b, True
    return a, b, False


@kernel
def hermite_guess(a, b, ga, gb, dga, dgb):
    """First guess [s] of a root of g in (a, b), given g(a) >= 0 > g(b) and g' at both ends. Where g is
    monotone on the cell (g' < 0 at both ends) the inverse cubic Hermite interpolant x(g) at g = 0 (error
    O(h^4) against the secant's O(h^2)); else the secant point. Arithmetic only: no basis evaluation."""
    x = a + (b - a) * ga / (ga - gb)
    if dga < 0.0 and dgb < 0.0:
        # x(g) on [gb, ga]: x(ga) = a, x(gb) = b, x'(g) = 1 / g'
        dg = ga - gb
        u = ga / dg  # the fraction of the way from g = ga to g = 0
        m0 = -dg / dga
        m1 = -dg / dgb
        h10 = u * (1.0 - u) * (1.0 - u)
        h01 = u * u * (3.0 - 2.0 * u)
        h11 = u * u * (u - 1.0)
        x = a + h10 * m0 + h01 * (b - a) + h11 * m1
    if not (a < x < b):
        x = 0.5 * (a + b)
    return x


@kernel
def refine_from(base, c, dc, a, b, x, s0, md, Om, W):
    """Return the first tau in (a, b] just past the root of g = c.B, given g(a) >= 0 > g(b), from the
    first iterate x in (a, b).

    Safeguarded Newton-bisection on the closed form; the returned point lies on the 'outside' (g < 0)
    side within a few ulp of the root. base: the seven-function basis of a base mode, else all nine.
    The basis at the first iterate is evaluated afresh, at each next one advanced from the
    previous one (:func:`basis_step`). W: work space (3 NB): two bases and the basis at b, kept for the
    caller (W[2 NB:]: on entry the basis at the given b).
    """
    Bx = W[0:NB]
    B = W[NB:2 * NB]
    Bend = W[2 * NB:3 * NB]
    mode_basis(base, x, s0, md, Om, Bx)
    xb = x
    for _ in range(100):
        tolx = 4.0 * EPS * (abs(s0) + abs(b)) + 1e-300
        if b - a <= tolx:
            break
        if x != xb:
            basis_step(base, x, xb, Bx, s0, md, Om, B)
            Bx, B = B, Bx
            xb = x
        g = mode_dot(base, c, Bx)
        dg = mode_dot(base, dc, Bx)
        if g >= 0.0:
            a = x
        else:
            b = x
            copy_basis(Bx, Bend)
        if dg != 0.0:
            xn = x - g / dg
            step = abs(xn - x)
            # g is known to its rounding, about EPS sum |c_j B_j|: a shallow crossing (small g') can be
            # located no closer than that over |g'|, and Newton's steps then creep (found when the basis
            # was first chained: g stayed at one rounding level for 100 steps of 2e-15 s). So once the step
            # is within that, the bracket is closed at 2 tolx as before, else at 4, 16, ... times that, up
            # to the rounding's reach
            tol_g = max(tolx, 4.0 * EPS * mode_absdot(base, c, Bx) / abs(dg))
            if step < tol_g:
                b0 = b
                t_close = tolx
                while True:
                    a, b, closed = bracket_across(base, c, x, g, t_close, a, b, s0, md, Om, Bx, B)
                    if closed or t_close >= tol_g:
                        break
                    t_close *= 4.0
                if b != b0:
                    copy_basis(B, Bend)
                if closed:
                    break
            if not (a < xn < b):
                xn = 0.5 * (a + b)
        else:
            xn = 0.5 * (a + b)
        x = xn
    return b


@kernel
def mode_root_ends(base, c, dc, a, b, Ba, Bb, s0, md, Om, W):
    """:func:`mode_root` on a cell whose basis values at both ends are known (Ba at a, Bb at b, as the
    scan has them): g and g' at the ends are dot products, the first iterate is the root of their
    cubic Hermite interpolant (:func:`hermite_guess`), and the iterates after the first advance the basis
    by their tiny steps (:func:`refine_from`). W: work space (3 NB; not Ba or Bb); W[2 NB:] holds
    the basis at the returned point."""
    ga = mode_dot(base, c, Ba)
    if ga < 0.0:
        copy_basis(Ba, W[2 * NB:3 * NB])
        return a
    copy_basis(Bb, W[2 * NB:3 * NB])
    gb = mode_dot(base, c, Bb)
    dga = mode_dot(base, dc, Ba)
    dgb = mode_dot(base, dc, Bb)
    return refine_from(base, c, dc, a, b, hermite_guess(a, b, ga, gb, dga, dgb), s0, md, Om, W)


@kernel
def mode_root(base, c, dc, a, b, s0, md, Om, W):
    """Return the first tau in (a, b] just past the root of g = c.B, given g(a) >= 0 > g(b) (a if
    g(a) < 0): the basis at both ends, then :func:`refine_from` from the Hermite guess. base: a base mode
    on the seven-function basis (:func:`basis_base`, the hot path), else a general mode. W: work space
    (3 NB); W[2 NB:] holds the basis at the returned point."""
    B = W[2 * NB:3 * NB]
    mode_basis(base, a, s0, md, Om, B)
    ga = mode_dot(base, c, B)
    if ga < 0.0:
        return a
    dga = mode_dot(base, dc, B)
    mode_basis(base, b, s0, md, Om, B)
    gb = mode_dot(base, c, B)
    dgb = mode_dot(base, dc, B)
    if not (gb < 0.0):
        x = 0.5 * (a + b)
    else:
        x = hermite_guess(a, b, ga, gb, dga, dgb)
    return refine_from(base, c, dc, a, b, x, s0, md, Om, W)


@kernel
def gl_energy(p, coef, contact, shell, s0, tau1, h, h_slow, md, Om, fe_level, B, acc):
    """Add drive work and viscous dissipation over [0, tau1] of a linear segment (Gauss-Legendre)."""
    if tau1 <= 0.0:
        return
    K, C, F0 = contact_terms(p, contact)
    cs = p[I_C]
    cc = C - cs
    # pieces of h, or growing from h to h_slow (a fast real mode)
    graded = h_slow > h
    npieces = int(math.ceil(tau1 / h))
    if npieces < 1:
        npieces = 1
    dt = tau1 / npieces
    if graded:
        npieces = gl_graded_count(tau1, h, h_slow)
        dt = h
    a = 0.0
    for k in range(npieces):
        if graded:
            if k > 0:
                a += dt
                dt = min(2.0 * dt, h_slow)
            if k == npieces - 1:
                dt = tau1 - a
        else:
            a = k * dt
        for q in range(5):
            t = a + 0.5 * dt * (GL_X[q] + 1.0)
            basis(t, s0, md, Om, B)
            vr = dot9(coef[1], B)
            Vc = dot9(coef[3], B)
            fe = drive_force(p, s0 + t, fe_level)
            wq = 0.5 * dt * GL_W[q]
            acc[E_DRIVE] += wq * fe * (Vc + vr)
            acc[E_DAMP] += wq * cs * vr * vr
            acc[E_CONTACT] += wq * cc * vr * vr


# ---------------------------------------------------------------------------
# the adaptive segment: slip with a speed-dependent law (eqs 22-23 above V_min), integrated by
# DOP853 (below); its right-hand side and event functions

NY = 10  # x_r, v_r, V_c, X_c, W_drive, D_damp, D_contact, D_friction, d, W_plugin


@kernel
def rk_rhs(p, contact, sgn, s, fe_level, y, dy, cont):
    """Right-hand side in (x_r, v_r, V_c, X_c, W_drive, D_damp, D_contact, D_friction, d).

    d = X_c - X_p is the extension of the substrate's presliding spring (substrate_compliance);
    sgn = 0: contact patch stuck (compliance only).

    D_friction includes the viscous drag c_v V_c^2 (the resisting force of :func:`kinetic_level`);
    cont: the speed law continued below V_min (:func:`slip_level`)."""
    K, C, F0 = contact_terms(p, contact)
    fe = drive_force(p, s, fe_level)
    Fi = K * y[0] + C * y[1] + F0
    # slip speed along the slip direction: > 0 during the slip; written without |.| so that the
    # right-hand side continues smoothly past the slip's end inside the step that locates it
    if p[I_KS] > 0.0:
        rk_rhs_patch(p, sgn, Fi, fe, y, dy, cont)
        dy[5] = p[I_C] * y[1] * y[1]
        dy[6] = (C - p[I_C]) * y[1] * y[1]
        return
    Vs = sgn * y[2]
    L = slip_level(p, Vs if Vs > 0.0 else 0.0, y[0], cont)
    dy[8] = 0.0
    ac = (-sgn * L - p[I_CV] * y[2] + Fi) / p[I_MC]
    am = (fe - Fi) / p[I_MM]
    dy[0] = y[1]
    dy[1] = am - ac
    dy[2] = ac
    dy[3] = y[2]
    dy[4] = fe * (y[2] + y[1])
    dy[5] = p[I_C] * y[1] * y[1]
    dy[6] = (C - p[I_C]) * y[1] * y[1]
    dy[7] = L * Vs + p[I_CV] * y[2] * y[2]


@kernel
def held_patch_extension(p, sgn, xr):
    """Extension d [m] of the presliding spring of a patch sliding in direction sgn on a wall with
    c_s = 0 (substrate_compliance): k_s d = sgn L(0, x_r), the level at zero slip speed with the tilt
    factor. Algebraic: the breakaway jumps to it, and a slide's end and the patch's stop take it
    instead of the integrated d, whose rounding a breakaway equal to the level saw as an exit."""
    return sgn * friction_level(p, 0.0, xr) / p[I_KS]


@kernel
def held_patch_rate(p, sgn, xr, vr):
    """Rate d' [m/s] of the presliding spring's extension while a patch slides in direction sgn on a
    wall with c_s = 0 (substrate_compliance): the massless patch keeps k_s d = sgn L(0, x_r), its level
    at zero slip speed (Coulomb's kinetic level, or a speed law's held at V_min) with the tilt factor,
    so d follows the tilt (tilt_friction) and the patch stops with its force at the level; 0 without
    tilt or where the tilt level is held at zero."""
    if p[I_KAP] == 0.0 or tilt_factor(p, xr) <= 0.0:
        return 0.0
    return sgn * p[I_L0] * p[I_KAP] / p[I_G1] * vr / p[I_KS]


@kernel
def rk_rhs_patch(p, sgn, Fi, fe, y, dy, cont):
    """Shell on a compliant wall (substrate_compliance, physics.md section 3): spring k_s and damper
    c_s between the shell and a massless contact patch carrying the set-valued friction.

    Patch stuck (sgn = 0): force on the shell -(k_s d + c_s V_c), d' = V_c. Patch sliding in
    direction sgn: the massless patch balances k_s d + c_s (V_c - V_p) = sgn L, so the shell feels
    -sgn L and d' = (sgn L - k_s d) / c_s. With c_s = 0 (the limit chosen for c_s -> 0) k_s d is the
    level at zero slip speed, sgn L(0, x_r), which moves only with the tilt (:func:`held_patch_rate`),
    V_p = V_c - d', and a speed law's level is taken at V_p. Dissipation: friction L |V_p|, damper
    c_s (V_c - V_p)^2, drag; with c_s = 0 the shell's work not stored in the spring.
    """
    ks = p[I_KS]
    cs = p[I_CS]
    cv = p[I_CV]
    Vc = y[2]
    if sgn == 0.0:
        Fs = ks * y[8] + cs * Vc
        dd = Vc
        diss = cs * Vc * Vc
    else:
        if cs > 0.0:
            L = friction_level(p, 0.0, y[0])  # Coulomb (a speed law with c_s > 0 is refused on packing)
            dd = (sgn * L - ks * y[8]) / cs
            Fs = sgn * L
            diss = L * sgn * (Vc - dd) + cs * dd * dd
        else:
            dd = held_patch_rate(p, sgn, y[0], y[1])
            Vs = sgn * (Vc - dd)
            L = slip_level(p, Vs if Vs > 0.0 else 0.0, y[0], cont)
            Fs = sgn * L
            # the shell's work not stored in the spring (friction L |V_p| for Coulomb)
            diss = Fs * Vc - ks * y[8] * dd
    ac = (Fi - Fs - cv * Vc) / p[I_MC]
    am = (fe - Fi) / p[I_MM]
    dy[0] = y[1]
    dy[1] = am - ac
    dy[2] = ac
    dy[3] = Vc
    dy[4] = fe * (Vc + y[1])
    dy[7] = diss + cv * Vc * Vc
    dy[8] = dd


# ---------------------------------------------------------------------------
# Dormand-Prince 8(5,3) (DOP853) for the adaptive segment: the stepper, its error norm and dense output
# (E. Hairer, S. P. Norsett, G. Wanner, "Solving Ordinary Differential Equations I: Nonstiff
# Problems", 2nd ed., Springer 1993, section II.10, and their Fortran code dop853.f; the
# coefficients below are that code's, as transcribed in scipy.integrate's DOP853). Eighth order
# with a 5th- and 3rd-order error estimate and a 7th-order continuous extension (3 more stages);
# at the engine's tight tolerance it takes several times fewer right-hand-side evaluations per
# unit time than the Dormand-Prince 5(4) it replaces (issue 13).


def _dop853_tableau():
    """Return (A, C, B, E3, E5, D) of DOP853: 16 stages (12 + FSAL + 3 dense), the 8th-order
    weights, the 3rd- and 5th-order error weights (13 stages) and the dense-output matrix (4 x 16)."""
    N_STAGES = 12
    A = np.zeros((16, 16))
    D = np.zeros((4, 16))
    C = np.array([0.0,
                  0.526001519587677318785587544488e-01,
                  0.789002279381515978178381316732e-01,
                  0.118350341907227396726757197510,
                  0.281649658092772603273242802490,
                  0.333333333333333333333333333333,
                  0.25,
                  0.307692307692307692307692307692,
                  0.651282051282051282051282051282,
                  0.6,
                  0.857142857142857142857142857142,
                  1.0,
                  1.0,
                  0.1,
                  0.2,
                  0.777777777777777777777777777778])

    A[1, 0] = 5.26001519587677318785587544488e-2

    A[2, 0] = 1.97250569845378994544595329183e-2
    A[2, 1] = 5.91751709536136983633785987549e-2

    A[3, 0] = 2.95875854768068491816892993775e-2
    A[3, 2] = 8.87627564304205475450678981324e-2

    A[4, 0] = 2.41365134159266685502369798665e-1
    A[4, 2] = -8.84549479328286085344864962717e-1
    A[4, 3] = 9.24834003261792003115737966543e-1

    A[5, 0] = 3.7037037037037037037037037037e-2
    A[5, 3] = 1.70828608729473871279604482173e-1
    A[5, 4] = 1.25467687566822425016691814123e-1

    A[6, 0] = 3.7109375e-2
    A[6, 3] = 1.70252211019544039314978060272e-1
    A[6, 4] = 6.02165389804559606850219397283e-2
    A[6, 5] = -1.7578125e-2

    A[7, 0] = 3.70920001185047927108779319836e-2
    A[7, 3] = 1.70383925712239993810214054705e-1
    A[7, 4] = 1.07262030446373284651809199168e-1
    A[7, 5] = -1.53194377486244017527936158236e-2
    A[7, 6] = 8.27378916381402288758473766002e-3

    A[8, 0] = 6.24110958716075717114429577812e-1
    A[8, 3] = -3.36089262944694129406857109825
    A[8, 4] = -8.68219346841726006818189891453e-1
    A[8, 5] = 2.75920996994467083049415600797e1
    A[8, 6] = 2.01540675504778934086186788979e1
    A[8, 7] = -4.34898841810699588477366255144e1

    A[9, 0] = 4.77662536438264365890433908527e-1
    A[9, 3] = -2.48811461997166764192642586468
    A[9, 4] = -5.90290826836842996371446475743e-1
    A[9, 5] = 2.12300514481811942347288949897e1
    A[9, 6] = 1.52792336328824235832596922938e1
    A[9, 7] = -3.32882109689848629194453265587e1
    A[9, 8] = -2.03312017085086261358222928593e-2

    A[10, 0] = -9.3714243008598732571704021658e-1
    A[10, 3] = 5.18637242884406370830023853209
    A[10, 4] = 1.09143734899672957818500254654
    A[10, 5] = -8.14978701074692612513997267357
    A[10, 6] = -1.85200656599969598641566180701e1
    A[10, 7] = 2.27394870993505042818970056734e1
    A[10, 8] = 2.49360555267965238987089396762
    A[10, 9] = -3.0467644718982195003823669022

    A[11, 0] = 2.27331014751653820792359768449
    A[11, 3] = -1.05344954667372501984066689879e1
    A[11, 4] = -2.00087205822486249909675718444
    A[11, 5] = -1.79589318631187989172765950534e1
    A[11, 6] = 2.79488845294199600508499808837e1
    A[11, 7] = -2.85899827713502369474065508674
    A[11, 8] = -8.87285693353062954433549289258
    A[11, 9] = 1.23605671757943030647266201528e1
    A[11, 10] = 6.43392746015763530355970484046e-1

    A[12, 0] = 5.42937341165687622380535766363e-2
    A[12, 5] = 4.45031289275240888144113950566
    A[12, 6] = 1.89151789931450038304281599044
    A[12, 7] = -5.8012039600105847814672114227
    A[12, 8] = 3.1116436695781989440891606237e-1
    A[12, 9] = -1.52160949662516078556178806805e-1
    A[12, 10] = 2.01365400804030348374776537501e-1
    A[12, 11] = 4.47106157277725905176885569043e-2

    A[13, 0] = 5.61675022830479523392909219681e-2
    A[13, 6] = 2.53500210216624811088794765333e-1
    A[13, 7] = -2.46239037470802489917441475441e-1
    A[13, 8] = -1.24191423263816360469010140626e-1
    A[13, 9] = 1.5329179827876569731206322685e-1
    A[13, 10] = 8.20105229563468988491666602057e-3
    A[13, 11] = 7.56789766054569976138603589584e-3
    A[13, 12] = -8.298e-3

    A[14, 0] = 3.18346481635021405060768473261e-2
    A[14, 5] = 2.83009096723667755288322961402e-2
    A[14, 6] = 5.35419883074385676223797384372e-2
    A[14, 7] = -5.49237485713909884646569340306e-2
    A[14, 10] = -1.08347328697249322858509316994e-4
    A[14, 11] = 3.82571090835658412954920192323e-4
    A[14, 12] = -3.40465008687404560802977114492e-4
    A[14, 13] = 1.41312443674632500278074618366e-1

    A[15, 0] = -4.28896301583791923408573538692e-1
    A[15, 5] = -4.69762141536116384314449447206
    A[15, 6] = 7.68342119606259904184240953878
    A[15, 7] = 4.06898981839711007970213554331
    A[15, 8] = 3.56727187455281109270669543021e-1
    A[15, 12] = -1.39902416515901462129418009734e-3
    A[15, 13] = 2.9475147891527723389556272149
    A[15, 14] = -9.15095847217987001081870187138

    B = A[N_STAGES, :N_STAGES]

    E3 = np.zeros(N_STAGES + 1)
    E3[:-1] = B.copy()
    E3[0] -= 0.244094488188976377952755905512
    E3[8] -= 0.733846688281611857341361741547
    E3[11] -= 0.220588235294117647058823529412e-1

    E5 = np.zeros(N_STAGES + 1)
    E5[0] = 0.1312004499419488073250102996e-1
    E5[5] = -0.1225156446376204440720569753e+1
    E5[6] = -0.4957589496572501915214079952
    E5[7] = 0.1664377182454986536961530415e+1
    E5[8] = -0.3503288487499736816886487290
    E5[9] = 0.3341791187130174790297318841
    E5[10] = 0.8192320648511571246570742613e-1
    E5[11] = -0.2235530786388629525884427845e-1

    # First 3 coefficients are computed separately.
    D[0, 0] = -0.84289382761090128651353491142e+1
    D[0, 5] = 0.56671495351937776962531783590
    D[0, 6] = -0.30689499459498916912797304727e+1
    D[0, 7] = 0.23846676565120698287728149680e+1
    D[0, 8] = 0.21170345824450282767155149946e+1
    D[0, 9] = -0.87139158377797299206789907490
    D[0, 10] = 0.22404374302607882758541771650e+1
    D[0, 11] = 0.63157877876946881815570249290
    D[0, 12] = -0.88990336451333310820698117400e-1
    D[0, 13] = 0.18148505520854727256656404962e+2
    D[0, 14] = -0.91946323924783554000451984436e+1
    D[0, 15] = -0.44360363875948939664310572000e+1

    D[1, 0] = 0.10427508642579134603413151009e+2
    D[1, 5] = 0.24228349177525818288430175319e+3
    D[1, 6] = 0.16520045171727028198505394887e+3
    D[1, 7] = -0.37454675472269020279518312152e+3
    D[1, 8] = -0.22113666853125306036270938578e+2
    D[1, 9] = 0.77334326684722638389603898808e+1
    D[1, 10] = -0.30674084731089398182061213626e+2
    D[1, 11] = -0.93321305264302278729567221706e+1
    D[1, 12] = 0.15697238121770843886131091075e+2
    D[1, 13] = -0.31139403219565177677282850411e+2
    D[1, 14] = -0.93529243588444783865713862664e+1
    D[1, 15] = 0.35816841486394083752465898540e+2

    D[2, 0] = 0.19985053242002433820987653617e+2
    D[2, 5] = -0.38703730874935176555105901742e+3
    D[2, 6] = -0.18917813819516756882830838328e+3
    D[2, 7] = 0.52780815920542364900561016686e+3
    D[2, 8] = -0.11573902539959630126141871134e+2
    D[2, 9] = 0.68812326946963000169666922661e+1
    D[2, 10] = -0.10006050966910838403183860980e+1
    D[2, 11] = 0.77771377980534432092869265740
    D[2, 12] = -0.27782057523535084065932004339e+1
    D[2, 13] = -0.60196695231264120758267380846e+2
    D[2, 14] = 0.84320405506677161018159903784e+2
    D[2, 15] = 0.11992291136182789328035130030e+2

    D[3, 0] = -0.25693933462703749003312586129e+2
    D[3, 5] = -0.15418974869023643374053993627e+3
    D[3, 6] = -0.23152937917604549567536039109e+3
    D[3, 7] = 0.35763911791061412378285349910e+3
    D[3, 8] = 0.93405324183624310003907691704e+2
    D[3, 9] = -0.37458323136451633156875139351e+2
    D[3, 10] = 0.10409964950896230045147246184e+3
    D[3, 11] = 0.29840293426660503123344363579e+2
    D[3, 12] = -0.43533456590011143754432175058e+2
    D[3, 13] = 0.96324553959188282948394950600e+2
    D[3, 14] = -0.39177261675615439165231486172e+2
    D[3, 15] = -0.14972683625798562581422125276e+3
    return A, C, B, E3, E5, D


DOP_A, DOP_C, DOP_B, DOP_E3, DOP_E5, DOP_D = _dop853_tableau()
DOP_NK = 16  # stages kept per step (rows of the stage array)
RK_ORDER_EXP = 1.0 / 8.0  # step-size exponent: 1 / (error-estimator order 7 + 1)


@kernel
def dop853_stages(p, contact, sg, s, h, fe_level, y, K, yt, i0, i1, plug, held, t0, pq, pfail, full, cont):
    """Stages i0 .. i1-1 of a DOP853 step of size h [s] from y at time s within the period:
    K[i] = f(s + c_i h, y + h sum_m a_im K[m]) (:func:`seg_rhs` with held, t0, pq, pfail when a user
    plugin force acts, else :func:`rk_rhs`). The right-hand side reads only the mechanical state
    (x_r, v_r, V_c, X_c) and, on a compliant wall, the patch extension d, never the energy
    integrals; so the stage states of the components after the fourth are formed only with
    ``full`` (a compliant wall), and the stages themselves, the step and its energy integrals are
    the same to the bit either way (40 % of the stage arithmetic without them). ``cont``: the speed
    law continued below V_min in the right-hand side (:func:`slip_level`). The loops have
    constant bounds so that LLVM unrolls them: written once for both ranges
    (a helper taking the range) the speed-law map points were 2-3 % slower."""
    for i in range(i0, i1):
        for q in range(4):
            yt[q] = 0.0
        for m in range(i):
            a = DOP_A[i, m]
            if a != 0.0:
                for q in range(4):
                    yt[q] += a * K[m, q]
        for q in range(4):
            yt[q] = y[q] + h * yt[q]
        if full:
            for q in range(4, NY):
                yt[q] = 0.0
            for m in range(i):
                a = DOP_A[i, m]
                if a != 0.0:
                    for q in range(4, NY):
                        yt[q] += a * K[m, q]
            for q in range(4, NY):
                yt[q] = y[q] + h * yt[q]
        if plug:
            seg_rhs(p, contact, sg, held, s + DOP_C[i] * h, t0, fe_level, yt, K[i], pq, pfail, cont)
        else:
            rk_rhs(p, contact, sg, s + DOP_C[i] * h, fe_level, yt, K[i], cont)


@kernel
def dop853_step(p, contact, sg, s, h, fe_level, y, k1, K, yt, y1, k7, plug, held, t0, pq, pfail, full, cont):
    """One DOP853 step of size h [s] from y at time s within the period (derivative k1 = f(s, y)).

    Fills the stages K[0..12] (K[12] = f(s + h, y1), also copied to k7 for the next step, FSAL)
    and the 8th-order solution y1. plug, held, t0, pq, pfail, full, cont as in :func:`dop853_stages`."""
    for q in range(NY):
        K[0, q] = k1[q]
    dop853_stages(p, contact, sg, s, h, fe_level, y, K, yt, 1, 12, plug, held, t0, pq, pfail, full, cont)
    for q in range(NY):
        acc = 0.0
        for m in range(12):
            acc += DOP_B[m] * K[m, q]
        y1[q] = y[q] + h * acc
    if plug:
        seg_rhs(p, contact, sg, held, s + h, t0, fe_level, y1, K[12], pq, pfail, cont)
    else:
        rk_rhs(p, contact, sg, s + h, fe_level, y1, K[12], cont)
    for q in range(NY):
        k7[q] = K[12, q]


@kernel
def dop853_error(K, h, y, y1, rtol, atol_x, atol_v):
    """Scaled error norm of a DOP853 step (Hairer's combined 5th/3rd-order estimate) over the
    mechanical state (x_r, v_r, V_c, X_c): <= 1 accepts the step."""
    e5 = 0.0
    e3 = 0.0
    for q in range(4):
        a5 = 0.0
        a3 = 0.0
        for m in range(13):
            a5 += DOP_E5[m] * K[m, q]
            a3 += DOP_E3[m] * K[m, q]
        at = atol_x if (q == 0 or q == 3) else atol_v
        sc = at + rtol * max(abs(y[q]), abs(y1[q]))
        e5 += (a5 / sc) ** 2
        e3 += (a3 / sc) ** 2
    if e5 == 0.0 and e3 == 0.0:
        return 0.0
    return abs(h) * e5 / math.sqrt((e5 + 0.01 * e3) * 4.0)


@kernel
def dop853_dense(p, contact, sg, s, h, fe_level, y, y1, K, yt, rc, plug, held, t0, pq, pfail, full, cont):
    """Continuous extension of an accepted DOP853 step: three more stages, then rc[0] = y and
    rc[1..7] the coefficients evaluated by :func:`dense_eval` (7th order in theta); plug, held, t0,
    pq, pfail, full, cont as in :func:`dop853_stages`."""
    dop853_stages(p, contact, sg, s, h, fe_level, y, K, yt, 13, 16, plug, held, t0, pq, pfail, full, cont)
    for q in range(NY):
        dy = y1[q] - y[q]
        rc[0, q] = y[q]
        rc[1, q] = dy
        rc[2, q] = h * K[0, q] - dy
        rc[3, q] = 2.0 * dy - h * (K[12, q] + K[0, q])
        for r in range(4):
            acc = 0.0
            for m in range(16):
                acc += DOP_D[r, m] * K[m, q]
            rc[4 + r, q] = h * acc


@kernel
def rk_step_factor(err, rejected, err_old, h_ratio):
    """Step-size factor after an accepted step of scaled error ``err`` (safety 0.9, within [0.2, 5];
    no growth right after a rejection). With the previous accepted step's error ``err_old`` > 0 and
    ``h_ratio`` = this step / that step, the factor is also capped by Gustafsson's predictive
    controller (K. Gustafsson, ACM Trans. Math. Softw. 20 (1994) 496-517; E. Hairer, G. Wanner,
    "Solving ODEs II", section IV.8), which foresees a growing error (as the slip speed nears
    V_min, where the law's derivatives grow) and so avoids some rejected steps."""
    if err == 0.0:
        fac = 5.0
    else:
        fac = 0.9 * err ** -RK_ORDER_EXP
        if err_old > 0.0:
            fac = min(fac, fac * h_ratio * (err_old / err) ** RK_ORDER_EXP)
        fac = min(5.0, max(0.2, fac))
    if rejected and fac > 1.0:
        fac = 1.0
    return fac


@kernel
def patch_force(p, d, Vc):
    """Force [N] of the presliding spring-damper on the stuck patch, k_s d + c_s V_c."""
    return p[I_KS] * d + p[I_CS] * Vc


@kernel
def decide_patch(p, contact, xr, vr, Vc, d, fe, Fc):
    """Return the patch state (PATCH_STICK, FAST_POS, FAST_NEG; -1 ill-posed) by the set-valued
    law applied to the patch force (substrate_compliance), as :func:`decide_shell` for the shell
    (Fc [N]: the user plugin force on the shell, 0 without a plugin)."""
    Pb = p[I_PB]
    if Pb == np.inf:
        return PATCH_STICK
    Pb *= tilt_factor(p, xr)
    F = patch_force(p, d, Vc)
    tol = 1e-12 * p[I_FS]
    aF = abs(F)
    if aF < Pb - tol:
        return PATCH_STICK
    sgn = 1.0 if F > 0.0 else -1.0
    if aF <= Pb + tol:
        K, C, F0 = contact_terms(p, contact)
        Fi = K * xr + C * vr + F0
        ac = (Fi - F - p[I_CV] * Vc + Fc) / p[I_MC]
        Fdot = p[I_KS] * Vc + p[I_CS] * ac
        if Pb == 0.0:
            # a zero level (tilt_friction held at zero) holds nothing: the patch goes where the force's
            # first nonzero derivative takes it (with c_s = 0, F' = k_s V_c and F'' = k_s a_c), and
            # sticks only if that is zero as well
            rate = Fdot
            if p[I_CS] == 0.0 and abs(Vc) <= TOL_V_REL * p[I_VS]:
                rate = ac
            if rate == 0.0:
                return PATCH_STICK
            return FAST_POS if rate > 0.0 else FAST_NEG
        dPb = p[I_PB] * p[I_KAP] / p[I_G1] * vr if Pb > 0.0 else 0.0
        if sgn * Fdot - dPb <= 0.0:
            return PATCH_STICK
    if aF - friction_level(p, 0.0, xr) < -tol:
        return -1
    return FAST_POS if sgn > 0 else FAST_NEG


@kernel
def dense_eval(rc, th, out):
    """Evaluate the DOP853 continuous extension (:func:`dop853_dense`) at theta in [0, 1] of the step."""
    t1 = 1.0 - th
    for i in range(NY):
        out[i] = rc[0, i] + th * (rc[1, i] + t1 * (rc[2, i] + th * (rc[3, i] + t1 * (
            rc[4, i] + th * (rc[5, i] + t1 * (rc[6, i] + th * rc[7, i]))))))


@kernel
def rk_event_value(p, contact, sgn, vlo, vhi, j, y):
    """Inside-positive event functions of an adaptive segment (j: 0 contact a, 1 contact b, 2 V_min or
    slip end; with substrate compliance 2/3 the patch's breakaway + / -, or 2 the patch's stop)."""
    G1 = p[I_G1]
    G2 = p[I_G2]
    if j >= 2 and p[I_KS] > 0.0:
        if sgn == 0.0:  # patch stuck: |k_s d + c_s V_c| <= P_b (1 + kappa x_r / G_1)
            Pb = p[I_PB] * (1.0 + p[I_KAP] * y[0] / G1)
            F = patch_force(p, y[8], y[2])
            return Pb - F if j == 2 else Pb + F
        if j == 3:
            return 1.0
        if p[I_CS] > 0.0:  # patch speed V_p = V_c - d'
            return sgn * (y[2] - (sgn * friction_level(p, 0.0, y[0]) - p[I_KS] * y[8]) / p[I_CS])
        return sgn * (y[2] - held_patch_rate(p, sgn, y[0], y[1]))
    if j == 3:
        return vhi - sgn * y[2] if vhi < np.inf else 1.0
    if j == 2:
        return sgn * y[2] - vlo
    if contact == 0:
        if j == 0:
            return G1 - y[0]
        if p[I_BACK] > 0.5:
            return y[0] + G2
        return 1.0
    if contact == 1:
        return y[0] - G1 if j == 0 else 1.0
    return -G2 - y[0] if j == 0 else 1.0


@kernel
def rk_event_slope(p, contact, sgn, vlo, vhi, j, y, dy, g, dlt, yd):
    """The time derivative of :func:`rk_event_value` j at state y with derivative dy, whose value there is g:
    a finite difference over dlt [s] along dy (the event functions are linear in the state, but for the
    clamp of a tilted level); yd: work space."""
    if g == 1.0:
        return 0.0
    for i in range(NY):
        yd[i] = y[i] + dlt * dy[i]
    return (rk_event_value(p, contact, sgn, vlo, vhi, j, yd) - g) / dlt


@kernel
def rk_dense_dip(p, contact, sgn, vlo, vhi, j, rc, tol, yd):
    """The first of 64 points of a step's dense output (rc) where event j is below -tol, as a fraction of the
    step (its crossing is then bracketed from the step's start), or -1 if none: the step's event
    function had a minimum inside (:func:`adaptive_segment`)."""
    for q in range(1, 65):
        th = q / 64.0
        dense_eval(rc, th, yd)
        if rk_event_value(p, contact, sgn, vlo, vhi, j, yd) < -tol:
            return th
    return -1.0


# ---------------------------------------------------------------------------
# user plugin forces (issue 9 item 4; capsule_cli.dynamics.plugin_force compiles them)
#
# The engine is compiled once and cached; a plugin force comes as a C-callable function (a numba ``cfunc``
# built by plugin_force.compile_forces) of one fixed signature
#     double plugin(int64 which, double t, double x_m, double v_m, double x_c, double v_c, double *q)
# returning the force on the magnet (which = 0) or on the shell (which = 1) [N] at time t [s] since the
# run's start, NaN when the user's function raised or returned a non-finite force; q: its parameters (SI).
# Its address travels in the parameter row (I_PLUG_FN) and the engine calls it indirectly, only on the
# plugin's own branches (seg_rhs, seg_event_value, plugin_stick_terms): the code of the runs without a
# plugin is unchanged.


@intrinsic
def _call_plugin_ptr(typingctx, addr, which, t, xm, vm, xc, vc, qptr):
    """Call the plugin at address ``addr`` (int64) with its parameters at ``qptr`` (int64); a cfunc does
    not unwind (nounwind)."""
    sig = types.float64(types.int64, types.int64, types.float64, types.float64, types.float64, types.float64,
                        types.float64, types.int64)

    def codegen(context, builder, signature, args):
        d = ir.DoubleType()
        fnty = ir.FunctionType(d, [ir.IntType(64), d, d, d, d, d, d.as_pointer()])
        fn = builder.inttoptr(args[0], fnty.as_pointer())
        q = builder.inttoptr(args[7], d.as_pointer())
        return builder.call(fn, list(args[1:7]) + [q], attrs=("nounwind",))

    return sig, codegen


@intrinsic
def _data_ptr(typingctx, arr):
    """Return the address (int64) of a contiguous array's first element, without touching its refcount."""
    sig = types.int64(arr)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, value=args[0])
        return builder.ptrtoint(ary.data, ir.IntType(64))

    return sig, codegen


@kernel
def plugin_force(pq, pfail, t, xr, vr, Xc, Vc):
    """Return (F_m, F_c) [N], the user plugin force on the magnet and the shell at time t [s] since the
    run's start and state (x_r, v_r, X_c, V_c) [m, m/s]; pq: [address, parameters...] (a copy of the row's
    plugin slots from I_PLUG_FN). A plugin that fails sets pfail[0] = 1 (the run stops with
    STATUS_PLUGIN) and counts as zero force."""
    addr = np.int64(pq[0])
    q = _data_ptr(pq) + 8 * (I_PLUG_P0 - I_PLUG_FN)
    Fm = _call_plugin_ptr(addr, 0, t, Xc + xr, Vc + vr, Xc, Vc, q)
    Fc = _call_plugin_ptr(addr, 1, t, Xc + xr, Vc + vr, Xc, Vc, q)
    if not (math.isfinite(Fm) and math.isfinite(Fc)):
        pfail[0] = 1.0
        return 0.0, 0.0
    return Fm, Fc


@kernel
def plugin_stick_terms(p, pq, pfail, t, contact, xr, vr, Xc, fe):
    """Return (F_m, F_c, dF_c/dt) [N, N, N/s] of the plugin force on a shell at rest (V_c = 0) for the stick
    test of :func:`decide_shell`; the rate by a central difference over 1e-7 of a drive period along the
    stuck motion (X_c fixed, x_r'' from the magnet's equation)."""
    Fm, Fc = plugin_force(pq, pfail, t, xr, vr, Xc, 0.0)
    K, C, F0 = contact_terms(p, contact)
    ar = (fe - (K * xr + C * vr + F0) + Fm) / p[I_MM]
    dt = 1e-7 / p[I_F]
    _, Fp = plugin_force(pq, pfail, t + dt, xr + dt * vr, vr + dt * ar, Xc, 0.0)
    _, Fn = plugin_force(pq, pfail, t - dt, xr - dt * vr, vr - dt * ar, Xc, 0.0)
    return Fm, Fc, (Fp - Fn) / (2.0 * dt)


@kernel
def held_rhs(p, contact, s, fe_level, y, dy, Fm):
    """Right-hand side (as :func:`rk_rhs`) of a shell held on a rigid wall with a plugin force: V_c = 0
    while |F_i + F_c| stays inside the friction cone (the breakaway is an event of
    :func:`seg_event_value`); only the magnet moves, M_m x_r'' = F_e - F_i + F_m. y[9] integrates the
    plugin's power F_m V_m."""
    K, C, F0 = contact_terms(p, contact)
    fe = drive_force(p, s, fe_level)
    Fi = K * y[0] + C * y[1] + F0
    dy[0] = y[1]
    dy[1] = (fe - Fi + Fm) / p[I_MM]
    dy[2] = 0.0
    dy[3] = 0.0
    dy[4] = fe * y[1]
    dy[5] = p[I_C] * y[1] * y[1]
    dy[6] = (C - p[I_C]) * y[1] * y[1]
    dy[7] = 0.0
    dy[8] = 0.0
    dy[9] = Fm * y[1]


@kernel
def seg_rhs(p, contact, sgn, held, s, t0, fe_level, y, dy, pq, pfail, cont):
    """Right-hand side of the adaptive segment with a user plugin force, at time s within the period
    starting at t0 [s]: :func:`rk_rhs` plus F_m on the magnet and F_c on the shell, their power
    F_m V_m + F_c V_c in y[9]; held: a shell stuck on a rigid wall (:func:`held_rhs`)."""
    if held:
        Fm, _ = plugin_force(pq, pfail, t0 + s, y[0], y[1], y[3], 0.0)
        held_rhs(p, contact, s, fe_level, y, dy, Fm)
        return
    rk_rhs(p, contact, sgn, s, fe_level, y, dy, cont)
    Fm, Fc = plugin_force(pq, pfail, t0 + s, y[0], y[1], y[3], y[2])
    dy[1] += Fm / p[I_MM] - Fc / p[I_MC]
    dy[2] += Fc / p[I_MC]
    dy[9] = Fm * (y[2] + y[1]) + Fc * y[2]


@kernel
def seg_event_value(p, contact, sgn, held, vlo, vhi, j, y, t, pq, pfail):
    """Inside-positive event functions of an adaptive segment at time t [s] since the run's start:
    :func:`rk_event_value`, or for a shell held with a plugin force its stick test (eq 21 with the plugin's
    force on the shell): j = 2 P_b - (F_i + F_c), j = 3 P_b + (F_i + F_c), P_b tilt-scaled; 1 when fixed."""
    if held and j >= 2:
        if p[I_PB] == np.inf:
            return 1.0
        _, Fc = plugin_force(pq, pfail, t, y[0], y[1], y[3], 0.0)
        K, C, F0 = contact_terms(p, contact)
        F = K * y[0] + C * y[1] + F0 + Fc
        Pb = p[I_PB] * tilt_factor(p, y[0])
        return Pb - F if j == 2 else Pb + F
    return rk_event_value(p, contact, sgn, vlo, vhi, j, y)


# ---------------------------------------------------------------------------
# the run


@kernel
def signed_rows(sg, c, dc, out_c, out_dc):
    """out_c, out_dc = sg c, sg dc: the rows of -g and -g' (sg = -1) for a root search that needs
    g(a) >= 0 > g(b) (:func:`mode_root`)."""
    for j in range(NB):
        out_c[j] = sg * c[j]
        out_dc[j] = sg * dc[j]


@kernel
def twin_reach(ga, gb, dga, dgb, h):
    """A lower bound of g over a cell [0, h] [s] where g' has one sign at both ends, from g and g' at the
    ends, if g'' is monotone across it (the scan's cell is 1/NPER of the fastest period); +inf where g'
    cannot vanish there. D = h (g'_a + g'_b) / 2 - (g_b - g_a) is the area between g' and its chord.
    Only g' convex (g' > 0 at both ends, D >= 0) or concave (g' < 0, D <= 0) can vanish twice, and
    then it reaches at most 2 |D| / h beyond its chord. Convex, g' below zero has at most the area D,
    so g >= g_a - D; concave, g' lies above its chord, so g >= g_a + h (g'_a + g'_b) / 2."""
    D = 0.5 * h * (dga + dgb) - (gb - ga)
    if dga > 0.0 and dgb > 0.0 and 2.0 * D > h * min(dga, dgb):
        return ga - D
    if dga < 0.0 and dgb < 0.0 and -2.0 * D > -h * max(dga, dgb):
        return ga + 0.5 * h * (dga + dgb)
    return math.inf


@kernel
def twin_extrema_root(base, c, dc, ddc, dddc, negc, negdc, tol, ga, dga, ddgb, ta, tb, s, md, Om, B):
    """Return the first tau in (ta, tb] just past a crossing of g = c.B below -tol, or -1.

    For a cell where g >= 0 at both ends and g' has one sign at both ends but g may dip below -tol
    (:func:`twin_reach`): g' vanishes twice inside if g'' changes sign (ddgb: g'' at tb) and g' its
    sign at the root of g''. g then has a maximum and a minimum (g' > 0 at the ends) or a minimum and
    a maximum (g' < 0); the minimum is the root of g' on its side of that point, and a crossing below
    -tol is bracketed from g's maximum (g' > 0) or from ta (g' < 0). dc, ddc: the coefficients of g'
    and g''; dddc, negc, negdc, B: work space.
    """
    rise = dga > 0.0
    mode_basis(base, ta, s, md, Om, B)
    ddga = mode_dot(base, ddc, B)
    # the extremum of g': g'' from - to + (a dip of g') or + to - (a bump)
    if (rise and not (ddga < 0.0 < ddgb)) or (not rise and not (ddga > 0.0 > ddgb)):
        return -1.0
    if base:
        deriv_base(ddc, md, Om, dddc)
    else:
        deriv_coefs(ddc, md, Om, dddc)
    signed_rows(-1.0 if rise else 1.0, ddc, dddc, negc, negdc)
    m1 = mode_root(base, negc, negdc, ta, tb, s, md, Om, B)
    mode_basis(base, m1, s, md, Om, B)
    dgm = mode_dot(base, dc, B)
    if (rise and dgm >= 0.0) or (not rise and dgm <= 0.0):
        return -1.0
    left = ta
    if rise:
        # g's maximum: g' from + to - on [ta, m1]; its minimum: g' from - to + on [m1, tb]
        left = mode_root(base, dc, ddc, ta, m1, s, md, Om, B)
        lo, hi = m1, tb
    else:
        if ga <= tol and ta == 0.0:
            return -1.0  # a mode starting on the surface and leaving it: decided by the mode's start
        lo, hi = ta, m1
    signed_rows(-1.0, dc, ddc, negc, negdc)
    tmin = mode_root(base, negc, negdc, lo, hi, s, md, Om, B)
    mode_basis(base, tmin, s, md, Om, B)
    if mode_dot(base, c, B) >= -tol:
        return -1.0
    return mode_root(base, c, dc, left, tmin, s, md, Om, B)


@kernel
def slot_factors(md, i, hc, R, j):
    """R[j:j+4] = the 2 x 2 map (row-major) taking a modal slot's pair (B[i], B[i+1]) at tau to tau + hc [s]:
    i = 0 (md[0:4]) or 7 (md[4:8]), kind, a, b, c as in :func:`basis`."""
    k = 0 if i == 0 else 4
    kind = md[k]
    if kind == MODE_OSC:
        e = math.exp(md[k + 1] * hc)
        disc = md[k + 2]
        w = md[k + 3]
        if disc < 0.0:
            C = math.cos(w * hc)
            S = math.sin(w * hc)
            R[j] = e * C
            R[j + 1] = -e * S * w
            R[j + 2] = e * S / w
            R[j + 3] = e * C
        elif disc > 0.0:
            C = math.cosh(w * hc)
            S = math.sinh(w * hc)
            R[j] = e * C
            R[j + 1] = e * S * w
            R[j + 2] = e * S / w
            R[j + 3] = e * C
        else:
            R[j] = e
            R[j + 1] = 0.0
            R[j + 2] = e * hc
            R[j + 3] = e
    elif kind == MODE_REAL:
        R[j] = math.exp(md[k + 1] * hc)
        R[j + 1] = 0.0
        R[j + 2] = 0.0
        R[j + 3] = math.exp(md[k + 2] * hc)
    else:
        R[j] = 0.0
        R[j + 1] = 0.0
        R[j + 2] = 0.0
        R[j + 3] = 0.0


@kernel
def basis_factors(base, hc, md, Om, R):
    """Fill R with the maps that advance :func:`basis` (or :func:`basis_base`) by hc [s]: the first
    modal slot (R[0:4]), the drive's cos, sin (R[4:8]) and the second slot (R[8:12]). Their cost is one
    basis evaluation; :func:`basis_advance` then costs a few multiplications. R[12:] keys the factors
    (hc, Om, md) so that a scan on the same cell size and mode reuses them."""
    slot_factors(md, 0, hc, R, 0)
    C = math.cos(Om * hc)
    S = math.sin(Om * hc)
    R[4] = C
    R[5] = -S
    R[6] = S
    R[7] = C
    if base:
        for j in range(8, 12):
            R[j] = 0.0
    else:
        slot_factors(md, 7, hc, R, 8)
    R[12] = hc
    R[13] = Om
    R[14] = 1.0 if base else 0.0
    for j in range(8):
        R[15 + j] = md[j]


@kernel
def factors_valid(base, hc, md, Om, R):
    """True if R holds :func:`basis_factors` of (base, hc, md, Om)."""
    if R[12] != hc or R[13] != Om or R[14] != (1.0 if base else 0.0):
        return False
    for j in range(8):
        if R[15 + j] != md[j]:
            return False
    return True


@kernel
def basis_advance(base, tb, R, Ba, Bb):
    """Bb = the basis at tb [s] from Ba at tb - hc (R: :func:`basis_factors` of hc): each modal slot and
    the drive's cos, sin advance by their 2 x 2 map (e^{lambda hc} products: rounding grows by about an
    ulp per step, so the scan re-evaluates the basis every SCAN_ANCHOR cells); 1, tau, tau^2 exactly."""
    b0 = Ba[0]
    b1 = Ba[1]
    Bb[0] = R[0] * b0 + R[1] * b1
    Bb[1] = R[2] * b0 + R[3] * b1
    b0 = Ba[2]
    b1 = Ba[3]
    Bb[2] = R[4] * b0 + R[5] * b1
    Bb[3] = R[6] * b0 + R[7] * b1
    Bb[4] = 1.0
    Bb[5] = tb
    Bb[6] = tb * tb
    if not base:
        b0 = Ba[7]
        b1 = Ba[8]
        Bb[7] = R[8] * b0 + R[9] * b1
        Bb[8] = R[10] * b0 + R[11] * b1


@kernel
def locate_event(evc, devc, ddevc, evcode, evtol, ne, cF, dcF, ddcF, md, Om, s, tau_end, h, h_slow,
                 recording, maxF, t_maxF, t_off, R, Bev, base):
    """Find the first event of a linear mode within (0, tau_end] and the extrema of F_i before it;
    return (event code or EV_NONE, its time tau, max |F_i|, its global time).

    Event functions are bracketed on cells growing from h to h_slow (h_slow = h: fixed cells), grazing
    minima caught by the sign change of g', crossings refined on the exact expressions by
    :func:`mode_root_ends` (g, g' at the cell's ends known: no basis evaluation for them); t_off is the
    period's start time. Bev: the basis at the returned time (for :func:`mode_state`); R: work space
    (LOCATE_WORK: the scan's maps and keys, the root searches' work, six bases, and g, g' at a cell's start
    per event). The work space is one array because arguments cost: each array is 7 words on the stack, and
    17 array arguments here took 15 % of the bench's time against 11 (session 13). base: a base mode
    on the seven-function basis (:func:`basis_base`, the benchmark's hot path), else a general mode
    (:func:`basis`).
    This scan used to be written out inline in :func:`run_core_at` for the base modes, where a call
    cost 20 %: that cost was numba's reference counting of the array arguments, which ``kernel``
    drops (the bench's us per period moved by less than its run-to-run spread).
    """
    o = 24 + 3 * NB
    Ba = R[o:o + NB]
    Bb = R[o + NB:o + 2 * NB]
    Bs = R[o + 2 * NB:o + 3 * NB]
    negc = R[o + 3 * NB:o + 4 * NB]
    negdc = R[o + 4 * NB:o + 5 * NB]
    dddc = R[o + 5 * NB:o + 6 * NB]
    ga = R[o + 6 * NB:o + 6 * NB + 6]
    dga = R[o + 6 * NB + 6:o + 6 * NB + 12]
    ev = EV_NONE
    tau_ev = tau_end
    # scan: Ba, Bb the basis at the cell's ends (swapped as the scan moves on)
    basis_start(base, s, md, Om, Ba)
    for e in range(ne):
        ga[e] = mode_dot(base, evc[e], Ba)
        dga[e] = mode_dot(base, devc[e], Ba)
    Fa = mode_dot(base, cF, Ba)
    dFa = mode_dot(base, dcF, Ba)
    if recording and abs(Fa) > maxF:
        maxF = abs(Fa)
        t_maxF = t_off + s
    ta = 0.0
    hcell = h
    n_adv = 0
    h_maps = -1.0  # the cell size R's maps are known to be for
    Wr = R[24:24 + 3 * NB]
    Wend = Wr[2 * NB:3 * NB]
    while True:
        tb = ta + hcell
        if tb < tau_end and n_adv < SCAN_ANCHOR - 1:
            # a whole cell: advance the basis (exact maps, no transcendental functions)
            if hcell != h_maps:
                if not factors_valid(base, hcell, md, Om, R):
                    basis_factors(base, hcell, md, Om, R)
                h_maps = hcell
            basis_advance(base, tb, R, Ba, Bb)
            n_adv += 1
        else:
            tb = min(tb, tau_end)
            mode_basis(base, tb, s, md, Om, Bb)
            n_adv = 0
        best = tb + 1.0
        best_e = -1
        for e in range(ne):
            gb = mode_dot(base, evc[e], Bb)
            dgb = mode_dot(base, devc[e], Bb)
            r = -1.0
            if gb < 0.0:
                if ga[e] > evtol[e] or (ta > 0.0 and ga[e] >= 0.0):
                    r = mode_root_ends(base, evc[e], devc[e], ta, tb, Ba, Bb, s, md, Om, Wr)
                else:
                    # a mode start on the event surface (|g| at rounding level, maybe g' ~ 0
                    # too, as at a Coulomb threshold): probe geometrically for the first point
                    # clearly inside, then bracket the crossing from there; none -> a genuine
                    # immediate exit.
                    r = ta
                    copy_basis(Ba, Wend)  # the basis at r (a mode_root below replaces it)
                    for kk in range(48):
                        tk = ta + (tb - ta) * 2.0 ** (kk - 47)
                        mode_basis(base, tk, s, md, Om, Bs)
                        if mode_dot(base, evc[e], Bs) > evtol[e]:
                            r = mode_root(base, evc[e], devc[e], tk, tb, s, md, Om, Wr)
                            break
            elif dgb > 0.0 and (dga[e] < 0.0 or (ta == 0.0 and abs(dga[e]) <= 1e-9 * dgb)):
                # an interior minimum of g (grazing). A mode that starts with g' ~ 0 (a slip
                # from a friction threshold: V_c' = 0) has g' of either sign at rounding
                # level at ta: probe geometrically for the first point where g' < 0.
                signed_rows(-1.0, devc[e], ddevc[e], negc, negdc)
                t0m = ta
                if dga[e] >= 0.0:
                    t0m = -1.0
                    for kk in range(48):
                        tk = ta + (tb - ta) * 2.0 ** (kk - 47)
                        mode_basis(base, tk, s, md, Om, Bs)
                        if mode_dot(base, devc[e], Bs) < 0.0:
                            t0m = tk
                            break
                m = tb
                if t0m == ta:
                    m = mode_root_ends(base, negc, negdc, ta, tb, Ba, Bb, s, md, Om, Wr)
                elif t0m >= 0.0:
                    m = mode_root(base, negc, negdc, t0m, tb, s, md, Om, Wr)
                copy_basis(Wend if t0m >= 0.0 else Bb, Bs)  # the basis at m
                gm = mode_dot(base, evc[e], Bs)
                if gm < -evtol[e]:
                    r = mode_root_ends(base, evc[e], devc[e], ta, m, Ba, Bs, s, md, Om, Wr)
            elif ga[e] >= -evtol[e] and twin_reach(ga[e], gb, dga[e], dgb, tb - ta) < -evtol[e]:
                # g' has one sign at both ends but may vanish twice inside (a maximum and a minimum of g
                # in one cell, as a contact left near the turning point of a swing), and g may then dip
                # below the surface. A mode that starts on the surface (a contact just left) has g(0) at
                # rounding level, of either sign: -evtol, not 0 (with 0 the turning-point contact of
                # test_dynamics_effects was found or missed by the sign of a 2e-19 m rounding)
                r = twin_extrema_root(base, evc[e], devc[e], ddevc[e], dddc, negc, negdc, evtol[e], ga[e],
                                      dga[e], mode_dot(base, ddevc[e], Bb), ta, tb, s, md, Om, Wr)
            if r >= 0.0 and r < best:
                best = r
                best_e = e
                copy_basis(Wend, Bev)
            ga[e] = gb
            dga[e] = dgb
        t_stop = tb if best_e < 0 else best
        # extrema of F_i within [ta, t_stop]
        if recording:
            Fb = mode_dot(base, cF, Bb)
            dFb = mode_dot(base, dcF, Bb)
            # an extremum of F_i inside the cell; refined only if it can beat maxF: with F'
            # monotone across a cell (1/NPER of the fastest period) |F(m)| <= |F_a| + |F'_a| h
            # and <= |F_b| + |F'_b| h
            hc = tb - ta
            if ((dFa > 0.0 and dFb < 0.0) or (dFa < 0.0 and dFb > 0.0)) and \
                    min(abs(Fa) + abs(dFa) * hc, abs(Fb) + abs(dFb) * hc) > maxF:
                if dFa > 0.0:
                    m = mode_root_ends(base, dcF, ddcF, ta, tb, Ba, Bb, s, md, Om, Wr)
                else:
                    signed_rows(-1.0, dcF, ddcF, negc, negdc)
                    m = mode_root_ends(base, negc, negdc, ta, tb, Ba, Bb, s, md, Om, Wr)
                if m <= t_stop:
                    Fm = abs(mode_dot(base, cF, Wend))  # Wend: the basis at m
                    if Fm > maxF:
                        maxF = Fm
                        t_maxF = t_off + s + m
            if best_e < 0 and abs(Fb) > maxF:
                maxF = abs(Fb)
                t_maxF = t_off + s + tb
            Fa = Fb
            dFa = dFb
        if best_e >= 0:
            ev = evcode[best_e]
            tau_ev = best
            break
        if tb >= tau_end:
            copy_basis(Bb, Bev)
            break
        ta = tb
        Ba, Bb = Bb, Ba
        if hcell < h_slow:
            hcell = min(2.0 * hcell, h_slow)
    return ev, tau_ev, maxF, t_maxF


@kernel
def settled_orbit(hist, k, xr, vr, Vc, dsub, contact, shell, tol_x, tol_v):
    """Store the state at the start of period k (phase 0) in the ring buffer ``hist`` and return the
    length q (1..SETTLE_ORBIT_MAX periods) of the periodic orbit it has settled on: the state of
    period k - q equal to this one within tol_x [m] (x_r, d) and tol_v [m/s] (v_r, V_c), in the
    same contact and shell state (0: not settled). The system is autonomous in the phase and
    invariant under a shift of X_c, so from then on each q periods repeat up to those tolerances."""
    n = hist.shape[0]
    row = hist[k % n]
    row[0] = xr
    row[1] = vr
    row[2] = Vc
    row[3] = dsub
    row[4] = contact
    row[5] = shell
    for q in range(1, n):
        if k - q < 0:
            break
        o = hist[(k - q) % n]
        if o[4] == contact and o[5] == shell and abs(o[0] - xr) <= tol_x and abs(o[1] - vr) <= tol_v \
                and abs(o[2] - Vc) <= tol_v and abs(o[3] - dsub) <= tol_x:
            return q
    return 0


@kernel
def fill_orbit(periods, k, q, T):
    """Fill the period table's rows k.. from the settled orbit of q periods recorded in rows k - q .. k - 1:
    row r is row r - q with its start X_c [m] advanced by the orbit's displacement and its peak time [s]
    by q T (T [s] the excitation period). Returns the orbit's displacement [m]."""
    D = 0.0
    for r in range(k - q, k):
        D += periods[r, P_DISP]
    for r in range(k, periods.shape[0]):
        for c in range(periods.shape[1]):
            periods[r, c] = periods[r - q, c]
        periods[r, P_XC0] += D
        periods[r, P_TMAXF] += q * T
    return D


@kernel
def open_period(row, xr, vr, Vc):
    """Record the state at the start of a recorded excitation period in its row of the period table:
    x_r [m], v_r [m/s], the magnet's and the shell's velocities [m/s]."""
    row[P_XR0] = xr
    row[P_VR0] = vr
    row[P_VM0] = Vc + vr
    row[P_VC0] = Vc


@kernel
def close_period(row, Xc_start, Xc, n_front, n_back, maxF, t_maxF, stick_fraction, n_stick):
    """Record a finished excitation period in its row of the period table: the shell's displacement
    over the period [m] and its start [m], the impacts on each constraint, the peak |F_i| [N] and its
    time [s], the fraction of the period stuck [-] and the number of sticks."""
    row[P_DISP] = Xc - Xc_start
    row[P_NFRONT] = n_front
    row[P_NBACK] = n_back
    row[P_MAXF] = maxF
    row[P_TMAXF] = t_maxF
    row[P_STICK] = stick_fraction
    row[P_XC0] = Xc_start
    row[P_NSTICK] = n_stick


@kernel
def shell_transition(p, ev, shell, contact, xr, vr, Vc, dsub, fe_now, pFm, pFc, pdFc, abort):
    """The shell's state after event ``ev`` (physics.md section 3: the set-valued friction law decides
    stick or slip from the net force, seed 000 eq 21): the new contact state, the event kinds to record,
    and the jumps of V_c and of the presliding spring's extension d.

    fe_now : drive force [N] at the event; pFm, pFc, pdFc : the plugin forces on a shell at rest (zeros
    without a plugin; :func:`plugin_stick_terms`); abort : a plugin failed while they were computed
    (return before any jump). Returns (new shell state (< 0: ill-posed), contact, kind, kind2, V_c [m/s],
    d [m], friction work released [J] when a c_s = 0 patch starts sliding)."""
    compliant = p[I_KS] > 0.0
    kind = 0
    kind2 = 0
    e_fric = 0.0
    if ev == EV_FRONT_ON:
        contact = 1
        kind = K_FRONT_ON
    elif ev == EV_BACK_ON:
        contact = 2
        kind = K_BACK_ON
    elif ev == EV_FRONT_OFF:
        contact = 0
        kind = K_FRONT_OFF
    elif ev == EV_BACK_OFF:
        contact = 0
        kind = K_BACK_OFF
    new_shell = shell
    if compliant and ev == EV_SLIP_END and p[I_CS] == 0.0 and p[I_KAP] != 0.0:
        # c_s = 0 under tilt: the patch stops with k_s d at its level exactly (held_patch_rate), not at the
        # level plus the slide's rounding, which a breakaway equal to the level saw as an exit at once
        dsub = held_patch_extension(p, 1.0 if shell == FAST_POS else -1.0, xr)
    if compliant:
        if ev == EV_BREAK_POS or ev == EV_BREAK_NEG:
            new_shell = decide_patch(p, contact, xr, vr, Vc, dsub, fe_now, pFc)
        elif ev == EV_SLIP_END and tilt_factor(p, xr) == 0.0:
            # stopping where the tilt level is held at zero: nothing holds the patch
            new_shell = decide_patch(p, contact, xr, vr, Vc, dsub, fe_now, pFc)
        elif ev == EV_SLIP_END:
            # the patch stops with its force at the kinetic level (<= breakaway): it sticks; a force
            # that keeps rising past the breakaway is a break event of the stuck patch
            new_shell = PATCH_STICK
    elif ev == EV_FRONT_ON or ev == EV_BACK_ON or ev == EV_FRONT_OFF or ev == EV_BACK_OFF:
        if shell == STICK:
            new_shell = decide_shell(p, contact, xr, vr, fe_now, pFm, pFc, pdFc)
    elif ev == EV_BREAK_POS or ev == EV_BREAK_NEG:
        new_shell = decide_shell(p, contact, xr, vr, fe_now, pFm, pFc, pdFc)
    elif ev == EV_SLIP_END:
        Vc = 0.0
        new_shell = decide_shell(p, contact, xr, vr, fe_now, pFm, pFc, pdFc)
    elif ev == EV_FAST_ON:
        new_shell = FAST_POS if shell == SLIP_POS else FAST_NEG
    elif ev == EV_FAST_OFF:
        if p[I_VFAST] > 0.0:
            new_shell = SLIP_POS if shell == FAST_POS else SLIP_NEG
        else:
            Vc = 0.0
            new_shell = decide_shell(p, contact, xr, vr, fe_now, pFm, pFc, pdFc)
    if abort or new_shell < 0:
        return new_shell, contact, kind, kind2, Vc, dsub, e_fric
    if new_shell != shell and compliant:
        if new_shell == PATCH_STICK:
            kind2 = K_STICK
        elif shell == PATCH_STICK:
            kind2 = K_SLIP_FWD if new_shell == FAST_POS else K_SLIP_BWD
            if p[I_CS] == 0.0:
                # c_s = 0: the massless patch jumps to the kinetic balance k_s d = sgn L at once;
                # the released spring energy is dissipated at the patch
                dnew = held_patch_extension(p, 1.0 if new_shell == FAST_POS else -1.0, xr)
                e_fric = 0.5 * p[I_KS] * (dsub * dsub - dnew * dnew)
                dsub = dnew
        else:  # reversal without sticking
            kind2 = K_SLIP_FWD if new_shell == FAST_POS else K_SLIP_BWD
    elif new_shell != shell:
        if new_shell == STICK:
            kind2 = K_STICK
            Vc = 0.0
        elif (new_shell == SLIP_POS or new_shell == FAST_POS) and not (shell == SLIP_POS or shell == FAST_POS):
            kind2 = K_SLIP_FWD
        elif (new_shell == SLIP_NEG or new_shell == FAST_NEG) and not (shell == SLIP_NEG or shell == FAST_NEG):
            kind2 = K_SLIP_BWD
        if new_shell != STICK and shell == STICK:
            Vc = 0.0
    return new_shell, contact, kind, kind2, Vc, dsub, e_fric


@kernel
def mode_path(p, shell, plug, exact_general, eff_slip, xr, vr):
    """Which path advances shell state ``shell`` at (x_r [m], v_r [m/s]): the base closed form (one modal
    slot: a stuck shell, or a Coulomb slip without drag or tilt, ``eff_slip`` False), a general linear mode
    (drag, tilt, substrate compliance: eigen-decomposition), or neither (the adaptive segment: a speed
    law above V_min, a plugin force, or ``exact_general`` off). Returns (lin_base, lin_gen, general mode
    GM_*, its slip direction (+-1, 0), tilt level active, the mode's slot among the general modes 0-4).

    The tilt level is active where 1 + kappa x_r / G_1 > 0; on the zero itself (a mode starting at
    EV_TILT) the direction of x_r decides (physics.md section 3, tilt_friction)."""
    compliant = p[I_KS] > 0.0
    lin_base = not plug and (shell == STICK or ((shell == SLIP_POS or shell == SLIP_NEG) and not eff_slip))
    lin_gen = False
    gmode = GM_SLIP
    sgm = 0.0
    if not lin_base and exact_general and not plug:
        if shell == SLIP_POS or shell == SLIP_NEG:
            gmode = GM_SLIP
            sgm = 1.0 if shell == SLIP_POS else -1.0
            lin_gen = True
        elif compliant and shell == PATCH_STICK:
            gmode = GM_PSTICK
            lin_gen = True
        elif compliant and p[I_LAW] < 0.5:
            gmode = GM_PSLIDE
            sgm = 1.0 if shell == FAST_POS else -1.0
            lin_gen = True
    tilt_on = True
    mk = 0
    if lin_gen:
        if p[I_KAP] != 0.0:
            fac0 = 1.0 + p[I_KAP] * xr / p[I_G1]
            tilt_on = fac0 > 1e-13 or (fac0 > -1e-13 and p[I_KAP] * vr > 0.0)
        if gmode == GM_SLIP:
            mk = 0 if sgm > 0.0 else 1
        elif gmode == GM_PSTICK:
            mk = 2
        else:
            mk = 3 if sgm > 0.0 else 4
    return lin_base, lin_gen, gmode, sgm, tilt_on, mk


@kernel
def mode_events(p, contact, shell, lin_gen, gmode, sgm, tilt_on, coef, md, Om, tol_x, tol_v, tol_F, evc, evcode,
                evtol, cF, gwork):
    """Write the event functions of a linear mode as coefficient rows on its basis (``coef``, ``md``,
    ``Om``: :func:`setup_linear` or :func:`setup_general`) and return their number: the contact's
    on/off crossings of each constraint (gaps G_1, G_2), then for a base mode the breakaway of a
    stuck shell (|F_i| = P_b, scaled by the tilt) or the end of a slip and the V_fast crossing, and for
    a general mode (drag, tilt, compliance) those of :func:`general_events`. evcode and evtol [m,
    m/s or N] take each row's event code and root tolerance; cF the coefficients of F_i [N]
    (seed 000 eqs 19-21, physics.md section 3)."""
    K, Cd, F0 = contact_terms(p, contact)
    G1 = p[I_G1]
    G2 = p[I_G2]
    back = p[I_BACK] > 0.5
    ne = 0
    if contact == 0:
        for j in range(NB):
            evc[ne, j] = -coef[0, j]
        evc[ne, 4] += G1
        evcode[ne] = EV_FRONT_ON
        evtol[ne] = tol_x
        ne += 1
        if back:
            for j in range(NB):
                evc[ne, j] = coef[0, j]
            evc[ne, 4] += G2
            evcode[ne] = EV_BACK_ON
            evtol[ne] = tol_x
            ne += 1
    elif contact == 1:
        for j in range(NB):
            evc[ne, j] = coef[0, j]
        evc[ne, 4] -= G1
        evcode[ne] = EV_FRONT_OFF
        evtol[ne] = tol_x
        ne += 1
    else:
        for j in range(NB):
            evc[ne, j] = -coef[0, j]
        evc[ne, 4] -= G2
        evcode[ne] = EV_BACK_OFF
        evtol[ne] = tol_x
        ne += 1
    for j in range(NB):
        cF[j] = K * coef[0, j] + Cd * coef[1, j]
    cF[4] += F0
    if lin_gen:
        ne = general_events(p, gmode, sgm, tilt_on, coef, md, Om, evc, evcode, evtol, ne, tol_v, tol_F,
                            gwork)
    elif shell == STICK:
        if p[I_PB] < np.inf:
            for j in range(NB):
                evc[ne, j] = -cF[j]
                evc[ne + 1, j] = cF[j]
            if p[I_KAP] != 0.0:
                # tilt: breakaway P_b (1 + kappa x_r / G_1), linear in the state
                kq = p[I_PB] * p[I_KAP] / G1
                for j in range(NB):
                    evc[ne, j] += kq * coef[0, j]
                    evc[ne + 1, j] += kq * coef[0, j]
            evc[ne, 4] += p[I_PB]
            evc[ne + 1, 4] += p[I_PB]
            evcode[ne] = EV_BREAK_POS
            evcode[ne + 1] = EV_BREAK_NEG
            evtol[ne] = tol_F
            evtol[ne + 1] = tol_F
            ne += 2
    else:
        sg = 1.0 if shell == SLIP_POS else -1.0
        for j in range(NB):
            evc[ne, j] = sg * coef[3, j]
        evcode[ne] = EV_SLIP_END
        evtol[ne] = tol_v
        ne += 1
        if p[I_VFAST] < np.inf:
            for j in range(NB):
                evc[ne, j] = -sg * coef[3, j]
            evc[ne, 4] += p[I_VFAST]
            evcode[ne] = EV_FAST_ON
            evtol[ne] = tol_v
            ne += 1
    return ne


@kernel
def event_derivatives(ne, lin_gen, md, Om, evc, devc, ddevc, cF, dcF, ddcF):
    """The first and second time derivatives of the ne event rows and of F_i, as coefficient rows on
    the mode's basis (the event scan's bounds, :func:`locate_event`)."""
    if lin_gen:
        for e in range(ne):
            deriv_coefs(evc[e], md, Om, devc[e])
            deriv_coefs(devc[e], md, Om, ddevc[e])
        deriv_coefs(cF, md, Om, dcF)
        deriv_coefs(dcF, md, Om, ddcF)
    else:
        for e in range(ne):
            deriv_base(evc[e], md, Om, devc[e])
            deriv_base(devc[e], md, Om, ddevc[e])
        deriv_base(cF, md, Om, dcF)
        deriv_base(dcF, md, Om, ddcF)


@kernel
def mode_state(coef, lin_gen, dsub, B):
    """Return the state (x_r [m], v_r [m/s], X_c [m], V_c [m/s], d [m]) of a linear mode from its closed
    form, given B, the basis at that time (:func:`locate_event` returns it at the segment's end); a base
    mode keeps the substrate's extension dsub [m]."""
    base = not lin_gen
    d = mode_dot(base, coef[R_D], B) if lin_gen else dsub
    return mode_dot(base, coef[0], B), mode_dot(base, coef[1], B), mode_dot(base, coef[2], B), \
        mode_dot(base, coef[3], B), d


@kernel
def mode_samples(coef, md, Om, s, tau_ev, sample_times, j_sample, t_shift, rec_t0, contact, seg_stick, K, Cd, F0,
                 samples, Bs):
    """Write the trajectory samples due within a linear mode, at phases [s, s + tau_ev) [s], from its closed
    form: sample j is at sample_times[j] - t_shift [s] into this period (rec_t0 [s]: the record's start,
    added to the time column). Returns the index of the next sample due."""
    n_samples = sample_times.shape[0]
    while j_sample < n_samples:
        ts = sample_times[j_sample] - t_shift
        if ts >= s + tau_ev:
            break
        tt = ts - s
        if tt < 0.0:
            tt = 0.0
        basis(tt, s, md, Om, Bs)
        sx = dot9(coef[0], Bs)
        sv = dot9(coef[1], Bs)
        sXc = dot9(coef[2], Bs)
        sVc = dot9(coef[3], Bs)
        row = samples[j_sample]
        row[S_T] = rec_t0 + sample_times[j_sample]
        row[S_XM] = sXc + sx
        row[S_XC] = sXc
        row[S_VM] = sVc + sv
        row[S_VC] = sVc
        row[S_XR] = sx
        row[S_CONTACT] = contact
        row[S_STICK] = 1.0 if seg_stick else 0.0
        row[S_FI] = K * sx + Cd * sv + F0
        j_sample += 1
    return j_sample


@kernel
def adaptive_segment(p, contact, shell, s, tau_end, fe_level, period, T, xr, vr, Xc, Vc, dsub,
                     rtol, max_steps, recording, do_energy, maxF, t_maxF, sample_times, n_transient, samples,
                     j_sample, rec_t0, seg_stick, plug, pq, pfail, energy, y, y1, yt, k1, k7, rc, KD, yd, gab):
    """Advance one mode on the adaptive path (DOP853 with dense output, tolerance ``rtol``) from phase
    ``s`` [s] for at most ``tau_end`` [s], or to its first event: a speed-dependent law above V_min
    (seed 000 eqs 22-23, physics.md section 3), a nearly defective general mode, or any mode with a
    user plugin force.

    Events are located on the dense output by bisection (grazing contacts by the interpolant's
    minimum); the peak |F_i| of the segment updates (maxF, t_maxF) [N, s]; trajectory samples due
    within the segment are written from the dense output; with do_energy the segment's work and
    dissipation are added to ``energy``. y .. yd, rc, KD are work arrays (NY, (8, NY), (DOP_NK, NY)).

    Returns (status, status_time_s, event code (EV_NONE at tau_end), tau_event_s, x_r, v_r, X_c, V_c,
    d, maxF, t_maxF, next sample index)."""
    status = STATUS_OK
    status_t = 0.0
    ev = EV_NONE
    K, Cd, F0 = contact_terms(p, contact)
    Mm = p[I_MM]
    Mc = p[I_MC]
    f = p[I_F]
    harmonic = p[I_WAVE] < 0.5
    compliant = p[I_KS] > 0.0
    tol_x = 1e-13 * p[I_XS]
    n_samples = sample_times.shape[0]
    sg = 1.0 if (shell == FAST_POS or shell == SLIP_POS) else -1.0
    # a shell stuck on a rigid wall comes here only with a plugin force: it is held (V_c = 0).
    # With a plugin the right-hand side and events are seg_rhs / seg_event_value; without, rk_rhs /
    # rk_event_value are called directly: a plugin call inside them keeps LLVM from inlining
    # them here (measured: the speed-law slips 40 % slower), so the branch sits at the call sites.
    held = shell == STICK
    t0 = period * T
    # a slip (not fast) mode here is a general linear mode with nearly defective eigenvectors:
    # its events are the slip's end (V_c = 0) and V_min
    rk_slow = shell == SLIP_POS or shell == SLIP_NEG
    vlo = 0.0 if rk_slow else p[I_VFAST]
    vhi = p[I_VFAST] if rk_slow else np.inf
    w0 = math.sqrt(K * (1.0 / Mm + 1.0 / Mc))
    wmax = w0
    if harmonic:
        wmax = max(wmax, TWO_PI * f)
    if compliant:
        if shell == PATCH_STICK:
            sg = 0.0
            wmax = max(wmax, math.sqrt((K + p[I_KS]) / Mc + K / Mm))
        elif p[I_CS] > 0.0:
            wmax = max(wmax, p[I_KS] / p[I_CS])
    hmax = TWO_PI / wmax / 2.0
    # stage states beyond the mechanical state only where the right-hand side reads d (dop853_stages)
    full = compliant
    # a speed-law slip above V_min that ends at its V_min event: the law continued below V_min in the
    # right-hand side (slip_level); not where the segment itself spans V_min: vlo below it, or a patch
    # sliding on a compliant wall, which runs on to the patch's stop (rk_event_value)
    cont = p[I_LAW] > 0.5 and (shell == FAST_POS or shell == FAST_NEG) and vlo >= p[I_VMIN] and not compliant
    y[0] = xr
    y[1] = vr
    y[2] = Vc
    y[3] = Xc
    for i in range(4, NY):
        y[i] = 0.0
    y[8] = dsub
    tau = 0.0
    hh = hmax * 0.1
    if plug:
        seg_rhs(p, contact, sg, held, s, t0, fe_level, y, k1, pq, pfail, cont)
    else:
        rk_rhs(p, contact, sg, s, fe_level, y, k1, cont)
    atol_x = rtol * p[I_XS]
    atol_v = rtol * p[I_VS]
    if cont and k1[2] != 0.0:
        # a speed law's derivatives grow as V^-k towards V_min: the first step is at most the time the
        # slip speed takes to change by a tenth (fewer rejected first steps: 11-30 -> 0-7 per period)
        hh = min(hh, 0.1 * abs(y[2] / k1[2]))
    nsteps = 0
    rk_rej = False
    rk_err_old = 0.0
    rk_h_old = 1.0
    Fa = K * y[0] + Cd * y[1] + F0
    dFa = K * k1[0] + Cd * k1[1]
    # on a compliant wall, the patch's events (j = 2, 3: its stop, or its breakaway + / -): values and slopes
    # at the step's start (gab[j - 2], gab[j]) and end (gab[j + 2], gab[j + 4]), for a dip below zero and
    # back inside one step; kept in an array, off the loop's registers (a rigid wall's slip end and V_min
    # are not checked so: that cost the speed-law runs about 10 %)
    for j in range(2, 4 if compliant else 2):
        gab[j - 2] = rk_event_value(p, contact, sg, vlo, vhi, j, y)
        gab[j] = rk_event_slope(p, contact, sg, vlo, vhi, j, y, k1, gab[j - 2], 1e-6 * hmax, yd)
        gab[j + 2] = gab[j - 2]
        gab[j + 4] = gab[j]
    while True:
        nsteps += 1
        if nsteps > max_steps:
            status = STATUS_RKFAIL
            status_t = period * T + s + tau
            break
        hh = min(hh, hmax, tau_end - tau)
        sa = s + tau
        dop853_step(p, contact, sg, sa, hh, fe_level, y, k1, KD, yt, y1, k7, plug, held, t0, pq, pfail, full, cont)
        if pfail[0] != 0.0:
            status = STATUS_PLUGIN
            status_t = t0 + sa
            break
        err = dop853_error(KD, hh, y, y1, rtol, atol_x, atol_v)
        if err > 1.0:
            hh *= max(0.2, 0.9 * err ** -RK_ORDER_EXP)
            rk_rej = True
            continue
        # dense output: computed when a step needs it (events, F_i extrema, samples)
        rc_ok = False
        # events
        th_ev = 2.0
        e_ev = -1
        for j in range(4):
            if plug:
                g1 = seg_event_value(p, contact, sg, held, vlo, vhi, j, y1, t0 + sa + hh, pq, pfail)
            else:
                g1 = rk_event_value(p, contact, sg, vlo, vhi, j, y1)
            lo = 0.0
            hi = -1.0
            if g1 < 0.0:
                hi = 1.0
            elif j < 2 and g1 != 1.0:
                # grazing: the contact function's derivative is +-v_r
                dsa = k1[0] if ((contact == 0 and j == 1) or contact == 1) else -k1[0]
                dsb = k7[0] if ((contact == 0 and j == 1) or contact == 1) else -k7[0]
                if dsa < 0.0 and dsb > 0.0:
                    if not rc_ok:
                        dop853_dense(p, contact, sg, sa, hh, fe_level, y, y1, KD, yt, rc, plug, held, t0, pq, pfail,
                                     full, cont)
                        rc_ok = True
                    a_ = 0.0
                    b_ = 1.0
                    for _ in range(60):
                        mth = 0.5 * (a_ + b_)
                        # derivative from the interpolant (central difference)
                        dense_eval(rc, min(mth + 1e-7, 1.0), yd)
                        gp = rk_event_value(p, contact, sg, vlo, vhi, j, yd)
                        dense_eval(rc, max(mth - 1e-7, 0.0), yd)
                        gm_ = rk_event_value(p, contact, sg, vlo, vhi, j, yd)
                        if gp - gm_ < 0.0:
                            a_ = mth
                        else:
                            b_ = mth
                    dense_eval(rc, 0.5 * (a_ + b_), yd)
                    if rk_event_value(p, contact, sg, vlo, vhi, j, yd) < -tol_x:
                        hi = 0.5 * (a_ + b_)
            elif compliant and j >= 2 and g1 != 1.0 and not plug:
                # a minimum of the patch's speed or force inside the step: the slope at the step's ends from
                # the stages (finite difference along y'); one minimum (slope - to +) or, where twin_reach
                # allows it, a maximum and a minimum (slope of one sign at both ends)
                ga_ = gab[j - 2]
                dga_ = gab[j]
                dgb_ = rk_event_slope(p, contact, sg, vlo, vhi, j, y1, k7, g1, 1e-6 * hmax, yd)
                gab[j + 2] = g1
                gab[j + 4] = dgb_
                tol_j = TOL_V_REL * (p[I_FS] if sg == 0.0 else p[I_VS])
                if (dga_ < 0.0 < dgb_) or (ga_ >= 0.0 and twin_reach(ga_, g1, dga_, dgb_, hh) < -tol_j):
                    if not rc_ok:
                        dop853_dense(p, contact, sg, sa, hh, fe_level, y, y1, KD, yt, rc, plug, held, t0, pq, pfail,
                                     full, cont)
                        rc_ok = True
                    hi = rk_dense_dip(p, contact, sg, vlo, vhi, j, rc, tol_j, yd)
            if hi > 0.0:
                if not rc_ok:
                    dop853_dense(p, contact, sg, sa, hh, fe_level, y, y1, KD, yt, rc, plug, held, t0, pq, pfail,
                                 full, cont)
                    rc_ok = True
                a_ = lo
                b_ = hi
                for _ in range(80):
                    mth = 0.5 * (a_ + b_)
                    dense_eval(rc, mth, yd)
                    if plug:
                        gmid = seg_event_value(p, contact, sg, held, vlo, vhi, j, yd, t0 + sa + mth * hh,
                                               pq, pfail)
                    else:
                        gmid = rk_event_value(p, contact, sg, vlo, vhi, j, yd)
                    if gmid >= 0.0:
                        a_ = mth
                    else:
                        b_ = mth
                    if b_ - a_ < 1e-16:
                        break
                if b_ < th_ev:
                    th_ev = b_
                    e_ev = j
        th_stop = 1.0 if e_ev < 0 else th_ev
        if th_stop < 1.0:
            dense_eval(rc, th_stop, y1)
        # F_i extrema
        if recording:
            Fb = K * y1[0] + Cd * y1[1] + F0
            dFb = K * k7[0] + Cd * k7[1]
            if dFa * dFb < 0.0:
                if not rc_ok:
                    dop853_dense(p, contact, sg, sa, hh, fe_level, y, y1, KD, yt, rc, plug, held, t0, pq, pfail,
                                 full, cont)
                    rc_ok = True
                a_ = 0.0
                b_ = th_stop
                sgnF = 1.0 if dFa > 0 else -1.0
                for _ in range(60):
                    m1 = a_ + (b_ - a_) * 0.381966
                    m2 = a_ + (b_ - a_) * 0.618034
                    dense_eval(rc, m1, yd)
                    f1 = sgnF * (K * yd[0] + Cd * yd[1] + F0)
                    dense_eval(rc, m2, yd)
                    f2 = sgnF * (K * yd[0] + Cd * yd[1] + F0)
                    if f1 > f2:
                        b_ = m2
                    else:
                        a_ = m1
                dense_eval(rc, 0.5 * (a_ + b_), yd)
                Fm = abs(K * yd[0] + Cd * yd[1] + F0)
                if Fm > maxF:
                    maxF = Fm
                    t_maxF = period * T + sa + 0.5 * (a_ + b_) * hh
            if abs(Fb) > maxF:
                maxF = abs(Fb)
                t_maxF = period * T + sa + th_stop * hh
            Fa = Fb
            dFa = dFb
        # samples
        if recording and n_samples > 0:
            while j_sample < n_samples:
                ts = sample_times[j_sample] - (period - n_transient) * T
                if ts >= sa + th_stop * hh:
                    break
                th = (ts - sa) / hh
                if th < 0.0:
                    th = 0.0
                if not rc_ok:
                    dop853_dense(p, contact, sg, sa, hh, fe_level, y, y1, KD, yt, rc, plug, held, t0, pq, pfail,
                                 full, cont)
                    rc_ok = True
                dense_eval(rc, th, yd)
                row = samples[j_sample]
                row[S_T] = rec_t0 + sample_times[j_sample]
                row[S_XM] = yd[3] + yd[0]
                row[S_XC] = yd[3]
                row[S_VM] = yd[2] + yd[1]
                row[S_VC] = yd[2]
                row[S_XR] = yd[0]
                row[S_CONTACT] = contact
                row[S_STICK] = 1.0 if seg_stick else 0.0
                row[S_FI] = K * yd[0] + Cd * yd[1] + F0
                j_sample += 1
        if e_ev >= 0:
            tau += th_stop * hh
            for i in range(NY):
                y[i] = y1[i]
            if held and e_ev >= 2:
                ev = EV_BREAK_POS if e_ev == 2 else EV_BREAK_NEG
            elif compliant and e_ev >= 2:
                if sg == 0.0:
                    ev = EV_BREAK_POS if e_ev == 2 else EV_BREAK_NEG
                else:
                    ev = EV_SLIP_END
            elif e_ev == 2:
                ev = EV_SLIP_END if rk_slow else EV_FAST_OFF
            elif e_ev == 3:
                ev = EV_FAST_ON
            elif contact == 0:
                ev = EV_FRONT_ON if e_ev == 0 else EV_BACK_ON
            elif contact == 1:
                ev = EV_FRONT_OFF
            else:
                ev = EV_BACK_OFF
            break
        tau += hh
        for i in range(NY):
            y[i] = y1[i]
            k1[i] = k7[i]
        if compliant:
            for j in range(4):
                gab[j] = gab[j + 4]
        if tau >= tau_end:
            break
        fac = rk_step_factor(err, rk_rej, rk_err_old, hh / rk_h_old)
        rk_err_old = max(err, 1e-4)
        rk_h_old = hh
        hh *= fac
        rk_rej = False
    if status != STATUS_OK:
        return status, status_t, ev, tau, xr, vr, Xc, Vc, dsub, maxF, t_maxF, j_sample
    tau_ev = tau if ev != EV_NONE else tau_end
    xr = y[0]
    vr = y[1]
    Vc = y[2]
    Xc = y[3]
    dsub = y[8]
    if compliant and sg != 0.0 and p[I_CS] == 0.0 and p[I_KAP] != 0.0:
        # c_s = 0 under tilt: k_s d = sg L(0, x_r) is algebraic (held_patch_rate); drop the integration's
        # drift, which at a level held at zero left a force at rounding level for the stick test
        dsub = held_patch_extension(p, sg, xr)
    if recording and do_energy:
        energy[E_DRIVE] += y[4]
        energy[E_DAMP] += y[5]
        energy[E_CONTACT] += y[6]
        energy[E_FRIC] += y[7]
        energy[E_PLUGIN] += y[9]
    return status, status_t, ev, tau_ev, xr, vr, Xc, Vc, dsub, maxF, t_maxF, j_sample


@njit(cache=True, nogil=True)
def run_core(p, opts, state0, n_transient, n_record, sample_dt, n_samples, ev_cap):
    """Run n_transient + n_record excitation periods from state0; return the records.

    Trajectory samples at t = j sample_dt (j < n_samples) after the transient; see
    :func:`run_core_at` for the records. Releases the GIL (``nogil``), so that a long run can go on in a
    worker thread while the main thread takes Ctrl-C (:func:`capsule_cli.interrupts.call_interruptibly`);
    the mode decomposition's object-mode block takes the GIL back for its few lines.
    """
    times = np.arange(n_samples) * sample_dt
    return run_core_at(p, opts, state0, n_transient, n_record, times, ev_cap)


@njit(cache=True)
def run_core_at(p, opts, state0, n_transient, n_record, sample_times, ev_cap):
    """Run n_transient + n_record excitation periods from state0; return the records.

    sample_times : ascending times [s] after the transient at which the trajectory is sampled
    exactly (closed form, or the adaptive segment's dense output).

    state0 = [x_r, v_r, X_c, V_c] [m, m/s] at phase 0 (time 0).
    ev_cap : the event list's capacity (> 0: STATUS_EVCAP past it), 0 for no events, < 0 for as many as
    the run has: the list starts at EV_CAP_START + EV_CAP_PER_PERIOD events per recorded period (at most
    EV_CAP_FIRST_MAX; np.empty: no cost for room not used; -ev_cap events for ev_cap < -1) and, should the
    run fill it, the run is repeated
    with room for 1.25 times the events its rate so far implies (at least four times as much). The list is
    not grown in place: an array variable rebound inside the segment loop cost numba an atomic
    reference-count increment and decrement at each segment, 8 % of the benchmark's time.
    Returns (status, status_time_s, samples, n_samples_written, events, n_events,
    periods, energy, final_state) where final_state = [x_r, v_r, X_c, V_c, contact, shell,
    periods integrated (fewer than n_transient + n_record when a settled transient was cut, settle_tol,
    and its recorded periods filled from one settled orbit, :func:`fill_orbit`)].
    """
    if ev_cap >= 0:
        return run_segments(p, opts, state0, n_transient, n_record, sample_times, ev_cap,
                            np.empty((ev_cap if ev_cap > 0 else 1, 2)))
    cap = min(EV_CAP_START + EV_CAP_PER_PERIOD * max(n_record, 0), EV_CAP_FIRST_MAX) if ev_cap == -1 else -ev_cap
    T = 1.0 / p[I_F]
    while True:
        r = run_segments(p, opts, state0, n_transient, n_record, sample_times, ev_cap, np.empty((cap, 2)))
        if r[0] != STATUS_EVGROW:
            return r
        # r[1]: the time the list filled; the recorded time so far implies the rate
        t_rec = max(r[1] - n_transient * T, 1e-3 * T)
        need = 1.25 * cap * (max(n_record, 1) * T) / t_rec + EV_CAP_START
        cap = max(4 * cap, int(min(need, 1e12)))


@njit(cache=True)
def run_segments(p, opts, state0, n_transient, n_record, sample_times, ev_cap, events):
    """The body of :func:`run_core_at`, with the event list given (events: (capacity, 2)); a full list
    ends the run with STATUS_EVGROW when ev_cap < 0 (the caller repeats it with more room), else it
    sets STATUS_EVCAP and records no more events."""
    nper = opts[O_NPER]
    do_energy = opts[O_ENERGY] > 0.5
    zeno_max = int(opts[O_ZENO])
    exact_general = opts[O_EXACT] > 0.5
    max_steps = int(opts[O_MAXSTEPS])
    rtol = opts[O_RTOL]
    # settled transient: end it early once the phase-0 state repeats (not with a plugin force, which
    # may depend on time and position)
    settle = opts[O_SETTLE] > 0.0 and p[I_PLUG] < 0.5 and n_transient > 0
    settle_tol = opts[O_SETTLE]
    if p[I_LAW] > 0.5:
        settle_tol = max(settle_tol, SETTLE_RTOL_FRACTION * rtol)
    settle_x = settle_tol * p[I_XS]
    settle_v = settle_tol * p[I_VS]
    f = p[I_F]
    T = 1.0 / f
    harmonic = p[I_WAVE] < 0.5
    DT = p[I_DUTY] * T
    tol_x = 1e-13 * p[I_XS]
    tol_v = TOL_V_REL * p[I_VS]
    tol_F = 1e-13 * p[I_FS]

    n_samples = sample_times.shape[0]
    samples = np.zeros((n_samples, N_SAMPLE_COLS))
    rec_events = ev_cap != 0
    periods = np.zeros((max(n_record, 0), N_PERIOD_COLS))
    energy = np.zeros(N_ENERGY)
    final = np.zeros(N_FINAL)
    n_skipped = 0  # periods skipped once settled (settle_tol)
    # a settled orbit (q periods) also fills the recorded periods once one orbit of them is integrated, in
    # runs that record no samples, events or energy (maps and sweeps): the rest repeat it
    orbit_q = np.int64(0)
    hist = np.zeros((SETTLE_ORBIT_MAX + 1, 6))  # phase-0 states of the last periods (settled transient)
    Xc_hist = np.zeros(SETTLE_ORBIT_MAX + 1)

    coef = np.zeros((N_ROWS, NB))
    md = np.zeros(8)
    evc = np.zeros((6, NB))
    devc = np.zeros((6, NB))
    ddevc = np.zeros((6, NB))
    evcode = np.zeros(6, dtype=np.int64)
    evtol = np.zeros(6)
    cF = np.zeros(NB)
    dcF = np.zeros(NB)
    ddcF = np.zeros(NB)
    negc = np.zeros(NB)
    negdc = np.zeros(NB)
    B = np.zeros(NB)
    Bs = np.zeros(NB)
    Ba = np.zeros(NB)
    Bev = np.zeros(NB)
    Rsc = np.zeros(LOCATE_WORK)
    Rsc[12] = -1.0
    ga = np.zeros(6)
    dga = np.zeros(6)
    dddc = np.zeros(NB)
    # general linear modes: the system and, per mode (contact x slip/patch state x tilt level), its
    # eigen-decomposition, computed once per run
    gA = np.zeros((N_ROWS, N_ROWS))
    gb0 = np.zeros(N_ROWS)
    gbc = np.zeros(N_ROWS)
    gu0 = np.zeros(N_ROWS)
    gwork = np.zeros(NB)
    eff_slip = p[I_CV] > 0.0 or p[I_KAP] != 0.0
    ncache = N_GM_KEYS if (eff_slip or p[I_KS] > 0.0) else 1
    c_done = np.zeros(ncache, dtype=np.int64)
    c_ok = np.zeros(ncache, dtype=np.int64)
    c_nc = np.zeros(ncache, dtype=np.int64)
    c_nq = np.zeros(ncache, dtype=np.int64)
    c_scale = np.zeros(ncache)
    c_slow = np.zeros(ncache)
    c_core = np.zeros((ncache, 4), dtype=np.int64)
    c_quad = np.zeros((ncache, N_ROWS), dtype=np.int64)
    c_lam = np.zeros((ncache, 4), dtype=np.complex128)
    c_V = np.zeros((ncache, 4, 4), dtype=np.complex128)
    c_Vi = np.zeros((ncache, 4, 4), dtype=np.complex128)
    c_mdt = np.zeros((ncache, 8))
    c_fneig = np.zeros((ncache, 4), dtype=np.int64)
    # RK work arrays
    y = np.zeros(NY)
    y1 = np.zeros(NY)
    yt = np.zeros(NY)
    k1 = np.zeros(NY)
    k7 = np.zeros(NY)
    rc = np.zeros((8, NY))
    KD = np.zeros((DOP_NK, NY))
    yd = np.zeros(NY)
    gab = np.zeros(8)
    # user plugin force: the row's plugin slots (a contiguous copy the plugin reads through a pointer)
    # and the failure latch
    plug = p[I_PLUG] > 0.5
    pq = p[I_PLUG_FN:].copy()  # [address, n, parameters]: contiguous, read by the plugin through a pointer
    pfail = np.zeros(1)

    xr = state0[0]
    vr = state0[1]
    Xc = state0[2]
    Vc = state0[3]
    contact = contact_of(p, xr)
    s = 0.0
    fe0 = drive_force(p, 0.0, p[I_PD])
    compliant = p[I_KS] > 0.0
    dsub = 0.0  # presliding spring extension X_c - X_p (substrate compliance), relaxed at the start
    if compliant:
        Fc0 = 0.0
        if plug:
            _, Fc0 = plugin_force(pq, pfail, 0.0, xr, vr, Xc, Vc)
        shell = decide_patch(p, contact, xr, vr, Vc, dsub, fe0, Fc0)
        if pfail[0] != 0.0:
            return STATUS_PLUGIN, 0.0, samples, 0, events, 0, periods, energy, final
        if shell < 0:
            return STATUS_ILLPOSED, 0.0, samples, 0, events, 0, periods, energy, final
    elif Vc == 0.0:
        Fm0, Fc0, dFc0 = 0.0, 0.0, 0.0
        if plug:
            Fm0, Fc0, dFc0 = plugin_stick_terms(p, pq, pfail, 0.0, contact, xr, vr, Xc, fe0)
        shell = decide_shell(p, contact, xr, vr, fe0, Fm0, Fc0, dFc0)
        if pfail[0] != 0.0:
            return STATUS_PLUGIN, 0.0, samples, 0, events, 0, periods, energy, final
        if shell < 0:
            return STATUS_ILLPOSED, 0.0, samples, 0, events, 0, periods, energy, final
    else:
        fast = abs(Vc) >= p[I_VFAST]
        if Vc > 0:
            shell = FAST_POS if fast else SLIP_POS
        else:
            shell = FAST_NEG if fast else SLIP_NEG

    n_total = n_transient + n_record
    # np.int64(0), not 0, here and for orbit_q and settled_orbit's k: a literal 0 reaching a callee is typed
    # Literal[int](0) and compiles it (adaptive_segment, mode_samples, ...) twice in one process (measured once,
    # cold: a first simulate 73.9 s instead of 80.6 s)
    period = np.int64(0)
    n_ev = 0
    j_sample = np.int64(0)
    status = STATUS_OK
    status_t = 0.0
    zeno_count = 0
    if settle:
        Xc_hist[0] = Xc
        settled_orbit(hist, np.int64(0), xr, vr, Vc, dsub, contact, shell, settle_x, settle_v)
    # period accumulators
    Xc_start = Xc
    n_front = 0
    n_back = 0
    maxF = -1.0
    t_maxF = 0.0
    stick_time = 0.0
    n_stick = 0
    if n_record > 0 and n_transient == 0:
        open_period(periods[0], xr, vr, Vc)
    E_at_record = stored_energy(p, xr, vr, Vc) + 0.5 * p[I_KS] * dsub * dsub if n_transient == 0 else 0.0
    energy[E_START] = E_at_record
    rec_t0 = n_transient * T
    if n_transient == 0 and n_record > 0 and not harmonic and rec_events:
        events[0, 0] = 0.0
        events[0, 1] = K_DRIVE_ON
        n_ev = 1

    while period < n_total:
        recording = period >= n_transient
        # segment boundary and drive level
        if harmonic:
            s_end = T
            fe_level = 0.0
        else:
            if s < DT:
                s_end = DT
                fe_level = p[I_PD]
            else:
                s_end = T
                fe_level = 0.0
        tau_end = s_end - s
        ev = EV_NONE
        tau_ev = tau_end
        K, Cd, F0 = contact_terms(p, contact)
        seg_stick = shell == STICK or shell == PATCH_STICK
        Xc_seg0 = Xc

        # which path: the base closed form (one modal slot), a general linear mode (effects: drag,
        # tilt, substrate compliance; eigen-decomposition), or the adaptive segment (speed law above
        # V_min, literal law, or a general mode whose eigenvectors are nearly defective)
        # (a user plugin force makes every mode nonlinear: all go through the adaptive segment)
        lin_base, lin_gen, gmode, sgm, tilt_on, mk = mode_path(p, shell, plug, exact_general, eff_slip, xr, vr)
        if lin_gen:
            key = contact * 10 + mk * 2 + (0 if tilt_on else 1)
            mode_system(p, contact, gmode, sgm, tilt_on, fe_level, gA, gb0, gbc)
            if c_done[key] == 0:
                nc_, nq_, ok_, sc_, sl_ = mode_decompose(gA, c_core[key], c_quad[key], c_lam[key], c_V[key],
                                                    c_Vi[key], c_mdt[key], c_fneig[key])
                c_done[key] = 1
                c_ok[key] = 1 if ok_ else 0
                c_nc[key] = nc_
                c_nq[key] = nq_
                c_scale[key] = sc_
                c_slow[key] = sl_
            lin_gen = c_ok[key] == 1
        if lin_base or lin_gen:
            # ---------------- linear closed-form segment
            if lin_base:
                wmax, Om = setup_linear(p, contact, shell, s, xr, vr, Xc, Vc, fe_level, coef, md)
                coef[R_D, B_ONE] = dsub
            else:
                Om = TWO_PI * f if harmonic else 0.0
                gu0[R_XR] = xr
                gu0[R_VR] = vr
                gu0[R_XC] = Xc
                gu0[R_VC] = Vc
                gu0[R_D] = dsub
                setup_general(gA, gb0, gbc, Om, s, gu0, c_core[key], c_nc[key], c_quad[key], c_nq[key],
                              c_lam[key], c_V[key], c_Vi[key], c_mdt[key], c_fneig[key], coef, md, gwork)
                wmax = max(c_scale[key], Om)
            h = TWO_PI / wmax / nper
            # scan cells: from h (the fastest mode) doubling to h_slow (a fast real mode has decayed)
            h_slow = h
            if lin_gen:
                h_slow = TWO_PI / max(c_slow[key], Om, 1e-300) / nper
                h_slow = min(max(h_slow, h), tau_end)
            ne = mode_events(p, contact, shell, lin_gen, gmode, sgm, tilt_on, coef, md, Om, tol_x, tol_v, tol_F,
                             evc, evcode, evtol, cF, gwork)
            event_derivatives(ne, lin_gen, md, Om, evc, devc, ddevc, cF, dcF, ddcF)
            ev, tau_ev, maxF, t_maxF = locate_event(evc, devc, ddevc, evcode, evtol, ne, cF, dcF, ddcF, md, Om,
                                                    s, tau_end, h, h_slow, recording, maxF, t_maxF, period * T,
                                                    Rsc, Bev, not lin_gen)
            xr1, vr1, Xc1, Vc1, d1 = mode_state(coef, lin_gen, dsub, Bev)
            if recording:
                F1 = abs(K * xr1 + Cd * vr1 + F0)
                if F1 > maxF:
                    maxF = F1
                    t_maxF = period * T + s + tau_ev
            if recording and n_samples > 0:
                j_sample = mode_samples(coef, md, Om, s, tau_ev, sample_times, j_sample, (period - n_transient) * T,
                                        rec_t0, contact, seg_stick, K, Cd, F0, samples, Bs)
            if recording and do_energy:
                gl_energy(p, coef, contact, shell, s, tau_ev, h, h_slow, md, Om, fe_level, Bs, energy)
                if lin_gen:
                    gl_friction(p, coef, md, Om, s, tau_ev, h, h_slow, gmode, sgm, tilt_on, gwork, Bs, energy)
                elif shell != STICK:
                    energy[E_FRIC] += p[I_L0] * abs(Xc1 - Xc_seg0)
            xr = xr1
            vr = vr1
            Xc = Xc1
            Vc = 0.0 if shell == STICK else Vc1
            dsub = d1
        else:
            # ---------------- adaptive segment: speed-dependent law above V_min (DOP853, dense output)
            status, status_t, ev, tau_ev, xr, vr, Xc, Vc, dsub, maxF, t_maxF, j_sample = adaptive_segment(
                p, contact, shell, s, tau_end, fe_level, period, T, xr, vr, Xc, Vc, dsub, rtol, max_steps,
                recording, do_energy, maxF, t_maxF, sample_times, n_transient, samples, j_sample, rec_t0,
                seg_stick, plug, pq, pfail, energy, y, y1, yt, k1, k7, rc, KD, yd, gab)
            if status != STATUS_OK:
                break

        # ---------------- bookkeeping of the segment
        if recording and seg_stick:
            stick_time += tau_ev
        if ev == EV_NONE:
            s = s_end
            zeno_count = 0
        else:
            s = s + tau_ev
            if tau_ev <= 1e-12 * T:
                zeno_count += 1
                if zeno_count > zeno_max:
                    status = STATUS_ZENO
                    status_t = period * T + s
                    break
            else:
                zeno_count = 0
        t_glob = period * T + s
        if ev == EV_FRONT_ON or ev == EV_BACK_ON:
            if recording:
                if ev == EV_FRONT_ON:
                    n_front += 1
                else:
                    n_back += 1
        # the plugin force on a shell at rest, counted in the stick test (zeros without a plugin)
        fe_now = drive_force(p, s, fe_level)
        pFm, pFc, pdFc = 0.0, 0.0, 0.0
        if plug and ev != EV_NONE:
            c_new = contact
            if ev == EV_FRONT_ON:
                c_new = 1
            elif ev == EV_BACK_ON:
                c_new = 2
            elif ev == EV_FRONT_OFF or ev == EV_BACK_OFF:
                c_new = 0
            if compliant:
                _, pFc = plugin_force(pq, pfail, t_glob, xr, vr, Xc, Vc)
            else:
                pFm, pFc, pdFc = plugin_stick_terms(p, pq, pfail, t_glob, c_new, xr, vr, Xc, fe_now)
        new_shell, contact, kind, kind2, Vc, dsub, e_fric = shell_transition(
            p, ev, shell, contact, xr, vr, Vc, dsub, fe_now, pFm, pFc, pdFc, pfail[0] != 0.0)
        if pfail[0] != 0.0:
            status = STATUS_PLUGIN
            status_t = t_glob
            break
        if new_shell < 0:
            status = STATUS_ILLPOSED
            status_t = t_glob
            break
        if recording:
            if kind2 == K_STICK:
                n_stick += 1
            if do_energy:
                energy[E_FRIC] += e_fric
        shell = new_shell
        if ev == EV_NONE and not harmonic:
            kind = K_DRIVE_OFF if s_end == DT and s_end < T else 0
        if recording and rec_events and (kind > 0 or kind2 > 0):
            for kk in (kind, kind2):
                if kk > 0:
                    if n_ev >= events.shape[0]:
                        status = STATUS_EVGROW if ev_cap < 0 else STATUS_EVCAP
                        status_t = t_glob
                    if n_ev < events.shape[0]:
                        events[n_ev, 0] = t_glob
                        events[n_ev, 1] = kk
                        n_ev += 1
            if status == STATUS_EVGROW:
                break
        # ---------------- period end
        if ev == EV_NONE and s_end == T:
            if recording:
                close_period(periods[period - n_transient], Xc_start, Xc, n_front, n_back, maxF, t_maxF,
                             stick_time / T, n_stick)
            period += 1
            s = 0.0
            Xc_start = Xc
            n_front = 0
            n_back = 0
            maxF = -1.0
            stick_time = 0.0
            n_stick = 0
            if settle and period < n_transient:
                Xc_hist[period % Xc_hist.shape[0]] = Xc
                q = settled_orbit(hist, period, xr, vr, Vc, dsub, contact, shell, settle_x, settle_v)
                if q > 0:
                    # skip whole orbits of the rest of the transient; the shell advances by the orbit's
                    # displacement each time (the recorded periods start at the same phase of the orbit)
                    m = (n_transient - period) // q
                    if m > 0:
                        Xc += m * (Xc - Xc_hist[(period - q) % Xc_hist.shape[0]])
                        period += m * q
                        n_skipped += m * q
                        Xc_start = Xc
                        settle = False
                        if n_samples == 0 and not rec_events and not do_energy:
                            orbit_q = q
            elif orbit_q > 0 and period - n_transient >= orbit_q and (n_total - period) % orbit_q == 0 \
                    and period < n_total:
                # one orbit recorded since the transient ended: the remaining periods repeat it
                D = fill_orbit(periods, period - n_transient, orbit_q, T)
                Xc += (n_total - period) // orbit_q * D
                n_skipped += n_total - period
                period = n_total
            if period >= n_transient and period < n_total:
                open_period(periods[period - n_transient], xr, vr, Vc)
                if period == n_transient:
                    energy[E_START] = stored_energy(p, xr, vr, Vc) + 0.5 * p[I_KS] * dsub * dsub
                if not harmonic and rec_events:
                    if n_ev >= events.shape[0]:
                        status = STATUS_EVGROW if ev_cap < 0 else STATUS_EVCAP
                        status_t = period * T
                        if ev_cap < 0:
                            break
                    if n_ev < events.shape[0]:
                        events[n_ev, 0] = period * T
                        events[n_ev, 1] = K_DRIVE_ON
                        n_ev += 1
    energy[E_END] = stored_energy(p, xr, vr, Vc) + 0.5 * p[I_KS] * dsub * dsub
    final[0] = xr
    final[1] = vr
    final[2] = Xc
    final[3] = Vc
    final[4] = contact
    final[5] = shell
    final[6] = period - n_skipped
    return status, status_t, samples, j_sample, events, n_ev, periods, energy, final


@njit(cache=True, parallel=True)
def run_many(P, opts, states0, n_transient, n_record):
    """Run many independent points in parallel (fixed initial conditions, no samples/events).

    P: (n, N_PARAMS); states0: (n, 4). Returns (status (n,), periods (n, n_record, cols),
    energy (n, N_ENERGY), final (n, N_FINAL)).
    """
    n = P.shape[0]
    status = np.zeros(n, dtype=np.int64)
    periods = np.zeros((n, n_record, N_PERIOD_COLS))
    energy = np.zeros((n, N_ENERGY))
    final = np.zeros((n, N_FINAL))
    for i in prange(n):
        # np.int64(0), not 0: a literal would make numba compile run_core and everything it calls a second time
        # (a Literal[int](0) signature beside the int64 one Python's calls give); measured once, cold: the first
        # progression batch after a simulate compiled in 25.9 s instead of 43.6 s
        st, st_t, sm, ns, ev, nev, per, en, fin = run_core(P[i], opts, states0[i], n_transient, n_record,
                                                          1.0, np.int64(0), np.int64(0))
        status[i] = st
        periods[i] = per
        energy[i] = en
        final[i] = fin
    return status, periods, energy, final
