"""Any rosbag2 recording (MCAP, sqlite3 .db3, split folders) to a Recording by a field mapping.

Without a mapping the bag must hold this project's ``/samples`` topic, read by the one
reader of that topic, :func:`motor_id.bag.read_any_recording`. With one
(:class:`motor_id.data.mapping.TopicMapping`: which topic and field each channel comes from,
and the plant kind), the mapped topics are read through ``rosbags.highlevel.AnyReader``.

Times: the header stamp where the message has a (non-zero) header, else the receive
(log) time. Commands from another topic are held onto the speed's times by the rule of
:mod:`motor_id.data.align` (``hold`` or ``next``); a current from another topic is
interpolated linearly. Samples outside a stream's span are dropped at the ends.
"""

from collections.abc import Callable
import os
from pathlib import Path
from typing import Any

import numpy as np

from motor_id.bag import read_any_recording
from motor_id.bag.anyreader import open_reader, reading
from motor_id.contracts import BAG_SAMPLES_TOPIC
from motor_id.data.align import held_command_index
from motor_id.data.mapping import field_getter, FieldSpec, kind_note, resolve, TopicMapping
from motor_id.errors import BagError
from motor_id.recording import Recording


def is_rosbag(path: str | os.PathLike[str]) -> bool:
    """True for a path this module reads: a directory, an ``.mcap`` or a ``.db3`` file."""
    p = Path(path)
    return p.is_dir() or p.suffix in ('.mcap', '.db3')


def read_bag(path: str | os.PathLike[str], mapping: TopicMapping | None = None) -> Recording:
    """Read a rosbag2 recording as a :class:`Recording` (not validated).

    Parameters
    ----------
    path : str or os.PathLike
        An MCAP file, a ``.db3`` file or a rosbag2 folder (``metadata.yaml``, split files).
    mapping : TopicMapping, optional
        Empty or None: the project's ``/samples`` topic.

    Returns
    -------
    Recording
        Times [s] from the first speed sample; ``meta`` names the source, the mapping,
        the time source per topic and the samples dropped at the ends.

    Raises
    ------
    BagError
        Unreadable bag, missing topic, field or joint, wrong type (one line naming what
        exists).
    ConfigError
        Contradicting mapping settings.
    """
    mapping = mapping or TopicMapping()
    if mapping.is_empty:
        try:
            rec = read_any_recording(path)
        except BagError as exc:
            if f'no {BAG_SAMPLES_TOPIC} topic' not in str(exc):
                raise
            raise BagError(f'{exc}; map the channels: input, speed (and current) as '
                           'TOPIC[:FIELD]', params=('input', 'speed', 'current')) from exc
        if mapping.input_kind is not None:
            rec.input_kind = mapping.input_kind
        return rec
    reader = open_reader(path)
    try:
        return _read_mapped(reader, path, mapping)
    finally:
        reader.close()


