"""What is in an MCAP file: topics, types, counts, time span, integrity (damaged files too)."""

import os
from typing import Any

from motor_id.bag.metadata import METADATA_RECORD, read_ros_distro
from motor_id.bag.scan import scan_file


def bag_info(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Summary of an MCAP file: topics, types, counts, time span, integrity.

    Built on the tolerant scan, so it works on truncated or damaged files too (then
    ``complete`` is False and ``problem`` says why).

    Parameters
    ----------
    path : str or Path
        An ``.mcap`` file or a rosbag2 directory holding one.

    Returns
    -------
    dict
        ``path, size_bytes, profile, library, complete, problem, messages, chunks,
        compression, start_ns, end_ns, duration_s, topics`` (list of ``{topic, type,
        count, encoding, qos}``), ``metadata`` (record names), ``ros_distro``.

    Raises
    ------
    BagError
        Missing, empty or non-MCAP file.
    """
    scan = scan_file(path)
    counts = scan.topic_counts()
    topics = []
    for ch in sorted(scan.channels.values(), key=lambda c: c.topic):
        schema = scan.schemas.get(ch.schema_id)
        topics.append({'topic': ch.topic, 'type': schema.name if schema else '',
                       'count': counts.get(ch.topic, 0), 'encoding': ch.message_encoding,
                       'qos': ch.metadata.get('offered_qos_profiles', '')})
    times = [m.log_time for m in scan.messages]
    start = min(times) if times else 0
    end = max(times) if times else 0
    return {
        'path': scan.path, 'size_bytes': scan.size, 'profile': scan.profile,
        'library': scan.library, 'complete': scan.complete, 'problem': scan.problem(),
        'messages': len(scan.messages), 'chunks': scan.chunks,
        'compression': sorted(scan.compressions), 'start_ns': start, 'end_ns': end,
        'duration_s': (end - start) * 1e-9, 'topics': topics,
        'metadata': [name for name, _ in scan.metadata],
        'ros_distro': _ros_distro(scan.metadata),
    }


def _ros_distro(metadata: list[Any]) -> str:
    """``ros_distro`` of the ``rosbag2`` metadata record ('' when absent)."""
    for name, values in metadata:
        if name == METADATA_RECORD:
            return read_ros_distro(values.get('serialized_metadata')) or values.get(
                'ROS_DISTRO', '')
    return ''
