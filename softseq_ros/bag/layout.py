"""
Where a bag's files are: the rosbag2 folder layout and the MCAP magic, in one place.

A bag is a folder holding ``metadata.yaml`` (written when the recording closes) beside its
MCAP files; a bag split by size or duration has several (``name_0.mcap``, ``name_1.mcap``, ...).
Every reader of the package finds the files here, in the same order.
"""

from pathlib import Path

import yaml

from softseq_ros.errors import UserError

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
    if path.is_file():
        if path.suffix != '.mcap':
            raise error(f'{path}: not a bag (give the bag folder or its .mcap file)')
        return path.parent, (path,)
    if not path.is_dir():
        raise error(f'{path}: no such bag folder')
    files = tuple(sorted(path.glob('*.mcap'), key=file_order))
    if not files:
        others = sorted(p.name for p in path.glob('*.db3'))
        why = (f'a sqlite3 bag ({", ".join(others)}); softseq reads MCAP bags only'
               if others else 'no .mcap file in it')
        raise error(f'{path}: not an MCAP bag: {why}')
    return path, files


def listed_files(folder: Path, error: type[UserError]) -> list[Path] | None:
    """
    The files ``metadata.yaml`` lists, in its order (None: no metadata, or it lists none).

    A metadata file that is not rosbag2's, or that lists a file that is not there, is refused
    with ``error``.
    """
    metadata = folder / METADATA_FILE
    if not metadata.is_file():
        return None
    try:
        # libyaml's loader where it is built in: a tenth of a report's reading otherwise.
        info = yaml.load(metadata.read_text(encoding='utf-8'),
                         Loader=getattr(yaml, 'CSafeLoader', yaml.SafeLoader))[
            'rosbag2_bagfile_information']
        names = info.get('relative_file_paths') or []
    except (yaml.YAMLError, KeyError, TypeError, AttributeError) as err:
        raise error(f'{metadata}: not a rosbag2 metadata file ({err})') from None
    files = [folder / name for name in names]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise error(f'{metadata}: lists {", ".join(missing)}, which does not exist')
    return files or None
