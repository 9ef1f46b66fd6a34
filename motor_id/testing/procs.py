"""Node processes and their ROS environment, for the demo, the benchmarks and the tests.

Imports no rclpy: a parent that only starts and stops nodes needs no ROS in itself.

A :class:`Process` cannot outlive the process that started it: it runs in its own
session and process group (ended as a whole by :meth:`Process.kill`), it is tied to its
parent by the parent-death signal (:func:`motor_id.lifeline.tied`: SIGTERM, a clean
stop, when the parent dies even of SIGKILL), and whatever is still running when the
parent's interpreter exits is killed (``atexit``). :func:`live_groups` lists the
process groups started here that still have a member, for a test run's last check.
"""

import atexit
from collections.abc import Callable, Collection, Mapping, Sequence
import fcntl
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from typing import IO
import zlib

from motor_id.errors import MotorIdError
from motor_id.lifeline import tied

_LIVE: set['Process'] = set()
_GROUPS: set[int] = set()
"""Every process group started here (the children lead their own)."""
_BURNERS: set[int] = set()
"""The load processes of :func:`start_burners` (not leftovers)."""
_DOMAINS: dict[str, tuple[int, IO[bytes] | None]] = {}
"""The ROS domain ids leased by :func:`domain_id`, by name, with their lease files."""


@atexit.register
def _kill_leftovers() -> None:
    """Never leave node processes behind, even when the parent dies of an error."""
    for proc in list(_LIVE):
        proc.kill()
        proc.release()


def live_groups() -> list[int]:
    """The process groups started by :class:`Process` that still have a running member
    (psutil, from the ``test`` extra).

    A group outlives its leader when the leader left a child behind. Zombies (ended, not
    reaped: a container's init may never reap an orphan) do not count.
    """
    import psutil
    live = set()
    for proc in psutil.process_iter():
        try:
            pgid = os.getpgid(proc.pid)
            if pgid in _GROUPS and proc.status() != psutil.STATUS_ZOMBIE:
                live.add(pgid)
        except (OSError, psutil.Error):
            continue
    return sorted(live)


def leftovers(exclude: Collection[int] = ()) -> list[str]:
    """Kill what this process started and left running; describe it (``pid: command``).

    Looks at this process's descendants (psutil, from the ``test`` extra) and at the
    groups of :func:`live_groups`; zombies (ended, not yet reaped), the processes in
    ``exclude``, the burners of :func:`start_burners` and multiprocessing's own fork
    server and resource tracker do not count.
    """
    exclude = set(exclude) | _BURNERS
    import psutil
    found: dict[int, psutil.Process] = {}
    candidates = psutil.Process().children(recursive=True)
    groups = set(live_groups())
    if groups:
        candidates += [p for p in psutil.process_iter() if _pgid(p.pid) in groups]
    _GROUPS.difference_update(_GROUPS - groups)   # ended groups: their numbers get reused
    for proc in candidates:
        try:
            cmd = ' '.join(proc.cmdline())
            if proc.pid in exclude or proc.status() == psutil.STATUS_ZOMBIE or \
                    ('multiprocessing' in cmd and ('forkserver' in cmd or
                                                   'resource_tracker' in cmd)):
                continue
        except psutil.Error:
            continue
        found[proc.pid] = proc
    described = []
    for pid, proc in sorted(found.items()):
        try:
            described.append(f'{pid}: {" ".join(proc.cmdline())}')
            proc.kill()
        except psutil.Error:
            pass
    return described


def _pgid(pid: int) -> int | None:
    try:
        return os.getpgid(pid)
    except OSError:
        return None


def start_burners(count: int | None = None) -> list['subprocess.Popen[bytes]']:
    """Busy-looping Python processes, one per core this process may use (or ``count``),
    tied to this process: the load beside a test run (``MOTOR_ID_BURN=1``).

    The caller kills them (they also die with this process).
    """
    cores = (len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity')
             else os.cpu_count() or 1)
    n = count or cores
    burners = [subprocess.Popen(tied([sys.executable, '-c', 'while True: pass']),
                                stdin=subprocess.DEVNULL) for _ in range(n)]
    _BURNERS.update(p.pid for p in burners)
    return burners


