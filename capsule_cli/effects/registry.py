"""The registry of base models and physical effects, built in and from plugins.

A *base model* predicts the measured response of one measurement kind
(contract section 3) from its covariates; an *effect* is a named, documented
term that a model file switches on (contract section 4). Both are plain
dataclasses holding pure functions:

``predict(x, p, ctx) -> y`` (base) and ``apply(y, x, p, ctx) -> y`` (effect), where

* ``x`` maps covariate *base names* (``speed``, ``position``, ``time``, ``Ri``,
  ``bend_radius``, ``temperature``, ...) to numpy arrays in SI units ([m/s],
  [m], [s], °C stays °C); label columns (``statistic``) come as string arrays;
* ``p`` maps parameter base names (the declared name without its unit suffix:
  ``a_mN`` -> ``a``) to SI values ([N], [m], [Pa] ...);
* ``ctx`` holds the model's resolved base parameters (SI, base names, e.g.
  ``mu``, ``mass``) and the fixed capsule/intestine constants (``Rc``, ``L``,
  ``g`` ...) from ``configs/params``;
* ``y`` is the response in SI ([N] for friction, [Pa] for pressure).

Parameters are declared with :class:`Param` in the unit of their name's
suffix (``a_mN`` in mN, ``relax_time_s`` in s); the suffix sets the SI factor
(``capsule_cli.units``). A coefficient per degree Celsius takes its
numerator's suffix (``slope_mN`` = mN per °C, since °C has factor 1).

Every effect has an ``off`` value per parameter at which ``apply`` returns
``y`` unchanged, so a model with the effect nests the model without it.

Plugins
-------
A plugin is a Python file (``--plugins FILE.py``) or a module exposed in the
entry-point group ``capsule_cli.effects`` that registers effects::

    from capsule_cli.effects import Param, register_effect

    @register_effect(
        name="thermal_softening", kind="friction", covariates=("temperature_C",),
        params=(Param("slope_mN", start=0.5, bounds=(-20.0, 20.0), off=0.0,
                      description="friction change per degree Celsius"),),
        description="Friction changes linearly with the tissue temperature.",
        source="my lab notebook, 2024-05-02")
    def thermal_softening(y, x, p, ctx):
        return y + p["slope"] * (x["temperature"] - 37.0)

From then on the effect is listed by ``effects list``, usable in model files
and ``synth``, fitted by ``compare`` and tried by ``diagnose``.

Dynamics plugins (kinds ``progression`` and ``trajectory``; one registered with either kind is an effect of
both, as the two share the equations of motion) change the equations of motion and come in two roles:
``role="drive"``, a per-row drive transform ``apply(f_Hz, Pd_N, duty, p) -> (f_Hz, Pd_N, duty)`` (p: dict of
SI values by base name); and ``role="force"``, an extra force of state and time::

    @register_effect(name="magnet_attraction", kind="progression", role="force",
                     params=(Param("attraction_mN", 2.0, (0.0, 100.0), off=0.0),
                             Param("range_mm", 0.3, (0.01, 10.0), off=0.3)),
                     description="...", source="...")
    def magnet_attraction(t, x_m, v_m, x_c, v_c, p):     # SI: s, m, m/s; p: float64 array, SI
        F = p[0] * math.exp(-(x_c + 1.6e-3 - x_m) / p[1])
        return F, -F                                      # on the magnet, on the shell [N]

compiled with numba (nopython), checked when the system is built and integrated by the engine's
adaptive segment, counted in the stick test and the energy balance
(:mod:`capsule_cli.dynamics.plugin_force` documents the signature and the checks).
"""
from __future__ import annotations

import difflib
import hashlib
import importlib.util
import math
import sys
import traceback
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np

from ..errors import InputError
from ..units import UNITS, split_unit, unit_label

#: the quasi-static kinds this registry serves now (dynamics kinds come later)
KINDS = ("friction", "pressure", "relaxation", "progression", "trajectory")
#: the kinds whose effects change the equations of motion (the vibro-impact engine's; one physics for both)
DYNAMICS_KINDS = ("progression", "trajectory")

