"""
The report of a rig bag: metrics.json, report.md, summary.txt and the figures.

``metrics.json`` holds every number in SI (m^3, Pa gauge, J, m, s); ``report.md`` and the
summary show the same numbers in mL, kPa and mm for people.

A dynamic bag (a scene with a fluid network) also gets its transients
(:mod:`softseq_ros.analysis.transients`): ``transients`` in metrics.json, lines in the summary,
a section in report.md and the figure ``transients.png``; a quasi-static bag's report has none
of them.

A scene given for the report must be the one that made the bag: when the bag records the
scene its actuator ran (``actuator/scene``), a scene whose segments have another digest is
refused (:class:`SceneMismatchError`) before anything is written or assembled. A bag that
records no scene (older bags, other recorders) is reported as before, with a note that the
scene could not be checked. Without a scene the report names the recorded one but does not
load it: the report stays a function of its arguments, and as fast.
"""

import json
import math
import os
from pathlib import Path

import numpy as np

from softseq_ros.analysis.experiment import Experiment, compare, read_experiment
from softseq_ros.analysis.metrics import (
    LEAD_SHARE,
    Trace,
    TraceError,
    analyse,
    bend_angles,
    segment_limits,
)
from softseq_ros.analysis.recording import CUT_SHORT, Recording, load_recording
from softseq_ros.analysis.text import duration_text, millijoules_text
from softseq_ros.analysis.transients import (
    Transients,
    analyse_transients,
    is_dynamic,
    timed_snaps,
)
from softseq_ros.errors import (
    NotRegularFileError,
    UserError,
    read_regular_file,
    write_text,
    writing,
)
from softseq_ros.segments.identity import segments_sha256, short
from softseq_ros.wire import contract
from softseq_ros.yaml_text import parse_yaml

ML = 1e6
KPA = 1e-3
MM = 1e3
MS = 1e3


class ReferenceFileError(UserError):
    """A reference file that cannot be used."""


class SceneMismatchError(UserError):
    """A scene given for a bag that a scene with other segments made."""


def _named(scene_name: str, digest: str) -> str:
    return f'scene {scene_name!r} (segments sha256 {short(digest)})'


def check_scene(recording: Recording, scene: object) -> list[str]:
    """
    Notes on whether ``scene`` made ``recording``; SceneMismatchError when it cannot have.

    The recorded identity names the segments by their digest
    (:func:`softseq_ros.segments.identity.segments_sha256`): another digest is other physics,
    whatever the names. The same digest under another scene name is the same physics (a
    renamed or copied scene file): a note says so.
    """
    digest = segments_sha256(scene.members)
    recorded = recording.scenes
    if not recorded:
        topic = contract.resolve(contract.SCENE.name, recording.namespace)
        return [f'the bag records no {topic} (an older bag, or another recorder): whether '
                f'scene {scene.name!r} made it could not be checked']
    if not any(r.segments_sha256 == digest for r in recorded):
        said = ', '.join(_named(r.scene, r.segments_sha256) for r in recorded)
        raise SceneMismatchError(f'{recording.path}: recorded by {said}, not by '
                                 f'{_named(scene.name, digest)}: their segments (or supply '
                                 'lines) differ')
    match = next(r for r in recorded if r.segments_sha256 == digest)
    notes = []
    if match.scene != scene.name:
        notes.append(f'recorded as scene {match.scene!r}, which has the same segments as '
                     f'scene {scene.name!r} (sha256 {short(digest)})')
    return notes


def scene_notes(recording: Recording, scene: object) -> list[str]:
    """
    :func:`check_scene`, and SceneMismatchError when the bag's segments are not the scene's.

    A bag that records no scene can only be checked by its segments' names.
    """
    notes = check_scene(recording, scene)
    if scene.segment_names != recording.segment_names:
        raise SceneMismatchError(f"{recording.path}: the bag's segments "
                                 f'{", ".join(recording.segment_names)} are not the '
                                 f'scene\'s {", ".join(scene.segment_names)}')
    return notes


def recording_trace(recording: Recording) -> Trace:
    """The states of a recording as a :class:`Trace`."""
    curvatures = recording.curvatures if recording.curvatures.shape[0] == \
        recording.volumes.shape[0] else None
    return Trace(recording.state_injected, recording.pressure, recording.volumes,
                 recording.state_flow_sign, curvatures, recording.events,
                 recording.segment_names)


def _network(scene: object | None) -> object | None:
    """The scene's fluid network, if a scene with one was given."""
    return getattr(scene, 'network', None)


