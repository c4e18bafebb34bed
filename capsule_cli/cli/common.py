"""Options and helpers shared by the command modules."""
from __future__ import annotations

from pathlib import Path

import typer

QUIET = typer.Option(False, "--quiet", "-q", help="No progress bar (also off when stderr is not a terminal).")


def out_option(default: str | None = None, help: str = "Output file or folder (written atomically).") -> Path:
    """Return a typer ``--out`` option."""
    return typer.Option(default, "--out", "-o", help=help)


def ensure_suffix(path: Path, suffixes: tuple[str, ...], what: str) -> None:
    """Raise InputError unless ``path`` ends with one of ``suffixes``."""
    from ..errors import InputError

    if path.suffix.lower() not in suffixes:
        raise InputError(f"{path}: {what} must end with {' or '.join(suffixes)}")
