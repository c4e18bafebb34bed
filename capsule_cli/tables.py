"""The only Parquet I/O of the project: table schemas, atomic writes, provenance,
and validation of measurement tables (contract section 3).

Every table written by the project has a :class:`TableSchema`; each column's
unit and description go into the Parquet field metadata and the provenance
(package version, git commit, config hash, command line, seed, synthetic flag)
into the schema metadata under the key ``capsule_cli``.
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import socket
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from . import __version__
from .errors import InputError
from .units import UNITS, convert, dimension, split_unit, unit_label

PROVENANCE_KEY = b"capsule_cli"

# ---------------------------------------------------------------------------
# atomic writes


def _stage_prefix(path: Path) -> str:
    """The temporary name's prefix for ``path``: hidden, then the writer's process and host, so that a later run
    can tell a stage left by a killed process from one being written (:func:`remove_stale_stages`)."""
    return f".{path.name}.pid{os.getpid()}@{socket.gethostname()}."


def _process_gone(pid: int) -> bool:
    """True when no process ``pid`` runs on this machine (a process of another user counts as running)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:  # PermissionError: it runs, as another user
        return False
    return False


def remove_stale_stages(path: str | os.PathLike) -> list[Path]:
    """Remove the temporary files and stage folders that runs killed while writing ``path`` left beside it.

    SIGINT and SIGTERM remove them (:func:`atomic_path`, :func:`staged_folder`); SIGKILL, an out-of-memory kill or
    a power cut cannot, and a stage can hold a long run's tables. A temporary is removed only when its name says
    it was made on this host by a process that no longer runs, so that a run writing the same path elsewhere (a
    cluster's shared disk) or now is never touched; one whose process number has since been reused stays. Names
    of the form before this rule (no process in them) are left alone. Returns the paths removed.
    """
    import re
    import shutil

    path = Path(path)
    pattern = re.compile(re.escape(f".{path.name}.pid") + r"(\d+)@(.+)\.[^.]+\.tmp")
    host = socket.gethostname()
    removed = []
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return removed
    for entry in entries:
        m = pattern.fullmatch(entry.name)
        if m is None or m.group(2) != host or int(m.group(1)) == os.getpid() or not _process_gone(int(m.group(1))):
            continue
        stale = Path(entry.path)
        if entry.is_dir(follow_symlinks=False):
            shutil.rmtree(stale, ignore_errors=True)
        else:
            with contextlib.suppress(FileNotFoundError):
                stale.unlink()
        removed.append(stale)
    return removed


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside ``path``; move it into place only on success.

    A failed write (an exception, Ctrl-C, SIGTERM) leaves neither a half-written file
    nor the temporary one; the file gets the permissions the user's umask gives.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_stages(path)
    fd, tmp = tempfile.mkstemp(prefix=_stage_prefix(path), suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; a file gets what the umask gives
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def staged_folder(path: str | os.PathLike):
    """Yield a temporary folder beside the output folder ``path``; on success move its files into ``path``.

    A command writes its whole output set there (tables, figures, JSON). An error, Ctrl-C or SIGTERM before
    the end leaves ``path`` as it was (no residual table without its metrics or figures, no new file beside an
    older run's) and removes the temporary folder. On success ``path`` is created if need be and each file
    moves in by one rename (the same file system), the renames with SIGINT / SIGTERM held
    (:func:`capsule_cli.interrupts.deferred_signals`). Files already in ``path`` that this run does not write
    are left alone. A stage that a killed run left (SIGKILL, a power cut) is removed by the next run that
    writes ``path`` (:func:`remove_stale_stages`).
    """
    import shutil

    from .interrupts import deferred_signals

    path = Path(path).resolve()  # a folder that is a link to another disk: the stage beside its target (renames)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_stages(path)
    stage = Path(tempfile.mkdtemp(prefix=_stage_prefix(path), suffix=".tmp", dir=path.parent))
    try:
        yield stage
        with deferred_signals():
            path.mkdir(exist_ok=True)
            for f in sorted(stage.rglob("*")):  # parents before their files
                dest = path / f.relative_to(stage)
                if f.is_dir():
                    dest.mkdir(exist_ok=True)
                else:
                    os.replace(f, dest)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _umask() -> int:
    """Return the process umask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically and return the path."""
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return Path(path)


def write_json_atomic(path: str | os.PathLike, data) -> Path:
    """Write ``data`` as indented JSON (NaN/inf as null-safe strings) atomically."""
    return write_text_atomic(path, json.dumps(_jsonable(data), indent=2, sort_keys=False) + "\n")


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        x = float(x)
        return x if np.isfinite(x) else (None if np.isnan(x) else ("inf" if x > 0 else "-inf"))
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, Path):
        return str(x)
    return x


