"""
One short-lived ROS participant for a ``softseq ros`` command: names, deadline, graph waits.

A command that finds nothing must not hang: every wait shares one deadline (``--timeout``), and
what was not found is said in one line with where else it is (a service of that name in
another namespace), since a namespace left out is the usual reason.
"""

import math
import os
import time
from typing import Any, Callable, Sequence

from softseq_ros.errors import UserError

# Long enough for DDS discovery on a loaded machine, short enough that a wrong name is told
# at once; --timeout changes it.
DEFAULT_TIMEOUT_S = 5.0
# How often a wait looks at the graph again.
GRAPH_POLL_S = 0.05


class RosToolError(UserError):
    """A name, value or option that cannot be used, or what it names was not found in time."""


# The longest a command waits for a node, a service or a message [s]: an hour is beyond any
# rig's start-up, and a wait longer than that is a typing slip, not a plan.
MAX_TIMEOUT_S = 3600.0


def timeout_seconds(text: str) -> float:
    """``--timeout``: seconds > 0, at most MAX_TIMEOUT_S (an argparse type, one-line refusal)."""
    from argparse import ArgumentTypeError

    try:
        seconds = float(text)
    except ValueError:
        raise ArgumentTypeError(f'{text!r} is not a number of seconds') from None
    if not (math.isfinite(seconds) and 0.0 < seconds <= MAX_TIMEOUT_S):
        raise ArgumentTypeError(f'must be a number of seconds > 0 and at most '
                                f'{MAX_TIMEOUT_S:g}, got {text}')
    return seconds


def seconds_text(seconds: float) -> str:
    """``5 s``, ``0.5 s``: a timeout as the messages say it."""
    return f'{seconds:g} s'


def _first_line(err: Exception) -> str:
    """The reason rclpy gives for an invalid name: its first line, no colon at the end."""
    return ' '.join(str(err).split('\n')[0].split()).rstrip(':')


def check_name(name: str, what: str) -> str:
    """
    Refuse a name no ROS graph can hold before any participant starts, in one line.

    ``what`` says which argument it is (``SERVICE``, ``NODE``, ``TOPIC``). A ``~`` name is
    refused too: it would name this command's own node.
    """
    from rclpy.exceptions import InvalidTopicNameException
    from rclpy.validate_topic_name import validate_topic_name

    if name.startswith('~'):
        raise RosToolError(f'{what} {name}: a ~ name means the node of this command itself; '
                           'give the absolute name, e.g. /syringe_pump/start')
    try:
        validate_topic_name(name)
    except InvalidTopicNameException as err:
        raise RosToolError(f'{what} {name!r}: not a valid ROS name ({_first_line(err)})') \
            from None
    return name


def check_namespace(namespace: str) -> str:
    """``--namespace``: absolute, as ROS wants it (``rig2`` is taken as ``/rig2``)."""
    from rclpy.exceptions import InvalidNamespaceException
    from rclpy.validate_namespace import validate_namespace

    absolute = namespace if namespace.startswith('/') else '/' + namespace
    absolute = absolute.rstrip('/') or '/'
    try:
        validate_namespace(absolute)
    except InvalidNamespaceException as err:
        raise RosToolError(f'--namespace {namespace!r}: not a valid namespace '
                           f'({_first_line(err)})') from None
    return absolute


