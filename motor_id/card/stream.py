"""Byte streams to frames: cut what the transport returns into messages and errors.

Each direction has its parser: :class:`FrameParser` (card -> host: samples, replies) and
:class:`CommandParser` (host -> card: commands, the card's side). They keep partial
frames between calls, resynchronise after garbage and count what they skip; they log
nothing and never touch a device.
"""

from collections import Counter, deque
from typing import Any

from motor_id.card.protocol import (
    _Kind,
    CARD_TYPES,
    Command,
    CRC,
    crc,
    HEADER,
    HOST_TYPES,
    OVERHEAD,
    Reply,
    Sample,
    SYNC,
)
from motor_id.errors import ProtocolError


class _StreamSplitter:
    """Cut a byte stream into frames of one direction; resynchronise after garbage."""

    def __init__(self, table: dict[int, _Kind]) -> None:
        self._table = table
        self._buf = bytearray()
        self.garbage_bytes = 0
        """Bytes skipped while looking for a frame (noise, torn or corrupted frames)."""
        self.frames = 0
        """Frames decoded successfully."""
        self.errors: Counter[str] = Counter()
        """ProtocolError count by kind."""

    @property
    def buffered(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget buffered bytes (after reopening the device); counters stay."""
        self._buf.clear()

    def _items(self, data: bytes, final: bool = False) -> list[Any]:
        buf = self._buf
        buf += data
        out = []
        pos = 0
        while True:
            i = buf.find(SYNC, pos)
            if i < 0:
                keep = 1 if (pos < len(buf) and buf[-1:] == SYNC[:1] and not final) else 0
                self.garbage_bytes += len(buf) - pos - keep
                pos = len(buf) - keep
                break
            self.garbage_bytes += i - pos
            pos = i
            if len(buf) - pos < HEADER.size:
                break
            ftype, length = buf[pos + 2], buf[pos + 3]
            kind = self._table.get(ftype)
            if kind is None or length not in kind.lengths:
                # not a frame of ours: a sync pattern inside garbage
                self.garbage_bytes += 1
                pos += 1
                continue
            end = pos + OVERHEAD + length
            if len(buf) < end:
                break
            body = bytes(buf[pos + 2:end - CRC.size])
            if crc(body) != CRC.unpack_from(buf, end - CRC.size)[0]:
                # A corrupted frame if the next frame follows right after it; else the
                # length may be wrong (torn frame): rescan from the next byte.
                if len(buf) < end + len(SYNC) and not final:
                    break
                err = ProtocolError('bad_crc', f'type {ftype:#04x}, {length} byte payload')
                out.append(err)
                self.errors[err.kind] += 1
                if buf[end:end + len(SYNC)] == SYNC or len(buf) == end:
                    pos = end
                else:
                    self.garbage_bytes += 1
                    pos += 1
                continue
            try:
                item = kind.decode(body[2:])
            except ProtocolError as err:
                out.append(err)
                self.errors[err.kind] += 1
            else:
                out.append(item)
                self.frames += 1
            pos = end
        del buf[:pos]
        if final and buf:
            short = ProtocolError('short', f'stream ends inside a frame ({len(buf)} bytes)')
            out.append(short)
            self.errors[short.kind] += 1
            buf.clear()
        return out


class FrameParser(_StreamSplitter):
    """Split the card -> host byte stream into samples and errors.

    Feed it whatever the transport returns; it keeps partial frames between calls and
    resynchronises on the next sync marker after garbage.

    Attributes
    ----------
    garbage_bytes : int
        Bytes skipped that belonged to no valid frame.
    frames : int
        Frames decoded (samples and replies).
    errors : collections.Counter
        ProtocolError count by kind.
    replies : collections.deque of Reply
        Replies to commands, oldest first (the last ``max_replies``); pop them to read.

    Notes
    -----
    A frame with a bad CRC is reported as soon as the bytes after it arrive: if the
    next frame starts right after it, the whole frame is skipped, otherwise only its
    first byte (its length byte may be wrong) and scanning resumes.
    """

    def __init__(self, max_replies: int = 64) -> None:
        super().__init__(CARD_TYPES)
        self.replies: deque[Reply] = deque(maxlen=max_replies)

    def _route(self, items: list[Any]) -> list[Sample | ProtocolError]:
        out = []
        for item in items:
            if isinstance(item, Reply):
                self.replies.append(item)
            else:
                out.append(item)
        return out

    def feed(self, data: bytes) -> list[Sample | ProtocolError]:
        """Add received bytes; return the new items in stream order.

        Parameters
        ----------
        data : bytes

        Returns
        -------
        list of Sample or ProtocolError
            Replies are not in the list: they go to :attr:`replies`.
        """
        return self._route(self._items(bytes(data)))

    def flush(self) -> list[Sample | ProtocolError]:
        """End of stream: report what is still buffered (``bad_crc`` or ``short``)."""
        return self._route(self._items(b'', final=True))


class CommandParser(_StreamSplitter):
    """Split the host -> card byte stream into commands and errors (the card's side)."""

    def __init__(self) -> None:
        super().__init__(HOST_TYPES)

    def feed(self, data: bytes) -> list[Command | ProtocolError]:
        """Add received bytes; return a list of commands and ProtocolError items."""
        return self._items(bytes(data))

    def flush(self) -> list[Command | ProtocolError]:
        """End of stream: report what is still buffered."""
        return self._items(b'', final=True)
