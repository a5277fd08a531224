"""
Progress lines of long commands: a batch run, a FEM table.

Rewritten in place on a terminal; one plain line each in a log file or a pipe, where carriage
returns would leave one endless line.
"""

from typing import TextIO


def is_terminal(stream: TextIO | None) -> bool:
    """Whether ``stream`` is an interactive terminal."""
    return bool(stream is not None and getattr(stream, 'isatty', lambda: False)())


def write_progress(stream: TextIO | None, text: str) -> None:
    """Show ``text`` as the current progress line of ``stream`` (nothing when None)."""
    if stream is None:
        return
    stream.write('\r' + text if is_terminal(stream) else text + '\n')
    stream.flush()


def end_progress(stream: TextIO | None) -> None:
    """End a terminal's rewritten progress line, so that what follows starts on its own."""
    if is_terminal(stream):
        stream.write('\n')
        stream.flush()
