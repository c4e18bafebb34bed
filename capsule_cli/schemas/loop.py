"""Study-config section for the loop stage (see capsule_cli.config.StudyConfig)."""
from __future__ import annotations

from pydantic import Field

from ..config_base import Strict


class LoopStudy(Strict):
    """Settings of the loop stage of the study; every field has units in its description."""

    enabled: bool = Field(default=True, description="run this stage in the study")