def _read_mapped(reader: Any, path: str | os.PathLike[str], mapping: TopicMapping) -> Recording:
    topics = reader.topics
    specs, kind, effort_is = resolve(mapping, topics, path)
    by_topic: dict[str, list[str]] = {}
    for role, spec in specs.items():
        by_topic.setdefault(spec.topic, []).append(role)
    conns = [c for c in reader.connections if c.topic in by_topic]
    streams = {t: _Stream(t, topics[t].msgtype, [(r, specs[r]) for r in roles], mapping.joint,
                          path)
               for t, roles in by_topic.items()}
    with reading(path):
        for conn, log_ns, raw in reader.messages(connections=conns):
            streams[conn.topic].add(reader.deserialize(raw, conn.msgtype), log_ns)
    for stream in streams.values():
        stream.finish()
    base = streams[specs['speed'].topic]
    t_ns = base.stamps
    if t_ns.size == 0:
        raise BagError(f'{path}: {specs["speed"].topic} has no messages')
    t0 = int(t_ns[0])
    t = (t_ns - t0) * 1e-9
    valid = np.ones(t.size, dtype=bool)
    chans = {}
    for role, spec in specs.items():
        stream = streams[spec.topic]
        if stream is base:
            chans[role] = base.values[role]
            continue
        ts = (stream.stamps - t0) * 1e-9
        if ts.size == 0:
            raise BagError(f'{path}: {spec.topic} has no messages')
        if role == 'input':
            idx = held_command_index(t, ts, mapping.align)
            ok = idx >= 0
            chans[role] = np.where(ok, stream.values[role][np.maximum(idx, 0)], np.nan)
        else:
            ok = (t >= ts[0]) & (t <= ts[-1])
            chans[role] = np.interp(t, ts, stream.values[role])
        valid &= ok
    keep = np.flatnonzero(valid)
    if keep.size == 0:
        sources = ', '.join(f'{s.topic}: {s.time_source} time'
                            for s in sorted(streams.values(), key=lambda s: s.topic))
        raise BagError(f'{path}: the streams do not overlap in time ({sources}); check that '
                       'the stamps share one clock')
    lo, hi = int(keep[0]), int(keep[-1]) + 1
    meta = {
        'source': str(path), 'bag': str(path), 'input_kind_rule': kind_note(kind, effort_is),
        'mapping': {r: s.text for r, s in specs.items()},
        'align': mapping.align, 'time_origin_ns': t0 + int(t_ns[lo] - t_ns[0]),
        'time_source': {s.topic: s.time_source for s in streams.values()},
        'messages': {s.topic: s.count for s in streams.values()},
        'dropped_at_ends': {'start': lo, 'end': t.size - hi},
    }
    if mapping.joint is not None:
        meta['joint'] = mapping.joint
    if effort_is:
        meta['effort_is'] = effort_is
    if base.duplicates:
        meta['duplicate_stamps_dropped'] = base.duplicates
    window = slice(lo, hi)
    time, u, w = t[window] - t[lo], chans['input'][window], chans['speed'][window]
    if 'current' not in chans:
        return Recording(time, u, w, input_kind=kind, meta=meta)
    return Recording(time, u, w, chans['current'][window], kind, meta)


class _Stream:
    """Stamps and the mapped values of one topic, gathered message by message."""

    def __init__(self, topic: str, msgtype: str, roles: list[tuple[str, FieldSpec]],
                 joint: str | None, path: str | os.PathLike[str]) -> None:
        self.topic, self.msgtype, self.path = topic, msgtype, path
        self.roles = roles
        self.joint = joint
        self.getters: list[tuple[str, Callable[[Any], float]]] | None = None
        self.time_source: str | None = None
        self._stamps: list[int] = []
        self._values: dict[str, list[float]] = {r: [] for r, _ in roles}
        self.count = 0
        self.stamps = np.zeros(0, dtype=np.int64)
        """Sorted stamps [ns] (after :meth:`finish`)."""
        self.values: dict[str, np.ndarray] = {}
        """The values of each role at :attr:`stamps` (after :meth:`finish`)."""
        self.duplicates = 0

    def _setup(self, msg: Any) -> list[tuple[str, Callable[[Any], float]]]:
        header = getattr(msg, 'header', None)
        stamp = getattr(header, 'stamp', None)
        has_stamp = stamp is not None and (stamp.sec or stamp.nanosec)
        self.time_source = 'header' if has_stamp else 'receive'
        self.getters = [(r, field_getter(self.topic, self.msgtype, spec, r, self.joint,
                                         msg, self.path)) for r, spec in self.roles]
        return self.getters

    def add(self, msg: Any, log_ns: int) -> None:
        getters = self.getters if self.getters is not None else self._setup(msg)
        if self.time_source == 'header':
            st = msg.header.stamp
            self._stamps.append(st.sec * 1_000_000_000 + st.nanosec)
        else:
            self._stamps.append(log_ns)
        for role, get in getters:
            try:
                self._values[role].append(get(msg))
            except (AttributeError, IndexError, KeyError, TypeError, ValueError) as exc:
                raise BagError(f'{self.path}: {self.topic} message {self.count}: cannot read '
                               f'the {role} ({exc})') from exc
        self.count += 1

    def finish(self) -> None:
        stamps = np.asarray(self._stamps, dtype=np.int64)
        order = np.argsort(stamps, kind='stable')
        stamps = stamps[order]
        keep = np.r_[True, np.diff(stamps) > 0] if stamps.size else np.zeros(0, bool)
        self.duplicates = int(stamps.size - np.count_nonzero(keep))
        self.stamps = stamps[keep]
        self.values = {r: np.asarray(v, dtype=float)[order][keep]
                       for r, v in self._values.items()}
