"""
Where shipped files are: the config folder of a source checkout or of an installed package.

Scenes, segment tables and segment designs ship under ``config/``; a bare name (``paper``,
``paper_top``) means the shipped file of that name.
"""

import os
from pathlib import Path
import sys

from softseq_ros.errors import not_a_file
from softseq_ros.scene.validation import SceneError

PACKAGE = 'softseq_ros'


def config_dir_candidates() -> list[Path]:
    """Folders searched for shipped scenes: source checkout, ament prefixes, sys.prefix."""
    candidates = [Path(__file__).resolve().parents[2] / 'config']
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / 'share' / PACKAGE / 'config')
    candidates.append(Path(sys.prefix) / 'share' / PACKAGE / 'config')
    return candidates


def config_dir() -> Path:
    """
    The folder of the shipped scenes.

    In a source checkout this is ``<repo>/config``; in an installed package it is
    ``<prefix>/share/softseq_ros/config``. Raises SceneError when neither exists.
    """
    candidates = config_dir_candidates()
    for candidate in candidates:
        if (candidate / 'paper.yaml').is_file():
            return candidate
    looked = ', '.join(str(c) for c in candidates)
    raise SceneError(f'no shipped config folder found (looked in {looked})')


def shipped_scenes() -> list[str]:
    """Names of the shipped scenes (``paper``, ...), sorted."""
    return sorted(path.stem for path in config_dir().glob('*.yaml'))


def scene_path(name_or_path: str | Path) -> Path:
    """
    Resolve a scene argument: an existing file, or a bare name like ``paper``.

    A bare name (no folder, no suffix) means ``<config_dir()>/<name>.yaml``.
    """
    path = Path(name_or_path)
    text = str(name_or_path)
    is_bare = path.suffix == '' and os.sep not in text and '/' not in text
    shipped = config_dir() / f'{text}.yaml' if is_bare and text else None
    try:
        if path.is_file():
            return path
        if shipped is not None and shipped.is_file():
            return shipped
    except (OSError, ValueError) as err:
        # A name the system cannot even look up (too long, a NUL byte).
        shown = text if len(text) <= 80 else f'{text[:60]}... ({len(text)} characters)'
        raise SceneError(f'{shown}: not a scene file or a shipped scene name '
                         f'({getattr(err, "strerror", None) or err})') from None
    if os.path.lexists(path):
        # There, but no file to read (a folder, a FIFO): not "not found".
        raise SceneError(f'{text}: {not_a_file(path, "scene file")}: not a scene file')
    if shipped is not None:
        known = ', '.join(shipped_scenes())
        raise SceneError(f'{text}: no such scene file and no shipped scene of that name '
                         f'(shipped: {known})')
    raise SceneError(f'{text}: scene file not found')
