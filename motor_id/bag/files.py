"""Finding a bag's .mcap file and checking that it is one, with one-line errors."""

import os
from pathlib import Path
from typing import BinaryIO

from motor_id.errors import BagError

MAGIC = b'\x89MCAP0\r\n'
"""The 8 bytes an MCAP file starts (and, when complete, ends) with (MCAP specification)."""


def resolve(path: str | os.PathLike[str]) -> Path:
    """The ``.mcap`` file of ``path``: the file itself, or the one file of a rosbag2 folder.

    Raises
    ------
    BagError
        A directory that does not hold exactly one ``.mcap`` file.
    """
    p = Path(path)
    if p.is_dir():
        found = sorted(p.glob('*.mcap'))
        if len(found) != 1:
            raise BagError(f'{path}: is a directory with {len(found)} .mcap file(s); '
                           'pass the .mcap file itself')
        return found[0]
    return p


def is_single_mcap(path: str | os.PathLike[str]) -> bool:
    """True for one MCAP file, or a folder holding exactly one (this project's bags)."""
    p = Path(path)
    if p.is_file():
        return p.suffix == '.mcap'
    return p.is_dir() and len(list(p.glob('*.mcap'))) == 1 and not list(p.glob('*.db3'))


def open_mcap(path: str | os.PathLike[str]) -> tuple[BinaryIO, int]:
    """Open an MCAP file for reading, positioned at its start.

    Parameters
    ----------
    path : str or Path
        An ``.mcap`` file or a rosbag2 directory holding exactly one.

    Returns
    -------
    (file object, int)
        The open binary file (the caller closes it) and its size [bytes].

    Raises
    ------
    BagError
        Missing or unreadable file, empty file, or a file without the MCAP magic.
    """
    p = resolve(path)
    try:
        fh = open(p, 'rb')
    except FileNotFoundError as exc:
        raise BagError(f'{path}: no such file') from exc
    except OSError as exc:
        raise BagError(f'{path}: cannot read ({exc.strerror})') from exc
    try:
        size = fh.seek(0, 2)
        fh.seek(0)
        start = fh.read(len(MAGIC))
        fh.seek(0)
    except OSError as exc:
        fh.close()
        raise BagError(f'{path}: cannot read ({exc.strerror})') from exc
    if not start:
        fh.close()
        raise BagError(f'{path}: empty file, not an MCAP recording')
    if start != MAGIC:
        fh.close()
        raise BagError(f'{path}: not an MCAP file (starts with {start!r}, expected the MCAP '
                       f'magic {MAGIC!r})')
    return fh, size
