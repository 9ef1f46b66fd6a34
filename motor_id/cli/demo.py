"""`motor-id demo`: simulated card, driver and identifier as processes; bag, report, plots.

Ctrl-C, SIGTERM and SIGHUP stop it alike (exit 130): the driver, the identifier and the
card are sent SIGINT together (the driver commands 0 V and closes the bag) and killed
if they hang; killed itself (SIGKILL), the demo's children get SIGTERM from the kernel
(:mod:`motor_id.lifeline`) and stop the same way. ``--robot wheel|arm|elevator`` runs
:mod:`motor_id.cli.demo_robot` instead: the simulated ros2_control robot and
``motor-id experiment`` on its joint.
"""

import argparse
import json
import os
import random
import time
from typing import Any, TYPE_CHECKING

from motor_id.contracts import profile_span
from motor_id.errors import ConfigError, MotorIdError
from motor_id.model import MotorParams, PARAM_NAMES, Plant

if TYPE_CHECKING:  # ROS loads only when the demo runs
    from motor_id.testing.demo_client import DemoClient
    from motor_id.testing.procs import Processes

DEMO_MOTOR = MotorParams(J=0.052, K_T=0.66, K_b=0.66, B=0.002, L_m=0.0345, R_m=2.3)
"""The paper's motor with K_b = K_T = 0.66 (SI units; the paper lists K_b = 0.64)."""