def domain_id(name: str, low: int = 1, high: int = 101) -> int:
    """A ROS_DOMAIN_ID in ``low..high`` for ``name``, leased to this process.

    The first choice is varied by the name and the process id; an id that another live
    process (another test run on the same machine, a benchmark) holds is passed over. The
    lease is an exclusive ``flock`` on a file in the temporary directory, held until this
    process ends (the kernel drops it even on SIGKILL). The same name in the same process
    always gets the same id; two names never share one while a free id is left (when every
    id is leased the first choice is returned).
    """
    if name in _DOMAINS:
        return _DOMAINS[name][0]
    span = high - low + 1
    first = (zlib.crc32(name.encode()) + os.getpid() * 7) % span
    for k in range(span):
        domain = low + (first + k) % span
        lease = domain_lease(domain)
        if lease is not None:
            _DOMAINS[name] = (domain, lease)
            return domain
    _DOMAINS[name] = (low + first, None)
    return low + first


def domain_lease(domain: int) -> IO[bytes] | None:
    """The open, exclusively locked lease file of ``domain``, or None if it is taken."""
    path = os.path.join(tempfile.gettempdir(), f'motor_id-ros-domain-{domain}.lease')
    try:
        handle = open(path, 'ab')
    except OSError:
        return None
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.close()
        return None
    return handle


def ros_env(domain: int, pythonpath: str | None = None, **extra: object) -> dict[str, str]:
    """The environment of a node process: LOCALHOST discovery and ``domain``.

    Parameters
    ----------
    domain : int
        ROS_DOMAIN_ID.
    pythonpath : str, optional
        Put first on PYTHONPATH (e.g. a source checkout).
    **extra
        More variables (values converted to str).

    Returns
    -------
    dict
        A copy of ``os.environ`` with unbuffered Python output, uncoloured ROS logs and
        the Python stacks printed on a crash.
    """
    env = dict(os.environ)
    env.pop('ROS_STATIC_PEERS', None)
    env.update({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_DOMAIN_ID': str(domain),
                'PYTHONUNBUFFERED': '1', 'PYTHONFAULTHANDLER': '1',
                'RCUTILS_COLORIZED_OUTPUT': '0'})
    if pythonpath:
        env['PYTHONPATH'] = pythonpath + os.pathsep + env.get('PYTHONPATH', '')
    env.update({k: str(v) for k, v in extra.items()})
    return env


def use_ros_env(domain: int) -> None:
    """Select LOCALHOST discovery and ``domain`` for rclpy in this process."""
    os.environ.pop('ROS_STATIC_PEERS', None)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ['ROS_DOMAIN_ID'] = str(domain)


