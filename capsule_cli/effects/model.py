"""Turn a model file (contract section 4) into a calibratable predictor.

:func:`build_model` validates the file's semantics against the registry (base
and effect names, parameter names, bounds) and returns a :class:`Model`;
:meth:`Model.bind` ties it to a table's covariates and returns a
:class:`BoundModel` whose ``predict(theta)`` maps the free-parameter vector
(in the unit of each parameter's suffix) to the response in the table's unit
(mN, kPa). Inside, everything is SI (:mod:`capsule_cli.units`).
"""
from __future__ import annotations

import difflib
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from ..config import FreeParam, ModelFile, config_hash, load_model_file
from ..errors import InputError
from ..tables import LABEL_COLUMNS, response_column
from ..units import split_unit, to_si, unit_factor
from ..validation import call_effect
from .constants import capsule_constants
from .registry import BaseModel, Effect, Param, base_name, get_base, get_effect, si_factor


@dataclass
class ParamSpec:
    """One parameter of a model: where it comes from, its value and whether it is calibrated."""

    key: str  # the key in the model file (plain name, or 'effect.name' when names clash)
    param: Param
    owner: str  # "base" or the effect's name
    value: float  # in the unit of the name's suffix
    free: bool
    bounds: tuple[float, float]

    @property
    def name(self) -> str:
        return self.param.name

    @property
    def si_key(self) -> str:
        return self.param.key

    def to_si(self, v):
        return v * si_factor(self.param.name)


@dataclass
class Model:
    """A validated model: base, effects in order, and its parameters."""

    kind: str
    base: BaseModel
    effects: list[Effect]
    specs: list[ParamSpec]
    name: str
    path: str
    content: dict
    hash: str

    @property
    def effect_names(self) -> list[str]:
        return [e.name for e in self.effects]

    def covariates_needed(self) -> list[str]:
        """Return covariate columns the model needs beyond the kind's required ones."""
        out = list(self.base.covariates)
        for e in self.effects:
            out += [c for c in e.covariates if c not in out]
        return out

    def spec(self, key: str) -> ParamSpec:
        for s in self.specs:
            if s.key == key:
                return s
        raise KeyError(key)

    def with_effect(self, effect: Effect, values: Mapping[str, float] | None = None) -> "Model":
        """Return a copy with ``effect`` appended (its free parameters at ``values`` [declared units])."""
        specs = [replace(s) for s in self.specs]
        taken = {s.key for s in specs}
        for prm in effect.params:
            key = prm.name if prm.name not in taken else f"{effect.name}.{prm.name}"
            v = prm.start if values is None or prm.name not in values else float(values[prm.name])
            lo, hi = prm.bounds
            specs.append(ParamSpec(key, prm, effect.name, float(np.clip(v, lo, hi)), prm.free, prm.bounds))
        content = dict(self.content)
        content["effects"] = list(self.effect_names) + [effect.name]
        return Model(self.kind, self.base, self.effects + [effect], specs, f"{self.name}+{effect.name}",
                     self.path, content, model_content_hash(content))

    def with_values(self, values: Mapping[str, float]) -> "Model":
        """Return a copy whose parameter values (keyed by spec key) are replaced."""
        specs = [replace(s, value=float(values[s.key])) if s.key in values else replace(s) for s in self.specs]
        return replace(self, specs=specs)

    def bind(self, df: pd.DataFrame, where: str = "") -> "BoundModel":
        """Return the model tied to the covariates of ``df`` (a measurement or design table)."""
        return BoundModel(self, df, where)

    def to_yaml_dict(self, values: Mapping[str, float] | None = None, name: str | None = None,
                     notes: str = "") -> dict:
        """Return a model-file mapping (contract section 4); free parameters keep their bounds."""
        params = {}
        for s in self.specs:
            v = float(values[s.key]) if values and s.key in values else s.value
            if not np.isfinite(v):
                v_out: float | str = v
            else:
                v_out = float(f"{v:.6g}")
            given = s.key in (self.content.get("params") or {})
            if s.free:
                lo, hi = s.bounds
                params[s.key] = {"value": v_out, "free": True, "bounds": [float(f"{lo:.6g}"), float(f"{hi:.6g}")]}
            elif given or s.owner != "base":
                params[s.key] = v_out
        out = {"kind": self.kind, "base": self.base.name, "effects": list(self.effect_names), "params": params}
        if self.content.get("protocol"):
            out["protocol"] = dict(self.content["protocol"])
        if name:
            out["name"] = name
        if notes:
            out["notes"] = notes
        return out


