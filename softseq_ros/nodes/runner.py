"""
Running rig nodes as a process: init, spin until SIGINT/SIGTERM, then destroy and shut down.

A configuration mistake (scene file, parameter value) ends the process with one line on stderr
and exit status 2, not a traceback. Node-prefixed ``-p`` rules are matched here for every node
of the process (softseq_ros.nodes.parameters); one that would change nothing is such a mistake.

``--help`` or ``-h`` before any ``--ros-args`` prints the node's parameters, topics and
services and exits 0 without starting anything (no rclpy context, no DDS participant, no file).
The parameters are read from the node's own declarations, run in a dry build
(:func:`declared_parameters`), so the help cannot drift from what the node declares.
"""

import sys
import textwrap
from typing import Any, Callable, NoReturn, Sequence

from rcl_interfaces.msg import ParameterDescriptor, ParameterType
import rclpy
from rclpy.exceptions import ParameterException, ParameterUninitializedException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from softseq_ros.nodes.core_node import LocalCores
from softseq_ros.nodes.parameters import (
    NodeConfigError,
    RosArguments,
    check_rule_values,
    node_fqn,
    rcl_reason,
    read_rules,
    split_ros_arguments,
)
from softseq_ros.rig.build import SettingError
from softseq_ros.scene.loader import SceneError
from softseq_ros.wire import contract


def run_node(node_class: Callable[..., Node], args: list[str] | None = None) -> None:
    """Run one node until SIGINT/SIGTERM."""
    run_nodes([node_class], args, getattr(node_class, 'NODE_NAME', 'node'))


# ------------------------------------------------------------------------------ --help

HELP_FLAGS = frozenset({'-h', '--help'})


def wants_help(args: Sequence[str] | None) -> bool:
    """True when ``-h``/``--help`` stands before any ``--ros-args`` (``args`` as argv)."""
    tokens = list(sys.argv if args is None else args)[1:]
    before = tokens[:tokens.index('--ros-args')] if '--ros-args' in tokens else tokens
    return any(token in HELP_FLAGS for token in before)


class _DeclarationsOverError(Exception):
    """A dry build reached the node's first step past declaring its parameters."""


class _DryNode(Node):
    """
    Stands in for rclpy's Node under a node class: records the declarations, starts nothing.

    Placed between the node's own classes and rclpy's Node, it answers the calls a node makes
    while it declares its parameters; any other rclpy Node method (a publisher, a timer, the
    graph) means the declarations are over and ends the dry build with _DeclarationsOverError.
    rclpy's Node is never initialised, so no context, participant or file is touched.
    """

    def __init__(self, node_name: str, **_node_kwargs: Any) -> None:
        self._dry_name = node_name
        self._dry_declared: dict[str, tuple[Any, ParameterDescriptor]] = {}
        # Values given in place of defaults (a scene, say): the declarations that follow
        # from them, as a node started with them makes them.
        self._dry_values: dict[str, Any] = dict(getattr(self, '_dry_given', {}))

    def __getattribute__(self, name: str) -> Any:
        if name in _NODE_API and name not in _DRY_API:
            raise _DeclarationsOverError(name)
        return object.__getattribute__(self, name)

    def get_name(self) -> str:
        return self._dry_name

    def get_namespace(self) -> str:
        return '/'

    def get_fully_qualified_name(self) -> str:
        return '/' + self._dry_name

    def add_on_set_parameters_callback(self, callback: Any) -> None:
        pass

    def add_post_set_parameters_callback(self, callback: Any) -> None:
        pass

    def declare_parameter(self, name: str, value: Any = None,
                          descriptor: ParameterDescriptor | None = None,
                          ignore_override: bool = False) -> Parameter:
        default = None if isinstance(value, Parameter.Type) else value
        self._dry_declared[name] = (default, descriptor or ParameterDescriptor())
        return Parameter(name, value=self._dry_values.get(name, default))

    def has_parameter(self, name: str) -> bool:
        return name in self._dry_declared or name == 'use_sim_time'

    def get_parameter(self, name: str) -> Parameter:
        if name == 'use_sim_time':
            return Parameter(name, value=False)
        if name not in self._dry_declared:
            raise _DeclarationsOverError(name)
        default, descriptor = self._dry_declared[name]
        default = self._dry_values.get(name, default)
        if default is None:
            if descriptor.dynamic_typing:
                return Parameter(name)   # as rclpy: a dynamically typed one reads as not set
            raise ParameterUninitializedException(name)
        return Parameter(name, value=default)


