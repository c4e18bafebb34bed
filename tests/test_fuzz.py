"""Property-based fuzz of the three loaders users feed by hand (issue 11 item 6): the measurement-table
loader, the model-file loader and the plugin loader.

Every generated case must end in one of two ways: accepted, and then the result is valid (numeric
columns finite float64 with the kind's required columns; a model whose prediction has one finite
value per row, or a named NaN/plugin failure), or an ``InputError`` whose message is one line. Any
other exception is a crash and fails the test. The number of cases per loader is set below
(>= 2,000 in total in the test suite); ``CAPSULE_FUZZ_SCALE=10`` runs ten times as many (nightly).
The generation is derandomized, so CI sees the same cases every run.
"""
from __future__ import annotations

import itertools
import os
from collections import Counter

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from capsule_cli.effects import registry
from capsule_cli.effects.model import build_model
from capsule_cli.errors import InputError
from capsule_cli.tables import MEASUREMENT_KINDS, read_measurements
from capsule_cli.validation import check_model_output

SCALE = float(os.environ.get("CAPSULE_FUZZ_SCALE", "1"))
N_TABLES = int(1200 * SCALE)
N_MODELS = int(600 * SCALE)
N_PLUGINS = int(300 * SCALE)
OUTCOMES: Counter = Counter()


def fuzz_settings(n: int):
    return settings(max_examples=n, deadline=None, derandomize=True, database=None,
                    suppress_health_check=list(HealthCheck))


def outcome(loader: str, fn):
    """Run ``fn``; record accepted / rejected; a one-line InputError is the only allowed failure."""
    try:
        result = fn()
    except InputError as exc:
        msg = str(exc)
        assert msg and "\n" not in msg and "\r" not in msg, f"{loader}: multi-line message {msg!r}"
        assert "Traceback" not in msg
        OUTCOMES[(loader, "rejected: InputError, one line")] += 1
        return None
    OUTCOMES[(loader, "accepted and valid")] += 1
    return result


@pytest.fixture
def fuzz_dir(tmp_path):
    return tmp_path


@pytest.fixture(scope="module", autouse=True)
def report_outcomes():
    yield
    if OUTCOMES:
        lines = [f"{loader}: {what}: {n}" for (loader, what), n in sorted(OUTCOMES.items())]
        print("\nfuzz outcomes (" + str(sum(OUTCOMES.values())) + " cases):\n  " + "\n  ".join(lines))


# ---------------------------------------------------------------------------
# tables

NAMES = ["speed_mm_s", "friction_mN", "pressure_kPa", "time_s", "f_Hz", "Pd_N", "velocity_mm_s", "run",
         "capsule_mm", "speed_m_s", "friction_N", "Ri_mm", "duty", "case", "trial", "position_mm",
         "temperature_C", "speed_mm_s ", " friction_mN", "speed", "foo_bar", "speed_mm_s.1", "x_qq", "",
         "Unnamed: 0", "wave form", "ünï_mm", "speed_kPa", "statistic", "waveform", "1e5", "#"]
CELLS = ["1", "2.5", "-3", "0", "1e3", "1e400", "-1e400", "9" * 400, "-" + "9" * 40, "nan", "NaN", "inf",
         "-inf", "", " ", "abc", "1,5", '"7"', '"a,b"', "0x10", "1_000", "+4", ".5", "5.", "1e-320",
         "True", "ü", "\t3", "2 ", "0.5", "0.999", "avg", "max", "harmonic", "square", "None", "-0"]


@st.composite
def csv_texts(draw):
    n_cols = draw(st.integers(1, 5))
    header = draw(st.lists(st.sampled_from(NAMES), min_size=n_cols, max_size=n_cols))
    friendly = draw(st.integers(0, 2)) != 2  # about two cases in three: a valid core, mostly valid cells
    if friendly:
        core = draw(st.sampled_from([["speed_mm_s", "friction_mN"], ["time_s", "pressure_kPa"],
                                     ["f_Hz", "Pd_N", "velocity_mm_s"], ["speed_mm_s", "pressure_kPa"],
                                     ["speed_m_s", "friction_N"]]))
        extra = draw(st.sampled_from([0, 0, 0, 1, 2]))
        header = core + draw(st.lists(st.sampled_from(["trial", "case", "Ri_mm", "position_mm", "temperature_C",
                                                       "duty"] + NAMES[:12]),
                                      min_size=extra, max_size=extra, unique=True))
    n_rows = draw(st.integers(0 if not friendly else 1, 6))
    numbers = st.floats(allow_nan=False, allow_infinity=False, min_value=0.01, max_value=0.99).map(repr)
    big = st.floats(allow_nan=False, allow_infinity=False, min_value=0, max_value=1e6).map(repr)
    junk = st.sampled_from(CELLS)
    cell = st.one_of(*([junk] + [numbers, big] * (40 if friendly else 1)))
    rows = []
    for _ in range(n_rows):
        width = len(header) if (friendly or draw(st.integers(0, 9))) else draw(st.integers(0, len(header) + 2))
        rows.append(",".join(draw(cell) for _ in range(width)))
    text = ",".join(header) + "\n" + "\n".join(rows) + ("\n" if rows else "")
    if draw(st.integers(0, 19)) == 0:  # rare raw garbage
        text = draw(st.text(max_size=60))
    return text