def recording_metrics(recording: Recording, scene: object | None = None,
                      emap: object | None = None, transients: Transients | None = None) -> dict:
    """
    Every number of a recording (first cycle), SI units, gauge pressures.

    ``transients``: the recording's, when already analysed (the report draws them too);
    otherwise a dynamic recording's are analysed here.
    """
    runs = recording.runs()
    metrics: dict = {
        'bag': str(recording.path),
        'namespace': recording.namespace,
        'units': 'SI: volumes m^3, pressures Pa (gauge), energy J, positions m, times s',
        'segments': list(recording.segment_names),
        'duration_s': float(recording.pump_time_s[-1]),
        'message_counts': dict(sorted(recording.counts.items())),
        'ignored_from_before_the_first_pump_command': recording.ignored,
        'skipped_as_unusable': recording.skipped,
        'ambient_pressure_pa': recording.ambient_pressure_pa,
        'recorded_scene': recording.scene.as_dict() if recording.scene else None,
        # The numbers of the first run; a bag of several runs lists each under 'runs'.
        **run_metrics(runs[0]),
        'warnings': [],
        'notes': [],
    }
    if len(runs) > 1:
        metrics['runs'] = [{'run': run.run, 'from_s': run.run_span_s[0],
                            'until_s': run.run_span_s[1],
                            'began': 'the recording began' if run.run == 1 else
                            recording.run_starts[run.run - 2].cause,
                            **run_metrics(run)} for run in runs]
        metrics['warnings'].append(
            f'the bag holds {len(runs)} pump runs (' + '; '.join(
                f'run {start_number} from {start.time_s:.3f} s: {start.cause}'
                for start_number, start in enumerate(recording.run_starts, start=2))
            + '): the numbers above the runs are those of run 1; runs lists each')
    if len(recording.scenes) > 1:
        metrics['warnings'].append(
            'the actuator was restarted on other segments during the recording: '
            + ', '.join(_named(r.scene, r.segments_sha256) for r in recording.scenes)
            + '; recorded_scene is the first')
    end = metrics['pump_end']
    if end is not None and end['state'] in CUT_SHORT:
        metrics['warnings'].append(
            f'the pump {end["state"]} at {end["time_s"]:.3f} s, {_ml(end["injected_m3"])} '
            f'injected ({end["reason"] or "no reason given"}): the programme did not run to '
            'its end, and every number here is that of the part it ran')
    # What the analysis could not use (a foreign publisher's messages, say), topic by topic.
    metrics['warnings'].extend(recording.skipped_lines())
    if recording.ignored:
        metrics['warnings'].append(
            'left out, stamped before the first pump command (latched from an earlier run): '
            + ', '.join(f'{topic} {n}' for topic, n in sorted(recording.ignored.items())))
    if scene is not None and emap is not None:
        from softseq_ros.quasistatic.equilibrium import classify

        metrics['scene'] = scene.name
        metrics['sequence_type_of_scene'] = classify(emap)
        metrics['segment_pressure_limits_pa'] = segment_limits(list(scene.segments),
                                                               scene.segment_names)
        from softseq_ros.quasistatic.graph import visits

        # Which stable branches of the scene's transition graph (softseq graph) it went along.
        metrics['branches_visited'] = visits(emap, recording.state_time_s, recording.volumes,
                                             recording.pressure)
        if metrics['sequence_type_of_scene'] != metrics['sequence_type']:
            metrics['warnings'].append(
                f'the recording reads as {metrics["sequence_type"]}, the scene classifies as '
                f'{metrics["sequence_type_of_scene"]} over its whole range (the pump may not '
                'cover it)')
    if scene is not None and emap is not None and is_dynamic(recording) \
            and metrics['hysteresis_area_j'] is not None:
        metrics.update(_hysteresis_parts(recording, scene, emap, metrics['hysteresis_area_j']))
    if transients is None:
        transients = analyse_transients(recording, emap, _network(scene))
    if transients is not None:
        metrics['transients'] = transients.metrics
        metrics['warnings'].extend(transients.warnings)
    return metrics


def _hysteresis_parts(recording: Recording, scene: object, emap: object,
                      total: float) -> dict:
    """
    A recording in time: its hysteresis area split into the segments' own and the flow's.

    The quasi-static path along the recorded injected volumes has the elastic hysteresis of
    the curves alone (the snaps' losses), which stays however slowly the pump goes; the rest is
    the viscous loss of the fluid's flow through the tubes, which vanishes as the pump slows.
    """
    from softseq_ros.quasistatic.equilibrium import DomainError
    from softseq_ros.quasistatic.reach import start_tracker

    injected = recording.state_injected
    try:
        # From where the scene's programme starts (rest, or where its start history led).
        path = start_tracker(scene.pump.profile, emap, scene.segment_names).sweep(injected)
    except DomainError:
        return {}
    still = analyse(Trace(injected, path.pressure, path.volumes, recording.state_flow_sign))
    elastic = still['hysteresis_area_j']
    if elastic is None:
        return {}
    return {'hysteresis_area_quasi_static_j': elastic,
            'hysteresis_area_rate_dependent_j': total - elastic}


def _snaps_in_time(recording: Recording) -> list[dict] | None:
    """
    The snap-throughs the actuator said, for a recording in time (None: found in the volumes).

    As the volumes' analysis gives them, so that the summary, metrics.json and the transients
    count the same ones: in time a snap is an exchange of fluid over many states, not a jump
    between two commands. A run's events are those of its span (Recording.runs).
    """
    if recording.target_pressure is not None:
        return _regulated_snaps(recording)
    said = timed_snaps(recording) if is_dynamic(recording) else []
    if not said:
        # Nothing said in time (an actuator that reports no events, or exchanges too fast
        # against the pump for its watcher): the jumps the volumes show, as quasi-statically.
        return None
    return [{'injected_m3': snap.injected, 'direction': snap.direction,
             'fluid_moved_m3': snap.fluid_moved,
             'from_volumes_m3': list(snap.from_volumes), 'to_volumes_m3': list(snap.to_volumes),
             'from_pressure_pa': snap.from_pressure, 'to_pressure_pa': snap.to_pressure,
             'start_time_s': snap.start_s, 'duration_s': snap.duration_s}
            for snap in said]


def _ml_moved(snap: dict) -> str:
    """Where a snap's fluid went: between the segments, or through the regulator."""
    moved = _ml(snap['fluid_moved_m3'], 3)
    if not snap.get('through_regulator'):
        return f'{_kpa(snap["to_pressure_pa"])}, {moved} moved between segments'
    way = 'given back to' if snap['direction'] == 'deflation' else 'taken from'
    return f'{_kpa(snap["to_pressure_pa"])}, {moved} {way} the regulator'


def _regulated_snaps(recording: Recording) -> list[dict]:
    """
    Behind a regulator: the flips the actuator said, each a segment's jump at one pressure.

    The injected volume jumps with the segment (the regulator gives the fluid), so the jumps
    the volumes show at one command are no test: the events are the snaps. Their fluid moved
    went through the regulator (``through_regulator``), not between the segments.
    """
    snaps = []
    times = recording.state_time_s
    for event, at in zip(recording.events, recording.event_times_s.tolist()):
        row = min(int(np.searchsorted(times, at)), times.size - 1)
        sign = recording.state_flow_sign[row] if recording.state_flow_sign.size else 1
        before, after = event['from_volumes_m3'], event['to_volumes_m3']
        snaps.append({'injected_m3': float(event['injected_m3']),
                      'direction': 'deflation' if sign < 0 else 'inflation',
                      'fluid_moved_m3': float(sum(abs(b - a) for a, b in zip(before, after))),
                      'from_volumes_m3': [float(v) for v in before],
                      'to_volumes_m3': [float(v) for v in after],
                      'from_pressure_pa': float(event['from_pressure_pa']),
                      'to_pressure_pa': float(event['to_pressure_pa']),
                      'through_regulator': True})
    return snaps


