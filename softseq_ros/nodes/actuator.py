"""
Actuator node: the actuator core (softseq_ros.rig.actuator) behind ROS topics.

Each ``pump/command`` goes to the actuator's model (softseq_ros.rig.model: the quasi-static
equilibrium at the commanded injected volume); a model that moves between commands is
advanced on a timer at its rate. The node publishes the outputs the ``outputs`` parameter
lists (default: the scene's): ``actuator/pressure`` (absolute: gauge +
``ambient_pressure_pa``), ``actuator/volumes`` (position = volumes, effort = gauge pressure),
``actuator/curvatures`` and one JSON object per snap-through (in time: per exchange of fluid
between the segments) on ``actuator/events``, each
stamped with the command it answers; once at start, latched, ``actuator/scene``: which scene's
segments it runs (name and digest); and once it knows it starts at rest and no command came
yet, its rest state, so a controller or camera that starts first sees it.

Commands faster than it answers (softseq_ros.rig.intake): while it keeps up it answers every
``pump/command`` in order; once far behind it takes the waiting ones without answering, answers
the newest every 20 ms, counts what it skipped (passed over, or dropped by its queue) and says
so in its log at most once a second.

Resume: on start the node waits up to ``resume_timeout_s`` for a latched ``actuator/volumes``
from a live publisher and resumes on the branch nearest the newest of those it hears; without
one it reads ``state_file`` (the core writes it at most ten times a second, and the last state
at a clean stop; by default
``$ROS_HOME/softseq/<namespace>/actuator.json``, ``$ROS_HOME`` being ``~/.ros`` unless set).
Only an abnormal end is resumed: destroying the node (a handled SIGINT or SIGTERM) marks the
file closed, and the next start is at rest without a word; an actuator killed with ``kill -9``
or crashed comes back on its branch, with a warning naming the file, the volume and how to
start at rest. With no file, a closed one, or ``state_file`` empty, it starts at rest. Commands
that arrive while waiting are answered in order afterwards.

An actuator that hears more than one publisher on its command topic (two pumps, or two rigs
in one namespace) warns once, naming them.
"""

import os
from pathlib import Path
import time
from typing import Any, Callable

import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.node import Parameter

from softseq_ros.nodes.core_node import CoreNode, log_to, message_class, qos_profile
from softseq_ros.nodes.diagnostics import Health
from softseq_ros.nodes.parameters import outputs_reason
from softseq_ros.nodes.runner import run_node
from softseq_ros.rig.actuator import STATE_SAVE_PERIOD_S
from softseq_ros.rig.build import actuator_core
from softseq_ros.rig.intake import FLUSH_PERIOD_S, CommandIntake
from softseq_ros.wire import contract
from softseq_ros.wire.payloads import InputError, segment_volumes
from softseq_ros.wire.values import WARNING, Notice, SegmentVolumes

RESUME_POLL_S = 0.02
# A live publisher's latched volumes come as its history, oldest first: the resume takes the
# newest heard until none came for this long.
RESUME_SETTLE_S = 0.1
PUBLISHER_CHECK_S = 1.0


