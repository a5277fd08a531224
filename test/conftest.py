"""Test-wide environment: every test process gets its own ROS domain, limited to this host.

This module runs before pytest imports any test module, so the variables below are in place
before the first ``import rclpy`` (the DDS participant reads them once, at creation).
"""

import os
import sys

import pytest

# Domain 0 is everyone's default, so a stray node elsewhere could join it. 1..101 stays inside
# the range whose DDS ports are valid on Linux for any participant count (the ROS docs' advice).
# Under pytest-xdist the workers (gw0, gw1, ...) of one run take consecutive domains.
_WORKER = os.environ.get('PYTEST_XDIST_WORKER', '')
ROS_DOMAIN_ID = 1 + ((os.getppid() + int(_WORKER[2:])) if _WORKER.startswith('gw')
                     else os.getpid()) % 101

os.environ['ROS_DOMAIN_ID'] = str(ROS_DOMAIN_ID)
# Limited to this host by the Fast DDS profile below (UDP on the loopback interface alone), not
# by ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST: with that range rmw_fastrtps adds its shared-memory
# transport, and a participant killed with SIGKILL (as several tests do) leaves its port behind;
# the next participant of this domain that takes the same port (a restarted node) can then hear
# nothing at all. SYSTEM_DEFAULT leaves the transports to the profile.
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SYSTEM_DEFAULT'
os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = os.path.join(os.path.dirname(__file__),
                                                            'fastdds_udp_localhost.xml')
os.environ.pop('FASTDDS_BUILTIN_TRANSPORTS', None)
# Deprecated in Jazzy and overridden by the variable above; dropped so it cannot confuse a run.
os.environ.pop('ROS_LOCALHOST_ONLY', None)

# The pip-installed ROS wheels put message definitions and the ament index under sys.prefix,
# and ament_index_python finds nothing without AMENT_PREFIX_PATH naming it.
_prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
if sys.prefix not in _prefixes:
    os.environ['AMENT_PREFIX_PATH'] = os.pathsep.join([sys.prefix, *_prefixes])

# Children started by name (softseq, colcon, ruff) must come from this venv even when it is
# not activated, e.g. `.venv/bin/python -m pytest`.
_venv_bin = os.path.join(sys.prefix, 'bin')
if _venv_bin not in os.environ.get('PATH', '').split(os.pathsep):
    os.environ['PATH'] = os.pathsep.join([_venv_bin, os.environ.get('PATH', '')])

# Figures are written to files in tests; never try to open a window.
os.environ.setdefault('MPLBACKEND', 'Agg')


@pytest.fixture(autouse=True)
def ros_home(tmp_path_factory, monkeypatch):
    """Every test its own ROS home: an actuator's state file never carries over to another."""
    home = tmp_path_factory.mktemp('ros_home')
    monkeypatch.setenv('ROS_HOME', str(home))
    return home


@pytest.fixture
def ros_env() -> dict[str, str]:
    """Return a fresh copy of the environment for child processes (nodes, the CLI).

    The whole environment is passed on: the ROS wheels re-execute Python once with
    LD_LIBRARY_PATH set and mark that with _ROS_WHEELS_BOOTSTRAP_COMPLETE, so a child that
    inherits the mark without LD_LIBRARY_PATH cannot load rclpy. The copy also carries this
    run's ROS_DOMAIN_ID and discovery range, so children talk to this test and nothing else.
    """
    env = dict(os.environ)
    # Child output must reach the test promptly, even when a child is killed.
    env['PYTHONUNBUFFERED'] = '1'
    return env


@pytest.fixture
def context():
    """A fresh rclpy Context for one test, shut down afterwards."""
    import rclpy

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)