def model_content_hash(content: Mapping) -> str:
    """Return the hash of what defines a model (kind, base, effects, params), not its name or notes."""
    keys = ("kind", "base", "effects", "params") + (("protocol",) if content.get("protocol") else ())
    return config_hash({k: content.get(k) for k in keys})


def build_model(source: str | os.PathLike | ModelFile, path: str | None = None) -> Model:
    """Return a :class:`Model` from a model file (path or parsed), validating its semantics.

    Unknown base, effect or parameter names raise :class:`InputError` naming the
    file and the key with a suggestion. Load plugins first when the file uses them.
    """
    if isinstance(source, ModelFile):
        mf = source
        where = path or "<model>"
    else:
        where = str(source)
        mf = load_model_file(source)
    pre = f"{where}: "
    if mf.protocol is not None and mf.kind not in ("progression", "trajectory"):
        raise InputError(f"{pre}protocol: only dynamics models (progression, trajectory) say how conditions were run")
    base = get_base(mf.kind, mf.base, where=f"{where}: base: ")
    effs: list[Effect] = []
    for i, name in enumerate(mf.effects):
        eff = get_effect(mf.kind, name, where=f"{where}: effects[{i}]: ")
        if eff.bases and base.name not in eff.bases:
            raise InputError(f"{pre}effects[{i}]: effect '{name}' applies to base {' or '.join(eff.bases)}, "
                             f"not '{base.name}'")
        if name in [e.name for e in effs]:
            raise InputError(f"{pre}effects[{i}]: effect '{name}' listed twice")
        effs.append(eff)

    owners: list[tuple[str, Param]] = [("base", p) for p in base.params]
    for e in effs:
        owners += [(e.name, p) for p in e.params]
    counts: dict[str, int] = {}
    for _, p in owners:
        counts[p.name] = counts.get(p.name, 0) + 1
    keys = [(p.name if counts[p.name] == 1 else f"{o}.{p.name}") for o, p in owners]
    given = dict(mf.params or {})
    specs = []
    for key, (owner, prm) in zip(keys, owners):
        raw = given.pop(key, None)
        if raw is None and counts[prm.name] > 1 and prm.name in given:
            raise InputError(f"{pre}params.{prm.name}: ambiguous (several effects have it): write "
                             f"'{key}'")
        value, free, bounds = prm.start, (prm.free and owner != "base"), prm.bounds
        if isinstance(raw, FreeParam):
            value, free = raw.value, raw.free
            if raw.bounds is not None:
                bounds = (float(raw.bounds[0]), float(raw.bounds[1]))
        elif raw is not None:
            value, free = float(raw), False
        if free:
            lo, hi = bounds
            if not (lo <= value <= hi):
                raise InputError(f"{pre}params.{key}: value {value} outside its bounds [{lo}, {hi}]")
            if not (np.isfinite(value)):
                raise InputError(f"{pre}params.{key}: a free parameter needs a finite value")
        specs.append(ParamSpec(key, prm, owner, float(value), bool(free), (float(bounds[0]), float(bounds[1]))))
    if given:
        bad = next(iter(given))
        hint = difflib.get_close_matches(bad, keys, n=1)
        raise InputError(f"{pre}params.{bad}: unknown parameter of {mf.kind} model '{base.name}'"
                         + (f" with {', '.join(mf.effects)}" if mf.effects else "")
                         + (f" (did you mean '{hint[0]}'?)" if hint else f" (parameters: {', '.join(keys)})"))
    content = mf.model_dump(mode="json", exclude_none=True)
    name = mf.name or Path(where).stem
    return Model(mf.kind, base, effs, specs, name, where, content, model_content_hash(content))


# ---------------------------------------------------------------------------
# binding to a table


def covariates_si(df: pd.DataFrame, response: str | None = None) -> dict[str, np.ndarray]:
    """Return ``{base name: SI array}`` of a table's numeric covariates (+ label columns as strings)."""
    x: dict[str, np.ndarray] = {}
    for col in df.columns:
        if col == response:
            continue
        if col in LABEL_COLUMNS:
            x[col] = df[col].astype(str).to_numpy()
            continue
        if not pd.api.types.is_numeric_dtype(df[col]):
            continue
        b, suffix = split_unit(col)
        key = b if suffix else col
        x[key] = np.asarray(to_si(df[col].to_numpy(dtype=float), col), float)
    return x


