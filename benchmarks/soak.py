"""Soak test: the demo pipeline for minutes on a faulty simulated card, memory bounded.

    python benchmarks/soak.py [--minutes 10] [--period 0.001] [--json OUT]

Runs what ``motor-id demo`` runs, as separate processes (``motor-id card-sim``, the
driver node recording to MCAP, the identifier node re-identifying periodically), for
``--minutes`` of wall time, with the card injecting line noise, corrupt, dropped,
duplicated and reordered frames and disconnecting every ``--disconnect-every`` seconds.
A client in this process calls ``~/identify`` every ``--identify-every`` seconds, and
the resident memory (RSS) of every process is sampled every ``--sample-every`` seconds.

It prints a summary and ``RESULT: PASS`` only when:

- no process crashed, and the driver and identifier exit cleanly on SIGINT (code 0,
  no traceback in their logs);
- every injected fault kind was counted by the driver, and the disconnects seen match
  the ones injected;
- nothing was lost after the serial link: the identifier received, the client received
  and the bag holds exactly the samples the driver published;
- every identify call was answered (success, or a refusal with its reason) and at least
  one succeeded;
- memory stayed bounded: after the warm-up (the identifier's buffer full, the first fit
  done), neither node's RSS grew by more than ``--max-growth-mib``;
- the driver logged at most a few lines per fault kind and per outage (no flood).

Exit code 0 on PASS, 1 on FAIL, 2 on a set-up error.
"""

import argparse
import json
import math
import os
import re
import shutil
import sys
import tempfile
import time

from common import render_table
import numpy as np
from rosproc import close_all, num, processes, ros_env, rows_counter_client, wait_for

from motor_id.errors import MotorIdError
from motor_id.model import MotorParams, PAPER_MOTOR
from motor_id.output import to_jsonable

MOTOR = MotorParams(J=PAPER_MOTOR.J, K_T=0.65, K_b=0.65, B=PAPER_MOTOR.B, L_m=PAPER_MOTOR.L_m,
                    R_m=PAPER_MOTOR.R_m)
"""K_T = K_b so that the identifier's default tie holds."""

FAULTS = {'garbage': 0.01, 'bad_crc': 0.002, 'drop': 0.0005, 'duplicate': 0.002,
          'reorder': 0.001}
"""Per-frame fault probabilities of the simulated card."""

DRIVER_COUNTERS = {'garbage': 'garbage_bytes', 'bad_crc': 'frames_bad', 'drop': 'lost',
                   'duplicate': 'duplicates', 'reorder': 'late'}
"""Which driver diagnostics counter shows each injected fault."""

LOG_LINE = re.compile(r'^\[(WARN|ERROR|FATAL)\]', re.MULTILINE)


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--minutes', type=float, default=10.0, help='wall time (default 10)')
    ap.add_argument('--period', type=float, default=0.001,
                    help='card sample period [s] (default 0.001: 1 kHz)')
    ap.add_argument('--window', type=float, default=None,
                    help='identifier window_s [s] (default 10, or a sixth of a short run)')
    ap.add_argument('--max-samples', type=int, default=None,
                    help='identifier buffer rows (default: 2 windows of samples)')
    ap.add_argument('--identify-every', type=float, default=None,
                    help='seconds between client identify calls (default: 30, or a third '
                         'of a short run)')
    ap.add_argument('--disconnect-every', type=float, default=None,
                    help='seconds between card disconnects (default: 60, or a third of a '
                         'short run)')
    ap.add_argument('--sample-every', type=float, default=10.0,
                    help='seconds between memory samples (default 10)')
    ap.add_argument('--max-growth-mib', type=float, default=16.0,
                    help='allowed RSS growth per node after warm-up [MiB] (default 16)')
    ap.add_argument('--json', metavar='OUT', help='write the result as JSON')
    ap.add_argument('--keep', action='store_true', help='keep the logs and the bag')
    args = ap.parse_args(argv)
    duration = args.minutes * 60.0
    if not (duration > 0 and args.period > 0 and args.sample_every > 0):
        ap.error('--minutes, --period and --sample-every must be positive')
    if args.window is None:
        args.window = min(10.0, duration / 6)
    if args.max_samples is None:
        args.max_samples = int(math.ceil(2 * args.window / args.period))
    if args.identify_every is None:
        args.identify_every = min(30.0, duration / 3)
    if args.disconnect_every is None:
        args.disconnect_every = min(60.0, duration / 3)
    return args


