"""rosbag2 recordings of any storage (sqlite3, MCAP, split folders) through rosbags.

The one place that opens a bag with ``rosbags.highlevel.AnyReader`` and turns what
rosbags raises on a missing, damaged or unknown file into one-line :class:`BagError`\\ s.
This project's own MCAP files are read by :mod:`motor_id.bag.reader` with the mcap
library; the mapped reading of a robot's topics is :mod:`motor_id.data.rosbag`.
"""

from collections.abc import Iterator, Mapping
import contextlib
import os
from pathlib import Path
from typing import Any

from motor_id.errors import BagError, MotorIdError


def open_reader(path: str | os.PathLike) -> Any:
    """An open ``AnyReader`` on ``path`` with the ROS 2 Jazzy type store (caller closes it).

    Raises
    ------
    BagError
        No such path, or not a readable rosbag2 recording (one line with the reason).
    """
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import get_typestore, Stores
    p = Path(path)
    if not p.exists():
        raise BagError(f'{path}: no such file or directory')
    reader = AnyReader([p], default_typestore=get_typestore(Stores.ROS2_JAZZY))
    try:
        reader.open()
    except (AnyReaderError, OSError, ValueError, KeyError) as exc:
        raise BagError(f'{path}: not a readable rosbag2 recording ({_first_line(exc)})') \
            from exc
    return reader


@contextlib.contextmanager
def reading(path: str | os.PathLike) -> Iterator[None]:
    """Turn what rosbags raises on a damaged file or an unknown type into one BagError."""
    from rosbags.rosbag2 import ReaderError
    from rosbags.serde import SerdeError
    from rosbags.typesys import TypesysError
    try:
        yield
    except (ReaderError, SerdeError, TypesysError, KeyError, ValueError, EOFError,
            OSError) as exc:
        if isinstance(exc, MotorIdError):
            raise
        raise BagError(f'{path}: cannot read the messages ({_first_line(exc)})') from exc


def topic_table(topics: Mapping[str, Any]) -> str:
    """``/a (pkg/msg/T, n), ...``: one line naming the topics of a bag (``reader.topics``)."""
    return ', '.join(f'{name} ({info.msgtype}, {info.msgcount})'
                     for name, info in sorted(topics.items())) or 'none'


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
