"""Friction steps: fits of friction-speed laws, model-file predictions, hoop grids, tables.

* :data:`LAWS` and :func:`fit_friction_law` -- fit F(V) laws to pull-test tables with
  :func:`capsule_cli.fitting.fit_least_squares` (multi-start, 95 % intervals, band);
* :func:`predict_friction` -- evaluate a model file of kind ``friction`` (contract
  section 4) through the effects registry (:mod:`capsule_cli.effects`);
* :func:`hoop_table` -- the hoop-friction components over a speed x R_i grid;
* :func:`read_friction_reference` -- the published values of seed 000 section 4.

Table units: speeds in mm/s, frictions in mN (fits, predictions) or N (hoop grid);
the models underneath are SI (:mod:`capsule_cli.models.friction`).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import pandas as pd

from ..config import ModelFile, load_param_set_si
from ..errors import InputError
from ..fitting import SCREEN_ROWS, FitResult, fit_least_squares, prediction_band
from ..models import friction as fm
from ..tables import Column, TableSchema
from ..validation import check_model_output

MM = 1e-3  # mm -> m, mm/s -> m/s, mN -> N

# ---------------------------------------------------------------------------
# friction-speed laws in table units (V in mm/s, F in mN)


@dataclass(frozen=True)
class Law:
    """A friction-speed law for fitting: F[mN] = func(V[mm/s], *params)."""

    name: str
    formula: str
    params: tuple[str, ...]  # names with unit suffixes
    func: Callable[..., np.ndarray]
    source: str
    guess: Callable[[np.ndarray, np.ndarray], np.ndarray]
    bounds: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


def _scale(F: np.ndarray) -> float:
    return float(max(np.ptp(F), np.abs(F).max(), 1e-9))


def _lin_ab(V, F, n):
    """Return (a, b, rss) of the linear least-squares fit F = a V^n + b (closed form, O(rows))."""
    X = np.power(V, n)
    xm, fm_ = X.mean(), F.mean()
    dx = X - xm
    sxx = float(dx @ dx)
    a = float(dx @ (F - fm_)) / sxx if sxx > 0 else 0.0
    b = fm_ - a * xm
    r = F - (a * X + b)
    return a, b, float(r @ r)


def _power_guess(V, F):
    grid = np.linspace(0.05, 2.0, 40)
    if V.size > SCREEN_ROWS:  # the exponent's grid search on an even subset: a start needs no more
        step = -(-V.size // SCREEN_ROWS)
        Vs, Fs = V[::step], F[::step]
    else:
        Vs, Fs = V, F
    best = min(grid, key=lambda n: _lin_ab(Vs, Fs, n)[2])
    a, b, _ = _lin_ab(V, F, best)
    return np.array([a, best, b])


def _power(V, a, n, b):
    return fm.power_law_friction_N(V * MM, a * MM, n, b * MM, V_ref_m_s=1.0 * MM) / MM


def _viscous(V, Fc, c):
    return Fc + fm.viscous_friction_N(V * MM, c) / MM


def _stribeck(V, Fc, Fs, Vs):
    return fm.stribeck_friction_N(V * MM, Fc * MM, Fs * MM, Vs * MM, delta=2.0) / MM


def _stribeck_guess(V, F):
    order = np.argsort(V)
    k = max(1, len(V) // 4)
    return np.array([F[order[-k:]].mean(), F[order[:k]].mean(), float(np.median(V[V > 0])) if (V > 0).any() else 1.0])


def _wide(F, k):
    s = 100.0 * _scale(F)
    return np.full(k, -s), np.full(k, s)


LAWS: dict[str, Law] = {
    "power": Law(
        "power", "F = a (V / 1 mm/s)^n + b", ("a_mN", "n", "b_mN"), _power,
        "seed 000 eqs 17-18 (n free)", _power_guess,
        lambda V, F: (np.array([-100 * _scale(F), 0.01, -100 * _scale(F)]),
                      np.array([100 * _scale(F), 3.0, 100 * _scale(F)]))),
    "power_fixed_n": Law(
        "power_fixed_n", "F = a (V / 1 mm/s)^n + b, n fixed", ("a_mN", "b_mN"), None,  # func set per call
        "seed 000 eqs 17-18 (n = 0.25 in the paper)", None, lambda V, F: _wide(F, 2)),
    "viscous": Law(
        "viscous", "F = Fc + c V", ("Fc_mN", "c_Ns_m"), _viscous,
        "Coulomb + viscous (Armstrong-Helouvry et al. 1994, Automatica 30(7))",
        lambda V, F: np.polyfit(V, F, 1)[::-1] if np.ptp(V) > 0 else np.array([F.mean(), 0.0]),
        lambda V, F: (np.array([-100 * _scale(F), -100 * _scale(F) / max(np.ptp(V), 1e-9)]),
                      np.array([100 * _scale(F), 100 * _scale(F) / max(np.ptp(V), 1e-9)]))),
    "stribeck": Law(
        "stribeck", "F = Fc + (Fs - Fc) exp(-(V/Vs)^2)", ("Fc_mN", "Fs_mN", "Vs_mm_s"), _stribeck,
        "Stribeck curve (Armstrong-Helouvry et al. 1994; Olsson et al. 1998)", _stribeck_guess,
        lambda V, F: (np.array([-100 * _scale(F), -100 * _scale(F), max(V.max(), 1e-6) * 1e-3]),
                      np.array([100 * _scale(F), 100 * _scale(F), max(V.max(), 1e-6) * 10.0]))),
    "coulomb": Law(
        "coulomb", "F = Fc (speed independent)", ("Fc_mN",), lambda V, Fc: np.full_like(V, Fc, dtype=float),
        "seed 000 eq 1 (Coulomb)", lambda V, F: np.array([F.mean()]), lambda V, F: _wide(F, 1)),
}


@dataclass
class FrictionFit:
    """A fitted friction-speed law with its uncertainty, band and residuals."""

    law: str
    formula: str
    source: str
    fit: FitResult
    n_fixed: float | None
    band: pd.DataFrame  # speed_mm_s, friction_mN, ci_low_mN, ci_high_mN, pi_low_mN, pi_high_mN
    residuals: pd.DataFrame  # speed_mm_s, friction_mN, fitted_mN, residual_mN (+ group)
    groups: dict = field(default_factory=dict)

    @property
    def params(self) -> dict[str, float]:
        """Return ``{name: value}`` of the fitted parameters (units in the names)."""
        return dict(zip(self.fit.names, map(float, self.fit.values)))

    def predict_mN(self, speed_mm_s) -> np.ndarray:
        """Return the fitted law at ``speed_mm_s`` [mm/s] in mN."""
        return law_function(self.law, self.n_fixed)(np.asarray(speed_mm_s, float), *self.fit.values)

    def summary(self) -> dict:
        """Return the JSON record of the fit (fit.json)."""
        f = self.fit
        params = f.as_dict()
        if self.n_fixed is not None:
            params["n"] = {"value": float(self.n_fixed), "fixed": True}
        return {
            "law": self.law, "formula": self.formula, "source": self.source,
            "n": f.n, "k": f.k, "params": params, "r2": f.r2, "aic": f.aic, "bic": f.bic,
            "rss_mN2": f.rss, "sigma_mN": f.sigma, "success": f.success,
            "starts_converged": f.starts_converged, "at_bound": f.at_bound,
            "intervals": "95 % Student-t intervals from the Gauss-Newton covariance (capsule_cli.fitting)",
            "band": "95 % confidence band of the fitted curve (delta method); pi_* columns: "
                    "95 % prediction band for a new measurement",
            "groups": self.groups,
        }


def law_function(law: str, n_fixed: float | None = None) -> Callable[..., np.ndarray]:
    """Return F[mN] = f(V[mm/s], *params) of a named law (``power_fixed_n`` needs ``n_fixed``)."""
    if law not in LAWS:
        raise InputError(f"unknown friction law '{law}' (one of {', '.join(LAWS)})")
    if law == "power_fixed_n":
        if n_fixed is None:
            raise InputError("law 'power_fixed_n' needs n_fixed")
        return lambda V, a, b: _power(V, a, n_fixed, b)
    return LAWS[law].func


def speed_grid_mm_s(speed_mm_s: np.ndarray, num: int = 240) -> np.ndarray:
    """Return the speed grid [mm/s] of a fitted curve: (0, max speed], plus the data's minimum."""
    vmax = float(np.max(speed_mm_s)) if np.max(speed_mm_s) > 0 else 1.0
    grid = np.linspace(0.0, vmax, num + 1)[1:]
    vmin = float(np.min(speed_mm_s[speed_mm_s > 0])) if np.any(speed_mm_s > 0) else grid[0]
    return np.unique(np.concatenate([grid, [vmin]]))


