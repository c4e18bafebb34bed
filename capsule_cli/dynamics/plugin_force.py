"""User plugin forces of the dynamics (issue 9 item 4, second sort): compile, check, hand to the engine.

A plugin file registers an extra force as a function of state and time, with ``role="force"``::

    import math
    from capsule_cli.effects import Param, register_effect

    for kind in ("progression", "trajectory"):
        @register_effect(name="magnet_attraction", kind=kind, role="force",
                         params=(Param("attraction_mN", 2.0, (0.0, 100.0), off=0.0,
                                       description="attraction at contact"),
                                 Param("range_mm", 0.3, (0.01, 10.0), off=0.3,
                                       description="decay length of the attraction")),
                         description="Magnet and shell attract, more as they approach.", source="my notes")
        def magnet_attraction(t, x_m, v_m, x_c, v_c, p):
            F = p[0] * math.exp(-(x_c + 1.6e-3 - x_m) / p[1])   # p in SI: N, m
            return F, -F                                         # on the magnet, on the shell [N]

The function (:data:`FORCE_SIGNATURE`):

* arguments: ``t`` [s] since the run's start (the drive is ``P_d cos(2 pi f t)``), the magnet's position and
  velocity ``x_m`` [m], ``v_m`` [m/s], the shell's ``x_c`` [m], ``v_c`` [m/s] (forward = +x, the run starts at
  rest at 0), and ``p``: a float64 array of the effect's parameters in SI, in the order they are declared
  (``p[0]`` is the first Param, converted from the unit of its name's suffix: ``attraction_mN`` -> N);
* returns ``(F_on_magnet_N, F_on_shell_N)``; an internal force (magnetic attraction between the two) is an
  equal and opposite pair ``(F, -F)``; an external one (a field gradient on the magnet alone) is ``(F, 0)``;
* must compile with numba in nopython mode (``math``, numpy scalar functions, arithmetic, ``if``; no dicts,
  lists of objects or other Python objects), must not raise and must return finite numbers. This is checked
  when the system is built (compilation and a trial call at rest and at a small displacement); a failure
  is one line and exit code 2. At run time a raise or a non-finite force stops the run with one line
  (:data:`engine.STATUS_PLUGIN`), exit code 2.

The force is compiled once per process (its ``njit`` body is cached on disk by numba when the plugin
file's folder allows it) and wrapped in a C-callable ``cfunc`` of one fixed signature (:func:`_cfunc`);
the engine (compiled once, cached) calls it through its address, carried in the parameter row with the
parameters. So a plugin does not recompile the engine, and the runs without a plugin keep their code.
Every mode of a system with a plugin force goes through the engine's adaptive (Dormand-Prince) segment;
the stick test and the energy balance count it (``plugin_work_J``). Several force effects in one model
add their forces. The user's function must not modify ``p``.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import InputError
from ..interrupts import call_interruptibly, deferred_call
from . import engine as E

#: the Python signature of a plugin force (documentation; see the module doc)
FORCE_SIGNATURE = "force(t, x_m, v_m, x_c, v_c, p) -> (F_on_magnet_N, F_on_shell_N)"

#: trial states (t [s], x_m, v_m, x_c, v_c [m, m/s]) of the build-time check: rest, and a small displacement
TRIAL_STATES = ((0.0, 0.0, 0.0, 0.0, 0.0), (1e-3, 1e-4, 1e-2, -2e-5, -1e-3))


@dataclass(frozen=True)
class CompiledForce:
    """The plugin forces of one model, compiled: ``address`` of the C-callable sum (see the module doc)."""

    names: tuple[str, ...]
    n_params: tuple[int, ...]
    address: int
    cfunc: object  # keeps the compiled code alive
    jitted: object  # the summed force, njit (callable from Python, for checks)


_COMPILED: dict[tuple, CompiledForce] = {}
_JITTED: dict[int, tuple] = {}  # id(apply) -> (apply, its dispatcher)
_CHECKED: set = set()  # (id(apply), params) already checked
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _first_line(exc: BaseException) -> str:
    """Return the informative first line of an exception (numba's errors are multi-line, coloured)."""
    lines = [_ANSI.sub("", ln).strip() for ln in str(exc).splitlines()]
    lines = [ln for ln in lines if ln and not ln.startswith(("Failed in ", "During: ", "File ", "^"))]
    return (lines[0] if lines else type(exc).__name__)[:300]


def _jit_user(eff):
    """Return the effect's force as a numba dispatcher (compiled lazily, cached on disk when possible;
    one per function and process)."""
    from numba import njit
    from numba.core.registry import CPUDispatcher

    fn = eff.apply
    hit = _JITTED.get(id(fn))
    if hit is not None and hit[0] is fn:
        return hit[1]
    if isinstance(fn, CPUDispatcher):
        jf = fn
    else:
        try:
            jf = njit(cache=True)(fn)
        except Exception:  # noqa: BLE001  (no cache locator for this file: compile without the disk cache)
            jf = njit(fn)
    _JITTED[id(fn)] = (fn, jf)
    return jf


def _one(f):
    from numba import njit

    @njit
    def force(t, xm, vm, xc, vc, p):
        r = f(t, xm, vm, xc, vc, p)
        return float(r[0]), float(r[1])

    return force


def _sum(f, g, nf):
    from numba import njit

    @njit
    def force(t, xm, vm, xc, vc, p):
        a = f(t, xm, vm, xc, vc, p[:nf])
        b = g(t, xm, vm, xc, vc, p[nf:])
        return a[0] + b[0], a[1] + b[1]

    return force


def _cfunc(h, n_params: int):
    """Return the C-callable plugin of the engine around the summed force ``h`` with ``n_params``
    parameters: ``double plugin(int64 which, double t, double x_m, double v_m, double x_c, double v_c,
    double *q)`` returns the force on the magnet (which = 0) or on the shell (1) [N], NaN when ``h``
    raised or returned a non-finite force (engine.plugin_force). It reads q and writes no memory."""
    from numba import carray, cfunc, types

    sig = types.float64(types.int64, types.float64, types.float64, types.float64, types.float64, types.float64,
                        types.CPointer(types.float64))
    n = int(n_params)

    @cfunc(sig)
    def plugin(which, t, xm, vm, xc, vc, qp):
        q = carray(qp, (n,))
        try:
            Fm, Fc = h(t, xm, vm, xc, vc, q)
        except Exception:  # noqa: BLE001  (reported by the engine as STATUS_PLUGIN)
            return math.nan
        if not (math.isfinite(Fm) and math.isfinite(Fc)):
            return math.nan
        return Fm if which == 0 else Fc

    return plugin


def _check_one(eff, jf, p: np.ndarray, where: str) -> None:
    """Compile ``eff``'s force and call it at the trial states: InputError (one line) when it cannot."""
    from numba.core.errors import NumbaError

    label = f"{where}plugin force '{eff.name}' ({eff.origin})"
    for state in TRIAL_STATES:
        try:
            r = deferred_call(jf, *state, p)  # a Ctrl-C: KeyboardInterrupt after the call, not "the plugin raised"
        except NumbaError as exc:
            raise InputError(f"{label} does not compile with numba (nopython mode; use math and numbers, "
                             f"no dicts or Python objects): {_first_line(exc)}") from None
        except Exception as exc:  # noqa: BLE001  (the user's function raised: their input, exit 2)
            raise InputError(f"{label} raised {type(exc).__name__}: {_first_line(exc)} at t = {state[0]} s, "
                             f"x_m = {state[1]} m") from None
        try:
            fm, fc = (float(v) for v in r)
        except (TypeError, ValueError):
            raise InputError(f"{label} must return two numbers (force on the magnet, force on the shell "
                             f"[N]), got {r!r}") from None
        if not (math.isfinite(fm) and math.isfinite(fc)):
            raise InputError(f"{label} returned a non-finite force ({fm}, {fc}) at t = {state[0]} s, "
                             f"x_m = {state[1]} m, x_c = {state[3]} m")


def compile_forces(forces: Sequence[tuple], where: str = "") -> CompiledForce:
    """Compile and check the plugin forces ``((kind, name, params SI tuple), ...)`` of a model.

    Checks each with its parameters at :data:`TRIAL_STATES`; returns the C-callable sum (cached per
    process by the effects' functions). InputError, one line, for a force that does not compile, raises,
    returns non-finite values or has too many parameters.
    """
    from ..effects.registry import get_effect

    effs = [get_effect(kind, name, where) for kind, name, _ in forces]
    nps = tuple(len(prm) for _, _, prm in forces)
    if sum(nps) > E.MAX_PLUG_PARAMS:
        raise InputError(f"{where}plugin forces take at most {E.MAX_PLUG_PARAMS} parameters in all, "
                         f"got {sum(nps)}")
    key = tuple((e.kind, e.name, e.origin, id(e.apply)) for e in effs) + (nps,)
    jitted = [_jit_user(e) for e in effs]
    for eff, jf, (_, _, prm) in zip(effs, jitted, forces):
        # check with these parameters (a new parameter set may make the force non-finite)
        ck = (id(eff.apply), tuple(float(v) for v in prm))
        if ck not in _CHECKED:
            _check_one(eff, jf, np.asarray(prm, dtype=float), where)
            _CHECKED.add(ck)
    comp = _COMPILED.get(key)
    if comp is not None:
        return comp
    total = _one(jitted[0])
    n_acc = nps[0]
    for jf, n in zip(jitted[1:], nps[1:]):
        total = _sum(total, _one(jf), n_acc)
        n_acc += n
    try:  # compiled in a worker thread: in the main thread llvmlite's callbacks can drop a Ctrl-C
        cf = call_interruptibly(_cfunc, total, sum(nps))
    except Exception as exc:  # noqa: BLE001
        names = ", ".join(e.name for e in effs)
        raise InputError(f"{where}plugin forces ({names}) do not compile together: {_first_line(exc)}") from None
    addr = int(cf.address)
    if int(float(addr)) != addr:  # the row carries it as a float64 (exact below 2**53)
        raise RuntimeError(f"plugin force address {addr:#x} is not exact in a float64")
    comp = CompiledForce(names=tuple(e.name for e in effs), n_params=nps, address=addr, cfunc=cf, jitted=total)
    _COMPILED[key] = comp
    return comp


def pack_forces(p: np.ndarray, forces: Sequence[tuple]) -> None:
    """Fill the plugin slots of the engine's parameter row ``p`` (I_PLUG ...) for ``forces``
    ((kind, name, params SI tuple), ...); nothing when there are none (the slots stay 0: off)."""
    if not forces:
        return
    comp = compile_forces(forces)
    vals = [float(v) for _, _, prm in forces for v in prm]
    p[E.I_PLUG] = 1.0
    p[E.I_PLUG_FN] = float(comp.address)
    p[E.I_PLUG_NP] = float(len(vals))
    p[E.I_PLUG_P0:E.I_PLUG_P0 + len(vals)] = vals
