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
* :class:`SignalThread` hears the stop signals on a thread of its own instead (the
  nodes, the card simulator): no Python code runs in the main thread for them, and a
  process that has not ended :data:`STOP_DEADLINE` seconds after its first stop signal
  is ended (its last-resort hook first: 0 at the output).

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

import atexit
from collections.abc import Callable, Iterator, Sequence
import contextlib
import ctypes
import os
import signal
import socket
import sys
import threading
import time
from types import FrameType
from typing import Any

DEATH_SIGNAL = signal.SIGTERM
"""What a tied child receives when its parent dies: SIGTERM, a clean stop."""

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""The signals that stop every motor_id process as Ctrl-C does."""

STOP_DEADLINE = 20.0
"""Seconds a process watched by a :class:`SignalThread` may take to end after its first
stop signal (a clean stop takes a few seconds on a loaded machine); then its last-resort
hook runs and ``os._exit`` ends it."""

HOOK_TIME = 0.5
"""Seconds a :class:`SignalThread` gives each of its hooks (it goes on without them)."""

# ---------------------------------------------------------------------------- shim --
# Why: Python has no API for the Linux parent-death signal. prctl(2) is called through
# ctypes from the C library already loaded in the process; this is the only place
# motor_id does so.
_PR_SET_PDEATHSIG = 1


def set_parent_death_signal(sig: int = DEATH_SIGNAL, parent: int | None = None) -> bool:
    """Ask the kernel to send ``sig`` to this process when its parent dies (Linux).

    The parent may have died before this call (a child forked just before its parent was
    killed): the kernel then has nothing to send. So, once the signal is set, the
    parent is checked: when it is no longer ``parent``, this process sends itself
    ``sig``.

    Parameters
    ----------
    sig : int
        The signal number; 0 clears it.
    parent : int, optional
        The pid of the parent that started this process, as the parent knew it (passed
        down: a forked worker's initializer argument); None: no check.

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
    if sig and parent is not None and os.getppid() != parent:   # it died before prctl
        os.kill(os.getpid(), sig)
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
    if os.getppid() != parent:      # the parent died before the signal was set: no exec
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
    handlers come back at the end; if one of the signals came, they are ignored from the
    interpreter's exit on (:func:`ignore_at_exit`).
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
        if handler.fired:
            ignore_at_exit(list(previous))


def ignore_at_exit(signals: Sequence[int]) -> None:
    """Ignore ``signals`` from the interpreter's exit on (an ``atexit`` hook; main thread).

    Finalisation puts the default action back on every signal that has a Python handler;
    a SIGTERM or SIGHUP repeated then (the test's second one, a dying parent's
    parent-death signal per thread) ended a stopping node by the signal (exit -1) instead
    of 0, with every core busy, where the end of a node takes long. An ignored signal
    keeps being ignored through finalisation."""
    def hook() -> None:
        if threading.current_thread() is threading.main_thread():
            for sig in signals:
                signal.signal(sig, signal.SIG_IGN)
    atexit.register(hook)


def _no_op(signum: int, frame: FrameType | None) -> None:
    """Python-level handler of a :class:`SignalThread`: nothing; the number reaches the
    wakeup socket from the interpreter's C-level handler."""


class SignalThread:
    """SIGINT, SIGTERM and SIGHUP heard by a thread of their own, with a deadline.

    Python runs a signal's handler in the main thread between two bytecodes, wherever
    that thread is. A handler that takes a lock deadlocks when the main thread holds that
    lock at that moment: ``threading.Event.set`` in a handler, with the main thread inside
    ``Event.wait`` of the same event (it holds the event's lock for a few bytecodes on
    each wake-up), hangs the process for good, and each later signal's handler blocks on
    the same lock (a killed demo's card simulator was left so). Here the handlers do
    nothing: the interpreter's C-level handler writes the signal number to a socket
    (:func:`signal.set_wakeup_fd`), whichever thread the kernel interrupts, and this
    thread reads it.

    On the first stop signal the thread records it in :attr:`received`, calls
    ``on_stop(signum)`` (there: send 0 at once) and sets :attr:`stopped`, which the main
    thread waits on or polls. Repeats of SIGTERM and SIGHUP are ignored (the parent-death
    signal comes once per thread of a dying parent); a second SIGINT (Ctrl-C twice) ends
    the process at once. A process still running ``deadline`` seconds after the first
    signal, its main thread stuck wherever, is ended too: ``last_resort()`` (there: 0 at
    the output once more), then ``os._exit(128 + signal)``. Each hook runs on a thread of
    its own and is given :data:`HOOK_TIME` seconds: the main thread may hold what it
    needs.

    Parameters
    ----------
    on_stop : callable, optional
        ``on_stop(signum)``, called once on this thread at the first stop signal.
    last_resort : callable, optional
        Called before ``os._exit``.
    deadline : float or None
        Seconds from the first signal to the forced end; None: no deadline.
    signals : sequence of int
        The stop signals. SIGHUP ignored on entry (``nohup``) stays ignored.
    stopped : object with ``set()``, optional
        What is set after ``on_stop`` (default: a new :class:`threading.Event`).

    The hooks are attributes, and may be set after :meth:`install`.
    """

    def __init__(self, on_stop: Callable[[int], object] | None = None,
                 last_resort: Callable[[], object] | None = None,
                 deadline: float | None = STOP_DEADLINE,
                 signals: Sequence[int] = STOP_SIGNALS,
                 stopped: Any = None) -> None:
        self.on_stop = on_stop
        self.last_resort = last_resort
        self.deadline = deadline
        self.signals = tuple(int(s) for s in signals)
        self.received: int | None = None
        self.stopped = threading.Event() if stopped is None else stopped
        self._read: socket.socket | None = None
        self._write: socket.socket | None = None
        self._previous: dict[int, object] = {}
        self._old_fd = -1

    def install(self) -> 'SignalThread':
        """Route the signals to the thread and start it (main thread only); returns self.

        Call it first thing: before it the signals keep their dispositions (SIGTERM's
        default ends the process at once, which is safe while nothing has started).
        """
        self._read, self._write = socket.socketpair()
        self._write.setblocking(False)
        self._old_fd = signal.set_wakeup_fd(self._write.fileno(), warn_on_full_buffer=False)
        for sig in self.signals:
            if sig == signal.SIGHUP and signal.getsignal(sig) is signal.SIG_IGN:
                continue
            self._previous[sig] = signal.signal(sig, _no_op)
        ignore_at_exit([sig for sig in self._previous if sig != signal.SIGINT])
        threading.Thread(target=self._watch, name='signals', daemon=True).start()
        return self

    def uninstall(self) -> None:
        """Give the signals their previous handlers back (main thread only). A deadline
        already running keeps running: a stopping process still ends in time."""
        for sig, before in self._previous.items():
            signal.signal(sig, before)   # type: ignore[arg-type]
        self._previous = {}
        signal.set_wakeup_fd(self._old_fd)

    def _next(self, until: float | None) -> int | None:
        """The next stop signal; None at ``until`` (monotonic) or when closed."""
        sock = self._read
        if sock is None:
            return None
        while True:
            if until is not None:
                left = until - time.monotonic()
                if left <= 0:
                    return None
                sock.settimeout(left)
            try:
                data = sock.recv(1)
            except TimeoutError:
                return None
            if not data:
                return None
            if data[0] in self.signals:
                return data[0]

    def _watch(self) -> None:
        first = self._next(None)
        if first is None:
            return
        self.received = first
        until = None if self.deadline is None else time.monotonic() + self.deadline
        hook = self.on_stop
        if hook is not None:
            _bounded(hook, first)
        self.stopped.set()
        while True:
            again = self._next(until)
            if again == signal.SIGINT:
                self.end(again, 'a second SIGINT')
            elif again is None:
                if until is None or time.monotonic() < until:
                    return   # the socket closed
                self.end(first, f'still running {self.deadline:g} s after '
                                f'{signal.Signals(first).name}')

    def end(self, sig: int, why: str) -> None:
        """The last resort, then ``os._exit(128 + sig)``, saying ``why`` on stderr."""
        name = os.path.basename(sys.argv[0] or 'python')
        _bounded(lambda: print(f'{name}: {why}: ended', file=sys.stderr, flush=True))
        if self.last_resort is not None:
            _bounded(self.last_resort)
        os._exit(128 + sig)


def _bounded(fn: Callable[..., object], *args: object) -> None:
    """Run ``fn(*args)`` on a thread of its own for at most :data:`HOOK_TIME` s
    (the main thread may hold what it needs, or stderr may be a full pipe)."""
    def call() -> None:
        try:
            fn(*args)
        except Exception as exc:   # noqa: BLE001 - a hook's failure must not stop the stop
            with contextlib.suppress(Exception):
                print(f'stop hook failed: {type(exc).__name__}: {exc}', file=sys.stderr,
                      flush=True)

    worker = threading.Thread(target=call, name='stop-hook', daemon=True)
    worker.start()
    worker.join(HOOK_TIME)

if __name__ == '__main__':
    sys.exit(_launch(sys.argv[1:]))