ENTRY_POINT_GROUP = "capsule_cli.effects"


def base_name(name: str) -> str:
    """Return a unit-suffixed name without its suffix (``a_mN`` -> ``a``; ``mu`` -> ``mu``)."""
    base, suffix = split_unit(name)
    return base if suffix else name


def si_factor(name: str) -> float:
    """Return the factor converting a value in the unit of ``name``'s suffix to SI (1 if none)."""
    _, suffix = split_unit(name)
    return 1.0 if suffix is None else UNITS[suffix][0]


@dataclass(frozen=True)
class Param:
    """A parameter of a base model or effect, in the unit of its name's suffix.

    name : unit-suffixed name (``a_mN``, ``relax_time_s``; dimensionless: ``n``)
    start : default value (start value of a calibration)
    bounds : (lower, upper) used when the parameter is free
    off : value at which the effect vanishes (the model reduces to the one without it);
        None for base-model parameters
    free : whether the parameter is freed when the effect is added by ``diagnose``
    description : what it is
    log_from : dynamics calibrations only: the value (unit of the suffix) above the lower bound from which
        the calibration's box coordinate u in [0, 1] is logarithmic, theta = lo + r ((1 + span / r)^u - 1)
        with r = log_from, for a parameter whose plausible values sit decades below its upper bound; None:
        the default map (``capsule_cli.steps.dynamics_loop.box_map``)
    """

    name: str
    start: float
    bounds: tuple[float, float] = (-np.inf, np.inf)
    off: float | None = None
    free: bool = True
    description: str = ""
    log_from: float | None = None

    @property
    def key(self) -> str:
        """The SI key in ``p`` (the name without its unit suffix)."""
        return base_name(self.name)

    @property
    def unit(self) -> str:
        return unit_label(self.name)


GuessFn = Callable[[np.ndarray, Mapping[str, np.ndarray], Mapping[str, float]], Mapping[str, float]]


@dataclass(frozen=True)
class Effect:
    """A named physical effect a model can switch on (contract section 4).

    apply(y, x, p, ctx) -> y returns the response with the effect (SI, see the module doc);
    guess(residual, x, ctx) -> {param key: SI value}, optional, gives data-based start values
    from the residual of the model without the effect (SI response units).
    bases : base models the effect applies to (empty: all of its kind)
    """

    name: str
    kind: str
    description: str
    source: str
    params: tuple[Param, ...]
    covariates: tuple[str, ...]
    apply: Callable
    guess: GuessFn | None = None
    bases: tuple[str, ...] = ()
    origin: str = "built-in"
    #: dynamics kinds only: "drive" marks a per-row drive transform
    #: ``apply(f_Hz, Pd_N, duty, p) -> (f_Hz, Pd_N, duty)`` (p: SI values by base name), applied to every
    #: condition before it is simulated (capsule_cli.dynamics.system); "force" an extra force of state and
    #: time ``apply(t, x_m, v_m, x_c, v_c, p) -> (F_on_magnet_N, F_on_shell_N)`` (SI; p: float64 array of
    #: the parameters in SI in declaration order), compiled with numba and integrated by the engine
    #: (capsule_cli.dynamics.plugin_force); "friction" (progression; diagnose's covariate probes only, through
    #: :func:`register_probe`) a factor ``apply(x, p) -> float`` of the friction level P_f at each condition, x its
    #: value of the probe's one covariate; "" for the others
    role: str = ""
    #: whether a model may hold it more than once (a physical series: a second Maxwell arm); the k-th
    #: instance is the effect ``<name>_<k>`` with parameters ``<param>_<k>`` (see :func:`effect_instance`)
    repeatable: bool = False
    #: other effects of the kind this one contains as a special case, each as (effect name, the setting of this
    #: one's parameters where it reduces to that one, in words), e.g. ``(("viscous_drag", "n = 1"),)``: the
    #: verdict compares such a pair by the nested F test, not by Vuong's test of non-nested fits, and names
    #: the simpler one unless the richer fits significantly better (:func:`capsule_cli.steps.verdict.rank_supported`)
    nests: tuple[tuple[str, str], ...] = ()
    #: where this one reduces to an effect it nests, as values of its own parameters: (effect name, ((own
    #: parameter name, a number or the nested effect's parameter name whose fitted value it takes), ...)), e.g.
    #: ``(("viscous_drag", (("n", 1.0), ("a_mN", "drag_Ns_m"))),)``. The dynamics loop fits the nested effect
    #: first and starts this one's calibration there too, so the richer fit is never worse than the one it
    #: contains (register_effect takes it as a mapping)
    nest_starts: tuple = ()

    def applicable(self, columns: Iterable[str], base: str | None = None) -> bool:
        """Return True when every covariate the effect needs is in ``columns`` (and the base fits)."""
        have = {base_name(c) for c in columns}
        if self.bases and base is not None and base not in self.bases:
            return False
        return all(base_name(c) in have for c in self.covariates)

    def n_free(self) -> int:
        return sum(p.free for p in self.params)


