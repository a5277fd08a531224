"""
Reading what users write: YAML with one-line errors, and typed access by key path.

Scene files and segment-design files share it. Every mistake becomes ``SceneError`` (or a
subclass) with one line ``<file>: <key path>: <problem>``: :class:`Context` knows the file and
checks each value as it is taken (``ctx.number(raw['rate_hz'], 'pump.rate_hz', gt=0)``).
"""

import math
from pathlib import Path
import re
from typing import Any

import yaml

from softseq_ros.errors import NotRegularFileError, UserError, read_regular_file
from softseq_ros.scene.limits import LIMITS
from softseq_ros.scene.plausibility import material_problem
from softseq_ros.segments.materials import LAW_NAMES, make_material, material_parameter_names
from softseq_ros.yaml_text import parse_yaml as parse_yaml_text

SEGMENT_NAME = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')
SCENE_NAME = re.compile(r'^[A-Za-z0-9][A-Za-z0-9_.-]*$')
# Tokens that mark where a key's unit suffix starts (``flow_rate_m3_per_s`` -> ``flow_rate``).
UNIT_TOKENS = frozenset({
    'm', 'mm', 'cm', 'um', 'km', 'm3', 'mm3', 'cm3', 'ml', 'l', 'cc', 'pa', 'kpa', 'mpa', 'gpa',
    'bar', 'mbar', 'psi', 's', 'ms', 'min', 'h', 'hz', 'khz', 'per', 'deg', 'rad', 'px',
})
NUMBER_TYPES = (int, float)
INT64_MAX = 2**63 - 1


class SceneError(UserError):
    """A scene file that cannot be used; the message is ``<file>: <key path>: <problem>``."""


class YamlLoader(yaml.SafeLoader):
    """Safe loader that reads ``5e-8`` as a number and refuses duplicate keys."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        """Build a mapping, raising on a key given twice (YAML would keep the last silently)."""
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            if isinstance(key, (str, int, float, bool)) and key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f'duplicate key {key!r}', key_node.start_mark)
            if isinstance(key, (str, int, float, bool)):
                seen.add(key)
        return super().construct_mapping(node, deep=deep)


# YAML 1.1 needs a dot in a float (5.0e-8); scene authors write 5e-8, so accept that too.
YamlLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r'^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$'),
    list('-+0123456789'))


def read_yaml(path: Path, shown: str) -> Any:
    """A YAML file parsed, or SceneError naming ``shown`` and the line and column at fault."""
    try:
        text = read_regular_file(path).decode('utf-8')
    except NotRegularFileError as err:
        raise SceneError(f'{shown}: {err.kind}, not a regular file') from None
    except OSError as err:
        raise SceneError(f'{shown}: cannot read the scene file ({err.strerror})') from None
    except UnicodeDecodeError:
        raise SceneError(f'{shown}: not a UTF-8 text file') from None
    return parse_yaml(text, shown)


def parse_yaml(text: str, shown: str) -> Any:
    """YAML text in the scenes' syntax, or SceneError naming ``shown`` and the fault."""
    return parse_yaml_text(text, shown, SceneError, YamlLoader)


# ----------------------------------------------------------------------------------------------
# Typed access with key paths


def join(key_path: str, key: str) -> str:
    """``pump`` and ``rate_hz`` give ``pump.rate_hz``; an empty path gives the key."""
    return f'{key_path}.{key}' if key_path else key


def unit_stem(key: str) -> str:
    """A key without its unit suffix (``flow_rate_m3_per_s`` -> ``flow_rate``)."""
    tokens = key.lower().split('_')
    for index, token in enumerate(tokens[1:], start=1):
        if token in UNIT_TOKENS:
            return '_'.join(tokens[:index])
    return '_'.join(tokens)


def _digits(value: int) -> int:
    """About how many decimal digits an integer has (str() refuses beyond 4300 of them)."""
    return max(1, round(abs(value).bit_length() * math.log10(2)))


def type_name(value: object) -> str:
    """A value's type as YAML would call it in an error (``null`` for None)."""
    return 'null' if value is None else type(value).__name__


