"""Study-config section for the dynamics stage (see capsule_cli.config.StudyConfig).

Defaults are the full study (seed 000 Figs 17-19, seed 004 Scenario 3); the smoke config
overrides the grids with a few points.
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from ..config_base import Strict

Protocol = Literal["rest", "up", "down"]
FrictionKind = Literal["coulomb", "eq22", "eq23", "fixed"]


class FrictionCase(Strict):
    """One friction model of a frequency sweep (seed 000 eqs 21-23)."""

    label: str = Field(description="name of the case in file names and legends, e.g. coulomb_7p8mN")
    friction: FrictionKind = Field(description="coulomb (level Pf_N), eq22, eq23 (well-posed laws) or fixed (P_f = inf)")
    Pf_N: float | None = Field(default=None, description="Coulomb level P_f [N] (coulomb only)")
    figure: Literal["fig17", "fig18"] = Field(description="which figure of seed 000 the case belongs to")
    law_speed_unit: Literal["mm/s", "m/s"] = Field(default="mm/s", description="unit V is taken in by eq22/eq23: "
                                                   "mm/s as fitted (physics.md), m/s a sensitivity case")


class FrequencySweep(Strict):
    """Bifurcation / progression sweeps over f for P_d fixed (seed 000 Figs 17-18)."""

    model: str = Field(default="prototype_one_sided", description="parameter set in configs/params")
    Pd_N: float = Field(default=0.15, gt=0, description="drive amplitude P_d [N] (seed 000 section 5.3)")
    f_start_Hz: float = Field(default=1.0, gt=0, description="first frequency [Hz]")
    f_stop_Hz: float = Field(default=40.0, gt=0, description="last frequency [Hz]")
    f_num: int = Field(default=391, ge=1, description="number of frequencies [-] (391: 0.1 Hz steps)")
    transient_periods: int = Field(default=300, ge=0, description="periods discarded per point [-]")
    recorded_periods: int = Field(default=60, ge=1, description="periods recorded per point [-]")
    protocols: list[Protocol] = Field(default_factory=lambda: ["rest", "up", "down"],
                                      description="initial conditions: rest (every point from rest), up/down (continuation)")
    cases: list[FrictionCase] = Field(default_factory=lambda: [
        FrictionCase(label="coulomb_7p8mN", friction="coulomb", Pf_N=0.0078, figure="fig17"),
        FrictionCase(label="eq22", friction="eq22", figure="fig17"),
        FrictionCase(label="eq22_V_in_m_s", friction="eq22", figure="fig17", law_speed_unit="m/s"),
        FrictionCase(label="coulomb_2p5N", friction="coulomb", Pf_N=2.5, figure="fig18"),
        FrictionCase(label="eq23", friction="eq23", figure="fig18"),
        FrictionCase(label="eq23_V_in_m_s", friction="eq23", figure="fig18", law_speed_unit="m/s"),
    ], description="friction cases (one sweep per case and protocol)")

    @field_validator("cases")
    @classmethod
    def _unique(cls, v):
        labels = [c.label for c in v]
        if len(set(labels)) != len(labels):
            raise ValueError(f"case labels must be unique, got {labels}")
        return v


class DutyMap(Strict):
    """Square-wave frequency x duty map of progression speed (seed 004 Scenario 3, double-sided model)."""

    model: str = Field(default="prototype_double_sided", description="parameter set in configs/params")
    Pd_N: float = Field(default=1.2, gt=0, description="square-wave amplitude P_d [N] (seed 004 Scenario 3)")
    f_Hz: list[float] = Field(default_factory=lambda: [10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0],
                              description="frequencies [Hz] (seed 004: 10-40 Hz)")
    duty_start: float = Field(default=0.2, gt=0, lt=1, description="first duty cycle [-]")
    duty_stop: float = Field(default=0.8, gt=0, lt=1, description="last duty cycle [-]")
    duty_num: int = Field(default=25, ge=1, description="number of duty cycles [-]")
    friction: FrictionKind = Field(default="eq23", description="shell friction: eq23 = Case 4 contractive intestine "
                                   "(seed 004 simulates a contracted intestine)")
    Pf_N: float | None = Field(default=None, description="Coulomb level [N] when friction is coulomb")
    transient_periods: int = Field(default=200, ge=0, description="periods discarded per point [-]")
    recorded_periods: int = Field(default=50, ge=1, description="periods recorded per point [-]")
    protocol: Protocol = Field(default="rest", description="initial conditions of every point")


class MagnifyMap(Strict):
    """Magnification factor A_f = max|F_i|/P_d over (P_d, f) (seed 000 eq 24, Fig 19)."""

    enabled: bool = Field(default=True, description="compute the maps")
    model: str = Field(default="prototype_one_sided", description="parameter set in configs/params")
    Pd_start_N: float = Field(default=0.01, gt=0, description="first amplitude [N]")
    Pd_stop_N: float = Field(default=0.5, gt=0, description="last amplitude [N]")
    Pd_num: int = Field(default=50, ge=1, description="number of amplitudes [-]")
    f_start_Hz: float = Field(default=5.0, gt=0, description="first frequency [Hz]")
    f_stop_Hz: float = Field(default=40.0, gt=0, description="last frequency [Hz]")
    f_num: int = Field(default=71, ge=1, description="number of frequencies [-]")
    Pf_N: list[float] = Field(default_factory=lambda: [0.007, 0.17, 2.5, 4.5, 10.0, float("inf")],
                              description="Coulomb levels [N] (seed 000 Fig 19; .inf = shell fixed)")
    laws: list[Literal["eq22", "eq23"]] = Field(default_factory=lambda: ["eq22", "eq23"],
                                                description="speed-law frictions of seed 000 Fig 19 (F_c1e eq 22, "
                                                            "F_c4e eq 23)")
    transient_periods: int = Field(default=200, ge=0, description="periods discarded per point [-]")
    recorded_periods: int = Field(default=30, ge=1, description="periods recorded per point [-]")
    protocol: Protocol = Field(default="rest", description="initial conditions (rest, or up/down in f)")
    target_job_s: float = Field(default=300.0, gt=0, description="target wall time of one map job [s]: maps are "
                                "split along P_d into jobs of about this length, tiny maps grouped into one job")
    threads_per_job: int = Field(default=2, ge=1, description="threads (cores) of one map job [-]")
    cost_us_per_period: dict[Literal["coulomb", "fixed", "eq22", "eq23"], float] = Field(
        default_factory=lambda: {"coulomb": 15.0, "fixed": 10.0, "eq22": 46.0, "eq23": 42.0},
        description="engine cost per simulated period on one core [us], by friction kind: sizes the map jobs. "
                    "eq22 / eq23 measured by `capsule-cli bench --fig19 --json` on the full 100 x 100 grid "
                    "(wall time x 2 threads / nominal periods, 230 per point: 45.5 and 41.3 us; 2-core dev "
                    "machine, quiet, 2026-11-24, session 10); coulomb / fixed from the 2026-11-23 sample, above that "
                    "run's 5-10 and 4 us (session 10's full grid: 3-8 and 4 us)")


class DynamicsStudy(Strict):
    """Settings of the dynamics stage of the study; every field has units in its description."""

    enabled: bool = Field(default=True, description="run this stage in the study")
    frequency_sweeps: FrequencySweep = Field(default_factory=FrequencySweep,
                                             description="seed 000 Figs 17-18 sweeps")
    duty_map: DutyMap = Field(default_factory=DutyMap, description="seed 004 Scenario 3 map")
    magnify: MagnifyMap = Field(default_factory=MagnifyMap, description="seed 000 Fig 19 maps")
    bench: bool = Field(default=True, description="run `capsule-cli bench --json` in the study [-]")