# ---------------------------------------------------------------------------
# provenance


def user_path(path: str | os.PathLike) -> str:
    """Return ``path`` as the user would write it from where the command runs: relative to the current
    folder (never an absolute path of this machine in an output), unchanged if already relative."""
    p = Path(path)
    if not p.is_absolute():
        return str(p)
    try:
        return os.path.relpath(p)
    except ValueError:  # another drive (Windows)
        return str(p)


def git_commit() -> str | None:
    """Return the git commit of the source tree (with '-dirty'), or None outside git."""
    root = Path(__file__).resolve().parents[1]
    try:
        sha = subprocess.run(["git", "-C", str(root), "rev-parse", "--short=12", "HEAD"],
                             capture_output=True, text=True, timeout=5)
        if sha.returncode != 0:
            return None
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=5)
        return sha.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


def provenance(config_hash: str | None = None, seed: int | None = None, synthetic: bool = False,
               **extra) -> dict:
    """Return the provenance record stored with every table.

    Parameters
    ----------
    config_hash : hash of the config or model file the table was made from
    seed : random seed used, if any
    synthetic : True for data made by ``capsule-cli synth`` (never a measurement)
    extra : anything else worth recording (model, sources, true parameters ...)
    """
    rec = {
        "package": "capsule-cli",
        "version": __version__,
        "git_commit": git_commit(),
        "config_hash": config_hash,
        "seed": seed,
        "synthetic": bool(synthetic),
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]) if sys.argv else "",
    }
    rec.update(extra)
    return rec


# ---------------------------------------------------------------------------
# schemas


@dataclass(frozen=True)
class Column:
    """A table column: name (with unit suffix), dtype, unit and description."""

    name: str
    dtype: str  # "float64", "int64", "bool", "string"
    description: str
    unit: str | None = None  # default: from the name's suffix
    required: bool = True

    @property
    def unit_text(self) -> str:
        return self.unit if self.unit is not None else unit_label(self.name)


@dataclass(frozen=True)
class TableSchema:
    """A declared table: its columns and what one row is."""

    name: str
    description: str
    columns: tuple[Column, ...]
    allow_extra: bool = False

    def arrow_schema(self, df: pd.DataFrame, meta: dict) -> pa.Schema:
        fields = []
        known = {c.name: c for c in self.columns}
        for name in df.columns:
            col = known.get(name)
            typ = pa.Schema.from_pandas(df[[name]], preserve_index=False).field(name).type
            if col is not None:
                typ = _ARROW[col.dtype]
                fmeta = {"unit": col.unit_text, "description": col.description}
            else:
                fmeta = {"unit": unit_label(name), "description": "extra column"}
            fields.append(pa.field(name, typ, metadata={k: str(v) for k, v in fmeta.items()}))
        return pa.schema(fields, metadata={PROVENANCE_KEY: json.dumps(_jsonable(meta)).encode(),
                                           b"table": self.name.encode(),
                                           b"table_description": self.description.encode()})


_ARROW = {"float64": pa.float64(), "int64": pa.int64(), "bool": pa.bool_(), "string": pa.string()}


def check_frame(df: pd.DataFrame, schema: TableSchema) -> pd.DataFrame:
    """Return ``df`` with columns in schema order and dtypes coerced; ValueError if it does not fit."""
    missing = [c.name for c in schema.columns if c.required and c.name not in df.columns]
    if missing:
        raise ValueError(f"table '{schema.name}' lacks columns {missing}")
    extra = [c for c in df.columns if c not in {k.name for k in schema.columns}]
    if extra and not schema.allow_extra:
        raise ValueError(f"table '{schema.name}' has undeclared columns {extra}")
    order = [c.name for c in schema.columns if c.name in df.columns] + extra
    out = df[order].copy()
    for c in schema.columns:
        if c.name in out.columns:
            if c.dtype == "string":
                out[c.name] = out[c.name].astype("string")
            else:
                out[c.name] = out[c.name].astype(c.dtype)
    return out.reset_index(drop=True)