def fit_friction_law(speed_mm_s, friction_mN, law: str = "power", n_fixed: float = 0.25, groups=None,
                     seed: int = 0, n_starts: int = 6, x0: Sequence[float] | None = None,
                     grid_mm_s: Sequence[float] | None = None) -> FrictionFit:
    """Return the least-squares fit of a friction-speed law to pull-test data.

    Parameters
    ----------
    speed_mm_s : capsule speeds V >= 0 [mm/s]
    friction_mN : measured frictions F [mN] (one per speed, e.g. trial averages)
    law : ``power`` (F = a V^n + b, n free), ``power_fixed_n`` (n = ``n_fixed``, as
        seed 000 eqs 17-18 with n = 0.25), ``viscous`` (Fc + c V), ``stribeck``
        (Fc + (Fs - Fc) exp(-(V/Vs)^2)) or ``coulomb`` (a constant Fc)
    n_fixed : exponent for ``power_fixed_n`` [-]
    groups : optional labels per row (trial, case): carried into the residuals and
        summarised per group (count, RMS residual, mean residual)
    seed : seed of the multi-start draws (deterministic)
    n_starts : starting points (the first from a data-driven guess, or ``x0``)
    x0 : explicit first starting point (parameter order of ``LAWS[law].params``)
    grid_mm_s : speeds of the fitted curve and its band (default: 240 up to the fastest)

    Returns
    -------
    :class:`FrictionFit` with parameters, 95 % intervals, R^2, AIC/BIC, the 95 %
    confidence band of the curve and the residuals.
    """
    if law not in LAWS:
        raise InputError(f"unknown friction law '{law}' (one of {', '.join(LAWS)})")
    V = np.asarray(speed_mm_s, float).ravel()
    F = np.asarray(friction_mN, float).ravel()
    if V.shape != F.shape:
        raise InputError(f"speed and friction have different lengths ({V.size} and {F.size})")
    if not (np.isfinite(V).all() and np.isfinite(F).all()):
        raise InputError("speed and friction must be finite numbers")
    if (V < 0).any():
        raise InputError(f"negative speed {V[V < 0][0]} mm/s")
    spec = LAWS[law]
    k = len(spec.params)
    if V.size < k + 1:
        raise InputError(f"law '{law}' has {k} parameters and needs at least {k + 1} data points, got {V.size}")
    if law in ("power", "viscous", "stribeck", "power_fixed_n") and np.unique(V).size < 2:
        raise InputError(f"law '{law}' needs at least two distinct speeds")
    if law == "power" and np.unique(V).size < 3:
        raise InputError("law 'power' (free n) needs at least three distinct speeds")
    nf = float(n_fixed) if law == "power_fixed_n" else None
    if nf is not None and not nf > 0:
        raise InputError(f"n_fixed must be positive, got {n_fixed}")
    func = law_function(law, nf)
    if x0 is None:
        if law == "power_fixed_n":
            a, b, _ = _lin_ab(V, F, nf)
            start = np.array([a, b])
        else:
            start = np.asarray(spec.guess(V, F), float)
    else:
        start = np.asarray(x0, float)
        if start.size != k:
            raise InputError(f"x0 has {start.size} values; law '{law}' has parameters {list(spec.params)}")
    lo, hi = spec.bounds(V, F)
    start = np.clip(start, lo, hi)
    res = fit_least_squares(lambda p: func(V, *p), F, start, spec.params, bounds=(lo, hi),
                            n_starts=n_starts, seed=seed, model_rows=lambda p, rows: func(V[rows], *p))
    grid = speed_grid_mm_s(V) if grid_mm_s is None else np.asarray(grid_mm_s, float)
    curve = lambda p: func(grid, *p)  # noqa: E731
    centre, c_lo, c_hi = prediction_band(curve, res)
    _, p_lo, p_hi = prediction_band(curve, res, observation=True)
    band = pd.DataFrame({"speed_mm_s": grid, "friction_mN": centre, "ci_low_mN": c_lo, "ci_high_mN": c_hi,
                         "pi_low_mN": p_lo, "pi_high_mN": p_hi})
    fitted = F - res.residuals
    resid = pd.DataFrame({"speed_mm_s": V, "friction_mN": F, "fitted_mN": fitted, "residual_mN": res.residuals})
    summary = {}
    if groups is not None:
        g = np.asarray(groups).ravel()
        if g.size != V.size:
            raise InputError(f"groups has {g.size} labels for {V.size} rows")
        resid["group"] = pd.Series(g.astype(str), dtype="string")
        stats = (resid.assign(_sq=resid["residual_mN"] ** 2).groupby("group", sort=True)
                 .agg(n=("residual_mN", "size"), mean_r=("residual_mN", "mean"), ms=("_sq", "mean")))
        summary = {str(label): {"n": int(row.n), "rms_residual_mN": float(np.sqrt(row.ms)),
                                "mean_residual_mN": float(row.mean_r)} for label, row in stats.iterrows()}
    formula = spec.formula + (f" (n = {nf:g})" if nf is not None else "")
    return FrictionFit(law, formula, spec.source, res, nf, band, resid, summary)


