"""A batch run stopped by a signal keeps all it produced: its bag is a prefix of the whole run."""

import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from mcap.reader import make_reader
import pytest
from scenes import fast_asymmetric

import softseq_ros
from softseq_ros.stopping import TerminatedError
from softseq_ros.wire.contract import NS_PER_S

CONFIG = Path(__file__).resolve().parents[1] / 'config'
START_S = 1_795_000_000                 # 2026-11-18, the same start time for every run
START_NS = START_S * 10**9

Messages = dict[str, list[tuple[int, int, bytes]]]


def read_topics(bag: Path) -> Messages:
    """Every message of the bag by topic, as (log time, publish time, CDR bytes), in order."""
    topics: Messages = {}
    with open(next(bag.glob('*.mcap')), 'rb') as stream:
        for _, channel, message in make_reader(stream).iter_messages(log_time_order=True):
            topics.setdefault(channel.topic, []).append(
                (message.log_time, message.publish_time, bytes(message.data)))
    return topics


def assert_prefix(whole: Messages, stopped: Messages) -> None:
    """
    ``stopped`` holds, topic by topic, exactly what ``whole`` holds up to its last instant.

    Up to the stopped bag's last log time, not only up to each topic's own last message: a
    frame of an instant whose pump command is in the bag belongs in it too.
    """
    assert set(stopped) <= set(whole)
    last = max(message[0] for messages in stopped.values() for message in messages)
    assert last < max(message[0] for messages in whole.values() for message in messages), \
        'the run was not stopped before its end'
    for topic, messages in whole.items():
        expected = [message for message in messages if message[0] <= last]
        got = stopped.get(topic, [])
        assert len(got) == len(expected), (topic, len(got), len(expected))
        assert got == expected, topic


@pytest.fixture(scope='module')
def short_scene(tmp_path_factory) -> Path:
    """The Fig. 1 asymmetric pair over 5 s: pump 50 Hz, camera 10 Hz and three triggers."""
    return fast_asymmetric(tmp_path_factory.mktemp('scene'), 'short_asymmetric')


@pytest.fixture(scope='module')
def short_whole(short_scene, tmp_path_factory) -> Messages:
    out = tmp_path_factory.mktemp('whole') / 'whole'
    softseq_ros.run(short_scene, out, start_time_ns=START_NS)
    return read_topics(out)


@pytest.mark.parametrize('signum, raised', [(signal.SIGINT, KeyboardInterrupt),
                                            (signal.SIGTERM, TerminatedError)])
def test_a_signal_between_two_cores_of_one_instant_keeps_the_whole_instant(
        short_scene, short_whole, tmp_path, signum, raised):
    # The signal arrives while the pump ticks at 2 s, an instant at which the camera takes a
    # frame after the pump: the frame of that instant belongs in the bag with its command.
    at_ns = START_NS + 2 * NS_PER_S

    def wrap(label, function):
        if label != 'pump.tick':
            return function

        def tick(now):
            if now == at_ns:
                os.kill(os.getpid(), signum)
            return function(now)
        return tick

    out = tmp_path / 'stopped'
    with pytest.raises(raised):
        softseq_ros.run(short_scene, out, start_time_ns=START_NS, wrap=wrap)
    stopped = read_topics(out)
    assert stopped['/camera/backbone'][-1][0] == at_ns
    assert stopped['/pump/command'][-1][0] == at_ns
    assert_prefix(short_whole, stopped)


def softseq_run(out: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, '-m', 'softseq_ros.cli', 'run', 'paper',
                             '--out', str(out), '--start-time', str(START_S), '--quiet',
                             '--no-report', *extra],
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


@pytest.fixture(scope='module')
def paper_whole(tmp_path_factory) -> Messages:
    out = tmp_path_factory.mktemp('paper') / 'whole'
    process = softseq_run(out)
    _, stderr = process.communicate(timeout=600)
    assert process.returncode == 0, stderr
    return read_topics(out)


@pytest.mark.parametrize('signal_name, exit_code', [('SIGINT', 130), ('SIGTERM', 143)])
def test_softseq_run_stopped_by_a_signal_is_a_prefix_of_the_whole_run(
        paper_whole, tmp_path, signal_name, exit_code):
    out = tmp_path / 'stopped'
    process = softseq_run(out)
    try:
        mcap = out / 'stopped_0.mcap'
        deadline = time.monotonic() + 300
        # Signal once the run has written a few chunks, however slow the machine is.
        while not (mcap.exists() and mcap.stat().st_size > 3_000_000):
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, 'the run wrote nothing'
            time.sleep(0.05)
        process.send_signal(getattr(signal, signal_name))
        _, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == exit_code, stderr
    assert_prefix(paper_whole, read_topics(out))


def test_a_run_whose_pump_never_finishes_ends_after_its_programme_with_its_bag(tmp_path):
    # A rig that no longer says where it is (here: a pump whose programme never ends) ran on
    # forever; the run's own limits hold while it runs: it ends two ticks past the programme.
    import math

    import softseq_ros
    from softseq_ros.bag.reader import bag_summary

    def wrap(label, function):
        if label != 'pump.tick':
            return function
        pump = function.__self__

        def tick(now):
            pump.duration_s = math.inf
            return function(now)
        return tick

    result = softseq_ros.run('fig1_none', tmp_path / 'bag', start_time_ns=0, wrap=wrap)
    scene = softseq_ros.load_scene('fig1_none')
    duration = scene.pump.profile.duration()
    period = 1.0 / scene.pump.rate_hz
    assert duration < result.sim_duration_s <= duration + 3 * period
    assert result.pump_state == 'running'
    assert any('had not finished its' in line and 'the run ends here' in line
               for line in result.warnings)
    summary = bag_summary(tmp_path / 'bag')
    assert summary.topics['/pump/command'].message_count == result.message_counts['/pump/command']


def test_a_run_holds_its_message_limit_while_it_runs(tmp_path, monkeypatch):
    import softseq_ros
    from softseq_ros import batch

    # The estimate before the start says the bag fits; the count while running says it does not.
    monkeypatch.setattr(batch, 'MAX_RUN_MESSAGES', 10_000)
    monkeypatch.setattr(batch, 'COUNT_CHECK_NS', 10**9)
    monkeypatch.setattr(batch._BatchRun, 'estimate', lambda self: (0.0, 0.0))
    result = softseq_ros.run('fig1_none', tmp_path / 'bag', start_time_ns=0, by_blocks=False)
    written = sum(result.message_counts.values())
    assert 10_000 < written < 10_000 + 2 * 1000     # at most a second of rig time past it
    assert any('more than 1e+04' in line for line in result.warnings)