def write_table(df: pd.DataFrame | Mapping[str, np.ndarray], path: str | os.PathLike, schema: TableSchema,
                prov: dict | None = None) -> Path:
    """Write ``df`` as Parquet with units and provenance, atomically; return the path.

    ``df`` is a DataFrame, or a mapping of column name -> 1-D array (no pandas import: the
    fast path of short commands; :func:`columns_table` makes the same file as the DataFrame would).
    """
    meta = prov if prov is not None else provenance()
    if isinstance(df, Mapping):
        table = columns_table(df, schema, meta)
    else:
        df = check_frame(df, schema)
        table = pa.Table.from_pandas(df, schema=schema.arrow_schema(df, meta), preserve_index=False)
    with atomic_path(path) as tmp:
        write_parquet(table, tmp)
    return Path(path)


#: rows per Parquet row group: pyarrow's default (``pq.write_table``), so the files are the same bytes
ROW_GROUP_ROWS = 1 << 20


def write_parquet(table: pa.Table, path: str | os.PathLike) -> None:
    """Write ``table`` to ``path`` one row group at a time.

    The same file, byte for byte, as ``pq.write_table`` (its row groups are the same size), but Ctrl-C and
    SIGTERM are taken between row groups: one call for a 16.7-million-row trajectory (a `simulate` of 100,000
    periods at 5 kHz) held them for 5.6 s, a row group takes about 0.35 s.
    """
    if table.num_rows <= ROW_GROUP_ROWS:
        pq.write_table(table, path)
        return
    with pq.ParquetWriter(path, table.schema) as writer:
        for start in range(0, table.num_rows, ROW_GROUP_ROWS):
            writer.write_table(table.slice(start, ROW_GROUP_ROWS))


#: pandas' own names of the declared dtypes, for the ``pandas`` schema metadata (Arrow's pandas
#: metadata format) that :func:`columns_table` writes so that reading back gives the same dtypes
_PANDAS_TYPE = {"float64": ("float64", "float64"), "int64": ("int64", "int64"), "bool": ("bool", "bool"),
                "string": ("unicode", "string")}


def columns_table(columns: Mapping[str, np.ndarray], schema: TableSchema, meta: dict) -> pa.Table:
    """Return the Arrow table of ``columns`` (name -> 1-D array) checked against ``schema``.

    The same checks, column order, dtypes and metadata as the DataFrame path of :func:`write_table`
    (:func:`check_frame`, :meth:`TableSchema.arrow_schema`), without importing pandas; only
    declared columns are accepted here.
    """
    known = {c.name: c for c in schema.columns}
    missing = [c.name for c in schema.columns if c.required and c.name not in columns]
    if missing:
        raise ValueError(f"table '{schema.name}' lacks columns {missing}")
    extra = [c for c in columns if c not in known]
    if extra:
        raise ValueError(f"table '{schema.name}' has undeclared columns {extra} (use a DataFrame)")
    cols = [c for c in schema.columns if c.name in columns]
    lengths = {len(columns[c.name]) for c in cols}
    if len(lengths) > 1:
        raise ValueError(f"table '{schema.name}': columns of different lengths {sorted(lengths)}")
    arrays, fields, pmeta = [], [], []
    for c in cols:
        arrays.append(_arrow_array(columns[c.name], c.dtype))
        fields.append(pa.field(c.name, _ARROW[c.dtype],
                               metadata={"unit": str(c.unit_text), "description": str(c.description)}))
        pt, nt = _PANDAS_TYPE[c.dtype]
        pmeta.append({"name": c.name, "field_name": c.name, "pandas_type": pt, "numpy_type": nt, "metadata": None})
    pandas_meta = {"index_columns": [], "column_indexes": [], "columns": pmeta, "attributes": {},
                   "creator": {"library": "pyarrow", "version": pa.__version__},
                   "pandas_version": _pandas_version()}
    sch = pa.schema(fields, metadata={PROVENANCE_KEY: json.dumps(_jsonable(meta)).encode(),
                                      b"table": schema.name.encode(),
                                      b"table_description": schema.description.encode(),
                                      b"pandas": json.dumps(pandas_meta).encode()})
    return pa.Table.from_arrays(arrays, schema=sch)


