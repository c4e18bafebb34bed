"""Study-config section for the contact stage (see capsule_cli.config.StudyConfig)."""
from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from ..config_base import Strict


def _range(v):
    start, stop, num = v
    if not (0 <= start < stop) or int(num) < 2:
        raise ValueError(f"need [start, stop, num] with 0 <= start < stop and num >= 2, got {list(v)}")
    return v


def _positive_list(v):
    if not v or any(x <= 0 for x in v):
        raise ValueError(f"need a non-empty list of positive values, got {v}")
    return v


class ContactStudy(Strict):
    """Settings of the contact stage of the study; every field has units in its description."""

    enabled: bool = Field(default=True, description="run this stage in the study")
    params: str = Field(default="capsule_intestine",
                        description="parameter set in configs/params/ (capsule and intestine, seed 003 Table 1)")
    speed_range_mm_s: tuple[float, float, int] = Field(
        default=(0.2, 16.0, 80),
        description="[start mm/s, stop mm/s, number of speeds] of the pressure-vs-speed table (seed 003 tests: "
                    "up to about 15 mm/s)")
    hoop_Ri_mm: list[float] = Field(
        default=[4.4, 4.6, 4.8, 5.0],
        description="intestine inner radii [mm] of the hoop model in the pressure-vs-speed table "
                    "(Case 3: 5 mm, seed 003; Case 4 of seed 000: 4.4-4.8 mm)")
    Ri_range_mm: tuple[float, float, int] = Field(
        default=(4.0, 5.5, 61),
        description="[start mm, stop mm, number] of intestine inner radii for the pressure-vs-R_i table "
                    "(R_i >= R_c = 5.5 mm means no hoop contact)")
    Ri_sweep_speeds_mm_s: list[float] = Field(
        default=[0.5, 4.0, 10.0], description="capsule speeds [mm/s] of the pressure-vs-R_i table")
    profile_speeds_mm_s: list[float] = Field(
        default=[0.5, 2.0, 4.0, 10.0], description="capsule speeds [mm/s] of the hoop pressure profiles")
    end_lengths_mm: list[float] = Field(
        default=[2.75, 4.125, 5.5, 6.875, 8.25],
        description="semi-elliptical end lengths [mm] of the end-shape study (seed 001 section 6: up to "
                    "8.25 mm, 5.5 mm = hemisphere recommended; the shorter ones span R_c/2 to R_c)")
    end_shape_speed_mm_s: float = Field(default=10.0, gt=0,
                                        description="capsule speed [mm/s] of the end-shape study (seed 001 Fig 15)")
    wall_modes: list[Literal["attenuated", "original"]] = Field(
        default=["attenuated", "original"],
        description="hoop wall thickness: attenuated t_i,e (seed 003 eq 9) and/or original t_i (what reproduces "
                    "seed 003's 11.87 kPa)")
    case2_geometry: Literal["conforming", "as_printed"] = Field(
        default="conforming",
        description="lower contact of Case 2: conforming (capsule in a trough, R_e = (1/R_c - 1/R_i)^-1) or "
                    "as_printed (seed 003 eq 2, R_e = (1/R_c + 1/R_i)^-1)")

    _check_speed = field_validator("speed_range_mm_s")(lambda cls, v: _range(v))
    _check_ri = field_validator("Ri_range_mm")(lambda cls, v: _range(v))
    _check_lists = field_validator("hoop_Ri_mm", "Ri_sweep_speeds_mm_s", "profile_speeds_mm_s",
                                   "end_lengths_mm")(lambda cls, v: _positive_list(v))
