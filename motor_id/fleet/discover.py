"""Which recordings a fleet run covers, whose robot each is, and how a recording is keyed.

Arguments are files, folders or glob patterns. A rosbag2 folder (one with a
``metadata.yaml``) is one recording; any other folder is searched (recursively) for bag
folders and for loose ``.mcap`` / ``.db3`` files. The key of a recording is its
resolved path with its size and modification time [ns] (of the folder's files, for a
bag folder): a recording that is written again is fitted again.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
import glob
import os
from pathlib import Path
import re

from motor_id.errors import ConfigError

SUFFIXES = ('.mcap', '.db3')
ROBOT_RULES = 'parent (default), parent:N (N folders up), regex:PATTERN (group "robot" or 1)'


@dataclass(frozen=True)
class RecordingRef:
    """A recording found on disk: its path, robot, size [bytes] and mtime [ns]."""

    path: str
    robot: str
    size: int
    mtime_ns: int

    @property
    def key(self) -> str:
        """Identity of this recording's content on disk."""
        return f'{self.path}|{self.size}|{self.mtime_ns}'


def find_recordings(args: Sequence[str], robot_from: str = 'parent') -> list[RecordingRef]:
    """Expand file, folder and glob arguments into recordings, sorted by path.

    Parameters
    ----------
    args : sequence of str
    robot_from : str
        How the robot's name follows from a recording's path (:data:`ROBOT_RULES`).

    Returns
    -------
    list of RecordingRef

    Raises
    ------
    ConfigError
        A path that does not exist, a pattern that matches nothing, a bad rule, or no
        recording at all.
    """
    robot_of = robot_rule(robot_from)
    found = {}
    for arg in args:
        if glob.has_magic(arg):
            paths = sorted(glob.glob(arg, recursive=True))
            if not paths:
                raise ConfigError(f'{arg}: the pattern matches nothing')
        else:
            if not os.path.exists(arg):
                raise ConfigError(f'{arg}: no such file or directory')
            paths = [arg]
        for p in paths:
            for rec in _expand(Path(p)):
                found[str(rec)] = rec
    if not found:
        raise ConfigError(f'no rosbag2 recording (a folder with metadata.yaml, an .mcap or '
                          f'.db3 file) in {" ".join(args)}')
    out = []
    for path in sorted(found):
        rec = found[path]
        size, mtime = _stat(rec)
        out.append(RecordingRef(path, robot_of(rec), size, mtime))
    return out


def _is_bag_folder(p: Path) -> bool:
    return p.is_dir() and (p / 'metadata.yaml').is_file()


def _expand(p: Path) -> Iterator[Path]:
    p = p.resolve()
    if p.is_file():
        if _is_bag_folder(p.parent):
            yield p.parent
        elif p.suffix in SUFFIXES:
            yield p
        return
    if _is_bag_folder(p):
        yield p
        return
    for root, dirs, files in os.walk(p):
        here = Path(root)
        if (here / 'metadata.yaml').is_file():
            dirs[:] = []
            yield here
            continue
        dirs.sort()
        for name in sorted(files):
            if name.endswith(SUFFIXES):
                yield here / name


def _stat(path: Path) -> tuple[int, int]:
    """Size [bytes] and newest mtime [ns] of a file or of a bag folder's files."""
    if path.is_file():
        st = path.stat()
        return st.st_size, st.st_mtime_ns
    size = mtime = 0
    for f in sorted(path.iterdir()):
        if f.is_file():
            st = f.stat()
            size += st.st_size
            mtime = max(mtime, st.st_mtime_ns)
    return size, mtime


def robot_rule(text: str) -> Callable[[str | Path], str]:
    """A function from a recording's path to its robot's name.

    Parameters
    ----------
    text : str
        ``parent``: the folder holding the recording (a bag folder's own parent);
        ``parent:N``: N folders up; ``regex:PATTERN``: the named group ``robot`` (or
        the first group, or the whole match) of a search in the full path.

    Raises
    ------
    ConfigError
    """
    text = str(text or 'parent')
    if text == 'parent' or text.startswith('parent:'):
        levels = 1
        if ':' in text:
            try:
                levels = int(text.split(':', 1)[1])
            except ValueError:
                levels = 0
            if levels < 1:
                raise ConfigError(f'robot_from {text}: want parent:N with N >= 1',
                                  params=('robot_from',))

        def parent(path: str | Path) -> str:
            p = Path(path)
            for _ in range(levels):
                p = p.parent
            return p.name or str(p)
        return parent
    if text.startswith('regex:'):
        try:
            pattern = re.compile(text[len('regex:'):])
        except re.error as exc:
            raise ConfigError(f'robot_from {text}: bad pattern ({exc})',
                              params=('robot_from',)) from None

        def by_regex(path: str | Path) -> str:
            m = pattern.search(str(path))
            if m is None:
                raise ConfigError(f'robot_from {text}: no match in {path}',
                                  params=('robot_from',))
            if 'robot' in pattern.groupindex:
                return m.group('robot')
            return m.group(1) if pattern.groups else m.group(0)
        return by_regex
    raise ConfigError(f'robot_from {text}: want {ROBOT_RULES}', params=('robot_from',))
