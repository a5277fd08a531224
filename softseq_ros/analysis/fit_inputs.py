"""
What ``softseq fit`` reads: measured inflations of one segment, of three kinds (docs/fit.md).

- a **table**: a CSV with ``volume_m3`` (the segment's whole volume) and ``pressure_pa``
  (gauge), read as every segment table is (:func:`softseq_ros.scene.tables.read_cycle`);
- an **experiment file**: a CSV with ``injected_m3`` and ``pressure_pa``, as ``softseq report
  --experiment`` reads it (:func:`softseq_ros.analysis.experiment.read_experiment`): the
  injected volume is not the segment's whole volume, so the rest volume is given and added;
  absolute pressures are made gauge with the file's own ambient, and refused without one;
- a **rig bag**: a folder with ``metadata.yaml`` as ``softseq run`` writes it, read by
  :func:`softseq_ros.analysis.recording.load_recording`: one segment's recorded volume against
  the recorded gauge pressure, its rows split into the loading and unloading branches as that
  segment's own volume rises and falls, with its recorded curvature where there is one.

The kind is told from the path; one kind per fit.
"""

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from softseq_ros.analysis.experiment import read_experiment
from softseq_ros.analysis.recording import Recording, load_recording
from softseq_ros.scene.csv_columns import read_rows
from softseq_ros.scene.tables import INFLATION_COLUMNS, read_cycle
from softseq_ros.segments.fit import (
    MIN_ROWS,
    Cycle,
    Deflation,
    FitError,
    Inflation,
    split_cycle,
)

TABLE = 'table'
EXPERIMENT = 'experiment file'
BAG = 'bag'
# A rig records at its pump's rate, tens of thousands of rows a run: each branch is thinned to
# at most this many of its raw rows (every k-th in volume, none averaged, so the noise estimated
# from them is still the rows' own), far more than a law of three parameters needs.
MAX_BAG_ROWS = 2000


@dataclass
class FitInputs:
    """The cycles read, the kind of input they came from, and what the readers noted."""

    cycles: list[Cycle]
    kind: str
    notes: list[str] = field(default_factory=list)


def input_kind(path: Path) -> str:
    """Which kind of input ``path`` is: a bag folder, an experiment file or a table."""
    if path.is_dir():
        if (path / 'metadata.yaml').is_file():
            return BAG
        raise FitError(f'{path}: a folder without metadata.yaml: not a bag (a folder with '
                       'metadata.yaml and .mcap, as softseq run writes), nor a CSV file')
    _, header, _ = read_rows(path, FitError, 'measured inflation', INFLATION_COLUMNS)
    if 'injected_m3' in header and 'volume_m3' not in header:
        return EXPERIMENT
    return TABLE


def read_fit_inputs(paths: Sequence[Path], segment: str | None = None,
                    rest_volume: float | None = None, size: float | None = None) -> FitInputs:
    """
    The measured cycles of one segment from ``paths``, all of one kind.

    ``segment``: the segment of a bag (required for bags, refused otherwise). ``rest_volume``
    [m^3]: what an experiment file's injected volume is added to (required for experiment
    files). ``size`` [m]: the segment's, for the check of a table's volume unit.
    """
    kinds = [input_kind(Path(path)) for path in paths]
    first = kinds[0]
    for path, kind in zip(paths, kinds):
        if kind != first:
            raise FitError(f'{path}: {_with_article(kind)}, but {paths[0]} is '
                           f'{_with_article(first)}: give inputs of one kind (tables, experiment '
                           'files or bags)')
    if first == BAG and segment is None:
        raise FitError(f'{paths[0]}: a bag holds every segment of its scene: name the one to '
                       'fit with --segment NAME')
    if first != BAG and segment is not None:
        raise FitError(f'{paths[0]}: --segment {segment}: only a bag has segments to choose '
                       f'from; this is {_with_article(first)}')
    if first == EXPERIMENT and rest_volume is None:
        raise FitError(f'{paths[0]}: an experiment file holds the injected volume, not the '
                       "segment's whole volume: give the rest volume it adds to (--radius-m "
                       'for a sphere, --rest-volume-m3 for a bulge)')
    inputs = FitInputs([], first)
    for path in paths:
        if first == BAG:
            inputs.cycles.append(bag_cycle(Path(path), segment or '', inputs.notes))
        elif first == EXPERIMENT:
            inputs.cycles.append(experiment_cycle(Path(path), rest_volume or 0.0,
                                                  inputs.notes))
        else:
            inputs.cycles.append(read_cycle(path, size))
    return inputs


