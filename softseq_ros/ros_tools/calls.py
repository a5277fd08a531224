"""
Services, parameters and lifecycle transitions of running nodes, as ``ros2`` would call them.

Each function prints what the node answered and returns the exit code: 0 when the node did
what was asked, 1 when it answered with a refusal (its reason printed on stderr). A name or
value that cannot be used, or a node or service that is not there in time, raises
RosToolError (one line, exit 2) before or instead of any request.
"""

import sys
from typing import Any

import yaml

from softseq_ros.ros_tools.session import RosToolError, Session

TRIGGER = 'std_srvs/srv/Trigger'
SET_BOOL = 'std_srvs/srv/SetBool'
BOOL_WORDS = {'true': True, 'false': False}


def _refusal(command: str, text: str) -> int:
    print(f'softseq ros {command}: {" ".join(text.split())}', file=sys.stderr)
    return 1


# ------------------------------------------------------------------------------- call

def call_service(session: Session, service: str, data: str | None) -> int:
    """
    Call a std_srvs/Trigger service (no ``data``) or std_srvs/SetBool (``data`` true/false).

    The type is the one the graph gives the service, so a SetBool called without its data,
    or a service of another type, is refused in one line. Prints ``success`` and ``message``;
    exit 0 when the service answered success, 1 when it answered failure.
    """
    from std_srvs.srv import SetBool, Trigger

    name = session.resolve(service)
    types = session.wait(lambda: session.service_types(name))
    if not types:
        raise session.not_found(f'no service {name}', name)
    if TRIGGER in types:
        if data is not None:
            raise RosToolError(f'{name} is a {TRIGGER} service: it takes no DATA, got {data!r}')
        response = session.call(Trigger, name, Trigger.Request())
    elif SET_BOOL in types:
        if data is None or data.lower() not in BOOL_WORDS:
            given = 'none' if data is None else repr(data)
            raise RosToolError(f'{name} is a {SET_BOOL} service: give DATA true or false, '
                               f'got {given}')
        response = session.call(SetBool, name, SetBool.Request(data=BOOL_WORDS[data.lower()]))
    else:
        raise RosToolError(f'{name} is a {", ".join(types)} service; softseq ros call calls '
                           f'{TRIGGER} and {SET_BOOL} services only')
    print(f'success: {str(response.success).lower()}')
    print(f'message: {response.message}')
    return 0 if response.success else 1


# ------------------------------------------------------------------------------ param

def _type_names() -> dict[int, str]:
    from rcl_interfaces.msg import ParameterType

    return {value: name[len('PARAMETER_'):].lower() for name, value in vars(ParameterType).items()
            if name.startswith('PARAMETER_')}


def value_text(value: Any) -> str:
    """A parameter's value as it is printed: a string as is, anything else as YAML."""
    if isinstance(value, str):
        return value
    if value is None:
        return 'not set'
    return yaml.safe_dump(value, default_flow_style=True, width=10**9).strip().removesuffix(
        '\n...').strip()


def parameter_value(text: str, declared_type: int, dynamic_typing: bool) -> Any:
    """
    The rcl_interfaces ParameterValue that ``text`` gives a parameter of ``declared_type``.

    As ``ros2 param set``: ``text`` is read as YAML (``true`` a bool, ``5`` an integer,
    ``[1.0, 2.0]`` a double array) and anything else is a string. Two differences, for the
    type the node declares: a string parameter takes ``text`` as the string it is (the
    pump's ``legs``, YAML of its own, would otherwise be read as a list the node refuses; a
    YAML string in quotes loses them, as rclpy reads it), and a double parameter takes an
    integer (``rate_hz 100``) as the double it means.
    """
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rclpy.parameter import get_parameter_value

    try:
        parsed = yaml.safe_load(text)
    except yaml.YAMLError:
        parsed = text
    if isinstance(parsed, str) and declared_type != ParameterType.PARAMETER_STRING:
        # YAML 1.1 reads 1e9 (no dot) as text; a number parameter means the number.
        parsed = _number(parsed)
        if not isinstance(parsed, str):
            text = repr(parsed)
    if not dynamic_typing and declared_type == ParameterType.PARAMETER_STRING:
        return ParameterValue(type=ParameterType.PARAMETER_STRING,
                              string_value=parsed if isinstance(parsed, str) else text)
    if not dynamic_typing and declared_type == ParameterType.PARAMETER_DOUBLE \
            and isinstance(parsed, int) and not isinstance(parsed, bool):
        return ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=float(parsed))
    if not dynamic_typing and declared_type == ParameterType.PARAMETER_DOUBLE_ARRAY \
            and isinstance(parsed, list) and parsed and all(
                isinstance(item, (int, float)) and not isinstance(item, bool) for item in parsed):
        return ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY,
                              double_array_value=[float(item) for item in parsed])
    if isinstance(parsed, (dict, set)) or parsed is None:
        # rclpy's own guess would put the mapping itself into the string field.
        return ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=text)
    return get_parameter_value(text)


