"""
Where a bag's files are: the rosbag2 folder layout and the MCAP magic, in one place.

A bag is a folder holding ``metadata.yaml`` (written when the recording closes) beside its
MCAP files; a bag split by size or duration has several (``name_0.mcap``, ``name_1.mcap``, ...).
Every reader of the package finds the files here, in the same order.
"""

import os
from pathlib import Path
from typing import Any

import yaml

from softseq_ros.errors import NotRegularFileError, UserError, file_kind, read_regular_file
from softseq_ros.yaml_text import parse_yaml

METADATA_FILE = 'metadata.yaml'
MCAP_MAGIC = b'\x89MCAP0\r\n'


def file_order(path: Path) -> tuple[int, str]:
    """Sort key of a bag's files: the number after the last '_' (name_0, name_1, ..., name_10)."""
    stem = path.name.split('.mcap')[0]
    number = stem.rpartition('_')[2]
    return (int(number), path.name) if number.isdigit() else (-1, path.name)


def mcap_files(path: Path, error: type[UserError]) -> tuple[Path, tuple[Path, ...]]:
    """
    The bag folder and its .mcap files in recording order; a path to one .mcap file is a bag.

    ``error`` (the caller's kind of UserError) names the path and what is wrong: no such
    folder, a file that is not .mcap, or a folder without .mcap files (a sqlite3 bag is said so).
    """
    kind = _kind(path)
    if kind == 'a regular file':
        if path.suffix != '.mcap':
            raise error(f'{path}: not a bag (give the bag folder or its .mcap file)')
        return path.parent, (path,)
    if kind is None:
        raise error(f'{path}: no such bag folder')
    if kind != 'a folder':
        # A FIFO would block every reader until a writer came.
        raise error(f'{path}: {kind}, not a bag (give the bag folder or its .mcap file)')
    files = tuple(sorted(path.glob('*.mcap'), key=file_order))
    for file in files:
        if _kind(file) != 'a regular file':
            raise error(f'{file}: {_kind(file) or "gone"}, not a regular file: not a bag file')
    if not files:
        others = sorted(p.name for p in path.glob('*.db3'))
        why = (f'a sqlite3 bag ({", ".join(others)}); softseq reads MCAP bags only'
               if others else 'no .mcap file in it')
        raise error(f'{path}: not an MCAP bag: {why}')
    return path, files


def _kind(path: Path) -> str | None:
    """What ``path`` is ('a regular file', 'a folder', 'a FIFO', ...), None if nothing."""
    try:
        return file_kind(os.stat(path).st_mode)
    except OSError:
        return None


# Nesting below this goes to libyaml's loader (30,000 levels crash it on this machine, 10,000
# do not); Python's own loader takes the rest, and raises RecursionError past Python's limit.
FAST_YAML_MAX_NESTING = 2000


def _nesting_bound(text: str) -> int:
    """
    An upper bound of how deep YAML ``text`` nests its collections.

    A flow collection opens with ``[`` or ``{``; a block one is indented deeper than its
    parent, or opens on its parent's line after ``- `` or ``? ``, so the longest line bounds
    the block levels.
    """
    return text.count('[') + text.count('{') + max(map(len, text.splitlines()), default=0)


def read_metadata(folder: Path, error: type[UserError]) -> dict[str, Any]:
    """
    ``rosbag2_bagfile_information`` of the folder's metadata.yaml, or ``error`` in one line.

    One line also for what YAML cannot hold in Python: nesting deeper than the recursion
    limit, an integer of thousands of digits.
    """
    metadata = folder / METADATA_FILE
    try:
        text = read_regular_file(metadata).decode('utf-8')
        # libyaml's loader where it is built in: a tenth of a report's reading otherwise. It
        # nests C calls without a limit, and a file nested tens of thousands of levels deep
        # crashes the process (SIGSEGV), so only a file that cannot nest deeply is given to it.
        fast = getattr(yaml, 'CSafeLoader', None)
        loader = fast if fast is not None and _nesting_bound(text) < FAST_YAML_MAX_NESTING \
            else yaml.SafeLoader
    except NotRegularFileError as err:
        raise error(f'{metadata}: {err.kind}, not a regular file') from None
    except OSError as err:
        raise error(f'{metadata}: cannot read it ({err.strerror or err})') from None
    except UnicodeDecodeError as err:
        raise error(f'{metadata}: not UTF-8 text (byte {err.start})') from None
    document = parse_yaml(text, str(metadata), error, loader)
    info = document.get('rosbag2_bagfile_information') if isinstance(document, dict) else None
    if not isinstance(info, dict):
        raise error(f'{metadata}: not a rosbag2 metadata file (no rosbag2_bagfile_information '
                    'mapping)')
    return info


def listed_files(folder: Path, error: type[UserError]) -> list[Path] | None:
    """
    The files ``metadata.yaml`` lists, in its order (None: no metadata, or it lists none).

    A metadata file that is not rosbag2's, or that lists a file that is not there, is refused
    with ``error``.
    """
    metadata = folder / METADATA_FILE
    if not metadata.is_file():
        return None
    names = read_metadata(folder, error).get('relative_file_paths') or []
    if not isinstance(names, list):
        raise error(f'{metadata}: not a rosbag2 metadata file (relative_file_paths is no list)')
    files = [folder / name for name in names]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise error(f'{metadata}: lists {", ".join(missing)}, which does not exist')
    return files or None
