"""Warnings at most once per interval per kind, with a count of the ones held back."""

import time
from typing import Callable

WARNING_INTERVAL_S = 2.0


class Throttle:
    """
    Lets a warning of one ``key`` through at most every ``interval_s`` (wall time).

    A flood of the same refusal (a publisher sending garbage at 1 kHz) must not flood the log,
    but the count of what was held back is told with the next one that goes through.
    """

    def __init__(self, interval_s: float = WARNING_INTERVAL_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """Hold back repeats of a key for ``interval_s`` seconds of ``clock``."""
        self.interval_s = interval_s
        self._clock = clock
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def admit(self, key: str, text: str) -> str | None:
        """The text to log now (with the count held back since the last one), or None."""
        now = self._clock()
        last = self._last.get(key)
        if last is not None and now - last < self.interval_s:
            self._held[key] = self._held.get(key, 0) + 1
            return None
        held = self._held.pop(key, 0)
        self._last[key] = now
        return f'{text} ({held} similar warnings suppressed)' if held else text
