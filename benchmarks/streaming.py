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
import tempfile
import time

from common import Skip, target
import numpy as np
from rosproc import (
    close_all,
    cpu_percent,
    cpu_times,
    num,
    processes,
    ros_env,
    rows_counter_client,
    wait_for,
)

from motor_id.identify.space import VOLTAGE_FREE
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
        from diagnostic_msgs.msg import DiagnosticArray  # noqa: F401
        import rclpy  # noqa: F401
        from std_srvs.srv import Trigger  # noqa: F401
    except ImportError as exc:
        raise Skip(f'ROS 2 Python packages not importable ({exc})') from None
    for mod in ('motor_id.nodes.driver', 'motor_id.nodes.identifier',
                'motor_id.nodes.messages', 'motor_id.card.simulator'):
        try:
            __import__(mod)
        except ImportError as exc:
            raise Skip(f'{mod} is not available ({exc})') from None


def run(quick=False):
    """Run the section; returns the section record (or raises :class:`Skip`)."""
    _require()
    duration = 4.0 if quick else 60.0
    calls_at = (2.5,) if quick else (12.0, 24.0, 36.0, 48.0)
    window = 2.0 if quick else 4.0
    generations = 20 if quick else 160
    period = 0.001
    domain = 1 + (os.getpid() * 7 + 29) % 101
    env = ros_env(domain)
    tmp = tempfile.mkdtemp(prefix='motor_id_bench_')
    procs = processes(env, tmp)
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
        # identifier, client and driver first, so that every sample the card sends
        # reaches matched subscribers; the driver waits for the device, then the card starts
        procs.start('identifier', [
            '-m', 'motor_id.nodes.identifier', '--ros-args',
            '-p', f'window_s:={window}', '-p', f'generations:={generations}',
            '-p', f'R_m:={MOTOR.R_m}'])
        client = rows_counter_client(domain)
        _start_driver_and_card(procs, client, tmp, period, duration)
        t0 = client.first_rx
        cpu_start = cpu_times(procs)
        calls, cpu_idle = _identify_calls(client, procs, t0, calls_at)
        wait_for(lambda: time.monotonic() - t0 >= duration, duration + 1.0, 0.01)
        cpu_end = cpu_times(procs)
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
        close_all(client, procs)
        logs = {name: p.output()[-3000:] for name, p in procs.items()}
        shutil.rmtree(tmp, ignore_errors=True)

    return _record(quick, settings, calls, (cpu_start, cpu_idle, cpu_end), drv, idn,
                   (rows_total, rx_rows, rx_batches, seq), exit_codes, logs,
                   (duration, calls_at, window))


def _start_driver_and_card(procs, client, tmp, period, duration):
    """The driver (waiting for the device with a short backoff), then the card; return
    once the client receives samples."""
    pfile = os.path.join(tmp, 'motor.json')
    with open(pfile, 'w') as fh:
        json.dump(MOTOR.to_dict(), fh)
    link = os.path.join(tmp, 'card')
    procs.start('driver', [
        '-m', 'motor_id.nodes.driver', '--ros-args', '-p', f'device:={link}',
        '-p', f'sample_period:={period}', '-p', 'excitation:=multisine',
        '-p', 'autostart:=true',
        '-p', f'duration:={duration + 30.0}', '-p', 'reopen_backoff_max:=0.2'])
    topic = '/' + client.messages.SAMPLES_TOPIC
    if not wait_for(lambda: client.node.count_publishers(topic) >= 1
                    and client.node.count_subscribers(topic) >= 2
                    and client.node.count_publishers('/identifier/estimate') >= 1, 40.0):
        raise RuntimeError('driver / identifier did not come up:\n'
                           + procs['driver'].output()[-1500:]
                           + procs['identifier'].output()[-1500:])
    time.sleep(0.5)
    procs.start('card', ['-m', 'motor_id.cli', 'card-sim', '--link', link,
                         '--period', str(period), '--params', pfile,
                         '--noise', '0.05,0.005', '--seed', '0'])
    if not wait_for(lambda: client.first_rx is not None or not procs['card'].alive(), 40.0) \
            or not procs['card'].alive():
        raise RuntimeError('no samples from the card through the driver:\n'
                           + procs['card'].output()[-1500:]
                           + procs['driver'].output()[-1500:])


def _identify_calls(client, procs, t0, calls_at):
    """Call ~/identify at each of ``calls_at`` [s]; the calls and the CPU before the first."""
    cpu_idle = None
    calls = []
    for at in calls_at:
        wait_for(lambda at=at: time.monotonic() - t0 >= at, at + 1.0, 0.01)
        if cpu_idle is None:
            cpu_idle = cpu_times(procs)
        n_est = len(client.estimates)
        t_call, t_resp, resp = client.call_identify(timeout=120.0)
        got = resp.success and wait_for(
            lambda n_est=n_est: len(client.estimates) > n_est, 10.0, 0.002)
        t_est = client.estimates[-1][0] if got else None
        est = client.estimates[-1][1] if got else {}
        calls.append({'at_s': at, 'success': bool(resp.success),
                      'response_s': t_resp - t_call,
                      'estimate_s': (t_est - t_call) if t_est else None,
                      'message': resp.message.splitlines()[0] if resp.message else '',
                      'estimate': {k: num(est, k) for k in VOLTAGE_FREE}})
    return calls, cpu_idle


def _record(quick, settings, calls, cpu, drv, idn, rows, exit_codes, logs, plan):
    """The section record: tables, targets and notes from what the run measured."""
    cpu_start, cpu_idle, cpu_end = cpu
    rows_total, rx_rows, rx_batches, seq = rows
    duration, calls_at, window = plan
    wall = cpu_end[0] - cpu_start[0]
    cpu_all = cpu_percent(cpu_start, cpu_end)
    cpu_stream = cpu_percent(cpu_start, cpu_idle) if cpu_idle else {}
    last_seq = num(drv, 'last_seq')
    sent = None if last_seq is None else int(last_seq) + 1
    counts = {
        'card: samples sent (last seq + 1)': sent,
        'samples topic: first seq': seq[0],
        'driver: frames ok': num(drv, 'frames_ok'),
        'driver: frames lost (seq gaps)': num(drv, 'lost'),
        'driver: duplicates': num(drv, 'duplicates'),
        'driver: bad frames': num(drv, 'frames_bad'),
        'driver: samples published': num(drv, 'samples_published'),
        'identifier: received': num(idn, 'received'),
        'identifier: gaps': num(idn, 'gaps'),
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
    targets = _targets(quick, counts, calls, seq, exit_codes)
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
            'the identifier warms its compiled kernels at start-up (a tiny fit before it '
            'subscribes), so the first identify call does not stall reception',
        ],
    }


def _targets(quick, counts, calls, seq, exit_codes):
    """The section's targets: losses, latency and a clean exit."""
    lat = [c['estimate_s'] for c in calls if c['estimate_s'] is not None]
    later = lat[1:] if len(lat) > 1 else lat
    published = counts['driver: samples published']
    received = counts['identifier: received']
    ros_lost = None if None in (published, received) else published - received
    serial_lost = counts['driver: frames lost (seq gaps)']
    held = None if None in (published, counts['driver: frames ok']) else \
        counts['driver: frames ok'] - published
    rate = counts['client: rate [Hz]']
    return [
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