def _arrow_array(values, dtype: str) -> pa.Array:
    """A null-free Arrow array of ``values`` as ``dtype`` ("float64", "int64", "bool", "string").

    Built from buffers: ``pa.array`` on NumPy input or Python strings imports pandas (about 0.2 s
    of a short command's start-up).
    """
    if dtype == "string":
        data = [str(x).encode("utf-8") for x in values]
        offsets = np.zeros(len(data) + 1, dtype=np.int32)
        np.cumsum([len(b) for b in data], out=offsets[1:])
        return pa.StringArray.from_buffers(len(data), pa.py_buffer(offsets), pa.py_buffer(b"".join(data)))
    arr = np.ascontiguousarray(np.asarray(values).astype(dtype))
    if arr.ndim != 1:
        raise ValueError(f"a table column must be 1-D, got shape {arr.shape}")
    buf = np.packbits(arr, bitorder="little") if dtype == "bool" else arr
    return pa.Array.from_buffers(_ARROW[dtype], arr.size, [None, pa.py_buffer(buf)])


def _pandas_version() -> str:
    """pandas' version string without importing pandas."""
    from importlib.metadata import version

    return version("pandas")


def read_table(path: str | os.PathLike) -> pd.DataFrame:
    """Read a Parquet table written by :func:`write_table` (provenance in ``df.attrs``)."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: file not found")
    try:
        table = pq.read_table(p)
    except (pa.ArrowInvalid, OSError) as exc:
        raise InputError(f"{p}: not a readable Parquet file ({str(exc).splitlines()[0]})") from None
    df = table.to_pandas()
    df.attrs["provenance"] = read_provenance(p)
    return df


def read_provenance(path: str | os.PathLike) -> dict:
    """Return the provenance record of a Parquet file ({} if it has none)."""
    meta = pq.read_schema(path).metadata or {}
    raw = meta.get(PROVENANCE_KEY)
    return json.loads(raw) if raw else {}


def read_column_units(path: str | os.PathLike) -> dict[str, str]:
    """Return ``{column: unit}`` from a Parquet file's field metadata."""
    sch = pq.read_schema(path)
    return {f.name: (f.metadata or {}).get(b"unit", b"").decode() for f in sch}


# ---------------------------------------------------------------------------
# measurement tables (contract section 3)

#: canonical columns: name -> (description, required-for kinds)
LABEL_COLUMNS = {"case", "trial", "statistic", "waveform", "run", "replicate", "group", "source",
                 "kind", "note", "label", "id"}

MEASUREMENT_KINDS: dict[str, dict[str, tuple[str, ...]]] = {
    "friction": {"required": ("speed_mm_s", "friction_mN"),
                 "optional": ("case", "trial", "Ri_mm", "position_mm", "time_s", "bend_radius_mm")},
    "pressure": {"required": ("speed_mm_s", "pressure_kPa"),
                 "optional": ("case", "Ri_mm", "statistic", "bend_radius_mm", "end_length_mm",
                              "coating_mm", "coating_modulus_kPa")},
    "relaxation": {"required": ("time_s", "pressure_kPa"), "optional": ("trial",)},
    "progression": {"required": ("f_Hz", "Pd_N", "velocity_mm_s"),
                    "optional": ("duty", "waveform", "Pf_N", "run")},
    "trajectory": {"required": ("run", "time_s", "capsule_mm"),
                   "optional": ("magnet_mm", "f_Hz", "Pd_N", "duty", "waveform")},
}
#: kinds handled by the engine-based loop (capsule_cli.steps.dynamics_loop.DYN_KINDS); named here so that the
#: quasi-static kinds' compare, diagnose and synth do not import the engine (numba, about 0.5 s)
DYNAMICS_KINDS = ("progression", "trajectory")

#: columns that must be >= 0 (the message names them)
NONNEGATIVE = {"speed": "negative speed", "f": "negative frequency", "Pd": "negative drive amplitude",
               "Ri": "negative radius", "time": "negative time", "Pf": "negative friction level"}