@dataclass(frozen=True)
class BaseModel:
    """A base model of a measurement kind (contract section 4 table).

    predict(x, p, ctx) -> y (SI). ``column_params`` are parameters that a table
    column of the same name replaces row by row (``Ri_mm``: "or the table's column").
    """

    name: str
    kind: str
    description: str
    source: str
    params: tuple[Param, ...]
    predict: Callable
    covariates: tuple[str, ...] = ()
    column_params: tuple[str, ...] = ()
    origin: str = "built-in"


_EFFECTS: dict[tuple[str, str], Effect] = {}
_BASES: dict[tuple[str, str], BaseModel] = {}
_LOADED_PLUGINS: set[str] = set()
_BUILTINS_LOADED = False
_CURRENT_ORIGIN = ["built-in"]


def _check_params(owner: str, params: Sequence[Param], is_effect: bool) -> None:
    seen = set()
    for prm in params:
        if not isinstance(prm, Param):
            raise ValueError(f"{owner}: parameters must be capsule_cli.effects.Param, got {type(prm).__name__}")
        if prm.name in seen:
            raise ValueError(f"{owner}: parameter '{prm.name}' declared twice")
        seen.add(prm.name)
        lo, hi = prm.bounds
        if not lo < hi:
            raise ValueError(f"{owner}: parameter '{prm.name}' bounds must be lower < upper, got {prm.bounds}")
        if not (lo <= prm.start <= hi):
            raise ValueError(f"{owner}: parameter '{prm.name}' start {prm.start} outside bounds {prm.bounds}")
        if is_effect and prm.off is None:
            raise ValueError(f"{owner}: parameter '{prm.name}' needs an 'off' value (where the effect vanishes)")


def register_effect(effect: Effect | None = None, *, name: str | None = None, kind: str | None = None,
                    params: Sequence[Param] = (), covariates: Sequence[str] = (), description: str = "",
                    source: str = "", guess: GuessFn | None = None, bases: Sequence[str] = (), role: str = "",
                    repeatable: bool = False, nests: Sequence[tuple[str, str]] = (),
                    nest_starts: Mapping[str, Mapping[str, float | str]] | None = None):
    """Register an effect; use as ``register_effect(Effect(...))`` or as a decorator.

    As a decorator the function is ``apply(y, x, p, ctx) -> y`` (see the module doc)::

        @register_effect(name="my_effect", kind="friction", params=(Param("k_mN", 1.0, (0, 50), 0.0),),
                         covariates=("temperature_C",), description="...", source="...")
        def my_effect(y, x, p, ctx):
            return y + p["k"] * (x["temperature"] - 37.0)

    ``repeatable=True`` lets a model hold the effect more than once (``<name>_2`` with parameters
    ``<param>_2``, see :func:`effect_instance`). ``nests`` names effects this one contains as a special case
    (``(("viscous", "n = 1"),)``; see :attr:`Effect.nests`), ``nest_starts`` the same settings as values
    (``{"viscous": {"n": 1.0, "a_mN": "c_Ns_m"}}``: a number, or the nested effect's parameter whose fitted
    value it takes; see :attr:`Effect.nest_starts`). Raises ValueError on a bad registration (unknown
    kind, a parameter without bounds/off, a name clash with another effect of the kind).
    """
    if effect is not None:
        _add_effect(effect)
        return effect

    def deco(fn):
        if not callable(fn):
            raise ValueError("register_effect decorates a function apply(y, x, p, ctx)")
        eff = Effect(name=name or fn.__name__, kind=kind or "", description=description or (fn.__doc__ or "").strip(),
                     source=source or "user plugin", params=tuple(params), covariates=tuple(covariates),
                     apply=fn, guess=guess, bases=tuple(bases), origin=_CURRENT_ORIGIN[-1], role=role,
                     repeatable=bool(repeatable),
                     nests=tuple(tuple(x) if isinstance(x, (list, tuple)) else x for x in nests),
                     nest_starts=nest_start_pairs(nest_starts))
        _add_effect(eff)
        return fn

    return deco


