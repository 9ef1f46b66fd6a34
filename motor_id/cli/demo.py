"""`motor-id demo`: simulated card, driver and identifier as processes; bag, report, plots."""

import json
import os
import random
import signal
import subprocess
import sys
import time

from motor_id.contracts import profile_span
from motor_id.errors import ConfigError, MotorIdError
from motor_id.model import MotorParams, PARAM_NAMES, Plant

DEMO_MOTOR = MotorParams(J=0.052, K_T=0.66, K_b=0.66, B=0.002, L_m=0.0345, R_m=2.3)
"""The paper's motor with K_b = K_T = 0.66 (SI units; the paper lists K_b = 0.64)."""

NOISE = '0.02,0.0015'
"""Card measurement noise: about 0.5 % of the speed and 1 % of the current spread."""


def add_arguments(parser):
    """CLI arguments of `motor-id demo`."""
    parser.add_argument('--out', default='out', metavar='DIR',
                        help='where the bag, report.json and plots go (default: out)')
    parser.add_argument('--fast', action='store_true',
                        help='run the card 40x faster than real time instead of 10x')
    parser.add_argument('--params', metavar='FILE', help='card motor parameters (JSON)')
    parser.add_argument('--noise', default=NOISE, metavar='SPEED,CURRENT',
                        help=f'card noise std [rad/s, A] (default {NOISE})')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--domain', type=int, help='ROS_DOMAIN_ID (default: random 1..101)')


class _Children:
    """Child processes with logs in the output folder; all stopped on exit."""

    def __init__(self, out, env):
        self.out = out
        self.env = env
        self.procs = {}

    def start(self, name, args):
        log = open(os.path.join(self.out, f'{name}.log'), 'wb')
        proc = subprocess.Popen([sys.executable] + args, env=self.env, stdout=subprocess.PIPE
                                if name == 'card' else log, stderr=log,
                                stdin=subprocess.DEVNULL, start_new_session=True)
        self.procs[name] = (proc, log)
        return proc

    def log(self, name):
        with open(os.path.join(self.out, f'{name}.log'), errors='replace') as fh:
            return fh.read()

    def check(self):
        for name, (proc, _) in self.procs.items():
            if proc.poll() is not None:
                raise MotorIdError(f'the {name} process exited ({proc.returncode}); '
                                   f'see {os.path.join(self.out, name + ".log")}: '
                                   + self.log(name).strip().splitlines()[-1:][0]
                                   if self.log(name).strip() else '')

    def stop(self, name, timeout=10.0):
        proc, log = self.procs.pop(name)
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(5)
        log.close()
        return proc.returncode

    def stop_all(self):
        for name in list(self.procs):
            self.stop(name)


def _say(text):
    print(text, flush=True)


