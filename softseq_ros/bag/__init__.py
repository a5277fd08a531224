"""MCAP bags in the rosbag2 layout: writing, reading, playback."""

from .forms import offered_qos_yaml, qos_profile_dict, serialize
from .msgdefs import MessageDefinitionError, message_definition, type_description_hash
from .reader import BagMessage, BagReadError, BagSummary, TopicSummary, bag_summary, read_bag
from .recovery import RecoveryResult, recover
from .writer import BagWriter, BagWriterError

__all__ = [
    'BagMessage', 'BagReadError', 'BagSummary', 'BagWriter', 'BagWriterError',
    'MessageDefinitionError', 'RecoveryResult', 'TopicSummary', 'bag_summary',
    'message_definition', 'offered_qos_yaml', 'qos_profile_dict', 'read_bag', 'recover',
    'serialize', 'type_description_hash',
]
