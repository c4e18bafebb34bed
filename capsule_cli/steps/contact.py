"""Contact-pressure step: parameters from configs, model sweeps as tables, the reference table.

Composes :mod:`capsule_cli.models.contact` over grids of speed, intestine
radius R_i, end length and wall-thickness mode, and returns tidy tables (one
row per model, case, speed, R_i, end length, wall mode and statistic) whose
schemas are declared here (:data:`PRESSURE_SCHEMA`, :data:`PROFILE_SCHEMA`,
:data:`REFERENCE_SCHEMA`).
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pandas as pd

from ..config import configs_dir, load_param_set_file
from ..errors import InputError
from ..models import contact as cm
from ..tables import Column, TableSchema
from ..units import UNITS, split_unit

MODELS = ("hertz", "collapsed", "hoop")
CASE_OF_MODEL = {"hertz": "case1", "collapsed": "case2", "hoop": "case3"}
SOURCE_TYPES = ("experiment", "FE", "analytic", "fit")

# parameter name in configs/params/capsule_intestine.yaml -> keyword of the model functions
_PARAM_NAMES = {
    "Rc_mm": "Rc_m", "L_mm": "L_m", "wall_mm": "wall_m", "Ec_GPa": "Ec_Pa", "nu_c": "nu_c",
    "Ei_kPa": "Ei_Pa", "nu_i": "nu_i", "E1_kPa": "E1_Pa", "E2_kPa": "E2_Pa", "eta1_MPa_s": "eta1_Pa_s",
    "rho_i_g_cm3": "rho_i_kg_m3", "g_m_s2": "g_m_s2", "load_FE_g": "load_kg",
}
_CASE_NAMES = {"Ri_case1_mm": "case1", "Ri_case2_mm": "case2", "Ri_case3_mm": "case3"}


def _si(name: str, value: float) -> float:
    _, suffix = split_unit(name)
    return value * (UNITS[suffix][0] if suffix else 1.0)


def contact_params_from_config(name: str | os.PathLike = "capsule_intestine") -> dict[str, float]:
    """Return the contact-model parameters in SI, keyed by the model functions' keyword names.

    Reads ``configs/params/<name>.yaml`` (or a path): ``Rc_m``, ``L_m``,
    ``wall_m``, ``Ec_Pa``, ``nu_c``, ``Ei_Pa``, ``nu_i``, ``E1_Pa``, ``E2_Pa``,
    ``eta1_Pa_s``, ``rho_i_kg_m3``, ``g_m_s2`` and ``load_N`` (the Case 1
    capsule load ``load_FE_g`` times g, seed 003 section 4). A missing
    parameter is an :class:`InputError` naming the file and the key.
    """
    ps = load_param_set_file(name)
    where = name if str(name).endswith((".yaml", ".yml")) else f"configs/params/{name}.yaml"
    out: dict[str, float] = {}
    for key, kw in _PARAM_NAMES.items():
        if key not in ps.params:
            raise InputError(f"{where}: missing parameter '{key}' needed by the contact models")
        out[kw] = _si(key, ps.params[key].value)
    out["load_N"] = out.pop("load_kg") * out["g_m_s2"]
    return out


def case_radii_from_config(name: str | os.PathLike = "contact_cases") -> dict[str, float]:
    """Return ``{'case1': R_i, 'case2': R_i, 'case3': R_i}`` [m] from ``configs/params/contact_cases.yaml``."""
    ps = load_param_set_file(name)
    out = {}
    for key, case in _CASE_NAMES.items():
        if key not in ps.params:
            raise InputError(f"configs/params/contact_cases.yaml: missing parameter '{key}'")
        out[case] = _si(key, ps.params[key].value)
    return out


def _pick(params: dict, *names: str) -> dict:
    return {n: params[n] for n in names}


HERTZ_KEYS = ("Ec_Pa", "nu_c", "Ei_Pa", "nu_i")
HOOP_KEYS = ("Rc_m", "L_m", "wall_m", "E1_Pa", "E2_Pa", "eta1_Pa_s")

# ---------------------------------------------------------------------------
# table schemas

PRESSURE_SCHEMA = TableSchema(
    name="contact_pressure",
    description="contact pressure per model and case over speed, intestine radius, end length and wall mode "
                "(seed 003 eqs 2-14; seed 001 section 6 for the end length)",
    columns=(
        Column("model", "string", "contact model: hertz (Case 1, seed 003 eqs 2-5), collapsed (Case 2, eq 6 "
                                  "with a wall-weight closed form), hoop (Case 3, eqs 8-14)", unit=""),
        Column("case", "string", "contact case of seed 003 (case1 flat, case2 collapsed, case3 contractive)", unit=""),
        Column("statistic", "string", "avg: average over the contact strip (Hertz) or over the body (hoop, eq 14); "
                                      "max: maximum; contact_avg: area-weighted over the whole hoop contact "
                                      "including the ends; wall_avg: the collapsed wall's share P_1", unit=""),
        Column("speed_mm_s", "float64", "capsule speed"),
        Column("Ri_mm", "float64", "intestine inner radius (inf: flat)"),
        Column("end_length_mm", "float64", "axial length of the semi-elliptical ends (R_c: hemispherical); "
                                           "NaN where the model has no ends"),
        Column("wall_mode", "string", "hoop wall thickness: attenuated (t_i,e, eq 9) or original (t_i); "
                                      "empty for other models", unit=""),
        Column("load_g", "float64", "capsule load as a mass (Hertz and collapsed); NaN for hoop"),
        Column("semi_width_mm", "float64", "Hertz semi-contact width a (eq 2); NaN otherwise"),
        Column("pressure_kPa", "float64", "contact pressure"),
    ),
)

PROFILE_SCHEMA = TableSchema(
    name="hoop_profile",
    description="hoop pressure along the capsule, x from the first capsule-wall contact "
                "(seed 003 eqs 8-13, seed 000 eqs 4-9, seed 001 section 6)",
    columns=(
        Column("speed_mm_s", "float64", "capsule speed"),
        Column("Ri_mm", "float64", "intestine inner radius"),
        Column("end_length_mm", "float64", "axial length of the semi-elliptical ends (R_c: hemispherical)"),
        Column("wall_mode", "string", "wall thickness: attenuated (t_i,e) or original (t_i)", unit=""),
        Column("segment", "string", "head (front end), body (cylinder) or tail (rear end)", unit=""),
        Column("x_mm", "float64", "axial position from the first contact point (the head's contact ring)"),
        Column("x_body_mm", "float64", "axial position from the start of the cylindrical body (x - x_c)"),
        Column("radius_mm", "float64", "capsule radius R(x)"),
        Column("pressure_kPa", "float64", "hoop pressure P_h(x)"),
    ),
)

REFERENCE_COLUMNS = ("case", "statistic", "speed_mm_s", "Ri_mm", "end_length_mm", "bend_radius_mm",
                     "coating_mm", "coating_modulus_kPa", "pressure_kPa", "source_type", "source", "note", "label")

REFERENCE_SCHEMA = TableSchema(
    name="contact_pressure_reference",
    description="published contact pressures (experiment, FE, analytic) with a citation per row "
                "(physics.md section 4; seeds 003, 001, 004)",
    columns=(
        Column("case", "string", "contact case or study (case1, case2, case3, case3_curved, case3_end_shape, "
                                 "case3_coating, ...)", unit=""),
        Column("statistic", "string", "avg or max pressure", unit=""),
        Column("speed_mm_s", "float64", "capsule speed (NaN: not speed-specific)"),
        Column("Ri_mm", "float64", "intestine inner radius (inf: flat)"),
        Column("end_length_mm", "float64", "semi-elliptical end length (NaN: not stated or hemispherical)"),
        Column("bend_radius_mm", "float64", "bending radius of a curved intestine (NaN: straight)"),
        Column("coating_mm", "float64", "elastomer coating thickness (NaN: none)"),
        Column("coating_modulus_kPa", "float64", "elastomer coating Young's modulus (NaN: none)"),
        Column("pressure_kPa", "float64", "published contact pressure"),
        Column("source_type", "string", "experiment, FE, analytic or fit", unit=""),
        Column("source", "string", "citation: seed file and section/figure", unit=""),
        Column("note", "string", "what the value is and any reading choice", unit=""),
        Column("label", "string", "short label for figures (S003 = seed 003; +g: with gravity)", unit=""),
    ),
)

# ---------------------------------------------------------------------------
# sweeps


def _mm(x_m):
    """Metres to millimetres, rounded to 1e-9 mm so that 5e-3 m reads back as 5.0 mm."""
    return np.round(np.asarray(x_m, float) * 1e3, 9)


def _rows(model, statistic, speeds_mm_s, Ri_mm, end_mm, wall_mode, load_g, semi_mm, p_Pa):
    p = np.broadcast_to(np.asarray(p_Pa, float), np.shape(speeds_mm_s))
    return pd.DataFrame({
        "model": model, "case": CASE_OF_MODEL[model], "statistic": statistic,
        "speed_mm_s": np.asarray(speeds_mm_s, float), "Ri_mm": float(Ri_mm), "end_length_mm": end_mm,
        "wall_mode": wall_mode, "load_g": load_g, "semi_width_mm": semi_mm, "pressure_kPa": p / 1e3,
    })


def pressure_table(models, speeds_m_s, params: dict, Ri_m=None, end_lengths_m=None,
                   wall_modes=("attenuated",), load_N=None, case2_conforming: bool = True,
                   case_radii: dict | None = None) -> pd.DataFrame:
    """Return the contact pressures of ``models`` over speeds (and R_i, end lengths, wall modes).

    Parameters
    ----------
    models : subset of ``("hertz", "collapsed", "hoop")``
    speeds_m_s : capsule speeds [m/s] (>= 0)
    params : SI parameters (:func:`contact_params_from_config`)
    Ri_m : intestine inner radii [m] used by every selected model; None: each
        model's paper case (Case 1 flat, Case 2 13 mm, Case 3 5 mm; ``case_radii``)
    end_lengths_m : hoop end lengths [m]; None: hemispherical (R_c)
    wall_modes : hoop wall-thickness modes ("attenuated", "original")
    load_N : capsule load [N] for Hertz and collapsed (default ``params['load_N']``)
    case2_conforming : lower contact of Case 2 as a cylinder in a trough (see
        :func:`capsule_cli.models.contact.hertz_equivalent_radius_m`)
    """
    speeds = np.asarray(speeds_m_s, float)
    v_mm = _mm(speeds)
    load = params["load_N"] if load_N is None else float(load_N)
    load_g = float(np.round(load / params["g_m_s2"] * 1e3, 9))
    radii = case_radii or case_radii_from_config()
    hz = _pick(params, *HERTZ_KEYS)
    frames = []
    for model in models:
        Ris = [radii[CASE_OF_MODEL[model]]] if Ri_m is None else list(Ri_m)
        for Ri in Ris:
            Ri_mm = float(_mm(Ri))
            if model == "hertz":
                a = cm.hertz_semi_width_m(load, params["Rc_m"], Ri, params["L_m"], **hz)
                pavg = cm.hertz_pressure_avg_Pa(load, params["Rc_m"], Ri, params["L_m"], **hz)
                pmax = cm.hertz_pressure_max_Pa(load, params["Rc_m"], Ri, params["L_m"], **hz)
                frames += [_rows(model, "avg", v_mm, Ri_mm, np.nan, "", load_g, a * 1e3, pavg),
                           _rows(model, "max", v_mm, Ri_mm, np.nan, "", load_g, a * 1e3, pmax)]
            elif model == "collapsed":
                if case2_conforming and not Ri > params["Rc_m"]:
                    raise InputError(f"collapsed model: R_i = {Ri_mm:g} mm must exceed R_c = "
                                     f"{params['Rc_m'] * 1e3:g} mm (the capsule lies inside the tube)")
                wall = _pick(params, "wall_m", "rho_i_kg_m3", "g_m_s2")
                p1 = cm.collapsed_wall_pressure_Pa(Ri, **wall, Rc_m=params["Rc_m"], length_m=params["L_m"], **hz)
                ptot = cm.collapsed_pressure_avg_Pa(load, Ri, **wall, Rc_m=params["Rc_m"], length_m=params["L_m"],
                                                    conforming=case2_conforming, **hz)
                a = cm.hertz_semi_width_m(load, params["Rc_m"], Ri, params["L_m"], conforming=case2_conforming, **hz)
                frames += [_rows(model, "avg", v_mm, Ri_mm, np.nan, "", load_g, a * 1e3, ptot),
                           _rows(model, "wall_avg", v_mm, Ri_mm, np.nan, "", load_g, np.nan, p1)]
            elif model == "hoop":
                ends = [params["Rc_m"]] if end_lengths_m is None else list(end_lengths_m)
                hp = _pick(params, *HOOP_KEYS)
                for end in ends:
                    for mode in wall_modes:
                        kw = dict(Ri_m=Ri, wall_mode=mode, end_length_m=end, **hp)
                        for stat, fn in (("avg", cm.hoop_pressure_avg_Pa), ("max", cm.hoop_pressure_max_Pa),
                                         ("contact_avg", cm.hoop_pressure_contact_avg_Pa)):
                            frames.append(_rows(model, stat, v_mm, Ri_mm, float(_mm(end)), mode, np.nan, np.nan,
                                                fn(speeds, **kw)))
            else:
                raise InputError(f"unknown contact model '{model}' (one of {', '.join(MODELS)})")
    return pd.concat(frames, ignore_index=True)


def hoop_profile_table(speeds_m_s, params: dict, Ri_m, end_lengths_m=None, wall_modes=("attenuated",),
                       n_end: int = 60, n_body: int = 150) -> pd.DataFrame:
    """Return the hoop pressure along the whole contact (head end, body, tail end) per case.

    ``n_end`` points on each end and ``n_body`` on the body (end points of the
    segments included, so the profile is continuous). Arguments as :func:`pressure_table`.
    """
    hp = _pick(params, *HOOP_KEYS)
    frames = []
    ends = [params["Rc_m"]] if end_lengths_m is None else list(end_lengths_m)
    for Ri in np.atleast_1d(Ri_m):
        for end in ends:
            xc = float(cm.hoop_contact_start_m(Ri, params["Rc_m"], end))
            L = params["L_m"]
            segs = (("head", np.linspace(0.0, xc, n_end)), ("body", np.linspace(xc, xc + L, n_body)),
                    ("tail", np.linspace(xc + L, 2 * xc + L, n_end)))
            for V in np.atleast_1d(speeds_m_s):
                for mode in wall_modes:
                    for seg, x in segs:
                        R = cm.capsule_radius_m(x, Ri, params["Rc_m"], L, end)
                        P = cm.hoop_pressure_profile_Pa(x, V, Ri, wall_mode=mode, end_length_m=end, **hp)
                        frames.append(pd.DataFrame({
                            "speed_mm_s": float(_mm(V)), "Ri_mm": float(_mm(Ri)), "end_length_mm": float(_mm(end)),
                            "wall_mode": mode, "segment": seg, "x_mm": x * 1e3, "x_body_mm": (x - xc) * 1e3,
                            "radius_mm": R * 1e3, "pressure_kPa": P / 1e3}))
    return pd.concat(frames, ignore_index=True)


# ---------------------------------------------------------------------------
# the reference table


def reference_path() -> Path:
    """Return ``configs/reference/contact_pressure.csv``."""
    return configs_dir() / "reference" / "contact_pressure.csv"


def load_reference_table(path: str | os.PathLike | None = None) -> pd.DataFrame:
    """Return the validated table of published contact pressures (one citation per row).

    Checks the columns of :data:`REFERENCE_SCHEMA`, numeric cells, a known
    ``source_type`` and a non-empty ``source`` on every row; InputError otherwise.
    """
    p = Path(path) if path is not None else reference_path()
    if not p.is_file():
        raise InputError(f"{p}: file not found")
    try:
        df = pd.read_csv(p, comment="#", keep_default_na=True)
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot be read ({str(exc).splitlines()[0]})") from None
    missing = [c for c in REFERENCE_COLUMNS if c not in df.columns]
    if missing:
        raise InputError(f"{p}: missing column '{missing[0]}'")
    extra = [c for c in df.columns if c not in REFERENCE_COLUMNS]
    if extra:
        raise InputError(f"{p}: unknown column '{extra[0]}' (columns: {', '.join(REFERENCE_COLUMNS)})")
    for col in ("speed_mm_s", "Ri_mm", "end_length_mm", "bend_radius_mm", "coating_mm",
                "coating_modulus_kPa", "pressure_kPa"):
        raw = df[col]
        vals = pd.to_numeric(raw, errors="coerce")
        bad = vals.isna() & raw.notna()
        if bad.any():
            i = int(np.argmax(bad.to_numpy()))
            raise InputError(f"{p}: column '{col}' row {i + 1}: non-numeric value {raw.iloc[i]!r}")
        df[col] = vals.astype(float)
    if df["pressure_kPa"].isna().any():
        i = int(np.argmax(df["pressure_kPa"].isna().to_numpy()))
        raise InputError(f"{p}: column 'pressure_kPa' row {i + 1}: missing value")
    for i, (st, src) in enumerate(zip(df["source_type"], df["source"])):
        if st not in SOURCE_TYPES:
            raise InputError(f"{p}: column 'source_type' row {i + 1}: {st!r} is not one of {', '.join(SOURCE_TYPES)}")
        if not isinstance(src, str) or len(src.strip()) < 5:
            raise InputError(f"{p}: column 'source' row {i + 1}: missing citation")
    for col in ("case", "statistic", "source_type", "source", "note", "label"):
        df[col] = df[col].fillna("").astype(str)
    return df


def parse_float_list(text: str, what: str) -> list[float]:
    """Return the floats of a comma-separated option value ('0.5,1,inf'); InputError naming ``what``."""
    out = []
    for tok in str(text).split(","):
        tok = tok.strip()
        if not tok:
            continue
        try:
            out.append(float(tok))
        except ValueError:
            raise InputError(f"{what}: '{tok}' is not a number (give a comma-separated list)") from None
    if not out:
        raise InputError(f"{what}: empty list")
    if any(math.isnan(v) for v in out):
        raise InputError(f"{what}: NaN is not allowed")
    return out


def parse_range(text: str, what: str) -> list[float]:
    """Return ``numpy.linspace(start, stop, num)`` of 'start:stop:num'; InputError naming ``what``."""
    parts = str(text).split(":")
    if len(parts) != 3:
        raise InputError(f"{what}: expected start:stop:num, got '{text}'")
    try:
        start, stop, num = float(parts[0]), float(parts[1]), int(parts[2])
    except ValueError:
        raise InputError(f"{what}: expected start:stop:num with numbers, got '{text}'") from None
    if num < 1 or not (math.isfinite(start) and math.isfinite(stop)):
        raise InputError(f"{what}: need finite start, stop and num >= 1, got '{text}'")
    return list(np.linspace(start, stop, num))