NOISE = '0.02,0.0015'
"""Card measurement noise: about 0.5 % of the speed and 1 % of the current spread."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
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
    parser.add_argument('--robot', choices=('wheel', 'arm', 'elevator'),
                        help='instead of the card: `motor-id experiment` on a joint of the '
                             'simulated ros2_control robot (--fast: a shorter plan)')
    parser.add_argument('--watchdog', type=float, metavar='SEC',
                        help="--robot: the experiment's state watchdog (default: "
                             "motor-id experiment's); a busy machine may stall the "
                             'robot longer now and then (0.5 holds at a load of 8 on 2 '
                             'cores, where the default stopped one run in two)')


def _say(text: str) -> None:
    print(text, flush=True)


def run(args: argparse.Namespace) -> int:
    """Run the demo end to end; exit 0 when the estimate came back."""
    if args.robot:
        from motor_id.cli.demo_robot import run as run_robot
        return run_robot(args)
    t_start = time.monotonic()
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    truth = DEMO_MOTOR
    if args.params:
        truth = Plant.from_json(args.params).params
    params_file, meta = _write_inputs(out, truth)
    domain = args.domain or random.SystemRandom().randint(1, 101)
    if not 0 <= domain <= 232:
        raise ConfigError(f'--domain must be in 0..232, got {domain}')
    from motor_id.testing.procs import Processes, ros_env, use_ros_env
    env = ros_env(domain)
    use_ros_env(domain)
    from motor_id.nodes.shm import clean_stale_shm
    cleaned = clean_stale_shm()   # Fast DDS files that killed processes left behind
    bag = os.path.join(out, 'demo.mcap')
    for stale in (bag, os.path.join(out, 'report.json')):
        if os.path.exists(stale):
            os.remove(stale)
    speedup = '40' if args.fast else '10'
    link = os.path.join(out, 'card')
    kids = Processes(env, out)
    from motor_id.testing.demo_client import DemoClient
    client = None
    try:
        _say(f'demo: ROS_DOMAIN_ID={domain}, LOCALHOST discovery; logs in {out}'
             + (f'; removed {len(cleaned)} stale Fast DDS shared-memory file(s)'
                if cleaned else ''))
        card = kids.start('card', ['-m', 'motor_id.cli', 'card-sim', '--params', params_file,
                                   '--link', link, '--speedup', speedup, '--noise', args.noise,
                                   '--seed', str(args.seed)])
        line = card.wait_for(r'^\S+$', timeout=30.0, stream='stdout').group(0)
        _say(f'card:       simulated card on {line} ({speedup}x real time)')
        kids.start('identifier', ['-m', 'motor_id.nodes.identifier', '--ros-args',
                                  '-p', f'R_m:={truth.R_m}', '-p', 'select:=profile',
                                  # 40 s of wall clock (160,000 rows at 40x): the
                                  # profile is still in the window when this process
                                  # sees its end late on a loaded machine
                                  '-p', f'window_s:={40.0 * float(speedup)}',
                                  '-p', f'seed:={args.seed}'])
        kids.start('driver', ['-m', 'motor_id.nodes.driver', '--ros-args',
                              '-p', f'device:={link}', '-p', 'autostart:=false',
                              '-p', 'publish_channels:=false',   # 3 messages a sample
                              '-p', f'record_path:={bag}', '-p', f'meta_file:={meta}'])
        client = DemoClient(domain)
        if not client.wait_identifier_receiving(40.0):
            kids.check()
            raise MotorIdError('the identifier received no samples within 40 s; see the logs')
        ok, text = client.trigger('/driver/start', wait_service=30.0)
        if not ok:
            raise MotorIdError(f'the driver could not start the profile: {text}')
        _say('driver:     paper_steps profile started (0 / 3.8 / 7 / 9 V at 0, 3, 16, 28 s)')
        # a failure bound: a loaded machine reads the card's stream seconds late
        _wait_for_profile_end(client, kids, 40.0 / float(speedup) * 5 + 60.0)
        t_call = time.monotonic()
        ok, text = client.identify()
        latency = time.monotonic() - t_call
        if not ok:
            raise MotorIdError(f'identification failed: {text}')
        report = client.wait_report(1)
        if report is None:
            raise MotorIdError('no report arrived on /identifier/report')
        _say(f'identifier: {text.splitlines()[0]} ({latency:.2f} s from the call)')
    finally:   # Ctrl-C, SIGTERM, SIGHUP and errors alike: the driver stops first (0 V)
        try:
            kids.close(last=('card',))   # the driver sends 0 V to a card still there
        finally:
            if client is not None:
                client.close()
    report['truth'] = truth.to_dict()
    report['demo'] = {'bag': bag, 'domain_id': domain, 'speedup': float(speedup),
                      'service_latency_s': latency,
                      'seconds': time.monotonic() - t_start}
    _finish(report, truth, bag, out)
    return 0


def _write_inputs(out: str, truth: MotorParams) -> tuple[str, str]:
    """The card's motor (JSON) and the recording's metadata in ``out``; their paths."""
    params_file = os.path.join(out, 'truth.json')
    with open(params_file, 'w') as fh:
        json.dump(truth.to_dict(), fh, indent=2)
    meta = os.path.join(out, 'meta.json')
    with open(meta, 'w') as fh:
        json.dump({'provenance': 'motor-id demo: simulated card (motor_id.card.simulator), '
                                 "the paper's Eq. 14 excitation",
                   'truth': {'params': truth.to_dict(), 'input_kind': 'voltage',
                             'effects': {}}}, fh)
    return params_file, meta


def _wait_for_profile_end(client: 'DemoClient', kids: 'Processes', limit: float) -> None:
    """Print the sample count while the profile runs; MotorIdError after ``limit`` [s]."""
    t0 = time.monotonic()
    client.samples = 0
    last = -1
    while not client.profile_end.wait(0.5):
        kids.check()
        if client.samples // 1000 != last:
            last = client.samples // 1000
            _say(f'  {client.samples:5d} / 4000 samples')
        if time.monotonic() - t0 > limit:
            raise MotorIdError(f'the profile did not end within {limit:.0f} s')
    _say(f'  {client.samples:5d} / 4000 samples: profile done')


def _finish(report: dict[str, Any], truth: MotorParams, bag: str, out: str) -> None:
    """Print estimates next to the truth, check the bag, write JSON and plots."""
    from motor_id.bag import read_recording, read_samples
    from motor_id.identify import Identifier
    from motor_id.output import plot_fit, write_json
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
    start, end = profile_span(read_samples(bag).flags) or (0, len(rec))
    ident = Identifier(R_m=truth.R_m, random_state=0).fit(rec.slice(start, end))
    plot = os.path.join(out, 'fit.png')
    plot_fit(ident.result_, plot, title='motor-id demo: simulated card, paper excitation')
    path = os.path.join(out, 'report.json')
    write_json(report, path)
    _say(f'wrote {path} and {plot} ({report["demo"]["seconds"]:.1f} s in all)')
