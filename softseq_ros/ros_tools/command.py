"""
The ``softseq ros`` subcommands: their arguments, help and exit codes.

Exit codes, alike for every subcommand: 0 when the node did what was asked, 1 when it answered
with a refusal (a service's success false, a parameter value it refused, a lifecycle
transition it failed; its reason on stderr), 2 for input that cannot be used or a node,
service or topic not found within ``--timeout`` (one line on stderr), 130 or 143 when
interrupted (``echo`` ends at Ctrl-C with 0: that is how it is stopped).
"""

import argparse
from pathlib import Path
from typing import Any

from softseq_ros.ros_tools.session import (
    DEFAULT_TIMEOUT_S,
    check_name,
    check_namespace,
    timeout_seconds,
)

EXIT_CODES = ('Exit codes: 0 done; 1 the node refused (its reason on stderr); 2 bad input, or '
              'nothing found within --timeout (one line on stderr).')
NAMES = ('Relative names resolve in --namespace (default: the root namespace /); absolute '
         'names (/rig2/syringe_pump) are taken as they are.')


def _session(args: argparse.Namespace) -> Any:
    from softseq_ros.ros_tools.session import Session

    return Session(check_namespace(args.namespace), args.timeout, args.ros_args or ())


def _call(args: argparse.Namespace) -> int:
    from softseq_ros.ros_tools.calls import call_service

    check_name(args.service, 'SERVICE')
    with _session(args) as session:
        return call_service(session, args.service, args.data)


def _param(args: argparse.Namespace) -> int:
    from softseq_ros.ros_tools import calls

    check_name(args.node, 'NODE')
    needs = {'list': 0, 'get': 1, 'describe': 1, 'set': 2}[args.verb]
    given = [value for value in (args.name, args.value) if value is not None]
    if len(given) != needs:
        wanted = {0: 'NODE alone', 1: 'NODE NAME', 2: 'NODE NAME VALUE'}[needs]
        raise calls.RosToolError(f'{args.verb} takes {wanted}, got '
                                 f'{" ".join([args.node, *given])}')
    with _session(args) as session:
        if args.verb == 'list':
            return calls.param_list(session, args.node)
        if args.verb == 'get':
            return calls.param_get(session, args.node, args.name)
        if args.verb == 'describe':
            return calls.param_describe(session, args.node, args.name)
        return calls.param_set(session, args.node, args.name, args.value)


def _lifecycle(args: argparse.Namespace) -> int:
    from softseq_ros.ros_tools import calls

    check_name(args.node, 'NODE')
    if args.verb == 'get' and args.transition is not None:
        raise calls.RosToolError(f'get takes NODE alone, got {args.transition!r} too')
    if args.verb == 'set' and args.transition not in calls.TRANSITIONS:
        given = 'none' if args.transition is None else repr(args.transition)
        raise calls.RosToolError(f'set: TRANSITION must be one of '
                                 f'{", ".join(calls.TRANSITIONS)}, got {given}')
    with _session(args) as session:
        if args.verb == 'get':
            return calls.lifecycle_get(session, args.node)
        return calls.lifecycle_set(session, args.node, args.transition)


def _echo(args: argparse.Namespace) -> int:
    from softseq_ros.ros_tools.echo import echo
    from softseq_ros.ros_tools.session import RosToolError

    check_name(args.topic, 'TOPIC')
    if args.count is not None and args.count < 1:
        raise RosToolError(f'--count: must be at least 1, got {args.count}')
    if args.truncate_length < 1:
        raise RosToolError(f'--truncate-length: must be at least 1, got {args.truncate_length}')
    with _session(args) as session:
        return echo(session, args.topic, args.count, args.truncate_length)


def _rig(args: argparse.Namespace) -> int:
    from softseq_ros.ros_tools.launcher import run_rig

    namespace = check_namespace(args.namespace)
    return run_rig(namespace, args.params_file, args.scene, args.record,
                   args.timeout if args.start else None)