DIMENSIONLESS_COLUMNS = {"duty", "mu"}


def infer_kind(columns: Iterable[str]) -> str | None:
    """Return the measurement kind whose required columns (any unit) are all present."""
    bases = {split_unit(c)[0] for c in columns} | set(columns)
    for kind, spec in MEASUREMENT_KINDS.items():
        if all(split_unit(r)[0] in bases or r in bases for r in spec["required"]):
            return kind
    return None


#: covariates for which +inf is a value (a flat, cut-open intestine; a straight tube)
INFINITE_OK = {"Ri", "bend_radius"}
#: what to do about a missing value in a measured column whose rows may simply be left out
_LOST_FRAME = ("a frame the tracker lost? leave its row out, or pass --drop-incomplete (frames need not be evenly "
               "spaced)")
MISSING_HINT = {"capsule": _LOST_FRAME, "magnet": _LOST_FRAME,
                "velocity": "a condition not measured? leave its row out, or pass --drop-incomplete"}
#: the ``statistic`` values the built-in models of a kind predict (friction: trial averages only)
SUPPORTED_STATISTICS = {"friction": ("avg",), "pressure": ("avg", "max")}


def read_csv_with_comments(path: Path) -> pd.DataFrame:
    """Return a CSV table whose full-line ``#`` comments (citations, notes) are skipped."""
    import pandas as pd
    with open(path, encoding="utf-8") as fh:
        lines = [ln for ln in fh if not ln.lstrip().startswith("#")]
    if not "".join(lines).strip():
        raise pd.errors.EmptyDataError("no data")
    return pd.read_csv(io.StringIO("".join(lines)))


def text_label_columns(df: pd.DataFrame) -> list[str]:
    """Return columns without a unit suffix whose every non-empty cell is text (not a number): notes such as
    ``source_type``; they label rows and take no part in any model."""
    import pandas as pd
    out = []
    for col in df.columns:
        if col in LABEL_COLUMNS or col in DIMENSIONLESS_COLUMNS or split_unit(col)[1] is not None:
            continue
        vals = df[col].dropna()
        if len(vals) and pd.to_numeric(vals, errors="coerce").isna().all():
            out.append(col)
    return out


def incomplete_rows(df: pd.DataFrame, numeric: list[str]) -> np.ndarray:
    """Return a mask of rows with an empty cell in a numeric column (a value not stated)."""
    if not numeric:
        return np.zeros(len(df), bool)
    return df[numeric].isna().to_numpy().any(axis=1)


def unsupported_statistic_rows(df: pd.DataFrame, kind: str) -> np.ndarray:
    """Return a mask of rows whose ``statistic`` (avg, max, min, peak ...) the kind's models do not predict."""
    if "statistic" not in df.columns:
        return np.zeros(len(df), bool)
    ok = SUPPORTED_STATISTICS.get(kind)
    if ok is None:
        return np.zeros(len(df), bool)
    return ~df["statistic"].astype(str).str.strip().str.lower().isin(ok).to_numpy()


def _fail(path, msg):
    raise InputError(f"{path}: {msg}")


