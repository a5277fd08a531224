"""
Commands given what they cannot use, stopped or killed while they wait: play, info, report,
rates, recover.

Each refusal is one line naming the option, file or field and what is wrong, exit 2, before
anything is published or run; a FIFO is refused without blocking; a stop signal is 130 or 143
and loses nothing; a killed command takes its workers with it.
"""

import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time

from mcap.reader import make_reader
import pytest
import rosbags.rosbag2
from rosbags.rosbag2 import Reader
from scenes import fast_asymmetric
from sensor_msgs.msg import JointState

import softseq_ros
from softseq_ros import cli
from softseq_ros.bag.forms import serialize
from softseq_ros.bag.recovery import recover
from softseq_ros.bag.writer import BagWriter

TIMEOUT_S = 120


def softseq(*args: str, timeout: float = TIMEOUT_S, **options) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'softseq_ros.cli', *args], capture_output=True,
                          text=True, timeout=timeout, stdin=subprocess.DEVNULL, **options)


def one_line(result: subprocess.CompletedProcess, command: str) -> str:
    """The one line of a refusal (exit 2), without a traceback or a warning around it."""
    assert result.returncode == 2, result.stderr
    line, = result.stderr.strip().splitlines()
    assert line.startswith(f'softseq {command}: error: '), line
    return line


