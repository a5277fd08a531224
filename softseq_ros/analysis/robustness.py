"""
How robust a sequence verdict is: the peak-valley features it rests on, against the noise.

A symmetric or asymmetric verdict rests on peaks and valleys of the segments' PV curves. A
*feature* is one falling stretch of a curve, from a peak to the valley after it (flat rows, such
as two equal readings of a quantised sensor, neither start nor end one); its depth is the
pressure the curve loses there. The features a verdict rests on are those the solver's paths
use (:func:`deciding_features`): a segment that jumps across a feature in a snap-through, or
whose volume goes through one (losing volume while the total grows). A wiggle that no path uses
decides nothing, however small it is.

Each feature is compared with its segment's noise: the ``noise_std_pa`` a segment declares (its
``smoothing`` block in the scene, or a ``# noise_std_pa: X`` comment line in its table; in a
table written by ``softseq fit`` that line is the fitted curve's standard error, and is named
so, since such rows are a law's and carry no scatter to estimate), else an
estimate from the table's rows as read (:func:`~softseq_ros.segments.smoothing.estimated_noise`:
the residuals of local cubic fits, which a smooth curve keeps near zero however curved it is).
A smoothed table is judged by the noise of its rows before the smoothing, never by what is left
of it after (a fraction of it: the features would look many times more significant than they
are). A closed-form law has no noise. The verdict is flagged when even the most significant
feature it rests on (the deepest against its
noise) is within NOISE_FACTOR noise deviations.
"""

from dataclasses import dataclass, field
from pathlib import Path
import re

import numpy as np

from softseq_ros.segments.models import TabulatedSegment
from softseq_ros.segments.smoothing import estimated_noise

# A feature below this many noise deviations may be noise itself.
NOISE_FACTOR = 3.0
CLOSED_FORM = 'a closed-form law'   # a segment's noise source when it is no table
ESTIMATED = 'estimated from the table rows'
ESTIMATED_RAW = 'estimated from the table rows as read, before smoothing'
DECLARED = 'declared'
FITTED = "the fitted curve's standard error, which softseq fit wrote"
_NOISE_LINE = re.compile(r'^\s*#\s*noise_std_pa\s*:\s*([0-9.eE+-]+)', re.MULTILINE)
# softseq fit's segment tables (softseq_ros/analysis/fit_outputs.py): a law's rows, their
# # noise_std_pa: line the curve's uncertainty and the measured noise on a line of its own.
_FIT_LINES = (re.compile(r'^\s*#\s*softseq fit:', re.MULTILINE),
              re.compile(r'^\s*#\s*measured_noise_std_pa\s*:', re.MULTILINE))
# Features listed per verdict; the others are counted.
FEATURES_SHOWN = 4


@dataclass
class Feature:
    """One peak-valley feature of a segment's curve: peak, valley, depth, and the noise."""

    segment: str
    depth_pa: float
    peak_m3: float
    peak_pa: float
    valley_m3: float
    valley_pa: float
    noise_pa: float | None
    noise_source: str
    # What the solver's paths do with it: snap-throughs across it, (leg, injected volume [m^3]),
    # and the injected volumes between which the segment goes through it on inflation.
    snaps: list[tuple[str, float]] = field(default_factory=list)
    through_m3: tuple[float, float] | None = None

    @property
    def used(self) -> bool:
        """Whether a path of the solver uses the feature."""
        return bool(self.snaps) or self.through_m3 is not None

    @property
    def uses(self) -> str:
        """What the solver's paths do with the feature, in words."""
        parts = []
        for leg in ('inflation', 'deflation'):
            at = [_ml(u) for kind, u in self.snaps if kind == leg]
            if at:
                parts.append(f'snap-through{"s" if len(at) > 1 else ""} across it on {leg} '
                             f'at {", ".join(at)} injected')
        if self.through_m3 is not None:
            parts.append(f'the segment goes through it, losing volume, on inflation from '
                         f'{_ml(self.through_m3[0])} to {_ml(self.through_m3[1])} injected')
        return '; '.join(parts)

    @property
    def at_volume_m3(self) -> float:
        """Where the feature starts: its peak's volume."""
        return self.peak_m3

    @property
    def significance(self) -> float:
        """Depth in noise deviations (infinite without noise)."""
        if not self.noise_pa:
            return np.inf if self.noise_pa is not None else 0.0
        return self.depth_pa / self.noise_pa


