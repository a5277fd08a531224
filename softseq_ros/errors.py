"""
The one root of every error that a user's input causes.

A file, a field, a setting, an argument or a recording that cannot be used raises a subclass of
:class:`UserError` whose message is one line naming it and what is wrong. The ``softseq``
command prints those as one line and exits 2; any other exception is a bug and keeps its
traceback.
"""

from contextlib import contextmanager
import os
from pathlib import Path
from typing import Iterator


class UserError(ValueError):
    """Input that cannot be used; the message is one line that names the input and the fault."""


def one_line(text: str) -> str:
    """``text`` on one line: a library's message of several lines (YAML's) joined by spaces."""
    return ' '.join(part.strip() for part in text.splitlines() if part.strip())


class OutputWriteError(UserError):
    """An output file that cannot be written: full disk, read-only folder."""


@contextmanager
def writing(path: str | os.PathLike) -> Iterator[None]:
    """
    Turn a failed write of ``path`` into one line naming it (:class:`OutputWriteError`).

    Every file a report or a library writes goes through here (the figures too), so a full
    disk or a read-only folder stops the command with the file's name, not a traceback.
    """
    try:
        yield
    except OSError as err:
        raise OutputWriteError(f'{path}: cannot write ({err.strerror or err})') from None


def write_text(path: Path, text: str) -> None:
    """Write a text file, failing in one line that names it."""
    with writing(path):
        path.write_text(text)
