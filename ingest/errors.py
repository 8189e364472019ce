"""The single error family for bad user input.

Every problem with a file a user hands us (wrong format, truncated, missing topic or column, absurd values) is
raised as an :class:`InputError` whose message names the file, the topic or column, and what was expected.
The CLI and the dashboard catch exactly this family and show the message; anything else is a bug.
"""

from __future__ import annotations


class InputError(ValueError):
    """A user-supplied file or value cannot be used.

    Parameters
    ----------
    message : str
        What is wrong and what was expected.
    source : str, optional
        The file (or upload name) the problem is in; prefixed to the message.
    field : str, optional
        The topic, column or key concerned; prefixed to the message after the source.
    """

    def __init__(self, message: str, *, source: str | None = None, field: str | None = None):
        self.source = source
        self.field = field
        self.detail = message
        where = ": ".join(part for part in (source, field) if part)
        super().__init__(f"{where}: {message}" if where else message)


class FileTooLargeError(InputError):
    """The file exceeds the configured size limit."""
