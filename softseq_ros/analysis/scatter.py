"""
The sequence under manufacturing scatter: Monte Carlo over a scene's parameters, and Sobol indices.

A scene gives the nominal segments; each varied parameter gets a distribution (docs/scatter.md):

- a closed-form segment (``balloon``, ``linear``): any number of its scene entry, by its key
  under the model (``top.thickness_m``, ``top.material.shear_modulus_pa``,
  ``top.material.mu_pa[0]``, ``bottom.stiffness_pa_per_m3``); the segment is built again from
  the entry with the drawn value, checked as the scene loader checks it;
- a table (or a design's FEM table): ``pressure_scale`` (every row's pressure times the drawn
  factor; 1 is the table) and ``noise_std_pa`` (Gaussian noise of that deviation [Pa] added to
  every row, a fresh draw per sample; a scene that smooths the table smooths the noisy rows
  with the same options);
- a segment design's FEM table, besides: ``modulus_scale`` (every modulus of its law times the
  factor: exactly its pressure times it) or a one-modulus law's ``material.shear_modulus_pa``,
  and ``geometry.membrane_thickness_m`` / ``geometry.wall_thickness_m``, read from the
  design's unit cells computed (or found cached) on a grid over the draws' range and
  interpolated (:func:`with_fem_grid`).

A distribution is ``normal:MEAN,STD``, ``normal:P%`` (mean: the scene's value, deviation: P %
of it), ``uniform:LOW,HIGH`` or ``uniform:P%`` (the scene's value +- P %); a noise is its
deviation, a number. A normal draw is held within its TAIL and 1 - TAIL quantiles (4.75
deviations), so that the check before the run, the segment built at both ends of every
distribution, covers every draw.

Every sample is classified as ``softseq classify`` classifies a scene (inflated over the whole
range and deflated back, :func:`~softseq_ros.quasistatic.equilibrium.inflate_and_deflate`),
and measured on the same sweep as ``softseq library`` measures an assembly: the switch volume,
the snap-throughs on inflation and deflation, the plateau (pressure and where it is reached).
Sample ``i`` draws its inputs from its own generator, ``numpy.random.default_rng([seed, i])``:
the same seed gives the same samples whatever the workers, the backend or where a run stopped.

Every probability comes with its Wilson score interval at the confidence asked for; a run with
``until_width`` checks after every CHECK_EVERY samples (in sample order) whether the widest of
them is that narrow, and stops there. Sobol first-order and total indices (SALib, Saltelli's
scheme on a scrambled Sobol' sequence, Jansen's estimators) come from a separate design of
``sobol`` x (parameters + 2) samples: one per parameter and output, with their intervals.
"""

from collections import Counter
from dataclasses import dataclass, field
import math
import re
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from softseq_ros.errors import UserError
from softseq_ros.parallel import run_jobs
from softseq_ros.quasistatic.sequence import SEQUENCE_TYPES

FloatArray = NDArray[np.float64]

# A normal draw is held within these quantiles: the check before the run builds the segment
# there, so no draw of a run reaches a value it did not check.
TAIL = 1e-6
# Samples per job, and how often (in samples, in order) a run checks its intervals' width.
CHUNK = 10
CHECK_EVERY = 50
# Progress lines per phase of a run, at most (and one at every check of the intervals).
PROGRESS_STEPS = 20
MAX_SAMPLES = 100_000
MAX_SOBOL_EVALUATIONS = 200_000
DEFAULT_SAMPLES = 1000
DEFAULT_SOBOL = 64
DEFAULT_CONFIDENCE = 0.95
# The sweep of each sample: as many volumes as `softseq classify` takes.
SWEEP_SAMPLES = 4001
TABLE_KEYS = ('pressure_scale', 'noise_std_pa')
# A design's geometry drawn through its unit cells' FEM tables on a grid (docs/scatter.md).
DESIGN_GEOMETRY_KEYS = ('membrane_thickness_m', 'wall_thickness_m')
DEFAULT_FEM_POINTS = 3
# Why a run with every parameter in one correlated group has no Sobol indices.
ONE_GROUP = ('no Sobol indices: every parameter is in one correlated group, which explains all '
             'of every output')
MAX_FEM_POINTS = 9
# A grid value this close to the scene's value is the scene's value (its own table).
SAME_VALUE_RTOL = 1e-9
_NAME = re.compile(r'^([A-Za-z][A-Za-z0-9_]*)\.([A-Za-z_][A-Za-z0-9_]*(?:\[\d+\])?'
                   r'(?:\.[A-Za-z_][A-Za-z0-9_]*(?:\[\d+\])?)*)$')


Show = Callable[[str], None]


class ScatterError(UserError):
    """A scatter study that cannot run: a distribution, a parameter or a setting at fault."""


# ------------------------------------------------------------------------------ distributions

@dataclass(frozen=True)
class Distribution:
    """
    A parameter's distribution: ``normal``, ``uniform`` or a table's ``noise``.

    ``normal``: a = mean, b = deviation; ``uniform``: a = low, b = high; ``noise``: a = the
    noise's deviation [Pa], and the parameter's uniform input picks the draw.
    """

    kind: str
    a: float
    b: float = 0.0
    text: str = ''

    def values(self, u: FloatArray) -> FloatArray:
        """The parameter's values at uniform inputs ``u`` in [0, 1) (inverse CDF)."""
        u = np.asarray(u, dtype=float)
        if self.kind == 'normal':
            from scipy.special import ndtri

            return self.a + self.b * ndtri(np.clip(u, TAIL, 1.0 - TAIL))
        if self.kind == 'uniform':
            return self.a + (self.b - self.a) * u
        return u   # a noise: its input is the draw itself

    def ends(self) -> tuple[float, float]:
        """The lowest and highest value a run draws."""
        low, high = self.values(np.array([0.0, 1.0]))
        return float(low), float(high)

    @property
    def variance(self) -> float:
        """The distribution's variance (a normal's before it is held within its quantiles)."""
        if self.kind == 'normal':
            return self.b**2
        if self.kind == 'uniform':
            return (self.b - self.a) ** 2 / 12.0
        return 0.0

    def describe(self) -> str:
        """In words: 'normal, mean 0.0005, deviation 2.5e-05'."""
        if self.kind == 'normal':
            return f'normal, mean {self.a:.6g}, deviation {self.b:.6g}'
        if self.kind == 'uniform':
            return f'uniform from {self.a:.6g} to {self.b:.6g}'
        return f'a fresh draw of Gaussian noise of {self.a:.6g} Pa on every row'

    def to_dict(self) -> dict:
        """The distribution as JSON: its kind, numbers and the text it was given as."""
        names = {'normal': ('mean', 'std'), 'uniform': ('low', 'high'),
                 'noise': ('noise_std_pa', None)}[self.kind]
        found: dict[str, Any] = {'kind': self.kind, names[0]: self.a, 'given_as': self.text}
        if names[1] is not None:
            found[names[1]] = self.b
        return found


