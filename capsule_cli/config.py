"""Configuration: parameter sets with citations, study configs and model files.

One place resolves and validates every YAML the project reads (style.md section 3):

* ``configs/params/*.yaml`` -- the papers' parameter sets, each value with its
  source (:func:`load_param_set`, :class:`ParamSetFile`);
* ``configs/study.yaml`` / ``configs/smoke.yaml`` -- study configs read by both
  the CLI and the Snakefile (:func:`load_study_config`, :class:`StudyConfig`);
* model files (contract section 4, :func:`load_model_file`, :class:`ModelFile`).

Unknown keys are errors everywhere: a misspelt key stops with one line that
names the file, the key and the closest valid key (exit code 2).
"""
from __future__ import annotations

import difflib
import functools
import hashlib
import json
import math
import os
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, Field, ValidationError, field_validator

from .config_base import Strict
from .errors import InputError
from .units import UNITS, split_unit

# ---------------------------------------------------------------------------
# locations


def repo_root() -> Path:
    """Return the project root (the folder holding ``configs/``)."""
    return Path(__file__).resolve().parents[1]


def configs_dir() -> Path:
    """Return the ``configs/`` folder (override with ``CAPSULE_CLI_CONFIGS``)."""
    env = os.environ.get("CAPSULE_CLI_CONFIGS")
    return Path(env) if env else repo_root() / "configs"


# ---------------------------------------------------------------------------
# YAML reading and error formatting


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate keys (a silent override is a typo)."""


_HAVE_LIBYAML = hasattr(yaml, "CSafeLoader")


class _FastStrictLoader(yaml.CSafeLoader if _HAVE_LIBYAML else yaml.SafeLoader):
    """The same with libyaml's parser when PyYAML has it (about 10 times faster; every command's start-up
    reads several YAML files); the constructors are the same safe ones."""


def _construct_mapping(loader, node, deep=False):
    keys = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in keys:
            raise InputError(f"duplicate key '{key}' at line {key_node.start_mark.line + 1}")
        keys.add(key)
    return yaml.SafeLoader.construct_mapping(loader, node, deep)


for _loader in (_StrictLoader, _FastStrictLoader):
    _loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def read_yaml(path: str | os.PathLike) -> Any:
    """Return the parsed content of a YAML file; InputError (exit 2) if unreadable.

    Parsed with libyaml when available; a file it rejects is parsed again by the pure-Python parser,
    whose message names the offending character, so that the error reads the same either way.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: file not found")
    try:
        try:
            with open(p, encoding="utf-8") as fh:
                return yaml.load(fh, Loader=_FastStrictLoader)
        except yaml.YAMLError:
            if not _HAVE_LIBYAML:
                raise
            with open(p, encoding="utf-8") as fh:
                return yaml.load(fh, Loader=_StrictLoader)
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise InputError(f"{p}:{where}: invalid YAML: {problem}") from None


def _known_fields(model: type[BaseModel], loc: tuple) -> list[str]:
    """Return the valid keys at ``loc`` (for 'did you mean')."""
    cur: Any = model
    for part in loc[:-1]:
        if isinstance(part, int) or not (isinstance(cur, type) and issubclass(cur, BaseModel)):
            return []
        field = cur.model_fields.get(part)
        if field is None:
            return []
        ann = field.annotation
        cur = ann if isinstance(ann, type) else None
    if isinstance(cur, type) and issubclass(cur, BaseModel):
        return list(cur.model_fields)
    return []


#: tags pydantic puts into an error's location for the branch of a union (``float | FreeParam``)
_UNION_TAGS = ("float", "FreeParam", "int", "str", "bool")


def _relevant_errors(errors: list[dict]) -> list[dict]:
    """Drop union-branch errors that cannot apply: a mapping given where a number or mapping is allowed
    fails the number branch too ("Input should be a valid number"); the mapping branch says why."""
    def number_branch_of_mapping(e):
        loc = tuple(e.get("loc", ()))
        return bool(loc) and loc[-1] in ("float", "int") and isinstance(e.get("input"), dict)

    kept = [e for e in errors if not number_branch_of_mapping(e)]
    return kept or list(errors)


