"""
Message definitions of installed ROS 2 interface packages, as rosbag2 stores them.

rosbag2's MCAP storage plugin puts the full definition text of a type into each schema
record: the type's own ``.msg`` file, then every type it depends on, once, depth first and
in sorted order, each preceded by a line of 80 ``=`` and a line ``MSG: pkg/Type``. Readers
such as Foxglove, rosbags and mcap-ros2-support rebuild the decoder from that text alone,
so it has to be complete. The ``.msg`` and ``.json`` files are looked up in the installed
packages' share directories (``<prefix>/share/<pkg>/msg``), found through the ament index
(``AMENT_PREFIX_PATH``) or, when that is not set, under ``sys.prefix``, where the ROS 2
Python wheels install them.
"""

from functools import lru_cache
import json
import os
from pathlib import Path
import re
import sys

from softseq_ros.errors import UserError

SEPARATOR = '=' * 80

# Same pattern as rosbag2_storage_mcap: the first word of every non-comment line is a type.
_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_TYPE_NAME = re.compile(r'^([a-zA-Z][a-zA-Z0-9_]*)/(?:(msg|srv)/)?([a-zA-Z][a-zA-Z0-9_]*)$')
# wstring is added to rosbag2's list: it is a primitive, not a type to look up.
_PRIMITIVES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring',
})
_MAX_DEPTH = 50


class MessageDefinitionError(UserError):
    """A message type is malformed or its definition is not installed."""


def split_type_name(type_name: str) -> tuple[str, str, str]:
    """
    Split ``pkg/msg/Type`` (or ``pkg/Type``) into package, namespace and type.

    Raises MessageDefinitionError for a name that is not of that form.
    """
    match = _TYPE_NAME.match(type_name)
    if match is None:
        raise MessageDefinitionError(
            f'message type {type_name!r}: expected the form pkg/msg/Type')
    package, namespace, name = match.groups()
    return package, namespace or 'msg', name


def canonical_type_name(type_name: str) -> str:
    """Return the ``pkg/msg/Type`` spelling of a message type name."""
    package, namespace, name = split_type_name(type_name)
    return f'{package}/{namespace}/{name}'


def share_directory(package: str) -> Path:
    """
    Return the share directory of an installed package.

    The ament index (AMENT_PREFIX_PATH) is asked first; without it, ``sys.prefix/share``
    is used. Raises MessageDefinitionError when neither holds the package.
    """
    if os.environ.get('AMENT_PREFIX_PATH'):
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )
        try:
            return Path(get_package_share_directory(package, print_warning=False))
        except (PackageNotFoundError, ValueError):
            pass
    candidate = Path(sys.prefix) / 'share' / package
    if candidate.is_dir():
        return candidate
    raise MessageDefinitionError(
        f'message package {package!r} is not installed (looked in AMENT_PREFIX_PATH and '
        f'{Path(sys.prefix) / "share"})')


def _interface_file(type_name: str, suffix: str) -> Path:
    package, namespace, name = split_type_name(type_name)
    return share_directory(package) / namespace / f'{name}{suffix}'


@lru_cache(maxsize=None)
def _msg_text(type_name: str) -> str:
    path = _interface_file(type_name, '.msg')
    try:
        return path.read_text(encoding='utf-8')
    except OSError as err:
        raise MessageDefinitionError(
            f'{path}: cannot read the definition of {type_name}: {err.strerror}') from None


def _dependencies(text: str, package: str) -> list[str]:
    found = set()
    for match in _FIELD_TYPE.finditer(text):
        field_type = match.group(1)
        if field_type in _PRIMITIVES:
            continue
        found.add(field_type if '/' in field_type else f'{package}/{field_type}')
    return sorted(found)


@lru_cache(maxsize=None)
def message_definition(type_name: str) -> str:
    """
    Return the full ``ros2msg`` definition text of a type, exactly as rosbag2 writes it.

    ``type_name`` is ``pkg/msg/Type``. The text is the type's .msg file followed by each
    dependency once (depth first, sorted by name), each block introduced by a newline, a
    line of 80 ``=`` and ``MSG: pkg/Type``.
    """
    canonical_type_name(type_name)
    seen: set[str] = set()

    def expand(name: str, depth: int) -> str:
        if depth <= 0:
            raise MessageDefinitionError(
                f'message type {type_name}: dependencies nest deeper than {_MAX_DEPTH}')
        text = _msg_text(name)
        result = text
        for dependency in _dependencies(text, split_type_name(name)[0]):
            if dependency not in seen:
                seen.add(dependency)
                result += f'\n{SEPARATOR}\nMSG: {dependency}\n' + expand(dependency, depth - 1)
        return result

    return expand(type_name, _MAX_DEPTH)


@lru_cache(maxsize=None)
def type_description_hash(type_name: str) -> str | None:
    """
    Return the RIHS01 type hash of a type from its installed ``.json`` type description.

    Returns None when the package ships no ``.json`` file for the type (pre-Iron packages),
    in which case rosbag2 also leaves the hash out.
    """
    canonical = canonical_type_name(type_name)
    path = _interface_file(type_name, '.json')
    if not path.is_file():
        return None
    try:
        description = json.loads(path.read_text(encoding='utf-8'))
    except (OSError, ValueError) as err:
        raise MessageDefinitionError(f'{path}: unreadable type description: {err}') from None
    for entry in description.get('type_hashes', []):
        if entry.get('type_name') == canonical:
            return entry.get('hash_string')
    return None