def nest_start_pairs(starts: Mapping[str, Mapping[str, float | str]] | None) -> tuple:
    """Return :attr:`Effect.nest_starts` from a mapping {nested effect: {own parameter: number or the nested
    effect's parameter name}} (None: none)."""
    return tuple((str(name), tuple((str(k), v if isinstance(v, str) else float(v)) for k, v in dict(setting).items()))
                 for name, setting in dict(starts or {}).items())


def _check_nest_starts(eff: Effect) -> None:
    """Raise ValueError unless every entry of ``eff.nest_starts`` names an effect of ``eff.nests`` and sets
    ``eff``'s own parameters, each to a finite number or to a parameter name of the nested effect (checked
    where the start is made, as that effect may be registered later)."""
    nested = {pair[0] for pair in eff.nests}
    own = {prm.name for prm in eff.params}
    for entry in eff.nest_starts:
        ok = isinstance(entry, tuple) and len(entry) == 2 and entry[0] in nested and isinstance(entry[1], tuple)
        bad = [] if not ok else [k for k, v in entry[1] if k not in own
                                 or not (isinstance(v, str) or (isinstance(v, float) and math.isfinite(v)))]
        if not ok or bad:
            which = ", ".join(sorted(nested)) or "none"
            raise ValueError(f"effect '{eff.name}': nest_starts must map an effect it nests ({which}) to its own "
                             f"parameters ({', '.join(sorted(own))}), each a number or the nested effect's parameter "
                             "name" + (f"; not {', '.join(map(str, bad))}" if bad else ""))


def _add_effect(eff: Effect) -> None:
    if eff.kind not in KINDS:
        raise ValueError(f"effect '{eff.name}': unknown kind '{eff.kind}' (one of {', '.join(KINDS)})")
    if not eff.name or not eff.name.replace("_", "").isalnum():
        raise ValueError(f"effect name '{eff.name}' must be a word (letters, digits, underscores)")
    if not callable(eff.apply):
        raise ValueError(f"effect '{eff.name}': apply must be callable")
    if eff.origin == "built-in" and _CURRENT_ORIGIN[-1] != "built-in":
        eff = Effect(**{**eff.__dict__, "origin": _CURRENT_ORIGIN[-1]})
    _check_params(f"effect '{eff.name}'", eff.params, True)
    if eff.role not in ("", "drive", "force"):
        # ("friction", a friction level set by a covariate, is diagnose's probes' only: register_probe)
        raise ValueError(f"effect '{eff.name}': unknown role '{eff.role}' (\"drive\" for a drive transform, "
                         "\"force\" for an extra force)")
    if eff.role and eff.repeatable:
        raise ValueError(f"effect '{eff.name}': a drive transform or force cannot be repeatable")
    if any(not (isinstance(pair, tuple) and len(pair) == 2 and all(isinstance(v, str) for v in pair))
           or pair[0] == eff.name for pair in eff.nests):
        raise ValueError(f"effect '{eff.name}': nests must be pairs (another effect's name, the setting where "
                         "this one reduces to it, in words)")
    _check_nest_starts(eff)
    if eff.role and eff.kind not in DYNAMICS_KINDS:
        raise ValueError(f"effect '{eff.name}': a drive transform or force is a progression or trajectory effect")
    for cov in eff.covariates:
        if split_unit(cov)[1] is None:
            raise ValueError(f"effect '{eff.name}': covariate '{cov}' needs a unit suffix (e.g. 'temperature_C')")
    # a dynamics effect changes the equations of motion, which progression speeds and trajectories share: one
    # registered for either kind is registered for both (as the built-in ones are), so that a user's plugin
    # works in a trajectory model as in a progression one
    copies = _kind_copies(eff)
    for kind, _ in copies:
        old = _EFFECTS.get((kind, eff.name))
        if old is not None and old.origin != eff.origin:
            raise ValueError(f"effect '{eff.name}' ({kind}) is already registered by {old.origin}")
    for kind, copy in copies:
        _EFFECTS[(kind, eff.name)] = copy


