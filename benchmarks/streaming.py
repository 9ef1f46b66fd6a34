"""Section 4: the streaming path, card -> driver -> identifier, at 1 kHz in real time.

Three processes, as deployed: ``motor-id card-sim`` (a virtual card on a pty, paced in
real time), the driver node and the identifier node (their default parameters except
the ones listed in the settings). A client node in this process counts the samples,
watches ``/diagnostics``, calls ``/identifier/identify`` a few times and times the
latched estimate. CPU is read per process with psutil.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

from common import REPO, Skip, target
from motor_id.model import MotorParams, PAPER_MOTOR

TITLE = 'Streaming: card-sim -> driver -> identifier at 1 kHz'
MOTOR = MotorParams(J=PAPER_MOTOR.J, K_T=0.65, K_b=0.65, B=PAPER_MOTOR.B, L_m=PAPER_MOTOR.L_m,
                    R_m=PAPER_MOTOR.R_m)
"""K_T = K_b so that the identifier's default tie holds."""


def _require():
    """Import what the section needs; :class:`Skip` with the reason if anything is missing."""
    try:
        import psutil  # noqa: F401
    except ImportError:
        raise Skip('psutil is not installed (pip install psutil)') from None
    try:
        import rclpy  # noqa: F401
        from diagnostic_msgs.msg import DiagnosticArray  # noqa: F401
        from std_srvs.srv import Trigger  # noqa: F401
    except ImportError as exc:
        raise Skip(f'ROS 2 Python packages not importable ({exc})') from None
    for mod in ('motor_id.nodes.driver', 'motor_id.nodes.identifier',
                'motor_id.nodes.messages', 'motor_id.card.simulator'):
        try:
            __import__(mod)
        except ImportError as exc:
            raise Skip(f'{mod} is not available ({exc})') from None


class _Proc:
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


class _Client:
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


def _cpu(procs):
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


def _cpu_percent(a, b):
    (t0, c0), (t1, c1) = a, b
    return {k: (100.0 * (c1[k] - c0[k]) / (t1 - t0)
                if c0.get(k) is not None and c1.get(k) is not None else None) for k in c0}


def _wait(pred, timeout, interval=0.05):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(interval)
    return bool(pred())


def _num(d, key):
    try:
        return float(d[key])
    except (KeyError, TypeError, ValueError):
        return None


