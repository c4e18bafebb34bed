"""Reference and baseline integrator: scipy.integrate.solve_ivp with events (independent code).

Written in the original coordinates (X_m, X_c, V_m, V_c) of seed 000 eqs 19-20 with
the same set-valued friction rules (eqs 21-23, physics.md section 3) as the engine,
but none of its closed forms: every smooth piece is integrated by solve_ivp and
every switch (contact on/off, stick/slip, |V_c| = V_min, square-wave edges,
period boundaries) is a terminal event or a chunk boundary. Used (1) at tight
tolerance (DOP853, rtol 1e-12) as the accuracy reference of the tests and the
benchmark and (2) at ordinary tolerance as the benchmark's baseline.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from .model import CapsuleModel, Drive, Friction, effective_friction


class ReferenceTimeout(RuntimeError):
    """:func:`reference_run` passed its ``max_wall_s``: ``periods_done`` whole periods were integrated
    in ``elapsed_s`` [s] of wall time."""

    def __init__(self, periods_done: int, elapsed_s: float):
        super().__init__(f"solve_ivp reference stopped after {elapsed_s:.3g} s, {periods_done} periods done")
        self.periods_done = periods_done
        self.elapsed_s = elapsed_s


@dataclass
class ReferenceResult:
    """Events [(time_s, kind)], phase-0 states (n+1, 4) [X_m, X_c, V_m, V_c] (SI), counts."""

    events: list
    poincare: np.ndarray
    n_rhs: int
    n_segments: int


class _Sys:
    def __init__(self, model: CapsuleModel, drive: Drive, friction: Friction):
        self.m = model
        self.d = drive
        friction = effective_friction(model, friction)
        self.fr = friction
        self.Mm = model.mass_magnet_kg
        self.Mc = model.mass_capsule_kg
        self.Pb, self.L0, self.Vmin = friction.levels()
        self.law = friction.kind in ("eq22", "eq23", "law")
        self.Om = 2 * math.pi * drive.frequency_Hz
        self.ks = 1.0 / model.compliance_m_N if model.compliance_m_N > 0 else 0.0
        self.cs = model.substrate_damping_Ns_m
        self.T = 1.0 / drive.frequency_Hz
        mu = self.Mm * self.Mc / (self.Mm + self.Mc)
        self.vscale = max(model.gap_m, drive.amplitude_N / model.spring_N_m, 1e-6) * \
            max(self.Om, math.sqrt(model.spring_N_m / mu))  # velocity scale [m/s] for zero tests
        self.nrhs = 0

    def tilt(self, xr):
        """Tilt scaling of the friction levels, max(0, 1 + kappa x_r / G_1) (tilt_friction)."""
        return max(0.0, 1.0 + self.m.tilt_kappa * xr / self.m.gap_m)

    def tilt_lin(self, xr):
        """The tilt factor without the clamp (1 + kappa x_r / G_1): a smooth event function whose
        sign changes exactly where the clamped threshold is crossed while |F_i| > 0."""
        return 1.0 + self.m.tilt_kappa * xr / self.m.gap_m

    def level(self, V, xr=0.0):
        """Resisting force on the slipping shell: tilt-scaled friction level plus drag c_v |V|."""
        return self.tilt(xr) * self._law(V) + self.m.drag_Ns_m * abs(V)

    def _law(self, V):
        if not self.law:
            return self.L0
        if self.fr.literal:
            return 1e-3 * (self.fr.a_mm_s * (abs(V) * 1e3) ** self.fr.n + self.fr.b_mN)
        if abs(V) < self.Vmin:
            return self.L0
        return 1e-3 * (self.fr.a_mm_s * (abs(V) * 1e3) ** self.fr.n + self.fr.b_mN)

    def fe(self, t):
        if self.d.waveform == "harmonic":
            return self.d.amplitude_N * math.cos(self.Om * t)
        ph = t / self.T - math.floor(t / self.T + 1e-12)
        return self.d.amplitude_N if ph < self.d.duty - 1e-12 else 0.0

    def fi(self, contact, xr, vr):
        m = self.m
        F = m.spring_N_m * xr + m.damping_Ns_m * vr
        if contact == 1:
            F += m.constraint_N_m * (xr - m.gap_m) + m.constraint_damping_Ns_m * vr
        elif contact == 2:
            F += m.constraint_back_N_m * (xr + m.gap_back_m) + m.constraint_back_damping_Ns_m * vr
        return F

    def contact_of(self, xr):
        if xr >= self.m.gap_m:
            return 1
        if self.m.back_active and xr <= -self.m.gap_back_m:
            return 2
        return 0

    def decide(self, contact, xr, vr, fe):
        """Shell state at V_c = 0: 0 stick, +1/-1 slip direction; None if ill-posed."""
        if math.isinf(self.Pb):
            return 0
        F = self.fi(contact, xr, vr)
        tol = 1e-11 * max(self.d.amplitude_N, self.Pb, 1e-9)
        Pb = self.Pb * self.tilt(xr)
        if abs(F) < Pb - tol:
            return 0
        sgn = 1 if F > 0 else -1
        if abs(F) <= Pb + tol:
            # at the threshold: stick if F_i moves back inside (its rate with the shell held)
            m = self.m
            K = m.spring_N_m + (m.constraint_N_m if contact == 1 else 0) + (m.constraint_back_N_m if contact == 2 else 0)
            C = m.damping_Ns_m + (m.constraint_damping_Ns_m if contact == 1 else 0) + \
                (m.constraint_back_damping_Ns_m if contact == 2 else 0)
            Fdot = K * vr + C * (fe - F) / self.Mm
            # the threshold P_b (1 + kappa x_r / G_1) moves with x_r (tilt_friction)
            dPb = self.Pb * self.m.tilt_kappa / self.m.gap_m * vr if Pb > 0 else 0.0
            if sgn * Fdot - dPb <= 0:
                return 0
        L0 = (1e-3 * self.fr.b_mN if (self.law and self.fr.literal) else self.L0) * self.tilt(xr)
        if abs(F) - L0 < -tol:
            return None
        return sgn

    def rhs(self, contact, shell):
        Mm, Mc = self.Mm, self.Mc

        def f(t, y):
            self.nrhs += 1
            xr = y[0] - y[1]
            vr = y[2] - y[3]
            F = self.fi(contact, xr, vr)
            fe = self.fe_seg(t)
            am = (fe - F) / Mm
            if self.ks > 0:
                # compliant wall: spring k_s + damper c_s to a massless patch with the friction
                if shell == 0:
                    Fs, dd = self.ks * y[4] + self.cs * y[3], y[3]
                elif self.cs > 0:
                    L = self.level(y[3], xr) - self.m.drag_Ns_m * abs(y[3])
                    dd = (shell * L - self.ks * y[4]) / self.cs
                    Fs = shell * L
                else:
                    # c_s = 0: k_s d = shell L(0, x_r) throughout; the level at the patch's speed
                    dd = self.held_patch_rate(shell, xr, vr)
                    Vp = y[3] - dd
                    Fs = shell * (self.level(Vp, xr) - self.m.drag_Ns_m * abs(Vp))
                ac = (F - Fs - self.m.drag_Ns_m * y[3]) / Mc
                return np.array([y[2], y[3], am, ac, dd])
            if shell == 0:
                return np.array([y[2], 0.0, am, 0.0, 0.0])
            ac = (-shell * self.level(y[3], xr) + F) / Mc
            return np.array([y[2], y[3], am, ac, 0.0])
        return f

    def patch_force(self, y):
        return self.ks * y[4] + self.cs * y[3]

    def held_patch_rate(self, shell, xr, vr):
        """d' of a patch sliding on a wall with c_s = 0, where k_s d = shell L(0, x_r) (the level at
        zero slip speed, tilt-scaled) holds: nonzero only with tilt_friction."""
        if self.m.tilt_kappa == 0 or self.tilt(xr) <= 0:
            return 0.0
        return shell * self._law(0.0) * self.m.tilt_kappa / self.m.gap_m * vr / self.ks

    def patch_speed(self, shell, y):
        """Speed of the sliding patch (V_c minus the presliding spring's rate)."""
        if self.cs == 0:
            return y[3] - self.held_patch_rate(shell, y[0] - y[1], y[2] - y[3])
        xr = y[0] - y[1]
        L = self.level(0.0, xr)
        return y[3] - (shell * L - self.ks * y[4]) / self.cs

    def decide_patch(self, contact, y, fe):
        """Patch state at V_p = 0 (compliant wall): 0 stuck, +1/-1 sliding; None if ill-posed."""
        if math.isinf(self.Pb):
            return 0
        xr, vr = y[0] - y[1], y[2] - y[3]
        F = self.patch_force(y)
        tol = 1e-11 * max(self.d.amplitude_N, self.Pb, 1e-9)
        Pb = self.Pb * self.tilt(xr)
        if abs(F) < Pb - tol:
            return 0
        sgn = 1 if F > 0 else -1
        if abs(F) <= Pb + tol:
            ac = (self.fi(contact, xr, vr) - F - self.m.drag_Ns_m * y[3]) / self.Mc
            Fdot = self.ks * y[3] + self.cs * ac
            if Pb == 0:  # a zero level (tilt) holds nothing: F's first nonzero derivative decides
                rate = ac if (self.cs == 0 and abs(y[3]) <= 1e-13 * self.vscale) else Fdot
                return 0 if rate == 0 else (1 if rate > 0 else -1)
            dPb = self.Pb * self.m.tilt_kappa / self.m.gap_m * vr if Pb > 0 else 0.0
            if sgn * Fdot - dPb <= 0:
                return 0
        if abs(F) - self.L0 * self.tilt(xr) < -tol:
            return None
        return sgn


def reference_run(model: CapsuleModel, drive: Drive, friction: Friction, periods: int, state0=None,
                  method: str = "DOP853", rtol: float = 1e-12, atol=None, max_segments: int = 10_000_000,
                  steps_per_period: float = 100.0, max_wall_s: float | None = None):
    """Integrate ``periods`` excitation periods from ``state0`` = [x_r, v_r, X_c, V_c] (rest by default).

    Returns :class:`ReferenceResult` with the event list (same kinds as the engine) and the
    phase-0 states. atol defaults to [1e-15 m, 1e-15 m, 1e-12 m/s, 1e-12 m/s] x (rtol/1e-12).

    solve_ivp only sees an event when its function changes sign between two steps, so a
    high-order method taking long steps in free flight can step over a whole contact. The step
    is capped at 1/``steps_per_period`` of the fastest period of the current contact state
    (relative oscillator of the reduced mass with the contact stiffness, or the drive period if
    shorter). A segment starts on the surface it
    just crossed (event function ~0 of either sign), so its first step is short (1e-4 of the
    cap): otherwise a whole excursion and the next crossing can fit in one step whose two ends
    lie on the same side.

    ``max_wall_s``: stop with :class:`ReferenceTimeout` once that much wall time [s] has passed (checked
    between segments). Some stick-slip regimes make solve_ivp crawl through millions of short
    segments (the Fig 19 grid centre at P_f = 0.17 N: over 60 s for 20 periods); a benchmark that
    only times the reference bounds it this way.
    """
    t_start = time.perf_counter()
    S = _Sys(model, drive, friction)
    mu = S.Mm * S.Mc / (S.Mm + S.Mc)

    def max_step_of(contact_state):
        K = model.spring_N_m + (model.constraint_N_m if contact_state == 1 else 0.0) + \
            (model.constraint_back_N_m if contact_state == 2 else 0.0)
        w = max(math.sqrt(K / mu), S.Om)
        if S.ks > 0:
            w = max(w, math.sqrt((K + S.ks) / S.Mc + K / S.Mm), S.ks / S.cs if S.cs > 0 else 0.0)
        return 2 * math.pi / w / steps_per_period
    if atol is None:
        atol = np.array([1e-15, 1e-15, 1e-12, 1e-12]) * (rtol / 1e-12)
    atol = np.asarray(atol, float)
    if atol.size == 4:  # the presliding spring extension d (substrate compliance) like a position
        atol = np.append(atol, atol[0])
    s0 = np.zeros(4) if state0 is None else np.asarray(state0, float)
    y = np.array([s0[2] + s0[0], s0[2], s0[3] + s0[1], s0[3], 0.0])
    T = S.T
    contact = S.contact_of(y[0] - y[1])
    t = 0.0
    square = drive.waveform == "square"
    if S.ks > 0:
        shell = S.decide_patch(contact, y, S.fe(0.0))
        if shell is None:
            raise RuntimeError("ill-posed friction law at t = 0")
    elif y[3] == 0.0:
        shell = S.decide(contact, y[0] - y[1], y[2] - y[3], S.fe(0.0))
        if shell is None:
            raise RuntimeError("ill-posed friction law at t = 0")
    else:
        shell = 1 if y[3] > 0 else -1
    fast = False  # |V_c| above V_min (speed law branch) in the current slip
    events = []
    poincare = [y.copy()]
    nseg = 0
    m = model
    for n in range(periods):
        bounds = [n * T + drive.duty * T, (n + 1) * T] if square else [(n + 1) * T]
        for bi, tb in enumerate(bounds):
            level_on = square and bi == 0
            S.fe_seg = (lambda tt, lv=level_on: drive.amplitude_N if lv else 0.0) if square else \
                (lambda tt: drive.amplitude_N * math.cos(S.Om * tt))
            while t < tb:
                nseg += 1
                if nseg > max_segments:
                    raise RuntimeError("too many segments (Zeno?)")
                if max_wall_s is not None and time.perf_counter() - t_start > max_wall_s:
                    raise ReferenceTimeout(n, time.perf_counter() - t_start)
                evs, kinds = [], []

                def mk(fun, kind):
                    fun.terminal = True
                    fun.direction = -1
                    evs.append(fun)
                    kinds.append(kind)
                G1, G2 = m.gap_m, m.gap_back_m
                if contact == 0:
                    mk(lambda tt, yy: G1 - (yy[0] - yy[1]), "front_contact_on")
                    if m.back_active:
                        mk(lambda tt, yy: (yy[0] - yy[1]) + G2, "back_contact_on")
                elif contact == 1:
                    mk(lambda tt, yy: (yy[0] - yy[1]) - G1, "front_contact_off")
                else:
                    mk(lambda tt, yy: -G2 - (yy[0] - yy[1]), "back_contact_off")
                c_ = contact
                if S.ks > 0:
                    sh = shell
                    if shell == 0:
                        mk(lambda tt, yy: S.Pb * S.tilt_lin(yy[0] - yy[1]) - S.patch_force(yy), "break+")
                        mk(lambda tt, yy: S.Pb * S.tilt_lin(yy[0] - yy[1]) + S.patch_force(yy), "break-")
                    else:
                        mk(lambda tt, yy: sh * S.patch_speed(sh, yy), "slip_end")
                elif shell == 0:
                    if not math.isinf(S.Pb):
                        mk(lambda tt, yy: S.Pb * S.tilt_lin(yy[0] - yy[1]) - S.fi(c_, yy[0] - yy[1], yy[2] - yy[3]),
                           "break+")
                        mk(lambda tt, yy: S.Pb * S.tilt_lin(yy[0] - yy[1]) + S.fi(c_, yy[0] - yy[1], yy[2] - yy[3]),
                           "break-")
                else:
                    sh = shell
                    mk(lambda tt, yy: sh * yy[3], "slip_end")
                    if S.law and not friction.literal:
                        vm = S.Vmin
                        if not fast:
                            mk(lambda tt, yy: vm - sh * yy[3], "vmin")
                        else:
                            mk(lambda tt, yy: sh * yy[3] - vm, "vmin")
                max_step = max_step_of(contact)
                sol = solve_ivp(S.rhs(contact, shell), (t, tb), y, method=method, rtol=rtol, atol=atol, max_step=max_step,
                                first_step=min(max_step * 1e-4, max(tb - t, 1e-300)),
                                events=evs, dense_output=False)
                if sol.status == -1:
                    raise RuntimeError(f"solve_ivp failed: {sol.message}")
                hit = None
                for i, te in enumerate(sol.t_events):
                    if len(te):
                        if hit is None or te[0] < sol.t_events[hit][0]:
                            hit = i
                if hit is None:
                    t = tb
                    y = sol.y[:, -1].copy()
                    break
                t = float(sol.t_events[hit][0])
                y = sol.y_events[hit][0].copy()
                kind = kinds[hit]
                xr, vr = y[0] - y[1], y[2] - y[3]
                fe = S.fe_seg(t)
                if kind.endswith("contact_on") or kind.endswith("contact_off"):
                    contact = {"front_contact_on": 1, "back_contact_on": 2}.get(kind, 0)
                    events.append((t, kind))
                    if shell == 0 and S.ks == 0:  # (compliant wall: the patch force does not jump)
                        new = S.decide(contact, xr, vr, fe)
                    else:
                        new = shell
                elif S.ks > 0 and kind.startswith("break"):
                    new = S.decide_patch(contact, y, fe)
                elif S.ks > 0 and kind == "slip_end":
                    if S.cs == 0:  # k_s d = shell L(0, x_r) is algebraic: drop the integration's drift
                        y[4] = shell * S.level(0.0, xr) / S.ks
                    # the patch stops at the kinetic level (<= breakaway) and sticks; at a zero
                    # level (tilt) nothing holds it
                    new = S.decide_patch(contact, y, fe) if S.tilt(xr) == 0 else 0
                elif kind.startswith("break"):
                    new = S.decide(contact, xr, vr, fe)
                elif kind == "slip_end":
                    y[3] = 0.0
                    fast = False
                    new = S.decide(contact, xr, y[2], fe)
                else:  # vmin: the law's kink, same mode, other branch
                    new = shell
                    fast = not fast
                if new is None:
                    raise RuntimeError(f"ill-posed friction law at t = {t}")
                if new != shell and S.ks > 0:
                    if new == 0:
                        events.append((t, "stick"))
                    else:
                        events.append((t, "slip_forward" if new == 1 else "slip_backward"))
                        if shell == 0 and S.cs == 0:
                            y[4] = new * S.level(0.0, xr) / S.ks  # c_s = 0: patch jumps to k_s d = sgn L
                elif new != shell:
                    fast = False
                    if new == 0:
                        y[3] = 0.0
                        events.append((t, "stick"))
                    elif new == 1:
                        events.append((t, "slip_forward"))
                    else:
                        events.append((t, "slip_backward"))
                    if shell == 0:
                        y[3] = 0.0
                shell = new
            if square and bi == 0:
                events.append((tb, "drive_off"))
        if square:
            events.append(((n + 1) * T, "drive_on"))
        poincare.append(y.copy())
    return ReferenceResult(events=events, poincare=np.array(poincare), n_rhs=S.nrhs, n_segments=nseg)