_NODE_API = frozenset(name for name in dir(Node) if not name.startswith('__'))
_DRY_API = frozenset(vars(_DryNode)) | {'_dry_name', '_dry_declared', '_dry_values',
                                         '_dry_given'}


def declared_parameters(node_class: Callable[..., Node], given: dict[str, Any] | None = None
                        ) -> list[tuple[str, Any, ParameterDescriptor]]:
    """
    (name, default, descriptor) of every parameter ``node_class`` declares, in order.

    The node's ``__init__`` runs on a :class:`_DryNode` (defaults of the default scene, or the
    values ``given``, e.g. another scene) up to its first step that would start something.
    """
    dry_class = type(f'Dry{node_class.__name__}', (node_class, _DryNode),
                     {'_dry_given': dict(given or {})})
    node = object.__new__(dry_class)
    try:
        node.__init__()
    except _DeclarationsOverError:
        pass
    return [(name, default, descriptor)
            for name, (default, descriptor) in node._dry_declared.items()]


_TYPE_NAMES = {value: name[len('PARAMETER_'):].lower() for name, value in
               vars(ParameterType).items() if name.startswith('PARAMETER_')}


def _default_text(default: Any) -> str:
    if default is None:
        return 'unset'
    if isinstance(default, str):
        return repr(default)
    if isinstance(default, float):
        return f'{default:g}'
    if isinstance(default, (list, tuple)):
        return '[' + ', '.join(_default_text(item) for item in default) + ']'
    return str(default).lower() if isinstance(default, bool) else str(default)


def _wrap(text: str, indent: str, later: str | None = None) -> str:
    return textwrap.fill(' '.join(text.split()), width=96, initial_indent=indent,
                         subsequent_indent=indent if later is None else later)


def _parameters_help(node_class: Callable[..., Node], several: bool) -> list[str]:
    node_name = getattr(node_class, 'NODE_NAME', 'node')
    try:
        declared = declared_parameters(node_class)
    except (SceneError, NodeConfigError, SettingError, OSError) as err:
        # The default scene itself cannot be read: the help still answers, and says why.
        return [f'Parameters of {node_name}: cannot be listed ({" ".join(str(err).split())})']
    how = (f'-p NAME:=VALUE for every node that has it, -p {node_name}:NAME:=VALUE for this one'
           if several else '-p NAME:=VALUE')
    if any(name == 'scene' for name, _, _ in declared):
        how += "; the defaults shown are the default scene's, another scene gives its own"
    lines = [_wrap(f'Parameters of {node_name} ({how}):', '')]
    for name, default, descriptor in declared:
        facts = [_TYPE_NAMES.get(descriptor.type, 'any')]
        if descriptor.additional_constraints:
            facts.append(f'range {descriptor.additional_constraints}')
        facts.append(f'default {_default_text(default)}')
        if descriptor.read_only:
            facts.append('read-only (set at start only)')
        lines.append(_wrap(f'{name}: {", ".join(facts)}', '  ', '      '))
        if descriptor.description:
            lines.append(_wrap(descriptor.description, '      '))
    # Declared by rclpy's Node itself (Jazzy), for every node.
    lines.append('  use_sim_time: bool, default false (ROS: follow /clock)')
    lines.append('  start_type_description_service: bool, default true, read-only (ROS: serve '
                 '~/get_type_description)')
    return lines


def node_role(node_class: Callable[..., Node]) -> str | None:
    """The contract role of a node class: a rig node's is its name's, a controller says its own."""
    return getattr(node_class, 'ROLE', None) or next(
        (role for role, node_name in contract.NODE_NAMES.items()
         if node_name == getattr(node_class, 'NODE_NAME', None)), None)