def run(args):
    """Run the demo end to end; exit 0 when the estimate came back."""
    t_start = time.monotonic()
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    truth = DEMO_MOTOR
    if args.params:
        truth = Plant.from_json(args.params).params
    params_file = os.path.join(out, 'truth.json')
    with open(params_file, 'w') as fh:
        json.dump(truth.to_dict(), fh, indent=2)
    domain = args.domain or random.SystemRandom().randint(1, 101)
    if not 0 <= domain <= 232:
        raise ConfigError(f'--domain must be in 0..232, got {domain}')
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED='1', RCUTILS_COLORIZED_OUTPUT='0')
    env.pop('ROS_STATIC_PEERS', None)
    os.environ.update({k: env[k] for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_DOMAIN_ID')})
    from motor_id.nodes.shm import clean_stale_shm
    cleaned = clean_stale_shm()   # Fast DDS files that killed processes left behind
    bag = os.path.join(out, 'demo.mcap')
    for stale in (bag, os.path.join(out, 'report.json')):
        if os.path.exists(stale):
            os.remove(stale)
    meta = os.path.join(out, 'meta.json')
    with open(meta, 'w') as fh:
        json.dump({'provenance': 'motor-id demo: simulated card (motor_id.card.simulator), '
                                 "the paper's Eq. 14 excitation",
                   'truth': {'params': truth.to_dict(), 'input_kind': 'voltage',
                             'effects': {}}}, fh)
    speedup = '40' if args.fast else '10'
    link = os.path.join(out, 'card')
    kids = _Children(out, env)
    from motor_id.nodes.demo_client import DemoClient
    client = None
    try:
        _say(f'demo: ROS_DOMAIN_ID={domain}, LOCALHOST discovery; logs in {out}'
             + (f'; removed {len(cleaned)} stale Fast DDS shared-memory file(s)'
                if cleaned else ''))
        card = kids.start('card', ['-m', 'motor_id.cli', 'card-sim', '--params', params_file,
                                   '--link', link, '--speedup', speedup, '--noise', args.noise,
                                   '--seed', str(args.seed)])
        line = card.stdout.readline().decode().strip()
        if not line:
            kids.check()
            raise MotorIdError('the card simulator printed no device path')
        _say(f'card:       simulated card on {line} ({speedup}x real time)')
        kids.start('identifier', ['-m', 'motor_id.nodes.identifier', '--ros-args',
                                  '-p', f'R_m:={truth.R_m}', '-p', 'select:=profile',
                                  '-p', 'window_s:=120.0', '-p', f'seed:={args.seed}'])
        kids.start('driver', ['-m', 'motor_id.nodes.driver', '--ros-args',
                              '-p', f'device:={link}', '-p', 'autostart:=false',
                              '-p', f'record_path:={bag}', '-p', f'meta_file:={meta}'])
        client = DemoClient(domain)
        if not client.wait_identifier_receiving(40.0):
            kids.check()
            raise MotorIdError('the identifier received no samples within 40 s; see the logs')
        ok, text = client.call('/driver/start', wait_service=30.0)
        if not ok:
            raise MotorIdError(f'the driver could not start the profile: {text}')
        _say('driver:     paper_steps profile started (0 / 3.8 / 7 / 9 V at 0, 3, 16, 28 s)')
        t0 = time.monotonic()
        client.samples = 0
        limit = 40.0 / float(speedup) * 3 + 20.0
        last = -1
        while not client.profile_end.wait(0.5):
            kids.check()
            if client.samples // 1000 != last:
                last = client.samples // 1000
                _say(f'  {client.samples:5d} / 4000 samples')
            if time.monotonic() - t0 > limit:
                raise MotorIdError(f'the profile did not end within {limit:.0f} s')
        _say(f'  {client.samples:5d} / 4000 samples: profile done')
        t_call = time.monotonic()
        ok, text = client.identify()
        latency = time.monotonic() - t_call
        if not ok:
            raise MotorIdError(f'identification failed: {text}')
        report = client.wait_report(1)
        if report is None:
            raise MotorIdError('no report arrived on /identifier/report')
        _say(f'identifier: {text.splitlines()[0]} ({latency:.2f} s from the call)')
    finally:
        if client is not None:
            client.close()
        kids.stop_all()
    report['truth'] = truth.to_dict()
    report['demo'] = {'bag': bag, 'domain_id': domain, 'speedup': float(speedup),
                      'service_latency_s': latency,
                      'seconds': time.monotonic() - t_start}
    _finish(report, truth, bag, out)
    return 0


def _finish(report, truth, bag, out):
    """Print estimates next to the truth, check the bag, write JSON and plots."""
    from motor_id.bag import read_recording, read_samples
    from motor_id.identify import Identifier
    from motor_id.report import plot_fit, write_json
    _say('')
    _say(f'{"parameter":<10}{"estimate":>14}{"std":>12}{"truth":>12}{"error":>9}')
    for name in PARAM_NAMES:
        p = report['parameters'].get(name, {})
        t = getattr(truth, name)
        if p.get('value') is None:
            _say(f'{name:<10}{"not determined":>14}{"":>12}{t:>12.6g}')
            continue
        std = '' if p.get('std') is None else f'{p["std"]:.3g}'
        _say(f'{name:<10}{p["value"]:>14.6g}{std:>12}{t:>12.6g}'
             f'{100 * (p["value"] - t) / t:>8.2f}%')
    rec = read_recording(bag)
    _say(f'\nbag: {bag} ({len(rec)} samples on /samples)')
    start, end = profile_span(read_samples(bag)['flags']) or (0, len(rec))
    ident = Identifier(R_m=truth.R_m, random_state=0).fit(rec.slice(start, end))
    plot = os.path.join(out, 'fit.png')
    plot_fit(ident.result_, plot, title='motor-id demo: simulated card, paper excitation')
    path = os.path.join(out, 'report.json')
    write_json(report, path)
    _say(f'wrote {path} and {plot} ({report["demo"]["seconds"]:.1f} s in all)')
