"""
Stopping a job by a signal without tearing what it writes.

Python raises KeyboardInterrupt (or, with :func:`raise_terminated` as the SIGTERM handler,
TerminatedError) between any two bytecodes, also in the middle of a chunk being written to a
bag file: the file then holds a torn record that its summary, written on close, does not
mend. A job that writes in a loop holds the signals with :class:`HeldSignals` and lets them
act only at a point where everything written is whole.
"""

import os
import signal
import threading
from types import FrameType, TracebackType

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class TerminatedError(BaseException):
    """
    SIGTERM arrived: unwind like an interrupt, so that open bags are closed completely.

    A BaseException, as KeyboardInterrupt is: the ``except Exception`` of a reader that takes
    any failure for damaged data (``softseq recover``'s read-back, its scan of chunks) must
    not take a stop for a fault of the bag.
    """


_MAIN_PID = os.getpid()


def raise_terminated(signum: int, _frame: FrameType | None) -> None:
    """SIGTERM handler of the ``softseq`` command: raise TerminatedError in its process."""
    if os.getpid() != _MAIN_PID:
        # A forked worker (the report's figure pool) ends as SIGTERM ends any process.
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
        return
    raise TerminatedError()


def stop_exception(signum: int) -> BaseException:
    """What a stop signal raises: KeyboardInterrupt for SIGINT, TerminatedError otherwise."""
    return KeyboardInterrupt() if signum == signal.SIGINT else TerminatedError()


class HeldSignals:
    """
    Hold SIGINT and SIGTERM while inside; :meth:`check` raises at a point of the caller's choice.

    ``pending`` is a list, empty until a stop signal arrives, so that a hot loop tests it with
    one truth test. A signal that arrives after the last check (while a bag is being closed,
    say) is raised when the block is left, unless an exception is already on its way. Outside
    the main thread signals cannot be handled, and the block holds nothing.
    """

    def __init__(self) -> None:
        self.pending: list[int] = []
        self._previous: dict[int, object] = {}

    def _hold(self, signum: int, _frame: FrameType | None) -> None:
        self.pending.append(signum)

    def check(self) -> None:
        """Raise the exception of the first stop signal held, if any."""
        if self.pending:
            raise stop_exception(self.pending[0])

    def __enter__(self) -> 'HeldSignals':
        if threading.current_thread() is threading.main_thread():
            for signum in STOP_SIGNALS:
                # A handler installed from C (rclpy's) could not be put back: leave it be.
                if signal.getsignal(signum) is not None:
                    self._previous[signum] = signal.signal(signum, self._hold)
        return self

    def __exit__(self, kind: type[BaseException] | None, _value: BaseException | None,
                 _traceback: TracebackType | None) -> None:
        for signum, previous in self._previous.items():
            signal.signal(signum, previous)  # type: ignore[arg-type]
        self._previous.clear()
        if kind is None:
            self.check()