def peak_valleys(segment: object) -> list[tuple[float, float, float, float]]:
    """
    The falling stretches of a segment's curve, base to top.

    Each is (peak volume, peak pressure, valley volume, valley pressure), built from the
    curve's monotone pieces: a flat piece neither starts nor ends a stretch, so a falling
    stretch broken by equal readings is one feature.
    """
    stretches: list[list[float]] = []
    previous = 0   # the direction of the last piece that was not flat
    for piece in segment.monotone_pieces():
        if piece.direction == 0:
            continue
        if piece.direction < 0:
            if previous < 0 and stretches:
                stretches[-1][2:] = [piece.v_hi, piece.p_at_hi]
            else:
                stretches.append([piece.v_lo, piece.p_at_lo, piece.v_hi, piece.p_at_hi])
        previous = piece.direction
    return [tuple(float(x) for x in stretch) for stretch in stretches]


def _declared_noise(segment: object, scene_entry: dict | None) -> tuple[float | None, str]:
    # The smoothing's options travel with a smoothed table; a scene entry is read for the rest.
    for options in reversed(getattr(segment, 'smoothing', ())):
        if options.get('noise_std_pa') is not None:
            return float(options['noise_std_pa']), DECLARED
    smoothing = (scene_entry or {}).get('smoothing') or {}
    if isinstance(smoothing, dict) and smoothing.get('noise_std_pa') is not None:
        return float(smoothing['noise_std_pa']), DECLARED
    source = getattr(segment, 'source', '')
    path = Path(source.replace(' (smoothed)', '')) if source else None
    if path is not None and path.is_file():
        text = path.read_text()
        found = _NOISE_LINE.search(text)
        if found:
            fitted = all(line.search(text) for line in _FIT_LINES)
            return float(found.group(1)), FITTED if fitted else DECLARED
    return None, DECLARED


def segment_noise(segment: object, scene_entry: dict | None = None) -> tuple[float | None, str]:
    """
    A segment's pressure noise [Pa] and where it comes from (declared, fitted, estimated, a law).

    A table's noise is estimated from its rows as read: a smoothed table's ``table_pressures``,
    not the smoothed ones, whose residual wiggle is a fraction of the measurement's noise. A
    table ``softseq fit`` wrote declares its curve's standard error (:data:`FITTED`): its rows
    are a law's, whose scatter is next to none and would make every feature look significant.
    """
    noise, source = _declared_noise(segment, scene_entry)
    if noise is not None:
        return noise, source
    if not isinstance(segment, TabulatedSegment):
        return 0.0, CLOSED_FORM   # a law's curve has no measurement noise
    if segment.smoothing:
        return estimated_noise(segment.volumes, segment.table_pressures), ESTIMATED_RAW
    return estimated_noise(segment.volumes, segment.pressures), ESTIMATED


def segment_features(segment: object, scene_entry: dict | None = None) -> list[Feature]:
    """Every peak-valley feature of one segment, with its noise."""
    stretches = peak_valleys(segment)
    if not stretches:
        return []
    noise, source = segment_noise(segment, scene_entry)
    return [Feature(segment.name, peak_p - valley_p, peak_v, peak_p, valley_v, valley_p,
                    noise, source) for peak_v, peak_p, valley_v, valley_p in stretches]


def _entry(scene_entries: list[dict] | None, index: int) -> dict | None:
    if scene_entries and index < len(scene_entries) and isinstance(scene_entries[index], dict):
        return scene_entries[index]
    return None


def smallest_features(segments: list, scene_entries: list[dict] | None = None) -> list[Feature]:
    """Per segment with a peak-valley feature: its shallowest one, and the noise."""
    found = []
    for index, segment in enumerate(segments):
        features = segment_features(segment, _entry(scene_entries, index))
        if features:
            found.append(min(features, key=lambda f: f.depth_pa))
    return found


def _ml(volume: float) -> str:
    return f'{volume * 1e6:.4g} mL'


def deciding_features(emap: object, scene_entries: list[dict] | None = None,
                      samples: int = 4001) -> tuple[list[Feature], list[Feature]]:
    """
    The features the solver's paths use, and those they do not, over the scene's range.

    The paths are the ones ``classify`` judges (inflation from rest to the end of the range and
    back). A feature is used when a segment's volume jumps across it in a snap-through (from
    before its peak to past its valley, or back), or when a segment's volume on the inflation
    path lies inside it: the segment loses volume while the total grows there.
    """
    from softseq_ros.quasistatic.equilibrium import inflate_and_deflate

    segments = list(emap.segments)
    features = [segment_features(segment, _entry(scene_entries, index))
                for index, segment in enumerate(segments)]
    if not any(features):
        return [], []
    inflation, deflation = inflate_and_deflate(emap, samples)
    tolerance = emap.tolerances.same_volume * float(emap.v_scale)
    for leg, path in (('inflation', inflation), ('deflation', deflation)):
        for event in path.events:
            before, after = np.asarray(event.from_volumes), np.asarray(event.to_volumes)
            crossed = []
            for j, found in enumerate(features):
                lo, hi = sorted((before[j], after[j]))
                crossed += [f for f in found if lo < f.valley_m3 - tolerance
                            and f.peak_m3 + tolerance < hi]
            if not crossed:
                # The fold itself: the feature with an end nearest to its segment's volume.
                nearest = min((min(abs(before[j] - f.peak_m3), abs(before[j] - f.valley_m3)),
                               j, k) for j, found in enumerate(features)
                              for k, f in enumerate(found))
                crossed = [features[nearest[1]][nearest[2]]]
            for feature in crossed:
                feature.snaps.append((leg, float(event.injected)))
    volumes = np.asarray(inflation.volumes)
    for j, found in enumerate(features):
        for feature in found:
            inside = (volumes[:, j] > feature.peak_m3 + tolerance) & \
                (volumes[:, j] < feature.valley_m3 - tolerance)
            if inside.any():
                where = np.asarray(inflation.injected)[inside]
                feature.through_m3 = (float(where[0]), float(where[-1]))
    flat = [f for found in features for f in found]
    return [f for f in flat if f.used], [f for f in flat if not f.used]


