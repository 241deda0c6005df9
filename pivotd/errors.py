"""Project exceptions.

Errors a user can cause (a bad file, config key, message or command-line value) raise
:class:`PivotdError` with a one-line message that names the file, key, line or topic.
The CLI prints the message and exits 2, without a traceback.
"""


class PivotdError(Exception):
    """A user-caused error with a one-line, self-explanatory message."""

    def __init__(self, message: str) -> None:
        super().__init__(" ".join(str(message).split()))


class InputError(PivotdError):
    """A bad input file or value (map, path, CSV, command-line option)."""


class ConfigError(PivotdError):
    """A bad configuration file or key."""
