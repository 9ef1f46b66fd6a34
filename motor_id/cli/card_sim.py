"""`motor-id card-sim`: run a simulated serial card on a pseudo-terminal."""

import argparse
import json

from motor_id.card.faults import FaultConfig
from motor_id.card.simulator import CardSimulator
from motor_id.cli.common import parse_noise, plant_from_args
from motor_id.errors import ConfigError
from motor_id.lifeline import SignalThread, STOP_DEADLINE
from motor_id.model import DISCRETISATIONS

WATCHDOG = 0.5
"""Default host silence [s] that stops the simulated card: the firmware sketch's value."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """CLI arguments of `motor-id card-sim`."""
    parser.add_argument('--params', metavar='FILE',
                        help='JSON motor parameters {J, K_T, K_b, B, L_m, R_m} and optional '
                             '"effects" (default: the paper\'s motor)')
    parser.add_argument('--effect', action='append', default=[], metavar='NAME[=VALUE]',
                        help='add a named effect (repeatable), e.g. coulomb_friction=0.2')
    parser.add_argument('--noise', default='0,0', metavar='SPEED[,CURRENT]',
                        help='measurement noise std in rad/s and A (absolute), e.g. 0.05,0.01')
    parser.add_argument('--no-current', action='store_true', help='send no current')
    parser.add_argument('--fault', action='append', default=[], metavar='NAME=VALUE',
                        help='inject faults (repeatable): garbage=P[:MAX], drop=P, '
                             'bad_crc=P, duplicate=P, reorder=P (per frame), '
                             'disconnect=EVERY[:DOWN] (seconds; needs --link), '
                             'current_spike=EVERY[:AMPS] (one sample per EVERY card '
                             'seconds reads AMPS, default 50 A)')
    parser.add_argument('--no-profiles', action='store_true',
                        help='a card without built-in profiles: answer "unsupported" to '
                             'start-profile commands (the driver then streams the profile)')
    parser.add_argument('--watchdog', type=float, default=WATCHDOG, metavar='SECONDS',
                        help='hold 0 V (a profile too) after this many wall-clock seconds '
                             f'without a command, as the firmware does (default {WATCHDOG:g}; '
                             'the driver pings); 0: off, as with --speedup 0')
    parser.add_argument('--period', type=float, default=0.01, help='sample period [s]')
    parser.add_argument('--speedup', type=float, default=1.0,
                        help='card seconds per wall second; 0 = as fast as read')
    parser.add_argument('--link', metavar='PATH',
                        help='keep a symlink to the pty here (stable across disconnects)')
    parser.add_argument('--method', choices=DISCRETISATIONS, default='zoh',
                        help='discretisation of the true plant')
    parser.add_argument('--seed', type=int, default=0, help='seed of noise and faults')
    parser.add_argument('--truth-out', metavar='FILE',
                        help='write the true parameters and settings as JSON')


def simulator_from_args(args: argparse.Namespace) -> CardSimulator:
    """Build a (not yet started) :class:`CardSimulator` from parsed CLI arguments."""
    plant = plant_from_args(args.params, args.effect)
    parts = parse_noise(args.noise, 'std values')
    speed_noise, current_noise = (parts + [0.0])[:2]
    faults = FaultConfig.parse(args.fault)
    if faults.disconnect_every and not args.link:
        raise ConfigError('--fault disconnect needs --link PATH so that the device comes '
                          'back at the same path')
    return CardSimulator(plant, args.period, args.speedup, not args.no_current, speed_noise,
                         current_noise, args.method, faults, args.link, args.seed,
                         profiles=not args.no_profiles, watchdog=args.watchdog)


def run(args: argparse.Namespace) -> int:
    """Serve the simulated card until SIGINT, SIGTERM or SIGHUP; print the device path
    first, and the card's 0 V last.

    The signals are heard by a :class:`~motor_id.lifeline.SignalThread` (a handler that
    set an event here could deadlock the main thread waiting on it): the card is put at
    0 V at once, then stopped; a process still running :data:`STOP_DEADLINE` seconds
    after the signal is ended.
    """
    sim = simulator_from_args(args)
    signals = SignalThread(on_stop=lambda signum: sim.halt(), last_resort=sim.halt,
                           deadline=STOP_DEADLINE).install()
    try:
        sim.start()
        if args.truth_out:
            with open(args.truth_out, 'w') as fh:
                json.dump(sim.truth().to_dict(), fh, indent=2)
        print(sim.path, flush=True)
        trips = 0
        while not signals.stopped.wait(0.1):
            trips = _report_trip(sim, trips)
            if not sim.running:
                break
    finally:
        sim.stop()
        signals.uninstall()
    print(f'stopped: 0 V from seq {sim.halted_at}', flush=True)
    if sim.error is not None:
        raise sim.error
    return 0


def _report_trip(sim: CardSimulator, seen: int) -> int:
    """Print a line for a new watchdog trip; return the trips reported."""
    card = sim.card
    trip = card.last_trip
    if card.watchdog_trips == seen or trip is None:
        return seen
    wall = sim.wall_time(trip.t_us / 1e6)
    print(f'watchdog: no command for {trip.silence:.3f} s of card time: 0 V from seq '
          f'{trip.seq} at card time {trip.t_us / 1e6:.3f} s'
          + ('' if wall is None else f' (monotonic clock {wall:.3f} s)'), flush=True)
    return card.watchdog_trips
