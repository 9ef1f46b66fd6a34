"""What is in an MCAP file: topics, types, counts, time span, integrity (damaged files too)."""

from dataclasses import asdict, dataclass
import os
from typing import Any

from motor_id.bag.metadata import METADATA_RECORD, read_ros_distro
from motor_id.bag.scan import scan_file


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag: its type, message count, encoding and offered QoS (YAML)."""

    topic: str
    type: str
    count: int
    encoding: str
    qos: str


@dataclass(frozen=True)
class BagInfo:
    """Summary of an MCAP file (see :func:`bag_info`).

    Attributes
    ----------
    path : str
    size_bytes : int
    profile, library : str
        The MCAP header's.
    complete : bool
        False for a truncated or damaged file; ``problem`` says why.
    problem : str
    messages, chunks : int
    compression : list of str
    start_ns, end_ns : int
        First and last log time [ns] (0 without messages).
    duration_s : float
    topics : list of TopicSummary
    metadata : list of str
        Metadata record names.
    ros_distro : str
    """

    path: str
    size_bytes: int
    profile: str
    library: str
    complete: bool
    problem: str
    messages: int
    chunks: int
    compression: list[str]
    start_ns: int
    end_ns: int
    duration_s: float
    topics: list[TopicSummary]
    metadata: list[str]
    ros_distro: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``motor-id bag info --json``)."""
        return asdict(self)


def bag_info(path: str | os.PathLike[str]) -> BagInfo:
    """Summary of an MCAP file: topics, types, counts, time span, integrity.

    Built on the tolerant scan, so it works on truncated or damaged files too (then
    ``complete`` is False and ``problem`` says why).

    Parameters
    ----------
    path : str or Path
        An ``.mcap`` file or a rosbag2 directory holding one.

    Returns
    -------
    BagInfo

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
        topics.append(TopicSummary(ch.topic, schema.name if schema else '',
                                   counts.get(ch.topic, 0), ch.message_encoding,
                                   ch.metadata.get('offered_qos_profiles', '')))
    times = [m.log_time for m in scan.messages]
    start = min(times) if times else 0
    end = max(times) if times else 0
    return BagInfo(
        path=scan.path, size_bytes=scan.size, profile=scan.profile, library=scan.library,
        complete=scan.complete, problem=scan.problem(), messages=len(scan.messages),
        chunks=scan.chunks, compression=sorted(scan.compressions), start_ns=start,
        end_ns=end, duration_s=(end - start) * 1e-9, topics=topics,
        metadata=[name for name, _ in scan.metadata], ros_distro=_ros_distro(scan.metadata))


def _ros_distro(metadata: list[Any]) -> str:
    """``ros_distro`` of the ``rosbag2`` metadata record ('' when absent)."""
    for name, values in metadata:
        if name == METADATA_RECORD:
            return read_ros_distro(values.get('serialized_metadata')) or values.get(
                'ROS_DISTRO', '')
    return ''