class Context:
    """The file being read (for error messages and relative paths) and typed access to it."""

    def __init__(self, shown: str, folder: Path) -> None:
        """
        Read a file shown as ``shown`` in errors, its relative paths starting from ``folder``.

        ``shown`` is '' for text that is no file (a setting): errors then start at the key.
        """
        self.shown = shown
        self.folder = folder

    def error(self, key_path: str, problem: str) -> SceneError:
        """The one-line error for ``key_path`` (after the file's name, when there is a file)."""
        one_line = ' '.join(str(problem).split())
        where = f'{self.shown}: ' if self.shown else ''
        return SceneError(f'{where}{key_path or "(top level)"}: {one_line}')

    def mapping(self, value: object, key_path: str, required: tuple[str, ...],
                optional: tuple[str, ...] = ()) -> dict[str, Any]:
        """
        A mapping with these keys.

        An unknown key is refused; when only its unit suffix is wrong, the error names the key
        to write instead.
        """
        if not isinstance(value, dict):
            raise self.error(key_path, f'must be a mapping, got {type_name(value)}')
        allowed = required + optional
        for key in value:
            if not isinstance(key, str):
                raise self.error(key_path, f'keys must be text, got {key!r} '
                                           f'({type_name(key)}); quote it')
            if key in allowed:
                continue
            stem = unit_stem(key)
            same_quantity = [name for name in allowed if unit_stem(name) == stem]
            if same_quantity:
                raise self.error(join(key_path, key),
                                 f'wrong or missing unit suffix; scene files use SI units, write '
                                 f'{same_quantity[0]}')
            raise self.error(join(key_path, key),
                             f'unknown key; expected one of {", ".join(allowed)}')
        for key in required:
            if key not in value:
                raise self.error(join(key_path, key), 'required key is missing')
        return value

    def number(self, value: object, key_path: str, *, gt: float | None = None,
               ge: float | None = None) -> float:
        """A finite number, optionally bounded below."""
        if isinstance(value, bool) or not isinstance(value, NUMBER_TYPES):
            raise self.error(key_path, f'must be a number, got {type_name(value)} {value!r}')
        try:
            number = float(value)
        except OverflowError:
            # An integer literal beyond a double (10**400): as good as infinite.
            raise self.error(key_path, f'must be finite, got an integer of about '
                                       f'{_digits(value)} digits, beyond the range of a float') \
                from None
        if not math.isfinite(number):
            raise self.error(key_path, f'must be finite, got {number}')
        if gt is not None and not number > gt:
            raise self.error(key_path, f'must be > {gt:g}, got {number:g}')
        if ge is not None and not number >= ge:
            raise self.error(key_path, f'must be >= {ge:g}, got {number:g}')
        return number

    def integer(self, value: object, key_path: str, *, ge: int | None = None) -> int:
        """An integer (not a bool), optionally bounded below."""
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key_path, f'must be an integer, got {type_name(value)} {value!r}')
        if not -INT64_MAX - 1 <= value <= INT64_MAX:
            # Beyond 64 bits no setting means anything, and a float could not show the bound.
            raise self.error(key_path, f'must fit in 64 bits (at most {INT64_MAX}), got an '
                                       f'integer of about {_digits(value)} digits')
        if ge is not None and value < ge:
            raise self.error(key_path, f'must be >= {ge}, got {value}')
        return value

    def limited(self, value: object, key_path: str, limit_key: str | None = None, *,
                integer: bool = False) -> float:
        """A number within its entry of LIMITS (by default the entry of ``key_path`` itself)."""
        number = self.integer(value, key_path) if integer else self.number(value, key_path)
        reason = LIMITS[limit_key or key_path].reason(number)
        if reason is not None:
            raise self.error(key_path, reason)
        return number

    def text(self, value: object, key_path: str) -> str:
        """A text value."""
        if not isinstance(value, str):
            raise self.error(key_path, f'must be text, got {type_name(value)} {value!r}')
        return value

    def sequence(self, value: object, key_path: str) -> list:
        """A list."""
        if not isinstance(value, list):
            raise self.error(key_path, f'must be a list, got {type_name(value)}')
        return value

    def material(self, value: object, key_path: str) -> Any:
        """A material block ``{law: ..., <its parameters>}``, checked and built."""
        if not isinstance(value, dict):
            raise self.error(key_path, f'must be a mapping, got {type_name(value)}')
        if 'law' not in value:
            raise self.error(join(key_path, 'law'), f'required key is missing; one of '
                                                    f'{", ".join(LAW_NAMES)}')
        law = self.text(value['law'], join(key_path, 'law'))
        if law not in LAW_NAMES:
            raise self.error(join(key_path, 'law'), f'unknown material law {law!r}; expected one '
                                                    f'of {", ".join(LAW_NAMES)}')
        names = material_parameter_names(law)
        required = tuple(n for n in names if not (law == 'yeoh' and n == 'c3_pa'))
        optional = tuple(n for n in names if n not in required)
        params = self.mapping(value, key_path, ('law',) + required, optional)
        checked: dict[str, object] = {}
        for key in names:
            if key not in params:
                continue
            where = join(key_path, key)
            if law == 'ogden':
                items = self.sequence(params[key], where)
                if not items:
                    raise self.error(where, 'must list at least one value')
                checked[key] = [self.number(item, f'{where}[{i}]') for i, item in enumerate(items)]
            elif key == 'jm' or key == 'lambda_m':
                checked[key] = self.number(params[key], where, gt=0.0)
            elif key in ('shear_modulus_pa', 'c1_pa'):
                checked[key] = self.number(params[key], where, gt=0.0)
            else:
                checked[key] = self.number(params[key], where)
        if law == 'ogden' and len(checked['mu_pa']) != len(checked['alpha']):
            raise self.error(join(key_path, 'alpha'),
                             f'needs as many values as mu_pa ({len(checked["mu_pa"])}), '
                             f'got {len(checked["alpha"])}')
        if law == 'ogden':
            # Ogden's stability condition, term by term: mu_i alpha_i > 0. Named at the value
            # that breaks it: a zero or wrongly signed exponent, else its modulus.
            for i, (mu, alpha) in enumerate(zip(checked['mu_pa'], checked['alpha'])):
                if not mu * alpha > 0.0:
                    at = f'alpha[{i}]' if alpha == 0.0 or mu > 0.0 else f'mu_pa[{i}]'
                    raise self.error(join(key_path, at),
                                     f'mu_pa[{i}] x alpha[{i}] = {mu:g} x {alpha:g} must be '
                                     '> 0 (each term of an Ogden law stiffens as it stretches)')
        try:
            material = make_material(law, checked)
        except ValueError as err:
            raise self.error(key_path, str(err)) from None
        problem = material_problem(material)
        if problem is not None:
            raise self.error(key_path, problem)
        return material
