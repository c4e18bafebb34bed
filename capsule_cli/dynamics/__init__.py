"""Event-driven vibro-impact dynamics of the capsule (seed 000 eqs 19-24; seed 001 App. A).

* :mod:`.engine` -- the numba-compiled closed-form engine (modes, events, stick-slip);
* :mod:`.model` -- parameters, drive, friction laws and their packing for the engine;
* :mod:`.run` -- one run as tables; :mod:`.reference` -- the scipy solve_ivp reference;
* :mod:`.sweep` -- sweeps and continuation; :mod:`.bench` -- the benchmark (contract section 6).
"""
from .model import CapsuleModel, Drive, EngineOptions, Friction, friction_preset, load_model  # noqa: F401
from .run import DynamicsError, RunResult, simulate  # noqa: F401
