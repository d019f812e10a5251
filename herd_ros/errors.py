"""Errors a user can act on: bad input files, bad parameters, unusable data."""


class HerdInputError(ValueError):
    """Input that cannot be used, with one sentence saying which file/field and why.

    The command line prints it as a single line and exits non-zero; nodes log it and
    keep running.
    """


class InputNote(UserWarning):
    """Something a reader did to the input that the user should know of (ids renamed,
    columns taken by another name); the command line prints it as one note line."""