def pump_end(recording: Recording) -> dict | None:
    """
    How the pump's programme ended in this run: its last status, when, and where.

    ``{'state', 'reason', 'time_s', 'injected_m3'}``; None when the bag holds no status.
    """
    if not recording.status:
        return None
    time_s, state, reason = recording.status[-1]
    at = int(np.searchsorted(recording.pump_time_s, time_s, side='right')) - 1
    injected = float(recording.pump_injected[max(at, 0)]) if recording.pump_injected.size \
        else None
    return {'state': state, 'reason': reason, 'time_s': float(time_s), 'injected_m3': injected}


def run_metrics(recording: Recording) -> dict:
    """The numbers of one run of a recording (first cycle), SI units, gauge pressures."""
    try:
        result = analyse(recording_trace(recording), snaps=_snaps_in_time(recording))
    except TraceError as err:
        where = f' (run {recording.run})' if recording.run_span_s else ''
        raise TraceError(f'{recording.path}{where}: {err}') from None
    top = int(np.argmax(recording.state_injected))
    rest = recording.volumes[0]
    added = recording.volumes[top] - rest
    share = added / max(float(np.sum(added)), 1e-300)
    return {
        **result,
        'pump_end': pump_end(recording),
        'peak_injection': {'injected_m3': float(recording.state_injected[top]),
                           'pressure_pa': float(recording.pressure[top]),
                           'share_of_added_volume': [float(x) for x in share]},
        'snap_events_topic': [{k: e[k] for k in ('injected_m3', 'from_pressure_pa',
                                                 'to_pressure_pa') if k in e}
                              for e in recording.events],
        'steps': [_step(s, len(recording.segment_names)) for s in recording.snapshots],
    }


def _step(shot: object, count: int) -> dict:
    """A snapshot as metrics.json holds it: where, when, the tip, and how far it bends."""
    angles = bend_angles(shot.points, count)
    return {'step': shot.step, 'direction': shot.direction, 'cycle': shot.cycle,
            'injected_m3': shot.injected, 'trigger_injected_m3': shot.trigger_injected,
            'time_s': shot.time_s, 'tip_m': [float(x) for x in shot.tip],
            # The tip's tangent from the base's, and each segment's share of it [rad].
            'tip_angle_rad': float(sum(angles)) if angles else None,
            'bend_angles_rad': angles or None}


def load_reference(path: str | os.PathLike) -> dict:
    """A reference file (YAML) of what a paper reports; see config/reference/."""
    path = Path(path)
    try:
        text = read_regular_file(path).decode('utf-8')
    except NotRegularFileError as err:
        raise ReferenceFileError(f'{path}: the reference file is {err.kind}, not a regular '
                                 'file') from None
    except OSError as err:
        raise ReferenceFileError(f'{path}: cannot read the reference file ({err.strerror})') \
            from None
    except UnicodeDecodeError as err:
        raise ReferenceFileError(f'{path}: not UTF-8 text (byte {err.start})') from None
    document = parse_yaml(text, str(path), ReferenceFileError)
    if not isinstance(document, dict) or not isinstance(document.get('reported'), dict):
        raise ReferenceFileError(f'{path}: a reference file needs a mapping "reported"')
    _check_reported(path, document['reported'])
    return document


def _check_reported(path: Path, reported: dict) -> None:
    """Refuse, naming the key, a reported fact of the wrong kind (the comparison needs it)."""
    from softseq_ros.quasistatic.sequence import SEQUENCE_TYPES

    def refuse(key: str, what: str, value: object) -> None:
        raise ReferenceFileError(f'{path}: reported.{key}: must be {what}, got {value!r:.60}')

    def volume(key: str, value: object) -> None:
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not math.isfinite(value) or value < 0:
            refuse(key, 'a finite volume >= 0 in m^3', value)

    if 'sequence_type' in reported and reported['sequence_type'] not in SEQUENCE_TYPES:
        refuse('sequence_type', f'one of {", ".join(SEQUENCE_TYPES)}', reported['sequence_type'])
    for key in ('plateau_onset_injected_m3', 'plateau_onset_tolerance_m3'):
        if key in reported:
            volume(key, reported[key])
    if 'segment_plateau_lower' in reported and \
            not isinstance(reported['segment_plateau_lower'], str):
        refuse('segment_plateau_lower', "a segment's name", reported['segment_plateau_lower'])
    steps = reported.get('steps', [])
    if not isinstance(steps, list):
        refuse('steps', 'a list of mappings', steps)
    for index, entry in enumerate(steps):
        where = f'steps[{index}]'
        if not isinstance(entry, dict):
            refuse(where, 'a mapping with step and volumes', entry)
        step = entry.get('step')
        if isinstance(step, bool) or not isinstance(step, int) or step < 1:
            refuse(f'{where}.step', 'a step number >= 1', step)
        for key in ('simulation_injected_m3', 'experiment_injected_m3'):
            if key in entry:
                volume(f'{where}.{key}', entry[key])


def check_reference_segments(path: str | os.PathLike, reference: dict,
                             segments: tuple[str, ...] | list[str]) -> None:
    """Refuse a reference that names a segment the recording does not have (before writing)."""
    named = reference['reported'].get('segment_plateau_lower')
    if named is not None and named not in segments:
        raise ReferenceFileError(f'{path}: reported.segment_plateau_lower: {named!r} is no '
                                 f'segment of this recording ({", ".join(segments)})')


