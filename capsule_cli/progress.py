"""Progress bars: rich on a terminal, silent in pipelines (``--quiet`` or no TTY).

Parallel sweeps and maps advance the bar as chunks finish (:mod:`.dynamics.parallel`).
"""
from __future__ import annotations

import sys
from contextlib import contextmanager
from typing import Iterable, Iterator, TypeVar

T = TypeVar("T")


def show_progress(quiet: bool = False) -> bool:
    """Return True when a progress bar should be drawn (a TTY on stderr and not quiet)."""
    return not quiet and sys.stderr.isatty()


def track(items: Iterable[T], description: str, total: int | None = None, quiet: bool = False) -> Iterator[T]:
    """Iterate over ``items`` with a progress bar when :func:`show_progress` allows."""
    if not show_progress(quiet):
        yield from items
        return
    from rich.progress import track as rich_track

    yield from rich_track(items, description=description, total=total, transient=True)


@contextmanager
def task(description: str, total: int, quiet: bool = False):
    """Yield an ``advance(n=1)`` callable driving a progress bar (no-op when quiet)."""
    if not show_progress(quiet):
        yield lambda n=1: None
        return
    from rich.progress import Progress

    with Progress(transient=True) as prog:
        tid = prog.add_task(description, total=total)
        yield lambda n=1: prog.advance(tid, n)


def _needs_compile(dispatcher) -> bool:
    """True when a numba dispatcher has no loaded code and no valid on-disk cache (it will compile)."""
    if getattr(dispatcher, "signatures", None):
        return False
    try:
        return not dispatcher._cache._cache_file._load_index()  # empty when missing or stale
    except Exception:  # numba internals changed: say nothing rather than guess
        return False


def compile_notice(quiet: bool = False, kernels: tuple[str, ...] = ("run_many",)) -> bool:
    """Say on stderr (terminal only) that the engine is being compiled, when it is; return whether it is.

    The first-ever call (or the first after the engine's source changed) compiles the numba
    engine, which takes tens of seconds; afterwards the on-disk cache loads in about a second.
    ``kernels``: names of the engine's compiled entry points the command will call.
    """
    if quiet or not sys.stderr.isatty():
        return False
    from .dynamics import engine as E

    if any(_needs_compile(getattr(E, k)) for k in kernels if hasattr(E, k)):
        sys.stderr.write("capsule-cli: compiling the dynamics engine (first run only, cached afterwards; "
                         "this can take a minute)...\n")
        sys.stderr.flush()
        return True
    return False


@contextmanager
def exit_on_interrupt():
    """Turn Ctrl-C (KeyboardInterrupt) inside a command into exit code 130 (contract section 5).

    Long work returns to Python between chunks (:mod:`.dynamics.parallel`), so the interrupt
    lands within about a chunk; outputs are written only after the work, atomically, so an
    interrupted command leaves no file behind. The one line "capsule-cli: interrupted" is the CLI's
    (:func:`capsule_cli.cli.main` says it for every exit 130); written here too, it came twice.
    """
    try:
        yield
    except KeyboardInterrupt:
        import typer

        raise typer.Exit(130) from None
