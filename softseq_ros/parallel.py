"""
Jobs in parallel, one way for the whole package: here, in worker processes or on Dask.

:func:`run_jobs` calls one function on every job of a list and returns the results in job
order, whatever order they finish in; ``progress`` hears of each as it finishes (in this
process, so it may write files). The backends:

- ``'serial'``: one after the other in this process; also what one job or one worker gets.
- ``'processes'``: worker processes on this machine, at most one per job, started by
  :func:`default_start_method`: ``fork`` (no interpreter to start, nothing to import again)
  where no other thread of this process runs Python, so no lock can be held by a thread the
  child would lack; ``spawn`` (a fresh interpreter) otherwise, or where there is no fork. The
  function must be importable (a module's top-level function) and the jobs picklable.
- ``'dask'``: a Dask cluster (``distributed``): the scheduler at ``scheduler`` (its workers,
  for studies that outgrow one machine), or else a ``LocalCluster`` of ``workers`` processes
  with one thread each, started for the call and closed after it.

A job that raises ends the call: the other jobs are dropped, the workers stopped, and a
:class:`JobError` names the job, with the job's own exception as its ``__cause__``. A job's
:class:`~softseq_ros.errors.UserError` (input it refused) or ``OSError`` (a file) comes back as
a JobError that is one as well (:class:`UserJobError`, :class:`FileJobError`), so the
``softseq`` command still shows it as one line. KeyboardInterrupt (or any other exception
raised while waiting) stops the workers at once, running jobs too, and goes on up; the workers
ignore SIGINT themselves, so a Ctrl-C in a terminal is handled once, here.

:class:`Workers` keeps worker processes for several calls (the report's figure worker, which
is forked before there is anything to draw). This module imports nothing heavy, and nothing of
the package but its errors: every layer may use it.
"""

from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
from typing import Any, Callable, Iterable, Sequence

from softseq_ros.errors import UserError

BACKENDS = ('serial', 'processes', 'dask')
DASK_CONNECT_TIMEOUT = '10s'
POLL_S = 0.2  # how long an interrupt may wait to be seen while jobs run
STOP_TIMEOUT_S = 5.0  # a stopped worker still alive after this is killed

# progress(done, total, result): called in this process as each job finishes.
Progress = Callable[[int, int, Any], None]
# name(job): how an error names a job (default: "job 3 of 9").
Namer = Callable[[Any], str]


def default_start_method() -> str:
    """
    ``fork`` where it is available and no other thread runs Python here; ``spawn`` otherwise.

    Every thread that runs Python counts, also one started without :mod:`threading` (pytest's
    xdist workers receive on such a thread), which ``threading.active_count`` misses. Native
    pools that prepare for a fork themselves (OpenBLAS's) do not count.
    """
    if 'fork' in multiprocessing.get_all_start_methods() and len(sys._current_frames()) == 1:
        return 'fork'
    return 'spawn'


class JobError(Exception):
    """
    A job raised; the message starts with the job's name, the job's exception is ``__cause__``.

    ``job_name`` and ``index`` (in the list of jobs) say which job it was.
    """

    job_name: str = ''
    index: int = -1


class UserJobError(JobError, UserError):
    """A job refused its input (a UserError): the command shows it as one line."""


class FileJobError(JobError, OSError):
    """A job could not read or write a file (an OSError)."""


class WorkerCountError(UserError):
    """A number of workers that is not a whole number >= 1."""


def worker_option(option: str, text: str | None) -> int | None:
    """
    A command's worker count (``--jobs``, ``--workers``) from its text; None when not given.

    The one rule for all of them: a whole number >= 1, refused in one line naming ``option``
    (0 or a negative count would otherwise be taken silently as one worker, or run nothing).
    """
    if text is None:
        return None
    try:
        value = int(text)
    except ValueError:
        raise WorkerCountError(f'{option}: {text!r} is not a whole number') from None
    if value < 1:
        raise WorkerCountError(f'{option}: must be >= 1 (worker processes), got {value}')
    return value


