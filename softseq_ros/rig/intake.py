"""
The actuator's commands under overload: answer the newest, count and report what was skipped.

A pump can command faster than an actuator node answers (a pump at 10 kHz, a publisher that
floods the topic, a node process stalled on a loaded machine). Answering every command in
order would then leave the actuator ever further behind until its queue overflows and DDS
drops commands without a word. The contract instead (docs/faults.md, Load):

- While the actuator keeps up, it answers every command, in order. A stall that leaves fewer
  than :data:`BACKLOG_COMMANDS` commands waiting behind the one it takes is caught up answer
  by answer, so a loaded machine's hiccups cost no answer.
- Once more are waiting, it is behind: it takes each waiting command without answering it
  (a few microseconds), keeps the newest, and answers that one every :data:`FLUSH_PERIOD_S`
  until it has caught up. The model walks through every volume it skipped (the jump rule), so
  the state it answers is the one an answer to every command would have reached.
- Every command it does not answer is counted: those it passed over for a newer one, and those
  its queue dropped before it could take them (gaps in the publisher's sequence numbers, where
  the middleware gives them and one pump publishes). :meth:`CommandIntake.report` says so in
  the log at most once per call (the node calls it every second), with the totals.

How far behind it is comes from what DDS says of each message (when it arrived) and the
pump's own pace (its sequence numbers over those arrival times): the age of the command taken
times the pump's rate is the number of commands that arrived after it. Nothing here knows ROS:
the node passes those numbers in.
"""

from dataclasses import dataclass
from typing import Any

from softseq_ros.wire import contract
from softseq_ros.wire.values import INFO, WARNING, Notice

# Commands waiting behind the one taken before the actuator counts as behind: a tenth of its
# queue (contract.PUMP_COMMAND's depth), 1 s of a 100 Hz pump, 10 ms of one at 10 kHz.
BACKLOG_COMMANDS = contract.PUMP_COMMAND.qos.depth // 10
# How often a behind actuator answers the newest command it has taken.
FLUSH_PERIOD_S = 0.02
# Weight of the newest interval in the pump's pace (an exponential mean over ~20 commands).
PACE_WEIGHT = 0.05


@dataclass
class Skipped:
    """Commands not answered: passed over for a newer one, or dropped before they were taken."""

    passed_over: int = 0
    dropped: int = 0

    @property
    def total(self) -> int:
        """Every command not answered."""
        return self.passed_over + self.dropped


class CommandIntake:
    """
    Decides, command by command, whether the actuator answers now or only keeps the newest.

    :meth:`take` is given each command as it is taken from the queue, with its publisher's
    sequence number and its arrival time (None where the middleware gives none: then every
    command is answered, as before); it returns the command to answer now, or None when the
    command waits as :attr:`pending` for :meth:`flush`.
    """

    def __init__(self, backlog_commands: int = BACKLOG_COMMANDS) -> None:
        """No command taken yet."""
        self.backlog_commands = backlog_commands
        self.pending: Any = None
        self.taken = 0
        self.answered = 0
        self.skipped = Skipped()
        self.behind = False
        self.one_publisher = True   # the node says when another pump publishes too
        self._last_sequence: int | None = None
        self._last_arrival: int | None = None
        self._interval_ns: float | None = None   # the pump's pace: ns between two commands
        self._reported = Skipped()
        self._reported_taken = 0
        self._reported_behind = False   # the last report said 'still behind'

    def take(self, command: Any, sequence: int | None, arrival_ns: int | None,
             now_ns: int) -> Any:
        """The command to answer now (``command``, or None: it waits for :meth:`flush`)."""
        self.taken += 1
        steps = self._count_sequence(sequence)
        behind = False
        if arrival_ns:
            last, self._last_arrival = self._last_arrival, arrival_ns
            if last is not None and steps and arrival_ns >= last:
                interval = (arrival_ns - last) / steps
                pace = self._interval_ns
                self._interval_ns = interval if pace is None else \
                    pace + PACE_WEIGHT * (interval - pace)
            pace = self._interval_ns
            # A pace of 0 (a burst that arrived at once) is as fast as it gets.
            waiting = (now_ns - arrival_ns) / max(pace, 1.0) if pace is not None else 0.0
            behind = waiting > self.backlog_commands
        self.behind = behind
        if self.pending is not None:
            # Whether answered now or kept, this command is newer than the one waiting.
            self.skipped.passed_over += 1
            self.pending = None
        if behind:
            self.pending = command
            return None
        self.answered += 1
        return command

    def refused(self, sequence: int | None) -> None:
        """A command that could not be read (refused by the node): its place in the sequence."""
        self._count_sequence(sequence)

    def flush(self) -> Any:
        """The newest command taken and not answered yet (None: none), now answered."""
        command, self.pending = self.pending, None
        if command is not None:
            self.answered += 1
        return command

    def _count_sequence(self, sequence: int | None) -> int:
        """Steps of the publisher's sequence since the last command (gaps counted dropped)."""
        if sequence is None or sequence <= 0:
            return 1
        last, self._last_sequence = self._last_sequence, sequence
        if last is None or sequence <= last:
            # The first command, or a new publisher (a restarted pump numbers from 1 again).
            return 1
        steps = sequence - last
        if steps > 1 and self.one_publisher:
            self.skipped.dropped += steps - 1
        return steps

    def report(self, role: str = contract.ACTUATOR) -> list[Notice]:
        """
        A warning when commands were skipped since the last report, with the totals.

        Once more when the last one said 'still behind' and the waiting command is answered
        now, so that the last report's totals account for every command.
        """
        skipped, before = self.skipped, self._reported
        new_passed = skipped.passed_over - before.passed_over
        new_dropped = skipped.dropped - before.dropped
        if not new_passed and not new_dropped and not (self._reported_behind
                                                       and self.pending is None):
            return []
        taken = self.taken - self._reported_taken
        self._reported = Skipped(skipped.passed_over, skipped.dropped)
        self._reported_taken = self.taken
        self._reported_behind = self.pending is not None
        state = 'still behind' if self.pending is not None else 'caught up'
        return [Notice(role, WARNING,
                       f'commands come faster than the actuator answers: '
                       f'{new_passed + new_dropped} skipped since the last report '
                       f'({new_passed} passed over for a newer one, {new_dropped} dropped by '
                       f'the queue; {taken} taken); {skipped.total} skipped and '
                       f'{self.answered} answered in all; it answers the newest (its state '
                       f'walks through every skipped volume); {state}')]

    def summary(self, role: str = contract.ACTUATOR) -> list[Notice]:
        """At the end: how many commands were answered and skipped, when any were skipped."""
        skipped = self.skipped
        if not skipped.total:
            return []
        return [Notice(role, INFO,
                       f'answered {self.answered} commands; skipped {skipped.total} '
                       f'({skipped.passed_over} passed over for a newer one, {skipped.dropped} '
                       'dropped by the queue)')]
