"""Salvaging a truncated or damaged MCAP file (e.g. its writer was killed) into a clean one."""

from dataclasses import dataclass
import os
from pathlib import Path

from motor_id.bag.files import resolve
from motor_id.bag.scan import scan_file
from motor_id.bag.writer import BagWriter, DEFAULT_CHUNK_SIZE
from motor_id.errors import BagError


@dataclass(frozen=True)
class Recovered:
    """What :func:`recover` salvaged.

    Attributes
    ----------
    out : str
        The clean file.
    messages : int
        Messages copied.
    topics : dict
        ``{topic: messages copied}``.
    chunks, chunks_lost : int
        Complete chunks read, corrupt chunks skipped.
    bytes_dropped : int
        The cut tail.
    orphans : int
        Messages of a channel whose definition was lost.
    was_complete : bool
    problem : str
        What was wrong with the input ('' when nothing).
    """

    out: str
    messages: int
    topics: dict[str, int]
    chunks: int
    chunks_lost: int
    bytes_dropped: int
    orphans: int
    was_complete: bool
    problem: str


def recover(path: str | os.PathLike[str], out_path: str | os.PathLike[str],
            chunk_size: int = DEFAULT_CHUNK_SIZE, compression: str = 'zstd') -> Recovered:
    """Copy every message that survives in a damaged MCAP file to a clean file.

    The tolerant scan (:func:`motor_id.bag.scan.scan_file`; no summary or footer
    needed) takes every complete record up to where the file is cut: all complete chunks
    (CRC-checked; a corrupt chunk is skipped, later ones are still read). Their schemas,
    channels (with their QoS metadata) and messages are copied, bytes unchanged, to
    ``out_path``, which gets a summary, a footer and the ``rosbag2`` metadata record.

    Parameters
    ----------
    path : str or Path
        The damaged ``.mcap`` file (or a rosbag2 directory holding one).
    out_path : str or Path
        The clean file to write (replaced if it exists; must differ from ``path``).
    chunk_size : int
        Chunk size of the output [bytes].
    compression : {'zstd', 'lz4', 'none'}

    Returns
    -------
    Recovered

    Notes
    -----
    What a killed :class:`~motor_id.bag.BagWriter` loses is the chunk it was filling: at
    most ``chunk_size`` bytes of messages, or ``flush_interval`` seconds of them.
    Messages of a channel whose definition was only in a lost chunk cannot be copied and
    are counted in ``orphans``.
    """
    src, dst = resolve(path), Path(out_path)
    if dst.exists() and dst.resolve() == src.resolve():
        raise BagError(f'{out_path}: the output must differ from the input')
    scan = scan_file(path)
    if not scan.messages:
        raise BagError(f'{scan.path}: nothing to recover ({scan.problem() or "no messages"})')
    counts: dict[str, int] = {}
    orphans = 0
    with BagWriter(out_path, chunk_size=chunk_size, compression=compression,
                   flush_interval=None) as bag:
        for msg in scan.messages:
            ch = scan.channels.get(msg.channel_id)
            if ch is None:
                orphans += 1
                continue
            schema = scan.schemas.get(ch.schema_id) if ch.schema_id else None
            bag.write_raw(ch.topic, schema, ch.message_encoding, msg.data, msg.log_time,
                          msg.publish_time, msg.sequence, ch.metadata)
            counts[ch.topic] = counts.get(ch.topic, 0) + 1
    return Recovered(out=str(out_path), messages=sum(counts.values()), topics=counts,
                     chunks=scan.chunks, chunks_lost=len(scan.bad_chunks),
                     bytes_dropped=scan.size - scan.stop_offset if not scan.footer else 0,
                     orphans=orphans, was_complete=scan.complete, problem=scan.problem())
