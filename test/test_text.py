"""Numbers as a person reads them: durations in the unit that keeps them short, energies."""

import math

import pytest

from softseq_ros.analysis.text import duration_text, millijoules_text


@pytest.mark.parametrize('seconds, text', [
    (0.0123, '12.3 ms'), (0.51, '510 ms'), (51.035, '51 s'), (3061.0, '51 min'),
    (51035.0, '14.2 h'), (None, '-'), (math.nan, '-'), (math.inf, '-'),
])
def test_a_duration_is_shown_in_the_unit_that_keeps_it_short(seconds, text):
    # A snap-through behind a narrow channel took 51 s: it read "51035 ms" and "5.104e+04 ms".
    assert duration_text(seconds) == text


@pytest.mark.parametrize('joules, text', [
    (-1e-9, '0.0000 mJ'), (-0.0, '0.0000 mJ'), (2.5e-3, '2.5000 mJ'), (-2.5e-3, '-2.5000 mJ'),
    (1.23456e-4, '0.1235 mJ'),
])
def test_an_energy_that_rounds_to_zero_shows_no_sign(joules, text):
    # The demo printed "hysteresis area: -0.0000 mJ" for a round-off of -1e-9 J.
    assert millijoules_text(joules) == text
