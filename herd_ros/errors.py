"""Errors a user can act on: bad input files, bad parameters, unusable data."""


class HerdInputError(ValueError):
    """Input that cannot be used, with one sentence saying which file/field and why.

    The command line prints it as a single line and exits non-zero; nodes log it and
    keep running.
    """
