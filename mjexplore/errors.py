"""Errors raised for bad user input.

Library code raises :class:`UserInputError` for anything a user can fix (a bad argument, a
malformed file); the CLI turns it into a one-paragraph message and exit code 2.
"""


class UserInputError(ValueError):
    """Bad input from a user, with a message that says what was wrong and how to fix it."""
