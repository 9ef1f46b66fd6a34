"""Reading a motor_id bag back: the ``/samples`` rows, the ``/motor_id/meta`` JSON, a Recording.

The one reader of the ``/samples`` topic. An MCAP file is read with the mcap library's
``StreamReader`` (CRCs checked); messages are decoded with the ROS 2 Jazzy type store of
rosbags. A file the library cannot read to the end of its data section is reported in
one line, with what ``motor-id bag recover`` would salvage (found by the tolerant scan
of :mod:`motor_id.bag.scan`). Other rosbag2 storages (sqlite3, split folders) are read
through rosbags (:func:`read_any_recording`); both paths share :func:`sorted_samples`
and :func:`samples_recording`.
"""

from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
import json
import os
from typing import Any

from mcap.records import Channel, DataEnd, Message, Schema
from mcap.stream_reader import StreamReader
import numpy as np
from numpy.typing import NDArray

from motor_id.bag.anyreader import open_reader, reading, topic_table
from motor_id.bag.files import is_single_mcap, open_mcap
from motor_id.bag.scan import DAMAGE_ERRORS, scan_file
from motor_id.bag.schemas import (
    DECODE_ERRORS,
    deserialize,
    FLOAT64_MULTI_ARRAY,
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    STRING,
    topic_name,
)
from motor_id.contracts import (
    BAG_META_TOPIC,
    BAG_POSITION_TOPIC,
    BAG_SAMPLES_TOPIC,
    batch_rows,
    INPUT_KINDS,
    POSITION_LABEL,
    SAMPLE_COLUMNS,
    SEQ,
    seq_step,
    T,
)
from motor_id.errors import BagError
from motor_id.recording import Recording


@dataclass
class _Contents:
    """The schemas, channels and messages (per channel, in file order) of a read bag."""

    path: str
    schemas: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)
    messages: dict = field(default_factory=dict)
    data_end: bool = False
    note: str = ''

    def take(self, record: Any) -> None:
        if isinstance(record, Message):
            self.messages.setdefault(record.channel_id, []).append(record)
        elif isinstance(record, Channel):
            self.channels[record.id] = record
        elif isinstance(record, Schema):
            self.schemas[record.id] = record
        elif isinstance(record, DataEnd):
            self.data_end = True

    def on_topic(self, topic: str) -> list[Channel]:
        """The channels named ``topic`` (relative or absolute)."""
        name = topic_name(topic)
        return [ch for ch in self.channels.values() if topic_name(ch.topic) == name]

    def topic_list(self) -> str:
        """``topics present: /a (type, n msgs), ...`` for an error message."""
        if not self.channels:
            return 'the file has no topics'
        items = []
        for ch in self.channels.values():
            schema = self.schemas.get(ch.schema_id)
            items.append(f'{ch.topic} ({schema.name if schema else "no schema"}, '
                         f'{len(self.messages.get(ch.id, []))} msgs)')
        return 'topics present: ' + ', '.join(sorted(items))


def _read(path: str | os.PathLike[str]) -> _Contents:
    """Every record of the data section; BagError (one line) if it cannot all be read."""
    fh, _ = open_mcap(path)
    contents = _Contents(str(path))
    with fh:
        try:
            for record in StreamReader(fh, validate_crcs=True).records:
                contents.take(record)
        except DAMAGE_ERRORS as exc:
            if not contents.data_end:
                raise _damaged(path, exc) from exc
            contents.note = 'data complete but the summary/footer is missing'
    return contents


def _damaged(path: str | os.PathLike[str], exc: BaseException) -> BagError:
    scan = scan_file(path)
    problem = scan.problem() or ' '.join(f'{type(exc).__name__}: {exc}'.split())
    return BagError(f'{scan.path}: truncated or corrupt MCAP ({problem}); '
                    + scan.recover_hint())


def _typed_channels(contents: _Contents, topic: str, msgtype: str) -> list[Channel]:
    """Channels of ``topic``, checked to be CDR-encoded ``msgtype``."""
    chans = contents.on_topic(topic)
    for ch in chans:
        schema = contents.schemas.get(ch.schema_id)
        if schema is None:
            raise BagError(f'{contents.path}: {ch.topic} has no schema, cannot decode it')
        if schema.encoding != SCHEMA_ENCODING or ch.message_encoding != MESSAGE_ENCODING:
            raise BagError(f'{contents.path}: cannot decode {ch.topic}: schema encoding '
                           f'{schema.encoding!r}, message encoding {ch.message_encoding!r} '
                           f'(need {SCHEMA_ENCODING!r} and {MESSAGE_ENCODING!r})')
        if schema.name != msgtype:
            raise BagError(f'{contents.path}: {ch.topic} has type {schema.name!r}, expected '
                           f'{msgtype}')
    return chans


