"""
Running rig nodes as a process: init, spin until SIGINT/SIGTERM, then destroy and shut down.

A configuration mistake (scene file, parameter value) ends the process with one line on stderr
and exit status 2, not a traceback. Node-prefixed ``-p`` rules are matched here for every node
of the process (softseq_ros.nodes.parameters); one that would change nothing is such a mistake.
"""

import sys
from typing import Any, Callable, NoReturn, Sequence

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

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


def run_node(node_class: Callable[..., Node], args: list[str] | None = None) -> None:
    """Run one node until SIGINT/SIGTERM."""
    run_nodes([node_class], args, getattr(node_class, 'NODE_NAME', 'node'))


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


def run_nodes(node_classes: Sequence[Callable[..., Node]], args: list[str] | None,
              name: str) -> None:
    """
    Run several nodes in one process, on one single-threaded executor.

    With more than one node, values between their cores go through one :class:`LocalCores`;
    every topic is still published over DDS for the world outside.
    """
    arguments = init_ros(args, name)
    nodes: list[Node] = []
    error = None
    try:
        shared = {'local': LocalCores()} if len(node_classes) > 1 else {}
        build_nodes(node_classes, arguments, nodes, **shared)
        executor = SingleThreadedExecutor()
        for node in nodes:
            executor.add_node(node)
        executor.spin()
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