def _pa(value: float) -> str:
    return f'{value * 1e-3:.3g} kPa' if abs(value) >= 1e3 else f'{value:.3g} Pa'


def _noise_text(feature: Feature) -> str:
    if feature.noise_source == CLOSED_FORM:
        return f'noise none ({CLOSED_FORM})'
    if feature.noise_pa is None:
        return 'noise unknown (too few table rows to estimate it)'
    times = (f', {feature.significance:.3g} x the noise' if feature.noise_pa > 0 else '')
    return f'noise {_pa(feature.noise_pa)} ({feature.noise_source}){times}'


def _feature_text(feature: Feature) -> str:
    return (f'segment {feature.segment}: peak {feature.peak_pa * 1e-3:.4g} kPa at '
            f'{_ml(feature.peak_m3)}, valley {feature.valley_pa * 1e-3:.4g} kPa at '
            f'{_ml(feature.valley_m3)}: depth {_pa(feature.depth_pa)}, {_noise_text(feature)}')


def robustness_lines(verdict: str, used: list[Feature],
                     unused: list[Feature] | None = None) -> tuple[list[str], list[str]]:
    """
    Lines that say which features the verdict rests on, and a warning when they are noise-sized.

    ``used``: the features the solver's paths use (:func:`deciding_features`); ``unused``: the
    others, counted in one line. Monotone curves give no lines: such a verdict rests on no peak
    or valley a wiggle could fake. The verdict is flagged when even its most significant
    feature (deepest against its noise) is within NOISE_FACTOR noise deviations.
    """
    unused = unused or []
    if not used and not unused:
        return [], []
    lines, warnings = [], []
    ranked = sorted(used, key=lambda f: (-f.significance, -f.depth_pa))
    for feature in ranked[:FEATURES_SHOWN]:
        lines.append(f'robustness: the {verdict} verdict rests on {_feature_text(feature)} '
                     f'({feature.uses})')
    if len(ranked) > FEATURES_SHOWN:
        rest = ranked[FEATURES_SHOWN:]
        lines.append(f'robustness: and on {len(rest)} more features, the shallowest '
                     f'{_pa(min(f.depth_pa for f in rest))}')
    if unused:
        deepest = max(unused, key=lambda f: f.depth_pa)
        segments = sorted({f.segment for f in unused})
        lines.append(f'robustness: {len(unused)} peak-valley feature'
                     f'{"s" if len(unused) != 1 else ""} of segment'
                     f'{"s" if len(segments) != 1 else ""} {", ".join(segments)} play no part '
                     f'in the verdict (no path snaps across or goes through them; the deepest '
                     f'{_pa(deepest.depth_pa)})')
    if ranked:
        best = ranked[0]
        if best.noise_pa is not None and best.depth_pa < NOISE_FACTOR * best.noise_pa:
            warnings.append(
                f'the {verdict} verdict rests on features no deeper than {NOISE_FACTOR:g} x '
                f'their noise: the most significant, of segment {best.segment} at '
                f'{_ml(best.peak_m3)}, is {_pa(best.depth_pa)} deep against a noise of '
                f'{_pa(best.noise_pa)} ({best.noise_source}): it may be noise; smooth the '
                'table (smoothing: {} in the scene)')
    return lines, warnings


def scene_features(scene: object, emap: object | None = None) -> tuple[list[Feature],
                                                                        list[Feature]]:
    """:func:`deciding_features` of a loaded scene, reading its segment entries for noise."""
    import yaml

    entries = None
    if getattr(scene, 'path', None) is not None:
        try:
            entries = (yaml.safe_load(Path(scene.path).read_text()) or {}).get('segments')
        except (OSError, yaml.YAMLError, AttributeError):
            entries = None
    if emap is None:
        from softseq_ros.quasistatic.solve import scene_map

        emap = scene_map(scene)
    return deciding_features(emap, entries if isinstance(entries, list) else None)
