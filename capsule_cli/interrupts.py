"""Ctrl-C and SIGTERM around work that must not be cut in two (contract section 5: exit 130 / 143).

The CLI makes SIGINT raise KeyboardInterrupt and SIGTERM raise ``Terminated`` (:mod:`capsule_cli.cli.common`).
Two places must not take them in the middle:

- a call into compiled (numba) code: a Python handler that runs while the call returns its result turns
  into "returned a result with an exception set", a SystemError, which ``except Exception`` takes for a
  failure (a Ctrl-C once let ``diagnose`` run to its end);
- the few renames that move a command's finished outputs into place (:func:`capsule_cli.tables.staged_folder`).

:func:`deferred_signals` holds the signals for the length of such a block and delivers them when it ends.
"""
from __future__ import annotations

import signal
import threading


class _Deferral:
    """The context manager of :func:`deferred_signals` (a class: entered tens of thousands of times a fit)."""

    __slots__ = ("signals", "prev", "got", "outer")
    depth = 0  # blocks open in the main thread; only the outermost swaps the handlers

    def __init__(self, signals):
        self.signals = signals
        self.prev: dict = {}
        self.got: list[int] = []
        self.outer = False

    def __enter__(self):
        if threading.current_thread() is not threading.main_thread():
            return self
        _Deferral.depth += 1
        if _Deferral.depth > 1:  # inside another block: its handlers already hold the signals
            return self
        self.outer = True
        got = self.got
        for sig in self.signals:
            h = signal.getsignal(sig)
            if h in (signal.SIG_IGN, None):  # ignored (e.g. a background job): leave it so
                continue
            self.prev[sig] = h
            signal.signal(sig, lambda s, _f: got.append(s))
        return self

    def __exit__(self, *exc) -> bool:
        if threading.current_thread() is not threading.main_thread():
            return False
        _Deferral.depth -= 1
        if self.outer:
            for sig, h in self.prev.items():
                signal.signal(sig, h)
            for sig in dict.fromkeys(self.got):
                signal.raise_signal(sig)
        return False


def deferred_signals(signals=(signal.SIGINT, signal.SIGTERM)) -> _Deferral:
    """Hold SIGINT / SIGTERM while the block runs, then deliver them to the previous handlers.

    The signal is kept in a flag and raised again after the block, so the process-level handlers
    (KeyboardInterrupt, exit 130 / 143) act cleanly, at the block's end at most: keep blocks short
    (the engine's calls are chunked to about 0.2 s, :mod:`capsule_cli.dynamics.parallel`). Outside the
    main thread (where handlers cannot be set) a no-op; an ignored signal (a background job) stays ignored.
    A block inside another costs a counter (the outer one's handlers hold the signals until it ends); the
    outermost swaps the handlers, about 15 us in and out.
    """
    return _Deferral(signals)
