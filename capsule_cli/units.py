"""Unit suffixes of column and parameter names, and their conversion to SI.

A name such as ``speed_mm_s`` carries its unit as a suffix (contract section 3).
:func:`split_unit` finds the longest known suffix; :func:`to_si` and
:func:`from_si` convert values. Dimensionless names (``mu``, ``duty``, ``n``)
have no suffix and a factor of 1.
"""
from __future__ import annotations

import math

# suffix -> (SI factor, human-readable unit, dimension)
UNITS: dict[str, tuple[float, str, str]] = {
    # length
    "m": (1.0, "m", "length"),
    "mm": (1e-3, "mm", "length"),
    "um": (1e-6, "µm", "length"),
    "cm": (1e-2, "cm", "length"),
    # time
    "s": (1.0, "s", "time"),
    "ms": (1e-3, "ms", "time"),
    "min": (60.0, "min", "time"),
    # speed
    "m_s": (1.0, "m/s", "speed"),
    "mm_s": (1e-3, "mm/s", "speed"),
    "cm_s": (1e-2, "cm/s", "speed"),
    # acceleration
    "m_s2": (1.0, "m/s²", "acceleration"),
    # force
    "N": (1.0, "N", "force"),
    "mN": (1e-3, "mN", "force"),
    # pressure / modulus
    "Pa": (1.0, "Pa", "pressure"),
    "kPa": (1e3, "kPa", "pressure"),
    "MPa": (1e6, "MPa", "pressure"),
    "GPa": (1e9, "GPa", "pressure"),
    "psi": (6894.757293168, "psi", "pressure"),
    # viscosity (modulus x time)
    "Pa_s": (1.0, "Pa·s", "viscosity"),
    "kPa_s": (1e3, "kPa·s", "viscosity"),
    "MPa_s": (1e6, "MPa·s", "viscosity"),
    # mass
    "kg": (1.0, "kg", "mass"),
    "g": (1e-3, "g", "mass"),
    # frequency
    "Hz": (1.0, "Hz", "frequency"),
    # stiffness and damping
    "N_m": (1.0, "N/m", "stiffness"),
    "N_mm": (1e3, "N/mm", "stiffness"),
    "kN_m": (1e3, "kN/m", "stiffness"),
    "Ns_m": (1.0, "N·s/m", "damping"),
    # compliance (inverse stiffness)
    "m_N": (1.0, "m/N", "compliance"),
    "mm_N": (1e-3, "mm/N", "compliance"),
    # density
    "kg_m3": (1.0, "kg/m³", "density"),
    "g_cm3": (1e3, "g/cm³", "density"),
    # angle, temperature, ratios
    "deg": (math.pi / 180.0, "deg", "angle"),
    "rad": (1.0, "rad", "angle"),
    "C": (1.0, "°C", "temperature"),
    "K": (1.0, "K", "temperature"),
    "pct": (1e-2, "%", "ratio"),
    "1": (1.0, "1", "ratio"),
}

# Names that are dimensionless or labels and carry no suffix.
DIMENSIONLESS = {"mu", "duty", "n", "nu", "factor", "exponent", "poisson", "kappa"}


def split_unit(name: str) -> tuple[str, str | None]:
    """Return ``(base, suffix)`` of a unit-suffixed name, longest suffix first.

    ``split_unit("speed_mm_s") == ("speed", "mm_s")``;
    ``split_unit("mu") == ("mu", None)``.
    """
    parts = name.split("_")
    for k in (3, 2, 1):
        if len(parts) > k:
            suffix = "_".join(parts[-k:])
            if suffix in UNITS:
                return "_".join(parts[:-k]), suffix
    return name, None


def unit_factor(name_or_suffix: str) -> float:
    """Return the factor that converts a value in the named unit to SI [-]."""
    if name_or_suffix in UNITS:
        return UNITS[name_or_suffix][0]
    _, suffix = split_unit(name_or_suffix)
    return 1.0 if suffix is None else UNITS[suffix][0]


def unit_label(name_or_suffix: str) -> str:
    """Return the human-readable unit of a suffixed name ('mm/s'), '' if none."""
    if name_or_suffix in UNITS:
        return UNITS[name_or_suffix][1]
    _, suffix = split_unit(name_or_suffix)
    return "" if suffix is None else UNITS[suffix][1]


def dimension(name_or_suffix: str) -> str | None:
    """Return the physical dimension of a suffixed name ('speed'), None if none."""
    if name_or_suffix in UNITS:
        return UNITS[name_or_suffix][2]
    _, suffix = split_unit(name_or_suffix)
    return None if suffix is None else UNITS[suffix][2]


def to_si(value, name_or_suffix: str):
    """Convert ``value`` given in the unit of ``name_or_suffix`` to SI.

    Temperatures are returned unchanged (°C stays °C: they are covariates only).
    """
    return value * unit_factor(name_or_suffix)


def from_si(value, name_or_suffix: str):
    """Convert an SI ``value`` to the unit of ``name_or_suffix``."""
    return value / unit_factor(name_or_suffix)


def convert(value, from_name: str, to_name: str):
    """Convert ``value`` between two names of the same dimension."""
    if dimension(from_name) != dimension(to_name):
        raise ValueError(f"cannot convert {from_name} to {to_name}: different dimensions")
    return value * unit_factor(from_name) / unit_factor(to_name)
