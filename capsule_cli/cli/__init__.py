"""The typer front end: parse, validate, call one step, write, exit code.

Exit codes (contract section 5): 0 success; 2 bad input (one line on stderr
saying what and where); 1 internal error (traceback only with ``--debug``).
Each command group lives in its own module with a ``register(app)`` function.
"""
from __future__ import annotations

import sys
import traceback

import typer

from .. import __version__
from ..errors import InputError, PluginError

app = typer.Typer(
    name="capsule-cli",
    help="Study pipeline for self-propelled vibro-impact capsule robots: contact pressure, "
         "friction laws, non-smooth dynamics, and the model-versus-measurement loop. "
         "SI inside; table columns carry their unit as a suffix (speed_mm_s, friction_mN).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # plain help: "[mm/s]" is a unit, not rich markup; flags print as flags
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _version_callback(value: bool):
    if value:
        typer.echo(f"capsule-cli {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version_callback, is_eager=True,
                                 help="Print the version and exit."),
    debug: bool = typer.Option(False, "--debug", help="Show a traceback on internal errors."),
):
    """capsule-cli: vibro-impact capsule robot studies."""


def _register_all() -> None:
    from . import contact, dynamics, friction, loop  # noqa: F401  (each adds its commands)

    for mod in (contact, friction, dynamics, loop):
        mod.register(app)
    _plain_help(app)


def _given(value):
    """``value`` unless it is typer's placeholder for 'not given' (then None)."""
    from typer.models import DefaultPlaceholder

    return None if isinstance(value, DefaultPlaceholder) else value


def _list_metavars(callback) -> None:
    """Show a repeatable option's value as ``<path> ...`` rather than ``<list[Path]>``."""
    import inspect
    import typing

    from typer.models import OptionInfo

    if callback is None:
        return
    hints = typing.get_type_hints(callback)
    for name, par in inspect.signature(callback).parameters.items():
        opt = par.default
        if not isinstance(opt, OptionInfo) or opt.metavar is not None:
            continue
        ann = hints.get(name)
        if typing.get_origin(ann) is typing.Union:  # Optional[List[X]]
            ann = next(a for a in typing.get_args(ann) if a is not type(None))
        if typing.get_origin(ann) in (list, tuple) and typing.get_args(ann):
            inner = typing.get_args(ann)[0]
            opt.metavar = f"<{getattr(inner, '__name__', str(inner)).lower()}> ..."


def _plain_help(typer_app: typer.Typer) -> None:
    """Render every help page as plain text, and list commands by their whole first paragraph.

    Rich markup would eat lower-case units in square brackets (``[mm]``, ``[mm/s]``, ``[kPa]``)
    and print flags with a ``<bool>`` value; click's default list of commands cuts each summary
    at the terminal width with '...'. Both are fixed here for every group and command.
    """
    typer_app.rich_markup_mode = None
    for info in typer_app.registered_commands:
        text = info.help or (info.callback.__doc__ if info.callback else None) or ""
        if info.short_help is None and text.strip():
            info.short_help = " ".join(text.strip().split("\n\n")[0].split())
        _list_metavars(info.callback)
    for group in typer_app.registered_groups:
        sub = group.typer_instance
        if sub is None:
            continue
        text = _given(group.help) or _given(sub.info.help) or ""
        if text.strip() and _given(group.short_help) is None and _given(sub.info.short_help) is None:
            sub.info.short_help = " ".join(text.strip().split("\n\n")[0].split())
        _plain_help(sub)


_register_all()