def rss_mib(procs):
    """Resident memory of each live process [MiB] (None if gone)."""
    import psutil
    out = {}
    for name, p in procs.items():
        try:
            out[name] = psutil.Process(p.pid).memory_info().rss / 2 ** 20
        except psutil.Error:
            out[name] = None
    return out


def start(args, tmp, env, domain):
    """Start identifier, client, driver, then the card; return (procs, client, bag)."""
    procs = processes(env, tmp)
    bag = os.path.join(tmp, 'soak.mcap')
    link = os.path.join(tmp, 'card')
    pfile = os.path.join(tmp, 'motor.json')
    with open(pfile, 'w') as fh:
        json.dump(MOTOR.to_dict(), fh)
    procs.start('identifier', [
        '-m', 'motor_id.nodes.identifier', '--ros-args', '-p', f'window_s:={args.window}',
        '-p', f'max_samples:={args.max_samples}', '-p', 'allow_gaps:=true',
        '-p', f'R_m:={MOTOR.R_m}'])
    client = rows_counter_client(domain)
    duration = args.minutes * 60.0
    procs.start('driver', [
        '-m', 'motor_id.nodes.driver', '--ros-args', '-p', f'device:={link}',
        '-p', f'sample_period:={args.period}', '-p', 'excitation:=multisine',
        '-p', 'autostart:=true',
        '-p', f'duration:={duration + 60.0}', '-p', 'reopen_backoff_max:=0.2',
        '-p', f'record_path:={bag}'])
    topic = '/' + client.messages.SAMPLES_TOPIC
    if not wait_for(lambda: client.node.count_publishers(topic) >= 1
                    and client.node.count_subscribers(topic) >= 2, 40.0):
        raise RuntimeError('driver / identifier did not come up:\n'
                           + procs['driver'].output()[-1500:]
                           + procs['identifier'].output()[-1500:])
    faults = []
    for name, p in FAULTS.items():
        faults += ['--fault', f'{name}={p}']
    faults += ['--fault', f'disconnect={args.disconnect_every}:0.5']
    procs.start('card', ['-m', 'motor_id.cli', 'card-sim', '--link', link,
                         '--period', str(args.period), '--params', pfile,
                         '--noise', '0.05,0.005', '--seed', '0'] + faults)
    if not wait_for(lambda: client.first_rx is not None or not procs['card'].alive(), 40.0) \
            or not procs['card'].alive():
        raise RuntimeError('no samples from the card through the driver:\n'
                           + procs['card'].output()[-1500:] + procs['driver'].output()[-1500:])
    return procs, client, bag


