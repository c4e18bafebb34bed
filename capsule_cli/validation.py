"""The one validation layer of run-time checks that end in exit code 2 (contract section 5).

Load-time checks live with their loaders (tables: :func:`capsule_cli.tables.read_measurements`;
model files: :mod:`capsule_cli.config`); this module holds what is checked around them:

* :func:`check_output_path` / :func:`check_ledger` -- an output that cannot be written is
  bad input, found *before* any work, naming the path;
* :func:`call_effect` -- a plugin function that raises or returns the wrong shape names
  the plugin and the effect (a built-in that does so is a bug and propagates);
* :func:`check_model_output` -- NaN/inf in a model's output at the start values or at the
  solution names the effect (or base model) that produced it and the first row;
* :func:`check_bounds` -- a model-file value outside its own bounds, for every command.

Every function raises :class:`capsule_cli.errors.InputError` with one line.
"""
from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from .errors import InputError

# ---------------------------------------------------------------------------
# output paths


def _first_existing(path: Path) -> Path:
    """Return ``path`` or its nearest existing ancestor."""
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def check_output_path(path: str | os.PathLike | None, option: str = "--out", folder: bool = False) -> None:
    """Raise InputError unless ``path`` can be written: a folder (``folder=True``) or a file.

    Checks the name is usable, that an existing path has the right type, and that the
    nearest existing ancestor is a folder we may write into. Nothing is created.
    """
    if path is None:
        return
    p = Path(path)
    text = str(path)
    if text.strip() == "" or "\x00" in text:
        raise InputError(f"{option} '{text}': not a valid path")
    for part in p.parts:
        if len(os.fsencode(part)) > 255:
            raise InputError(f"{option} {p}: a path component is longer than 255 bytes")
    if p.exists():
        if folder and not p.is_dir():
            raise InputError(f"{option} {p}: exists and is not a folder")
        if not folder and p.is_dir():
            raise InputError(f"{option} {p}: is a folder, expected a file")
        target = p if folder else p.parent
    else:
        anc = _first_existing(p.parent if not folder else p)
        if not anc.is_dir():
            raise InputError(f"{option} {p}: cannot be created ({anc} is not a folder)")
        target = anc
    if not os.access(target, os.W_OK | os.X_OK):
        raise InputError(f"{option} {p}: cannot write into {target} (permission denied)")
    _probe(target, p, option)


