"""Processes that cannot outlive their parent, and stop signals that act as Ctrl-C.

Every process motor_id starts (the demo's card, driver and identifier, the test
harness's nodes, the launch file's nodes, the forked fit workers) is tied to its parent:

* :func:`tied` wraps a command line so that the child asks the Linux kernel for a
  parent-death signal (``prctl(PR_SET_PDEATHSIG)``) before it becomes the command:
  when the parent dies, by any means (SIGKILL included), the child receives
  :data:`DEATH_SIGNAL`, SIGTERM, which every motor_id process handles as Ctrl-C (the
  driver commands 0 V and closes its bag). The wrapper is this file run as a script
  (``python -I -S lifeline.py PARENT SIGNAL COMMAND...``): it sets the signal, checks
  that its parent is still the one that started it (the parent may have died between
  ``fork`` and ``prctl``) and ``exec`` s the command, which keeps its process id and
  the signal. This costs one small interpreter start (~10 ms) per child; it is
  preferred to ``subprocess.Popen(preexec_fn=...)``, which runs Python between
  ``fork`` and ``exec`` in a parent that has threads (rclpy's, a test client's) and
  can deadlock there, as the ``subprocess`` documentation warns.
* :func:`set_parent_death_signal` does the same in a process already running (a forked
  worker).
* :func:`stop_signals_as_interrupt` makes SIGTERM and SIGHUP raise
  :class:`KeyboardInterrupt` as SIGINT does, so that a command's ``finally`` blocks (its
  children stopped, its files closed) run whichever of the three ends it.

The kernel sends the parent-death signal each time the child is handed from a dying
thread of its parent to another (a parent with many threads killed at once: once per
thread), so a child hears SIGTERM several times: motor_id's handlers act on the first
SIGTERM or SIGHUP and ignore repeats (only a second Ctrl-C forces an exit).

The parent-death signal is Linux only; elsewhere :func:`tied` returns the command as
given and the children rely on their own process group being ended by the parent
(:mod:`motor_id.testing.procs`). The kernel sends the signal when the *thread* that
started the child ends, not only the process: start long-lived children from a thread
that lives as long as they should (the main thread, or a pool thread that is never
retired).

This module imports nothing but the standard library: it runs as a script before the
child's own interpreter exists.
"""

from collections.abc import Iterator, Sequence
import contextlib
import ctypes
import os
import signal
import sys
import threading
from types import FrameType

DEATH_SIGNAL = signal.SIGTERM
"""What a tied child receives when its parent dies: SIGTERM, a clean stop."""

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""The signals that stop every motor_id process as Ctrl-C does."""

# ---------------------------------------------------------------------------- shim --
# Why: Python has no API for the Linux parent-death signal. prctl(2) is called through
# ctypes from the C library already loaded in the process; this is the only place
# motor_id does so.
_PR_SET_PDEATHSIG = 1


def set_parent_death_signal(sig: int = DEATH_SIGNAL) -> bool:
    """Ask the kernel to send ``sig`` to this process when its parent dies (Linux).

    Parameters
    ----------
    sig : int
        The signal number; 0 clears it.

    Returns
    -------
    bool
        True when set; False on systems without ``prctl`` (not Linux).

    Raises
    ------
    OSError
        ``prctl`` refused (an invalid signal number).
    """
    if not sys.platform.startswith('linux'):
        return False
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_PDEATHSIG, ctypes.c_ulong(int(sig)), ctypes.c_ulong(0),
                  ctypes.c_ulong(0), ctypes.c_ulong(0)) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f'prctl(PR_SET_PDEATHSIG, {sig}): {os.strerror(err)}')
    return True
# ------------------------------------------------------------------------ end shim --


def tied(args: Sequence[str], sig: int = DEATH_SIGNAL) -> list[str]:
    """The command line ``args``, started so that it gets ``sig`` when this process dies.

    Parameters
    ----------
    args : sequence of str
        The command (``args[0]`` is looked up on PATH as ``subprocess`` does).
    sig : int
        The parent-death signal.

    Returns
    -------
    list of str
        ``[python, -I, -S, <this file>, <this pid>, <sig>, *args]`` on Linux; ``args``
        unchanged elsewhere.
    """
    if not sys.platform.startswith('linux'):
        return list(args)
    return [*launcher_prefix(os.getpid(), sig), *args]


def launcher_prefix(parent: int, sig: int = DEATH_SIGNAL) -> list[str]:
    """The words that start a command tied to process ``parent`` (see :func:`tied`).

    For a launch file's ``prefix``: the launch process passes its own pid.
    """
    here = os.path.abspath(__file__)
    # isolated (-I) and without site (-S): nothing but the standard library is needed,
    # and nothing on PYTHONPATH can shadow it; a zipped install runs the module instead
    runner = ['-I', '-S', here] if os.path.isfile(here) else ['-m', 'motor_id.lifeline']
    return [sys.executable, *runner, str(int(parent)), str(int(sig))]


def _launch(argv: Sequence[str]) -> int:
    """``PARENT SIGNAL COMMAND...``: set the signal, check the parent, exec the command."""
    if len(argv) < 3:
        print('usage: lifeline.py PARENT_PID SIGNAL COMMAND [ARG...]', file=sys.stderr)
        return 2
    parent, sig, args = int(argv[0]), int(argv[1]), list(argv[2:])
    set_parent_death_signal(sig)
    if os.getppid() != parent:      # the parent died before the signal was set
        return 128 + sig
    try:
        os.execvp(args[0], args)
    except OSError as exc:
        print(f'lifeline: cannot run {args[0]!r}: {exc}', file=sys.stderr)
        return 127
    return 0   # not reached: exec replaced this process


class _Interrupt:
    """A handler raising :class:`KeyboardInterrupt` on the first of its signals only."""

    def __init__(self) -> None:
        self.fired = False

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if not self.fired:
            self.fired = True
            raise KeyboardInterrupt(signal.Signals(signum).name)


@contextlib.contextmanager
def stop_signals_as_interrupt(signals: Sequence[int] = (signal.SIGTERM, signal.SIGHUP),
                              ) -> Iterator[None]:
    """Within the block, ``signals`` raise :class:`KeyboardInterrupt` as SIGINT does.

    The first of them does; repeats are ignored, so that the cleanup they started is not
    cut short (the parent-death signal comes once per thread of a dying parent). Only in
    the main thread (elsewhere Python cannot set handlers: the block runs unchanged). A
    signal ignored on entry (``nohup`` ignores SIGHUP) stays ignored. The previous
    handlers come back at the end.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    handler = _Interrupt()
    previous = {}
    for sig in signals:
        if signal.getsignal(sig) is not signal.SIG_IGN:
            previous[sig] = signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, before in previous.items():
            signal.signal(sig, before)


if __name__ == '__main__':
    sys.exit(_launch(sys.argv[1:]))
