"""
``softseq ros rig``: a whole rig and its recorder in a namespace, as launch/rig.launch.py.

Two processes, started the way their executables start (same interpreter, same package):
the ``rig`` executable (syringe pump, actuator and camera on one executor) and the ``recorder``,
both with ``-r __ns:=NAMESPACE``, the parameters file and the options given. The launch file
starts the three rig nodes as three processes; the ``rig`` executable runs the same nodes
with the same parameters in one, which costs less on a small machine.

The children run in sessions of their own, so a Ctrl-C at the terminal reaches this command
alone and each child is stopped once, in order: the rig first, then the recorder, so the bag
holds everything the rig published and is closed completely. A child that ends by itself (a
refused parameter) ends the other. Should this command die without stopping them, the
kernel sends them SIGTERM (Linux), which they take as a stop too.
"""

import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from softseq_ros.errors import UserError, read_regular_file
from softseq_ros.ros_tools.session import RosToolError, seconds_text
from softseq_ros.yaml_text import parse_yaml

# How long a child may take to stop after SIGINT before it is killed: a recorder closing a
# large bag on a loaded machine takes seconds.
STOP_TIMEOUT_S = 60.0
# How often the supervisor looks at its children and the stop signals.
SUPERVISE_PERIOD_S = 0.1
# Children started by name, in the order they start; stopped in reverse.
RECORDER, RIG = 'recorder', 'rig'


def _executable(name: str) -> list[str]:
    """
    The command line that runs the console script ``name`` with this interpreter.

    Not the script's path: a venv keeps it in bin/, a colcon install in lib/softseq_ros/,
    and this interpreter with this package is what the user ran in any case.
    """
    return [sys.executable, '-c',
            f'import sys; sys.argv[0] = {name!r}; '
            f'from softseq_ros.nodes.entry import {name}; {name}()']


def rig_commands(namespace: str, params_file: Path | None, scene: str | None,
                 record: Path | None) -> dict[str, list[str]]:
    """The recorder's and the rig's command lines, by name, in the order they start."""
    # Values as YAML strings in double quotes: rcl reads a -p value as YAML, and a path such
    # as 2026 or true would otherwise be a number or a bool.
    common = ['--ros-args', '-r', f'__ns:={namespace}']
    file = ['--params-file', str(params_file)] if params_file is not None else []
    recorder = common + file + (['-p', f'output:={json.dumps(str(record))}'] if record else [])
    # As the launch file: the pump waits for ~/start, so the recorder has found every topic
    # before the first command. Given before the file, so that a file's autostart wins.
    rig = common + ['-p', 'autostart:=false'] + file + (
        ['-p', f'scene:={json.dumps(scene)}'] if scene else [])
    return {RECORDER: _executable(RECORDER) + recorder, RIG: _executable(RIG) + rig}


def check_inputs(params_file: Path | None, record: Path | None,
                 scene: str | None = None) -> None:
    """Refuse, before anything starts, a scene, parameters file or bag folder the nodes would."""
    if scene is not None:
        # Loaded here as the nodes will load it: a scene they would refuse starts nothing.
        from softseq_ros.rig.model import load_rig_scene

        if not scene.strip():
            raise RosToolError('--scene: empty; give a scene file or a shipped scene name')
        try:
            load_rig_scene(scene)
        except UserError as err:
            raise RosToolError(f'--scene {" ".join(str(err).split())}') from None
    if params_file is not None:
        check_params_file(params_file)
    if record is not None and record.exists() and (not record.is_dir()
                                                   or any(record.iterdir())):
        raise RosToolError(f'--record {record}: already exists and is not an empty folder; '
                           'a recording never overwrites one')


def check_params_file(path: Path) -> None:
    """
    Refuse a parameters file no node could take, before any node starts (RosToolError).

    Read as the nodes' rcl reads it: UTF-8 YAML whose top level maps node names (or
    namespaces holding them) to ``ros__parameters``. Handed on unread, a file of Latin-1
    text, of YAML nested too deeply or of one word started the rig, whose nodes then failed
    one by one (or ran with none of the parameters meant); a file without a single
    ``ros__parameters`` sets nothing, as a misspelt ``-p`` would not.
    """
    shown = f'--params-file {path}'
    try:
        text = read_regular_file(path).decode('utf-8')
    except OSError as err:
        raise RosToolError(f'{shown}: cannot read it ({err.strerror or err})') from None
    except UnicodeDecodeError as err:
        raise RosToolError(f'{shown}: not UTF-8 text (byte {err.start})') from None
    except UserError as err:   # a folder or a FIFO
        raise RosToolError(f'--params-file {err}') from None
    document = parse_yaml(text, shown, RosToolError)
    if not isinstance(document, dict) or not _sets_parameters(document):
        raise RosToolError(f'{shown}: no node parameters in it: a parameters file maps node '
                           'names to ros__parameters (config/params/params_example.yaml)')


def _sets_parameters(document: dict, depth: int = 0) -> bool:
    """Whether some mapping of ``document`` (node names, namespaces) holds ros__parameters."""
    if isinstance(document.get('ros__parameters'), dict):
        return True
    return depth < 32 and any(isinstance(value, dict) and _sets_parameters(value, depth + 1)
                              for value in document.values())


def _end_with_parent(parent: int) -> None:
    """In a child before it runs: SIGTERM when the supervisor dies (Linux's PDEATHSIG)."""
    if sys.platform.startswith('linux'):
        import ctypes

        pr_set_pdeathsig = 1
        ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, signal.SIGTERM)
    if os.getppid() != parent:
        os._exit(143)   # the supervisor died before the request took effect