def read_measurements(path: str | os.PathLike, kind: str | None = None,
                      drop_incomplete: bool = False) -> tuple[pd.DataFrame, str]:
    """Return ``(table, kind)`` of a validated measurement table (CSV or Parquet).

    Full-line ``#`` comments are skipped; text columns without a unit suffix are row labels
    (:func:`text_label_columns`); ``Ri_mm``/``bend_radius_mm`` may be ``inf``. With ``drop_incomplete``
    (published summary tables such as configs/reference/), columns that are empty throughout, rows with an
    empty numeric cell and rows whose ``statistic`` the kind's models do not predict are left out and listed
    in ``df.attrs['dropped_rows']`` ({row, reason}, 1-based data rows; {column, reason} for optional
    covariates not stated in every row, whose column goes); otherwise they are errors.

    Columns are renamed/converted to the canonical units of contract section 3
    (``speed_m_s`` becomes ``speed_mm_s``); extra covariates must carry a known
    unit suffix. Bad input raises :class:`InputError` with one line naming the
    file, the column and the first offending row.
    """
    import pandas as pd
    p = Path(path)
    if not p.is_file():
        _fail(p, "file not found")
    try:
        if p.suffix.lower() == ".csv":
            df = read_csv_with_comments(p)
        elif p.suffix.lower() in (".parquet", ".pq"):
            df = pq.read_table(p).to_pandas()
        else:
            _fail(p, f"unknown table format '{p.suffix}' (use .csv or .parquet)")
    except InputError:
        raise
    except pd.errors.EmptyDataError:
        _fail(p, "empty table")
    except (pd.errors.ParserError, pa.ArrowInvalid, OSError, UnicodeDecodeError) as exc:
        _fail(p, f"cannot be read ({str(exc).splitlines()[0]})")
    if df.shape[0] == 0:
        _fail(p, "empty table (no rows)")
    df.columns = check_column_names(p, df.columns)
    dropped: list[dict] = []
    if drop_incomplete:
        df = df.dropna(axis=1, how="all")
    texts = text_label_columns(df)
    for col in df.columns:  # every non-label column must carry a known unit suffix
        if col in LABEL_COLUMNS or col in texts or col in DIMENSIONLESS_COLUMNS or split_unit(col)[1] is not None:
            continue
        if "_" in col:
            _fail(p, f"column '{col}': unknown unit suffix '{col.rsplit('_', 1)[-1]}' "
                     "(known: mm, mm_s, mN, N, kPa, s, Hz, C, ...)")
        _fail(p, f"column '{col}': no unit suffix (name covariates like 'temperature_C', "
                 "'position_mm'; labels: case, trial, run)")

    if kind is None:
        kind = infer_kind(df.columns)
        if kind is None:
            _fail(p, "cannot infer the table kind from columns "
                     f"{list(df.columns)}; expected e.g. speed_mm_s + friction_mN (friction) or "
                     "time_s + pressure_kPa (relaxation); or give --kind")
    if kind not in MEASUREMENT_KINDS:
        _fail(p, f"unknown kind '{kind}' (one of {', '.join(MEASUREMENT_KINDS)})")
    spec = MEASUREMENT_KINDS[kind]
    canonical = list(spec["required"]) + list(spec["optional"])
    canon_by_base = {split_unit(c)[0]: c for c in canonical if split_unit(c)[1]}

    rename, numeric = {}, []
    for col in df.columns:
        if col in LABEL_COLUMNS or col in texts:
            continue
        base, suffix = split_unit(col)
        target = canon_by_base.get(base) if suffix else None
        if target is not None and target != col:  # e.g. speed_m_s -> speed_mm_s
            if dimension(target) != dimension(suffix):
                _fail(p, f"column '{col}': unit '{UNITS[suffix][1]}' does not fit "
                         f"'{target}' ({unit_label(target)})")
            if target in df.columns:
                _fail(p, f"columns '{col}' and '{target}' both given")
            rename[col] = target
        numeric.append(rename.get(col, col))
    df = df.rename(columns=rename)
    missing = [c for c in spec["required"] if c not in df.columns]
    if missing:
        _fail(p, f"missing column '{missing[0]}' for a {kind} table (required: "
                 f"{', '.join(spec['required'])})")

    if drop_incomplete:
        # a covariate not stated for every row cannot be used: its column goes; rows missing a required value go
        part = [c for c in numeric if c not in spec["required"] and df[c].isna().any()]
        for c in part:
            dropped.append({"column": c, "reason": f"column '{c}' is empty in {int(df[c].isna().sum())} rows"})
        df = df.drop(columns=part)
        numeric = [c for c in numeric if c not in part]
        bad = incomplete_rows(df, numeric) | unsupported_statistic_rows(df, kind)
        for i in np.flatnonzero(bad):
            why = ("an empty numeric cell" if incomplete_rows(df.iloc[[i]], numeric)[0] else
                   f"statistic '{df['statistic'].iloc[i]}' (the {kind} models predict "
                   f"{', '.join(SUPPORTED_STATISTICS[kind])})")
            dropped.append({"row": int(i) + 1, "reason": why})
        dropped = [d for d in dropped if "column" in d] + [d for d in dropped if "row" in d]
        df = df.loc[~bad].reset_index(drop=True)
        if df.empty:
            _fail(p, "no complete rows left (every row has an empty numeric cell or an unsupported statistic)")
    elif unsupported_statistic_rows(df, kind).any():
        i = int(np.argmax(unsupported_statistic_rows(df, kind)))
        _fail(p, f"column 'statistic' row {i + 1}: '{df['statistic'].iloc[i]}' is not predicted by the {kind} "
                 f"models ({', '.join(SUPPORTED_STATISTICS[kind])}); leave such rows out (--drop-incomplete)")
    for col in numeric:
        df[col] = numeric_column(p, col, df[col])
    for col, target in rename.items():
        df[target] = convert(df[target].to_numpy(), col, target)
    for col in df.columns:
        if col in LABEL_COLUMNS and df[col].isna().any():
            i = int(np.argmax(df[col].isna().to_numpy()))
            _fail(p, f"column '{col}' row {i + 1}: missing label")
    if kind == "trajectory":
        check_frame_order(p, df)
    df.attrs["source_path"] = str(p)
    df.attrs["kind"] = kind
    df.attrs["dropped_rows"] = dropped
    df.attrs["text_labels"] = texts
    df.attrs["provenance"] = _measurement_provenance(p)
    return df, kind