def run(args):
    """Run the soak; return the result dict (``passed`` and the checks)."""
    import psutil  # noqa: F401  (fail early with a clear message)

    from motor_id.nodes.shm import clean_stale_shm
    clean_stale_shm()
    domain = 1 + (os.getpid() * 7 + 53) % 101
    env = ros_env(domain)
    tmp = tempfile.mkdtemp(prefix='motor_id_soak_')
    duration = args.minutes * 60.0
    procs, client = {}, None
    memory, calls, crashed = [], [], []
    try:
        procs, client, bag = start(args, tmp, env, domain)
        t0 = time.monotonic()
        fill_s = args.max_samples * args.period
        # calls fall between disconnects (both default to a third of a short run)
        next_mem, next_call, last_print = 0.0, 0.75 * args.identify_every, -1e9
        print(f'soak: {args.minutes:g} min at {1 / args.period:g} Hz, faults '
              + ', '.join(f'{k}={v}' for k, v in FAULTS.items())
              + f', disconnect every {args.disconnect_every:g} s; logs in {tmp}', flush=True)
        while True:
            now = time.monotonic() - t0
            if now >= duration:
                break
            if now >= next_mem:
                memory.append({'t_s': round(now, 2), **rss_mib(procs)})
                next_mem += args.sample_every
            if now >= next_call:
                try:
                    t_call, t_resp, resp = client.call_identify(timeout=120.0)
                    calls.append({'at_s': round(now, 1), 'success': bool(resp.success),
                                  'seconds': t_resp - t_call,
                                  'message': (resp.message or '').splitlines()[0]})
                except MotorIdError as exc:
                    calls.append({'at_s': round(now, 1), 'success': False, 'seconds': None,
                                  'message': f'no answer: {exc}'})
                next_call += args.identify_every
            for name, p in procs.items():
                if not p.alive() and name not in crashed:
                    crashed.append(name)
            if now - last_print >= 30.0:
                with client.lock:
                    drv = client.diag.get('motor_id: driver', {})
                    print(f'  {now:6.0f} s  published {drv.get("samples_published", "-")}, '
                          f'lost {drv.get("lost", "-")}, bad {drv.get("frames_bad", "-")}, '
                          f'device lost {drv.get("device_lost", "-")}, link '
                          f'{drv.get("link", "-")}, fits {len(calls)}', flush=True)
                last_print = now
            time.sleep(0.05)
        memory.append({'t_s': round(time.monotonic() - t0, 2), **rss_mib(procs)})
        card_code = procs['card'].stop()
        # the last diagnostics (1 Hz) report the final counts once nothing moves
        settled = lambda: client.diag.get('motor_id: identifier', {}).get('received') == \
            client.diag.get('motor_id: driver', {}).get('samples_published')  # noqa: E731
        wait_for(settled, 10.0)
        time.sleep(2.2)
        with client.lock:
            drv = dict(client.diag.get('motor_id: driver', {}))
            idn = dict(client.diag.get('motor_id: identifier', {}))
            client_rows = client.rows
        codes = {name: procs[name].stop() for name in ('driver', 'identifier')}
        codes['card'] = card_code
        logs = {name: p.output() for name, p in procs.items()}
        try:
            from motor_id.bag import read_samples
            bag_rows = int(read_samples(bag).seq.size)
            bag_error = None
        except MotorIdError as exc:
            bag_rows, bag_error = None, str(exc)
    finally:
        close_all(client, procs)
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)
    return evaluate(args, duration, fill_s, memory, calls, crashed, drv, idn, client_rows,
                    codes, logs, bag_rows, bag_error, tmp)


def growth(memory, name, warm_s):
    """RSS growth of ``name`` after ``warm_s`` [MiB] and its slope [MiB/min]."""
    pts = [(m['t_s'], m[name]) for m in memory if m['t_s'] >= warm_s and m[name] is not None]
    if len(pts) < 2:
        return None, None
    t, r = np.array(pts).T
    slope = float(np.polyfit(t / 60.0, r, 1)[0])
    return float(r[-1] - r[0]), slope