class Session:
    """
    A context, one hidden node and an executor, for one command; closed by ``with``.

    The node sits in ``namespace``, so relative names resolve there as ROS resolves them
    (``--ros-args -r __ns:=/rig2`` has the same effect). It is hidden (its name starts with
    ``_``), as the ``ros2`` command's own node is, so it does not show among the rig's nodes.
    The context is this command's own: rclpy installs no signal handlers for it, and Ctrl-C
    stays a KeyboardInterrupt between two turns of the executor.
    """

    def __init__(self, namespace: str = '/', timeout_s: float = DEFAULT_TIMEOUT_S,
                 ros_args: Sequence[str] = ()) -> None:
        """Start the participant; the deadline of every wait starts now."""
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.timeout_s = timeout_s
        self.deadline = time.monotonic() + timeout_s
        self.context = rclpy.Context()
        arguments = ['softseq', '--ros-args', *ros_args] if ros_args else ['softseq']
        try:
            rclpy.init(args=arguments, context=self.context)
        except Exception as err:
            # rcl's refusal of an argument after --ros-args: its class is not public API.
            raise RosToolError(f'--ros-args: rcl refused them: {" ".join(str(err).split())}') \
                from None
        try:
            self.node = rclpy.create_node(f'_softseq_{os.getpid()}', namespace=namespace,
                                          context=self.context, enable_rosout=False,
                                          start_parameter_services=False)
            self.executor = SingleThreadedExecutor(context=self.context)
            self.executor.add_node(self.node)
        except BaseException:
            rclpy.try_shutdown(context=self.context)
            raise

    def __enter__(self) -> 'Session':
        return self

    def __exit__(self, *_exc: object) -> None:
        import rclpy

        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def left_s(self) -> float:
        """Seconds left before the deadline (0 when past it)."""
        return max(0.0, self.deadline - time.monotonic())

    def resolve(self, name: str) -> str:
        """The absolute name of a service or topic ``name`` as this command's node sees it."""
        return self.node.resolve_service_name(name)

    def wait(self, condition: Callable[[], Any]) -> Any:
        """Poll ``condition`` until it gives something true or the deadline passes (then None)."""
        while True:
            found = condition()
            if found:
                return found
            if self.left_s() <= 0.0:
                return None
            time.sleep(min(GRAPH_POLL_S, self.left_s()))

    def answer(self, future: Any) -> Any:
        """Spin until ``future`` is done or the deadline passes; its result, or None."""
        while not future.done() and self.left_s() > 0.0:
            self.executor.spin_once(timeout_sec=min(0.1, self.left_s()))
        return future.result() if future.done() else None

    def service_types(self, name: str) -> list[str]:
        """The types the graph knows for the service ``name`` (absolute), or []."""
        return dict(self.node.get_service_names_and_types()).get(name, [])

    def elsewhere(self, absolute: str, kind: str = 'service') -> str:
        """
        Where else a service, topic or node of this name runs, for a not-found message.

        ``/syringe_pump/start`` not found but ``/rig2/syringe_pump/start`` there: the user
        left out the namespace. The empty string when there is nothing of the kind.
        """
        if kind == 'node':
            names = [namespace.rstrip('/') + '/' + name
                     for name, namespace in self.node.get_node_names_and_namespaces()]
        else:
            names = [name for name, _ in (self.node.get_service_names_and_types()
                                          if kind == 'service'
                                          else self.node.get_topic_names_and_types())]
        # The last two parts (syringe_pump/start), or the last of a node's name.
        parts = absolute.rsplit('/', 1 if kind == 'node' else 2)
        suffix = '/' + '/'.join(parts[1:]) if len(parts) > 1 and all(parts[1:]) else absolute
        found = sorted({name for name in names if name.endswith(suffix) and name != absolute})
        if not found:
            return ''
        more = f' and {len(found) - 3} more' if len(found) > 3 else ''
        return f' (found {", ".join(found[:3])}{more})'

    def not_found(self, what: str, absolute: str, kind: str = 'service') -> RosToolError:
        """``no service /x within 5 s; is the node running, in that namespace?`` and more."""
        return RosToolError(f'{what} within {seconds_text(self.timeout_s)}; is the node '
                            f'running, in that namespace?{self.elsewhere(absolute, kind)}')

    def call(self, service_type: type, name: str, request: Any) -> Any:
        """
        Call the service ``name`` (absolute) once it is there; its response.

        RosToolError when it does not appear or does not answer before the deadline.
        """
        client = self.node.create_client(service_type, name)
        try:
            if not client.wait_for_service(timeout_sec=self.left_s()):
                raise self.not_found(f'no service {name}', name)
            response = self.answer(client.call_async(request))
            if response is None:
                raise RosToolError(f'{name} did not answer within '
                                   f'{seconds_text(self.timeout_s)}')
            return response
        finally:
            self.node.destroy_client(client)