class FreeParams:
    """The free parameters of a model tied to a table (shared by :class:`BoundModel` and the dynamics loop's
    ``DynBound``): needs ``self.model`` (a :class:`Model`) and ``self.free`` (its free :class:`ParamSpec` s).
    Values in the unit of each name's suffix (as in the model file)."""

    model: "Model"
    free: list

    @property
    def names(self) -> list[str]:
        return [s.key for s in self.free]

    @property
    def x0(self) -> np.ndarray:
        return np.array([s.value for s in self.free], float)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return (np.array([s.bounds[0] for s in self.free], float), np.array([s.bounds[1] for s in self.free], float))

    def values(self, theta: Sequence[float] | None = None) -> dict[str, float]:
        """Return ``{spec key: value}`` (declared units) with the free ones from ``theta``."""
        vals = {s.key: s.value for s in self.model.specs}
        if theta is not None:
            for s, v in zip(self.free, theta):
                vals[s.key] = float(v)
        return vals


@dataclass
class BoundModel(FreeParams):
    """A model tied to a table's covariates: ``predict(theta)`` in the response unit."""

    model: Model
    df: pd.DataFrame
    where: str = ""
    x: dict = field(init=False)
    free: list[ParamSpec] = field(init=False)
    column_keys: list[str] = field(init=False)
    response: str = field(init=False)

    def __post_init__(self):
        m = self.model
        self.response = response_column(m.kind)
        self.x = covariates_si(self.df, self.response)
        cols = set(self.df.columns)
        needed = [c for c in _kind_covariates(m.kind)] + m.covariates_needed()
        have = {base_name(c) for c in cols}
        for c in needed:
            if base_name(c) not in have:
                who = next((e.name for e in m.effects if c in e.covariates), m.base.name)
                raise InputError(f"{self.where or 'table'}: missing column '{c}' (needed by '{who}')")
        self.column_keys = []
        for s in m.specs:
            if s.param.name in cols:  # a column of the same name replaces the parameter row by row
                if s.free:
                    raise InputError(f"{m.path}: params.{s.key}: free, but the table gives '{s.param.name}' "
                                     "row by row: fix it or drop the column")
                self.column_keys.append(s.key)
        self.free = [s for s in m.specs if s.free and s.key not in self.column_keys]
        self._consts = capsule_constants()
        self._unit = unit_factor(self.response)
        # SI factors once at binding, not inside every prediction (the fits call predict thousands of times)
        self._by_owner: dict[str, list[tuple[ParamSpec, str, float]]] = {}
        for s in m.specs:
            self._by_owner.setdefault(s.owner, []).append((s, s.si_key, si_factor(s.param.name)))

    @property
    def n(self) -> int:
        return len(self.df)

    def observed(self) -> np.ndarray:
        return self.df[self.response].to_numpy(dtype=float)

    def _params_si(self, vals: Mapping[str, float], owner: str, rows: np.ndarray | None) -> dict:
        out = {}
        for s, key, f in self._by_owner.get(owner, ()):
            if s.key in self.column_keys:
                v = self.df[s.param.name].to_numpy(dtype=float)
                out[key] = (v if rows is None else v[rows]) * f
            else:
                out[key] = vals[s.key] * f
        return out

    def predict_si(self, theta=None, rows: np.ndarray | None = None, upto: int | None = None,
                   x: Mapping | None = None) -> np.ndarray:
        """Return the response in SI at the table's rows (or ``rows``); ``upto`` effects only."""
        vals = self.values(theta)
        xx = x if x is not None else (self.x if rows is None else {k: v[rows] for k, v in self.x.items()})
        pb = self._params_si(vals, "base", rows)
        ctx = {**self._consts, **pb}
        n = next((len(v) for v in xx.values() if np.ndim(v) == 1), self.n)  # rows evaluated
        base = self.model.base
        y = call_effect(base, base.predict, n, xx, pb, ctx)
        effs = self.model.effects if upto is None else self.model.effects[:upto]
        for e in effs:  # a plugin that raises or returns a wrong shape: exit 2 naming it (validation layer)
            y = call_effect(e, e.apply, n, y, xx, self._params_si(vals, e.name, rows), ctx)
        return y

    def predict(self, theta=None, rows: np.ndarray | None = None) -> np.ndarray:
        """Return the model's response in the table's unit (mN, kPa) at the table's rows."""
        return self.predict_si(theta, rows) / self._unit

    def context(self, theta=None) -> dict:
        """Return ctx (constants and base parameters, SI) at ``theta``."""
        return {**self._consts, **self._params_si(self.values(theta), "base", None)}


def _kind_covariates(kind: str) -> list[str]:
    from ..tables import MEASUREMENT_KINDS

    resp = response_column(kind)
    return [c for c in MEASUREMENT_KINDS[kind]["required"] if c != resp]
