"""
A file a command reads that is no regular file: a FIFO, a folder, a file it may not read.

A FIFO nobody writes blocked ``open`` for ever (past Ctrl-C of a caller that held it): every
reader of a user's file goes through :func:`softseq_ros.errors.read_regular_file`, and the
command refuses in one line naming the file and what it is. The adversarial suite's file
class (bench/bench_adversarial.py) tries every file argument of every command so.
"""

from contextlib import contextmanager
import os
from pathlib import Path
import re
import signal
from typing import Iterator

import pytest

from softseq_ros import cli
from softseq_ros.analysis.report import ReferenceFileError, load_reference
from softseq_ros.bag.layout import read_metadata
from softseq_ros.errors import UserError
from softseq_ros.scene.csv_columns import read_rows

CONFIG = Path(__file__).resolve().parent.parent / 'config'


class StillWaiting(BaseException):
    """Not an OSError: the command's own handler must not take it for a refusal."""


@contextmanager
def within(seconds: int) -> Iterator[None]:
    """Fail, instead of hanging, when the block still waits after ``seconds``."""
    def alarm(_signum: int, _frame: object) -> None:
        raise StillWaiting(f'still waiting on the file after {seconds} s')
    previous = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def _one_line(capsys: pytest.CaptureFixture, argv: list[str]) -> str:
    with within(20):
        code = cli.main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and 'Traceback' not in err, err
    return lines[0]


def test_a_fifo_as_a_csv_input_is_refused_naming_it(tmp_path, capsys):
    fifo = tmp_path / 'history.csv'
    os.mkfifo(fifo)
    line = _one_line(capsys, ['solve', 'fig1_none', '--path', str(fifo),
                              '--out', str(tmp_path / 'p.csv')])
    assert line == (f'softseq solve: error: {fifo}: the volume history is a FIFO, not a '
                    'regular file')
    # Every CSV reader of the package reads through the same function.
    with within(20), pytest.raises(UserError, match='the experiment file is a FIFO'):
        read_rows(fifo, UserError, 'experiment file', ('injected_m3',))


def test_a_fifo_or_a_folder_given_as_a_scene_is_named_for_what_it_is(tmp_path, capsys):
    fifo = tmp_path / 'scene.yaml'
    os.mkfifo(fifo)
    # It was "scene file not found", for a file that is there.
    assert _one_line(capsys, ['classify', str(fifo)]) == (
        f'softseq classify: error: {fifo}: a FIFO, not a regular file: not a scene file')
    assert _one_line(capsys, ['classify', str(tmp_path)]) == (
        f'softseq classify: error: {tmp_path}: a folder, not a regular file: not a scene file')


def test_a_fifo_as_a_yaml_input_is_refused_naming_it(tmp_path, capsys):
    fifo = tmp_path / 'problem.yaml'
    os.mkfifo(fifo)
    # The design problem is read by the scenes' YAML reader (designs too).
    line = _one_line(capsys, ['design', str(fifo), '--out', str(tmp_path / 'd')])
    assert line == f'softseq design: error: {fifo}: a FIFO, not a regular file'
    with within(20), pytest.raises(ReferenceFileError,
                                   match=f'{fifo}: the reference file is a FIFO, not a '
                                   'regular file'):
        load_reference(fifo)


def test_a_bags_metadata_yaml_that_is_a_fifo_is_refused_not_waited_on(tmp_path):
    (tmp_path / 'metadata.yaml').mkdir()
    with pytest.raises(UserError, match='metadata.yaml: a folder, not a regular file'):
        read_metadata(tmp_path, UserError)
    (tmp_path / 'metadata.yaml').rmdir()
    os.mkfifo(tmp_path / 'metadata.yaml')
    with within(20), pytest.raises(UserError, match='metadata.yaml: a FIFO, not a regular file'):
        read_metadata(tmp_path, UserError)


def test_an_unreadable_csv_input_is_refused_naming_it(tmp_path, capsys, monkeypatch):
    history = tmp_path / 'history.csv'
    history.write_text('injected_m3\n0\n1e-6\n')
    history.chmod(0)
    if hasattr(os, 'geteuid') and os.geteuid() == 0:
        # Root reads a file of mode 000 all the same: the system's refusal, as any other
        # user gets it, comes from the open itself.
        real_open = os.open

        def refusing_open(path, flags, *args, **kwargs):
            if os.fspath(path) == str(history):
                raise PermissionError(13, 'Permission denied', str(history))
            return real_open(path, flags, *args, **kwargs)

        monkeypatch.setattr(os, 'open', refusing_open)
    line = _one_line(capsys, ['solve', 'fig1_none', '--path', str(history),
                              '--out', str(tmp_path / 'p.csv')])
    assert line == (f'softseq solve: error: {history}: cannot read the volume history '
                    '(Permission denied)')


@pytest.mark.parametrize('name, data, says', [
    ('Latin-1', b'# Pr\xfcfstand\n/**:\n  ros__parameters:\n    rate_hz: 50\n',
     'not UTF-8 text (byte 4)'),
    ('nested', b'[' * 100_000 + b']' * 100_000, 'YAML nested too deeply'),
    ('one word', b'a' * 10_000, 'no node parameters in it'),
    ('empty', b'', 'no node parameters in it'),
    ('no ros__parameters', b'/rig1/syringe_pump:\n  rate_hz: 50\n', 'no node parameters in it'),
])
def test_a_params_file_no_node_could_take_is_refused_before_the_rig_starts(tmp_path, name,
                                                                          data, says):
    from softseq_ros.ros_tools.launcher import check_inputs
    from softseq_ros.ros_tools.session import RosToolError

    # Each started the rig, whose nodes then failed one by one or ran without the file.
    params = tmp_path / 'params.yaml'
    params.write_bytes(data)
    wanted = f'--params-file {re.escape(str(params))}: .*{re.escape(says)}'
    with pytest.raises(RosToolError, match=wanted):
        check_inputs(params, None)
    check_inputs(CONFIG / 'params' / 'params_example.yaml', None)