def against_reference(metrics: dict, reference: dict) -> dict:
    """Each reported fact beside what the recording shows, with the difference."""
    reported = reference['reported']
    checks = []
    if 'sequence_type' in reported:
        checks.append({'what': 'sequence type', 'reported': reported['sequence_type'],
                       'recorded': metrics['sequence_type'],
                       'agrees': reported['sequence_type'] == metrics['sequence_type']})
    onset = (metrics.get('plateau') or {}).get('onset_injected_m3')
    if 'plateau_onset_injected_m3' in reported:
        target = float(reported['plateau_onset_injected_m3'])
        tolerance = float(reported.get('plateau_onset_tolerance_m3', 0.1 * target))
        check = {'what': 'combined PV plateau reached (95 % of its pressure) at',
                 'reported_m3': target, 'recorded_m3': onset,
                 'difference_m3': None if onset is None else onset - target,
                 'agrees': onset is not None and abs(onset - target) <= tolerance}
        if onset is None:
            check['recorded_does_not_apply'] = not_applicable_reason(metrics, 'plateau')
        checks.append(check)
    order = reported.get('segment_plateau_lower')
    if order:
        switch = metrics.get('switch') or {}
        limits = metrics.get('segment_pressure_limits_pa') or {}
        lower = order
        taking = switch.get('segment_taking_over')
        agrees = taking == lower
        if limits:
            agrees = agrees and limits.get(lower, np.inf) == min(limits.values())
        check = {'what': 'segment with the lower plateau (takes the inflow after the switch)',
                 'reported': lower, 'recorded': taking,
                 'segment_pressure_limits_pa': limits or None, 'agrees': bool(agrees)}
        if taking is None:
            check['recorded_does_not_apply'] = not_applicable_reason(metrics, 'switch')
        checks.append(check)
    steps = {(s['step'], s['direction']): s for s in _first_cycle_steps(metrics)[0]}
    for entry in reported.get('steps', []):
        shot = steps.get((int(entry['step']), 'inflation'))
        recorded = None if shot is None else shot['injected_m3']
        row = {'what': f'step {entry["step"]} volume', 'recorded_m3': recorded}
        for key in ('simulation_injected_m3', 'experiment_injected_m3'):
            if key in entry:
                row[key.replace('_injected_m3', '_reported_m3')] = float(entry[key])
                row[key.replace('_injected_m3', '_difference_m3')] = \
                    None if recorded is None else recorded - float(entry[key])
        checks.append(row)
    return {'source': reference.get('source', ''), 'checks': checks}


def write_report(bag: str | os.PathLike, out: str | os.PathLike, scene_name: str | None = None,
                 experiment_csv: str | os.PathLike | None = None,
                 reference_file: str | os.PathLike | None = None, namespace: str | None = None,
                 svg: bool = False, figures: bool = True,
                 workers: object | None = None,
                 style: object | None = None) -> tuple[dict, str]:
    """
    Read the bag, write metrics.json, report.md, summary.txt and figures; return both.

    Figures are PNG, and SVG as well with ``svg`` (drawing them takes as long again), in
    ``style`` (a :class:`softseq_ros.analysis.figures.FigureStyle`; default: paper). A
    command that started a figure worker early (:mod:`softseq_ros.analysis.figure_workers`)
    passes it as ``workers`` and ends it itself; otherwise one is started here.
    """
    out = Path(out)
    own = None
    if figures and workers is None:
        from softseq_ros.analysis.figure_workers import start_workers

        workers = own = start_workers(svg)
    try:
        return _write_report(bag, out, scene_name, experiment_csv, reference_file, namespace,
                             svg, figures, workers, style)
    finally:
        if own is not None:
            from softseq_ros.analysis.figure_workers import stop_workers

            stop_workers(own)


REGULATED_SCENE_NOTE = (
    "the scene's supply is a pressure regulator: each segment is a hysteron of its own at the "
    'target pressure, so the volume-controlled equilibrium set and the quasi-static lag are '
    'not drawn beside the recording (softseq solve SCENE follows the hysterons)')


def _write_report(bag: str | os.PathLike, out: Path, scene_name: str | None,
                  experiment_csv: str | os.PathLike | None,
                  reference_file: str | os.PathLike | None, namespace: str | None, svg: bool,
                  figures: bool, workers: object | None,
                  style: object | None = None) -> tuple[dict, str]:
    experiment = read_experiment(experiment_csv) if experiment_csv is not None else None
    reference = load_reference(reference_file) if reference_file is not None else None
    scene = emap = None
    notes = []
    if scene_name is not None:
        from softseq_ros.quasistatic.solve import segments_graph
        from softseq_ros.scene.loader import load_scene

        scene = load_scene(scene_name, segments_graph)
    recording = load_recording(bag, namespace)
    if reference is not None:
        check_reference_segments(reference_file, reference, recording.segment_names)
    if scene is not None and scene.regulator is not None:
        # The scene's equilibrium set is the volume-controlled one: behind a regulator each
        # segment is a hysteron of its own, and the set would mislead beside the recording.
        notes.append(REGULATED_SCENE_NOTE)
        scene = None
    if scene is not None:
        # Before the equilibrium set is assembled and before anything is written.
        notes = scene_notes(recording, scene)
        from softseq_ros.quasistatic.solve import scene_map

        emap = scene_map(scene)
    transients = analyse_transients(recording, emap, _network(scene))
    metrics = recording_metrics(recording, scene, emap, transients)
    metrics['notes'].extend(notes)
    if experiment is not None:
        metrics['warnings'].extend(experiment.warnings)
        metrics['experiment'] = compare(recording_trace(recording), experiment,
                                        recording.snapshots)
    if reference is not None:
        metrics['reference'] = against_reference(metrics, reference)
    with writing(out):
        out.mkdir(parents=True, exist_ok=True)
    written = []
    if figures:
        from softseq_ros.analysis.figures import PAPER, write_figures

        written = write_figures(recording, emap, out, experiment, svg, workers, transients,
                                style or PAPER)
    metrics['figures'] = [p.name for p in written]
    write_text(out / 'metrics.json', json.dumps(metrics, indent=2, default=_json) + '\n')
    text = summary_text(metrics)
    write_text(out / 'summary.txt', text + '\n')
    write_text(out / 'report.md', markdown(metrics))
    return metrics, text


