"""
How messages and QoS are written down in a bag: CDR bytes, QoS profiles, YAML as rosbag2 has it.

One place for the forms that the bag writer, the recorder, the batch runner and recovery share:
a message's CDR bytes as they travel over DDS (:func:`serialize`), a publisher's offered QoS in
rosbag2's version-9 form (:func:`qos_profile_dict`, :func:`offered_qos_yaml`) and the YAML
dialect of rosbag2's metadata files (:func:`dump_yaml`).
"""

from functools import lru_cache
from typing import Any, Mapping, Sequence

import yaml

from softseq_ros.errors import UserError
from softseq_ros.wire.cdr import encode

from .msgdefs import message_definition

# RMW_DURATION_INFINITE as rosbag2 writes it: {sec: INT64_MAX // 1e9, nsec: INT64_MAX % 1e9}.
INFINITE_DURATION = {'sec': 9223372036, 'nsec': 854775807}


class QosFormError(UserError):
    """A topic's offered QoS text that is not rosbag2's form."""


def message_type_name(msg: Any) -> str:
    """Return ``pkg/msg/Type`` of an rclpy message object."""
    cls = type(msg)
    package, namespace = cls.__module__.split('.')[:2]
    return f'{package}/{namespace}/{cls.__name__}'


@lru_cache(maxsize=None)
def _cdr_decoder(type_name: str) -> Any:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(message_definition(type_name), type_name))
    return store


def serialize(msg: Any) -> bytes:
    """
    Serialize an rclpy message object to CDR bytes as they travel over DDS (needs rclpy).

    rclpy's serialize_message (Fast DDS) returns a buffer of the estimated size, which can
    end in bytes that belong to no field; strict readers (rosbags) refuse such messages, and
    a subscriber never receives them. The buffer is cut where the last field ends. The rig's
    own types skip all that through :mod:`softseq_ros.wire.cdr`.
    """
    type_name = message_type_name(msg)
    encoded = encode(msg, type_name)
    if encoded is not None:
        return encoded
    from rclpy.serialization import serialize_message
    raw = serialize_message(msg)
    store = _cdr_decoder(type_name)
    msgdef = store.get_msgdef(type_name)
    decode = msgdef.deserialize_cdr_le if raw[1] else msgdef.deserialize_cdr_be
    _, end = decode(raw[4:], 0, msgdef.cls, store)
    return bytes(raw[:4 + end])


class _IndentedDumper(yaml.SafeDumper):
    """Indent sequences inside mappings, as yaml-cpp (and so rosbag2) does."""

    def increase_indent(self, flow: bool = False, indentless: bool = False) -> None:
        """Never emit indentless sequences."""
        super().increase_indent(flow, False)


def dump_yaml(data: Any) -> str:
    """YAML as yaml-cpp (and so rosbag2) writes it: block style, sequences indented."""
    return yaml.dump(data, Dumper=_IndentedDumper, sort_keys=False, default_flow_style=False,
                     allow_unicode=True)


def qos_profile_dict(
    *, history: str = 'keep_last', depth: int = 10, reliability: str = 'reliable',
    durability: str = 'volatile', deadline: Mapping[str, int] = INFINITE_DURATION,
    lifespan: Mapping[str, int] = INFINITE_DURATION, liveliness: str = 'automatic',
    liveliness_lease_duration: Mapping[str, int] = INFINITE_DURATION,
    avoid_ros_namespace_conventions: bool = False,
) -> dict[str, Any]:
    """
    Build one offered QoS profile in rosbag2's version-9 form (policies by name).

    Names are those of rmw's qos_string_conversions: history keep_last/keep_all,
    reliability reliable/best_effort, durability volatile/transient_local, liveliness
    automatic/manual_by_topic (or system_default/unknown). Durations are {sec, nsec}.
    """
    return {
        'history': history, 'depth': int(depth), 'reliability': reliability,
        'durability': durability,
        'deadline': {'sec': int(deadline['sec']), 'nsec': int(deadline['nsec'])},
        'lifespan': {'sec': int(lifespan['sec']), 'nsec': int(lifespan['nsec'])},
        'liveliness': liveliness,
        'liveliness_lease_duration': {'sec': int(liveliness_lease_duration['sec']),
                                      'nsec': int(liveliness_lease_duration['nsec'])},
        'avoid_ros_namespace_conventions': bool(avoid_ros_namespace_conventions),
    }


def offered_qos_yaml(profiles: Sequence[Mapping[str, Any]]) -> str:
    """Serialize offered QoS profiles to the YAML string rosbag2 puts in channel metadata."""
    if not profiles:
        return ''
    return dump_yaml([dict(profile) for profile in profiles]).rstrip('\n')


def parse_qos_yaml(topic: str, qos_profiles_yaml: str) -> list[Any]:
    """The profiles of an offered-QoS YAML string ([] when empty); QosFormError if bad."""
    if not qos_profiles_yaml.strip():
        return []
    try:
        profiles = yaml.safe_load(qos_profiles_yaml)
    except yaml.YAMLError as err:
        raise QosFormError(
            f'topic {topic}: offered_qos_profiles is not valid YAML: {err}') from None
    if not isinstance(profiles, list):
        raise QosFormError(
            f'topic {topic}: offered_qos_profiles must be a YAML sequence of profiles')
    return profiles