def _batches(contents: _Contents,
             topic: str) -> Iterator[tuple[NDArray[np.float64], int]]:
    """(rows, log time [ns]) of every sample message of ``topic``, in file order."""
    chans = _typed_channels(contents, topic, FLOAT64_MULTI_ARRAY)
    if not chans:
        raise BagError(f'{contents.path}: no {topic_name(topic)} topic; '
                       f'{contents.topic_list()}')
    ids = {ch.id for ch in chans}
    messages = [m for cid in ids for m in contents.messages.get(cid, [])]
    for i, msg in enumerate(messages):
        try:
            decoded = deserialize(msg.data, FLOAT64_MULTI_ARRAY)
            dims = list(decoded.layout.dim)
            labels, sizes = [d.label for d in dims], [d.size for d in dims]
            rows = batch_rows(labels, sizes, decoded.layout.data_offset, decoded.data)
        except DECODE_ERRORS as exc:
            raise BagError(f'{contents.path}: {topic} message {i} (log time {msg.log_time} '
                           f'ns) is not a valid sample batch: {exc}') from exc
        yield rows, msg.log_time


@dataclass(frozen=True)
class SampleGap:
    """Missing sequence numbers: ``missing`` samples after ``after_seq`` (never filled)."""

    after_seq: int
    missing: int
    t_before: float
    t_after: float


@dataclass(frozen=True)
class SampleRows:
    """A bag's sample rows in sequence order (repeats dropped, gaps listed).

    Attributes
    ----------
    seq, t, voltage, speed, current, flags : ndarray
        The columns of :data:`motor_id.contracts.SAMPLE_COLUMNS`, one entry per row.
    log_time_ns : ndarray of int
        Log time of each row's message [ns].
    gaps : list of SampleGap
    duplicates : int
        Rows dropped for repeating a sequence number.
    """

    seq: NDArray[np.float64]
    t: NDArray[np.float64]
    voltage: NDArray[np.float64]
    speed: NDArray[np.float64]
    current: NDArray[np.float64]
    flags: NDArray[np.float64]
    log_time_ns: NDArray[np.int64]
    gaps: list[SampleGap]
    duplicates: int

    def rows(self) -> NDArray[np.float64]:
        """The rows again, shape (n, 6), columns :data:`~motor_id.contracts.SAMPLE_COLUMNS`."""
        return np.column_stack([getattr(self, c) for c in SAMPLE_COLUMNS])


def _samples(contents: _Contents, topic: str = BAG_SAMPLES_TOPIC) -> SampleRows:
    blocks, log_times = [], []
    for rows, log_time in _batches(contents, topic):
        blocks.append(rows)
        log_times.append(np.full(rows.shape[0], log_time, dtype=np.int64))
    if sum(b.shape[0] for b in blocks) == 0:
        raise BagError(f'{contents.path}: {topic_name(topic)} holds no sample rows')
    return sorted_samples(np.concatenate(blocks), np.concatenate(log_times))


def sorted_samples(rows: NDArray[np.float64], log_ns: NDArray[np.int64]) -> SampleRows:
    """Sample rows in sequence order, repeats dropped, gaps listed (never filled).

    The one rule for every storage the rows come from (this reader's MCAP, or any rosbag2
    storage read through rosbags).

    Parameters
    ----------
    rows : ndarray, shape (n, 6)
        Rows of :data:`motor_id.contracts.SAMPLE_COLUMNS`, in file order.
    log_ns : ndarray of int, shape (n,)
        Log time of each row's message [ns].

    Returns
    -------
    SampleRows
    """
    order = np.argsort(rows[:, SEQ], kind='stable')
    rows, log_ns = rows[order], log_ns[order]
    keep = np.ones(rows.shape[0], dtype=bool)
    keep[1:] = np.diff(rows[:, SEQ]) != 0
    rows, log_ns = rows[keep], log_ns[keep]
    seq = rows[:, SEQ]
    gaps = [SampleGap(int(seq[k]), int(seq[k + 1] - seq[k] - 1), float(rows[k, T]),
                      float(rows[k + 1, T]))
            for k in np.flatnonzero(seq_step(seq[:-1], seq[1:]) > 1)]
    columns = {name: rows[:, j].copy() for j, name in enumerate(SAMPLE_COLUMNS)}
    return SampleRows(**columns, log_time_ns=log_ns, gaps=gaps,
                      duplicates=int(np.count_nonzero(~keep)))