def _topics_help(node_class: Callable[..., Node]) -> list[str]:
    role = node_role(node_class)
    topics = [('publishes', topic) for topic in contract.RIG_TOPICS + (contract.CLOCK,)
              if topic.producer in (role, getattr(node_class, 'NODE_NAME', None))]
    if hasattr(node_class, 'DIAGNOSTIC_TASK'):
        topics.append(('publishes', contract.DIAGNOSTICS))
    topics += [('subscribes', topic) for topic in contract.consumed_by(role or '')]
    lines = []
    for verb, topic in topics:
        qos = topic.qos if verb == 'publishes' else topic.reader_qos
        if topic.output in contract.DERIVED_OUTPUTS:
            # Not a scene output: on with the one it belongs to, where the model has it.
            switch = (f', with scene output {contract.DERIVED_OUTPUTS[topic.output]} when '
                      'the scene has a network')
        else:
            switch = f', scene output {topic.output}' if topic.output else ''
        lines.append(_wrap(f'{verb} {topic.name} [{topic.type_name}] (depth {qos.depth}, '
                           f'{"reliable" if qos.reliable else "best effort"}'
                           f'{", latched" if qos.latched else ""}{switch})', '  ', '      '))
        lines.append(_wrap(topic.content, '      '))
    return lines


def help_text(node_classes: Sequence[Callable[..., Node]], name: str) -> str:
    """What ``name --help`` prints: per node its parameters, topics and services."""
    several = len(node_classes) > 1
    lines = [f'usage: {name} [-h] [--ros-args [-r __ns:=/NS] [-p [NODE:]NAME:=VALUE ...] '
             '[--params-file FILE]]', '']
    for node_class in node_classes:
        node_name = getattr(node_class, 'NODE_NAME', 'node')
        doc = sys.modules[node_class.__module__].__doc__ or ''
        summary = ' '.join(doc.strip().split('\n\n')[0].split())
        prefix = f'{node_name}:' if several else ''
        lines.append(_wrap(f'{prefix} {summary}'.strip() if several else summary, ''))
        lines.append('')
        lines += _parameters_help(node_class, several)
        topics = _topics_help(node_class)
        extra = getattr(node_class, 'HELP_TOPICS', ())
        if topics or extra:
            lines += ['', f'Topics of {node_name} (relative to its namespace):']
            lines += topics + [_wrap(text, '  ') for text in extra]
        services = getattr(node_class, 'SERVICES', {})
        if services:
            lines += ['', _wrap(f'Services of {node_name} (std_srvs/srv/Trigger, in its '
                                f'private namespace: /{node_name}/NAME at the root):', '')]
            lines += [f'  ~/{service}: {text}' for service, text in services.items()]
        for note in getattr(node_class, 'HELP_NOTES', ()):
            lines += ['', _wrap(note, '')]
        lines.append('')
    lines.append('Every node also has the ROS parameter services (ros2 param list/get/set, or '
                 'softseq ros param list/get/set without the ros2 command).')
    return '\n'.join(lines)


def exit_with_help(node_classes: Sequence[Callable[..., Node]], args: list[str] | None,
                   name: str) -> None:
    """Print the help and exit 0 when the command line asks for it; else return."""
    if wants_help(args):
        print(help_text(node_classes, name))
        sys.exit(0)


def _refuse(name: str, reason: str) -> NoReturn:
    print(f'{name}: error: {reason}', file=sys.stderr)
    sys.exit(2)


def init_ros(args: list[str] | None, name: str) -> RosArguments:
    """
    rclpy.init with the command line (``sys.argv`` when None); return how it was split.

    The node-prefixed ``-p`` rules are kept from rcl (parameters.split_ros_arguments) and
    given to each node by :func:`node_options`. A command line rcl refuses ends the process
    with one line and exit 2.
    """
    arguments = split_ros_arguments(sys.argv if args is None else args)
    try:
        check_rule_values(arguments.rules)
        rclpy.init(args=arguments.rcl_args)
    except NodeConfigError as err:
        _refuse(name, str(err))
    except Exception as err:
        if type(err).__name__ == 'UnknownROSArgsError':
            # rclpy names the arguments rcl did not know; its class is not public API.
            hint = '; -h/--help goes before --ros-args' if any(
                flag in str(err) for flag in HELP_FLAGS) else ''
            _refuse(name, f'unknown ROS argument(s) after --ros-args: {err}{hint}')
        _refuse(name, rcl_reason(err))
    return arguments


def node_names(node_classes: Sequence[Callable[..., Node]],
               arguments: RosArguments) -> list[tuple[str, str]]:
    """The (name, fully qualified name) each node class will get under ``arguments``."""
    return [node_fqn(getattr(cls, 'NODE_NAME', 'node'), '', arguments.remaps)
            for cls in node_classes]


