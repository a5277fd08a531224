"""Progress lines: rewritten in place on a terminal, plain lines in a log file."""

import os
import select

from softseq_ros.progress import end_progress, write_progress


def test_a_log_file_gets_one_plain_line_per_update(tmp_path):
    log = tmp_path / 'fem.log'
    with log.open('w') as stream:
        for step in range(3):
            write_progress(stream, f'step {step}')
        end_progress(stream)
    assert log.read_text() == 'step 0\nstep 1\nstep 2\n'


def test_a_terminal_gets_its_line_rewritten_and_ended_once():
    controller, terminal = os.openpty()
    try:
        with os.fdopen(terminal, 'w', closefd=False) as stream:
            assert stream.isatty()
            for step in range(3):
                write_progress(stream, f'step {step}')
            end_progress(stream)
        # The terminal turns \n into \r\n on output, and may hand it over in pieces.
        expected = b'\rstep 0\rstep 1\rstep 2\r\n'
        seen = b''
        while len(seen) < len(expected) and select.select([controller], [], [], 10.0)[0]:
            seen += os.read(controller, 1024)
        assert seen == expected
    finally:
        os.close(controller)
        os.close(terminal)