def _json(value: object) -> object:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f'not JSON serialisable: {type(value).__name__}')


def _ml(value: float | None, digits: int = 2) -> str:
    return '-' if value is None else f'{value * ML:.{digits}f} mL'


def _kpa(value: float | None, digits: int = 2) -> str:
    return '-' if value is None else f'{value * KPA:.{digits}f} kPa'


def _ml_per_s(value: float | None) -> str:
    return '-' if value is None or not np.isfinite(value) else f'{value * ML:.4g} mL/s'


def _share(spread: dict) -> str:
    return (f'{_ml(spread["largest_m3"], 4)} ({spread["largest_share_of_range"] * 100:.3g} % '
            f'of the range), median {_ml(spread["median_m3"], 4)}')


def _peak_channel(peaks: dict, show: object) -> str:
    """The channel with the largest peak, in display units (``show``), naming the channel."""
    found = {name: value for name, value in peaks.items() if value is not None}
    if not found:
        return '-'
    name = max(found, key=lambda key: abs(found[key]))
    return f'{show(found[name])} ({name})'


def _delay(snap: dict) -> str:
    if snap['delay_injected_m3'] is None:
        return ''
    return (f'; its exchange peaks late by {_ml(snap["delay_injected_m3"], 3)} injected after '
            f'the quasi-static snap at {_ml(snap["quasi_static_injected_m3"], 3)}')


def parties(snap: dict) -> str:
    """'top -> bottom': the segments that gave the fluid and those that took it."""
    giving, taking = snap.get('giving_segments'), snap.get('taking_segments')
    if giving is None and taking is None:
        return '-'
    return f'{" + ".join(giving or []) or "-"} -> {" + ".join(taking or []) or "-"}'


def _reynolds_line(transients: dict, sentence: bool = False) -> str:
    """Each channel's peak Reynolds number over the recorded flows, or what it needs."""
    reynolds = transients.get('peak_reynolds')
    line = ('peak Reynolds number per channel: needs the scene (--scene)' if reynolds is None else
            'peak Reynolds number per channel (recorded flows; laminar below about 2300): '
            + ', '.join(f'{name} {peak:.0f}' for name, peak in reynolds.items()))
    return 'P' + line[1:] + '.' if sentence else line


def _exchange_text(exchange: dict) -> str:
    """One exchange of fluid that was no snap-through, for humans."""
    return (f'{exchange["direction"]} at {_ml(exchange["injected_m3"], 3)}, '
            f't = {exchange["start_time_s"]:.3f} s: {_ml(exchange["fluid_moved_m3"], 3)} moved '
            f'({parties(exchange)}), 10-90 % in {duration_text(exchange["duration_s"])}'
            + _cut_text(exchange))


def _cut_text(exchange: dict) -> str:
    """Said of an exchange the run's end cut short: its numbers stop there."""
    return (' (still under way when the run ended: its numbers are up to there)'
            if exchange.get('cut_short') else '')


def _transient_lines(transients: dict) -> list[str]:
    """The summary's lines on a dynamic recording's transients."""
    snaps = transients['snaps']
    channels = ', '.join(transients['channels']) or 'none recorded'
    lines = [f'transients (fluid network; channels {channels}): {len(snaps)} snap-through'
             f'{"s" if len(snaps) != 1 else ""} in time']
    for number, snap in enumerate(snaps, start=1):
        lines.append(
            f'  snap {number} ({snap["direction"]}) at {_ml(snap["injected_m3"], 3)}, '
            f't = {snap["start_time_s"]:.3f} s: 10-90 % in {duration_text(snap["duration_s"])}, '
            f'{_ml(snap["fluid_moved_m3"], 3)} moved ({parties(snap)}), peak exchange '
            f'{_ml_per_s(snap["peak_exchange_m3_per_s"])}, gauge pressure '
            f'{_kpa(snap["from_pressure_pa"])} -> {_kpa(snap["to_pressure_pa"])}'
            + _cut_text(snap))
        lines.append(
            f'    peak channel flow {_peak_channel(snap["peak_channel_flow_m3_per_s"], _ml_per_s)}'
            f', peak pressure drop {_peak_channel(snap["peak_pressure_drop_pa"], _kpa)}'
            + _delay(snap))
    others = transients.get('exchanges') or []
    if others:
        lines.append(f'  other exchanges of fluid between the segments (no instability: the '
                     f'fluid lagging the pump or evening out): {len(others)}')
        lines += [f'    {_exchange_text(e)}' for e in others]
    lines.append('  ' + _reynolds_line(transients))
    lag = transients['lag']
    if lag is None:
        lines.append('  lag behind the quasi-static path: needs the scene (--scene)')
        return lines
    parts = []
    for key, where in (('off_snaps', 'off the snaps'), ('at_snaps', 'at the snaps')):
        if lag[key] is not None:
            parts.append(f'{where} largest {_share(lag[key])}')
    lines.append('  lag behind the quasi-static path (segment volume at the same injected '
                 'volume): ' + ('; '.join(parts) or '-'))
    if lag['quasi_static_snaps_not_followed_m3']:
        lines.append('  quasi-static snaps the recording never followed: '
                     + ', '.join(_ml(u, 3) for u in lag['quasi_static_snaps_not_followed_m3']))
    return lines


BRANCHES_SHOWN = 12   # stays on a branch listed in the summary; metrics.json has them all


