"""Tables: units and provenance in Parquet metadata, atomic writes, measurement validation."""
from __future__ import annotations

import pandas as pd
import pytest

from capsule_cli import tables
from capsule_cli.errors import InputError

SCHEMA = tables.TableSchema("demo", "one row per speed", (
    tables.Column("speed_mm_s", "float64", "capsule speed"),
    tables.Column("pressure_kPa", "float64", "average contact pressure"),
))


def test_write_table_records_units_and_provenance(tmp_path):
    p = tmp_path / "t.parquet"
    tables.write_table(pd.DataFrame({"speed_mm_s": [1.0, 2.0], "pressure_kPa": [3.0, 4.0]}), p, SCHEMA,
                       tables.provenance(config_hash="abc", seed=3))
    assert tables.read_column_units(p) == {"speed_mm_s": "mm/s", "pressure_kPa": "kPa"}
    prov = tables.read_provenance(p)
    assert prov["config_hash"] == "abc" and prov["seed"] == 3 and prov["synthetic"] is False
    assert prov["version"]
    assert tables.read_table(p)["pressure_kPa"].tolist() == [3.0, 4.0]


def test_failed_write_leaves_no_file(tmp_path):
    p = tmp_path / "t.parquet"
    with pytest.raises(ValueError):
        tables.write_table(pd.DataFrame({"speed_mm_s": [1.0]}), p, SCHEMA)  # missing column
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RuntimeError):
        with tables.atomic_path(p) as tmp:
            tmp.write_text("half")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def _write(tmp_path, text, name="m.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_measurements_kind_inferred_and_units_converted(tmp_path):
    p = _write(tmp_path, "speed_m_s,friction_N,trial\n0.001,0.0079,1\n0.002,0.0081,1\n")
    df, kind = tables.read_measurements(p)
    assert kind == "friction"
    assert df["speed_mm_s"].tolist() == pytest.approx([1.0, 2.0])
    assert df["friction_mN"].tolist() == pytest.approx([7.9, 8.1])


@pytest.mark.parametrize("text, fragment", [
    ("speed_mm_s,friction_mN\n1,2\n2,abc\n", "column 'friction_mN' row 2: non-numeric value 'abc'"),
    ("speed_mm_s,friction_mN\n1,2\n-0.4,3\n", "column 'speed_mm_s' row 2: negative speed -0.4"),
    ("speed_mm_s,friction_mN\n1,2\n2,\n", "column 'friction_mN' row 2: missing value"),
    ("speed_mm_s,friction_mN\n", "empty table"),
    ("speed_mm_s,friction_lbf\n1,2\n", "unknown unit suffix 'lbf'"),
    ("time_s,pressure_kPa,temp_F\n1,2,3\n", "unknown unit suffix 'F'"),
    ("speed_mm_s,friction_mN,position_s\n1,2,3\n", "does not fit"),
    # a camera track: a lost frame says how to go on; a run's frames out of time order are named
    ("run,f_Hz,Pd_N,time_s,capsule_mm\na,30,0.2,0,0\na,30,0.2,0.01,\n",
     "column 'capsule_mm' row 2: missing value (NaN); a frame the tracker lost? leave its row out, or pass "
     "--drop-incomplete"),
    ("run,f_Hz,Pd_N,time_s,capsule_mm\na,30,0.2,0,0\nb,30,0.2,0,0\na,30,0.2,0.02,1\na,30,0.2,0.01,2\n",
     "column 'time_s' row 4: run 'a' has t = 0.01 s after 0.02 s (row 3); each run's frames must come in "
     "increasing time"),
    ("run,f_Hz,Pd_N,time_s,capsule_mm\na,30,0.2,0,0\na,30,0.2,0,1\n", "row 2: run 'a' has t = 0 s after 0 s"),
])
def test_bad_measurements_fail_with_one_line(tmp_path, text, fragment):
    p = _write(tmp_path, text)
    with pytest.raises(InputError) as exc:
        tables.read_measurements(p)
    msg = str(exc.value)
    assert fragment in msg and "m.csv" in msg and "\n" not in msg


def test_trajectory_runs_may_interleave_and_skip_frames(tmp_path):
    # runs interleaved (a table sorted by time) and a frame missing (t = 0.01 s of run a): each run in time order
    p = _write(tmp_path, "run,f_Hz,Pd_N,time_s,capsule_mm\na,30,0.2,0,0\nb,30,0.2,0,0\nb,30,0.2,0.01,1\n"
                         "a,30,0.2,0.02,1\nb,30,0.2,0.02,2\n")
    df, kind = tables.read_measurements(p)
    assert kind == "trajectory" and df["time_s"].tolist() == [0, 0, 0.01, 0.02, 0.02]


def test_missing_required_column_named(tmp_path):
    p = _write(tmp_path, "speed_mm_s,pressure_kPa\n1,2\n")
    with pytest.raises(InputError, match="missing column 'friction_mN'"):
        tables.read_measurements(p, kind="friction")


def test_extra_covariate_with_known_unit_is_kept(tmp_path):
    p = _write(tmp_path, "speed_mm_s,friction_mN,temperature_C\n1,2,37\n")
    df, kind = tables.read_measurements(p)
    assert "temperature_C" in tables.covariate_columns(df, kind)


ALL_TYPES = tables.TableSchema("types", "one row per sample", (
    tables.Column("time_s", "float64", "time"),
    tables.Column("count", "int64", "a count", unit=""),
    tables.Column("flag", "bool", "a flag", unit=""),
    tables.Column("kind", "string", "a label", unit=""),
))


def test_columns_path_writes_the_same_file_as_the_dataframe_path(tmp_path):
    """write_table from arrays (no pandas, issue 13 start-up) = from a DataFrame: data, schema, dtypes."""
    import numpy as np
    import pyarrow.parquet as pq

    cols = {"time_s": np.array([0.0, 0.5, 1.25, -3.0, 7e-9]), "count": np.array([3, 0, -2, 7, 11]),
            "flag": np.array([True, False, True, True, False, ]), "kind": np.array(["a", "", "stick", "é", "b"],
                                                                                      dtype=object)}
    prov = tables.provenance(seed=1)
    a, b = tmp_path / "a.parquet", tmp_path / "b.parquet"
    tables.write_table(pd.DataFrame({**cols, "kind": pd.array(cols["kind"], dtype="string")}), a, ALL_TYPES, prov)
    tables.write_table(cols, b, ALL_TYPES, prov)
    ta, tb = pq.read_table(a), pq.read_table(b)
    assert ta.equals(tb) and ta.schema.equals(tb.schema, check_metadata=True)
    da, db = tables.read_table(a), tables.read_table(b)
    assert da.dtypes.equals(db.dtypes) and da.equals(db)
    assert db["flag"].tolist() == [True, False, True, True, False]
    with pytest.raises(ValueError, match="lacks columns"):
        tables.write_table({"time_s": cols["time_s"]}, tmp_path / "c.parquet", ALL_TYPES, prov)
    with pytest.raises(ValueError, match="undeclared"):
        tables.write_table({**cols, "x_mm": cols["time_s"]}, tmp_path / "c.parquet", ALL_TYPES, prov)
    assert not (tmp_path / "c.parquet").exists()


def test_a_long_table_is_written_by_row_groups_as_the_same_bytes(tmp_path, monkeypatch):
    """write_parquet writes a long table one row group at a time (Ctrl-C is taken between groups); the file is
    the same bytes as pyarrow's one-call write, whose default row group it uses."""
    import hashlib

    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    monkeypatch.setattr(tables, "ROW_GROUP_ROWS", 1000)  # pq.write_table's own row groups set to match
    n = 4500
    t = pa.table({"time_s": np.linspace(0.0, 1.0, n), "n": np.arange(n)}, metadata={b"k": b"v"})
    tables.write_parquet(t, tmp_path / "groups.parquet")
    pq.write_table(t, tmp_path / "one.parquet", row_group_size=1000)
    digest = [hashlib.sha256((tmp_path / f).read_bytes()).hexdigest() for f in ("groups.parquet", "one.parquet")]
    assert digest[0] == digest[1]
    assert pq.ParquetFile(tmp_path / "groups.parquet").metadata.num_row_groups == 5
    assert pq.read_table(tmp_path / "groups.parquet").equals(t)


def test_the_row_group_is_pyarrows_default(tmp_path):
    """ROW_GROUP_ROWS is what pq.write_table uses when not told, so that a long table's file does not change."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    n = tables.ROW_GROUP_ROWS + 10
    pq.write_table(pa.table({"x": np.zeros(n, dtype=np.int8)}), tmp_path / "d.parquet")
    md = pq.ParquetFile(tmp_path / "d.parquet").metadata
    assert md.num_row_groups == 2 and md.row_group(0).num_rows == tables.ROW_GROUP_ROWS
