"""Base class of every config schema (kept apart so stage schemas can import it)."""
from pydantic import BaseModel, ConfigDict


class Strict(BaseModel):
    """Base for every config schema: unknown keys are errors."""

    model_config = ConfigDict(extra="forbid")