def _run_lines(metrics: dict, segments: list[str]) -> list[str]:
    """The summary's lines on one run: type, switch, peak, plateau, snaps, hysteresis, steps."""
    lines = []
    end = metrics.get('pump_end')
    cut_short = end is not None and end['state'] in CUT_SHORT
    if cut_short:
        lines.append(f'pump {end["state"]} at {end["time_s"]:.3f} s, {_ml(end["injected_m3"])} '
                     f'injected: {end["reason"] or "no reason given"} (the programme did not '
                     'run to its end: what follows is that of the part it ran)')
    scene_type = metrics.get('sequence_type_of_scene')
    lines.append(f'sequence type: {metrics["sequence_type"]} (from the recording'
                 + (', cut short' if cut_short else '') + ')'
                 + (f'; scene: {scene_type}' if scene_type else ''))
    lead = metrics.get('lead')
    if lead:
        lines.append(f'lead: {lead["segment_leading"]} leads the inflow from '
                     f'{_ml(lead["injected_m3"])} injected (the first to take '
                     f'{LEAD_SHARE * 100:.0f} % of it)')
    elif 'lead' in metrics:
        lines.append(f'lead: {_not_applied(metrics, "lead")}')
    switch = metrics.get('switch')
    if switch:
        lines.append(f'switch: at {_ml(switch["injected_m3"])} injected, '
                     f'{switch["segment_taking_over"]} takes over the inflow (the largest change '
                     "of a segment's share)")
    else:
        lines.append(f'switch: {_not_applied(metrics, "switch")}')
    peak = metrics['peak_injection']
    split = ', '.join(f'{name} {share * 100:.0f} %' for name, share in
                      zip(segments, peak['share_of_added_volume']))
    lines.append(f'at peak injection: gauge pressure {_kpa(peak["pressure_pa"])}, '
                 f'added volume split {split}')
    plateau = metrics.get('plateau')
    if plateau:
        level = plateau.get('level_m3')
        stretch = (f', level from {_ml(level[0], 1)} to {_ml(level[1], 1)}' if level else '')
        lines.append(f'plateau: {_kpa(plateau["pressure_pa"])} gauge{stretch}, '
                     f'95 % of it reached at {_ml(plateau["onset_injected_m3"])}')
    else:
        lines.append(f'plateau: {_not_applied(metrics, "plateau")}')
    if metrics['snaps']:
        for snap in metrics['snaps']:
            lines.append(f'snap-through at {_ml(snap["injected_m3"], 3)} ({snap["direction"]}): '
                         f'gauge pressure {_kpa(snap["from_pressure_pa"])} -> '
                         f'{_ml_moved(snap)}')
    else:
        lines.append('snap-throughs: none')
    lines.append(f'hysteresis area: {_mj(metrics, "hysteresis_area_j")}'
                 + (f" (the segments' own, quasi-statically: "
                    f'{_mj(metrics, "hysteresis_area_quasi_static_j")}; the rest, '
                    f'{_mj(metrics, "hysteresis_area_rate_dependent_j")}, is the flow\'s '
                    'viscous loss, which vanishes as the pump slows)'
                    if 'hysteresis_area_quasi_static_j' in metrics else ''))
    first, later = _first_cycle_steps(metrics)
    for step in first:
        tip = step['tip_m']
        angle = step.get('tip_angle_rad')
        lines.append(f'step {step["step"]} ({step["direction"]}) at {_ml(step["injected_m3"], 1)}'
                     f': tip at x {tip[0] * MM:.1f} mm, z {tip[1] * MM:.1f} mm'
                     + (f', tip angle {np.degrees(angle):.1f} deg' if angle is not None else ''))
    if later:
        lines.append(f'({later} snapshots of later cycles in metrics.json)')
    return lines


def summary_text(metrics: dict) -> str:
    """A few lines a researcher reads first."""
    lines = [f'recording: {metrics["bag"]} (namespace {metrics["namespace"]})']
    recorded = metrics.get('recorded_scene')
    if recorded:
        checked = (f'checked against scene {metrics["scene"]}' if metrics.get('scene') else
                   'as recorded; no scene given to check it against')
        lines.append(f'scene: {recorded["scene"]} (segments '
                     f'{", ".join(recorded["segments"])}, sha256 '
                     f'{short(recorded["segments_sha256"])}; {checked})')
    runs = metrics.get('runs') or []
    injected = [r['injected_range_m3'] for r in runs] or [metrics['injected_range_m3']]
    lines.append(f'duration: {metrics["duration_s"]:.1f} s of rig time, injected '
                 f'{_ml(min(r[0] for r in injected))} to {_ml(max(r[1] for r in injected))}')
    if runs:
        lines.append(f'runs: {len(runs)} in the bag (the pump reset or restarted, or the '
                     'actuator restarted); run 1 first, then each other run')
    lines.extend(_run_lines(metrics, metrics['segments']))
    stays = metrics.get('branches_visited')
    if stays:
        shown = ' -> '.join(f'#{s["branch"]} ({s["state"]})' for s in stays[:BRANCHES_SHOWN])
        more = len(stays) - BRANCHES_SHOWN
        lines.append(f'branches visited (softseq graph numbering): {shown}'
                     + (f' and {more} more stays (metrics.json)' if more > 0 else ''))
    if 'transients' in metrics:
        lines.extend(_transient_lines(metrics['transients']))
    for run in runs[1:]:
        lines.append(f'run {run["run"]} (from {run["from_s"]:.3f} s to {run["until_s"]:.3f} s; '
                     f'began: {run["began"]}):')
        lines.extend('  ' + line for line in _run_lines(run, metrics['segments']))
    experiment = metrics.get('experiment')
    if experiment:
        lines.append(f'experiment {experiment["file"]}: PV RMSE {_kpa(experiment["pv_rmse_pa"])}'
                     f', max {_kpa(experiment["pv_max_error_pa"])} '
                     f'({experiment["rows_outside_model_range"]} rows outside the recording)')
        align = experiment.get('alignment')
        if align:
            lines.append(f'  best alignment: experiment = {align["pressure_scale"]:.4f} x model('
                         f'u - {_ml(align["volume_shift_m3"], 3)}), RMSE after '
                         f'{_kpa(align["rmse_after_pa"])}')
        for tip in experiment['tip_errors']:
            lines.append(f'  step {tip["step"]} ({tip["direction"]}): tip error '
                         f'{tip["error_m"] * MM:.1f} mm')
    reference = metrics.get('reference')
    if reference:
        lines.append(f'against {reference["source"]}:')
        lines.extend('  ' + _check_text(check) for check in reference['checks'])
    for note in metrics.get('notes', []):
        lines.append(f'note: {note}')
    for warning in metrics['warnings']:
        lines.append(f'warning: {warning}')
    return '\n'.join(lines)