def workers_or_scheduler(workers: int | None, scheduler: str | None,
                         error: type[UserError] = UserError) -> int:
    """
    The local worker count of a command taking ``--workers`` and ``--scheduler``.

    The scheduler's address is checked (:func:`scheduler_option`); ``--workers`` with it is
    refused (the cluster has its own workers), below 1 refused; by default, one per core.
    """
    scheduler_option('--scheduler', scheduler)
    if scheduler is not None and workers is not None:
        raise error('--workers: not with --scheduler (the cluster has its own workers)')
    count = workers if workers is not None else (os.cpu_count() or 1)
    if count < 1:
        raise error(f'--workers: must be >= 1, got {count}')
    return count


class SchedulerAddressError(UserError):
    """A ``--scheduler`` that is no address of a Dask scheduler."""


def scheduler_option(option: str, text: str | None) -> str | None:
    """
    A command's Dask scheduler address (``--scheduler``), checked; None when not given.

    Refused in one line naming ``option`` before any work starts: an address without a port
    (``distributed`` raised its ValueError only once the grid was to run, a traceback), a
    port that is not a number from 1 to 65535. Whether a scheduler answers there is known
    only on connecting (an OSError naming the address, within DASK_CONNECT_TIMEOUT).
    """
    if text is None:
        return None
    from distributed.comm.addressing import parse_address, parse_host_port

    example = 'e.g. tcp://10.0.0.5:8786'
    try:
        scheme, location = parse_address(text)
        if scheme in ('tcp', 'tls', 'ws', 'wss'):
            _, port = parse_host_port(location)
            if not 1 <= int(port) <= 65535:
                raise ValueError(f'port {port} is not from 1 to 65535')
    except (ValueError, TypeError) as err:
        raise SchedulerAddressError(f'{option}: {text!r} is not the address of a Dask '
                                    f'scheduler ({err}), {example}') from None
    return text


def worker_count(jobs: int, workers: int | None = None) -> int:
    """The workers worth starting: ``workers`` (default one per core), at most one per job."""
    wanted = (os.cpu_count() or 1) if workers is None else int(workers)
    if wanted < 1:
        raise WorkerCountError(f'workers must be >= 1, got {workers}')
    return max(1, min(wanted, jobs))


def _job_error(error: BaseException, job_name: str, index: int) -> JobError:
    """The JobError that names ``job_name`` for ``error`` (raise it ``from error``)."""
    if isinstance(error, UserError):
        wrapped: JobError = UserJobError(f'{job_name}: {error}')
    elif isinstance(error, OSError):
        wrapped = FileJobError(f'{job_name}: {error}')
    else:
        wrapped = JobError(f'{job_name}: {type(error).__name__}: {error}')
    wrapped.job_name, wrapped.index = job_name, index
    return wrapped


def run_jobs(function: Callable[[Any], Any], jobs: Iterable[Any], *,
             workers: int | None = None, backend: str = 'processes',
             progress: Progress | None = None, name: Namer | None = None,
             scheduler: str | None = None) -> list[Any]:
    """
    ``[function(job) for job in jobs]``, run on ``backend``; results in job order.

    ``workers`` (default one per core) is capped by the number of jobs; with one, or one job,
    the jobs run here (a Dask scheduler given by address is used all the same: the work is
    meant to run there, and ``workers`` does not apply to it). ``progress(done, total,
    result)`` is called here as each job finishes. ``name(job)`` names a failed job in its
    JobError.
    """
    jobs = list(jobs)
    if backend not in BACKENDS:
        raise ValueError(f'backend must be one of {", ".join(BACKENDS)}, got {backend!r}')
    if scheduler is not None and backend != 'dask':
        raise ValueError(f'a scheduler address is for the dask backend, not {backend!r}')
    count = worker_count(len(jobs), workers)
    if backend == 'dask' and (scheduler is not None or count > 1):
        return _run_dask(function, jobs, count, scheduler, progress, name)
    if backend == 'serial' or count == 1:
        return _run_serial(function, jobs, progress, name)
    with Workers(count) as pool:
        return pool.run(function, jobs, progress=progress, name=name)


