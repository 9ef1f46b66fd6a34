"""The rosbag2 metadata of an MCAP bag: offered QoS per channel and the ``rosbag2`` record.

What ``ros2 bag info`` / ``ros2 bag play`` of ROS 2 Jazzy expect besides the messages:
each channel's ``offered_qos_profiles`` (YAML) and ``topic_type_hash`` metadata, and a
metadata record ``rosbag2`` whose ``serialized_metadata`` is the bag's ``metadata.yaml``
(version 9). The QoS depths are the ones the nodes offer (:mod:`motor_id.contracts`).
"""

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import yaml

from motor_id.bag.schemas import MESSAGE_ENCODING, topic_name, type_hash
from motor_id.contracts import (
    BAG_ESTIMATE_TOPIC,
    BAG_META_TOPIC,
    BAG_SAMPLES_TOPIC,
    CHANNEL_DEPTH,
    LATCHED_DEPTH,
    SAMPLES_DEPTH,
)
from motor_id.errors import ConfigError

ROS_DISTRO = 'jazzy'
ROSBAG2_METADATA_VERSION = 9
METADATA_RECORD = 'rosbag2'


@dataclass(frozen=True)
class QosProfile:
    """An offered QoS profile: keep last ``depth``, no deadline, lifespan or lease.

    Attributes
    ----------
    reliability : {'reliable', 'best_effort'}
    durability : {'volatile', 'transient_local'}
    depth : int
        History depth (keep last).
    """

    reliability: str
    durability: str
    depth: int

    def to_dict(self) -> dict[str, Any]:
        """The form rosbag2 (metadata version 9) stores in ``offered_qos_profiles``."""
        unset = {'sec': 0, 'nsec': 0}
        return {'history': 'keep_last', 'depth': self.depth, 'reliability': self.reliability,
                'durability': self.durability, 'deadline': dict(unset),
                'lifespan': dict(unset), 'liveliness': 'automatic',
                'liveliness_lease_duration': dict(unset),
                'avoid_ros_namespace_conventions': False}


def qos_profile(reliability: str = 'reliable', durability: str = 'volatile',
                depth: int = 10) -> QosProfile:
    """An offered QoS profile, checked.

    Parameters
    ----------
    reliability : {'reliable', 'best_effort'}
    durability : {'volatile', 'transient_local'}
    depth : int
        History depth (keep last).

    Returns
    -------
    QosProfile

    Raises
    ------
    ConfigError
        A reliability, durability or depth out of its domain.
    """
    if reliability not in ('reliable', 'best_effort'):
        raise ConfigError(f'reliability must be reliable or best_effort, got {reliability!r}')
    if durability not in ('volatile', 'transient_local'):
        raise ConfigError(f'durability must be volatile or transient_local, got {durability!r}')
    if int(depth) < 1:
        raise ConfigError(f'QoS depth must be >= 1, got {depth}')
    return QosProfile(reliability, durability, int(depth))


def default_qos(topic: str) -> QosProfile:
    """The QoS the nodes offer a topic of the motor_id layout with (depths from contracts).

    ``/samples``: reliable, volatile, :data:`~motor_id.contracts.SAMPLES_DEPTH`;
    ``/motor_id/meta`` and ``/identifier/estimate``: reliable, transient local,
    :data:`~motor_id.contracts.LATCHED_DEPTH`; anything else (the per-channel topics):
    reliable, volatile, :data:`~motor_id.contracts.CHANNEL_DEPTH`.
    """
    topic = topic_name(topic)
    if topic == BAG_SAMPLES_TOPIC:
        return qos_profile('reliable', 'volatile', SAMPLES_DEPTH)
    if topic in (BAG_META_TOPIC, BAG_ESTIMATE_TOPIC):
        return qos_profile('reliable', 'transient_local', LATCHED_DEPTH)
    return qos_profile('reliable', 'volatile', CHANNEL_DEPTH)


def rosbag2_metadata(file_name: str, topics: Iterable[Any], start_ns: int | None,
                     end_ns: int | None) -> str:
    """The ``metadata.yaml`` text of a one-file Jazzy bag (version 9), as rosbag2 writes it.

    Parameters
    ----------
    file_name : str
    topics : iterable
        Objects with ``name, msgtype, count`` and ``metadata`` (the MCAP channel
        metadata: the QoS and type hash come from there).
    start_ns, end_ns : int or None
        First and last log time [ns] (None: no messages).

    Returns
    -------
    str
    """
    start = start_ns or 0
    duration = (end_ns - start) if end_ns is not None else 0
    listed = [{'topic_metadata': {
                   'name': t.name, 'type': t.msgtype, 'serialization_format': MESSAGE_ENCODING,
                   'offered_qos_profiles': offered_qos(t.metadata),
                   'type_description_hash': t.metadata.get('topic_type_hash', '')},
               'message_count': t.count} for t in topics]
    count = sum(t['message_count'] for t in listed)
    info = {
        'version': ROSBAG2_METADATA_VERSION,
        'storage_identifier': 'mcap',
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': count,
        'topics_with_message_count': listed,
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [file_name],
        'files': [{'path': file_name, 'starting_time': {'nanoseconds_since_epoch': start},
                   'duration': {'nanoseconds': duration}, 'message_count': count}],
        'custom_data': None,
        'ros_distro': ROS_DISTRO,
    }
    return _yaml(info)


def _yaml(value: Any) -> str:
    """Block-style YAML (the form yaml-cpp writes for rosbag2), keys in insertion order."""
    return yaml.safe_dump(value, default_flow_style=False, sort_keys=False)


def channel_metadata(msgtype: str, qos: QosProfile) -> dict[str, str]:
    """MCAP channel metadata of a topic as rosbag2 writes it (QoS YAML, type hash)."""
    return {'offered_qos_profiles': _yaml([qos.to_dict()]),
            'topic_type_hash': type_hash(msgtype)}


def offered_qos(metadata: Mapping[str, str]) -> list[dict[str, Any]]:
    """The QoS profiles (list of dicts) of an MCAP channel's metadata ([] if none/unreadable)."""
    try:
        profiles = yaml.safe_load(metadata.get('offered_qos_profiles') or '[]')
    except yaml.YAMLError:
        return []
    return profiles if isinstance(profiles, list) else []


def read_ros_distro(serialized_metadata: str) -> str:
    """``ros_distro`` of a ``serialized_metadata`` text ('' when absent or unreadable)."""
    try:
        info = yaml.safe_load(serialized_metadata or '')
    except yaml.YAMLError:
        return ''
    return str(info.get('ros_distro') or '') if isinstance(info, dict) else ''