def not_applicable_reason(metrics: dict, key: str) -> str | None:
    """Why metric ``key`` does not apply to the run, None when it applies."""
    return (metrics.get('not_applicable') or {}).get(key)


def _not_applied(metrics: dict, key: str) -> str:
    """A metric's absence in words: 'does not apply (why)'."""
    return f'does not apply ({not_applicable_reason(metrics, key) or "not measured"})'


def _mj(metrics: dict, key: str) -> str:
    value = metrics.get(key)
    return _not_applied(metrics, key) if value is None else millijoules_text(value)


def _first_cycle_steps(metrics: dict) -> tuple[list[dict], int]:
    first = [step for step in metrics['steps'] if step.get('cycle', 1) == 1]
    return first, len(metrics['steps']) - len(first)


def _check_text(check: dict) -> str:
    mark = {True: 'agrees', False: 'differs', None: ''}.get(check.get('agrees'), '')
    if 'recorded_m3' in check:
        recorded = _ml(check['recorded_m3'], 1)
        if check.get('recorded_does_not_apply'):
            recorded = f'none (does not apply: {check["recorded_does_not_apply"]})'
        parts = [f'{check["what"]}: recorded {recorded}']
        for key in ('reported_m3', 'simulation_reported_m3', 'experiment_reported_m3'):
            if key in check:
                label = key.replace('_reported_m3', '').replace('reported_m3', 'reported')
                parts.append(f'{label or "reported"} {_ml(check[key], 1)}')
        return ', '.join(parts) + (f' ({mark})' if mark else '')
    recorded = check['recorded']
    if check.get('recorded_does_not_apply'):
        recorded = f'none (does not apply: {check["recorded_does_not_apply"]})'
    return f'{check["what"]}: recorded {recorded}, reported {check["reported"]} ({mark})'


def _transient_markdown(transients: dict) -> list[str]:
    lines = ['', '## Transients (fluid network)', '',
             'Snap-throughs in time as the actuator reported them: duration from 10 % to 90 % '
             'of the fluid moved; from -> to: the segments that gave the fluid and those that '
             'took it; peak channel flow (positive towards the tip) and pressure drop within '
             'the window shown in `transients.png`; late by: injected volume pumped between '
             "the quasi-static snap and the peak of this one's exchange.", '']
    if transients['snaps']:
        lines += ['| snap | direction | start | injected | duration | fluid moved | from -> to | '
                  'peak exchange | gauge pressure | peak channel flow | peak pressure drop | '
                  'late by |', '|---:|---|---:|---:|---:|---:|---|---:|---|---|---|---:|']
        for number, snap in enumerate(transients['snaps'], start=1):
            lines.append(
                f'| {number} | {snap["direction"]} | {snap["start_time_s"]:.3f} s | '
                f'{_ml(snap["injected_m3"], 3)} | {duration_text(snap["duration_s"])}'
                f'{" (cut short by the end of the run)" if snap.get("cut_short") else ""} | '
                f'{_ml(snap["fluid_moved_m3"], 3)} | {parties(snap)} | '
                f'{_ml_per_s(snap["peak_exchange_m3_per_s"])} | '
                f'{_kpa(snap["from_pressure_pa"])} -> {_kpa(snap["to_pressure_pa"])} | '
                f'{_peak_channel(snap["peak_channel_flow_m3_per_s"], _ml_per_s)} | '
                f'{_peak_channel(snap["peak_pressure_drop_pa"], _kpa)} | '
                f'{_ml(snap["delay_injected_m3"], 3)} |')
    else:
        lines.append('No snap-through in time was reported.')
    others = transients.get('exchanges') or []
    if others:
        lines += ['', 'Other exchanges of fluid between the segments, without instability (the '
                  'fluid lagging the pump or evening out; docs/dynamic.md):', '']
        lines += [f'- {_exchange_text(e)}' for e in others]
    lines += ['', _reynolds_line(transients, sentence=True)]
    lag = transients['lag']
    lines += ['', 'Lag behind the quasi-static path: the largest difference of a segment '
              'volume from the quasi-static one at the same injected volume.', '']
    if lag is None:
        lines.append('Not computed: it needs the scene (`--scene`).')
        return lines
    lines += ['| where | largest | median | states |', '|---|---:|---:|---:|']
    for key, where in (('off_snaps', 'off the snaps'), ('at_snaps', 'at the snaps')):
        spread = lag[key]
        if spread is None:
            lines.append(f'| {where} | - | - | 0 |')
            continue
        lines.append(f'| {where} | {_ml(spread["largest_m3"], 4)} '
                     f'({spread["largest_share_of_range"] * 100:.3g} %) | '
                     f'{_ml(spread["median_m3"], 4)} '
                     f'({spread["median_share_of_range"] * 100:.3g} %) | {spread["states"]} |')
    if lag['quasi_static_snaps_not_followed_m3']:
        lines += ['', 'Quasi-static snaps the recording never followed: '
                  + ', '.join(_ml(u, 3) for u in lag['quasi_static_snaps_not_followed_m3'])
                  + '.']
    return lines


def _runs_markdown(runs: list[dict]) -> list[str]:
    """report.md's table of the runs of a bag that holds several (the numbers above: run 1)."""
    lines = ['', '## Runs', '', f'The bag holds {len(runs)} pump runs; the numbers above are '
             'those of run 1, each run is measured on its own here (all in `metrics.json`, '
             '`runs`).', '', '| run | from | until | began | sequence type | injected up to | '
             'switch | plateau | snap-throughs | hysteresis area |',
             '|---:|---:|---:|---|---|---:|---|---|---:|---|']
    for run in runs:
        switch, plateau = run['switch'], run['plateau']
        lines.append(
            f'| {run["run"]} | {run["from_s"]:.3f} s | {run["until_s"]:.3f} s | {run["began"]} '
            f'| {run["sequence_type"]} | {_ml(run["injected_range_m3"][1])} | '
            + (f'{_ml(switch["injected_m3"])}, {switch["segment_taking_over"]}' if switch
               else _not_applied(run, 'switch'))
            + ' | ' + (f'{_kpa(plateau["pressure_pa"])} from {_ml(plateau["onset_injected_m3"])}'
                       if plateau else _not_applied(run, 'plateau'))
            + f' | {run["snap_count"]} | {_mj(run, "hysteresis_area_j")} |')
    return lines