def _number(text: str) -> int | float | str:
    """``text`` as an int or a finite float when it is one, else as it is."""
    import math

    for kind in (int, float):
        try:
            number = kind(text)
        except ValueError:
            continue
        if math.isfinite(number):
            return number
    return text


class ParameterClient:
    """The parameter services of one node (rclpy's AsyncParameterClient), with the deadline."""

    def __init__(self, session: Session, node: str) -> None:
        """Wait for the node's parameter services; RosToolError when they do not come."""
        from rclpy.parameter_client import AsyncParameterClient

        self.session = session
        self.node = session.resolve(node)
        self.client = AsyncParameterClient(session.node, self.node)
        if not session.wait(self.client.services_are_ready):
            raise session.not_found(f'no node {self.node} (its parameter services)',
                                    self.node, 'node')

    def _answer(self, future: Any, what: str) -> Any:
        response = self.session.answer(future)
        if response is None:
            raise RosToolError(f'{self.node} did not answer {what} within '
                               f'{self.session.timeout_s:g} s')
        return response

    def names(self) -> list[str]:
        """Every parameter the node has, sorted."""
        return sorted(self._answer(self.client.list_parameters(), 'list_parameters')
                      .result.names)

    def check_name(self, name: str) -> None:
        """Refuse a parameter the node does not have, naming those it has that look alike."""
        names = self.names()
        if name not in names:
            import difflib

            close = difflib.get_close_matches(name, names, n=3)
            hint = f' (did you mean {", ".join(close)}?)' if close else \
                '; softseq ros param list shows them'
            raise RosToolError(f'{self.node} has no parameter {name}{hint}')

    def describe(self, name: str) -> Any:
        """The ParameterDescriptor of ``name`` (which the node has)."""
        response = self._answer(self.client.describe_parameters([name]), 'describe_parameters')
        return response.descriptors[0]

    def get(self, name: str) -> Any:
        """The value of ``name`` as Python (None when it has none)."""
        from rclpy.parameter import parameter_value_to_python

        response = self._answer(self.client.get_parameters([name]), 'get_parameters')
        # rclpy answers nothing for a parameter declared without a value.
        return parameter_value_to_python(response.values[0]) if response.values else None

    def set(self, name: str, value: Any) -> Any:
        """Ask the node to set ``name`` to ``value`` (a ParameterValue); the node's result."""
        from rcl_interfaces.msg import Parameter as ParameterMsg

        response = self._answer(self.client.set_parameters(
            [ParameterMsg(name=name, value=value)]), 'set_parameters')
        return response.results[0]


def param_list(session: Session, node: str) -> int:
    """Print every parameter's name, one a line."""
    for name in ParameterClient(session, node).names():
        print(name)
    return 0


def param_get(session: Session, node: str, name: str) -> int:
    """Print the value (a string as is, anything else as YAML); exit 1 when it has none."""
    client = ParameterClient(session, node)
    client.check_name(name)
    value = client.get(name)
    if value is None:
        return _refusal('param get', f'{client.node}: {name} is not set')
    print(value_text(value))
    return 0


def param_set(session: Session, node: str, name: str, text: str) -> int:
    """Set the value (YAML, see :func:`parameter_value`); exit 1 with the node's reason."""
    from rclpy.parameter import parameter_value_to_python

    client = ParameterClient(session, node)
    client.check_name(name)
    descriptor = client.describe(name)
    value = parameter_value(text, descriptor.type, descriptor.dynamic_typing)
    result = client.set(name, value)
    shown = value_text(parameter_value_to_python(value))
    if not result.successful:
        return _refusal('param set', f'{client.node} refused {name} = {shown}: '
                        f'{result.reason or "no reason given"}')
    print(f'{client.node}: {name} set to {shown}')
    return 0


