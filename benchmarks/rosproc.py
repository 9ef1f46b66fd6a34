"""Processes and a ROS client for the benchmarks that run nodes (streaming, soak).

Everything here imports rclpy and psutil lazily, so the other sections run without them.
"""

import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np

from common import REPO


def ros_env(domain):
    """The environment for node processes: LOCALHOST discovery, ``domain``, the repo."""
    env = dict(os.environ)
    env.update({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_DOMAIN_ID': str(domain),
                'PYTHONPATH': REPO + os.pathsep + env.get('PYTHONPATH', ''),
                'PYTHONUNBUFFERED': '1', 'RCUTILS_COLORIZED_OUTPUT': '0'})
    env.pop('ROS_STATIC_PEERS', None)
    return env


class Proc:
    """A child process with its output in files; stopped by SIGINT, killed on failure."""

    def __init__(self, name, args, env, logdir):
        self.name = name
        self.log = os.path.join(logdir, f'{name}.log')
        self._fh = open(self.log, 'wb')
        self.proc = subprocess.Popen([sys.executable] + args, env=env, stdout=self._fh,
                                     stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                     start_new_session=True)

    @property
    def pid(self):
        return self.proc.pid

    def output(self):
        with open(self.log, errors='replace') as fh:
            return fh.read()

    def alive(self):
        return self.proc.poll() is None

    def stop(self, timeout=15.0):
        """SIGINT, then SIGKILL of its process group after ``timeout``; returns the code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(10)
        self._fh.close()
        return self.proc.returncode


class RosClient:
    """An rclpy node in its own context, spun in a thread; records what arrives."""

    def __init__(self, domain):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from diagnostic_msgs.msg import DiagnosticArray
        from std_msgs.msg import Float64MultiArray
        from motor_id.nodes import messages

        self.rclpy = rclpy
        self.messages = messages
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node('benchmark_client', context=self.context)
        self.lock = threading.Lock()
        self.rows = 0
        self.batches = 0
        self.first_rx = None
        self.seq_first = None
        self.seq_last = None
        self.seq_gaps = 0
        self.diag = {}
        self.estimates = []
        self.node.create_subscription(Float64MultiArray, messages.SAMPLES_TOPIC,
                                      self._on_samples, messages.SAMPLES_QOS)
        self.node.create_subscription(DiagnosticArray, messages.DIAGNOSTICS_TOPIC,
                                      self._on_diag, messages.DIAGNOSTICS_QOS)
        self.node.create_subscription(DiagnosticArray, '/identifier/estimate',
                                      self._on_estimate, messages.LATCHED_QOS)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        from rclpy.executors import ExternalShutdownException
        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass

    def _on_samples(self, msg):
        rows = self.messages.msg_to_rows(msg)
        with self.lock:
            if self.first_rx is None:
                self.first_rx = time.monotonic()
            self.rows += rows.shape[0]
            self.batches += 1
            seq = rows[:, 0].astype(np.int64)
            if self.seq_first is None:
                self.seq_first = int(seq[0])
            elif seq[0] != self.seq_last + 1:
                self.seq_gaps += 1
            self.seq_gaps += int(np.sum(np.diff(seq) != 1))
            self.seq_last = int(seq[-1])

    def _on_diag(self, msg):
        with self.lock:
            for st in msg.status:
                self.diag[st.name] = {kv.key: kv.value for kv in st.values}

    def _on_estimate(self, msg):
        values = {}
        for st in msg.status:
            values.update({kv.key: kv.value for kv in st.values})
        with self.lock:
            self.estimates.append((time.monotonic(), values))

    def call_identify(self, timeout):
        """Call ``/identifier/identify``; return (t_call, t_response, response)."""
        from std_srvs.srv import Trigger
        cli = self.node.create_client(Trigger, '/identifier/identify')
        if not cli.wait_for_service(timeout_sec=20.0):
            raise RuntimeError('service /identifier/identify not available')
        done = threading.Event()
        t_call = time.monotonic()
        fut = cli.call_async(Trigger.Request())
        fut.add_done_callback(lambda _f: done.set())
        if not done.wait(timeout):
            raise RuntimeError(f'/identifier/identify did not answer in {timeout} s')
        t_resp = time.monotonic()
        self.node.destroy_client(cli)
        return t_call, t_resp, fut.result()

    def close(self):
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)
        self.thread.join(5.0)


def close_all(client, procs):
    """End a run: close the client (if any), stop every process still alive."""
    if client is not None:
        client.close()
    for p in procs.values():
        if p.alive():
            p.stop(5.0)


def cpu_times(procs):
    """Cumulative CPU seconds (user + system) of each process, and the wall clock."""
    import psutil
    out = {}
    for name, p in procs.items():
        try:
            t = psutil.Process(p.pid).cpu_times()
            out[name] = t.user + t.system
        except psutil.Error:
            out[name] = None
    return time.monotonic(), out


def cpu_percent(a, b):
    (t0, c0), (t1, c1) = a, b
    return {k: (100.0 * (c1[k] - c0[k]) / (t1 - t0)
                if c0.get(k) is not None and c1.get(k) is not None else None) for k in c0}


def wait_for(pred, timeout, interval=0.05):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(interval)
    return bool(pred())


def num(d, key):
    try:
        return float(d[key])
    except (KeyError, TypeError, ValueError):
        return None