def test_fuzz_table_loader(fuzz_dir):
    _table_cases(fuzz_dir)
    check_counts("table loader", N_TABLES)


@fuzz_settings(N_TABLES)
@given(text=csv_texts(), kind=st.sampled_from([None, None, "friction", "pressure", "progression", "nope"]))
def _table_cases(fuzz_dir, text, kind):
    path = fuzz_dir / "data.csv"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    res = outcome("table loader", lambda: read_measurements(path, kind=kind))
    if res is None:
        return
    df, k = res
    assert k in MEASUREMENT_KINDS and len(df) > 0
    assert all(c in df.columns for c in MEASUREMENT_KINDS[k]["required"])
    assert len(set(df.columns)) == len(df.columns)
    for c in df.columns:
        if df[c].dtype.kind == "f":
            assert np.isfinite(df[c].to_numpy()).all(), c
    for c in ("speed_mm_s", "f_Hz", "Pd_N", "time_s"):
        if c in df.columns and df[c].dtype.kind == "f":
            assert (df[c] >= 0).all()


# ---------------------------------------------------------------------------
# model files

NUMBER = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10, 10),
                   st.sampled_from([0.0, 0.2293, 1.0, 3.462, -1.0, 1e308]))
VALUE = st.one_of(NUMBER, st.text(max_size=5), st.none(), st.lists(NUMBER, max_size=3))
FREE = st.fixed_dictionaries({}, optional={
    "value": VALUE, "free": st.one_of(st.booleans(), st.sampled_from(["yes", 1, None])),
    "bounds": st.one_of(st.lists(NUMBER, min_size=0, max_size=3), st.none(), st.text(max_size=3)),
    "valu": NUMBER})
PARAM_NAMES = st.sampled_from(["mu", "mass_g", "a_mN", "n", "b_mN", "Ri_mm", "wall_mm", "E1_kPa", "E2_kPa",
                               "eta1_MPa_s", "factor", "c_Ns_m", "Pf_N", "gap_mm", "nope", "mu "])


VALID = {"friction": ("coulomb", ["speed_power_law", "viscous", "stribeck", "wall_weight", "curvature"],
                      {"mu": (0.0, 1.0), "mass_g": (0.5, 10.0)}),
         "pressure": ("hoop", ["wall_weight", "curvature", "coating", "end_shape"],
                      {"wall_mm": (0.5, 3.0), "E1_kPa": (1.0, 50.0), "E2_kPa": (1.0, 50.0)}),
         "relaxation": ("maxwell", ["maxwell_arm"], {"E1_kPa": (1.0, 50.0), "factor": (0.1, 2.0)})}


@st.composite
def good_params(draw, ranges):
    out = {}
    for name, (lo, hi) in ranges.items():
        if draw(st.booleans()):
            v = draw(st.floats(lo, hi))
            out[name] = v if draw(st.booleans()) else {"value": v, "free": draw(st.booleans()),
                                                       "bounds": [lo, hi]}
    return out


@st.composite
def model_docs(draw):
    if draw(st.booleans()):  # half the cases: a sensible model with mild mutations
        kind = draw(st.sampled_from(list(VALID)))
        base, effs, ranges = VALID[kind]
        doc = {"kind": kind, "base": base, "effects": draw(st.lists(st.sampled_from(effs), max_size=2,
                                                                    unique=True)),
               "params": draw(good_params(ranges))}
        if draw(st.integers(0, 3)) == 0:
            doc["params"][draw(PARAM_NAMES)] = draw(st.one_of(NUMBER, FREE))
        return doc
    kind = draw(st.sampled_from(["friction", "friction", "pressure", "relaxation", "progression", "bogus", 3]))
    base = draw(st.sampled_from(["coulomb", "hertz", "hoop", "maxwell", "one_sided", "zzz"]))
    effects = draw(st.lists(st.sampled_from(["speed_power_law", "viscous", "stribeck", "wall_weight",
                                             "maxwell_arm", "curvature", "nope", "viscous"]), max_size=3))
    params = draw(st.dictionaries(PARAM_NAMES, st.one_of(NUMBER, FREE, VALUE), max_size=4))
    doc = {"kind": kind, "base": base, "effects": effects, "params": params}
    for key in draw(st.lists(st.sampled_from(["kind", "base", "effects", "params"]), max_size=2)):
        doc.pop(key, None)
    if draw(st.integers(0, 9)) == 0:
        doc[draw(st.sampled_from(["efects", "name", "notes", "protocol"]))] = draw(VALUE)
    return doc