def _kinds_of(kind: str) -> tuple[str, ...]:
    """Return the kinds an effect of ``kind`` is registered for: both dynamics kinds for either, else itself."""
    return DYNAMICS_KINDS if kind in DYNAMICS_KINDS else (kind,)


def _kind_copies(eff: Effect) -> list[tuple[str, Effect]]:
    """Return (kind, ``eff`` as an effect of that kind) for every kind of :func:`_kinds_of`."""
    return [(k, eff if k == eff.kind else Effect(**{**eff.__dict__, "kind": k})) for k in _kinds_of(eff.kind)]


def unregister_effect(kind: str, name: str) -> None:
    """Remove the effect ``name`` of ``kind`` (of both dynamics kinds for a dynamics one, as it was registered),
    e.g. a plugin's that a test loaded (the file stays loaded; see ``_LOADED_PLUGINS``). Unknown names are
    ignored."""
    for k in _kinds_of(kind):
        _EFFECTS.pop((k, name), None)


def register_base(model: BaseModel) -> BaseModel:
    """Register a base model of a kind (built-ins; plugins may add bases the same way)."""
    if model.kind not in KINDS:
        raise ValueError(f"base model '{model.name}': unknown kind '{model.kind}'")
    _check_params(f"base model '{model.name}'", model.params, False)
    _BASES[(model.kind, model.name)] = model
    return model


def _ensure_builtins() -> None:
    global _BUILTINS_LOADED
    if _BUILTINS_LOADED:
        return
    _BUILTINS_LOADED = True
    from . import dynamics, friction, pressure, relaxation  # noqa: F401  (register on import)


#: covariate probes (dynamics): generic drive transforms that diagnose fits to find WHICH covariate an
#: effect that is not built in depends on; not candidates and not listed as effects, but found by
#: :func:`get_effect` so that a model holding one can be simulated (capsule_cli.effects.dynamics)
_PROBES: dict[tuple[str, str], Effect] = {}


def register_probe(eff: Effect) -> Effect:
    """Register a covariate probe (see ``_PROBES``); a dynamics one for both dynamics kinds, as effects are."""
    for kind, copy in _kind_copies(eff):
        _PROBES[(kind, eff.name)] = copy
    return eff


def probes(kind: str) -> list[Effect]:
    """Return the covariate probes of ``kind`` by name."""
    _ensure_builtins()
    return sorted((e for e in _PROBES.values() if e.kind == kind), key=lambda e: e.name)


def effects(kind: str | None = None) -> list[Effect]:
    """Return the registered effects (of one kind), built-ins first, then plugins, by name."""
    _ensure_builtins()
    out = [e for e in _EFFECTS.values() if kind is None or e.kind == kind]
    return sorted(out, key=lambda e: (KINDS.index(e.kind), e.origin != "built-in", e.name))


def bases(kind: str | None = None) -> list[BaseModel]:
    """Return the registered base models (of one kind)."""
    _ensure_builtins()
    return [b for b in _BASES.values() if kind is None or b.kind == kind]


_INSTANCES: dict[tuple[str, str, int], Effect] = {}


