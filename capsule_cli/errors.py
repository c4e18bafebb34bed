"""Exceptions that map to the exit codes of the contract (section 5)."""


class InputError(Exception):
    """Bad user input (usage, config, data, model file): exit code 2, one line.

    The message must say what is wrong and where, e.g.
    ``data.csv: column 'speed_mm_s' row 17: negative speed -0.4``.
    """

    exit_code = 2
