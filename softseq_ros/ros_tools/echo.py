"""
``softseq ros echo``: a topic's messages printed as YAML, as ``ros2 topic echo`` prints them.

A rig topic (softseq_ros.wire.contract, in any namespace) is read with the contract's QoS, so
a latched state (``pump/status``, ``actuator/volumes``) arrives at once; any other topic takes
its type from the graph and a QoS every publisher there can serve. Messages are printed by
rosidl_runtime_py when it is installed, else by :func:`message_fields` here, each followed by
``---``.
"""

import array
import os
import sys
from typing import Any

import yaml

from softseq_ros.ros_tools.session import RosToolError, Session
from softseq_ros.wire import contract

# As ros2 topic echo: arrays and strings longer than this are cut, with '...' after them.
DEFAULT_TRUNCATE_LENGTH = 128


def contract_topic(absolute: str) -> contract.Topic | None:
    """The contract's topic that ``absolute`` is in whatever namespace, or None."""
    for topic in contract.RIG_TOPICS + (contract.CLOCK, contract.DIAGNOSTICS):
        if absolute == topic.name or (not topic.name.startswith('/')
                                      and absolute.endswith('/' + topic.name)):
            return topic
    return None


def message_fields(value: Any, truncate: int = DEFAULT_TRUNCATE_LENGTH) -> Any:
    """A message as plain Python (dicts, lists, numbers, strings), arrays and strings cut."""
    if hasattr(value, 'get_fields_and_field_types'):
        return {name: message_fields(getattr(value, name), truncate)
                for name in value.get_fields_and_field_types()}
    if isinstance(value, (bytes, bytearray)):
        value = list(value)
    if isinstance(value, (list, tuple, array.array)) or type(value).__module__ == 'numpy':
        if hasattr(value, 'tolist') and not isinstance(value, (list, tuple)):
            value = value.tolist()
        if not isinstance(value, list):
            return value   # a numpy scalar, already a Python number
        items = [message_fields(item, truncate) for item in value[:truncate]]
        return items + ['...'] if len(value) > truncate else items
    if isinstance(value, str) and len(value) > truncate:
        return value[:truncate] + '...'
    return value


def message_yaml(message: Any, truncate: int = DEFAULT_TRUNCATE_LENGTH) -> str:
    """One message as YAML text (ending in a newline)."""
    try:
        from rosidl_runtime_py import message_to_yaml
    except ImportError:
        return yaml.safe_dump(message_fields(message, truncate), default_flow_style=False,
                              sort_keys=False, allow_unicode=True, width=10**9)
    return message_to_yaml(message, truncate_length=truncate)


def _subscription_for(session: Session, absolute: str) -> tuple[type, Any]:
    """The message class and QoS to read ``absolute`` with, once it has a publisher."""
    from rclpy.qos import QoSProfile

    from softseq_ros.nodes.core_node import message_class, qos_profile
    from softseq_ros.nodes.recorder import request_for_offers

    publishers = session.wait(lambda: session.node.get_publishers_info_by_topic(absolute))
    if not publishers:
        raise session.not_found(f'no publisher on {absolute}', absolute, 'topic')
    spec = contract_topic(absolute)
    if spec is not None:
        qos = qos_profile(spec.qos)
        return message_class(spec.type_name), qos
    types = sorted({info.topic_type for info in publishers})
    if len(types) > 1:
        print(f'softseq ros echo: warning: {absolute} has several types {types}; reading '
              f'{types[0]}', file=sys.stderr)
    try:
        message_type = message_class(types[0])
    except (ImportError, AttributeError, ValueError):
        raise RosToolError(f'{absolute}: its type {types[0]} has no Python package installed '
                           'here') from None
    offers = [info.qos_profile for info in publishers if info.topic_type == types[0]]
    request = request_for_offers(offers)
    # A printer keeps up with any rig topic; a shallow queue is enough.
    return message_type, QoSProfile(depth=100, reliability=request.reliability,
                                    durability=request.durability)


def echo(session: Session, topic: str, count: int | None,
         truncate: int = DEFAULT_TRUNCATE_LENGTH) -> int:
    """
    Print the messages on ``topic`` until ``count`` have come, or Ctrl-C (exit 0 both ways).

    The deadline bounds the wait for a publisher, and with ``count`` the wait for the first
    message too (a script that asks for N messages gets an answer in bounded time); once a
    message came, or without ``count``, messages are awaited as long as it takes, as
    ``ros2 topic echo`` does.
    """
    absolute = session.node.resolve_topic_name(topic)
    message_type, qos = _subscription_for(session, absolute)
    printed = [0]

    def show(message: Any) -> None:
        if count is not None and printed[0] >= count:
            return
        sys.stdout.write(message_yaml(message, truncate) + '---\n')
        sys.stdout.flush()
        printed[0] += 1

    session.node.create_subscription(message_type, absolute, show, qos)
    try:
        while count is None or printed[0] < count:
            session.executor.spin_once(timeout_sec=0.1)
            if count is not None and not printed[0] and session.left_s() <= 0.0:
                raise RosToolError(f'a publisher on {absolute}, but no message within '
                                   f'{session.timeout_s:g} s')
    except KeyboardInterrupt:
        pass   # Ctrl-C is how an echo without --count ends
    except BrokenPipeError:
        # The reader went away (| head): the echo is over. Standard output goes nowhere from
        # here, so that Python's own flush at exit does not fail on the closed pipe again.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    return 0