@pytest.fixture(scope='module')
def small_bag(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp('hostile')
    scene = fast_asymmetric(folder, 'hostile', pump_rate_hz=20, camera_rate_hz=2,
                            triggers=(2.5e-5,))
    softseq_ros.run(scene, folder / 'bag')
    return folder / 'bag'


def _recorded(bag: Path, topic: str) -> list[bytes]:
    with open(next(bag.glob('*.mcap')), 'rb') as stream:
        return [bytes(message.data) for _, _, message in make_reader(stream).iter_messages(
            topics=[topic], log_time_order=True)]


# ------------------------------------------------------------------------ softseq play --remap

COMMAND, VOLUMES = '/pump/command', '/actuator/volumes'
SWAP = ('--remap', f'{COMMAND}:={VOLUMES}', '--remap', f'{VOLUMES}:={COMMAND}')


def _heard_while(context, play) -> dict[str, list[bytes]]:
    """What a listener on /pump/command and /actuator/volumes hears while ``play()`` runs."""
    from rclpy.node import Node
    from rclpy.qos import QoSProfile

    from softseq_ros.testing import spinning

    listener = Node('swap_listener', context=context)
    got: dict[str, list[bytes]] = {COMMAND: [], VOLUMES: []}
    lock = threading.Lock()
    for topic in got:
        def keep(data, topic=topic) -> None:
            with lock:
                got[topic].append(bytes(data))
        listener.create_subscription(JointState, topic, keep, QoSProfile(depth=10000),
                                     raw=True)
    with spinning(context, listener):
        expected = play()
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and any(
                len(got[t]) < len(expected[t]) for t in got):
            time.sleep(0.05)
    return got


def _swapped(bag: Path) -> dict[str, list[bytes]]:
    return {COMMAND: _recorded(bag, VOLUMES), VOLUMES: _recorded(bag, COMMAND)}


@pytest.mark.ros
def test_remap_swaps_two_topics_and_never_reaches_rcl(context, small_bag, ros_env):
    # rcl took each FROM:=TO of --remap for a remap rule of its own: it warned that the syntax
    # is deprecated and mapped the player's new names back, so a swap was silently undone.
    results = []

    def play() -> dict[str, list[bytes]]:
        results.append(softseq('play', str(small_bag), '--rate', '20', '--topics', COMMAND,
                               VOLUMES, '--wait-for-subscribers', '30', *SWAP, env=ros_env))
        return _swapped(small_bag)

    got = _heard_while(context, play)
    result, = results
    assert result.returncode == 0, result.stderr
    assert got == _swapped(small_bag)       # each recorded topic under the other's name
    # rcl saw no remap rule: it warned on each that the syntax is deprecated.
    assert 'remap' not in result.stderr.lower() and 'deprecated' not in result.stderr, \
        result.stderr


PLAY_WITH_ITS_COMMAND_LINE = """
import sys
from softseq_ros.nodes.player import parse_remaps, play
words = sys.argv[2:]
remaps = parse_remaps([words[i + 1] for i, word in enumerate(words) if word == '--remap'])
play(sys.argv[1], rate=20.0, topics=['/pump/command', '/actuator/volumes'], wait_s=30.0,
     args=sys.argv, remap=remaps)
"""


@pytest.mark.ros
def test_a_command_line_handed_to_play_gives_rcl_none_of_its_remap_words(context, small_bag,
                                                                         ros_env, tmp_path):
    # play(args=sys.argv) passed the whole command line to rclpy.init: rcl took the FROM:=TO
    # words for its own remap rules and undid the player's swap. Its --ros-args still reach
    # rcl (a log level here).
    script = tmp_path / 'player.py'
    script.write_text(PLAY_WITH_ITS_COMMAND_LINE)
    results = []

    def play() -> dict[str, list[bytes]]:
        results.append(subprocess.run(
            [sys.executable, str(script), str(small_bag), *SWAP, '--ros-args', '--log-level',
             'warn'], capture_output=True, text=True, timeout=TIMEOUT_S,
            stdin=subprocess.DEVNULL, env=ros_env))
        return _swapped(small_bag)

    got = _heard_while(context, play)
    result, = results
    assert result.returncode == 0, result.stderr
    assert got == _swapped(small_bag)
    assert 'deprecated' not in result.stderr, result.stderr


@pytest.mark.ros
def test_two_topics_of_different_types_onto_one_name_are_refused_in_one_line(small_bag,
                                                                              ros_env):
    # It used to end in rclpy's traceback from create_publisher.
    line = one_line(softseq('play', str(small_bag), '--remap', '/actuator/pressure:=/x',
                            '--remap', '/pump/command:=x', env=ros_env), 'play')
    assert '/x would carry /actuator/pressure (sensor_msgs/msg/FluidPressure) and ' \
        '/pump/command (sensor_msgs/msg/JointState)' in line
    assert '--remap /actuator/pressure:=/x --remap /pump/command:=x' in line


@pytest.mark.ros
@pytest.mark.parametrize('topic, owner', [
    ('/rosout', "the player's log (rcl_interfaces/msg/Log)"),
    ('/parameter_events', "the player's parameter events (rcl_interfaces/msg/ParameterEvent)"),
])
def test_a_topic_remapped_onto_a_topic_of_the_players_node_is_refused_in_one_line(
        small_bag, ros_env, topic, owner):
    # The player's node publishes on these itself: rclpy's traceback from create_publisher
    # ("incompatible type"), exit 1.
    line = one_line(softseq('play', str(small_bag), '--remap', f'/pump/command:={topic}',
                            env=ros_env), 'play')
    assert line == (f'softseq play: error: --remap /pump/command:={topic}: {topic} would carry '
                    f'{owner} and /pump/command (sensor_msgs/msg/JointState); a topic has one '
                    'type')


def test_a_recorded_topic_of_another_type_on_the_players_log_is_refused_naming_the_bag(
        tmp_path):
    from std_msgs.msg import String

    from softseq_ros.nodes.player import BagPlayer, PlayError

    bag = tmp_path / 'bag'
    with BagWriter(bag, flush_period_s=None) as writer:
        writer.add_topic('/rosout', 'std_msgs/msg/String')
        writer.write('/rosout', serialize(String(data='a log line')), 1_700_000_000_000_000_000)
    with pytest.raises(PlayError, match=rf"^{bag}: /rosout would carry the player's log "
                       r'\(rcl_interfaces/msg/Log\) and /rosout \(std_msgs/msg/String\)'):
        BagPlayer(str(bag))


def test_a_recorded_clock_of_another_type_is_refused_with_clock(tmp_path):
    from std_msgs.msg import String

    from softseq_ros.nodes.player import BagPlayer, PlayError

    with BagWriter(tmp_path / 'bag', flush_period_s=None) as writer:
        writer.add_topic('/clock', 'std_msgs/msg/String')
        writer.write('/clock', serialize(String(data='tick')), 1_700_000_000_000_000_000)
    with pytest.raises(PlayError, match=r'^--clock: /clock would carry the bag time of --clock '
                       r'\(rosgraph_msgs/msg/Clock\) and /clock \(std_msgs/msg/String\)'):
        BagPlayer(str(tmp_path / 'bag'), clock=True)


# ----------------------------------------------------- softseq play: QoS overrides and offset

@pytest.mark.ros
@pytest.mark.parametrize('content, reason', [
    (b'/pump/command:\n  reliability: r\xe9liable\n', 'not UTF-8 text (byte 31)'),
    (b'[' * 100_000, 'YAML nested too deeply'),
    (b'/pump/command:\n  depth: 1' + b'0' * 30 + b'\n',
     'depth: expected an integer >= 0 and <= 2147483647 (a DDS history depth is 32 bits), '
     'got an integer of 31 digits'),
    (b'/pump/command:\n  deadline: {sec: 1' + b'0' * 30 + b', nsec: 0}\n',
     'deadline: an integer of 31 digits s and 0 ns is beyond the longest QoS duration'),
    (b'/pump/command:\n  lifespan: {sec: 9223372037}\n',
     'lifespan: 9223372037 s and 0 ns is beyond the longest QoS duration'),
    (b'/pump/command:\n  depth: 1' + b'0' * 5000 + b'\n', 'YAML: a value cannot be read'),
], ids=['latin1', 'nested', 'depth_1e30_as_integer', 'deadline_1e30_s',
        'lifespan_beyond_int64_ns', 'integer_of_5000_digits'])
def test_play_refuses_a_qos_file_it_cannot_use_in_one_line(small_bag, tmp_path, ros_env,
                                                           content, reason):
    overrides = tmp_path / 'qos.yaml'
    overrides.write_bytes(content)
    line = one_line(softseq('play', str(small_bag), '--qos-profile-overrides-path',
                            str(overrides), env=ros_env), 'play')
    assert f'{overrides}: ' in line and reason in line, line


@pytest.mark.ros
def test_play_refuses_a_fifo_as_qos_file_without_blocking(small_bag, tmp_path, ros_env):
    # open() of a FIFO blocks until a writer comes, and play holds SIGINT and SIGTERM meanwhile.
    fifo = tmp_path / 'qos.yaml'
    os.mkfifo(fifo)
    line = one_line(softseq('play', str(small_bag), '--qos-profile-overrides-path', str(fifo),
                            env=ros_env, timeout=60), 'play')
    assert f'{fifo}: cannot read the QoS overrides (a FIFO, not a regular file)' in line


@pytest.mark.ros
def test_play_refuses_a_start_offset_of_1e300_s_in_one_line(small_bag, ros_env):
    # 1e300 s is no integer of nanoseconds: an OverflowError's traceback.
    line = one_line(softseq('play', str(small_bag), '--start-offset', '1e300', env=ros_env),
                    'play')
    assert "start offset 1e+300 s is past the bag's end (5 s after its start)" in line


# ------------------------------------------------------------------------- softseq recover

def test_sigterm_during_recovers_read_back_exits_143_and_loses_nothing(tmp_path, monkeypatch,
                                                                       capsys):
    bag = tmp_path / 'bag'
    with BagWriter(bag, compression='zstd', flush_period_s=None) as writer:
        writer.add_topic('/actuator/volumes', 'sensor_msgs/msg/JointState')
        for i in range(200):
            msg = JointState()
            msg.position = [1e-6 * i]
            writer.write('/actuator/volumes', serialize(msg), 1_700_000_000_000_000_000 + i)
    (bag / 'metadata.yaml').unlink()
    before = {p.name: p.read_bytes() for p in bag.iterdir()}

    class StoppedReader(Reader):
        """rosbags' reader, with SIGTERM arriving as it opens the recovered bag."""

        def __init__(self, *args, **kwargs) -> None:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)     # the handler raises here
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(rosbags.rosbag2, 'Reader', StoppedReader)
    assert cli.main(['recover', str(bag)]) == 143
    assert capsys.readouterr().err.strip() == 'softseq recover: terminated'
    # Nothing lost: the file is as it was, and the next recover completes.
    assert (bag / 'bag_0.mcap').read_bytes() == before['bag_0.mcap']
    monkeypatch.undo()
    assert cli.main(['recover', str(bag)]) == 0
    with Reader(bag) as reader:
        assert sum(1 for _ in reader.messages()) == 200


