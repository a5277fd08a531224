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
import stat
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


def check_output_folder(path: str | os.PathLike, option: str) -> None:
    """
    Refuse an output folder that cannot be made or written in, naming ``option``.

    For a command that would otherwise find out only once its work is done: ``path`` (or
    the nearest folder above it that exists) must be a folder this process may write in.
    OutputWriteError in one line names what is in the way.
    """
    wanted = Path(path)
    existing = wanted
    while not os.path.lexists(existing) and existing.parent != existing:
        existing = existing.parent
    try:
        kind = file_kind(os.stat(existing).st_mode)
    except OSError as err:
        raise OutputWriteError(f'{option} {wanted}: {existing}: cannot use it '
                               f'({err.strerror or err})') from None
    if kind != 'a folder':
        raise OutputWriteError(f'{option} {wanted}: {existing} is {kind}, not a folder')
    if not os.access(existing, os.W_OK | os.X_OK):
        raise OutputWriteError(f'{option} {wanted}: cannot write in {existing} '
                               '(permission denied)')


class NotRegularFileError(UserError):
    """A path that is a FIFO, folder, socket or device where a file is to be read."""

    def __init__(self, path: str | os.PathLike, kind: str) -> None:
        """``kind``: what it is instead, as :func:`file_kind` says it ('a FIFO')."""
        super().__init__(f'{path}: {kind}, not a regular file')
        self.path, self.kind = path, kind


def file_kind(mode: int) -> str:
    """What a file of ``mode`` (``st_mode``) is, for a message: 'a regular file', 'a FIFO', ..."""
    for test, name in ((stat.S_ISREG, 'a regular file'), (stat.S_ISFIFO, 'a FIFO'),
                       (stat.S_ISDIR, 'a folder'), (stat.S_ISSOCK, 'a socket'),
                       (stat.S_ISCHR, 'a character device'), (stat.S_ISBLK, 'a block device')):
        if test(mode):
            return name
    return 'not a regular file'


def not_a_file(path: str | os.PathLike, what: str) -> str:
    """
    Why ``path``, found to be no regular file, cannot be read as ``what``, for a message.

    ``'<what> not found'`` when nothing is there; ``'a FIFO, not a regular file'`` (a folder,
    a socket, ...) when something else is: a file that is there is never said "not found".
    """
    try:
        kind = file_kind(os.stat(path).st_mode)
    except OSError:
        return f'{what} not found'
    return f'{what} not found' if kind == 'a regular file' else f'{kind}, not a regular file'


def read_regular_file(path: str | os.PathLike) -> bytes:
    """
    The bytes of ``path``, or NotRegularFileError when it is no regular file.

    Opened without blocking and checked on the open descriptor: a FIFO would block ``open``
    (and a reader of it) until a writer appears, also past SIGINT and SIGTERM held by the
    caller, and a check before opening could be raced. OSError as ``open`` raises it.
    """
    descriptor = os.open(path, os.O_RDONLY | getattr(os, 'O_NONBLOCK', 0))
    try:
        mode = os.fstat(descriptor).st_mode
        if not stat.S_ISREG(mode):
            raise NotRegularFileError(path, file_kind(mode))
        os.set_blocking(descriptor, True)
        with open(descriptor, 'rb', closefd=False) as stream:
            return stream.read()
    finally:
        os.close(descriptor)
