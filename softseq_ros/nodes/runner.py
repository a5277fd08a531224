"""
Running rig nodes as a process: init, spin until SIGINT/SIGTERM, then destroy and shut down.

A configuration mistake (scene file, parameter value) ends the process with one line on stderr
and exit status 2, not a traceback.
"""

import sys
from typing import Callable, Sequence

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from softseq_ros.nodes.core_node import LocalCores
from softseq_ros.nodes.parameters import NodeConfigError
from softseq_ros.rig.build import SettingError
from softseq_ros.scene.loader import SceneError


def run_node(node_class: Callable[..., Node], args: list[str] | None = None) -> None:
    """Run one node until SIGINT/SIGTERM."""
    run_nodes([node_class], args, getattr(node_class, 'NODE_NAME', 'node'))


def _init(args: list[str] | None, name: str) -> None:
    try:
        rclpy.init(args=args)
    except Exception as err:
        # rclpy's RCLError is not part of its public API: it is known by its name here.
        # rcl parses -p values as YAML: a string holding YAML (the pump's legs) needs its
        # own quotes, -p "legs:='[{inflate_to_m3: 5.0e-6}]'".
        if type(err).__name__ != 'RCLError':
            raise
        reason = ' '.join(str(err).split(', at ')[0].split())
        print(f'{name}: error: {reason}; quote a value that is YAML text, e.g. '
              '-p "legs:=\'[{inflate_to_m3: 5.0e-6}]\'"', file=sys.stderr)
        sys.exit(2)


def run_nodes(node_classes: Sequence[Callable[..., Node]], args: list[str] | None,
              name: str) -> None:
    """
    Run several nodes in one process, on one single-threaded executor.

    With more than one node, values between their cores go through one :class:`LocalCores`;
    every topic is still published over DDS for the world outside.
    """
    _init(args, name)
    nodes: list[Node] = []
    error = None
    try:
        local = LocalCores() if len(node_classes) > 1 else None
        for node_class in node_classes:
            nodes.append(node_class(local=local) if local is not None else node_class())
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