def markdown(metrics: dict) -> str:
    """report.md: the summary as a short document with tables."""
    lines = [f'# Report of `{metrics["bag"]}`', '',
             'Pressures are gauge; the numbers in SI are in `metrics.json`.', '',
             '| quantity | value |', '|---|---|',
             f'| sequence type (recording) | {metrics["sequence_type"]} |']
    recorded = metrics.get('recorded_scene')
    if recorded:
        lines.insert(-1, f'| scene (recorded) | `{recorded["scene"]}`, segments sha256 '
                         f'`{short(recorded["segments_sha256"])}` |')
    if metrics.get('sequence_type_of_scene'):
        lines.append(f'| sequence type (scene `{metrics["scene"]}`) | '
                     f'{metrics["sequence_type_of_scene"]} |')
    lead = metrics.get('lead')
    if 'lead' in metrics:
        lines.append(f'| lead (first to take {LEAD_SHARE * 100:.0f} % of the inflow) | '
                     + (f'{lead["segment_leading"]} leads from {_ml(lead["injected_m3"])}'
                        if lead else _not_applied(metrics, 'lead')) + ' |')
    switch = metrics.get('switch')
    lines.append("| switch (largest change of a segment's share of the inflow) | "
                 + (f'{_ml(switch["injected_m3"])}, {switch["segment_taking_over"]} takes over'
                    if switch else _not_applied(metrics, 'switch')) + ' |')
    plateau = metrics.get('plateau')
    if plateau:
        lines.append(f'| plateau pressure | {_kpa(plateau["pressure_pa"])} |')
        lines.append(f'| plateau reached (95 %) at | {_ml(plateau["onset_injected_m3"])} |')
    else:
        lines.append(f'| plateau | {_not_applied(metrics, "plateau")} |')
    lines.append(f'| hysteresis area | {_mj(metrics, "hysteresis_area_j")} |')
    lines.append(f'| snap-throughs | {metrics["snap_count"]} |')
    for name, limit in (metrics.get('segment_pressure_limits_pa') or {}).items():
        lines.append(f'| {name}: highest pressure of its curve (peak or plateau) | '
                     f'{_kpa(limit)} |')
    if metrics.get('runs'):
        lines += _runs_markdown(metrics['runs'])
    if metrics['snaps']:
        lines += ['', '## Snap-throughs', '', '| injected | direction | gauge pressure | '
                  'fluid moved |', '|---:|---|---|---:|']
        for snap in metrics['snaps']:
            lines.append(f'| {_ml(snap["injected_m3"], 3)} | {snap["direction"]} | '
                         f'{_kpa(snap["from_pressure_pa"])} -> {_kpa(snap["to_pressure_pa"])} | '
                         f'{_ml(snap["fluid_moved_m3"], 3)} |')
    if 'transients' in metrics:
        lines += _transient_markdown(metrics['transients'])
    first, later = _first_cycle_steps(metrics)
    if first:
        lines += ['', '## Steps (camera snapshots, first cycle)', '',
                  '| step | direction | injected | tip x | tip z | tip angle |',
                  '|---:|---|---:|---:|---:|---:|']
        if later:
            lines.insert(-2, f'{later} snapshots of later cycles are in `metrics.json`.\n')
        for step in first:
            angle = step.get('tip_angle_rad')
            lines.append(f'| {step["step"]} | {step["direction"]} | '
                         f'{_ml(step["injected_m3"], 1)} | {step["tip_m"][0] * MM:.1f} mm | '
                         f'{step["tip_m"][1] * MM:.1f} mm | '
                         + (f'{np.degrees(angle):.1f} deg |' if angle is not None else '- |'))
    experiment = metrics.get('experiment')
    if experiment:
        align = experiment.get('alignment') or {}
        lines += ['', f'## Against the experiment `{experiment["file"]}`', '',
                  '| quantity | value |', '|---|---|',
                  f'| PV RMSE | {_kpa(experiment["pv_rmse_pa"], 3)} |',
                  f'| PV max error | {_kpa(experiment["pv_max_error_pa"], 3)} |',
                  f"| rows outside the recording's range | "
                  f'{experiment["rows_outside_model_range"]} |',
                  f'| best volume shift | {_ml(align.get("volume_shift_m3"), 3)} |',
                  f'| best pressure scale | {align.get("pressure_scale", float("nan")):.4f} |',
                  f'| RMSE after alignment | {_kpa(align.get("rmse_after_pa"), 3)} |']
        for tip in experiment['tip_errors']:
            lines.append(f'| step {tip["step"]} ({tip["direction"]}) tip error | '
                         f'{tip["error_m"] * MM:.2f} mm |')
    reference = metrics.get('reference')
    if reference:
        lines += ['', f'## Against {reference["source"]}', '']
        lines.extend(f'- {_check_text(check)}' for check in reference['checks'])
    if metrics.get('notes'):
        lines += ['', '## Notes', '']
        lines.extend(f'- {note}' for note in metrics['notes'])
    if metrics['warnings']:
        lines += ['', '## Warnings', '']
        lines.extend(f'- {warning}' for warning in metrics['warnings'])
    if metrics.get('figures'):
        lines += ['', '## Figures', '']
        lines.extend(f'![{name}]({name})' for name in metrics['figures'] if name.endswith('.png'))
    return '\n'.join(lines) + '\n'


__all__ = ['Experiment', 'SceneMismatchError', 'against_reference', 'check_scene',
           'load_reference', 'markdown', 'not_applicable_reason', 'recording_metrics',
           'recording_trace', 'scene_notes', 'summary_text', 'write_report']
