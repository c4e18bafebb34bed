"""Exceptions that map to the exit codes of the contract (section 5)."""


class InputError(Exception):
    """Bad user input (usage, config, data, model file): exit code 2, one line.

    The message must say what is wrong and where, e.g.
    ``data.csv: column 'speed_mm_s' row 17: negative speed -0.4``.
    """

    exit_code = 2


class PluginError(Exception):
    """A user's plugin function failed by a fault of its own code (a KeyError for a parameter key, a TypeError,
    a NameError), not by an arithmetic failure at some parameter values: exit code 2, one line, as an
    :class:`InputError`. Not a subclass of it on purpose: the dynamics loop takes an InputError during a run as
    a region of the parameters the model cannot run in (a large cost, the search goes elsewhere) and must never
    swallow this one, so that a plugin with a bug is reported, not silently lost as a candidate."""

    exit_code = 2
