"""Processes and a ROS client for the benchmarks that run nodes (streaming, soak).

Everything here imports rclpy and psutil lazily, so the other sections run without them.
"""

from pathlib import Path
import sys
import tempfile
import threading
import time

from common import REPO
import numpy as np


def ros_env(domain):
    """The environment for node processes: LOCALHOST discovery, ``domain``, the repo."""
    from motor_id.testing.procs import ros_env as env_for
    return env_for(domain, pythonpath=REPO)


def run_rounds(rounds, cases, one_round, tag, burn=False):
    """Each case once per round, beside a busy process per core when ``burn``.

    ``one_round(case, folder, domain)`` runs in a fresh folder of a temporary directory
    with a ROS domain of its own (102..200, clear of the tests'); each row it returns is
    printed to stderr as it comes. Returns the rows and the number of burners.
    """
    from motor_id.testing.procs import domain_id, start_burners
    burners = start_burners() if burn else []
    rows = []
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for k in range(rounds):
                for case in cases:
                    folder = Path(tmp) / f'{case.replace(" ", "_")}_{k}'
                    folder.mkdir()
                    rows.append(one_round(case, folder, domain_id(f'{tag}{k}{case}', 102, 200)))
                    print(rows[-1], file=sys.stderr, flush=True)
    finally:
        for proc in burners:
            proc.kill()
    return rows, len(burners)


def processes(env, logdir):
    """Named node processes with logs in ``logdir`` (:class:`motor_id.testing.procs.Processes`)."""
    from motor_id.testing.procs import Processes
    return Processes(env, logdir)


def rows_counter_client(domain):
    """A :class:`motor_id.testing.client.RosClient` that counts samples and keeps diagnostics
    and estimates (imports rclpy)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64MultiArray
    from std_srvs.srv import Trigger

    from motor_id.contracts import SEQ
    from motor_id.nodes import messages
    from motor_id.testing.client import RosClient

    class BenchClient(RosClient):
        """Records what arrives: sample counts and sequence gaps, diagnostics, estimates."""

        def __init__(self):
            super().__init__(domain, 'benchmark_client')
            self.messages = messages
            self.lock = threading.Lock()
            self.rows = 0
            self.batches = 0
            self.first_rx = None
            self.seq_first = None
            self.seq_last = None
            self.seq_gaps = 0
            self.diag = {}
            self.estimates = []
            self.subscribe(Float64MultiArray, messages.SAMPLES_TOPIC, messages.SAMPLES_QOS,
                           self._on_samples)
            self.subscribe(DiagnosticArray, messages.DIAGNOSTICS_TOPIC,
                           messages.DIAGNOSTICS_QOS, self._on_diag)
            self.subscribe(DiagnosticArray, '/identifier/estimate', messages.LATCHED_QOS,
                           self._on_estimate)

        def _on_samples(self, msg):
            rows = messages.msg_to_rows(msg)
            with self.lock:
                if self.first_rx is None:
                    self.first_rx = time.monotonic()
                self.rows += rows.shape[0]
                self.batches += 1
                seq = rows[:, SEQ].astype(np.int64)
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
            t_call = time.monotonic()
            res = self.call(Trigger, '/identifier/identify', timeout=timeout)
            return t_call, time.monotonic(), res

    return BenchClient()


def close_all(client, procs):
    """End a run: close the client (if any), end every process."""
    if client is not None:
        client.close()
    for proc in procs.values():
        proc.close()


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
    """Poll ``pred()`` until true or ``timeout`` [s]; return whether it became true."""
    from motor_id.testing.procs import wait_until
    return wait_until(pred, timeout, interval)


def num(d, key):
    try:
        return float(d[key])
    except (KeyError, TypeError, ValueError):
        return None