class ActuatorNode(CoreNode):
    """Tracks the equilibrium of the scene's segments under the commanded injected volume."""

    NODE_NAME = contract.NODE_NAMES[contract.ACTUATOR]

    DIAGNOSTIC_TASK = 'actuator'

    def health(self) -> Health:
        """For /diagnostics: commands refused (garbage or beyond the tables) and the state."""
        base = super().health()
        intake = self.intake
        values: dict[str, object] = {
            'refused_commands': self.core.rejected_commands + self.refusals,
            # Under overload (softseq_ros.rig.intake): what it skipped, and why.
            'answered_commands': intake.answered,
            'skipped_commands': intake.skipped.total + self.core.skipped_while_waiting,
            'skipped_passed_over': intake.skipped.passed_over,
            'skipped_dropped_by_queue': intake.skipped.dropped,
            'behind_its_commands': intake.pending is not None}
        # What was last published, not the model asked anew: a dynamic model's state is
        # computed as it integrates, and a look from outside must not take part in that.
        state = self.last_published.get(SegmentVolumes)
        if state is not None:
            values['gauge_pressure_pa'] = state.gauge_pa
            values['segment_volumes_m3'] = ' '.join(f'{v:.9g}' for v in state.volumes_m3)
        base.values = {**values, **base.values}
        return base

    def __init__(self, **kwargs: Any) -> None:
        """Declare parameters, assemble the equilibrium map and start (or resume)."""
        super().__init__(self.NODE_NAME, **kwargs)
        scene = self.declare_scene()
        outputs = self.declare_texts(
            'outputs', sorted(scene.outputs), 'Outputs to publish (scene output names); the '
            'actuator serves pressure, volumes, curvature and events.', read_only=True,
            check=outputs_reason)
        ambient = self.declare_number(
            'ambient_pressure_pa', contract.DEFAULT_AMBIENT_PRESSURE_PA,
            'Added to the gauge pressure on actuator/pressure [Pa].', minimum=0.0)
        self.resume_timeout_s = self.declare_number(
            'resume_timeout_s', 1.0, 'How long to wait at start for the last actuator/volumes '
            'to resume from [s]; 0 starts fresh at once.', minimum=0.0, maximum=60.0,
            read_only=True)
        state_file = self.declare_text(
            'state_file', str(default_state_file(self.get_namespace(), self.get_name())),
            'File the state is written to when it changes (at most ten times a second, and at a '
            'clean stop) and resumed from when no '
            'actuator/volumes arrives at start and the last run did not stop cleanly (a clean '
            'stop marks it closed; default: in $ROS_HOME/softseq, one per node name and '
            'namespace); empty: off, every start at rest.', read_only=True)
        self.core = actuator_core(scene, outputs=frozenset(outputs),
                                  ambient_pressure_pa=ambient, state_file=state_file or None)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.intake = CommandIntake()
        # Armed while a command waits to be answered (the actuator is behind).
        self._flush_timer = self.create_timer(FLUSH_PERIOD_S, self._flush_command, clock=steady,
                                              autostart=False)
        self._flush_armed = False
        if self.core.state_file is not None:
            self.create_timer(STATE_SAVE_PERIOD_S, self._flush_state, clock=steady)
        # The core's own outputs: those its model can give (no flows without channels).
        self.connect(self.core.outputs)
        self.send(self.core.begin(self.now_ns()))  # the scene it runs, latched
        self._warned_publishers: frozenset[str] = frozenset()
        command = self.subscription(contract.PUMP_COMMAND)
        if command is not None:
            self.create_timer(PUBLISHER_CHECK_S, self._check_publishers, clock=steady)
        if self.core.rate_hz is not None:
            # A model whose state moves between commands is advanced on the ROS clock.
            self.create_timer(1.0 / self.core.rate_hz, self._advance)
        self._begin_resume()
        self.configured = True
        model = ('a fluid network in time' if self.core.rate_hz is not None
                 else 'quasi-static')
        self.get_logger().info(
            f'ready: scene {scene.name} ({", ".join(scene.segment_names)}), {model}, '
            f'publishing {", ".join(sorted(self.core.outputs))}')

    def _advance(self) -> None:
        self.send(self.core.tick(self.now_ns()))

    # ---------------------------------------------------------------- commands

    def receiver(self, topic: contract.Topic, decode: Callable[[Any], Any]) -> Callable:
        """Commands go through the intake (with what DDS says of them); others as usual."""
        if topic is not contract.PUMP_COMMAND:
            return super().receiver(topic, decode)
        intake = self.intake

        def on_command(msg: Any, info: Any) -> None:
            sequence = info.get('publication_sequence_number')
            try:
                value = decode(msg)
            except InputError as err:
                intake.refused(sequence)
                self.send(self.refused(err))
                return
            command = intake.take(value, sequence, info.get('received_timestamp'),
                                  time.time_ns())
            if command is not None:
                self.send(self.core.handle(command, self.now_ns()))
            elif not self._flush_armed:
                self._flush_armed = True
                self._flush_timer.reset()
        return on_command

    def _flush_command(self) -> None:
        command = self.intake.flush()
        if command is None:
            self._flush_timer.cancel()
            self._flush_armed = False
            return
        self.send(self.core.handle(command, self.now_ns()))

    def _flush_state(self) -> None:
        self.send(self.core.flush_state())

    @property
    def resuming(self) -> bool:
        """True while the node waits for a previous state at start."""
        return self.core.waiting

    # ---------------------------------------------------------------- resume

    def _begin_resume(self) -> None:
        """Listen for the last actuator/volumes for resume_timeout_s (wall time)."""
        self.core.begin_wait()
        self._resume_deadline = time.monotonic() + self.resume_timeout_s
        self._resume_heard: Any = None
        self._resume_settle = 0.0
        topic = contract.VOLUMES
        self._resume_subscription = self.create_subscription(
            message_class(topic.type_name), topic.name, self._on_resume_volumes,
            qos_profile(topic.reader_qos))
        # Wall clock: with use_sim_time the ROS clock may not move until /clock arrives.
        self._resume_timer = self.create_timer(
            RESUME_POLL_S, self._resume_poll, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _on_resume_volumes(self, msg: Any) -> None:
        if not self.core.waiting:
            return
        # The publisher sends what it keeps, oldest first; the newest is the state to take.
        value, heard = segment_volumes(msg), self._resume_heard
        if heard is None or value.stamp_ns >= heard.stamp_ns:
            self._resume_heard = value
        self._resume_settle = time.monotonic() + RESUME_SETTLE_S

    def _resume_from_heard(self) -> bool:
        value, self._resume_heard = self._resume_heard, None
        source = f'the last {self._resume_subscription.topic_name}'
        resumed, notices = self.core.resume_from(list(value.names), value.volumes_m3, source)
        self.send(notices)
        return resumed

    def _resume_poll(self) -> None:
        if not self.core.waiting:
            return
        now = time.monotonic()
        if self._resume_heard is not None and now >= self._resume_settle:
            if self._resume_from_heard():
                self._end_resume(resumed=True)
                return
        if now >= self._resume_deadline:
            # Starting at rest is the normal case and says nothing; a resume warns itself.
            resumed, notices = self.core.resume_from_file()
            self.send(notices)
            self._end_resume(resumed)

    def _end_resume(self, resumed: bool) -> None:
        self.destroy_timer(self._resume_timer)
        # Destroyed before the first publication, so the node never hears itself.
        self.destroy_subscription(self._resume_subscription)
        now = self.now_ns()
        answers = self.core.end_wait(now)
        if not resumed and not any(type(value) is not Notice for value in answers):
            # At rest and no command came while waiting: the rest state is said once,
            # latched, for a controller or camera that starts first.
            answers += self.core.announce(now)
        self.send(answers)

    def destroy_node(self) -> None:
        """
        Answer the newest command taken, mark the state file closed, then destroy.

        A clean stop: the state file holds the last state, closed, so the next start is at
        rest. What it says is logged once the node is gone: after a Ctrl-C the context is
        shut down, and the node's logger would fail to publish the lines on /rosout.
        """
        notices: list[Notice] = []
        core = getattr(self, 'core', None)
        intake = getattr(self, 'intake', None)
        if core is not None and intake is not None:
            pending = intake.flush()
            if pending is not None and not core.waiting:
                outputs = core.handle(pending, self.now_ns())
                if self.context.ok():
                    self.send([value for value in outputs if type(value) is not Notice])
                notices += [value for value in outputs if type(value) is Notice]
            notices += intake.report() + intake.summary()
        if core is not None:
            notices += core.close()
        logger_name = self.get_logger().name
        super().destroy_node()
        for notice in notices:
            log_to(rclpy.logging.get_logger(logger_name), notice.level, notice.text)

    # ---------------------------------------------------------------- graph

    def _check_publishers(self) -> None:
        subscription = self.subscription(contract.PUMP_COMMAND)
        infos = self.get_publishers_info_by_topic(subscription.topic_name)
        names = frozenset(
            f'{info.node_namespace.rstrip("/")}/{info.node_name}' for info in infos)
        # Two publishers' sequence numbers interleave: no gap means a dropped command then.
        self.intake.one_publisher = len(infos) <= 1
        self.send(self.intake.report())
        if len(names) > 1 and names != self._warned_publishers:
            self._warned_publishers = names
            self.log(WARNING, f'{subscription.topic_name} has {len(names)} publishers '
                                f'({", ".join(sorted(names))}): their commands interleave; '
                                'give each rig its own namespace (-r __ns:=/rig2)')

    def _parameters_changed(self, parameters: list[Parameter]) -> None:
        for parameter in parameters:
            if parameter.name == 'ambient_pressure_pa':
                self.core.set_ambient_pressure(float(parameter.value))


def default_state_file(namespace: str, node_name: str) -> Path:
    """``$ROS_HOME/softseq/<namespace>/<node name>.json``; ROS_HOME defaults to ``~/.ros``."""
    home = os.environ.get('ROS_HOME')
    root = Path(home).expanduser() if home else Path.home() / '.ros'
    return root.joinpath('softseq', *[part for part in namespace.split('/') if part],
                         f'{node_name}.json')


def main(args: list[str] | None = None) -> None:
    """Run the actuator node."""
    run_node(ActuatorNode, args)


if __name__ == '__main__':
    main()
