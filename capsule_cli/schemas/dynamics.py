"""Study-config section for the dynamics stage (see capsule_cli.config.StudyConfig)."""
from __future__ import annotations

from pydantic import Field

from ..config_base import Strict


class DynamicsStudy(Strict):
    """Settings of the dynamics stage of the study; every field has units in its description."""

    enabled: bool = Field(default=True, description="run this stage in the study")
