"""
How robust a sequence verdict is: the smallest pressure feature it rests on, against the noise.

A symmetric or asymmetric verdict rests on the peaks and valleys of the segments' PV curves;
each one, however small, is taken seriously by the solver. The smallest feature is the smallest
pressure change of a monotone piece next to an interior extremum (a peak-valley depth). It is
compared with the table's noise: the ``noise_std_pa`` a segment declares (its ``smoothing``
block in the scene, or a ``# noise_std_pa: X`` comment line in its table), else an estimate
from the table's rows (second differences, which a smooth table keeps far below its features).
"""

from dataclasses import dataclass
from pathlib import Path
import re

import numpy as np

from softseq_ros.segments.models import TabulatedSegment

# A feature below this many noise deviations may be noise itself.
NOISE_FACTOR = 3.0
CLOSED_FORM = 'a closed-form law'   # a segment's noise source when it is no table
_NOISE_LINE = re.compile(r'^\s*#\s*noise_std_pa\s*:\s*([0-9.eE+-]+)', re.MULTILINE)


@dataclass
class Feature:
    """The smallest peak-valley depth of one segment."""

    segment: str
    depth_pa: float
    at_volume_m3: float
    noise_pa: float | None
    noise_source: str


def _declared_noise(segment: object, scene_entry: dict | None) -> float | None:
    smoothing = (scene_entry or {}).get('smoothing') or {}
    if isinstance(smoothing, dict) and smoothing.get('noise_std_pa') is not None:
        return float(smoothing['noise_std_pa'])
    source = getattr(segment, 'source', '')
    path = Path(source.replace(' (smoothed)', '')) if source else None
    if path is not None and path.is_file():
        found = _NOISE_LINE.search(path.read_text())
        if found:
            return float(found.group(1))
    return None


def _estimated_noise(segment: object) -> float | None:
    pressures = getattr(segment, 'pressures', None)
    if pressures is None or len(pressures) < 5:
        return None
    # For white noise of deviation s, p[i-1] - 2 p[i] + p[i+1] has deviation s * sqrt(6); the
    # median absolute deviation keeps the knees of a smooth curve from counting.
    second = np.diff(np.asarray(pressures), 2)
    return float(1.4826 * np.median(np.abs(second - np.median(second))) / np.sqrt(6.0))


def smallest_features(segments: list, scene_entries: list[dict] | None = None) -> list[Feature]:
    """Per segment with a peak or valley: its smallest peak-valley depth and the noise."""
    features = []
    for index, segment in enumerate(segments):
        pieces = segment.monotone_pieces()
        if len(pieces) < 2:
            continue
        depths = [(abs(pc.p_at_hi - pc.p_at_lo), pc.v_lo if k else pc.v_hi)
                  for k, pc in enumerate(pieces)]
        depth, volume = min(depths)
        entry = scene_entries[index] if scene_entries and index < len(scene_entries) else None
        noise = _declared_noise(segment, entry)
        source = 'declared'
        if noise is None and not isinstance(segment, TabulatedSegment):
            noise, source = 0.0, CLOSED_FORM   # a law's curve has no measurement noise
        elif noise is None:
            noise, source = _estimated_noise(segment), 'estimated from the table rows'
        features.append(Feature(segment.name, float(depth), float(volume), noise, source))
    return features


def robustness_lines(verdict: str, features: list[Feature]) -> tuple[list[str], list[str]]:
    """
    Lines that say what the verdict rests on, and warnings when that is near the noise.

    Monotone curves give no lines: such a verdict rests on no peak or valley a wiggle could fake.
    """
    if not features:
        return [], []
    lines, warnings = [], []
    for feature in features:
        if feature.noise_source == CLOSED_FORM:
            noise = f'none ({CLOSED_FORM})'
        elif feature.noise_pa is not None:
            noise = f'{feature.noise_pa:.3g} Pa ({feature.noise_source})'
        else:
            noise = 'unknown (too few table rows to estimate it)'
        lines.append(f'robustness: segment {feature.segment}: smallest peak-valley depth '
                     f'{feature.depth_pa:.3g} Pa (at {feature.at_volume_m3:.6g} m^3), '
                     f'noise {noise}')
        if feature.noise_pa is not None and feature.depth_pa < NOISE_FACTOR * feature.noise_pa:
            warnings.append(
                f'the {verdict} verdict rests on a feature of segment {feature.segment} '
                f'({feature.depth_pa:.3g} Pa) near or below {NOISE_FACTOR:g} x its noise '
                f'({feature.noise_pa:.3g} Pa): it may be noise; smooth the table '
                '(smoothing: {} in the scene)')
    return lines, warnings


def scene_features(scene: object) -> list[Feature]:
    """:func:`smallest_features` of a loaded scene, reading its segment entries for noise."""
    import yaml

    entries = None
    if getattr(scene, 'path', None) is not None:
        try:
            entries = (yaml.safe_load(Path(scene.path).read_text()) or {}).get('segments')
        except (OSError, yaml.YAMLError, AttributeError):
            entries = None
    return smallest_features(list(scene.segments), entries if isinstance(entries, list)
                             else None)