def instance_name(name: str, k: int) -> str:
    """Return the name of the k-th instance of an effect (k = 1: the effect itself; ``maxwell_arm_2``)."""
    return name if k <= 1 else f"{name}_{k}"


def _instance_param_name(name: str, k: int) -> str:
    """Return a parameter's name in the k-th instance: the suffix before the unit (``arm_E_kPa`` ->
    ``arm_E_2_kPa``; ``n`` -> ``n_2``)."""
    b, suffix = split_unit(name)
    return f"{b}_{k}_{suffix}" if suffix else f"{name}_{k}"


def effect_instance(effect: Effect, k: int) -> Effect:
    """Return the k-th instance (k >= 2) of a repeatable effect: named ``<name>_<k>``, its parameters
    ``<param>_<k>`` (own keys, so two instances in one model never share a value), the same physics.

    ``apply`` and ``guess`` see the original parameter keys: the instance maps them back and forth.
    """
    if k <= 1:
        return effect
    if not effect.repeatable:
        raise InputError(f"effect '{effect.name}' ({effect.kind}) cannot be added more than once")
    key = (effect.kind, effect.name, k)
    if key in _INSTANCES:
        return _INSTANCES[key]
    params = tuple(Param(_instance_param_name(p.name, k), p.start, p.bounds, p.off, p.free, p.description)
                   for p in effect.params)
    to_orig = {new.key: old.key for new, old in zip(params, effect.params)}
    to_new = {v: k_ for k_, v in to_orig.items()}
    apply0, guess0 = effect.apply, effect.guess

    def apply(y, x, p, ctx):
        return apply0(y, x, {to_orig.get(k_, k_): v for k_, v in p.items()}, ctx)

    guess = None
    if guess0 is not None:
        def guess(r, x, ctx):
            g = guess0(r, x, ctx) or {}
            return {to_new.get(k_, k_): v for k_, v in g.items()}

    inst = Effect(name=instance_name(effect.name, k), kind=effect.kind,
                  description=f"{effect.description} (instance {k}: its own parameters, suffixed _{k})",
                  source=effect.source, params=params, covariates=effect.covariates, apply=apply, guess=guess,
                  bases=effect.bases, origin=effect.origin, role=effect.role, repeatable=False)
    _INSTANCES[key] = inst
    return inst


def _split_instance(name: str) -> tuple[str, int] | None:
    head, _, tail = name.rpartition("_")
    if head and tail.isdigit() and int(tail) >= 2:
        return head, int(tail)
    return None


def next_instance(kind: str, name: str, have: Iterable[str]) -> Effect | None:
    """Return the next instance of a repeatable effect not in ``have`` (``maxwell_arm`` -> ``maxwell_arm_2``
    when the model holds one arm), or None when the effect is not repeatable."""
    eff = get_effect(kind, name)
    if not eff.repeatable:
        return None
    have = set(have)
    k = 2
    while instance_name(name, k) in have:
        k += 1
    return effect_instance(eff, k)


def get_effect(kind: str, name: str, where: str = "") -> Effect:
    """Return the effect ``name`` of ``kind`` (``<name>_<k>``: the k-th instance of a repeatable one);
    InputError with a suggestion when unknown."""
    _ensure_builtins()
    eff = _EFFECTS.get((kind, name)) or _PROBES.get((kind, name))
    if eff is None:
        split = _split_instance(name)
        orig = _EFFECTS.get((kind, split[0])) if split else None
        if orig is not None:
            if not orig.repeatable:
                raise InputError(f"{where}effect '{split[0]}' ({kind}) cannot be added more than once, so "
                                 f"'{name}' is not an effect")
            return effect_instance(orig, split[1])
    if eff is None:
        names = [e.name for e in effects(kind)]
        other = [k for (k, n) in _EFFECTS if n == name]
        hint = difflib.get_close_matches(name, names, n=1)
        msg = f"{where}unknown {kind} effect '{name}'"
        if other:
            msg += f" (it is a {other[0]} effect)"
        elif hint:
            msg += f" (did you mean '{hint[0]}'?)"
        else:
            msg += f" (known: {', '.join(names) or 'none'}; a plugin may add it with --plugins FILE.py)"
        raise InputError(msg)
    return eff