class Supervisor:
    """The children of one ``softseq ros rig`` and the stop signals that came."""

    def __init__(self, commands: dict[str, list[str]]) -> None:
        """Hold SIGINT and SIGTERM (restored by :meth:`close`), then start every child."""
        self.signals: list[int] = []
        self._previous = {signum: signal.signal(signum, self._note)
                          for signum in (signal.SIGINT, signal.SIGTERM)}
        self.children: dict[str, subprocess.Popen] = {}
        parent = os.getpid()
        try:
            for name, argv in commands.items():
                self.children[name] = subprocess.Popen(
                    argv, start_new_session=True, stdin=subprocess.DEVNULL,
                    preexec_fn=lambda: _end_with_parent(parent))
        except BaseException:
            self.close()
            raise

    def _note(self, signum: int, _frame: object) -> None:
        self.signals.append(signum)

    def ended(self) -> tuple[str, int] | None:
        """The first child that has ended by itself, with its exit code, or None."""
        for name, child in self.children.items():
            if child.poll() is not None:
                return name, child.returncode
        return None

    def wait(self) -> tuple[str, int] | None:
        """Until a stop signal or a child's end; the child that ended (None: a signal)."""
        while not self.signals:
            ended = self.ended()
            if ended is not None:
                return ended
            time.sleep(SUPERVISE_PERIOD_S)
        return None

    def stop(self) -> list[str]:
        """
        SIGINT to each running child, the rig first; what went wrong, one line each.

        A child that does not stop within STOP_TIMEOUT_S is killed (a killed recorder's bag
        is made readable by ``softseq recover``).
        """
        faults = []
        for name in reversed(list(self.children)):
            child = self.children[name]
            if child.poll() is not None:
                continue   # ended by itself: the caller has said so
            child.send_signal(signal.SIGINT)
            try:
                code = child.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()
                fix = '; softseq recover makes its bag readable' if name == RECORDER else ''
                faults.append(f'{name} did not stop within {seconds_text(STOP_TIMEOUT_S)} '
                              f'and was killed{fix}')
                continue
            if code != 0:
                faults.append(f'{name} ended with exit code {code}')
        return faults

    def close(self) -> None:
        """Kill what still runs (after a failure of this command) and restore the handlers."""
        for child in self.children.values():
            if child.poll() is None:
                child.kill()
                child.wait()
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)


def run_rig(namespace: str, params_file: Path | None, scene: str | None, record: Path | None,
            start_timeout_s: float | None = None) -> int:
    """
    Run the rig and its recorder until SIGINT/SIGTERM or until one of them ends.

    Exit 0 when stopped by a signal and both stopped cleanly; 2 when a child refused its
    configuration (exit 2: its one line above says why), else 1 when anything went wrong.
    With ``start_timeout_s``, the pump's ``~/start`` is called once the recorder records its
    commands (within that many seconds, else exit 1).
    """
    check_inputs(params_file, record, scene)
    supervisor = Supervisor(rig_commands(namespace, params_file, scene, record))
    try:
        where = f'into {record}' if record else ('into the folder of the parameters file, '
                                                 'else bags/rig_<UTC time>')
        print(f'softseq ros rig: rig and recorder in {namespace}, recording {where}; Ctrl-C '
              'stops both', file=sys.stderr)
        ended = None
        if start_timeout_s is not None:
            ended, fault = start_when_recorded(supervisor, namespace, start_timeout_s)
            if fault is not None:
                faults = supervisor.stop()
                for line in [fault, *faults]:
                    print(f'softseq ros rig: {line}', file=sys.stderr)
                return 1
        if ended is None:
            ended = supervisor.wait()
        faults = supervisor.stop()
    finally:
        supervisor.close()
    code = 0
    if ended is not None:
        name, child_code = ended
        faults.insert(0, f'{name} ended by itself with exit code {child_code}; the other was '
                      'stopped')
        code = 2 if child_code == 2 else 1
    for line in faults:
        print(f'softseq ros rig: {line}', file=sys.stderr)
    return code if code else (1 if faults else 0)


def start_when_recorded(supervisor: Supervisor, namespace: str,
                        timeout_s: float) -> tuple[tuple[str, int] | None, str | None]:
    """
    Call the pump's ``~/start`` once the recorder subscribes to its commands.

    Returns (the child that ended meanwhile, or None; what went wrong, or None). A stop
    signal meanwhile returns (None, None) without starting anything.
    """
    from rclpy.node import Node
    from std_srvs.srv import Trigger

    from softseq_ros.ros_tools.session import Session

    with Session(namespace, timeout_s) as session:
        node: Node = session.node
        commands = session.resolve('pump/command')

        def recorded() -> bool:
            return any(info.node_name == RECORDER and info.node_namespace == namespace
                       for info in node.get_subscriptions_info_by_topic(commands))

        while not supervisor.signals:
            ended = supervisor.ended()
            if ended is not None:
                return ended, None
            if recorded():
                break
            if session.left_s() <= 0.0:
                return None, (f'the recorder did not record {commands} within '
                              f'{seconds_text(timeout_s)}; the pump was not started')
            time.sleep(SUPERVISE_PERIOD_S)
        else:
            return None, None
        start = session.resolve('syringe_pump/start')
        try:
            response = session.call(Trigger, start, Trigger.Request())
        except RosToolError as err:
            return None, str(err)
    if not response.success:
        return None, f'{start} refused: {response.message}'
    print(f'softseq ros rig: {start}: {response.message or "started"}', file=sys.stderr)
    return None, None