def run(quick=False):
    """Run the section; returns the section record (or raises :class:`Skip`)."""
    _require()
    duration = 4.0 if quick else 60.0
    calls_at = (2.5,) if quick else (12.0, 24.0, 36.0, 48.0)
    window = 2.0 if quick else 4.0
    generations = 20 if quick else 160
    period = 0.001
    domain = 1 + (os.getpid() * 7 + 29) % 101
    env = dict(os.environ)
    env.update({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_DOMAIN_ID': str(domain),
                'PYTHONPATH': REPO + os.pathsep + env.get('PYTHONPATH', ''),
                'PYTHONUNBUFFERED': '1', 'RCUTILS_COLORIZED_OUTPUT': '0'})
    env.pop('ROS_STATIC_PEERS', None)
    tmp = tempfile.mkdtemp(prefix='motor_id_bench_')
    procs = {}
    client = None
    settings = {
        'card': {'period': period, 'noise': '0.05 rad/s, 0.005 A', 'motor': MOTOR.to_dict(),
                 'speedup': 1.0},
        'driver': {'sample_period': period, 'excitation': 'multisine', 'batch_size': 10,
                   'publish_channels': True, 'autostart': True},
        'identifier': {'window_s': window, 'generations': generations, 'select': 'window'},
        'duration_s': duration, 'identify_at_s': list(calls_at), 'ros_domain_id': domain,
    }
    try:
        pfile = os.path.join(tmp, 'motor.json')
        with open(pfile, 'w') as fh:
            json.dump(MOTOR.to_dict(), fh)
        link = os.path.join(tmp, 'card')
        # identifier, client and driver first, so that every sample the card sends
        # reaches matched subscribers; the driver waits for the device with a short
        # backoff, then the card comes up
        procs['identifier'] = _Proc('identifier', [
            '-m', 'motor_id.nodes.identifier', '--ros-args',
            '-p', f'window_s:={window}', '-p', f'generations:={generations}',
            '-p', f'R_m:={MOTOR.R_m}'], env, tmp)
        client = _Client(domain)
        procs['driver'] = _Proc('driver', [
            '-m', 'motor_id.nodes.driver', '--ros-args', '-p', f'device:={link}',
            '-p', f'sample_period:={period}', '-p', 'excitation:=multisine',
            '-p', f'duration:={duration + 30.0}', '-p', 'reopen_backoff_max:=0.2'], env, tmp)
        topic = '/' + client.messages.SAMPLES_TOPIC
        if not _wait(lambda: client.node.count_publishers(topic) >= 1
                     and client.node.count_subscribers(topic) >= 2
                     and client.node.count_publishers('/identifier/estimate') >= 1, 40.0):
            raise RuntimeError('driver / identifier did not come up:\n'
                               + procs['driver'].output()[-1500:]
                               + procs['identifier'].output()[-1500:])
        time.sleep(0.5)
        procs['card'] = _Proc('card', ['-m', 'motor_id.cli', 'card-sim', '--link', link,
                                       '--period', str(period), '--params', pfile,
                                       '--noise', '0.05,0.005', '--seed', '0'], env, tmp)
        if not _wait(lambda: client.first_rx is not None or not procs['card'].alive(), 40.0) \
                or not procs['card'].alive():
            raise RuntimeError('no samples from the card through the driver:\n'
                               + procs['card'].output()[-1500:]
                               + procs['driver'].output()[-1500:])
        t0 = client.first_rx
        cpu_start = _cpu(procs)
        cpu_idle = None
        calls = []
        for at in calls_at:
            _wait(lambda: time.monotonic() - t0 >= at, at + 1.0, 0.01)
            if cpu_idle is None:
                cpu_idle = _cpu(procs)
            n_est = len(client.estimates)
            t_call, t_resp, resp = client.call_identify(timeout=120.0)
            got = resp.success and _wait(lambda: len(client.estimates) > n_est, 10.0, 0.002)
            t_est = client.estimates[-1][0] if got else None
            est = client.estimates[-1][1] if got else {}
            calls.append({'at_s': at, 'success': bool(resp.success),
                          'response_s': t_resp - t_call,
                          'estimate_s': (t_est - t_call) if t_est else None,
                          'message': resp.message.splitlines()[0] if resp.message else '',
                          'estimate': {k: _num(est, k) for k in ('J', 'K_T', 'K_b', 'B',
                                                                 'L_m')}})
        _wait(lambda: time.monotonic() - t0 >= duration, duration + 1.0, 0.01)
        cpu_end = _cpu(procs)
        with client.lock:
            rx_rows, rx_batches = client.rows, client.batches
        procs['card'].stop()
        time.sleep(2.2)   # let the last diagnostics (1 Hz) report the final counts
        with client.lock:
            drv = dict(client.diag.get('motor_id: driver', {}))
            idn = dict(client.diag.get('motor_id: identifier', {}))
            rows_total = client.rows
            seq = (client.seq_first, client.seq_last, client.seq_gaps)
        exit_codes = {name: procs[name].stop() for name in ('driver', 'identifier')}
    finally:
        if client is not None:
            client.close()
        for p in procs.values():
            if p.alive():
                p.stop(5.0)
        logs = {name: p.output()[-3000:] for name, p in procs.items()}
        shutil.rmtree(tmp, ignore_errors=True)

    wall = cpu_end[0] - cpu_start[0]
    cpu_all = _cpu_percent(cpu_start, cpu_end)
    cpu_stream = _cpu_percent(cpu_start, cpu_idle) if cpu_idle else {}
    last_seq = _num(drv, 'last_seq')
    sent = None if last_seq is None else int(last_seq) + 1
    counts = {
        'card: samples sent (last seq + 1)': sent,
        'samples topic: first seq': seq[0],
        'driver: frames ok': _num(drv, 'frames_ok'),
        'driver: frames lost (seq gaps)': _num(drv, 'lost'),
        'driver: duplicates': _num(drv, 'duplicates'),
        'driver: bad frames': _num(drv, 'frames_bad'),
        'driver: samples published': _num(drv, 'samples_published'),
        'identifier: received': _num(idn, 'received'),
        'identifier: gaps': _num(idn, 'gaps'),
        'client: rows': rows_total, 'client: seq gaps': seq[2],
        'client: rows in the timed window': rx_rows,
        'client: messages in the timed window': rx_batches,
        'client: rate [Hz]': rx_rows / wall if wall > 0 else None}
    truth = MOTOR.to_dict()
    call_rows = []
    for k, c in enumerate(calls):
        errs = [abs(v / truth[n] - 1) for n, v in c['estimate'].items() if v is not None]
        call_rows.append({'call': f'#{k + 1} at {c["at_s"]:.0f} s', 'ok': c['success'],
                          'response_s': c['response_s'], 'estimate_s': c['estimate_s'],
                          'max_error': max(errs) if errs else None})
    proc_rows = [{'process': n, 'cpu_streaming': cpu_stream.get(n),
                  'cpu_total': cpu_all.get(n)} for n in ('card', 'driver', 'identifier')]
    count_rows = [{'where': k, 'value': v} for k, v in counts.items()]
    lat = [c['estimate_s'] for c in calls if c['estimate_s'] is not None]
    later = lat[1:] if len(lat) > 1 else lat
    published = counts['driver: samples published']
    received = counts['identifier: received']
    ros_lost = None if None in (published, received) else published - received
    serial_lost = counts['driver: frames lost (seq gaps)']
    held = None if None in (published, counts['driver: frames ok']) else \
        counts['driver: frames ok'] - published
    rate = counts['client: rate [Hz]']
    targets = [
        target('samples lost in ROS transport (driver published - identifier received)',
               ros_lost, '0', ros_lost == 0 if ros_lost is not None else None),
        target('frames lost on the serial link (sequence gaps seen by the driver)',
               serial_lost, '0', serial_lost == 0 if serial_lost is not None else None),
        target('frames the driver read but had not published when the card stopped',
               held, 'informative (< batch_size)', None),
        target('samples the card sent before the driver opened the pty',
               seq[0], 'informative', None),
        target('client receive rate', rate, '~1000 Hz (+-2 %)',
               abs(rate - 1000) <= 20 if not quick and rate else None, 'Hz'),
        target('latency identify call -> published estimate (median, after the first)',
               float(np.median(later)) if later else None, 'informative', None, 's'),
        target('clean exit of driver and identifier on SIGINT',
               float(max(abs(v or 0) for v in exit_codes.values())), 'exit code 0',
               all(v == 0 for v in exit_codes.values())),
    ]
    return {
        'title': TITLE,
        'status': 'ok',
        'settings': settings,
        'tables': [
            {'title': f'CPU per process [% of one core] (streaming only: first '
                      f'{calls_at[0]:.0f} s; total: {duration:.0f} s with '
                      f'{len(calls_at)} fit(s) of {window:g} s windows)',
             'columns': [('process', 'process', ''), ('cpu_streaming', 'streaming %', '.1f'),
                         ('cpu_total', 'total %', '.1f')],
             'rows': proc_rows},
            {'title': 'samples', 'columns': [('where', 'count', ''), ('value', 'value', '')],
             'rows': [{'where': r['where'], 'value': '-' if r['value'] is None else
                       (f'{r["value"]:.1f}' if isinstance(r['value'], float) and
                        not float(r['value']).is_integer() else f'{int(r["value"])}')}
                      for r in count_rows]},
            {'title': 'identify calls (service response and latched estimate arrival, '
                      'from the call)',
             'columns': [('call', 'call', ''), ('ok', 'ok', ''),
                         ('response_s', 'response s', '.3f'),
                         ('estimate_s', 'estimate s', '.3f'),
                         ('max_error', 'max rel. err', '.2e')],
             'rows': call_rows},
        ],
        'targets': targets,
        'counts': counts, 'calls': calls, 'cpu_percent': {'streaming': cpu_stream,
                                                          'total': cpu_all},
        'exit_codes': exit_codes, 'logs_tail': logs,
        'notes': [
            'the card starts after the driver, identifier and client are matched on '
            '`samples`; "samples sent" is the last sequence number + 1 seen by the driver '
            '(the card numbers from 0); counts are read from /diagnostics of the nodes '
            'after the card has stopped. The card streams from its start, so the first '
            'few samples go out before the driver opens the pty',
            'the driver publishes the samples batch topic (10 rows per message) and, by '
            'default, the voltage/speed/current Float64 topics at the sample rate',
            'CPU: psutil user + system time of each process over the interval / wall time',
            'the first identify call includes loading the compiled simulation kernel',
        ],
    }