def wait_until(predicate: Callable[[], object], timeout: float = 20.0,
               interval: float = 0.05) -> bool:
    """Poll ``predicate()`` until true or ``timeout`` [s]; return whether it became true."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval)
    return bool(predicate())


class Process:
    """A child process in its own session, its stdout and stderr in files.

    The child is tied to this process (:func:`motor_id.lifeline.tied`): it gets SIGTERM
    when this process (precisely: the thread that starts it) ends.

    Parameters
    ----------
    args : list of str
        Command line; ``sys.executable`` is put first when it starts with ``-m``.
    env : dict
    logdir : path
        Where ``<name>.out`` and ``<name>.err`` go.
    name : str
    """

    def __init__(self, args: Sequence[str], env: Mapping[str, str],
                 logdir: str | os.PathLike[str], name: str) -> None:
        if args[0] == '-m':
            args = [sys.executable, *args]
        self.name = name
        self.args = args
        self.killed = False
        self.out_path = os.path.join(str(logdir), f'{name}.out')
        self.err_path = os.path.join(str(logdir), f'{name}.err')
        self._out = open(self.out_path, 'wb')
        self._err = open(self.err_path, 'wb')
        self.proc = subprocess.Popen(tied(args), env=env, stdout=self._out, stderr=self._err,
                                     stdin=subprocess.DEVNULL, start_new_session=True)
        _LIVE.add(self)
        _GROUPS.add(self.proc.pid)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stdout(self) -> str:
        with open(self.out_path, errors='replace') as fh:
            return fh.read()

    def stderr(self) -> str:
        with open(self.err_path, errors='replace') as fh:
            return fh.read()

    def output(self) -> str:
        """stdout and stderr together (ROS logs go to stderr)."""
        return self.stdout() + self.stderr()

    def last_line(self) -> str:
        """The last non-empty line of the output ('' if none)."""
        lines = self.output().strip().splitlines()
        return lines[-1] if lines else ''

    def wait_for(self, pattern: str, timeout: float = 20.0,
                 stream: str = 'output') -> re.Match[str]:
        """Wait until ``pattern`` (regex) appears in ``stream``; return the match.

        Raises
        ------
        MotorIdError
            The process exited first, or ``timeout`` [s] passed; with the output.
        """
        deadline = time.monotonic() + timeout
        rx = re.compile(pattern, re.MULTILINE)
        while True:
            m = rx.search(getattr(self, stream)())
            if m:
                return m
            if self.proc.poll() is not None:
                raise MotorIdError(f'{self.name} exited ({self.proc.returncode}) before '
                                   f'{pattern!r}:\n{self.output()}')
            if time.monotonic() > deadline:
                raise MotorIdError(f'{self.name}: no {pattern!r} in {timeout} s:\n'
                                   f'{self.output()}')
            time.sleep(0.05)

    def check(self) -> None:
        """Raise :class:`MotorIdError` with the last log line if the process has exited."""
        if self.proc.poll() is not None:
            raise MotorIdError(f'the {self.name} process exited ({self.proc.returncode}): '
                               f'{self.last_line()}')

    def wait(self, timeout: float = 20.0) -> int:
        """Wait for exit and return the code (raises ``subprocess.TimeoutExpired``)."""
        return self.proc.wait(timeout)

    def send_signal(self, sig: int = signal.SIGINT) -> None:
        """Send ``sig`` if the process still runs (do not wait)."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)

    def stop(self, sig: int = signal.SIGINT, timeout: float = 15.0) -> int:
        """Send ``sig`` and return the exit code; after ``timeout`` [s] kill the group
        (then :attr:`killed` is true)."""
        self.send_signal(sig)
        return self.finish(timeout)

    def finish(self, timeout: float = 15.0) -> int:
        """Wait up to ``timeout`` [s] for the exit, then kill the group (:attr:`killed`
        is then true); return the exit code."""
        if self.proc.poll() is None:
            try:
                self.proc.wait(max(timeout, 0.0))
            except subprocess.TimeoutExpired:
                self.killed = True
        self.kill()
        return self.proc.returncode

    def kill(self) -> None:
        """Kill the process group (the process and whatever it left behind in it)."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
        self.proc.wait(10)

    def close(self, timeout: float = 10.0) -> None:
        """End the process: SIGINT first, so that it leaves the ROS graph at once (a
        killed participant's endpoints linger in its peers until their lease expires and
        would match the next run's publishers and clients); SIGKILL of its group after
        ``timeout`` [s]."""
        self.send_signal(signal.SIGINT)
        self.finish(timeout)
        self.release()

    def release(self) -> None:
        """Forget the ended process and close its log files."""
        _LIVE.discard(self)
        self._out.close()
        self._err.close()


class Processes(dict[str, Process]):
    """Named :class:`Process` es sharing an environment and a log folder."""

    def __init__(self, env: Mapping[str, str], logdir: str | os.PathLike[str]) -> None:
        super().__init__()
        self.env = env
        self.logdir = str(logdir)

    def start(self, name: str, args: Sequence[str]) -> Process:
        """Start ``args`` as process ``name``; return it."""
        self[name] = Process(args, self.env, self.logdir, name)
        return self[name]

    def check(self) -> None:
        """Raise :class:`MotorIdError` if any process has exited."""
        for proc in self.values():
            proc.check()

    def stop(self, *names: str, timeout: float = 15.0) -> dict[str, int]:
        """SIGINT the named processes in turn; return ``{name: exit code}``."""
        return {name: self[name].stop(timeout=timeout) for name in names}

    def close(self, timeout: float = 10.0, last: Sequence[str] = ()) -> None:
        """End every process: SIGINT to all at once, then wait for all together, up to
        ``timeout`` [s], then SIGKILL the process groups still there (see
        :meth:`Process.close`). The processes named in ``last`` are signalled only when
        the others have ended (the card a driver commands 0 V to on its way out)."""
        for group in ([p for n, p in self.items() if n not in last],
                      [p for n, p in self.items() if n in last]):
            for proc in group:
                proc.send_signal(signal.SIGINT)
            deadline = time.monotonic() + timeout
            for proc in group:
                proc.finish(deadline - time.monotonic())
                proc.release()
