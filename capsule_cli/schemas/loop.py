"""Study-config section for the loop stage (see capsule_cli.config.StudyConfig)."""
from __future__ import annotations

from typing import Literal

from pydantic import Field

from ..config_base import Strict


class LoopStudy(Strict):
    """Settings of the loop stage: one hidden-effect demo per kind plus the published-data loops."""

    enabled: bool = Field(default=True, description="run this stage in the study")
    kinds: list[Literal["friction", "pressure", "relaxation"]] = Field(default_factory=lambda: ["friction", "pressure", "relaxation"],
                             description="kinds with a synth -> compare -> diagnose -> compare -> ledger demo")
    replicates: int = Field(default=4, ge=1, description="replicates per design row of the synthetic demos [-]")
    folds: int = Field(default=5, ge=2, description="cross-validation folds [-]")
    noise_sd_friction_mN: float = Field(default=1.5, ge=0, description="noise SD of the friction demo [mN]")
    noise_sd_pressure_kPa: float = Field(default=0.2, ge=0, description="noise SD of the pressure demo [kPa]")
    noise_sd_relaxation_kPa: float = Field(default=0.05, ge=0, description="noise SD of the relaxation demo [kPa]")
    dynamics_kinds: list[Literal["progression", "trajectory"]] = Field(
        default_factory=list,
        description="dynamics kinds with a hidden-effect demo (progression: the hidden effect is dynamics_demo; "
                    "trajectory: trajectory_demo); none when the list is empty (configs/study.yaml turns them on)")
    dynamics_design: str = Field(default="progression_grid.csv",
                                 description="design of the progression demo (configs/designs/)")
    dynamics_replicates: int = Field(default=2, ge=1, description="replicates per condition of the dynamics demo [-]")
    dynamics_effort: Literal["full", "quick"] = Field(default="full", description="calibration budget of the "
                                                      "dynamics demo (capsule-cli --effort)")
    dynamics_demo: Literal["sdf", "secondary"] = Field(
        default="sdf", description="hidden effect of the dynamics demo: speed_dependent_friction (sdf; adaptive "
                                   "engine path) or secondary_constraint (closed form, the smoke run's)")
    dynamics_candidates: list[str] = Field(default_factory=list, description="effects the dynamics demo's diagnose "
                                           "tries (capsule-cli diagnose --candidate); empty: every applicable one")
    noise_sd_progression_mm_s: float = Field(default=0.5, ge=0, description="noise SD of the progression demo [mm/s]")
    trajectory_demo: Literal["tilt"] = Field(
        default="tilt", description="hidden effect of the trajectory demo: tilt_friction (the README's trajectory "
                                    "example, configs/models/trajectory_tilt_truth.yaml)")
    trajectory_design: str = Field(default="trajectory_runs.csv",
                                   description="runs of the trajectory demo (configs/designs/; one run per row)")
    noise_sd_trajectory_mm: float = Field(default=0.3, ge=0,
                                          description="position noise SD of the trajectory demo [mm]")
    frame_rate_Hz: float = Field(default=100.0, gt=0, description="camera frame rate of the trajectory demo [Hz]")
    published: bool = Field(default=True, description="also run the loops on the published seed values "
                                                      "(configs/data/)")
