"""
What the rig benchmarks say about the machine they ran on, and their latency rows.

Shared by bench_rig.py and bench_soak.py; imports nothing of ROS, so a batch child of the
soak can use it without loading rclpy.
"""

import importlib.metadata
import os
from pathlib import Path
import platform

import numpy as np


def machine_facts() -> dict[str, str]:
    """Cores, CPU, Python, the rclpy wheel and the middleware: the header of a results file."""
    try:
        rclpy_version = importlib.metadata.version('ros-rclpy')
    except importlib.metadata.PackageNotFoundError:
        rclpy_version = 'unknown'
    try:
        model = next(line.split(':', 1)[1].strip()
                     for line in Path('/proc/cpuinfo').read_text().splitlines()
                     if line.startswith('model name'))
    except (OSError, StopIteration):
        model = platform.processor() or 'unknown'
    return {
        'cores (os.cpu_count)': str(os.cpu_count()),
        'cores usable (sched_getaffinity)': str(len(os.sched_getaffinity(0))),
        'cpu': model,
        'python': platform.python_version(),
        'rclpy (ros-rclpy wheel)': rclpy_version,
        'rmw': os.environ.get('RMW_IMPLEMENTATION', 'default (rmw_fastrtps_cpp)'),
        'platform': platform.platform(),
    }


def load_text() -> str:
    """The load average over 1, 5 and 15 minutes, as the results files print it."""
    one, five, fifteen = os.getloadavg()
    return f'{one:.2f} / {five:.2f} / {fifteen:.2f}'


def latency_row(values_ms: list[float], percentiles: tuple[float, ...] = (50, 90, 99)) -> str:
    """Table cells: the given percentiles (50 is the median), the maximum and the count."""
    data = np.array(values_ms)
    if data.size == 0:
        return ' | '.join(['-'] * (len(percentiles) + 1) + ['0'])
    cells = [f'{np.percentile(data, q):.2f}' for q in percentiles] + [f'{data.max():.2f}']
    return ' | '.join(cells + [str(data.size)])