def check_rules_reach(arguments: RosArguments, names: Sequence[tuple[str, str]]) -> None:
    """Refuse a node-prefixed rule that no node of this process takes, naming the nodes."""
    for rule in arguments.rules:
        if not any(rule.matches(name, fqn) for name, fqn in names):
            nodes = ', '.join(fqn for _, fqn in names)
            raise NodeConfigError(
                f'-p {rule.text}: no node {rule.node} in this process (its nodes: {nodes}); '
                'give a node name or a fully qualified name')


def node_options(arguments: RosArguments, name: str, fqn: str,
                 context: Any = None) -> dict[str, Any]:
    """The keywords that give a node the command line's parameters meant for it."""
    overrides = read_rules(arguments.rules_for(name, fqn), context)
    return {'parameter_overrides': overrides} if overrides else {}


def check_rules_taken(arguments: RosArguments, nodes: Sequence[Node]) -> None:
    """
    Refuse a ``-p`` rule that no node it reaches declares: it would change nothing.

    A node declares all its parameters while it is built, so once they are built a parameter
    none has is a misspelt name or one meant for a node of another process.
    """
    for rule in arguments.global_rules + arguments.rules:
        reached = [node for node in nodes
                   if rule.matches(node.get_name(), node.get_fully_qualified_name())]
        if reached and not any(node.has_parameter(rule.name) for node in reached):
            where = ', '.join(node.get_fully_qualified_name() for node in reached)
            raise NodeConfigError(f'-p {rule.text}: no parameter {rule.name} on {where}')


def build_nodes(node_classes: Sequence[Callable[..., Node]], arguments: RosArguments,
                nodes: list[Node], **keywords: Any) -> None:
    """
    Build one node per class (by its ``NODE_NAME``) into ``nodes``, each with its parameters.

    ``nodes`` is the caller's list, so that what was built before an error is still destroyed;
    ``keywords`` go to every node. A ``-p`` rule that would change nothing is refused
    (NodeConfigError): a prefix that names no node here, or a parameter no node it reaches has.
    """
    names = node_names(node_classes, arguments)
    check_rules_reach(arguments, names)
    for node_class, (node_name, fqn) in zip(node_classes, names):
        nodes.append(node_class(**node_options(arguments, node_name, fqn), **keywords))
        actual = nodes[-1].get_fully_qualified_name()
        if actual != fqn:
            # The rules were matched to the name the remapping rules predicted.
            raise NodeConfigError(
                f'node {actual}: its -p rules were matched for {fqn}; move or rename it with '
                '-r [node:]__ns:= or -r [node:]__node:= only')
    check_rules_taken(arguments, nodes)


# What rclpy's take says when it received a message but could not convert it to Python.
LOST_MESSAGE = 'to Python object'


def spin_past_lost_messages(executor: SingleThreadedExecutor, node: Node) -> None:
    """
    Spin until shutdown; a message rclpy fails to take is lost with a warning, not the process.

    Under heavy load (a 10 kHz pump on 2 cores) rclpy's take has failed, rarely, to convert a
    message it received ("Unable to convert call argument '0' to Python object"), and the
    executor raises that from spin. Only that message is lost, as one DDS drops would be; the
    nodes go on, and ``node`` logs a warning.
    """
    while True:
        try:
            executor.spin()
            return
        except RuntimeError as err:
            if LOST_MESSAGE not in str(err) or not executor.context.ok():
                raise
            node.get_logger().warning(f'a message could not be taken and is lost: {err}')


def run_nodes(node_classes: Sequence[Callable[..., Node]], args: list[str] | None,
              name: str) -> None:
    """
    Run several nodes in one process, on one single-threaded executor.

    With more than one node, values between their cores go through one :class:`LocalCores`;
    every topic is still published over DDS for the world outside.
    """
    exit_with_help(node_classes, args, name)
    arguments = init_ros(args, name)
    nodes: list[Node] = []
    error = None
    try:
        shared = {'local': LocalCores()} if len(node_classes) > 1 else {}
        build_nodes(node_classes, arguments, nodes, **shared)
        executor = SingleThreadedExecutor()
        for node in nodes:
            executor.add_node(node)
        spin_past_lost_messages(executor, nodes[0])
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (SceneError, NodeConfigError, SettingError, ParameterException) as err:
        error = ' '.join(str(err).split())
    except Exception:
        # SIGINT shuts the context down under a running callback, whose publish then fails
        # (context invalid). After a shutdown that is the end of the run, not a bug.
        if rclpy.ok():
            raise
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    if error is not None:
        print(f'{name}: error: {error}', file=sys.stderr)
        sys.exit(2)
