"""capsule-cli: study pipeline for self-propelled vibro-impact capsule robots.

Layers (see docs/architecture.md):
``models`` (pure physics, SI) -> ``dynamics`` (event-driven engine) ->
``steps`` (compose models over tables) -> ``tables``/``plots`` -> ``cli``.
"""
from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version("capsule-cli")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"
