"""The one parallel executor: job order, named failures, every backend alike, clean interrupts."""

import multiprocessing
import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from softseq_ros import parallel
from softseq_ros.errors import UserError
from softseq_ros.parallel import (
    FileJobError,
    JobError,
    UserJobError,
    Workers,
    run_jobs,
    worker_count,
)

SLOW_JOB_S = 60.0   # a job that a stop must not wait for

# Jobs are module-level functions: worker processes are spawned and import them by name.


def late_square(x: int) -> int:
    """x squared, the first jobs finishing last."""
    time.sleep(0.05 * (4 - x) if x < 4 else 0)
    return x * x


def inverse(x: float) -> float:
    return 1 / x


def refuse(x: int) -> int:
    if x == 2:
        raise UserError('table.csv: no pressure column')
    if x == 3:
        raise FileNotFoundError(2, 'No such file or directory', 'missing.csv')
    return x


def pid(_job: object) -> int:
    return os.getpid()


def nap(seconds: float) -> float:
    time.sleep(seconds)
    return seconds


def interrupt_myself(_job: object) -> str:
    # A Ctrl-C in a terminal signals the whole process group, workers too.
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.2)
    return 'still here'


def remember(value: str) -> None:
    os.environ['SOFTSEQ_TEST_WORKER'] = value


def remembered() -> str:
    return os.environ.get('SOFTSEQ_TEST_WORKER', '')


@pytest.mark.parametrize('backend', ['serial', 'processes'])
def test_results_come_back_in_job_order_and_progress_hears_of_each(backend):
    heard = []
    results = run_jobs(late_square, range(6), workers=2, backend=backend,
                       progress=lambda done, total, result: heard.append((done, total, result)))
    assert results == [0, 1, 4, 9, 16, 25]
    assert [(done, total) for done, total, _ in heard] == [(k, 6) for k in range(1, 7)]
    assert sorted(result for _, _, result in heard) == results


def test_serial_and_processes_give_the_same_results():
    jobs = [0.5, 2.0, -4.0, 1e-3]
    assert (run_jobs(inverse, jobs, backend='serial')
            == run_jobs(inverse, jobs, workers=2, backend='processes') == [1 / x for x in jobs])


@pytest.mark.parametrize('backend', ['serial', 'processes'])
def test_a_failing_job_names_itself(backend):
    with pytest.raises(JobError, match=r'^x=0: ZeroDivisionError: division by zero$') as caught:
        run_jobs(inverse, [1, 2, 0, 4], workers=2, backend=backend, name=lambda x: f'x={x}')
    assert caught.value.job_name == 'x=0' and caught.value.index == 2
    assert isinstance(caught.value.__cause__, ZeroDivisionError)
    # Without a namer a job is named by its place.
    with pytest.raises(JobError, match=r'^job 3 of 4: ZeroDivisionError'):
        run_jobs(inverse, [1, 2, 0, 4], workers=2, backend=backend)


@pytest.mark.parametrize('backend', ['serial', 'processes'])
def test_a_user_error_or_a_file_error_stays_one(backend):
    # The softseq command shows a UserError or OSError as one line: named, it still is one.
    with pytest.raises(UserJobError, match=r'^job 3 of 4: table.csv: no pressure column$') as err:
        # One failing job: with two, which fails first would depend on the machine's load.
        run_jobs(refuse, [0, 1, 2, 1], workers=2, backend=backend)
    assert isinstance(err.value, UserError) and isinstance(err.value.__cause__, UserError)
    with pytest.raises(FileJobError, match=r'^job 2 of 2: .*missing.csv') as err:
        run_jobs(refuse, [1, 3], workers=2, backend=backend)
    assert isinstance(err.value, OSError)


def test_one_worker_or_one_job_runs_here():
    here = os.getpid()
    assert run_jobs(pid, range(3), workers=1) == [here] * 3
    assert run_jobs(pid, ['only'], workers=2) == [here]
    assert run_jobs(pid, [], workers=2) == []
    elsewhere = run_jobs(pid, range(4), workers=2)
    assert here not in elsewhere and 1 <= len(set(elsewhere)) <= 2


