"""Progress bars: rich on a terminal, silent in pipelines (``--quiet`` or no TTY)."""
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