def _probe(folder: Path, p: Path, option: str) -> None:
    """Create and remove a file in ``folder``: catches read-only file systems that os.access misses."""
    import tempfile

    try:
        fd, tmp = tempfile.mkstemp(prefix=".capsule-cli-probe.", dir=folder)
    except OSError as exc:
        raise InputError(f"{option} {p}: cannot write into {folder} ({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(tmp)


def check_ledger(path: str | os.PathLike | None) -> None:
    """Raise InputError unless a ledger row can be appended to ``path`` (checked before any work)."""
    if path is None:
        return
    check_output_path(path, "--ledger")
    p = Path(path)
    if p.suffix.lower() != ".parquet":
        raise InputError(f"--ledger {p}: must end with .parquet")
    if p.is_file():
        from .steps.ledger import read_ledger

        read_ledger(p)  # an existing file must be a ledger (InputError otherwise)


def oserror_message(exc: OSError) -> str | None:
    """Return a one-line message for an OSError caused by a path the user gave, else None.

    Used by the CLI as the last line of defence: permissions, read-only or full disks,
    and paths that are files where folders are needed are bad input (exit 2), not bugs.
    """
    user = (errno.EACCES, errno.EPERM, errno.EROFS, errno.ENOSPC, errno.EDQUOT, errno.ENOTDIR, errno.EISDIR,
            errno.EEXIST, errno.ENAMETOOLONG, errno.ENOENT)
    if exc.errno not in user:
        return None
    where = exc.filename if exc.filename is not None else "(path)"
    return f"{where}: {exc.strerror or type(exc).__name__} (check the path and its permissions)"


# ---------------------------------------------------------------------------
# plugin functions and model output


def call_effect(effect, fn: Callable, n: int, *args) -> np.ndarray:
    """Call a base-model or effect function; a plugin's failure is InputError naming plugin and effect.

    ``effect`` is the registry entry (``.name``, ``.origin``); ``n`` the number of rows the
    result must have. A built-in's exception propagates unchanged (it is a bug: exit 1).
    """
    origin = getattr(effect, "origin", "built-in")
    plugin = origin != "built-in"
    if not plugin:
        return np.asarray(fn(*args), float)
    label = f"{origin}: effect '{effect.name}'"
    try:
        out = fn(*args)
    except (KeyboardInterrupt, SystemExit, MemoryError):
        raise
    except Exception as exc:  # noqa: BLE001  (the user's plugin failed: exit 2)
        msg = str(exc).splitlines()[0] if str(exc) else ""
        raise InputError(f"{label} raised {type(exc).__name__}" + (f": {msg}" if msg else "")) from None
    try:
        arr = np.asarray(out, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{label} returned {type(out).__name__}, not an array of numbers") from None
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise InputError(f"{label} returned shape {arr.shape}, expected ({n},) (one value per row)")
    return arr


def _first_bad(y: np.ndarray) -> int:
    return int(np.argmax(~np.isfinite(y)))


def check_model_output(bound, theta: Sequence[float] | None, stage: str) -> np.ndarray:
    """Return ``bound.predict(theta)``; InputError naming the culprit if it is not finite.

    ``stage`` says where (``start values``, ``solution``). The culprit is found by evaluating
    the base model and then the effects one by one: the first whose output turns non-finite
    is named, with the first such row.
    """
    y = np.asarray(bound.predict(theta), float)
    if np.isfinite(y).all():
        return y
    m = bound.model
    culprit, bad = f"base model '{m.base.name}'", y
    for upto in range(len(m.effects) + 1):
        yy = np.asarray(bound.predict_si(theta, upto=upto), float)
        if not np.isfinite(yy).all():
            bad = yy
            if upto > 0:
                e = m.effects[upto - 1]
                culprit = f"effect '{e.name}'" + (f" ({e.origin})" if e.origin != "built-in" else "")
            break
    i = _first_bad(bad)
    shown = ", ".join(f"{k}={v:g}" for k, v in bound.values(theta).items())
    raise InputError(f"{m.path}: {culprit} gives {bad[i]} at data row {i + 1} at the {stage}"
                     + (f" ({shown})" if shown else ""))


def check_bounds(values: Mapping[str, float], bounds: Mapping[str, tuple[float, float]], where: str) -> None:
    """Raise InputError when a value lies outside its model-file bounds [lower, upper]."""
    for k, (lo, hi) in bounds.items():
        if k in values and not (lo <= values[k] <= hi):
            raise InputError(f"{where}: params.{k}: value {values[k]:g} outside its bounds [{lo:g}, {hi:g}]")


def check_model_file_bounds(model: str | os.PathLike, overrides: Mapping[str, float] | None = None) -> None:
    """Raise InputError when a model file's value (or its ``--set`` override) lies outside the file's bounds.

    ``model`` may also be a parameter-set name (no bounds: nothing to check). Called by every
    command that reads a model file (compare, diagnose, synth, friction predict, simulate, sweep),
    so that a file one command accepts is accepted by all.
    """
    from .config import FreeParam, load_model_file, read_yaml

    p = Path(model)
    if p.suffix.lower() not in (".yaml", ".yml") or not p.is_file():
        return
    data = read_yaml(p)
    if not (isinstance(data, dict) and "kind" in data and "base" in data):
        return  # a parameter-set file
    mf = load_model_file(p)
    values, bounds = {}, {}
    for key, val in (mf.params or {}).items():
        if isinstance(val, FreeParam) and val.bounds is not None:
            values[key] = val.value
            bounds[key] = (float(val.bounds[0]), float(val.bounds[1]))
    for key, v in (overrides or {}).items():
        if key in bounds:
            values[key] = float(v)
    check_bounds(values, bounds, str(p))
