"""
The figure worker: a forked process that has matplotlib loaded before there is anything to draw.

Importing matplotlib costs a report about half a second, as much as reading the paper bag.
Forked first thing, before the parent imports numpy or opens the bag, the worker pays it while
the parent reads; it then draws the figures, on both cores
(:func:`softseq_ros.analysis.figures.write_figures`). This module imports nothing heavy, so a
command can start the worker before anything else.
"""

import os

from softseq_ros.parallel import Workers, default_start_method


def _warm_up(svg: bool) -> None:
    """Import the drawing stack and the figure functions the jobs will name."""
    from matplotlib.backends import backend_agg  # noqa: F401
    from matplotlib.figure import Figure

    import softseq_ros.analysis.figures  # noqa: F401 - the drawing jobs are unpickled into it

    if svg:
        from matplotlib.backends import backend_svg  # noqa: F401
    Figure().subplots()


def start_workers(svg: bool = False) -> Workers | None:
    """
    A forked figure worker that starts importing matplotlib now (SVG's backend too with ``svg``).

    It splits itself in two when it draws, so matplotlib is imported once for two cores. None
    on one core, where fork is not available, or where another thread of this process runs
    Python (the fork could inherit a lock that thread holds, and a figure worker forked so
    once died mid-report): the figures are then drawn in the caller.
    """
    if (os.cpu_count() or 1) <= 1 or default_start_method() != 'fork':
        return None
    # Fork, not spawn: the worker is to inherit nothing but this module, and to be ready
    # before the caller has imported anything heavy.
    return Workers(1, initializer=_warm_up, initargs=(svg,), start_method='fork',
                   start_now=True)


def stop_workers(workers: Workers | None) -> None:
    """End a worker from :func:`start_workers` (None is accepted: there was none)."""
    if workers is not None:
        workers.close()