def _common(parser: argparse.ArgumentParser, timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
    """--namespace, --timeout and --ros-args, for every subcommand that reaches a node."""
    parser.add_argument('--namespace', default='/', metavar='NS',
                        help='namespace that relative names resolve in (default /)')
    parser.add_argument('--timeout', type=timeout_seconds, default=timeout_s, metavar='S',
                        help=f'seconds to wait for the node, service or topic and its answer '
                        f'(default {timeout_s:g}), all told')
    parser.add_argument('--ros-args', nargs=argparse.REMAINDER, metavar='ARG',
                        help="rcl arguments for this command's own node, as a node takes "
                        'them (-r __ns:=/rig2 is the same as --namespace /rig2); last')


def add_ros_parser(sub: Any) -> argparse.ArgumentParser:
    """Add ``softseq ros`` and its subcommands to the subparsers ``sub`` of ``softseq``."""
    ros = sub.add_parser(
        'ros', help='what the ros2 command gives: call, param, lifecycle, echo, and a rig '
        'with its recorder', description='Reach running nodes as the ros2 command does, '
        'where it is not installed (the PyPI wheels have no ros2 command): call services, '
        'get and set parameters, drive a lifecycle node, print a topic; and start a rig '
        'with its recorder in a namespace, as launch/rig.launch.py does. ' + EXIT_CODES)
    verbs = ros.add_subparsers(dest='ros_command', required=True, metavar='SUBCOMMAND')

    call = verbs.add_parser(
        'call', help='call a std_srvs Trigger or SetBool service (ros2 service call)',
        description='Call a std_srvs/srv/Trigger service (no DATA), e.g. /syringe_pump/start, '
        'or a std_srvs/srv/SetBool service with DATA true or false, e.g. '
        '/syringe_pump/setpoint_mode true; the type is the one the graph gives the service. '
        'Prints success and message. ' + NAMES,
        epilog='Exit codes: 0 the service answered success true; 1 it answered success false '
        '(a refusal, its message printed); 2 bad input, or no service or no answer within '
        '--timeout.')
    call.add_argument('service', metavar='SERVICE', help='service name, e.g. '
                      '/rig2/syringe_pump/start')
    call.add_argument('data', metavar='DATA', nargs='?', help='true or false, for a SetBool '
                      'service only')
    _common(call)
    call.set_defaults(handler=_call, command_path='ros call')

    param = verbs.add_parser(
        'param', help="list, get, set or describe a node's parameters (ros2 param)",
        description="Through the node's parameter services (rcl_interfaces): list its "
        'parameters, get one, set one, or describe one (type, description, range, '
        'read-only). VALUE is read as YAML, as ros2 param set reads it (true, 5, 2.5, '
        '[1.0, 2.0], text); a parameter the node declares as a string takes VALUE as the '
        'text it is, so YAML of its own passes whole: param set /syringe_pump legs '
        '"[{inflate_to_m3: 2.0e-5}, {deflate_to_m3: 0.0}]"; a double parameter takes an '
        'integer as the double it means. ' + NAMES,
        epilog='Exit codes: 0 done; 1 the node refused the value (its reason on stderr) or '
        'the parameter is not set; 2 bad input, no such parameter, or no node or no answer '
        'within --timeout.')
    param.add_argument('verb', choices=('list', 'get', 'set', 'describe'))
    param.add_argument('node', metavar='NODE', help='node name, e.g. /rig2/syringe_pump')
    param.add_argument('name', metavar='NAME', nargs='?', help='parameter name (not for list)')
    param.add_argument('value', metavar='VALUE', nargs='?', help='new value (set only)')
    _common(param)
    param.set_defaults(handler=_param, command_path='ros param')

    lifecycle = verbs.add_parser(
        'lifecycle', help="get or change a managed node's state (ros2 lifecycle)",
        description="Through the node's lifecycle services (lifecycle_msgs ~/get_state, "
        '~/get_available_transitions, ~/change_state): get prints the state; set requests a '
        'transition by name (configure, activate, deactivate, cleanup, shutdown) and prints '
        'the state it led to. For managed_syringe_pump: configure, then activate. ' + NAMES,
        epilog='Exit codes: 0 done; 1 the transition is not available in the present state '
        'or the node failed it; 2 bad input, or no node or no answer within --timeout.')
    lifecycle.add_argument('verb', choices=('get', 'set'))
    lifecycle.add_argument('node', metavar='NODE', help='node name, e.g. /syringe_pump')
    lifecycle.add_argument('transition', metavar='TRANSITION', nargs='?',
                           help='configure, activate, deactivate, cleanup or shutdown (set '
                           'only)')
    _common(lifecycle)
    lifecycle.set_defaults(handler=_lifecycle, command_path='ros lifecycle')

    echo = verbs.add_parser(
        'echo', help="print a topic's messages (ros2 topic echo)",
        description="Print each message on TOPIC as YAML, followed by '---'. A rig topic "
        '(pump/status, actuator/volumes, ... in any namespace) is read with the QoS of the '
        "rig's contract, so a latched state arrives at once; any other topic takes its type "
        'from the graph. Ends after --count messages, or at Ctrl-C (exit 0). ' + NAMES,
        epilog='Exit codes: 0 done or stopped by Ctrl-C; 2 bad input, or no publisher within '
        '--timeout, or with --count no first message within it either (without --count, '
        'messages are awaited until Ctrl-C, as ros2 topic echo does).')
    echo.add_argument('topic', metavar='TOPIC', help='topic name, e.g. /rig2/pump/status')
    echo.add_argument('--count', type=int, metavar='N', help='stop after N messages')
    echo.add_argument('--truncate-length', type=int, default=128, metavar='N',
                      help='cut arrays and strings longer than N, as ros2 topic echo '
                      '(default 128)')
    _common(echo)
    echo.set_defaults(handler=_echo, command_path='ros echo')

    rig = verbs.add_parser(
        'rig', help='a rig and its recorder in a namespace (ros2 launch softseq_ros '
        'rig.launch.py)',
        description='Start the rig (syringe pump, actuator and camera: the rig executable) '
        'and its recorder in NAMESPACE, with the parameters file and the scene given, as '
        'launch/rig.launch.py starts them; run until Ctrl-C or SIGTERM, then stop the rig '
        'and close the bag. The pump waits for ~/start (softseq ros call '
        '/NAMESPACE/syringe_pump/start) unless --start, or autostart in the parameters '
        'file. A parameters file names each node by its fully qualified name '
        '(config/params/params_example.yaml).',
        epilog='Exit codes: 0 stopped by Ctrl-C or SIGTERM, both cleanly; 1 a node failed or '
        'did not stop; 2 bad input, or a node refused its parameters (its line above).')
    rig.add_argument('--namespace', default='/rig1', metavar='NS',
                     help='namespace of every node, topic and service (default /rig1, as the '
                     'launch file)')
    rig.add_argument('--params-file', type=Path, metavar='FILE',
                     help='ROS parameters file for the rig and the recorder')
    rig.add_argument('--scene', help='scene YAML file or shipped scene name (default: the '
                     "parameters file's, else the nodes' default, paper)")
    rig.add_argument('--record', type=Path, metavar='DIR',
                     help="the bag folder (default: the parameters file's recorder output, "
                     'else bags/rig_<UTC time>); must not exist, or be empty')
    rig.add_argument('--start', action='store_true',
                     help="call the pump's ~/start once the recorder records its commands, "
                     'so the bag holds the programme from its first command')
    rig.add_argument('--timeout', type=timeout_seconds, default=60.0, metavar='S',
                     help='with --start: seconds to wait for the rig and the recorder '
                     '(default 60)')
    rig.set_defaults(handler=_rig, command_path='ros rig')
    ros.commands = dict(verbs.choices)
    return ros