TABLES = {"friction": {"speed_mm_s": [0.5, 2.0, 8.0, 12.0], "friction_mN": [10.0, 11.0, 12.0, 12.5],
                       "Ri_mm": [4.4, 4.8, 5.0, 13.0], "bend_radius_mm": [10, 25, 100, 400.0],
                       "position_mm": [0, 10, 47, 120.0], "time_s": [0, 5, 30, 100.0]},
          "pressure": {"speed_mm_s": [0.5, 2.0, 8.0, 12.0], "pressure_kPa": [1.0, 1.1, 1.2, 1.3],
                       "Ri_mm": [4.4, 4.8, 5.0, 13.0], "bend_radius_mm": [10, 25, 100, 400.0]},
          "relaxation": {"time_s": [0.0, 1.0, 10.0, 100.0], "pressure_kPa": [5.0, 4.0, 3.0, 2.5]}}


def test_fuzz_model_file_loader(fuzz_dir):
    _model_cases(fuzz_dir)
    check_counts("model-file loader", N_MODELS)


@fuzz_settings(N_MODELS)
@given(doc=model_docs(), raw=st.one_of(st.none(), st.none(), st.none(), st.text(max_size=40)))
def _model_cases(fuzz_dir, doc, raw):
    import pandas as pd

    path = fuzz_dir / "model.yaml"
    path.write_text(raw if raw is not None else yaml.safe_dump(doc, allow_unicode=True), encoding="utf-8",
                    errors="surrogatepass")

    def load_and_predict():
        m = build_model(path)
        if m.kind in TABLES:  # a model that loads must predict, or name what gives NaN
            y = check_model_output(m.bind(pd.DataFrame(TABLES[m.kind])), None, "start values")
            assert y.shape == (4,) and np.isfinite(y).all()
        return m

    outcome("model-file loader", load_and_predict)


# ---------------------------------------------------------------------------
# plugins

_counter = itertools.count()
HEADER = "import numpy as np\nfrom capsule_cli.effects import Param, register_effect\n"
BODIES = ["return y + p['k'] * 1e-3"] * 6 + ["return y * (1 + 0 * x['speed'])", "return y * np.nan", "return y[:1]", "raise ValueError('bad')",
          "return 'x'", "return float(p['k'])", "return None", "return y + x['speed']",
          "return y + x['temperature']", "return np.stack([y, y])", "return y / 0.0", "return [1, 2]"]
PARAMS = ['Param("k_mN", start=1.0, bounds=(0.0, 5.0), off=0.0)'] * 6 + [
          'Param("k_mN", start=9.0, bounds=(0.0, 5.0), off=0.0)',  # start outside bounds
          'Param("k_mN", start=1.0, bounds=(5.0, 0.0), off=0.0)',  # reversed
          'Param("k_mN", start=1.0, bounds=(0.0, 5.0))',  # no off value
          '"k_mN"']
KIND = ['"friction"'] * 6 + ['"pressure"', '"nope"']
COVS = ["()"] * 6 + ['("temperature_C",)', '("speed",)']
PREFIX = [""] * 12 + ["import not_a_module_xyz\n", "def broken(:\n", "raise RuntimeError('at import')\n",
          "x = 1 / 0\n"]


def test_fuzz_plugin_loader(fuzz_dir):
    _plugin_cases(fuzz_dir)
    check_counts("plugin loader", N_PLUGINS)


@fuzz_settings(N_PLUGINS)
@given(body=st.sampled_from(BODIES), param=st.sampled_from(PARAMS), kind=st.sampled_from(KIND),
       covs=st.sampled_from(COVS), prefix=st.sampled_from(PREFIX), register=st.integers(0, 9))
def _plugin_cases(fuzz_dir, body, param, kind, covs, prefix, register):
    import pandas as pd

    name = f"fz{next(_counter)}"
    src = HEADER + prefix
    if register != 9:  # one case in ten registers nothing
        src += (f"@register_effect(name='{name}', kind={kind}, params=({param},), covariates={covs},\n"
                f"                 description='fuzz', source='fuzz')\n")
    src += f"def {name}(y, x, p, ctx):\n    {body}\n"
    folder = fuzz_dir
    plug = folder / f"{name}.py"
    plug.write_text(src)
    model = folder / "m.yaml"
    model.write_text(f"kind: friction\nbase: coulomb\neffects: [{name}]\n"
                     "params:\n  mu: {value: 0.2, free: true, bounds: [0, 1]}\n")
    registry._ensure_builtins()
    saved, loaded = dict(registry._EFFECTS), set(registry._LOADED_PLUGINS)

    def load_and_run():
        registry.load_plugins([plug], entry_points=False)
        m = build_model(model)
        df = pd.DataFrame({**TABLES["friction"], "temperature_C": [36.0, 37.0, 38.0, 39.0]})
        y = check_model_output(m.bind(df), None, "start values")
        assert y.shape == (4,) and np.isfinite(y).all()
        return m

    try:
        outcome("plugin loader", load_and_run)
    finally:
        registry._EFFECTS.clear()
        registry._EFFECTS.update(saved)
        registry._LOADED_PLUGINS.clear()
        registry._LOADED_PLUGINS.update(loaded)


def check_counts(loader: str, n: int) -> None:
    """Every generated case ran, and both outcomes occurred (the fuzz is not vacuous)."""
    got = {what: k for (ld, what), k in OUTCOMES.items() if ld == loader}
    assert sum(got.values()) >= n, got
    assert set(got) == {"accepted and valid", "rejected: InputError, one line"}, got