def test_the_worker_count_is_capped_by_the_job_count(monkeypatch):
    assert worker_count(3, 8) == 3
    assert worker_count(10, 2) == 2
    assert worker_count(0, 4) == 1
    assert worker_count(100) == min(100, os.cpu_count() or 1)
    with pytest.raises(ValueError, match='workers must be >= 1'):
        worker_count(5, 0)
    started = []

    class Counted(Workers):
        def __init__(self, workers: int, **options) -> None:
            started.append(workers)
            super().__init__(workers, **options)

    monkeypatch.setattr(parallel, 'Workers', Counted)
    assert run_jobs(late_square, [4, 5], workers=8) == [16, 25]
    assert started == [2]


def test_a_bad_backend_or_a_scheduler_without_dask_is_refused():
    with pytest.raises(ValueError, match='backend must be one of'):
        run_jobs(pid, [1], backend='threads')
    with pytest.raises(ValueError, match='for the dask backend'):
        run_jobs(pid, [1], backend='processes', scheduler='tcp://127.0.0.1:8786')


def test_workers_ignore_sigint_and_leave_it_to_the_parent():
    assert run_jobs(interrupt_myself, range(2), workers=2) == ['still here'] * 2


def _interrupt_from_another_thread() -> None:
    # The system may hand a Ctrl-C to any thread of the process; the main thread must see it
    # all the same, while it waits for jobs.
    signal.pthread_kill(threading.get_ident(), signal.SIGINT)


def test_an_interrupt_stops_the_workers_at_once():
    # One job would take a minute: Ctrl-C must not wait for it, nor leave its process behind.
    timer = threading.Timer(1.5, _interrupt_from_another_thread)
    start = time.perf_counter()
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            run_jobs(nap, [0.1, SLOW_JOB_S], workers=2)
    finally:
        timer.cancel()
    # Well short of the minute the slow job takes, however loaded the machine.
    assert time.perf_counter() - start < SLOW_JOB_S / 2
    assert multiprocessing.active_children() == []


def test_a_failing_job_stops_the_others():
    start = time.perf_counter()
    with pytest.raises(JobError, match=r'^nap x: TypeError'):
        run_jobs(nap, [SLOW_JOB_S, 0.0, 'x'], workers=2,
                 name=lambda seconds: f'nap {seconds}')
    assert time.perf_counter() - start < SLOW_JOB_S / 2
    assert multiprocessing.active_children() == []


def test_kept_workers_run_an_initializer_and_calls_until_closed():
    with Workers(1, initializer=remember, initargs=('warm',), start_method='fork',
                 start_now=True) as workers:
        assert workers.apply(remembered) == 'warm'
        assert workers.apply(pid, (None,)) != os.getpid()
        with pytest.raises(ZeroDivisionError):
            workers.apply(inverse, (0,))
        # A job's own error leaves kept workers be.
        assert workers.run(inverse, [1, 2]) == [1.0, 0.5]
    with pytest.raises(RuntimeError, match='closed'):
        workers.apply(remembered)
    workers.close()  # twice is harmless
    assert multiprocessing.active_children() == []


def test_the_dask_backend_runs_on_a_local_cluster_of_two_workers():
    pytest.importorskip('distributed')
    results = run_jobs(late_square, range(5), workers=2, backend='dask')
    assert results == [0, 1, 4, 9, 16]
    with pytest.raises(JobError, match=r'^x=0: ZeroDivisionError') as caught:
        run_jobs(inverse, [1, 0], workers=2, backend='dask', name=lambda x: f'x={x}')
    assert caught.value.index == 1


def test_workers_spawn_and_no_figure_worker_forks_beside_another_python_thread():
    from softseq_ros.analysis.figure_workers import start_workers
    from softseq_ros.parallel import default_start_method

    release, started = threading.Event(), threading.Event()

    def wait() -> None:
        started.set()
        release.wait()

    helper = threading.Thread(target=wait)
    helper.start()
    started.wait()
    try:
        # Another thread may hold a lock that a forked child would inherit held.
        assert default_start_method() == 'spawn'
        assert start_workers() is None
    finally:
        release.set()
        helper.join()


def test_a_process_of_one_thread_forks_its_workers_and_its_figure_worker():
    probe = ('from softseq_ros.parallel import default_start_method\n'
             'from softseq_ros.analysis.figure_workers import start_workers, stop_workers\n'
             'method = default_start_method()\n'
             'workers = start_workers()\n'
             'print(method, workers is not None)\n'
             'stop_workers(workers)\n')
    done = subprocess.run([sys.executable, '-c', probe], capture_output=True, text=True,
                          timeout=120, check=True)
    expected = 'True' if (os.cpu_count() or 1) > 1 else 'False'
    assert done.stdout.split() == ['fork', expected]
