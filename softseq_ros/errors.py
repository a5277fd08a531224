"""
The one root of every error that a user's input causes.

A file, a field, a setting, an argument or a recording that cannot be used raises a subclass of
:class:`UserError` whose message is one line naming it and what is wrong. The ``softseq``
command prints those as one line and exits 2; any other exception is a bug and keeps its
traceback.
"""


class UserError(ValueError):
    """Input that cannot be used; the message is one line that names the input and the fault."""