def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns (and exits with) the contract's exit code (section 5).

    Usage errors are reported by typer with exit code 2; :class:`InputError`
    from a command, and an OSError on a path the user gave (permissions, a
    read-only or full disk), become one line on stderr and exit code 2; Ctrl-C
    (SIGINT) is exit code 130, SIGTERM 143 and SIGHUP 129, all raised as exceptions so
    that atomic writes remove their temporary files; anything else is a bug:
    exit code 1, traceback only with ``--debug``.

    Run as the program (``argv`` None), it exits through :func:`_exit_without_collecting`.
    """
    from .common import install_signal_handlers, restore_signal_handlers

    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    command = typer.main.get_command(app)
    previous = install_signal_handlers()
    try:
        code = _run(command, args, debug)
    finally:
        restore_signal_handlers(previous)
    if argv is None:
        _exit_without_collecting(code)
    return code


def _exit_without_collecting(code: int) -> None:
    """Exit with ``code``, first moving every object out of the garbage collector's reach (``gc.freeze``).

    At interpreter shutdown the collector otherwise walks every object the imports created (pandas, scipy,
    matplotlib: about 0.15 s of a short command's wall time, issue 13 item 5) only to free memory the
    operating system reclaims anyway. Shutdown itself is unchanged: ``atexit`` handlers, ``finally`` blocks
    and the flushing of stdout/stderr still run. The command's outputs are complete before this point
    (written atomically and closed), so nothing depends on a finaliser the skipped collection would run.
    """
    import gc

    gc.freeze()
    sys.exit(code)


def _run(command, args: list[str], debug: bool) -> int:
    """Run the click command and map every outcome to an exit code."""
    from ..validation import oserror_message
    from .common import Terminated

    try:
        command.main(args=args, prog_name="capsule-cli", standalone_mode=True)
        return 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        if code == 130:  # typer turns Ctrl-C into exit code 130
            typer.echo("capsule-cli: " + _SIGNAL_WORDS[130], err=True)
        return code
    except (InputError, PluginError) as exc:
        typer.echo(f"capsule-cli: error: {_one_line(exc)}", err=True)
        return 2
    except (KeyboardInterrupt, Terminated) as exc:
        code = _signal_code(exc)
        typer.echo("capsule-cli: " + _SIGNAL_WORDS[code], err=True)
        return code
    except Exception as exc:  # a bug, unless an OSError on a user's path or an interrupt a C extension wrapped
        signal_code = _wrapped_interrupt(exc)
        if signal_code:
            typer.echo("capsule-cli: " + _SIGNAL_WORDS[signal_code], err=True)
            return signal_code
        msg = oserror_message(exc) if isinstance(exc, OSError) else None
        if msg is not None and not debug:
            typer.echo(f"capsule-cli: error: {msg}", err=True)
            return 2
        if debug:
            traceback.print_exc()
        else:
            typer.echo(f"capsule-cli: internal error: {type(exc).__name__}: {exc} "
                       "(rerun with --debug for a traceback)", err=True)
        return 1


def _wrapped_interrupt(exc: BaseException) -> int:
    """Return 130 (Ctrl-C), 143 (SIGTERM) or 129 (SIGHUP) when ``exc`` was caused by the signal's exception, else 0.

    A handler that runs while compiled code returns its result surfaces as "returned a result with an
    exception set", a SystemError whose cause is the KeyboardInterrupt (the engine's calls hold the signals,
    :func:`capsule_cli.interrupts.deferred_signals`; this is the net for any other extension)."""
    seen = set()
    e = exc.__cause__ or exc.__context__
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        code = _signal_code(e)
        if code:
            return code
        e = e.__cause__ or e.__context__
    return 0


#: the one line (after "capsule-cli: ") of each signal's exit code
_SIGNAL_WORDS = {130: "interrupted", 143: "terminated", 129: "hung up"}


def _signal_code(exc: BaseException) -> int:
    """Return the exit code of the exception a signal raised (SIGINT 130, SIGHUP 129, SIGTERM 143), else 0."""
    from .common import HungUp, Terminated

    if isinstance(exc, KeyboardInterrupt):
        return 130
    if isinstance(exc, HungUp):
        return 129
    return 143 if isinstance(exc, Terminated) else 0


def _one_line(exc: Exception) -> str:
    """Return an exception's message on one line (the contract's 'one line on stderr')."""
    return " ".join(str(exc).split())
