"""
The identity of a scene's segments: a digest of what defines them, the same on every machine.

A bag records which scene made it (as ROS records a robot's ``robot_description``): the scene's
name, its segment names and this digest. The digest hashes each segment's definition
(:meth:`softseq_ros.segments.models.Segment.definition`: name, length and the model's data, a
table's rows as read or a model's parameters), base to tip, as JSON with sorted keys, with
SHA-256. Floats go into JSON as their shortest round-trip text, so equal numbers give equal
bytes everywhere; curves sampled from the models are never hashed, because a transcendental
function may round differently on another machine. For the same reason a segment named by its
design (``design:``) is defined by the design's identity, not by the rows of the FEM table
cached for it, and a smoothed table by its rows as read and the smoothing's options, not by the
fit. What does not change the physics does not change the digest: a table's file name, comment
lines, line endings, byte-order mark, column order or extra columns, 1 written for 1.0. A
changed row, parameter, length or segment name does.

No ROS and no numerics here: the rig's actuator publishes the digest, the analysis compares it.
"""

import hashlib
import json
from typing import Iterable, Protocol, Sequence

SHORT_LENGTH = 12


class Defined(Protocol):
    """A segment model that can say what defines it."""

    def definition(self) -> dict[str, object]:
        """Exact JSON-able values: name, length, model and its data."""
        ...


def exact(value: float) -> float:
    """A number as a Python float, -0.0 as 0.0: one spelling of one value in a definition."""
    return float(value) + 0.0


def exact_list(values: Iterable[float]) -> list[float]:
    """Numbers as Python floats (see :func:`exact`)."""
    return [exact(value) for value in values]


def segments_definition(segments: Sequence[Defined]) -> list[dict[str, object]]:
    """Each segment's definition, base to tip."""
    return [segment.definition() for segment in segments]


def _canonical(value: object) -> object:
    """Numbers as exact floats (1 and 1.0 alike), mappings and sequences recursively."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, float)):
        return exact(value)
    if isinstance(value, dict):
        return {str(key): _canonical(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_canonical(item) for item in value]
    raise TypeError(f'a segment definition holds {type(value).__name__} {value!r}: only '
                    'numbers, text, lists and mappings can be hashed')


def canonical_json(segments: Sequence[Defined]) -> str:
    """The text that is hashed: the definitions as JSON with sorted keys, no NaN or inf."""
    return json.dumps(_canonical(segments_definition(segments)), sort_keys=True,
                      allow_nan=False, ensure_ascii=True, separators=(',', ':'))


def segments_sha256(segments: Sequence[Defined]) -> str:
    """The hex SHA-256 of the segments' definitions (64 characters)."""
    return hashlib.sha256(canonical_json(segments).encode('ascii')).hexdigest()


def short(digest: str) -> str:
    """The first characters of a digest, as messages show it."""
    return digest[:SHORT_LENGTH]
