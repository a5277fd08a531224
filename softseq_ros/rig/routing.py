"""
Routing between cores that live in one process, by the contract's consumers.

The batch runner and the one-process ``rig`` executable hand a core's outputs straight to the
cores that consume their topics, in the order they were produced, as rclcpp's intra-process
communication would: a pump command reaches the actuator, and its state the camera, within the
pump's own tick. The router only hands values over and returns everything produced; what to do
with it (publish it, record it, log a notice) is the driver's business.
"""

from typing import Any, Callable, Mapping

from softseq_ros.wire.values import TOPIC_VALUE_TYPES, Output


class Router:
    """Delivers outputs to the consuming cores among ``cores`` (by role)."""

    def __init__(self, cores: Mapping[str, Any], clock: Callable[[], int]) -> None:
        """``clock()`` gives the time (ns) a consuming core is handed a value at."""
        self.cores = dict(cores)
        self._clock = clock
        # Value type -> the cores of this process whose handle takes it.
        self._consumers: dict[type, tuple[Any, ...]] = {}
        for kind in TOPIC_VALUE_TYPES:
            consumers = tuple(self.cores[role] for role in kind.topic.consumers
                              if role in self.cores)
            if consumers:
                self._consumers[kind] = consumers

    def run(self, outputs: list[Output]) -> list[Output]:
        """
        ``outputs`` and everything their consumers produce, in the order produced.

        Values are handed over first in, first out: all consumers of one value before the
        next value's, and what a handler produces after what was already waiting. The list
        ``outputs`` itself is extended and returned.
        """
        consumers_of = self._consumers.get
        clock = self._clock
        produced = outputs
        index = 0
        while index < len(produced):
            consumers = consumers_of(type(produced[index]))
            if consumers is not None:
                value = produced[index]
                for core in consumers:
                    produced.extend(core.handle(value, clock()))
            index += 1
        return produced
