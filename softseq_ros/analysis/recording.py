"""
A rig recording as arrays: what the pump commanded, what the actuator did, what the camera saw.

Reads a bag written by the recorder or by ``softseq run`` (topics as in the README) and returns
plain numpy arrays in SI units, ready to compare with an experiment or with the solver.
"""

from dataclasses import dataclass, field
import json
import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from softseq_ros.bag.reader import read_bag
from softseq_ros.physics.csv_columns import read_columns

PUMP_TOPIC = '/pump/command'
VOLUMES_TOPIC = '/actuator/volumes'
CURVATURES_TOPIC = '/actuator/curvatures'
EVENTS_TOPIC = '/actuator/events'
SNAPSHOTS_TOPIC = '/camera/snapshots'
BACKBONE_TOPIC = '/camera/backbone'

FloatArray = NDArray[np.float64]


class RecordingError(ValueError):
    """A bag that lacks what an analysis needs; the message names the bag and the topic."""


@dataclass
class Snapshot:
    """The camera's backbone at one trigger volume: points (M, 2) as (x, z) in m."""

    time_s: float
    injected: float
    points: FloatArray


@dataclass
class Recording:
    """Time series of one rig run (times in s from the first pump command)."""

    path: Path
    segment_names: tuple[str, ...]
    pump_time_s: FloatArray
    pump_injected: FloatArray
    state_time_s: FloatArray
    state_injected: FloatArray
    pressure: FloatArray                # gauge, Pa
    volumes: FloatArray                 # (n, N), m^3
    curvature_time_s: FloatArray
    curvatures: FloatArray              # (m, N), 1/m
    events: list[dict] = field(default_factory=list)
    snapshots: list[Snapshot] = field(default_factory=list)
    backbone_count: int = 0


def _stamp_s(msg: object) -> float:
    stamp = msg.header.stamp  # type: ignore[attr-defined]
    return stamp.sec + stamp.nanosec * 1e-9


def load_recording(directory: str | os.PathLike) -> Recording:
    """Read a rig bag into arrays; raises RecordingError when the pump or actuator is missing."""
    path = Path(directory)
    pump_t, pump_u = [], []
    state_t, pressure, volumes = [], [], []
    curv_t, curvatures = [], []
    events: list[dict] = []
    snapshots: list[tuple[float, FloatArray]] = []
    names: tuple[str, ...] = ()
    backbones = 0
    for item in read_bag(path):
        msg = item.msg
        if item.topic == PUMP_TOPIC:
            pump_t.append(_stamp_s(msg))
            pump_u.append(float(msg.position[0]))
        elif item.topic == VOLUMES_TOPIC:
            names = tuple(msg.name)
            state_t.append(_stamp_s(msg))
            volumes.append(np.asarray(msg.position, dtype=float))
            pressure.append(float(np.mean(msg.effort)))
        elif item.topic == CURVATURES_TOPIC:
            curv_t.append(_stamp_s(msg))
            curvatures.append(np.asarray(msg.position, dtype=float))
        elif item.topic == EVENTS_TOPIC:
            events.append(json.loads(msg.data))
        elif item.topic == SNAPSHOTS_TOPIC:
            points = np.array([[p.position.x, p.position.z] for p in msg.poses])
            snapshots.append((_stamp_s(msg), points))
        elif item.topic == BACKBONE_TOPIC:
            backbones += 1
    if not pump_t:
        raise RecordingError(f'{path}: no {PUMP_TOPIC} messages: not a rig recording')
    if not state_t:
        raise RecordingError(f'{path}: no {VOLUMES_TOPIC} messages: the actuator did not run '
                             'or its volumes were not recorded')
    t0 = pump_t[0]
    pump_time = np.asarray(pump_t) - t0
    pump_injected = np.asarray(pump_u)
    state_time = np.asarray(state_t) - t0
    vols = np.vstack(volumes)
    state_injected = _injected_at(pump_time, pump_injected, state_time)
    shots = [Snapshot(t - t0, float(_injected_at(pump_time, pump_injected,
                                                 np.array([t - t0]))[0]), pts)
             for t, pts in snapshots]
    curv = np.vstack(curvatures) if curvatures else np.zeros((0, len(names)))
    return Recording(path, names, pump_time, pump_injected, state_time, state_injected,
                     np.asarray(pressure), vols, np.asarray(curv_t) - t0, curv, events, shots,
                     backbones)


def _injected_at(times: FloatArray, injected: FloatArray, at: FloatArray) -> FloatArray:
    """The last commanded volume at or before each time in ``at``."""
    index = np.clip(np.searchsorted(times, at, side='right') - 1, 0, times.size - 1)
    return injected[index]


def read_experiment(path: str | os.PathLike) -> tuple[FloatArray, FloatArray]:
    """Injected volume [m^3] and gauge pressure [Pa] columns of a measured PV curve (CSV)."""
    columns = read_columns(path, ('injected_m3', 'pressure_pa'), RecordingError,
                           'experiment file')
    return columns['injected_m3'], columns['pressure_pa']