def _job_name(name: Namer | None, jobs: Sequence[Any], index: int) -> str:
    if name is not None:
        return name(jobs[index])
    return f'job {index + 1} of {len(jobs)}'


def _run_serial(function: Callable[[Any], Any], jobs: list[Any], progress: Progress | None,
                name: Namer | None) -> list[Any]:
    results = []
    for index, job in enumerate(jobs):
        try:
            result = function(job)
        except Exception as error:
            raise _job_error(error, _job_name(name, jobs, index), index) from error
        results.append(result)
        if progress is not None:
            progress(index + 1, len(jobs), result)
    return results


def _run_dask(function: Callable[[Any], Any], jobs: list[Any], count: int,
              scheduler: str | None, progress: Progress | None,
              name: Namer | None) -> list[Any]:
    from distributed import Client, LocalCluster
    from distributed import as_completed as dask_completed

    results: list[Any] = [None] * len(jobs)
    with contextlib.ExitStack() as stack:
        if scheduler is None:
            address: Any = stack.enter_context(LocalCluster(
                n_workers=count, threads_per_worker=1, processes=True, dashboard_address=None))
        else:
            address = scheduler
        client = stack.enter_context(Client(address, timeout=DASK_CONNECT_TIMEOUT))
        futures = client.map(function, jobs, pure=False)
        index_of = {future.key: index for index, future in enumerate(futures)}
        try:
            for done, future in enumerate(dask_completed(futures), start=1):
                index = index_of[future.key]
                try:
                    results[index] = future.result()
                except Exception as error:
                    raise _job_error(error, _job_name(name, jobs, index), index) from error
                if progress is not None:
                    progress(done, len(jobs), results[index])
        except BaseException:
            # Stop what is queued or running on the cluster: nobody will collect it.
            client.cancel(futures)
            raise
    return results


# prctl(2): the signal a process gets when its parent dies.
PR_SET_PDEATHSIG = 1


def end_with_parent(parent_pid: int) -> None:
    """
    In a worker process: end it (SIGKILL) when its parent ``parent_pid`` dies, however.

    A worker waits for jobs on a pipe that it holds both ends of (a fork inherits them), so
    it never sees the parent go: after a ``kill -9`` of the parent it would live on for
    ever, holding the caller's stdout and stderr open (a shell's pipe never ends). On Linux
    the kernel sends the signal (``prctl(PR_SET_PDEATHSIG)``); a parent that died before
    this call is seen from the parent pid. Limits: the kernel counts the death of the
    thread that started the worker as the parent's (workers are started from the thread
    that submits their first job, the main thread in softseq's commands); elsewhere than
    Linux nothing is set.
    """
    if sys.platform.startswith('linux'):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:
        os.kill(os.getpid(), signal.SIGKILL)


def _start_worker(initializer: Callable[..., None] | None, initargs: tuple,
                  parent_pid: int) -> None:
    """
    In a new worker: end with the parent, leave SIGINT to it, then initialise.

    The parent stops its workers with SIGTERM, which must end one at once, also in the middle
    of C code: a forked worker would otherwise keep a Python handler of its parent's.
    """
    end_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if initializer is not None:
        initializer(*initargs)


def _wait(pending: set[Future]) -> tuple[set[Future], set[Future]]:
    """
    The futures done (none, after POLL_S) and those still pending.

    Waiting without a timeout, this thread would not see a Ctrl-C that the system hands to
    another thread of this process (the executor's) until a job finished, minutes later maybe.
    """
    finished, still = wait(pending, timeout=POLL_S, return_when=FIRST_COMPLETED)
    return set(finished), set(still)


def _ready() -> None:
    """A job that does nothing: submitted to start the workers now."""


