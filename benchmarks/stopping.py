"""How fast every way of stopping leaves the motor at 0 V and no process behind.

    python benchmarks/stopping.py [--runs N] [--json OUT]

Two measurements, each repeated ``--runs`` times, as processes on real DDS:

- ``motor-id demo`` (10x real time) signalled right after its profile started, with
  SIGINT, SIGTERM, SIGHUP or SIGKILL: seconds from the signal to the last of its card,
  driver and identifier gone (after SIGKILL they stop by the parent-death signal), the
  demo's exit code and whether the bag is complete;
- ``motor-id card-sim --speedup 4`` and the driver playing ``paper_steps``: SIGKILL of the
  driver at 3.8 V; seconds (wall clock) from the kill to the card's first 0 V sample, as
  the card reports it (its watchdog: 0.5 s).

Prints a table (median, max) and writes the runs as JSON. Needs ROS 2 (Jazzy) and psutil.
"""

import argparse
import json
import os
import signal
import statistics
import sys
import tempfile
import time

import numpy as np
import psutil

from motor_id.bag import bag_info
from motor_id.testing.procs import domain_id, Process, ros_env, wait_until

SIGNALS = {'SIGINT': signal.SIGINT, 'SIGTERM': signal.SIGTERM, 'SIGHUP': signal.SIGHUP,
           'SIGKILL': signal.SIGKILL}


def _gone(proc):
    try:
        return proc.status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def stop_demo(tmp, name, sig):
    """One demo, signalled after its profile started: the figures of the stop."""
    out = os.path.join(tmp, name)
    env = ros_env(domain_id(name))
    demo = Process(['-m', 'motor_id.cli', 'demo', '--out', out, '--domain',
                    env['ROS_DOMAIN_ID']], env, tmp, name)
    demo.wait_for(r'^driver: .*profile started', timeout=180.0, stream='stdout')
    kids = psutil.Process(demo.pid).children(recursive=True)
    t0 = time.monotonic()
    demo.send_signal(sig)
    code = demo.finish(120.0)
    wait_until(lambda: all(_gone(k) for k in kids), 120.0, interval=0.01)
    gone = time.monotonic() - t0
    demo.release()
    info = bag_info(os.path.join(out, 'demo.mcap'))
    return {'signal': signal.Signals(sig).name, 'children_gone_s': round(gone, 3),
            'exit_code': code, 'bag_complete': info['complete'],
            'children_left': sum(not _gone(k) for k in kids)}


def kill_driver(tmp, name):
    """card-sim at 4x, the driver at 3.8 V, SIGKILL: wall seconds to the card's 0 V."""
    from std_msgs.msg import Float64MultiArray

    from motor_id.nodes import messages
    from motor_id.testing.client import RosClient
    from motor_id.testing.ros import rows_of
    domain = domain_id(name)
    env, link = ros_env(domain), os.path.join(tmp, f'{name}_card')
    client = RosClient(domain, 'stopping_bench')
    card = drv = None
    try:
        samples = client.collect(Float64MultiArray, 'samples', messages.SAMPLES_QOS)
        card = Process(['-m', 'motor_id.cli', 'card-sim', '--link', link, '--speedup', '4'],
                       env, tmp, f'{name}_card')
        drv = Process(['-m', 'motor_id.nodes.driver', '--ros-args', '-p', f'device:={link}',
                       '-p', 'publish_channels:=false'], env, tmp, f'{name}_driver')
        drv.wait_for('device .* open', 60.0)
        client.trigger('/driver/start')
        wait_until(lambda: (rows_of(samples)[:, 2] == np.float32(3.8)).sum() > 100, 120.0)
        killed = time.monotonic()
        os.kill(drv.pid, signal.SIGKILL)
        m = card.wait_for(r'watchdog: .* \(monotonic clock ([\d.]+) s\)', 60.0, 'stdout')
        return {'zero_volts_after_s': round(float(m[1]) - killed, 3)}
    finally:
        for proc in (drv, card):
            if proc is not None:
                proc.close()
        client.close()


def _row(label, values, unit='s'):
    return (f'| {label} | {statistics.median(values):.2f} {unit} | {max(values):.2f} {unit} '
            f'| {len(values)} |')


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--runs', type=int, default=3)
    ap.add_argument('--json', metavar='OUT')
    args = ap.parse_args(argv)
    runs = []
    with tempfile.TemporaryDirectory(prefix='motor_id_stopping_') as tmp:
        for k in range(args.runs):
            for sig_name, sig in SIGNALS.items():
                runs.append(stop_demo(tmp, f'stop_{sig_name}_{k}', sig))
                print(json.dumps(runs[-1]), flush=True)
            runs.append(kill_driver(tmp, f'kill_driver_{k}'))
            print(json.dumps(runs[-1]), flush=True)
    print(f'\nload average at the end: {os.getloadavg()[0]:.1f} ({os.cpu_count()} cores)')
    print('| event | median | max | runs |\n|---|---|---|---|')
    for sig_name in SIGNALS:
        done = [r for r in runs if r.get('signal') == sig_name]
        print(_row(f'demo {sig_name}: all children gone', [r['children_gone_s'] for r in done]))
    zero = [r['zero_volts_after_s'] for r in runs if 'zero_volts_after_s' in r]
    print(_row('driver SIGKILL at 3.8 V: 0 V at the card', zero))
    bad = [r for r in runs if r.get('children_left') or r.get('bag_complete') is False]
    print(f'runs with a child left or a bag without its footer: {len(bad)}')
    if args.json:
        with open(args.json, 'w') as fh:
            json.dump({'runs': runs}, fh, indent=2)
    return 1 if bad else 0


if __name__ == '__main__':
    sys.exit(main())