def _meta(contents: _Contents) -> dict[str, Any]:
    meta = {}
    for ch in _typed_channels(contents, BAG_META_TOPIC, STRING):
        for msg in contents.messages.get(ch.id, []):
            try:
                item = json.loads(deserialize(msg.data, STRING).data)
            except DECODE_ERRORS as exc:
                raise BagError(f'{contents.path}: a {BAG_META_TOPIC} message is not valid '
                               f'JSON ({exc})') from exc
            if not isinstance(item, dict):
                raise BagError(f'{contents.path}: a {BAG_META_TOPIC} message is not a JSON '
                               'object')
            meta.update(item)
    return meta


def read_samples(path: str | os.PathLike[str], topic: str = BAG_SAMPLES_TOPIC) -> SampleRows:
    """All rows of the ``/samples`` topic, sorted by sequence number.

    Parameters
    ----------
    path : str or Path
        An ``.mcap`` file (or a rosbag2 directory holding exactly one).
    topic : str

    Returns
    -------
    SampleRows
        One entry per row (a repeated ``seq`` keeps its first row); gaps are listed,
        never filled.

    Raises
    ------
    BagError
        One line: missing file, not an MCAP, truncated/corrupt (with the count that
        :func:`motor_id.bag.recover` would salvage), no such topic (with the topics
        present), wrong or undecodable type, unexpected layout.
    """
    return _samples(_read(path), topic)


