"""Ctrl-C and SIGTERM around work that must not be cut in two (contract section 5: exit 130 / 143).

The CLI makes SIGINT raise KeyboardInterrupt and SIGTERM raise ``Terminated`` (:mod:`capsule_cli.cli.common`).
Two places must not take them in the middle:

- a call into compiled (numba) code: a Python handler that runs while the call returns its result turns
  into "returned a result with an exception set", a SystemError, which ``except Exception`` takes for a
  failure (a Ctrl-C once let ``diagnose`` run to its end);
- the few renames that move a command's finished outputs into place (:func:`capsule_cli.tables.staged_folder`).

:func:`deferred_signals` holds the signals for the length of such a block and delivers them when it ends
(:func:`deferred_call`: a compiled call, compiled first with the signals free). That is right for calls of a
fraction of a second (the sweeps' chunks, a fit's runs). One call can last far longer: a
`simulate` of millions of periods. :func:`call_interruptibly` runs such a call in a worker thread, so that the
main thread takes the signal at once.
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


def deferred_signals(signals=(signal.SIGINT, signal.SIGTERM, signal.SIGHUP)) -> _Deferral:
    """Hold SIGINT / SIGTERM / SIGHUP while the block runs, then deliver them to the previous handlers.

    The signal is kept in a flag and raised again after the block, so the process-level handlers
    (KeyboardInterrupt, exit 130 / 143) act cleanly, at the block's end at most: keep blocks short
    (the engine's calls are chunked to about 0.2 s, :mod:`capsule_cli.dynamics.parallel`). Outside the
    main thread (where handlers cannot be set) a no-op; an ignored signal (a background job) stays ignored.
    A block inside another costs a counter (the outer one's handlers hold the signals until it ends); the
    outermost swaps the handlers, about 15 us in and out.
    """
    return _Deferral(signals)


def compile_first(fn, *args) -> None:
    """Compile the numba dispatcher ``fn`` for the types of ``args`` (or load it from numba's disk cache) when it
    has no compiled code yet, in a worker thread while the main thread waits (:func:`call_interruptibly`); else,
    or when ``fn`` is not a dispatcher, nothing.

    A first call compiles the engine: minutes with a cold cache (a fresh clone, or the engine's source changed),
    and Ctrl-C was lost there twice over. Inside :func:`deferred_signals` it waited for the compilation; and
    in the main thread the handler's KeyboardInterrupt is raised inside one of llvmlite's ctypes callbacks,
    which prints "Exception ignored" and drops it: a `diagnose` of progression speeds, SIGINT 8 s after the
    start (14.6 s of compiling run_many), ran on. The worker's callbacks never see the signal; the main thread
    takes it at once (the compiler releases the GIL in its ctypes calls). An interrupted compilation leaves
    numba's cache as it was (numba writes its cache files by rename). Only a dispatcher with no code at all is
    compiled: the engine's entry points are called with one set of types, and looking the types up at every
    call would cost more than the deferral itself.
    """
    overloads = getattr(fn, "overloads", None)
    if overloads is None or len(overloads):
        return
    from numba import typeof

    call_interruptibly(fn.compile, tuple(typeof(a) for a in args))


def deferred_call(fn, *args):
    """Return ``fn(*args)`` (a call into compiled code) with SIGINT / SIGTERM held for the call and delivered
    after it (:func:`deferred_signals`), but free while ``fn`` is first compiled (:func:`compile_first`)."""
    compile_first(fn, *args)
    with deferred_signals():
        return fn(*args)


def call_interruptibly(fn, *args):
    """Return ``fn(*args)``, run in a worker thread while the main thread waits, so that a SIGINT / SIGTERM
    stops the caller at once (within 0.1 s) instead of when ``fn`` returns.

    ``fn`` must let the GIL go: a numba function compiled with ``nogil=True``, or Python code such as numba's
    compiler (which gives it up at the interpreter's switch interval and in its ctypes calls). The main thread
    waits in ``Thread.join``, which a signal interrupts, and its handler raises there. An exception of ``fn`` is
    raised here. On an interrupt the worker is left to finish on its own (a daemon thread: a command that exits
    on the interrupt ends it with the process); its result is dropped, and no Python object is shared with it
    but ``args``. Outside the main thread ``fn`` is called directly.
    """
    if threading.current_thread() is not threading.main_thread():
        return fn(*args)
    box: dict = {}

    def work():
        try:
            box["result"] = fn(*args)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller below
            box["error"] = exc

    worker = threading.Thread(target=work, name="capsule-cli compiled call", daemon=True)
    worker.start()
    while worker.is_alive():
        worker.join(0.1)  # a signal's handler raises here
    if "error" in box:
        raise box["error"]
    return box["result"]
