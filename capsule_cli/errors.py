"""Exceptions that map to the exit codes of the contract (section 5)."""


class InputError(Exception):
    """Bad user input (usage, config, data, model file): exit code 2, one line.

    The message must say what is wrong and where, e.g.
    ``data.csv: column 'speed_mm_s' row 17: negative speed -0.4``.
    """

    exit_code = 2


class PluginError(InputError):
    """A user's plugin function failed by a fault of its own code (a KeyError for a parameter key, a TypeError,
    a NameError), not by an arithmetic failure at some parameter values: exit code 2, one line. The dynamics
    loop takes a run that fails for a parameter value as a region the model cannot run in (a large cost, the
    search goes elsewhere); this one it never swallows, so a plugin with a bug is reported, not silently lost
    as a candidate."""
