"""
The node executables' entry points: a signal that comes while a node still loads ends it quietly.

Loading a node (rclpy, numpy, scipy, its scene) takes a second or more, and a Ctrl-C in that
time ended in a KeyboardInterrupt traceback through the imports. Until the node's module is
loaded, SIGINT and SIGTERM end the process at once with 130 and 143, as a shell reports them:
nothing is open yet that would need closing. Then the handlers there were come back, and the
node's own stop (rclpy's, at its init) takes over.
"""

from importlib import import_module
import os
import signal
from types import FrameType


def _while_loading(signum: int, _frame: FrameType | None) -> None:
    os._exit(128 + signum)


def _run(module: str) -> None:
    stops = (signal.SIGINT, signal.SIGTERM)
    previous = {signum: signal.signal(signum, _while_loading) for signum in stops}
    main = import_module(f'softseq_ros.nodes.{module}').main
    for signum, handler in previous.items():
        signal.signal(signum, handler)
    main()


def syringe_pump() -> None:
    """The ``syringe_pump`` executable."""
    _run('syringe_pump')


def managed_syringe_pump() -> None:
    """The ``managed_syringe_pump`` executable."""
    _run('managed_syringe_pump')


def actuator() -> None:
    """The ``actuator`` executable."""
    _run('actuator')


def camera() -> None:
    """The ``camera`` executable."""
    _run('camera')


def pressure_hold() -> None:
    """The ``pressure_hold`` executable (the example controller)."""
    _run('pressure_hold')


def recorder() -> None:
    """The ``recorder`` executable."""
    _run('recorder')


def sim_clock() -> None:
    """The ``sim_clock`` executable."""
    _run('sim_clock')


def rig() -> None:
    """The ``rig`` executable."""
    _run('rig')
