"""The tolerant scan of a damaged MCAP file: what survives, and where and why it breaks.

Only :func:`motor_id.bag.recover` and :func:`motor_id.bag.bag_info` (and the reader's
diagnosis of a file it cannot read) use it; normal reading goes through the mcap
library's reader. The scan runs the library's ``StreamReader`` record by record, checks
every chunk on its own (a corrupt chunk is counted and skipped) and, where the stream
reader gives up, reads the 9-byte record frame (opcode, length) to tell a cut file from
a damaged record and to resume after a damaged one.
"""

from collections.abc import Iterator
from dataclasses import dataclass, field
import os
import struct
from typing import Any, BinaryIO

from mcap.exceptions import McapError
from mcap.records import (
    Channel,
    Chunk,
    DataEnd,
    Footer,
    Header,
    Message,
    Metadata,
    Schema,
    Statistics,
)
from mcap.stream_reader import breakup_chunk, StreamReader
import zstandard

from motor_id.bag.files import open_mcap
from motor_id.contracts import BAG_SAMPLES_TOPIC

DAMAGE_ERRORS = (McapError, ValueError, struct.error, RuntimeError, EOFError, IndexError,
                 ArithmeticError, zstandard.ZstdError)
"""What the mcap library raises on cut or corrupt bytes (lz4 raises RuntimeError)."""
_FRAME = struct.Struct('<BQ')


@dataclass
class Scan:
    """What a tolerant linear pass over an MCAP file found."""

    path: str
    size: int = 0
    profile: str = ''
    library: str = ''
    schemas: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)
    messages: list = field(default_factory=list)
    metadata: list = field(default_factory=list)
    statistics: object = None
    chunks: int = 0
    compressions: set = field(default_factory=set)
    bad_chunks: list = field(default_factory=list)
    bad_records: list = field(default_factory=list)
    data_end: bool = False
    footer: bool = False
    end_magic: bool = False
    stop_offset: int = 0
    stop_reason: str = ''

    @property
    def data_complete(self) -> bool:
        """True when every message the writer wrote is here."""
        return self.data_end and not self.bad_chunks and not self.bad_records

    @property
    def complete(self) -> bool:
        """True when the file is whole: all data, summary, footer and closing magic."""
        return self.data_complete and self.footer and self.end_magic

    def problem(self) -> str:
        """One line on what is wrong, or '' when the file is whole."""
        parts = []
        if not self.data_end:
            parts.append(self.stop_reason or 'the data section does not end')
        if self.bad_chunks:
            off, why = self.bad_chunks[0]
            parts.append(f'{len(self.bad_chunks)} corrupt chunk(s), first at byte {off} '
                         f'({why})')
        if self.bad_records:
            off, why = self.bad_records[0]
            parts.append(f'{len(self.bad_records)} unreadable record(s), first at byte {off} '
                         f'({why})')
        if self.data_end and not self.footer:
            parts.append('summary/footer missing (' + (self.stop_reason or 'cut') + ')')
        elif self.footer and not self.end_magic:
            parts.append('closing magic missing')
        return '; '.join(parts)

    def topic_counts(self) -> dict[str, int]:
        """Messages per topic (``<channel N>`` for a message whose channel was lost)."""
        counts: dict[str, int] = {}
        for msg in self.messages:
            ch = self.channels.get(msg.channel_id)
            name = ch.topic if ch else f'<channel {msg.channel_id}>'
            counts[name] = counts.get(name, 0) + 1
        return counts

    def recover_hint(self) -> str:
        """How much :func:`motor_id.bag.recover` would salvage, and the command."""
        counts = self.topic_counts()
        return (f'{sum(counts.values())} message(s) ({counts.get(BAG_SAMPLES_TOPIC, 0)} on '
                f'{BAG_SAMPLES_TOPIC}) can be recovered: motor-id bag recover {self.path} '
                'OUT.mcap')


def scan_file(path: str | os.PathLike[str]) -> Scan:
    """Read every complete record of an MCAP file, tolerating a cut end and bad chunks.

    Parameters
    ----------
    path : str or Path
        An ``.mcap`` file or a rosbag2 directory holding one.

    Returns
    -------
    Scan

    Raises
    ------
    BagError
        Missing, empty or non-MCAP file (everything else is reported in the Scan).
    """
    fh, size = open_mcap(path)
    scan = Scan(str(path), size)
    with fh:
        skip_magic = False
        while True:
            records = StreamReader(fh, skip_magic=skip_magic, emit_chunks=True,
                                   record_size_limit=None).records
            if not _take_records(scan, fh, records):
                break
            skip_magic = True
    return scan


def _take_records(scan: Scan, fh: BinaryIO, records: Iterator[Any]) -> bool:
    """Consume records until the end or an error; True to resume after a damaged record."""
    while True:
        start = fh.tell()
        try:
            record = next(records)
        except StopIteration:
            scan.stop_offset = fh.tell()
            scan.end_magic = True
            return False
        except DAMAGE_ERRORS as exc:
            return _damaged_at(scan, fh, start, exc)
        _take(scan, record, start)
        if isinstance(record, Footer):
            scan.footer = True


def _damaged_at(scan: Scan, fh: BinaryIO, start: int, exc: BaseException) -> bool:
    """Note why reading stopped at ``start``; seek past the record if its frame is whole."""
    scan.stop_offset = start
    if scan.footer:
        return False                      # only the closing magic is missing or wrong
    n = scan.size
    if start == n:
        scan.stop_reason = f'file ends at byte {n} without a footer'
        return False
    if start + _FRAME.size > n:
        scan.stop_reason = f'cut inside a record header at byte {start} of {n}'
        return False
    fh.seek(start)
    _, length = _FRAME.unpack(fh.read(_FRAME.size))
    end = start + _FRAME.size + length
    if end > n:
        scan.stop_reason = (f'record at byte {start} cut short ({n - start - _FRAME.size} of '
                            f'{length} bytes present)')
        return False
    scan.bad_records.append((start, _why(exc)))
    fh.seek(end)
    return True


def _why(exc: BaseException) -> str:
    """An exception as one line of text."""
    return ' '.join(str(exc).split()) or type(exc).__name__


def _take(scan: Scan, record: Any, offset: int) -> None:
    if isinstance(record, Header):
        scan.profile, scan.library = record.profile, record.library
    elif isinstance(record, Chunk):
        scan.compressions.add(record.compression or 'none')
        try:
            inner = breakup_chunk(record, validate_crc=True)
        except DAMAGE_ERRORS as exc:
            scan.bad_chunks.append((offset, _why(exc)))
            return
        scan.chunks += 1
        for item in inner:
            _take(scan, item, offset)
    elif isinstance(record, Schema):
        scan.schemas[record.id] = record
    elif isinstance(record, Channel):
        scan.channels[record.id] = record
    elif isinstance(record, Message):
        scan.messages.append(record)
    elif isinstance(record, Metadata):
        scan.metadata.append((record.name, dict(record.metadata)))
    elif isinstance(record, Statistics):
        scan.statistics = record
    elif isinstance(record, DataEnd):
        scan.data_end = True