def check_frame_order(path, df: pd.DataFrame) -> None:
    """InputError unless each run's frames come in increasing ``time_s`` (runs may interleave).

    A trajectory run is compared frame after frame from rest (its drift, its successive differences, its
    residuals' correlation along time), so a frame out of order or two frames at one time are a table error,
    named at the first such row (1-based data row), not something to guess around."""
    import pandas as pd
    t = df["time_s"].to_numpy(float)
    rows = pd.Series(np.arange(len(df)))
    prev = rows.groupby(df["run"].to_numpy(), sort=False).shift().to_numpy()  # the run's frame before, NaN first
    has = ~np.isnan(prev)
    j = np.flatnonzero(has)[t[has] <= t[prev[has].astype(int)]]
    if j.size:
        i, k = int(j[0]), int(prev[j[0]])
        _fail(path, f"column 'time_s' row {i + 1}: run '{df['run'].iloc[i]}' has t = {t[i]:g} s after {t[k]:g} s "
                    f"(row {k + 1}); each run's frames must come in increasing time (sort by run, time_s)")


def check_column_names(path, columns: Iterable) -> list[str]:
    """Return the column names stripped of surrounding spaces; InputError on a duplicated name.

    A CSV reader renames a repeated header ``x`` to ``x.1``; that, and names that only
    differ by surrounding spaces, are reported as the duplicate they are.
    """
    names = [str(c).strip() for c in columns]
    seen: dict[str, int] = {}
    for j, name in enumerate(names):
        base, dot, num = name.rpartition(".")
        if dot and num.isdigit() and base in names[:j] and name not in names[:j]:
            name = base  # pandas' mangled duplicate
        if name in seen:
            _fail(path, f"column '{name}' given twice (header columns {seen[name] + 1} and {j + 1})")
        seen[name] = j
    return names


def _cell_float(v) -> float:
    """Return one cell as a float (inf when too large, NaN when not a number)."""
    if v is None or (isinstance(v, float) and np.isnan(v)):
        return np.nan
    try:
        return float(str(v).strip())
    except (ValueError, OverflowError):
        return np.nan


