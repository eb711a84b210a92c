"""Errors the command line reports as one clear line (see `simplenerf.cli.main`), instead of a traceback."""


class SimpleNeRFError(Exception):
    """Base class: bad input or setup the user can fix; the message says what and where."""


class DataError(SimpleNeRFError, ValueError):
    """A scene on disk is missing, incomplete or inconsistent, or a split cannot be made from it."""