def evaluate(args, duration, fill_s, memory, calls, crashed, drv, idn, client_rows, codes,
             logs, bag_rows, bag_error, tmp):
    """Turn the observations into named checks; return the result dict."""
    checks = []

    def check(name, passed, value):
        checks.append({'check': name, 'passed': bool(passed), 'value': value})

    published = num(drv, 'samples_published')
    check('no process crashed', not crashed, ', '.join(crashed) or 'none')
    tracebacks = [n for n, text in logs.items() if 'Traceback' in text]
    check('driver and identifier exit 0 on SIGINT, no traceback',
          codes['driver'] == 0 and codes['identifier'] == 0 and not tracebacks,
          f'exit codes {codes}, tracebacks in: {", ".join(tracebacks) or "none"}')
    for fault, counter in DRIVER_COUNTERS.items():
        check(f'injected {fault} counted by the driver ({counter})',
              (num(drv, counter) or 0) > 0, drv.get(counter))
    injected = int(duration // args.disconnect_every)
    seen = int(num(drv, 'device_lost') or 0)
    check('disconnects seen = injected (+-1)', abs(seen - injected) <= 1,
          f'{seen} seen, {injected} injected')
    check('identifier received = driver published', published is not None and
          num(idn, 'received') == published, f'{idn.get("received")} / {published}')
    check('client received = driver published', client_rows == published,
          f'{client_rows} / {published}')
    check('bag rows = driver published', bag_rows == published,
          bag_error or f'{bag_rows} / {published}')
    answered = [c for c in calls if not c['message'].startswith('no answer')]
    check('every identify call answered, at least one fit', calls and
          len(answered) == len(calls) and any(c['success'] for c in calls),
          f'{len(answered)} of {len(calls)} answered, '
          f'{sum(c["success"] for c in calls)} succeeded')
    first_fit = min((c['at_s'] + (c['seconds'] or 0) for c in calls if c['success']),
                    default=0.0)
    warm_s = max(fill_s, first_fit) + 1.0
    mem = {}
    for name in ('driver', 'identifier'):
        grew, slope = growth(memory, name, warm_s)
        mem[name] = {'growth_mib': grew, 'slope_mib_per_min': slope}
        check(f'{name} RSS growth after warm-up <= {args.max_growth_mib:g} MiB',
              grew is not None and grew <= args.max_growth_mib,
              'too short to tell' if grew is None else
              f'{grew:+.1f} MiB ({slope:+.2f} MiB/min)')
    kinds = sum(1 for k in drv if k.startswith('frame_')) + 3 + 1   # + lost/dup/late, garbled
    lines = len(LOG_LINE.findall(logs.get('driver', '')))
    allowed = kinds + 3 * (seen + 1) + 2
    check('driver log: a line per fault kind and outage, no flood', lines <= allowed,
          f'{lines} warning/error lines (allowed {allowed})')
    return {'passed': all(c['passed'] for c in checks), 'checks': checks,
            'settings': {'minutes': args.minutes, 'period_s': args.period,
                         'window_s': args.window, 'max_samples': args.max_samples,
                         'faults': FAULTS, 'disconnect_every_s': args.disconnect_every,
                         'identify_every_s': args.identify_every, 'warm_up_s': warm_s},
            'driver': drv, 'identifier': idn, 'memory_mib': memory, 'memory': mem,
            'calls': calls, 'exit_codes': codes, 'logdir': tmp if args.keep else None,
            'date': time.strftime('%Y-%m-%dT%H:%M:%S%z')}


def report(result):
    """Print the summary tables and the verdict."""
    mem_rows = []
    for name, m in result['memory'].items():
        rss = [r[name] for r in result['memory_mib'] if r.get(name) is not None]
        mem_rows.append({'process': name, 'start': rss[0] if rss else None,
                         'peak': max(rss) if rss else None, 'end': rss[-1] if rss else None,
                         'growth': m['growth_mib'], 'slope': m['slope_mib_per_min']})
    print()
    print(render_table([('process', 'process', ''), ('start', 'RSS start MiB', '.1f'),
                        ('peak', 'peak MiB', '.1f'), ('end', 'end MiB', '.1f'),
                        ('growth', 'growth after warm-up MiB', '+.1f'),
                        ('slope', 'MiB/min', '+.2f')], mem_rows))
    drv = result['driver']
    keys = ('frames_ok', 'frames_bad', 'garbage_bytes', 'lost', 'duplicates', 'late',
            'device_lost', 'opens', 'samples_published')
    print()
    print(render_table([('k', 'driver counter', ''), ('v', 'value', '')],
                       [{'k': k, 'v': drv.get(k, '-')} for k in keys]))
    print()
    print(render_table([('check', 'check', ''), ('ok', 'ok', ''), ('value', 'value', '')],
                       [{'check': c['check'], 'ok': 'PASS' if c['passed'] else 'FAIL',
                         'value': str(c['value'])} for c in result['checks']]))
    print()
    print('RESULT: ' + ('PASS' if result['passed'] else 'FAIL'))


def main(argv=None):
    args = parse_args(argv)
    try:
        result = run(args)
    except (RuntimeError, ImportError, OSError) as exc:
        print(f'soak: set-up failed: {exc}', file=sys.stderr)
        return 2
    report(result)
    if args.json:
        with open(args.json, 'w') as fh:
            json.dump(to_jsonable(result), fh, indent=1)
    return 0 if result['passed'] else 1


if __name__ == '__main__':
    sys.exit(main())
