"""
MCAP bags in the rosbag2 layout: writing, recovery, message definitions.

A rig bag is read with :func:`softseq_ros.load_recording` (the one public reader: its topics
as arrays); the readers below it (``arrays``, ``reader``, ``info``) are this package's inside.
The names below load their module on first use, so that writing a bag never imports rosbags.
"""

from importlib import import_module
from typing import Any

_MODULE_OF = {
    'offered_qos_yaml': 'forms', 'qos_profile_dict': 'forms', 'serialize': 'forms',
    'MessageDefinitionError': 'msgdefs', 'message_definition': 'msgdefs',
    'type_description_hash': 'msgdefs',
    'RecoveryResult': 'recovery', 'recover': 'recovery',
    'BagWriter': 'writer', 'BagWriterError': 'writer',
}

__all__ = sorted(_MODULE_OF)


def __getattr__(name: str) -> Any:
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    return getattr(import_module(f'{__name__}.{module}'), name)