def param_describe(session: Session, node: str, name: str) -> int:
    """Print the parameter's type, description, range and constraints, as the node declares."""
    client = ParameterClient(session, node)
    client.check_name(name)
    descriptor = client.describe(name)
    lines = [f'{client.node} {name}',
             f'  type: {_type_names().get(descriptor.type, "unknown")}'
             + (' (dynamic typing: another type is taken too)' if descriptor.dynamic_typing
                else '')]
    if descriptor.description:
        lines.append(f'  description: {" ".join(descriptor.description.split())}')
    for span in descriptor.floating_point_range:
        lines.append(f'  range: {span.from_value:g} to {span.to_value:g}'
                     + (f', step {span.step:g}' if span.step else ''))
    for span in descriptor.integer_range:
        lines.append(f'  range: {span.from_value} to {span.to_value}'
                     + (f', step {span.step}' if span.step else ''))
    if descriptor.additional_constraints:
        lines.append(f'  constraints: {" ".join(descriptor.additional_constraints.split())}')
    lines.append(f'  read-only: {str(descriptor.read_only).lower()}'
                 + (' (set at start only)' if descriptor.read_only else ''))
    print('\n'.join(lines))
    return 0


# -------------------------------------------------------------------------- lifecycle

# The transitions a user asks for by name (lifecycle_msgs/msg/Transition's labels).
TRANSITIONS = ('configure', 'activate', 'deactivate', 'cleanup', 'shutdown')


def _state(session: Session, node: str) -> Any:
    from lifecycle_msgs.srv import GetState

    return session.call(GetState, f'{node}/get_state', GetState.Request()).current_state


def _lifecycle_node(session: Session, node: str) -> str:
    """
    The absolute name of ``node`` once its lifecycle services are there.

    A node that runs without them is no managed node (the plain ``syringe_pump``): said so,
    rather than that nothing was found.
    """
    absolute = session.resolve(node)
    service = f'{absolute}/get_state'
    if session.wait(lambda: session.service_types(service)):
        return absolute
    running = {namespace.rstrip('/') + '/' + name
               for name, namespace in session.node.get_node_names_and_namespaces()}
    if absolute in running:
        raise RosToolError(f'{absolute} runs but has no lifecycle services ({service}): it is '
                           'no managed node (managed_syringe_pump is the managed pump)')
    raise session.not_found(f'no lifecycle node {absolute}', service)


def lifecycle_get(session: Session, node: str) -> int:
    """Print the node's lifecycle state: ``inactive [2]``, as ``ros2 lifecycle get``."""
    absolute = _lifecycle_node(session, node)
    state = _state(session, absolute)
    print(f'{state.label} [{state.id}]')
    return 0


def lifecycle_set(session: Session, node: str, transition: str) -> int:
    """
    Request ``transition`` by name; print the state it led to.

    The node's ``~/get_available_transitions`` gives the transition's id in its present state
    (``shutdown`` has one per state); a transition the state has not is refused naming those
    it has (exit 1). A transition the node fails (a pump programme it cannot run) exits 1.
    """
    from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions

    absolute = _lifecycle_node(session, node)
    available = session.call(GetAvailableTransitions, f'{absolute}/get_available_transitions',
                             GetAvailableTransitions.Request()).available_transitions
    chosen = next((t.transition for t in available if t.transition.label == transition), None)
    if chosen is None:
        state = _state(session, absolute)
        labels = sorted({t.transition.label for t in available}) or ['none']
        return _refusal('lifecycle set', f'{absolute} is {state.label}: no transition '
                        f'{transition} from there (it has: {", ".join(labels)})')
    request = ChangeState.Request()
    request.transition.id = chosen.id
    request.transition.label = chosen.label
    response = session.call(ChangeState, f'{absolute}/change_state', request)
    state = _state(session, absolute)
    if not response.success:
        return _refusal('lifecycle set', f'{absolute} failed {transition}; it is '
                        f'{state.label} (its log says why)')
    print(f'{absolute}: {transition} done, now {state.label}')
    return 0