def numeric_column(path, col: str, raw: pd.Series) -> np.ndarray:
    """Return a numeric measurement or design column as float64; InputError naming column and first bad row.

    Rejects non-numeric cells, missing values, numbers a float64 cannot hold (overflow,
    inf), values below zero where :data:`NONNEGATIVE` says so, and duty outside (0, 1).
    """
    import pandas as pd
    raw = raw.reset_index(drop=True)
    try:
        vals = pd.to_numeric(raw, errors="coerce").to_numpy(dtype=float, na_value=np.nan)
    except (OverflowError, TypeError, ValueError):  # e.g. a 400-digit integer: convert cell by cell
        vals = np.array([_cell_float(v) for v in raw], dtype=float)
    present = raw.notna().to_numpy()
    bad = np.isnan(vals) & present
    if bad.any():
        i = int(np.argmax(bad))
        _fail(path, f"column '{col}' row {i + 1}: non-numeric value {_short(raw.iloc[i])}")
    if np.isnan(vals).any():
        i = int(np.argmax(np.isnan(vals)))
        hint = MISSING_HINT.get(split_unit(col)[0])
        _fail(path, f"column '{col}' row {i + 1}: missing value (NaN)" + (f"; {hint}" if hint else ""))
    # +inf is a physical value for some columns (a flat intestine: R_i = inf, seed 003 Case 1)
    ok = np.isfinite(vals) | ((vals == np.inf) & (split_unit(col)[0] in INFINITE_OK))
    if not ok.all():
        i = int(np.argmax(~ok))
        _fail(path, f"column '{col}' row {i + 1}: {_short(raw.iloc[i])} is infinite or too large for a "
                    "64-bit float")
    base = split_unit(col)[0]
    if base in NONNEGATIVE and (vals < 0).any():
        i = int(np.argmax(vals < 0))
        _fail(path, f"column '{col}' row {i + 1}: {NONNEGATIVE[base]} {vals[i]:g}")
    if col == "duty" and ((vals <= 0) | (vals >= 1)).any():
        i = int(np.argmax((vals <= 0) | (vals >= 1)))
        _fail(path, f"column 'duty' row {i + 1}: duty must lie in (0, 1), got {vals[i]:g}")
    return vals


def _short(v, n: int = 40) -> str:
    """Return ``repr(v)`` cut to ``n`` characters (a 400-digit cell stays one readable line)."""
    text = str(float(v)) if isinstance(v, (float, np.floating)) else repr(v)
    return text if len(text) <= n else f"{text[:n - 12]}...({len(str(v))} characters)"


def _measurement_provenance(p: Path) -> dict:
    """Return a measurement table's provenance: Parquet metadata, or a CSV's ``.provenance.json`` sidecar."""
    if p.suffix.lower() in (".parquet", ".pq"):
        return read_provenance(p)
    side = p.with_name(p.name + ".provenance.json")
    if side.is_file():
        try:
            return json.loads(side.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError):
            return {}
    return {}


def is_synthetic(df: pd.DataFrame) -> bool:
    """Return True when a measurement table read by :func:`read_measurements` was made by ``synth``."""
    return bool(df.attrs.get("provenance", {}).get("synthetic"))


def covariate_columns(df: pd.DataFrame, kind: str) -> list[str]:
    """Return the numeric covariate columns of a measurement table (not the response)."""
    import pandas as pd
    response = {"friction": "friction_mN", "pressure": "pressure_kPa", "relaxation": "pressure_kPa",
                "progression": "velocity_mm_s", "trajectory": "capsule_mm"}[kind]
    return [c for c in df.columns if c != response and c not in LABEL_COLUMNS
            and pd.api.types.is_numeric_dtype(df[c])]


def response_column(kind: str) -> str:
    """Return the measured quantity's column of a measurement kind."""
    return {"friction": "friction_mN", "pressure": "pressure_kPa", "relaxation": "pressure_kPa",
            "progression": "velocity_mm_s", "trajectory": "capsule_mm"}[kind]


def write_measurements(df: pd.DataFrame, path: str | os.PathLike, prov: dict) -> Path:
    """Write a measurement-kind table (CSV or Parquet by suffix) atomically.

    Parquet keeps the provenance (and the synthetic flag) in its metadata; CSV
    gets a sidecar ``<file>.provenance.json``.
    """
    p = Path(path)
    if p.suffix.lower() == ".csv":
        with atomic_path(p) as tmp:
            df.to_csv(tmp, index=False)
        write_json_atomic(p.with_name(p.name + ".provenance.json"), prov)
        return p
    cols = tuple(Column(c, _dtype_of(df[c]), "measurement column" if c != "synthetic" else "") for c in df.columns)
    return write_table(df, p, TableSchema("measurements", "measurement-kind table", cols), prov)


def _dtype_of(s: pd.Series) -> str:
    import pandas as pd
    if pd.api.types.is_bool_dtype(s):
        return "bool"
    if pd.api.types.is_integer_dtype(s):
        return "int64"
    if pd.api.types.is_float_dtype(s):
        return "float64"
    return "string"
