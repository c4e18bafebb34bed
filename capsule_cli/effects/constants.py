"""Fixed constants of the capsule and intestine that models and effects read (SI).

Values come from ``configs/params`` (capsule_intestine.yaml, contact_cases.yaml,
friction_laws.yaml), each with its citation there; nothing is hard-coded here.
"""
from __future__ import annotations

from functools import lru_cache

from ..config import load_param_set_si


@lru_cache(maxsize=1)
def capsule_constants() -> dict[str, float]:
    """Return ``{base name: SI value}`` of the capsule/intestine set plus the power-law V_ref [m/s]."""
    c = dict(load_param_set_si("capsule_intestine"))
    c.update({k: v for k, v in load_param_set_si("contact_cases").items()})
    laws = load_param_set_si("friction_laws")
    c["V_ref"] = laws["V_ref"]
    return c


def published(name: str, set_name: str = "capsule_intestine") -> float:
    """Return a published value in the unit of its name's suffix (for default parameter values)."""
    from ..config import load_param_set

    return float(load_param_set(set_name)[name])
