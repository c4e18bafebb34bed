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


# ---------------------------------------------------------------------------
# signals (contract section 5: 130 on SIGINT, 143 on SIGTERM, nothing half-written)


class Terminated(BaseException):
    """Raised by the SIGTERM handler; a BaseException so that ``except Exception`` does not swallow it."""


class HungUp(Terminated):
    """Raised by the SIGHUP handler (the terminal closed, an ssh connection dropped): exit 129, cleaned up."""


def _raise_terminated(signum, frame):  # noqa: ARG001
    raise Terminated()


def _raise_hung_up(signum, frame):  # noqa: ARG001
    raise HungUp()


def install_signal_handlers() -> dict:
    """Make SIGINT raise KeyboardInterrupt, SIGTERM :class:`Terminated` and SIGHUP :class:`HungUp`; return the old
    handlers.

    Raising (instead of dying) lets every ``atomic_path`` and ``staged_folder`` remove its temporary files. SIGHUP
    is taken only where it would kill the command (its default action): under ``nohup`` it stays ignored.
    Only possible in the main thread; elsewhere nothing is changed.
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return {}
    old = {signal.SIGINT: signal.getsignal(signal.SIGINT), signal.SIGTERM: signal.getsignal(signal.SIGTERM)}
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _raise_terminated)
    if signal.getsignal(signal.SIGHUP) == signal.SIG_DFL:
        old[signal.SIGHUP] = signal.SIG_DFL
        signal.signal(signal.SIGHUP, _raise_hung_up)
    return old


def restore_signal_handlers(old: dict) -> None:
    """Put back the handlers returned by :func:`install_signal_handlers`."""
    import signal

    for sig, handler in old.items():
        signal.signal(sig, handler if handler is not None else signal.SIG_DFL)


def check_outputs(*, folder=None, file=None, ledger=None, option: str = "--out", **more) -> None:
    """Check, before any work, that the command's outputs can be written (InputError naming the path).

    ``folder`` / ``file``: the ``--out`` folder or file; ``ledger``: a ledger to append to;
    ``more``: other output files by option name (``write_model=Path(...)`` -> ``--write-model``).
    """
    from ..validation import check_ledger, check_output_path

    check_output_path(folder, option, folder=True)
    check_output_path(file, option)
    check_ledger(ledger)
    for name, path in more.items():
        check_output_path(path, "--" + name.replace("_", "-"))