def read_meta(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The merged JSON objects of ``/motor_id/meta`` ({} when the bag has none)."""
    return _meta(_read(path))


def read_recording(path: str | os.PathLike[str]) -> Recording:
    """Rebuild a :class:`~motor_id.recording.Recording` from a bag's ``/samples`` topic.

    Rows are sorted by ``seq``; gaps in ``seq`` are kept as they are (time simply jumps)
    and listed in ``rec.meta['gaps']``; ``input_kind`` and the rest of the metadata come
    from ``/motor_id/meta``. The current channel is None when it is NaN throughout.
    The recording is not validated here (``Recording.validate`` or the fitter does it).

    Raises
    ------
    BagError
        See :func:`read_samples`.
    """
    contents = _read(path)
    samples = _samples(contents)
    rec = samples_recording(samples, _meta(contents), contents.path, contents.note)
    _attach_position(contents, rec, np.round(samples.seq).astype(np.int64))
    return rec


def _attach_position(contents: _Contents, rec: Recording, wanted: NDArray[np.int64]) -> None:
    """Give ``rec`` the bag's measured position (``/motor_id/position``), matched to the
    samples by sequence number; a position missing for some samples is left out whole,
    with a note in ``rec.meta``."""
    chans = _typed_channels(contents, BAG_POSITION_TOPIC, FLOAT64_MULTI_ARRAY)
    if not chans:
        return
    parts = []
    for ch in chans:
        for i, msg in enumerate(contents.messages.get(ch.id, [])):
            try:
                decoded = deserialize(msg.data, FLOAT64_MULTI_ARRAY)
                dims = list(decoded.layout.dim)
                if len(dims) != 2 or dims[1].label != POSITION_LABEL or dims[1].size != 2:
                    raise ValueError(f'layout {[(d.label, d.size) for d in dims]} is not '
                                     f'(n, 2) rows of {POSITION_LABEL}')
                parts.append(np.asarray(decoded.data, dtype=float).reshape(-1, 2))
            except DECODE_ERRORS as exc:
                raise BagError(f'{contents.path}: {BAG_POSITION_TOPIC} message {i} is not a '
                               f'valid position batch: {exc}') from exc
    seq, pos = (np.concatenate(parts) if parts else np.zeros((0, 2))).T
    lookup = dict(zip(seq.astype(np.int64).tolist(), pos.tolist(), strict=True))
    missing = [k for k in wanted.tolist() if k not in lookup]
    if missing:
        rec.meta['position_note'] = (f'{BAG_POSITION_TOPIC} lacks {len(missing)} of '
                                     f'{wanted.size} samples (first seq {missing[0]}): '
                                     'position left out')
        return
    rec.position = np.array([lookup[k] for k in wanted.tolist()])



def samples_recording(samples: SampleRows, meta: dict[str, Any], path: str | os.PathLike[str],
                      note: str | None = None) -> Recording:
    """A :class:`Recording` from :func:`sorted_samples` output and ``/motor_id/meta``.

    ``input_kind`` comes from the metadata; gaps, repeated and flagged rows are noted in
    ``meta``; the current channel is None when it is NaN throughout.
    """
    meta = dict(meta)
    kind = meta.pop('input_kind', 'voltage')
    if kind not in INPUT_KINDS:
        raise BagError(f'{path}: {BAG_META_TOPIC} input_kind must be voltage or '
                       f'torque, got {kind!r}')
    segments = _runs(meta.pop('runs', None), samples.seq, path)
    current = samples.current if np.any(np.isfinite(samples.current)) else None
    meta['bag'] = str(path)
    meta['gaps'] = [asdict(g) for g in samples.gaps]
    if samples.duplicates:
        meta['duplicate_rows'] = samples.duplicates
    nonzero = int(np.count_nonzero(samples.flags))
    if nonzero:
        meta['flagged_rows'] = nonzero
    if note:
        meta['bag_note'] = note
    return Recording(samples.t, samples.voltage, samples.speed, current, kind, meta, segments)


def _runs(runs: Any, seq: NDArray[np.float64], path: str | os.PathLike[str]
          ) -> list[tuple[int, int]] | None:
    """The sample ranges of the runs ``[[first_seq, end_seq], ...]`` of the metadata
    (None: one run). A run whose samples are all missing is dropped; a run's missing
    samples are gaps inside it, as in a single run."""
    if runs is None:
        return None
    try:
        pairs = [(int(a), int(b)) for a, b in runs]
    except (TypeError, ValueError) as exc:
        raise BagError(f'{path}: {BAG_META_TOPIC} runs must be [first, end) sequence '
                       f'number pairs, got {runs!r}') from exc
    if any(b <= a for a, b in pairs) or any(
            b0 > a1 for (_, b0), (a1, _) in zip(pairs, pairs[1:], strict=False)):
        raise BagError(f'{path}: {BAG_META_TOPIC} runs {pairs} are not increasing, '
                       'non-overlapping [first, end) ranges')
    edges = [(int(np.searchsorted(seq, a)), int(np.searchsorted(seq, b)))
             for a, b in pairs]
    out = [(a, b) for a, b in edges if b > a]
    return out if len(out) > 1 else None


def read_any_recording(path: str | os.PathLike[str]) -> Recording:
    """The ``/samples`` recording of any rosbag2 storage.

    One MCAP file (or a folder holding one): :func:`read_recording`; a ``.db3`` file or a
    folder of split files: the same rows read through rosbags, sorted and noted by the
    same rules.

    Raises
    ------
    BagError
        Unreadable bag, no ``/samples`` topic (naming the topics present), or a message
        that is not a sample batch.
    """
    if is_single_mcap(path):
        return read_recording(path)
    reader = open_reader(path)
    try:
        topics = reader.topics
        if BAG_SAMPLES_TOPIC not in topics:
            raise BagError(f'{path}: no {BAG_SAMPLES_TOPIC} topic (topics: '
                           f'{topic_table(topics)})')
        return _rosbag2_recording(reader, path)
    finally:
        reader.close()


def _rosbag2_recording(reader: Any, path: str | os.PathLike[str]) -> Recording:
    """The ``/samples`` rows (and ``/motor_id/meta``) of an open rosbags reader."""
    conns = [c for c in reader.connections if c.topic in (BAG_SAMPLES_TOPIC, BAG_META_TOPIC)]
    rows, log_times, meta = [], [], {}
    with reading(path):
        messages = [(c.topic, log_ns, reader.deserialize(raw, c.msgtype))
                    for c, log_ns, raw in reader.messages(connections=conns)]
    for topic, log_ns, msg in messages:
        if topic == BAG_META_TOPIC:
            try:
                item = json.loads(msg.data)
            except (ValueError, AttributeError) as exc:
                raise BagError(f'{path}: a {BAG_META_TOPIC} message is not JSON') from exc
            if isinstance(item, dict):
                meta.update(item)
            continue
        try:
            dims = msg.layout.dim
            rows.append(batch_rows([d.label for d in dims], [d.size for d in dims],
                                   msg.layout.data_offset, msg.data))
        except (AttributeError, ValueError) as exc:
            raise BagError(f'{path}: {BAG_SAMPLES_TOPIC} is not a sample batch ({exc})') \
                from exc
        log_times.append(np.full(rows[-1].shape[0], log_ns, dtype=np.int64))
    if not rows or sum(r.shape[0] for r in rows) == 0:
        raise BagError(f'{path}: {BAG_SAMPLES_TOPIC} holds no sample rows')
    samples = sorted_samples(np.concatenate(rows), np.concatenate(log_times))
    rec = samples_recording(samples, meta, path)
    rec.meta['source'] = str(path)
    return rec