def _with_article(kind: str) -> str:
    return f'an {kind}' if kind[0] in 'aeiou' else f'a {kind}'


def experiment_cycle(path: Path, rest_volume: float, notes: list[str]) -> Cycle:
    """
    An experiment file as a cycle of the segment: whole volume = ``rest_volume`` + injected.

    Rows in the file's order; where the injected volume rises and then falls, the rows after
    the largest are the deflation (:func:`~softseq_ros.segments.fit.split_cycle`).
    """
    experiment = read_experiment(path)
    if experiment.pressure_kind == 'absolute' and not experiment.ambient_declared:
        # The fit's pressures are gauge: a default ambient 1 kPa off the day's is a 1 kPa
        # error on every row, as large as a balloon's whole curve.
        raise FitError(f'{path}: absolute pressures, but no "# ambient_pressure_pa:" line: the '
                       'ambient they are measured above is unknown; give it, or gauge pressures')
    notes.extend(experiment.warnings)
    return split_cycle(rest_volume + experiment.injected, experiment.pressure, str(path))


def bag_cycle(path: Path, segment: str, notes: list[str]) -> Cycle:
    """
    One segment's recorded volume against the recorded gauge pressure, as a cycle.

    Quasi-statically every segment sits at the common pressure, so each recorded row is a
    point of the segment's own p(v). The rows where the segment's volume rose are its loading
    branch, those where it fell its unloading branch (another segment's snap-through can make
    it fall while the pump inflates); each is sorted by volume, a repeated volume kept once,
    and thinned to :data:`MAX_BAG_ROWS`. An unloading branch of fewer than
    :data:`~softseq_ros.segments.fit.MIN_ROWS` rows is left out.
    """
    recording = load_recording(path)
    if segment not in recording.segment_names:
        raise FitError(f'{path}: --segment {segment}: no such segment in the bag (its segments: '
                       f'{", ".join(recording.segment_names)})')
    column = recording.segment_names.index(segment)
    volume = recording.volumes[:, column]
    pressure = recording.pressure
    curvature = _curvature_at_states(recording, column)
    source = f'{path} (segment {segment})'
    if recording.channel_flows is not None:
        notes.append(f'{source}: a bag of a fluid network in time: while water moves the '
                     "segment's own pressure differs from the common one recorded, and those "
                     'rows lie off its p(v)')
    step = np.diff(volume)
    rising = np.concatenate([[True], step > 0.0])
    falling = np.concatenate([[False], step < 0.0])
    loading = _branch_rows(rising, volume, pressure, curvature)
    inflation = Inflation(loading[0], loading[1], source, loading[2])
    if np.count_nonzero(falling) < MIN_ROWS:
        return Cycle(inflation)
    unloading = _branch_rows(falling, volume, pressure, curvature)
    if unloading[0].size < MIN_ROWS:
        return Cycle(inflation)
    falling_rows = [None if rows is None else rows[::-1].copy() for rows in unloading]
    return Cycle(inflation, Deflation(falling_rows[0], falling_rows[1], source, falling_rows[2]))


def _curvature_at_states(recording: Recording, column: int) -> np.ndarray | None:
    """The segment's recorded curvature at each volume row, or None where none was recorded."""
    curvatures = recording.curvatures
    if curvatures.shape[0] < 2:
        return None
    if curvatures.shape[0] == recording.volumes.shape[0] and np.array_equal(
            recording.curvature_time_s, recording.state_time_s):
        return curvatures[:, column]
    # Recorded at other instants: taken at the volume rows' times.
    return np.interp(recording.state_time_s, recording.curvature_time_s, curvatures[:, column])


def _branch_rows(rows: np.ndarray, volume: np.ndarray, pressure: np.ndarray,
                 curvature: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A branch's rows in strictly rising volume, thinned to at most MAX_BAG_ROWS."""
    volume, pressure = volume[rows], pressure[rows]
    order = np.argsort(volume, kind='stable')
    first = np.concatenate([[True], np.diff(volume[order]) > 0.0])
    order = order[first]
    if order.size > MAX_BAG_ROWS:
        order = order[np.unique(np.round(np.linspace(0, order.size - 1,
                                                     MAX_BAG_ROWS)).astype(int))]
    return volume[order], pressure[order], None if curvature is None else curvature[rows][order]
