"""Study-config section for the friction stage (see capsule_cli.config.StudyConfig)."""
from __future__ import annotations

from typing import Literal

from pydantic import Field

from ..config_base import Strict

FitLaw = Literal["power", "power_fixed_n", "viscous", "stribeck", "coulomb"]


class FrictionStudy(Strict):
    """Settings of the friction stage of the study; every field has units in its description."""

    enabled: bool = Field(default=True, description="run this stage in the study")
    hoop_Ri_mm: str = Field(default="4.2:5.4:25", description="intestine radii R_i [mm] of the hoop grid "
                            "(start:stop:num and/or a,b,c); must include figure_Ri_mm")
    hoop_speeds_mm_s: str = Field(default="0.2:12:60,0.4,4,8", description="capsule speeds [mm/s] of the hoop "
                                  "grid (start:stop:num and/or a,b,c)")
    wall_mode: Literal["attenuated", "original"] = Field(
        default="attenuated", description="wall thickness in the hoop pressure: attenuated t_i,e (seed 000 eq 6) "
                                          "or original t_i (seed 003)")
    figure_Ri_mm: str = Field(default="4.4,4.8", description="radii R_i [mm] of the hoop lines in the speed "
                              "figure (seed 000 Fig 13c: 4.4 and 4.8 mm)")
    components_speed_mm_s: float = Field(default=4.0, gt=0, description="speed [mm/s] of the components-vs-R_i "
                                         "panel (seed 000 Fig 14: 4 mm/s)")
    curve_speeds_mm_s: str = Field(default="0:12:121", description="speeds [mm/s] of the model curves "
                                   "(Coulomb, eqs 17-18) in the figures")
    synthetic_model: str = Field(default="configs/models/friction_seed000_eq17.yaml",
                                 description="model file (repo-relative) of the synthetic Case 1 pull tests")
    synthetic_design: str = Field(default="configs/designs/friction_speed.csv",
                                  description="design table (repo-relative): the pull-test speeds [mm/s]")
    synthetic_replicates: int = Field(default=3, ge=1, description="synthetic trials per design speed")
    synthetic_noise_sd_mN: float = Field(default=1.5, gt=0, description="noise SD [mN] of the synthetic "
                                         "trial averages")
    fit_laws: list[FitLaw] = Field(default_factory=lambda: ["power_fixed_n", "power", "viscous", "stribeck"],
                                   min_length=1, description="laws fitted to the synthetic Case 1 data; the "
                                                             "first one is drawn in the speed figure")
    n_fixed: float = Field(default=0.25, gt=0, description="exponent n [-] of the power_fixed_n law "
                           "(seed 000 eqs 17-18)")
    n_starts: int = Field(default=6, ge=1, description="starting points of each least-squares fit")