def _number(where: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ScatterError(f'{where}: {text!r} is not a number') from None
    if not math.isfinite(value):
        raise ScatterError(f'{where}: must be a finite number, got {text!r}')
    return value


def parse_distribution(where: str, text: str, nominal: float, noise: bool = False
                       ) -> Distribution:
    """
    A distribution from its text (module docstring); ``nominal``: the scene's value.

    ScatterError naming ``where`` for anything else: a negative or zero spread, NaN or inf, a
    percentage of a zero value, an unknown kind.
    """
    text = text.strip()
    if noise:
        sigma = _number(where, text)
        if sigma <= 0.0:
            raise ScatterError(f"{where}: a noise's deviation must be > 0 Pa, got {text}")
        return Distribution('noise', sigma, 0.0, text)
    kind, _, numbers = text.partition(':')
    kind = kind.strip().lower()
    if kind not in ('normal', 'uniform') or not numbers.strip():
        raise ScatterError(f'{where}: {text!r} is no distribution; give normal:MEAN,STD, '
                           'normal:P%, uniform:LOW,HIGH or uniform:P%')
    parts = [part.strip() for part in numbers.split(',')]
    if len(parts) == 1 and parts[0].endswith('%'):
        share = _number(where, parts[0][:-1]) / 100.0
        if share <= 0.0:
            raise ScatterError(f'{where}: the spread must be > 0 %, got {parts[0]}')
        spread = share * abs(nominal)
        if spread == 0.0:
            raise ScatterError(f"{where}: {parts[0]} of the scene's value 0 is no spread; "
                               'give the numbers')
        if kind == 'normal':
            return Distribution('normal', nominal, spread, text)
        return Distribution('uniform', nominal - spread, nominal + spread, text)
    if len(parts) != 2:
        raise ScatterError(f'{where}: {text!r}: {kind} takes two numbers '
                           f'({"MEAN,STD" if kind == "normal" else "LOW,HIGH"}) or one '
                           'percentage')
    a, b = _number(where, parts[0]), _number(where, parts[1])
    if kind == 'normal' and b <= 0.0:
        raise ScatterError(f'{where}: the standard deviation must be > 0, got {parts[1]}')
    if kind == 'uniform' and b <= a:
        raise ScatterError(f'{where}: the high end must exceed the low end, got {parts[0]} '
                           f'to {parts[1]}')
    return Distribution(kind, a, b, text)


# ------------------------------------------------------------------------------ parameters

@dataclass(frozen=True)
class Parameter:
    """One varied number: its name, segment, key path in the segment's model and its law."""

    name: str
    segment: int
    key: tuple[str | int, ...]
    nominal: float
    distribution: Distribution

    def to_dict(self) -> dict:
        """The parameter as JSON."""
        return {'name': self.name, 'nominal': self.nominal,
                'distribution': self.distribution.to_dict()}


def _entry(segment: Any) -> dict | None:
    """A closed-form segment's scene entry (``{name, length_m, MODEL: {...}}``); None: a table."""
    from softseq_ros.segments.models import TabulatedSegment

    if isinstance(segment, TabulatedSegment):
        return None
    definition = dict(segment.definition())
    model = definition.pop('model')
    return {'name': definition.pop('name'), 'length_m': definition.pop('length_m'),
            model: definition}


def _leaves(value: Any, prefix: tuple = ()) -> dict[tuple, float]:
    """The numbers of an entry's model block by key path (lists by index); the law is none."""
    found: dict[tuple, float] = {}
    if isinstance(value, dict):
        for key, item in value.items():
            found.update(_leaves(item, prefix + (key,)))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            found.update(_leaves(item, prefix + (index,)))
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        found[prefix] = float(value)
    return found


def _key_text(key: tuple) -> str:
    text = ''
    for part in key:
        text += f'[{part}]' if isinstance(part, int) else (f'.{part}' if text else part)
    return text


def _parse_key(text: str) -> tuple:
    key: list[str | int] = []
    for part in text.split('.'):
        name, _, index = part.partition('[')
        key.append(name)
        if index:
            key.append(int(index.rstrip(']')))
    return tuple(key)


def parameters_of(scene: Any, vary: dict[str, str], option: str = '--vary') -> list[Parameter]:
    """
    The varied parameters of ``scene`` from ``{name: distribution text}``, checked.

    ScatterError in one line naming ``option`` and the parameter: a segment or a key the scene
    does not have (listing those it has), a distribution that cannot be drawn, a value at either
    end of a distribution that the segment refuses.
    """
    check_scene(scene)
    if not vary:
        raise ScatterError(f'{option}: nothing to vary; give at least one NAME=DISTRIBUTION, '
                           'e.g. top.thickness_m=normal:5%')
    names = list(scene.segment_names)
    parameters = []
    for name, text in vary.items():
        where = f'{option} {name}'
        found = _NAME.match(name)
        if found is None:
            raise ScatterError(f'{where}: a parameter is SEGMENT.KEY, e.g. top.thickness_m or '
                               'top.material.shear_modulus_pa')
        segment_name, key_text = found.groups()
        if segment_name not in names:
            raise ScatterError(f'{where}: the scene has no segment {segment_name!r} (it has '
                               f'{", ".join(names)})')
        index = names.index(segment_name)
        entry = _entry(scene.segments[index])
        key = _parse_key(key_text)
        if entry is None:
            nominal = _table_nominal(where, scene.segments[index], key_text)
        else:
            model = next(k for k in entry if k not in ('name', 'length_m'))
            leaves = _leaves(entry[model])
            if key not in leaves:
                known = ', '.join(_key_text(k) for k in leaves)
                raise ScatterError(f'{where}: segment {segment_name} ({model}) has no '
                                   f'{key_text!r}; it has {known}')
            nominal = leaves[key]
        distribution = parse_distribution(where, text, nominal, noise=key_text == 'noise_std_pa'
                                          and entry is None)
        parameters.append(Parameter(name, index, key, nominal, distribution))
    model = ScatterModel.of(scene, parameters)
    for k, parameter in enumerate(parameters):
        if parameter.distribution.kind == 'noise':
            continue
        for end, value in zip(('lowest', 'highest'), parameter.distribution.ends()):
            values = [p.nominal for p in parameters]
            values[k] = value
            try:
                if parameter.key[0] == 'geometry':
                    # A design's geometry: the design file's own checks, before any FEM.
                    _cell_design(_design_of(scene.segments[parameter.segment]),
                                 {parameter.key[1]: value})
                model.segments_at(values)
            except ValueError as err:
                raise ScatterError(f'{option} {parameter.name}={parameter.distribution.text}: '
                                   f'its {end} draw, {value:.6g}, is refused: {err}') from None
    return parameters


def _design_of(segment: Any) -> Any:
    """The segment design (softseq_ros.scene.design) whose cached FEM table ``segment`` is."""
    from pathlib import Path

    from softseq_ros.scene.design import design_from_dict

    identity = segment.design
    geometry = dict(identity['geometry'])
    if geometry.get('wall_reading', 'skin_bands') == 'skin_bands':
        geometry.pop('skin_band_thickness_m', None)
    if geometry.get('membrane_thickness_factors') is None:
        geometry.pop('membrane_thickness_factors', None)
    # The cache names a table NAME-HASH.csv: the design's name, shared with `softseq fem`.
    stem = Path(segment.source).stem
    name = stem.rsplit('-', 1)[0] if '-' in stem else segment.name
    material = identity['material']
    return design_from_dict({'name': name, 'geometry': geometry,
                             'material': {'law': material['law'], **material['params']},
                             'mesh': dict(identity['mesh']), 'volume': dict(identity['volume'])},
                            f'the design of segment {segment.name}')


def _only_modulus(law: str) -> str | None:
    """The law's one parameter in Pa, when it has one only (its stiffness): else None."""
    from softseq_ros.segments.materials import material_parameter_names

    moduli = [name for name in material_parameter_names(law) if name.endswith('_pa')]
    return moduli[0] if len(moduli) == 1 and law != 'ogden' else None


def _table_nominal(where: str, segment: Any, key_text: str) -> float:
    """
    The scene's value of a table's parameter (a design's FEM table has more of them).

    ScatterError naming the keys the segment has, when it has not this one.
    """
    if key_text in TABLE_KEYS:
        return 1.0 if key_text == 'pressure_scale' else 0.0
    if segment.design is None:
        raise ScatterError(f'{where}: segment {segment.name} is a table: it has '
                           f'{" and ".join(TABLE_KEYS)}, not {key_text!r} (its rows fix '
                           'its curve)')
    design = _design_of(segment)
    law = design.material.law
    modulus = _only_modulus(law)
    known = [*TABLE_KEYS, 'modulus_scale', *(f'geometry.{k}' for k in DESIGN_GEOMETRY_KEYS),
             *([f'material.{modulus}'] if modulus else [])]
    if key_text == 'modulus_scale':
        return 1.0
    group, _, key = key_text.partition('.')
    if group == 'geometry' and key in DESIGN_GEOMETRY_KEYS:
        if design.geometry.membrane_thickness_factors is not None:
            raise ScatterError(f'{where}: the design of segment {segment.name} scales each '
                               'membrane (membrane_thickness_factors, a whole segment); its '
                               'geometry is drawn through unit cells, which have one membrane')
        return float(getattr(design.geometry, key))
    if group == 'material' and key == modulus:
        return float(design.material.params[key])
    if group == 'material' and key in design.material.params:
        raise ScatterError(f'{where}: {key} alone changes the shape of the {law} law, not only '
                           f'its stiffness; vary {segment.name}.modulus_scale (every modulus '
                           'of the law by one factor)')
    raise ScatterError(f'{where}: segment {segment.name} is the FEM table of design '
                       f'{design.name}: it has {", ".join(known)}, not {key_text!r}')


def _cell_design(design: Any, geometry: dict[str, float]) -> Any:
    """The unit cell of a design with these geometry values (DesignError: refused)."""
    from softseq_ros.scene.design import with_changes

    return with_changes(design, {**{f'geometry.{k}': float(v) for k, v in geometry.items()},
                                 'mesh.model': 'unit_cell'})


def check_scene(scene: Any) -> None:
    """
    Refuse a scene whose samples could not be classified: one behind a pressure regulator.

    Its segments do not share the volume a syringe pushes, so it has no sequence type of the
    four (``softseq classify`` refuses it the same way).
    """
    if getattr(scene, 'regulator', None) is not None:
        where = scene.path if scene.path is not None else scene.name
        raise ScatterError(f'{where}: supply.regulator: scatter classifies segments sharing the '
                           'volume a syringe pushes; behind a regulator each segment is an '
                           'independent hysteron (softseq graph shows its flips): scatter the '
                           'pair without its regulator')


def scene_notes(scene: Any) -> list[str]:
    """What a scatter of this scene does not sample, said with its summary."""
    if getattr(scene, 'network', None) is None:
        return []
    return [f'{scene.name} has a fluid network; it is not sampled: every sample is classified '
            'and measured quasi-statically, as softseq classify does it, not in time at the '
            "pump's rate (softseq rates maps what the network's rate does)"]


def read_vary(vary: Sequence[str] | None, spec: Any = None) -> dict[str, str]:
    """
    ``{name: distribution}`` from ``--vary NAME=DIST`` words and a spec file's ``vary`` block.

    A name given twice, a word without ``=``, a spec file that is no mapping with ``vary``:
    ScatterError naming the option or the file.
    """
    found: dict[str, str] = {}
    for word in vary or ():
        name, equals, text = word.partition('=')
        name = name.strip()
        if not equals or not name or not text.strip():
            raise ScatterError(f'--vary: {word!r} is not NAME=DISTRIBUTION, e.g. '
                               'top.thickness_m=normal:5%')
        if name in found:
            raise ScatterError(f'--vary: {name} is given twice')
        found[name] = text
    if spec is not None:
        for name, text in _spec_vary(spec).items():
            if name in found:
                raise ScatterError(f'--vary {name}: given on the command line and in --spec')
            found[name] = text
    return found


def read_correlate(words: Sequence[str] | None, spec: Any = None) -> dict[tuple[str, str], float]:
    """
    ``{(name, name): rho}`` from ``--correlate A,B=RHO`` words and a spec file's ``correlate``.

    A word that is no ``A,B=RHO``, a correlation that is no number from -1 to 1, a parameter
    with itself, a pair given twice (in either order): ScatterError naming the option.
    """
    given = [(word, '--correlate') for word in words or ()]
    if spec is not None:
        given += [(f'{pair}={rho}', f'--spec {spec}: correlate')
                  for pair, rho in _spec_file(spec).get('correlate', {}).items()]
    found: dict[tuple[str, str], float] = {}
    for word, option in given:
        pair, equals, text = word.partition('=')
        names = tuple(name.strip() for name in pair.split(','))
        if not equals or len(names) != 2 or not all(names) or not text.strip():
            raise ScatterError(f'{option}: {word!r} is not NAME,NAME=RHO, e.g. '
                               'top.modulus_scale,bottom.modulus_scale=0.8')
        where = f'{option} {names[0]},{names[1]}'
        rho = _number(where, text.strip())
        if not -1.0 <= rho <= 1.0:
            raise ScatterError(f'{where}: a correlation from -1 to 1, got {text.strip()}')
        if names[0] == names[1]:
            raise ScatterError(f'{where}: a parameter is not correlated with itself')
        key = (names[0], names[1])
        if key in found or key[::-1] in found:
            raise ScatterError(f'{where}: given twice')
        found[key] = rho
    return found


@dataclass(frozen=True)
class Correlation:
    """
    Correlated draws: the parameters' normal scores are correlated (a Gaussian copula).

    Each parameter's uniform input ``u`` has the normal score ``z = Phi^-1(u)``; within a
    group of parameters tied by correlations the scores are mixed, ``z' = L z`` with ``L L^T``
    the group's correlation matrix, and ``u' = Phi(z')`` goes to the parameter's distribution
    as before: each parameter keeps its distribution, two normal ones have correlation rho,
    two uniform ones rank correlation (6/pi) asin(rho/2).
    """

    pairs: tuple[tuple[str, str, float], ...]
    groups: tuple[tuple[int, ...], ...]     # parameters drawn together, more than one each
    factors: tuple[FloatArray, ...]         # per group, L (L L^T = its correlation matrix)

    def mix(self, inputs: FloatArray) -> FloatArray:
        """Rows of independent uniform inputs made correlated (the others left as they are)."""
        from scipy.special import ndtr, ndtri

        mixed = np.array(inputs, dtype=float, copy=True)
        for group, factor in zip(self.groups, self.factors):
            scores = ndtri(np.clip(mixed[:, group], TAIL, 1.0 - TAIL))
            mixed[:, group] = ndtr(scores @ factor.T)
        return mixed

    def group_names(self, names: Sequence[str]) -> list[str]:
        """Each parameter's Sobol group: its own name, or its group's names joined by +."""
        found = list(names)
        for group in self.groups:
            joined = '+'.join(names[k] for k in group)
            for k in group:
                found[k] = joined
        return found

    def to_dict(self) -> list[dict]:
        """The correlations as given, as JSON."""
        return [{'parameters': [a, b], 'rho': rho} for a, b, rho in self.pairs]


def correlation_of(parameters: Sequence[Parameter], given: dict[tuple[str, str], float],
                   option: str = '--correlate') -> Correlation | None:
    """
    The correlations of ``given`` between ``parameters``, checked; None when none are given.

    ScatterError naming ``option``: a parameter not varied, a table's noise (its input picks
    a draw: nothing to correlate), correlations that cannot hold together (their matrix not
    positive semi-definite).
    """
    if not given:
        return None
    names = [p.name for p in parameters]
    matrix = np.eye(len(names))
    for (a, b), rho in given.items():
        for name in (a, b):
            if name not in names:
                raise ScatterError(f'{option} {a},{b}: {name} is not varied (the parameters: '
                                   f'{", ".join(names)})')
            if parameters[names.index(name)].distribution.kind == 'noise':
                raise ScatterError(f"{option} {a},{b}: {name} is a table's noise: its input "
                                   'picks a draw of the noise, nothing to correlate')
        i, j = names.index(a), names.index(b)
        matrix[i, j] = matrix[j, i] = rho
    # The groups: parameters joined by a non-zero correlation, directly or through others.
    group_of = list(range(len(names)))
    for (a, b), rho in given.items():
        if rho != 0.0:
            old, new = group_of[names.index(a)], group_of[names.index(b)]
            group_of = [new if g == old else g for g in group_of]
    groups, factors = [], []
    for label in dict.fromkeys(group_of):
        group = tuple(k for k, g in enumerate(group_of) if g == label)
        if len(group) < 2:
            continue
        block = matrix[np.ix_(group, group)]
        eigenvalues, vectors = np.linalg.eigh(block)
        if eigenvalues.min() < -1e-9:
            shown = ', '.join(names[k] for k in group)
            raise ScatterError(f'{option}: the correlations between {shown} cannot hold '
                               f'together (their matrix has the eigenvalue '
                               f'{eigenvalues.min():.3g} < 0)')
        try:
            factor = np.linalg.cholesky(block)
        except np.linalg.LinAlgError:   # singular (a correlation of 1): the square root
            factor = vectors * np.sqrt(np.clip(eigenvalues, 0.0, None))
        groups.append(group)
        factors.append(factor)
    pairs = tuple((a, b, float(rho)) for (a, b), rho in given.items())
    return Correlation(pairs, tuple(groups), tuple(factors))


def _spec_vary(path: Any) -> dict[str, str]:
    """The ``vary`` block of a spec file: ``{name: distribution text}``."""
    found = {}
    for name, value in _spec_file(path)['vary'].items():
        if not isinstance(name, str) or isinstance(value, (bool, dict, list)) or value is None:
            raise ScatterError(f'--spec {path}: vary.{name}: give a distribution as text, e.g. '
                               'normal:5%, or a noise in Pa')
        found[name] = str(value)
    return found


def _spec_file(path: Any) -> dict:
    """A spec file, checked: ``vary`` (a mapping) and, optionally, ``correlate`` (one too)."""
    from softseq_ros.errors import read_regular_file
    from softseq_ros.yaml_text import parse_yaml

    try:
        raw = read_regular_file(path)
    except OSError as err:
        raise ScatterError(f'--spec {path}: cannot read it ({err.strerror or err})') from None
    try:
        text = raw.decode('utf-8-sig')
    except UnicodeDecodeError as err:
        raise ScatterError(f'--spec {path}: not UTF-8 text (byte {err.start})') from None
    data = parse_yaml(text, f'--spec {path}', ScatterError)
    if (not isinstance(data, dict) or 'vary' not in data or not set(data) <= {'vary', 'correlate'}
            or not all(isinstance(block, dict) for block in data.values())):
        raise ScatterError(f'--spec {path}: must be a mapping with the key vary (a mapping of '
                           'NAME: DISTRIBUTION) and, optionally, correlate (a mapping of '
                           'NAME,NAME: RHO) (docs/scatter.md)')
    return data


# ------------------------------------------------------------------------------ the model

@dataclass(frozen=True)
class ScatterModel:
    """
    What a worker needs to build and measure a sample.

    The nominal segments, each closed-form segment's scene entry (None for a table), the
    varied parameters, the supply line and the solver's resolution.
    """

    segments: tuple
    entries: tuple
    parameters: tuple[Parameter, ...]
    supply: Any = None
    resolution: int | None = None
    # Per segment, the unit cells' FEM tables interpolated over its drawn geometry
    # (softseq_ros.fem.design_interpolation.SegmentFamily), or None: :func:`with_fem_grid`.
    families: tuple = ()
    # Correlations between the parameters' draws (:class:`Correlation`), or None.
    correlation: Any = None

    @classmethod
    def of(cls, scene: Any, parameters: Sequence[Parameter],
           correlation: Any = None) -> 'ScatterModel':
        """The model of a loaded scene with these parameters varied (and correlated)."""
        return cls(tuple(scene.segments), tuple(_entry(s) for s in scene.segments),
                   tuple(parameters), scene.supply, scene.solver.resolution,
                   correlation=correlation)

    def values_at(self, inputs: FloatArray) -> FloatArray:
        """The parameters' values at rows of independent uniform inputs (correlated here)."""
        inputs = np.atleast_2d(np.asarray(inputs, dtype=float))
        if self.correlation is not None:
            inputs = self.correlation.mix(inputs)
        return np.column_stack([p.distribution.values(inputs[:, k])
                                for k, p in enumerate(self.parameters)])

    def segments_at(self, values: Sequence[float]) -> tuple:
        """
        The segments with each parameter at its value (a noise's value: its draw in [0, 1)).

        ValueError (a SceneError or the models' own) when a segment refuses a value.
        """
        import copy

        from softseq_ros.scene.loader import segment_from_entry

        by_segment: dict[int, list[tuple[Parameter, float]]] = {}
        for parameter, value in zip(self.parameters, values):
            by_segment.setdefault(parameter.segment, []).append((parameter, float(value)))
        segments = list(self.segments)
        for index, changes in by_segment.items():
            entry = self.entries[index]
            if entry is None:
                family = self.families[index] if self.families else None
                geometry = {p.key[1]: v for p, v in changes if p.key[0] == 'geometry'}
                table = segments[index]
                if family is not None:
                    table = family.build(geometry, name=table.name)
                segments[index] = _table_at(table, changes)
                continue
            entry = copy.deepcopy(entry)
            model = next(k for k in entry if k not in ('name', 'length_m'))
            for parameter, value in changes:
                place = entry[model]
                for part in parameter.key[:-1]:
                    place = place[part]
                place[parameter.key[-1]] = value
            segments[index] = segment_from_entry(entry, entry['name'])
        return tuple(segments)


def with_fem_grid(model: ScatterModel, points: int = DEFAULT_FEM_POINTS,
                  cache_dir: Any = None, workers: int | None = None,
                  scheduler: str | None = None, progress: Show | None = None
                  ) -> tuple[ScatterModel, list[dict]]:
    """
    The model with each design segment whose geometry is drawn read from its unit cells' FEM.

    The unit cell of the segment's design (its material and mesh, ``mesh.model: unit_cell``)
    at ``points`` values of each drawn geometry key, evenly from the lowest draw to the
    highest (the scene's value itself where a grid point falls on it), every combination:
    tables from the FEM cache (``cache_dir``, default softseq's), the missing ones computed
    on the shared executor. A sample's segment is those tables interpolated multilinearly at
    fixed fluid volume per cell (as ``softseq design`` does). Returns the model and, per
    segment, what its grid is (JSON).
    """
    from dataclasses import replace
    import itertools

    from softseq_ros.fem.design_grid import ensure_tables
    from softseq_ros.fem.design_interpolation import SegmentFamily
    from softseq_ros.fem.design_problem import SegmentSpace

    families: list[Any] = [None] * len(model.segments)
    grids = []
    for index, segment in enumerate(model.segments):
        drawn = [p for p in model.parameters if p.segment == index and p.key[0] == 'geometry']
        if not drawn:
            continue
        own = _design_of(segment)
        design = _cell_design(own, {})
        axes = {}
        for parameter in drawn:
            values = np.linspace(*parameter.distribution.ends(), points)
            values[np.isclose(values, parameter.nominal, rtol=SAME_VALUE_RTOL, atol=0.0)] = \
                parameter.nominal
            axes[str(parameter.key[1])] = values
        cells = {at: _cell_design(design, {k: axes[k][i] for k, i in zip(axes, at)})
                 for at in itertools.product(range(points), repeat=len(axes))}
        what = f'scatter: segment {segment.name}'
        if progress is not None:
            progress(f'{what}: {len(cells)} unit-cell FEM tables of design {design.name} '
                     f'(mesh {design.mesh.element_size_m * 1e3:g} mm), computed where not cached')
        paths, runs = ensure_tables(list(cells.values()), cache_dir, workers, scheduler,
                                    progress, what)
        space = SegmentSpace(segment.name, design,
                             {k: (float(v[0]), float(v[-1])) for k, v in axes.items()})
        families[index] = SegmentFamily.from_tables(
            space, axes, {at: (paths[d.digest()], d) for at, d in cells.items()})
        grids.append({'segment': segment.name, 'design': design.name,
                      'scene_model': own.mesh.model, 'element_size_m': design.mesh.element_size_m,
                      'axes': {k: [float(x) for x in v] for k, v in axes.items()},
                      'tables': len(cells), 'computed': runs})
    return replace(model, families=tuple(families)), grids


def _table_at(segment: Any, changes: list[tuple[Parameter, float]]) -> Any:
    """A table with its pressures scaled and a noise drawn (and smoothed as the scene does)."""
    from softseq_ros.segments.models import TabulatedSegment
    from softseq_ros.segments.smoothing import smooth_table

    pressures = np.array(segment.pressures, dtype=float)
    for parameter, value in changes:
        if parameter.key[0] in ('pressure_scale', 'modulus_scale', 'material'):
            # A design's every modulus times k (its bulk modulus a fixed multiple of its shear
            # modulus): the FEM's state at each volume is the same, its pressure k times.
            scale = value / parameter.nominal if parameter.key[0] == 'material' else value
            if not scale > 0.0:
                what = 'pressure scale' if parameter.key[0] == 'pressure_scale' else 'modulus'
                raise ValueError(f'{parameter.name}: a {what} must be > 0, got {value:.6g}')
            pressures = pressures * scale
    for parameter, value in changes:
        if parameter.key == ('noise_std_pa',):
            draw = np.random.default_rng(int(value * 2**53))
            pressures = pressures + draw.normal(0.0, parameter.distribution.a, pressures.size)
    table = TabulatedSegment(segment.name, segment.length, segment.volumes, pressures,
                             segment.curvatures, source=segment.source)
    for options in segment.smoothing:
        table = table.smoothed(smooth_table(table.volumes, table.pressures,
                                            noise_std=options.get('noise_std_pa'),
                                            prominence=options.get('prominence_pa')),
                               **options)
    return table


def measure(segments: Sequence[Any], supply: Any = None,
            resolution: int | None = None) -> dict:
    """
    The sequence of these segments: type, switch, snap-throughs and plateau (SI, gauge).

    Classified as ``softseq classify`` does, measured on the same sweep as ``softseq library``
    measures an assembly (:func:`~softseq_ros.analysis.metrics.sweep_metrics`).
    """
    from softseq_ros.analysis.metrics import sweep_metrics
    from softseq_ros.quasistatic.equilibrium import (
        EquilibriumMap,
        inflate_and_deflate,
        sweep_sequence_type,
    )

    emap = (EquilibriumMap(segments, supply=supply) if resolution is None
            else EquilibriumMap(segments, resolution=resolution, supply=supply))
    lo, hi = emap.injected_range
    rising, falling = inflate_and_deflate(emap, SWEEP_SAMPLES)
    metrics = sweep_metrics(rising, falling, tuple(s.name for s in segments), hi - lo)
    switch, plateau = metrics['switch'], metrics['plateau']
    return {
        'sequence_type': sweep_sequence_type(emap, rising, falling),
        'switch_injected_m3': None if switch is None else switch['injected_m3'],
        'inflation_snaps_m3': [float(e.injected) for e in rising.events],
        'deflation_snaps_m3': [float(e.injected) for e in falling.events],
        'plateau_pressure_pa': None if plateau is None else plateau['pressure_pa'],
        'plateau_onset_m3': None if plateau is None else plateau['onset_injected_m3'],
        'converged': bool(emap.convergence.converged),
    }


def sample_inputs(seed: int, start: int, count: int, dimensions: int) -> FloatArray:
    """Uniform inputs of samples ``start`` to ``start + count``: each from its own generator."""
    return np.array([np.random.default_rng([seed, index]).random(dimensions)
                     for index in range(start, start + count)]).reshape(count, dimensions)


def scatter_chunk(job: tuple) -> tuple[int, list[dict]]:
    """
    A job of a run: ``(model, first index, uniform inputs)`` -> (first index, samples).

    Each sample holds its index, the parameters' values and :func:`measure`'s numbers. A
    segment that refuses its values, or a solver that fails on them, is a ScatterError that
    names the sample and its values.
    """
    model, start, inputs = job
    found = []
    for offset, row in enumerate(model.values_at(inputs) if len(inputs) else []):
        index = start + offset
        values = [float(x) for x in row]
        try:
            numbers = measure(model.segments_at(values), model.supply, model.resolution)
        except (ValueError, ArithmeticError) as err:
            drawn = ', '.join(f'{p.name} = {v:.6g}' for p, v in zip(model.parameters, values))
            raise ScatterError(f'sample {index} ({drawn}): {err}') from None
        found.append({'index': index, 'values': values, **numbers})
    return start, found


# ------------------------------------------------------------------------------ statistics

def _z(confidence: float) -> float:
    from scipy.special import ndtri

    return float(ndtri(0.5 + 0.5 * confidence))


def wilson_interval(count: int, samples: int, confidence: float = DEFAULT_CONFIDENCE
                    ) -> tuple[float, float]:
    """The Wilson score interval of a probability seen ``count`` times in ``samples``."""
    if samples <= 0:
        return 0.0, 1.0
    z = _z(confidence)
    share = count / samples
    scale = 1.0 + z * z / samples
    centre = (share + z * z / (2 * samples)) / scale
    half = z / scale * math.sqrt(share * (1.0 - share) / samples + z * z / (4 * samples**2))
    # It holds the share seen, also at 0 and 1 where round-off would leave it just outside.
    return max(0.0, min(share, centre - half)), min(1.0, max(share, centre + half))


def proportion(count: int, samples: int, confidence: float) -> dict:
    """A probability with its count and Wilson interval, as JSON."""
    low, high = wilson_interval(count, samples, confidence)
    return {'count': int(count), 'samples': int(samples),
            'probability': count / samples if samples else None, 'interval': [low, high]}


def spread(values: Sequence[float], confidence: float) -> dict:
    """Mean (with its interval), deviation, and the 2.5, 50 and 97.5 % quantiles of numbers."""
    if not len(values):
        return {'mean': None, 'mean_interval': None, 'std': None, 'quantiles': None,
                'min': None, 'max': None}
    x = np.asarray(values, dtype=float)
    std = float(np.std(x, ddof=1)) if x.size > 1 else 0.0
    half = _z(confidence) * std / math.sqrt(x.size)
    return {'mean': float(x.mean()), 'mean_interval': [float(x.mean() - half),
                                                       float(x.mean() + half)],
            'std': std, 'quantiles': {q: float(np.quantile(x, float(q) / 100.0))
                                      for q in ('2.5', '50', '97.5')},
            'min': float(x.min()), 'max': float(x.max())}


def summarise(samples: Sequence[dict], confidence: float = DEFAULT_CONFIDENCE) -> dict:
    """
    The distribution of the sequence over ``samples``: every probability with its interval.

    The sequence types (all four), whether a switch and a plateau are found and their numbers,
    how many snap-throughs each way and the volume of each (first, second, ...).
    """
    n = len(samples)
    types = Counter(s['sequence_type'] for s in samples)
    found: dict[str, Any] = {'samples': n, 'confidence': confidence,
                             'sequence_type': {t: proportion(types[t], n, confidence)
                                               for t in SEQUENCE_TYPES}}
    for key in ('switch_injected_m3', 'plateau_pressure_pa', 'plateau_onset_m3'):
        values = [s[key] for s in samples if s[key] is not None]
        found[key] = {'found': proportion(len(values), n, confidence),
                      **spread(values, confidence)}
    for leg in ('inflation', 'deflation'):
        snaps = [s[f'{leg}_snaps_m3'] for s in samples]
        counts = Counter(len(row) for row in snaps)
        found[f'{leg}_snaps'] = {
            'count': {str(k): proportion(counts[k], n, confidence) for k in sorted(counts)},
            'injected_m3': [spread([row[j] for row in snaps if len(row) > j], confidence)
                            for j in range(max(counts, default=0))]}
    found['unconverged_samples'] = sum(not s['converged'] for s in samples)
    return found


def probabilities(summary: dict) -> list[tuple[str, dict]]:
    """Every probability of a summary, by name: what the stop rule and the text go through."""
    found = [(f'sequence type {t}', p) for t, p in summary['sequence_type'].items()]
    for key in ('switch_injected_m3', 'plateau_pressure_pa', 'plateau_onset_m3'):
        found.append((f'{key} found', summary[key]['found']))
    for leg in ('inflation', 'deflation'):
        found += [(f'{k} snap-throughs on {leg}', p)
                  for k, p in summary[f'{leg}_snaps']['count'].items()]
    return found


def widest_interval(summary: dict) -> float:
    """The width of the widest interval of any probability of ``summary``."""
    return max(p['interval'][1] - p['interval'][0] for _, p in probabilities(summary))


# ------------------------------------------------------------------------------ Sobol

def sobol_inputs(dimensions: int, base: int, seed: int,
                 groups: Sequence[str] | None = None) -> FloatArray:
    """
    Saltelli's design (first and total order): ``base x (groups + 2)`` uniform rows.

    ``groups``: each input's group (None: each its own); a group's inputs are swapped
    together between the design's matrices, so its indices are the group's.
    """
    from SALib.sample import sobol as saltelli

    problem = _problem(dimensions, groups=groups)
    return np.asarray(saltelli.sample(problem, base, calc_second_order=False, scramble=True,
                                      seed=seed), dtype=float)


def _problem(dimensions: int, names: Sequence[str] | None = None,
             groups: Sequence[str] | None = None) -> dict:
    problem = {'num_vars': dimensions,
               'names': (list(names) if names is not None
                         else [f'x{i}' for i in range(dimensions)]),
               'bounds': [[0.0, 1.0]] * dimensions}
    if groups is not None and len(set(groups)) < dimensions:
        problem['groups'] = list(groups)
    return problem


def sobol_indices(names: Sequence[str], outputs: Sequence[float | None],
                  confidence: float = DEFAULT_CONFIDENCE, seed: int = 0,
                  groups: Sequence[str] | None = None) -> dict:
    """
    First-order and total Sobol indices of one output over :func:`sobol_inputs`' rows.

    The indices do not depend on how each uniform input is mapped to its parameter (a monotone
    map per input keeps the variance decomposition), so they are those of the parameters. An
    output missing in some row, or the same in every row, has none: ``reason`` says why.
    With ``groups`` (the design's), the indices are per group, by the group's name.
    """
    if any(y is None for y in outputs):
        missing = sum(y is None for y in outputs)
        return {'reason': f'not found in {missing} of {len(outputs)} samples'}
    y = np.asarray(outputs, dtype=float)
    if np.ptp(y) == 0.0:
        return {'reason': 'the same in every sample: no parameter moves it'}
    from SALib.analyze import sobol as jansen

    with np.errstate(all='ignore'):
        problem = _problem(len(names), names, groups)
        result = jansen.analyze(problem, y, calc_second_order=False,
                                conf_level=confidence, num_resamples=200, seed=seed)
    # SALib's groups come in the order they first appear.
    shown = list(dict.fromkeys(problem.get('groups', names)))
    return {name: {'first_order': float(result['S1'][i]),
                   'first_order_interval_half_width': float(result['S1_conf'][i]),
                   'total': float(result['ST'][i]),
                   'total_interval_half_width': float(result['ST_conf'][i])}
            for i, name in enumerate(shown)}


def sobol_outputs(samples: Sequence[dict]) -> dict[str, list[float | None]]:
    """The scalar outputs of Sobol samples: SOBOL_OUTPUTS and one indicator per type seen."""
    def first(row: list) -> float | None:
        return row[0] if row else None

    found: dict[str, list] = {
        'switch_injected_m3': [s['switch_injected_m3'] for s in samples],
        'plateau_pressure_pa': [s['plateau_pressure_pa'] for s in samples],
        'plateau_onset_m3': [s['plateau_onset_m3'] for s in samples],
        'inflation_snap_count': [float(len(s['inflation_snaps_m3'])) for s in samples],
        'first_inflation_snap_m3': [first(s['inflation_snaps_m3']) for s in samples],
        'deflation_snap_count': [float(len(s['deflation_snaps_m3'])) for s in samples],
        'first_deflation_snap_m3': [first(s['deflation_snaps_m3']) for s in samples]}
    for kind in SEQUENCE_TYPES:
        found[f'is_{kind}'] = [float(s['sequence_type'] == kind) for s in samples]
    return found


# ------------------------------------------------------------------------------ the run

@dataclass
class ScatterResult:
    """A scatter study: its settings, every sample, the summary and the Sobol indices."""

    scene: str
    parameters: list[Parameter]
    seed: int
    confidence: float
    samples: list[dict]
    summary: dict
    requested_samples: int
    until_width: float | None
    sobol_base: int
    sobol: dict = field(default_factory=dict)
    sobol_samples: list[dict] = field(default_factory=list)
    # Per design segment whose geometry is drawn: its unit cells' FEM grid (with_fem_grid).
    fem_grids: list[dict] = field(default_factory=list)
    # What the reader must know of how the samples were made (printed with the summary).
    notes: list[str] = field(default_factory=list)
    correlation: Correlation | None = None

    @property
    def stop(self) -> dict:
        """Whether the run stopped at the width asked for, and the widest interval it has."""
        widest = widest_interval(self.summary)
        return {'until_width': self.until_width, 'widest_interval': widest,
                'reached': None if self.until_width is None else widest <= self.until_width,
                'samples': len(self.samples), 'at_most': self.requested_samples,
                'check_every': CHECK_EVERY}

    def to_dict(self) -> dict:
        """Every number, SI (m^3, Pa), JSON-able."""
        return {'scene': self.scene, 'seed': self.seed, 'confidence': self.confidence,
                'parameters': [p.to_dict() for p in self.parameters],
                'correlations': [] if self.correlation is None else self.correlation.to_dict(),
                'stop': self.stop, 'notes': self.notes, 'fem_grids': self.fem_grids,
                'summary': self.summary,
                'sobol': {'base_samples': self.sobol_base,
                          'evaluations': len(self.sobol_samples), 'indices': self.sobol},
                'samples': self.samples, 'sobol_samples': self.sobol_samples}


class _Enough(Exception):  # noqa: N818 - no error: the run has what it needs
    """Raised from a run's progress: the samples in order so far are enough."""



def run_scatter(scene: Any, parameters: Sequence[Parameter], samples: int = DEFAULT_SAMPLES,
                until_width: float | None = None, confidence: float = DEFAULT_CONFIDENCE,
                seed: int = 0, sobol: int = DEFAULT_SOBOL, workers: int | None = None,
                backend: str = 'processes', scheduler: str | None = None,
                progress: Show | None = None, fem_points: int = DEFAULT_FEM_POINTS,
                fem_cache: Any = None, correlation: Correlation | None = None
                ) -> ScatterResult:
    """
    The Monte Carlo distribution of the scene's sequence, and the Sobol indices.

    ``samples``: at most this many; with ``until_width`` the run stops at the first multiple
    of CHECK_EVERY samples (in order) where every probability's interval is at most that wide.
    ``sobol``: base samples of the Sobol design (a power of 2; 0: none). ``workers``,
    ``backend`` and ``scheduler`` as :func:`softseq_ros.parallel.run_jobs` takes them;
    ``progress(line)`` hears how far the run is. A design segment's drawn geometry is read
    from ``fem_points`` unit cells per key (:func:`with_fem_grid`; ``fem_cache``: where their
    tables are cached, default softseq's FEM cache). ``correlation``: correlated draws
    (:func:`correlation_of`); the Sobol indices are then those of its groups.
    """
    check_settings(samples, until_width, confidence, sobol, len(parameters), fem_points)
    check_scene(scene)
    model, grids = with_fem_grid(ScatterModel.of(scene, parameters, correlation), fem_points,
                                 fem_cache, workers, scheduler, progress)
    notes = scene_notes(scene)
    for g in grids:
        notes.append(f'segment {g["segment"]}: its geometry from {g["tables"]} unit-cell FEM '
                     f'tables of design {g["design"]} ({", ".join(g["axes"])}; mesh '
                     f'{g["element_size_m"] * 1e3:g} mm; {g["computed"]} computed, the rest '
                     'cached), interpolated at each draw'
                     + ('' if g['scene_model'] == 'unit_cell' else
                        f"; the scene's design is a {g['scene_model']}, the samples its unit "
                        'cell'))
    dims = len(parameters)
    jobs = [(model, start, sample_inputs(seed, start, min(CHUNK, samples - start), dims))
            for start in range(0, samples, CHUNK)]
    done: dict[int, list[dict]] = {}
    kept: list[dict] = []
    checked = [CHECK_EVERY]

    def heard(count: int, total: int, result: tuple[int, list[dict]]) -> None:
        done[result[0]] = result[1]
        while len(kept) in done:
            kept.extend(done.pop(len(kept)))
        widest = None
        while until_width is not None and len(kept) >= checked[0]:
            widest = widest_interval(summarise(kept[:checked[0]], confidence))
            if widest <= until_width:
                del kept[checked[0]:]
                raise _Enough
            checked[0] += CHECK_EVERY
        if progress is not None and (widest is not None or _step(count, total)):
            progress(f'scatter: {min(count * CHUNK, samples)}/{samples} samples'
                     + ('' if widest is None else
                        f', widest interval {widest:.3g} (stop at {until_width:g})'))

    try:
        run_jobs(scatter_chunk, jobs, workers=workers, backend=backend, scheduler=scheduler,
                 progress=heard, name=_chunk_name)
    except _Enough:
        pass
    result = ScatterResult(scene.name, list(parameters), seed, confidence, kept,
                           summarise(kept, confidence), samples, until_width, sobol,
                           fem_grids=grids, notes=notes, correlation=correlation)
    one_group = (correlation is not None and len(parameters) > 1
                 and [len(g) for g in correlation.groups] == [len(parameters)])
    if sobol and one_group:
        result.notes.append(ONE_GROUP)
    elif sobol:
        result.sobol_samples, result.sobol = _sobol_run(model, sobol, seed, confidence,
                                                        workers, backend, scheduler, progress)
    return result


def _step(count: int, total: int) -> bool:
    """Whether job ``count`` of ``total`` is worth a progress line: one per PROGRESS_STEPS."""
    return (count == total
            or count * PROGRESS_STEPS // total != (count - 1) * PROGRESS_STEPS // total)


def _chunk_name(job: tuple) -> str:
    return f'samples {job[1]} to {job[1] + len(job[2]) - 1}'


def _sobol_run(model: ScatterModel, base: int, seed: int, confidence: float,
               workers: int | None, backend: str, scheduler: str | None,
               progress: Show | None) -> tuple[list[dict], dict]:
    """The Sobol design's samples and, per output, each parameter's indices."""
    names = [p.name for p in model.parameters]
    groups = None if model.correlation is None else model.correlation.group_names(names)
    inputs = sobol_inputs(len(model.parameters), base, seed, groups)
    jobs = [(model, start, inputs[start:start + CHUNK])
            for start in range(0, len(inputs), CHUNK)]

    def heard(count: int, total: int, _: object) -> None:
        if progress is not None and _step(count, total):
            progress(f'scatter: Sobol design {min(count * CHUNK, len(inputs))}/{len(inputs)} '
                     'samples')

    chunks = run_jobs(scatter_chunk, jobs, workers=workers, backend=backend,
                      scheduler=scheduler, progress=heard, name=_chunk_name)
    rows = [row for _, found in chunks for row in found]
    indices = {output: sobol_indices(names, values, confidence, seed, groups)
               for output, values in sobol_outputs(rows).items()}
    return rows, indices


def check_settings(samples: int, until_width: float | None, confidence: float, sobol: int,
                   dimensions: int, fem_points: int = DEFAULT_FEM_POINTS) -> None:
    """Refuse, naming the option, a run that cannot give what it is asked for."""
    if not 2 <= fem_points <= MAX_FEM_POINTS:
        raise ScatterError(f'--fem-points: unit cells per drawn geometry key of a design, from '
                           f'2 to {MAX_FEM_POINTS}, got {fem_points}')
    if not 1 <= samples <= MAX_SAMPLES:
        raise ScatterError(f'--samples: a number of samples from 1 to {MAX_SAMPLES}, got '
                           f'{samples}')
    if until_width is not None:
        if not (math.isfinite(until_width) and 0.0 < until_width < 1.0):
            raise ScatterError(f'--until-width: an interval width between 0 and 1 (a '
                               f'probability), got {until_width}')
        if samples < CHECK_EVERY:
            raise ScatterError(f'--until-width: checked every {CHECK_EVERY} samples: give '
                               f'--samples of at least {CHECK_EVERY}, got {samples}')
    if not (math.isfinite(confidence) and 0.5 <= confidence <= 0.9999):
        raise ScatterError(f'--confidence: a level from 0.5 to 0.9999, got {confidence}')
    if sobol:
        if sobol < 2 or sobol & (sobol - 1):
            raise ScatterError(f'--sobol: base samples of the Sobol design: 0 (none) or a '
                               f'power of 2 from 2 on, got {sobol}')
        if sobol * (dimensions + 2) > MAX_SOBOL_EVALUATIONS:
            raise ScatterError(f'--sobol: {sobol} x ({dimensions} parameters + 2) = '
                               f'{sobol * (dimensions + 2)} samples, more than '
                               f'{MAX_SOBOL_EVALUATIONS}')
    elif sobol < 0:
        raise ScatterError(f'--sobol: 0 (none) or a power of 2, got {sobol}')