class Workers:
    """
    Worker processes kept for several calls; ``close`` (or leaving a ``with``) ends them.

    ``initializer(*initargs)`` runs in each worker as it starts. ``start_method`` (default:
    :func:`default_start_method`) may ask for ``'fork'`` (a worker that inherits what this
    process has loaded) or ``'spawn'``. ``start_now`` starts the workers at once (with fork
    all of them, with spawn as many as there are workers, usually) rather than at the first
    job, so that an initializer's work overlaps the caller's. A job that raises leaves them be
    (the call's queued jobs are cancelled); an interrupt, or any other exception while
    waiting, ends them.
    """

    def __init__(self, workers: int | None = None, *,
                 initializer: Callable[..., None] | None = None, initargs: tuple = (),
                 start_method: str | None = None, start_now: bool = False) -> None:
        """Prepare ``workers`` processes (default one per core)."""
        self.workers = (os.cpu_count() or 1) if workers is None else int(workers)
        if self.workers < 1:
            raise ValueError(f'workers must be >= 1, got {workers}')
        self._pool: ProcessPoolExecutor | None = ProcessPoolExecutor(
            self.workers,
            mp_context=multiprocessing.get_context(start_method or default_start_method()),
            initializer=_start_worker, initargs=(initializer, initargs, os.getpid()))
        if start_now:
            for _ in range(self.workers):
                self._pool.submit(_ready)

    def __enter__(self) -> 'Workers':
        return self

    def __exit__(self, kind: type[BaseException] | None, *_: object) -> None:
        self.close(graceful=kind is None)

    def _executor(self) -> ProcessPoolExecutor:
        if self._pool is None:
            raise RuntimeError('these workers are closed')
        return self._pool

    def run(self, function: Callable[[Any], Any], jobs: Iterable[Any], *,
            progress: Progress | None = None, name: Namer | None = None) -> list[Any]:
        """``function(job)`` for every job on these workers; as :func:`run_jobs`."""
        jobs = list(jobs)
        pool = self._executor()
        results: list[Any] = [None] * len(jobs)
        futures: dict[Future, int] = {}
        try:
            for index, job in enumerate(jobs):
                futures[pool.submit(function, job)] = index
            pending, done = set(futures), 0
            while pending:
                finished, pending = _wait(pending)
                for future in sorted(finished, key=futures.__getitem__):
                    index = futures[future]
                    error = future.exception()
                    if error is not None:
                        for other in pending:
                            other.cancel()
                        raise _job_error(error, _job_name(name, jobs, index), index) from error
                    results[index] = future.result()
                    done += 1
                    if progress is not None:
                        progress(done, len(jobs), results[index])
        except JobError:
            raise
        except BaseException:
            self.close()
            raise
        return results

    def apply(self, function: Callable[..., Any], args: tuple = ()) -> Any:
        """``function(*args)`` in a worker; its exception, if any, is raised here as it is."""
        future = self._executor().submit(function, *args)
        try:
            while not _wait({future})[0]:
                pass
        except BaseException:
            self.close()
            raise
        return future.result()

    def close(self, graceful: bool = False) -> None:
        """
        End the workers now: queued jobs are dropped, running ones stopped (SIGTERM).

        ``graceful``: let them finish what they were given and exit on their own instead.
        Closing twice is harmless.
        """
        pool, self._pool = self._pool, None
        if pool is None:
            return
        if graceful:
            pool.shutdown(wait=True)
            return
        terminate = getattr(pool, 'terminate_workers', None)  # Python 3.14 and later
        if terminate is not None:
            terminate()
            return
        # Before 3.14 the executor can only wait for running jobs: stop its processes first,
        # then let it notice and clean up.
        processes = list((getattr(pool, '_processes', None) or {}).values())
        for process in processes:
            if process.is_alive():
                process.terminate()
        for process in processes:
            process.join(STOP_TIMEOUT_S)
            if process.is_alive():
                process.kill()
        pool.shutdown(wait=True, cancel_futures=True)
