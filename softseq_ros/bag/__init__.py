"""
MCAP bags in the rosbag2 layout: writing, reading, playback.

The names below load their module on first use: reading a rig bag into arrays
(softseq_ros.bag.arrays, what a report does) then never imports rosbags, which only the
message-by-message reader needs (a third of a second off every ``softseq report``).
"""

from importlib import import_module
from typing import Any

_MODULE_OF = {
    'offered_qos_yaml': 'forms', 'qos_profile_dict': 'forms', 'serialize': 'forms',
    'MessageDefinitionError': 'msgdefs', 'message_definition': 'msgdefs',
    'type_description_hash': 'msgdefs',
    'BagMessage': 'reader', 'BagReadError': 'reader', 'BagSummary': 'reader',
    'TopicSummary': 'reader', 'bag_summary': 'reader', 'read_bag': 'reader',
    'RecoveryResult': 'recovery', 'recover': 'recovery',
    'BagWriter': 'writer', 'BagWriterError': 'writer',
}

__all__ = sorted(_MODULE_OF)


def __getattr__(name: str) -> Any:
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    return getattr(import_module(f'{__name__}.{module}'), name)
