"""Stale Fast DDS shared-memory files: find and remove those that no live process holds.

Fast DDS's shared-memory transport keeps each segment (``fastrtps_<16 chars>``) and each
port (``fastrtps_port<N>``, with its ``sem.fastrtps_port<N>_mutex``) in ``/dev/shm``,
next to a lock file (suffix ``_el`` or ``_sl``) that the owning processes hold with
``flock`` while they live. A process that is killed leaves the files behind; they are
never reused and pile up. A lock file nobody holds marks such leftovers. This module
imports no rclpy.
"""

import fcntl
import os
import re
import time

SHM_DIR = '/dev/shm'
_LOCK_FILE = re.compile(r'^fastrtps_(?:port\d{1,5}|[0-9a-z]{16})_(?:el|sl)$')


def _held(path: str) -> bool:
    """Whether some process holds ``path`` locked (True when that cannot be told)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return False
    finally:
        os.close(fd)


def clean_stale_shm(shm_dir: str = SHM_DIR, min_age_s: float = 5.0) -> list[str]:
    """Remove Fast DDS shared-memory segments and ports whose owners are gone.

    Parameters
    ----------
    shm_dir : str
        Where the files are (``/dev/shm`` on Linux).
    min_age_s : float
        Lock files younger than this are left alone: a process starting up may not have
        taken its lock yet.

    Returns
    -------
    list of str
        The removed paths.
    """
    try:
        names = os.listdir(shm_dir)
    except OSError:
        return []
    now = time.time()
    removed = []
    for name in names:
        if not _LOCK_FILE.match(name):
            continue
        lock = os.path.join(shm_dir, name)
        try:
            if now - os.stat(lock).st_mtime < min_age_s:
                continue
        except OSError:
            continue
        if _held(lock):
            continue
        base = name[:-3]
        paths = [os.path.join(shm_dir, base), lock]
        if base.startswith('fastrtps_port'):
            paths.append(os.path.join(shm_dir, f'sem.{base}_mutex'))
        for path in paths:
            try:
                os.remove(path)
            except OSError:
                continue
            removed.append(path)
    return removed