# ---------------------------------------------------------------------------
# tables

BAND_SCHEMA = TableSchema("friction_fit_band", "fitted friction-speed law and its 95 % bands over a speed grid", (
    Column("speed_mm_s", "float64", "capsule speed"),
    Column("friction_mN", "float64", "fitted friction"),
    Column("ci_low_mN", "float64", "95 % confidence band of the fitted curve, lower"),
    Column("ci_high_mN", "float64", "95 % confidence band of the fitted curve, upper"),
    Column("pi_low_mN", "float64", "95 % prediction band of a new measurement, lower"),
    Column("pi_high_mN", "float64", "95 % prediction band of a new measurement, upper"),
))

RESIDUALS_SCHEMA = TableSchema("friction_fit_residuals", "data, fitted values and residuals of a friction fit", (
    Column("speed_mm_s", "float64", "capsule speed"),
    Column("friction_mN", "float64", "measured friction"),
    Column("fitted_mN", "float64", "fitted friction"),
    Column("residual_mN", "float64", "measured minus fitted"),
    Column("group", "string", "group label (trial, case)", unit="", required=False),
))

HOOP_SCHEMA = TableSchema("hoop_friction", "hoop-pressure friction components over speed and R_i "
                          "(seed 000 eqs 3-16, physics.md section 2)", (
    Column("speed_mm_s", "float64", "capsule speed V"),
    Column("Ri_mm", "float64", "intestine inner radius R_i"),
    Column("head_resistance_N", "float64", "f_hr, axial hoop resistance on the head (eq 10)"),
    Column("head_friction_N", "float64", "f_hf, hoop-induced Coulomb friction on the head (eq 11)"),
    Column("body_friction_N", "float64", "f_bf, hoop-induced Coulomb friction on the body (eq 12)"),
    Column("tail_push_N", "float64", "f_tr, axial hoop force on the tail (eq 13; < 0 pushes forward)"),
    Column("tail_friction_N", "float64", "f_tf, hoop-induced Coulomb friction on the tail (eq 14)"),
    Column("hoop_friction_N", "float64", "F_h = f_hr + f_hf + f_bf + f_tr + f_tf (eq 15 corrected)"),
    Column("coulomb_N", "float64", "F_g = mu m g (eq 1)"),
    Column("total_friction_N", "float64", "F_c4 = F_g + F_h (eq 16)"),
))