def format_validation_error(path: str | os.PathLike, exc: ValidationError, model: type[BaseModel]) -> str:
    """Return one line naming the file, the key path and what is wrong."""
    errors = _relevant_errors(exc.errors())
    errors = sorted(errors, key=lambda e: e.get("type") != "extra_forbidden")  # typos first
    err = errors[0]
    loc = tuple(p for p in err.get("loc", ()) if p not in _UNION_TAGS)
    where = ".".join(str(p) for p in loc) or "(top level)"
    if err.get("type") == "extra_forbidden":
        known = _known_fields(model, loc)
        hint = difflib.get_close_matches(str(loc[-1]), known, n=1)
        msg = f"unknown key '{loc[-1]}'" + (f" (did you mean '{hint[0]}'?)" if hint else "")
        if known and not hint:
            msg += f" (valid keys: {', '.join(known)})"
    else:
        msg = err.get("msg", "invalid value").removeprefix("Value error, ")
        if "input" in err and not isinstance(err["input"], (dict, list)) and "NaN" not in msg:
            msg += f" (got {err['input']!r})"
        if msg.startswith(where + "."):  # the validator named the key itself
            where, msg = msg.split(":", 1)[0], msg.split(":", 1)[1].strip()
    more = len(errors) - 1
    return f"{path}: {where}: {msg}" + (f" [+{more} more]" if more > 0 else "")


def validate(model: type[BaseModel], data: Any, path: str | os.PathLike):
    """Validate ``data`` against a pydantic ``model``; InputError with one line on failure."""
    try:
        return model.model_validate(data if data is not None else {})
    except ValidationError as exc:
        raise InputError(format_validation_error(path, exc, model)) from None


