"""`motor-id simulate`: write simulated motor data to CSV so anyone can try the tool."""

import argparse
import json

import numpy as np

from motor_id.cli.common import parse_noise, plant_from_args
from motor_id.data.csv_io import write_csv
from motor_id.errors import ConfigError
from motor_id.excitation import make_excitation, PROFILES
from motor_id.model import DISCRETISATIONS
from motor_id.simulate import simulate_recording


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """CLI arguments of `motor-id simulate`."""
    parser.add_argument('--params', metavar='FILE',
                        help="JSON motor parameters (default: the paper's motor)")
    parser.add_argument('--excitation', choices=PROFILES, default='paper_steps')
    parser.add_argument('--out', required=True, metavar='DATA.csv')
    parser.add_argument('--samples', type=int, default=4000)
    parser.add_argument('--period', type=float, default=0.01, help='sample period [s]')
    parser.add_argument('--amplitude', type=float, default=9.0, help='input amplitude [V]')
    parser.add_argument('--noise', default='0,0', metavar='SPEED[,CURRENT]',
                        help="noise std as fractions of each channel's std, e.g. 0.005,0.01")
    parser.add_argument('--effect', action='append', default=[], metavar='NAME[=VALUE]',
                        help='add a named effect (repeatable), e.g. coulomb_friction=0.2')
    parser.add_argument('--method', choices=DISCRETISATIONS, default='zoh')
    parser.add_argument('--no-current', action='store_true', help='omit the current column')
    parser.add_argument('--seed', type=int, default=0)


def run(args: argparse.Namespace) -> int:
    """Simulate and write the CSV."""
    plant = plant_from_args(args.params, args.effect)
    parts = parse_noise(args.noise, 'fractions')
    s_noise, c_noise = (parts + [parts[0]])[:2]
    if args.samples < 2 or args.period <= 0:
        raise ConfigError('--samples must be >= 2 and --period > 0')
    t = np.arange(args.samples) * args.period
    u = make_excitation(args.excitation, t, args.amplitude, args.seed)
    rec = simulate_recording(plant, t, u, s_noise, c_noise, not args.no_current, args.method,
                             args.seed)
    write_csv(rec, args.out, {'truth': json.dumps(plant.to_dict()),
                              'excitation': args.excitation, 'seed': args.seed,
                              'noise': args.noise})
    print(f'wrote {len(rec)} samples ({args.excitation}, T = {args.period} s) to {args.out}')
    return 0
