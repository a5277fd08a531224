"""Stop signals held until a point where what is written is whole."""

import os
import signal

import pytest

from softseq_ros.stopping import HeldSignals, TerminatedError


def _raise_marker(_signum, _frame):
    raise LookupError('the handler from before the block')


@pytest.fixture
def marked_handlers():
    previous = {s: signal.signal(s, _raise_marker) for s in (signal.SIGINT, signal.SIGTERM)}
    yield
    for signum, handler in previous.items():
        signal.signal(signum, handler)


@pytest.mark.parametrize('signum, raised', [(signal.SIGINT, KeyboardInterrupt),
                                            (signal.SIGTERM, TerminatedError)])
def test_a_signal_inside_acts_only_at_the_check(marked_handlers, signum, raised):
    steps = []
    with pytest.raises(raised):
        with HeldSignals() as held:
            os.kill(os.getpid(), signum)
            steps.append('went on')       # not torn where the signal arrived
            held.check()
            steps.append('past the check')
    assert steps == ['went on']
    with pytest.raises(LookupError):      # the handlers from before are back
        os.kill(os.getpid(), signum)


def test_a_signal_after_the_last_check_is_raised_on_leaving(marked_handlers):
    with pytest.raises(TerminatedError):
        with HeldSignals():
            os.kill(os.getpid(), signal.SIGTERM)
    with HeldSignals() as held:
        pass
    assert held.pending == []


def test_an_exception_on_its_way_is_not_replaced(marked_handlers):
    with pytest.raises(ZeroDivisionError):
        with HeldSignals():
            os.kill(os.getpid(), signal.SIGINT)
            raise ZeroDivisionError()
