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
