"""Test helpers for ROS node tests: domain ids, environments, node processes, a client."""

import atexit
import os
import re
import signal
import subprocess
import sys
import threading
import time
import zlib

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_LIVE = set()


@atexit.register
def _kill_leftovers():
    """Never leave node processes behind, even when a test run dies."""
    for proc in list(_LIVE):
        proc.kill()


def domain_id(name):
    """A ROS_DOMAIN_ID in 1..101 for one test module, varied by process id.

    Different modules and concurrent test runs get different ids (with high
    probability); the same module in the same process always gets the same id.
    """
    return 1 + (zlib.crc32(name.encode()) + os.getpid() * 7) % 101


def ros_env(domain, **extra):
    """The environment for a node process: LOCALHOST discovery, the domain, the repo."""
    env = dict(os.environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['ROS_DOMAIN_ID'] = str(domain)
    env.pop('ROS_STATIC_PEERS', None)
    env['PYTHONPATH'] = REPO + os.pathsep + env.get('PYTHONPATH', '')
    env['PYTHONUNBUFFERED'] = '1'
    env['PYTHONFAULTHANDLER'] = '1'   # a crash in a node prints the Python stacks
    env['RCUTILS_COLORIZED_OUTPUT'] = '0'
    env.update({k: str(v) for k, v in extra.items()})
    return env


class Process:
    """A child process with its stdout/stderr in files, killed on close.

    Parameters
    ----------
    args : list of str
        Command line; ``sys.executable`` is prepended when it starts with ``-m``.
    env : dict
    logdir : path
        Where ``<name>.out`` and ``<name>.err`` go.
    name : str
    """

    def __init__(self, args, env, logdir, name):
        if args[0] == '-m':
            args = [sys.executable] + list(args)
        self.name = name
        self.args = args
        self.out_path = os.path.join(str(logdir), f'{name}.out')
        self.err_path = os.path.join(str(logdir), f'{name}.err')
        self._out = open(self.out_path, 'wb')
        self._err = open(self.err_path, 'wb')
        self.proc = subprocess.Popen(args, env=env, stdout=self._out, stderr=self._err,
                                     stdin=subprocess.DEVNULL, start_new_session=True)
        _LIVE.add(self)

    @property
    def pid(self):
        return self.proc.pid

    def stdout(self):
        with open(self.out_path, errors='replace') as fh:
            return fh.read()

    def stderr(self):
        with open(self.err_path, errors='replace') as fh:
            return fh.read()

    def output(self):
        """stdout and stderr together (ROS logs go to stderr)."""
        return self.stdout() + self.stderr()

    def wait_for(self, pattern, timeout=20.0, stream='output'):
        """Wait until ``pattern`` (regex) appears; return the match or raise with the log."""
        deadline = time.monotonic() + timeout
        rx = re.compile(pattern)
        while True:
            text = getattr(self, stream)()
            m = rx.search(text)
            if m:
                return m
            if self.proc.poll() is not None:
                raise AssertionError(f'{self.name} exited ({self.proc.returncode}) before '
                                     f'{pattern!r}:\n{self.output()}')
            if time.monotonic() > deadline:
                raise AssertionError(f'{self.name}: no {pattern!r} in {timeout} s:\n'
                                     f'{self.output()}')
            time.sleep(0.05)

    def wait(self, timeout=20.0):
        """Wait for exit and return the code (raises TimeoutExpired)."""
        return self.proc.wait(timeout)

    def stop(self, sig=signal.SIGINT, timeout=15.0):
        """Send ``sig`` and return the exit code; kill the group after ``timeout``."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.kill()
                raise AssertionError(f'{self.name} ignored {sig!r} for {timeout} s:\n'
                                     f'{self.output()}') from None
        return self.proc.returncode

    def kill(self):
        """Kill the process group (cleanup)."""
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.proc.wait(10)

    def close(self):
        """End the process: SIGINT first, so that it leaves the ROS graph at once (a
        killed participant's endpoints linger in its peers until their lease expires and
        would match the next test's publishers and clients); SIGKILL if it hangs."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                pass
        self.kill()
        _LIVE.discard(self)
        self._out.close()
        self._err.close()


class Client:
    """An rclpy node in the test process, spun by a background executor.

    Uses its own context bound to ``domain``; the environment variables that select
    LOCALHOST discovery are set before rclpy initialises.
    """

    def __init__(self, domain, name='test_client'):
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        os.environ['ROS_DOMAIN_ID'] = str(domain)
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        from rclpy.executors import ExternalShutdownException
        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass

    def collect(self, msg_type, topic, qos):
        """Subscribe and return a list that fills with received messages."""
        box = []
        self.node.create_subscription(msg_type, topic, box.append, qos)
        return box

    def call(self, srv_type, name, request=None, timeout=60.0, wait_service=20.0):
        """Call a service asynchronously and wait for the response."""
        cli = self.node.create_client(srv_type, name)
        if not cli.wait_for_service(timeout_sec=wait_service):
            raise AssertionError(f'service {name} not available in {wait_service} s')
        fut = cli.call_async(request if request is not None else srv_type.Request())
        done = threading.Event()
        fut.add_done_callback(lambda _f: done.set())
        if not done.wait(timeout):
            raise AssertionError(f'service {name} did not answer in {timeout} s')
        return fut.result()

    def call_async(self, srv_type, name, request=None, wait_service=20.0):
        """Start a call; return the future."""
        cli = self.node.create_client(srv_type, name)
        if not cli.wait_for_service(timeout_sec=wait_service):
            raise AssertionError(f'service {name} not available in {wait_service} s')
        return cli.call_async(request if request is not None else srv_type.Request())

    def close(self):
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)
        self._thread.join(5.0)


def wait_until(predicate, timeout=20.0, interval=0.05):
    """Poll ``predicate()`` until true; return whether it became true."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval)
    return bool(predicate())


def stop_cleanly(proc, sig=signal.SIGINT):
    code = proc.stop(sig)
    err = proc.stderr()
    assert 'Traceback' not in err, err
    assert code == 0, f'{proc.name} exit {code}:\n{proc.output()}'


def rows_of(msgs):
    """All rows of the collected samples messages."""
    from motor_id.nodes import messages
    msgs = list(msgs)
    if not msgs:
        return np.zeros((0, 6))
    return np.vstack([messages.msg_to_rows(m) for m in msgs])


def latest_status(diags, name):
    """Key/values of the latest /diagnostics status named ``name`` (or {})."""
    for d in reversed(list(diags)):
        for st_ in d.status:
            if st_.name == name:
                return {kv.key: kv.value for kv in st_.values}
    return {}