def get_base(kind: str, name: str, where: str = "") -> BaseModel:
    """Return the base model ``name`` of ``kind``; InputError with a suggestion when unknown."""
    _ensure_builtins()
    model = _BASES.get((kind, name))
    if model is None:
        names = [b.name for b in bases(kind)]
        hint = difflib.get_close_matches(name, names, n=1)
        if not names:
            raise InputError(f"{where}no base model of kind '{kind}' is available yet (the loop covers "
                             "friction, pressure and relaxation)")
        raise InputError(f"{where}unknown {kind} base model '{name}'"
                         + (f" (did you mean '{hint[0]}'?)" if hint else f" (known: {', '.join(names)})"))
    return model


# ---------------------------------------------------------------------------
# plugins


def _load_file(path: Path) -> None:
    # a name stable across processes (numba's disk cache of a plugin force refers to its module by name)
    mod_name = f"capsule_cli_plugin_{hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:16]}"
    spec = importlib.util.spec_from_file_location(mod_name, path)
    if spec is None or spec.loader is None:
        raise InputError(f"{path}: cannot be loaded as a Python plugin (use a .py file)")
    module = importlib.util.module_from_spec(spec)
    before = dict(_EFFECTS)
    _CURRENT_ORIGIN.append(f"plugin {path.name}")
    try:
        sys.modules[mod_name] = module
        spec.loader.exec_module(module)
    except SyntaxError as exc:
        _rollback(before)
        raise InputError(f"{path}: line {exc.lineno}: syntax error: {exc.msg}") from None
    except InputError as exc:
        _rollback(before)
        raise InputError(f"{path}: {exc}") from None
    except Exception as exc:  # noqa: BLE001  (a plugin error is the user's input, exit 2)
        _rollback(before)
        tb = traceback.extract_tb(exc.__traceback__)
        line = next((f.lineno for f in reversed(tb) if Path(f.filename) == path), None)
        where = f" line {line}" if line else ""
        raise InputError(f"{path}:{where}: plugin failed: {type(exc).__name__}: {exc}") from None
    finally:
        _CURRENT_ORIGIN.pop()
    if len(_EFFECTS) == len(before) and all(_EFFECTS[k] is before[k] for k in before):
        raise InputError(f"{path}: the plugin registers no effect (use capsule_cli.effects.register_effect)")


def _rollback(before: dict) -> None:
    _EFFECTS.clear()
    _EFFECTS.update(before)


def load_plugins(paths: Iterable[str | Path] | None = None, entry_points: bool = True) -> list[str]:
    """Load plugin files and the ``capsule_cli.effects`` entry points; return what was loaded.

    A file is loaded once per process. Errors (file missing, syntax, a bad
    registration) raise :class:`InputError` with one line naming the file.
    """
    _ensure_builtins()
    loaded = []
    for raw in paths or ():
        path = Path(raw)
        if not path.is_file():
            raise InputError(f"{path}: plugin file not found")
        if path.suffix != ".py":
            raise InputError(f"{path}: a plugin must be a Python file (.py)")
        key = str(path.resolve())
        if key in _LOADED_PLUGINS:
            continue
        _load_file(path)
        _LOADED_PLUGINS.add(key)
        loaded.append(str(path))
    if entry_points:
        for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
            key = f"entry-point {ep.name}={ep.value}"
            if key in _LOADED_PLUGINS:
                continue
            before = dict(_EFFECTS)
            _CURRENT_ORIGIN.append(f"entry point {ep.name}")
            try:
                obj = ep.load()
                if callable(obj):
                    obj()
            except Exception as exc:  # noqa: BLE001
                _rollback(before)
                raise InputError(f"entry point '{ep.name}' ({ep.value}) of group {ENTRY_POINT_GROUP}: "
                                 f"{type(exc).__name__}: {exc}") from None
            finally:
                _CURRENT_ORIGIN.pop()
            _LOADED_PLUGINS.add(key)
            loaded.append(key)
    return loaded