PREDICTION_SCHEMA = TableSchema("friction_prediction", "friction predicted by a model file", (
    Column("speed_mm_s", "float64", "capsule speed"),
    Column("friction_mN", "float64", "predicted friction"),
), allow_extra=True)

REFERENCE_COLUMNS = ("case", "speed_mm_s", "friction_mN", "statistic", "source_type", "source", "note")
REFERENCE_STATISTICS = {"avg", "peak", "min", "max"}
REFERENCE_SOURCE_TYPES = {"experiment", "FE", "analytic", "fit"}


def read_friction_reference(path: str | os.PathLike) -> pd.DataFrame:
    """Return the published friction values (configs/reference/friction_seed000.csv), validated.

    Columns: case, speed_mm_s (empty when the paper gives no speed), friction_mN,
    statistic (avg/peak/min/max), source_type (experiment/FE/analytic/fit), source,
    note; optional Ri_mm, speed_min_mm_s, speed_max_mm_s (the speed span of a range).
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: file not found")
    try:
        df = pd.read_csv(p, comment="#")
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot be read ({str(exc).splitlines()[0]})") from None
    missing = [c for c in REFERENCE_COLUMNS if c not in df.columns]
    if missing:
        raise InputError(f"{p}: missing column '{missing[0]}' of a reference table")
    for col in ("speed_mm_s", "friction_mN", "Ri_mm", "speed_min_mm_s", "speed_max_mm_s"):
        if col in df.columns:
            vals = pd.to_numeric(df[col], errors="coerce")
            bad = vals.isna() & df[col].notna()
            if bad.any():
                i = int(np.argmax(bad.to_numpy()))
                raise InputError(f"{p}: column '{col}' row {i + 1}: non-numeric value {df[col].iloc[i]!r}")
            df[col] = vals.astype(float)
    for col, allowed in (("statistic", REFERENCE_STATISTICS), ("source_type", REFERENCE_SOURCE_TYPES)):
        bad = ~df[col].isin(allowed)
        if bad.any():
            i = int(np.argmax(bad.to_numpy()))
            raise InputError(f"{p}: column '{col}' row {i + 1}: {df[col].iloc[i]!r} not in {sorted(allowed)}")
    if df["friction_mN"].isna().any() or df["source"].isna().any():
        raise InputError(f"{p}: every row needs friction_mN and a source")
    return df


# ---------------------------------------------------------------------------
# hoop grid


def capsule_params_si() -> dict[str, float]:
    """Return the capsule and intestine parameters in SI (configs/params/capsule_intestine.yaml)."""
    return load_param_set_si("capsule_intestine")


def hoop_table(speeds_mm_s: Sequence[float], Ri_mm: Sequence[float], wall_mode: str = "attenuated",
               params: dict | None = None) -> pd.DataFrame:
    """Return the hoop-friction components [N] on the grid speeds x R_i (one row per pair).

    Parameters come from configs/params/capsule_intestine.yaml (SI) unless given.
    Columns: see :data:`HOOP_SCHEMA`.
    """
    p = capsule_params_si() if params is None else params
    if wall_mode not in fm.WALL_MODES:
        raise InputError(f"wall mode must be one of {', '.join(fm.WALL_MODES)}, got '{wall_mode}'")
    V, R = np.meshgrid(np.asarray(speeds_mm_s, float), np.asarray(Ri_mm, float), indexing="ij")
    comp = fm.hoop_friction_components_N(V * MM, R * MM, p["Rc"], p["L"], p["wall"], p["E1"], p["E2"], p["eta1"],
                                         p["mu"], wall_mode)
    Fg = float(fm.coulomb_friction_N(p["mu"], p["mass"], p["g"]))
    df = pd.DataFrame({"speed_mm_s": V.ravel(), "Ri_mm": R.ravel()})
    for key in fm.HOOP_COMPONENTS:
        df[f"{key}_N"] = comp[key].ravel()
    df["hoop_friction_N"] = comp["total"].ravel()
    df["coulomb_N"] = Fg
    df["total_friction_N"] = df["hoop_friction_N"] + Fg
    return df


# ---------------------------------------------------------------------------
# predictions from model files (contract section 4)


def predict_friction(model_file: str | os.PathLike | ModelFile, speeds_mm_s: Sequence[float] | None = None,
                     table: pd.DataFrame | None = None, path: str | None = None,
                     Ri_mm: Sequence[float] | None = None) -> pd.DataFrame:
    """Return the friction [mN] a model file of kind ``friction`` predicts.

    Give either ``speeds_mm_s`` (a grid, optionally crossed with radii ``Ri_mm``
    [mm] for effects that need the intestine radius, e.g. ``hoop_pressure``) or a
    validated measurement ``table`` (its covariates feed the effects). The result
    has the covariates and ``friction_mN`` (the prediction; a measured
    ``friction_mN`` is kept as ``measured_friction_mN``). The model is evaluated
    by the effects registry (:func:`capsule_cli.effects.model.build_model`: base
    ``coulomb`` and the effects of ``capsule-cli effects list``), so a model file
    means the same here as in ``synth``, ``compare`` and ``diagnose``.
    """
    from ..effects.model import build_model

    where = path or ("<model>" if isinstance(model_file, ModelFile) else str(model_file))
    model = build_model(model_file, path=where) if isinstance(model_file, ModelFile) else build_model(model_file)
    if model.kind != "friction":
        raise InputError(f"{where}: kind: '{model.kind}' model; friction predict needs kind 'friction'")
    if (speeds_mm_s is None) == (table is None):
        raise InputError("give either speeds or a data table to predict at")
    if table is None:
        v = np.asarray(speeds_mm_s, float).ravel()
        if v.size == 0 or not np.isfinite(v).all() or (v < 0).any():
            raise InputError("speeds must be finite, non-negative and at least one")
        if Ri_mm is None:
            df = pd.DataFrame({"speed_mm_s": v})
        else:
            r = np.asarray(Ri_mm, float).ravel()
            if r.size == 0 or not np.isfinite(r).all() or (r <= 0).any():
                raise InputError("radii R_i must be finite and positive")
            VV, RR = np.meshgrid(v, r, indexing="ij")
            df = pd.DataFrame({"speed_mm_s": VV.ravel(), "Ri_mm": RR.ravel()})
        table_where = "speed grid (add --Ri-mm for effects that need R_i)"
    else:
        df = table.copy()
        table_where = str(df.attrs.get("source_path", "table"))
    bound = model.bind(df, where=table_where)
    pred = check_model_output(bound, None, "model-file values")  # NaN predictions are never written (exit 2)
    if "friction_mN" in df.columns:
        df = df.rename(columns={"friction_mN": "measured_friction_mN"})
    df["friction_mN"] = np.broadcast_to(pred, (len(df),)).astype(float)
    df.attrs["model_hash"] = model.hash
    df.attrs["model_name"] = model.name
    return df


def parse_grid(text: str, what: str) -> np.ndarray:
    """Return the sorted unique numbers of a grid spec: comma-separated items, each a
    number or ``start:stop:num`` (linspace), e.g. ``0.2:12:60,0.4,4``.

    InputError (exit 2) with one line naming ``what`` when malformed.
    """
    out = []
    try:
        for item in str(text).split(","):
            item = item.strip()
            if not item:
                continue
            if ":" in item:
                parts = item.split(":")
                if len(parts) != 3 or int(parts[2]) < 1:
                    raise ValueError
                out.extend(np.linspace(float(parts[0]), float(parts[1]), int(parts[2])))
            else:
                out.append(float(item))
    except ValueError:
        raise InputError(f"{what}: '{text}' is not a grid (use start:stop:num, a,b,c or both)") from None
    vals = np.unique(np.round(np.asarray(out, float), 12))
    if vals.size == 0 or not np.isfinite(vals).all():
        raise InputError(f"{what}: '{text}' gives no finite values")
    return vals
