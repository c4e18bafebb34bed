"""Physical effects a model can switch on, and the base models they modify (contract section 4).

See :mod:`capsule_cli.effects.registry` for the API a plugin uses
(:class:`Param`, :func:`register_effect`) and :mod:`capsule_cli.effects.model`
for turning a model file into a calibratable predictor.
"""
from .registry import (BaseModel, Effect, Param, bases, effects, get_base, get_effect, load_plugins,  # noqa: F401
                       register_base, register_effect)