def config_hash(data: Any) -> str:
    """Return a short stable hash of a config's content (sha256 of canonical JSON)."""
    blob = json.dumps(data, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


# ---------------------------------------------------------------------------
# parameter sets (configs/params/*.yaml)


class ParamEntry(Strict):
    """One published parameter: value in the unit of its name's suffix, with its source."""

    value: float = Field(description="value in the unit given by the parameter name's suffix")
    source: str = Field(min_length=3, description="citation: seed file and table/equation/section")
    description: str = Field(default="", description="what the parameter is")


class ParamSetFile(Strict):
    """A parameter set from the papers: ``params`` maps unit-suffixed names to cited values."""

    title: str = Field(description="what the set describes")
    source: str = Field(description="the main citation")
    notes: str = Field(default="", description="interpretation choices, ambiguities resolved")
    params: dict[str, ParamEntry] = Field(description="name (with unit suffix) -> entry")



def param_set_path(name: str) -> Path:
    """Return the path of ``configs/params/<name>.yaml``."""
    return configs_dir() / "params" / f"{name}.yaml"


def load_param_set_file(name_or_path: str | os.PathLike) -> ParamSetFile:
    """Return a validated parameter-set file, by name (``capsule``) or path."""
    p = Path(name_or_path)
    if p.suffix not in (".yaml", ".yml"):
        p = param_set_path(str(name_or_path))
    return validate(ParamSetFile, read_yaml(p), p)


def load_param_set(name_or_path: str | os.PathLike) -> dict[str, float]:
    """Return ``{name: value}`` of a parameter set, values in the unit of each name's suffix.

    Convert with :func:`capsule_cli.units.to_si` (or use :func:`load_param_set_si`). Values are cached by
    (path, modification time, size): the dynamics loop builds a system per model evaluation (thousands per
    diagnose), and re-parsing the YAML was half the cost of a closed-form evaluation. A new dict each call.
    """
    p = Path(name_or_path)
    if p.suffix not in (".yaml", ".yml"):
        p = param_set_path(str(name_or_path))
    try:
        st = p.stat()
    except OSError:
        return {k: e.value for k, e in load_param_set_file(p).params.items()}  # says why (one line, exit 2)
    return dict(_param_values_cached(str(p), st.st_mtime_ns, st.st_size))


@functools.lru_cache(maxsize=64)
def _param_values_cached(path: str, mtime_ns: int, size: int) -> tuple:
    return tuple((k, e.value) for k, e in load_param_set_file(path).params.items())


def load_param_set_si(name_or_path: str | os.PathLike) -> dict[str, float]:
    """Return ``{base_name: SI value}`` of a parameter set (``Rc_mm: 5.5`` -> ``Rc: 0.0055``)."""
    out = {}
    for name, value in load_param_set(name_or_path).items():
        base, suffix = split_unit(name)
        out[base if suffix else name] = value * (UNITS[suffix][0] if suffix else 1.0)
    return out


# ---------------------------------------------------------------------------
# model files (contract section 4)

MeasurementKind = Literal["friction", "pressure", "relaxation", "progression", "trajectory"]


class FreeParam(Strict):
    """A model parameter that may be freed for calibration."""

    value: float = Field(description="value (start value when free), unit from the name's suffix")
    free: bool = Field(default=False, description="calibrate this parameter")
    bounds: tuple[float, float] | None = Field(default=None, description="[lower, upper] when free")

    @field_validator("value")
    @classmethod
    def _not_nan(cls, v):
        if math.isnan(v):
            raise ValueError("NaN is not a value (give a number)")
        return v

    @field_validator("bounds")
    @classmethod
    def _ordered(cls, v):
        if v is not None and (math.isnan(v[0]) or math.isnan(v[1])):
            raise ValueError(f"bounds must be numbers, got {list(v)}")
        if v is not None and not v[0] < v[1]:
            raise ValueError(f"bounds must be [lower, upper] with lower < upper, got {list(v)}"
                             + (" (reversed?)" if v[0] > v[1] else ""))
        return v


class RunProtocol(Strict):
    """How each condition of dynamics data was run (contract section 4 ``protocol``).

    Defaults where the file is silent: every condition from rest, 120 transient periods,
    60 recorded periods (the dynamics stage's defaults, configs/study.yaml).
    """

    start: Literal["rest", "up", "down"] = Field(
        default="rest", description="rest (every condition from rest), up or down (continuation in frequency "
                                    "at each amplitude)")
    transient_periods: int = Field(default=120, ge=0, description="drive periods run first and not recorded [-]")
    recorded_periods: int = Field(default=60, ge=4, description="drive periods over which the average velocity "
                                                                "is taken [-]")


class ModelFile(Strict):
    """A model file: a base model of a measurement kind plus named physical effects."""

    kind: MeasurementKind = Field(description="measurement kind the model predicts")
    base: str = Field(description="base model of that kind (contract section 4)")
    effects: list[str] = Field(default_factory=list, description="effect names, applied in order")
    params: dict[str, float | FreeParam] = Field(default_factory=dict,
                                                 description="fixed numbers or {value, free, bounds}")
    name: str | None = Field(default=None, description="a label for the ledger (default: file stem)")
    notes: str = Field(default="", description="free text")
    protocol: RunProtocol | None = Field(default=None, description="dynamics kinds only: how each condition was "
                                                                   "run (defaults: rest, 120, 60)")

    @field_validator("params")
    @classmethod
    def _fixed_not_nan(cls, v):
        for key, val in v.items():
            if isinstance(val, float) and math.isnan(val):
                raise ValueError(f"params.{key}: NaN is not a value (give a number)")
        return v


def load_model_file(path: str | os.PathLike) -> ModelFile:
    """Return a structurally validated model file (semantics are checked by the effects registry)."""
    data = read_yaml(path)
    if not isinstance(data, dict):
        raise InputError(f"{path}: a model file must be a mapping with kind, base, effects, params")
    return validate(ModelFile, data, path)


# ---------------------------------------------------------------------------
# study configs (configs/study.yaml, configs/smoke.yaml)


from .schemas.contact import ContactStudy  # noqa: E402
from .schemas.dynamics import DynamicsStudy  # noqa: E402
from .schemas.friction import FrictionStudy  # noqa: E402
from .schemas.loop import LoopStudy  # noqa: E402


class StudyConfig(Strict):
    """The whole paper study: one section per stage; read by the CLI and the Snakefile."""

    name: str = Field(default="study", description="label of the study (full, smoke, ...)")
    results_dir: str = Field(default="results", description="where tables and figures land")
    seed: int = Field(default=20261121, description="base random seed of the study (synthetic data)")
    contact: ContactStudy = Field(default_factory=ContactStudy, description="contact-pressure stage")
    friction: FrictionStudy = Field(default_factory=FrictionStudy, description="friction stage")
    dynamics: DynamicsStudy = Field(default_factory=DynamicsStudy, description="dynamics stage")
    loop: LoopStudy = Field(default_factory=LoopStudy, description="model-vs-measurement loop demos")


def load_study_config(path: str | os.PathLike) -> StudyConfig:
    """Return a validated study config from a YAML file."""
    return validate(StudyConfig, read_yaml(path), path)


def validate_study_config(data: dict, path: str = "<config>") -> StudyConfig:
    """Validate an already-parsed study config (the Snakefile's ``config``)."""
    return validate(StudyConfig, data, path)


def finite_or_inf(x: float) -> float:
    """Return ``x`` as float, accepting YAML ``.inf`` (used for P_f = ∞)."""
    return math.inf if x is None else float(x)