# softseq recover, with a pause at one step of the recovery: it says where it is and waits for
# a line on stdin, so the test's signal arrives there. A stop the recovery holds (it acts once
# the step is over) lets the pause end when the line comes.
RECOVER_WITH_A_PAUSE = """
import os, sys
from softseq_ros import cli
from softseq_ros.bag import recovery

step, bag = sys.argv[1:]

def pause():
    print('at', step, flush=True)
    sys.stdin.readline()

def before(function):
    def paused(*args, **kwargs):
        pause()
        return function(*args, **kwargs)
    return paused

if step == 'copy':
    copy, copied = recovery._Copier.copy, []
    def copy_pausing(self, record):
        copied.append(record)
        if len(copied) == 100:
            pause()
        return copy(self, record)
    recovery._Copier.copy = copy_pausing
elif step == 'rename':
    replace = os.replace
    def replace_pausing(source, target):
        replace(source, target)
        if str(target).endswith('.truncated'):
            pause()
    os.replace = replace_pausing
elif step == 'mcap_read_back':
    recovery._verify_file = before(recovery._verify_file)
elif step == 'rosbags_read_back':
    recovery._verify = before(recovery._verify)
sys.exit(cli.main(['recover', bag]))
"""


def _killed_recording(folder: Path, messages: int = 2000) -> tuple[Path, bytes]:
    """A bag cut in its last chunks without metadata.yaml, as a SIGKILL leaves it."""
    bag = folder / 'bag'
    with BagWriter(bag, flush_period_s=None) as writer:
        writer.add_topic('/actuator/volumes', 'sensor_msgs/msg/JointState')
        for i in range(messages):
            msg = JointState()
            msg.position = [1e-6 * i]
            writer.write('/actuator/volumes', serialize(msg), 1_700_000_000_000_000_000 + i)
            if i % 100 == 99:
                writer.flush()
    (bag / 'metadata.yaml').unlink()
    path = bag / 'bag_0.mcap'
    path.write_bytes(path.read_bytes()[:path.stat().st_size * 4 // 5])
    return bag, path.read_bytes()


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
@pytest.mark.parametrize('step', ['copy', 'mcap_read_back', 'rename', 'rosbags_read_back'])
def test_a_signal_at_any_step_of_recover_exits_128_plus_it_and_leaves_nothing_worse(
        tmp_path, step, signum):
    # A stop while the recovered copy was written or read back left the copy behind
    # (bag_0.mcap.recovering); one between setting the original aside and the copy taking its
    # name left the bag without its .mcap file.
    bag, original = _killed_recording(tmp_path)
    reference = tmp_path / 'reference'
    reference.mkdir()
    (reference / 'bag_0.mcap').write_bytes(original)
    intact = recover(reference).message_count
    script = tmp_path / 'recover.py'
    script.write_text(RECOVER_WITH_A_PAUSE)
    child = subprocess.Popen([sys.executable, str(script), step, str(bag)],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline() == f'at {step}\n', child.stderr.read()
        child.send_signal(signum)
        out, err = child.communicate('\n', timeout=TIMEOUT_S)
    finally:
        child.kill()
    assert child.returncode == 128 + signum, err
    stopped = 'interrupted' if signum == signal.SIGINT else 'terminated'
    assert err == f'softseq recover: {stopped}\n'
    # Nothing worse than before: no half-written file, the bag's .mcap in its place, the
    # original's bytes kept, and the next recover completes.
    names = sorted(p.name for p in bag.iterdir())
    assert not [name for name in names if name.endswith(('.recovering', '.tmp'))], names
    assert 'bag_0.mcap' in names
    kept = bag / ('bag_0.mcap.truncated' if 'bag_0.mcap.truncated' in names else 'bag_0.mcap')
    assert kept.read_bytes() == original
    assert recover(bag).message_count == intact
    with Reader(bag) as reader:
        assert sum(1 for _ in reader.messages()) == intact


# ---------------------------------------------------------------------------- softseq info

def _metadata_with(bag: Path, folder: Path, key: str, value: str) -> Path:
    """A copy of ``bag`` whose metadata.yaml gives ``key`` (a leaf) ``value`` as text."""
    copy = folder / 'bag'
    copy.mkdir()
    for file in bag.iterdir():
        if file.is_file():
            (copy / file.name).write_bytes(file.read_bytes())
    lines = (copy / 'metadata.yaml').read_text().splitlines()
    at = next(i for i, line in enumerate(lines) if line.strip().startswith(f'{key}:'))
    lines[at] = lines[at].split(':')[0] + f': {value}'
    (copy / 'metadata.yaml').write_text('\n'.join(lines) + '\n')
    return copy


@pytest.mark.parametrize('value, reason', [
    ('1' + '0' * 30, 'starting_time.nanoseconds_since_epoch: an integer of 31 digits is '
     'outside what a bag can carry: from 0 to 9223372036854775807 ns'),
    ('-1', 'starting_time.nanoseconds_since_epoch: -1 is outside what a bag can carry'),
], ids=['start_1e30_ns', 'start_negative'])
def test_info_refuses_a_start_time_no_bag_can_carry_in_one_line(small_bag, tmp_path, value,
                                                                 reason):
    # 1e30 ns was an OverflowError's traceback from datetime; -1 ns was shown as 1969.
    bag = _metadata_with(small_bag, tmp_path, 'nanoseconds_since_epoch', value)
    line = one_line(softseq('info', str(bag)), 'info')
    assert f'{bag / "metadata.yaml"}: {reason}' in line, line


@pytest.mark.parametrize('command', ['info', 'report'])
def test_a_metadata_file_nested_too_deeply_is_one_line(small_bag, tmp_path, command):
    # info ended in a RecursionError's traceback; report crashed in libyaml (SIGSEGV).
    bag = _metadata_with(small_bag, tmp_path, 'version', '1')
    (bag / 'metadata.yaml').write_text('[' * 100_000)
    line = one_line(softseq(command, str(bag), *(['--out', str(tmp_path / 'report')]
                                                 if command == 'report' else [])), command)
    assert f"{bag / 'metadata.yaml'}: YAML nested too deeply" in line, line
    assert not (tmp_path / 'report').exists()


@pytest.mark.parametrize('where', ['the_path_given', 'in_the_bag_folder'])
def test_info_refuses_a_fifo_named_like_a_bag_file_without_blocking(tmp_path, where):
    # A FIFO named x.mcap in a bag folder blocked info for ever; given itself, it was said to
    # be "no such bag folder".
    folder = tmp_path / 'bag'
    folder.mkdir()
    fifo = (folder if where == 'in_the_bag_folder' else tmp_path) / 'x.mcap'
    os.mkfifo(fifo)
    line = one_line(softseq('info', str(folder if where == 'in_the_bag_folder' else fifo),
                            timeout=60), 'info')
    assert f'{fifo}: a FIFO, not' in line, line



@pytest.mark.parametrize('command', ['recover', 'report', 'compare'])
def test_other_readers_refuse_a_fifo_in_the_bag_folder_without_blocking(tmp_path, command):
    # recover opened it (to see whether a writer holds its lock) and waited for ever.
    folder = tmp_path / 'bag'
    folder.mkdir()
    os.mkfifo(folder / 'x.mcap')
    line = one_line(softseq(command, str(folder), *([str(folder)] if command == 'compare'
                                                    else []), timeout=60), command)
    assert f'{folder / "x.mcap"}: a FIFO, not a regular file: not a bag file' in line, line

# --------------------------------------------------------------- softseq report killed (-9)

def _children(pid: int) -> set[int]:
    """The processes whose parent is ``pid``, from /proc."""
    found = set()
    for entry in Path('/proc').iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / 'stat').read_text().rpartition(')')[2].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                found.add(int(entry.name))
    return found


def _alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie nobody reaped yet has ended)."""
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rpartition(')')[2].split()[0]
    except OSError:
        return False
    return state != 'Z'


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='reads /proc')
@pytest.mark.skipif((os.cpu_count() or 1) <= 1, reason='on one core report forks no worker')
def test_a_report_killed_with_sigkill_takes_its_figure_worker_with_it(small_bag, tmp_path):
    # The forked worker waited for jobs on a pipe it holds both ends of: after a kill -9 of
    # the report it lived on for ever, holding the caller's stdout and stderr open.
    report = subprocess.Popen([sys.executable, '-m', 'softseq_ros.cli', 'report',
                               str(small_bag), '--out', str(tmp_path / 'report')],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              stdin=subprocess.DEVNULL)
    workers: set[int] = set()
    try:
        deadline = time.monotonic() + 60
        while not workers and report.poll() is None and time.monotonic() < deadline:
            workers = _children(report.pid)
            time.sleep(0.01)
        assert workers, 'the report forked no figure worker'
        report.kill()
        report.wait(timeout=30)
        # The caller's pipes end: nothing holds them any more.
        ended = threading.Thread(target=report.communicate, daemon=True)
        ended.start()
        ended.join(timeout=10)
        assert not ended.is_alive(), "the report's pipes are still held open"
        deadline = time.monotonic() + 10
        while any(map(_alive, workers)) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not any(map(_alive, workers)), f'workers {workers} outlived the report'
    finally:
        for pid in workers:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
        if report.poll() is None:
            report.kill()


# --------------------------------------------------------------------------- softseq rates

@pytest.mark.parametrize('options, message', [
    (['--scheduler', 'not a scheduler'], "--scheduler: 'not a scheduler' is not the address "
     "of a Dask scheduler (missing port number in address 'not a scheduler'), e.g. "
     'tcp://10.0.0.5:8786'),
    (['--samples', '1000000000'], '--samples: must be <= 100000 (samples of the path per leg'),
    (['--out', '{file}/map'], '--out {file}/map: {file} is a regular file, not a folder'),
], ids=['scheduler_no_address', 'samples_1e9', 'out_under_a_file'])
def test_rates_refuses_options_it_cannot_use_before_the_grid_runs(tmp_path, capsys,
                                                                  monkeypatch, options,
                                                                  message):
    # The scheduler was a traceback from distributed once the grid was to run; --out under a
    # file was refused only after the whole grid had run; 1e9 samples grew to 24 GB.
    import softseq_ros.analysis.rates as rates

    def ran(*_args, **_kwargs):
        raise AssertionError('the grid ran before the options were checked')
    monkeypatch.setattr(rates, 'run_rates', ran)
    monkeypatch.setattr(rates, 'quasistatic_reference', ran)
    blocker = tmp_path / 'a_file'
    blocker.write_text('not a folder\n')
    options = [option.format(file=blocker) for option in options]
    if '--out' not in options:
        options += ['--out', str(tmp_path / 'map')]
    assert cli.main(['rates', 'rate_inversion', '--flows', '1e-7', '--radii', '2e-4',
                     *options]) == 2
    line, = capsys.readouterr().err.strip().splitlines()
    assert line.startswith('softseq rates: error: ' + message.format(file=blocker)), line
    assert not (tmp_path / 'map').exists()


# --------------------------------------------------------------------------- softseq graph

def _wiggly_scene(folder: Path, folds: int) -> Path:
    """Three table segments whose curves each rise through ``folds`` peaks and valleys."""
    import math

    names = []
    for s in range(3):
        rows = ['volume_m3,pressure_pa,curvature_per_m']
        count = 60 * folds + 40
        for i in range(count + 1):
            x = i / count
            pressure = (1000 + 4000 * x + 1.8 * 4000 / (2 * math.pi * folds)
                        * math.sin(2 * math.pi * folds * x + 0.3 * s))
            rows.append(f'{1e-5 + 4e-5 * x:.9e},{pressure:.6f},{10 * x:.6f}')
        (folder / f'wiggle{s}.csv').write_text('\n'.join(rows) + '\n')
        names.append(f'  - name: s{s}\n    length_m: 0.1\n    table: wiggle{s}.csv\n')
    scene = folder / 'wiggles.yaml'
    scene.write_text('name: wiggles\nsegments:\n' + ''.join(names) + 'pump:\n'
                     '  flow_rate_m3_per_s: 1.0e-6\n  rate_hz: 10\n  legs:\n'
                     '    - inflate_to_m3: 2.0e-5\n    - deflate_to_m3: 0.0\n')
    return scene


def test_graph_refuses_a_graph_too_large_to_draw_before_writing_anything(tmp_path, capsys,
                                                                         monkeypatch):
    # Three segments of dozens of folds: graph.json was written, then the figure ran for
    # minutes and died of a MemoryError.
    import softseq_ros.analysis.graph_figure as graph_figure
    import softseq_ros.quasistatic.graph as quasistatic_graph

    def drew(*_args, **_kwargs):
        raise AssertionError('graph wrote or drew before refusing')
    monkeypatch.setattr(graph_figure, 'plot_graph', drew)
    monkeypatch.setattr(quasistatic_graph, 'write_graph_json', drew)
    scene = _wiggly_scene(tmp_path, 20)
    out = tmp_path / 'graph'
    assert cli.main(['graph', str(scene), '--out', str(out)]) == 2
    line, = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f'softseq graph: error: {scene}: 361 stable branches, more than '
                           'the 300 that graph.png can show'), line
    assert not out.exists()


# -------------------------------------------------------------------------- softseq design

def test_design_refuses_a_search_of_a_million_before_it_starts(tmp_path, capsys, monkeypatch):
    # A population of 1e6 was taken: 5 million pairs at 0.2 s each.
    import softseq_ros.fem.design_command as design_command

    def searched(*_args, **_kwargs):
        raise AssertionError('the search started')
    monkeypatch.setattr(design_command, 'search', searched)
    tiny = Path(__file__).resolve().parents[1] / 'config' / 'design_targets' / 'tiny.yaml'
    problem = tmp_path / 'big.yaml'
    problem.write_text(tiny.read_text().replace('population: 4', 'population: 1000000'))
    out = tmp_path / 'designs'
    assert cli.main(['design', str(problem), '--out', str(out)]) == 2
    line, = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f'softseq design: error: {problem}: search: population 1000000 x 1 '
                           'varied parameters (a population of 1048576 with the Sobol start) '
                           'x 5 generations'), line
    assert '= 5242880 pairs to assemble, more than 20000' in line
    assert not out.exists()
