"""
Numbers as a person reads them in a summary, a report or a figure's title (the files stay SI).

A snap-through lasts milliseconds in a fast rig and minutes behind a narrow channel: a
duration is shown in the unit that keeps it short. An energy that is zero up to round-off is
shown as zero, never as -0.0000.
"""

import math


def duration_text(seconds: float | None) -> str:
    """``12.3 ms``, ``4.56 s``, ``51.0 min``; ``-`` for none or a value that is no number."""
    if seconds is None or not math.isfinite(seconds):
        return '-'
    magnitude = abs(seconds)
    if magnitude < 1.0:
        shown, unit = seconds * 1e3, 'ms'
    elif magnitude < 120.0:
        shown, unit = seconds, 's'
    elif magnitude < 7200.0:
        shown, unit = seconds / 60.0, 'min'
    else:
        shown, unit = seconds / 3600.0, 'h'
    return f'{shown:.3g} {unit}' if abs(shown) < 100 else f'{shown:.0f} {unit}'


def millijoules_text(joules: float, decimals: int = 4) -> str:
    """An energy in mJ to ``decimals`` places; what rounds to zero shows as 0, unsigned."""
    shown = round(joules * 1e3, decimals)
    return f'{shown + 0.0 if shown != 0 else 0.0:.{decimals}f} mJ'
