"""Errors raised for bad user input: the CLI prints them as one line, never a traceback."""


class InputError(ValueError):
    """Bad or missing user input. The message names the file and the problem."""
