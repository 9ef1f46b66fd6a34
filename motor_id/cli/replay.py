"""`motor-id replay`: identify from a bag offline, or republish it into the ROS graph."""

import argparse

import numpy as np

from motor_id.cli.data_args import add_data_arguments, load_from_args
from motor_id.cli.fit import add_fit_arguments, identify_and_report
from motor_id.contracts import profile_span
from motor_id.errors import ConfigError

LAST_RUN = 'last-run'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """CLI arguments of `motor-id replay`."""
    parser.add_argument('bag', metavar='BAG',
                        help='rosbag2 recording: .mcap or .db3 file, or a bag folder')
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument('--offline', action='store_true',
                      help='run the identification straight from the bag, no ROS graph '
                           '(the default)')
    mode.add_argument('--rate', type=float, metavar='X',
                      help='republish the (mapped) recording as /samples rows at X times '
                           'recorded speed')
    parser.add_argument('--subscribers', type=int, default=None, metavar='N',
                        help='--rate: wait (up to 30 s) for N matched subscribers before '
                             'publishing (default: up to 5 s for the first one)')
    parser.add_argument('--last-run', action='store_true',
                        help='offline: fit only the last complete excitation profile '
                             '(/samples flags)')
    parser.add_argument('--profile', nargs='?', const=LAST_RUN, metavar='FILE',
                        help='FILE: YAML mapping profile (as fit); without FILE: the same '
                             'as --last-run (kept for old scripts)')
    add_data_arguments(parser, profile=False)
    add_fit_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Offline: the same report as `motor-id fit`; --rate: publish and exit."""
    args.data = args.bag   # identify_and_report names plots after args.data
    last_run = args.last_run or args.profile == LAST_RUN
    if args.profile == LAST_RUN:
        args.profile = None
    if args.rate is not None:
        return _republish(args)
    rec = load_from_args(args, args.bag, validate=not last_run)
    if last_run:
        flags = _flags(args.bag)
        if flags is None:
            raise ConfigError('--last-run needs the /samples flags of a motor_id bag; this '
                              'bag is mapped from other topics')
        start, end = profile_span(flags) or (0, len(rec))
        rec = rec.slice(start, end)
    if rec.meta.get('gaps'):
        print(f'note: the bag has {len(rec.meta["gaps"])} gap(s) in its sequence numbers; '
              'time jumps over them (nothing is filled in)')
    identify_and_report(rec, args, extra={'bag': args.bag,
                                          'truth': rec.meta.get('truth')})
    return 0


def _flags(path: str) -> np.ndarray | None:
    """The /samples flags of a single-MCAP motor_id bag, or None."""
    from motor_id.bag import read_samples
    from motor_id.bag.files import is_single_mcap
    if not is_single_mcap(path):
        return None
    return read_samples(path).flags


def _republish(args: argparse.Namespace) -> int:
    from motor_id.nodes.replayer import replay
    if not args.rate > 0:
        raise ConfigError(f'--rate must be > 0, got {args.rate}')
    if args.subscribers is not None and args.subscribers < 1:
        raise ConfigError(f'--subscribers must be >= 1, got {args.subscribers}')
    rec = load_from_args(args, args.bag, validate=False)
    if rec.meta.get('mapping') is None and _flags(args.bag) is not None:
        from motor_id.bag import read_samples
        rows = read_samples(args.bag).rows()
    else:
        rows = rec.sample_rows()
    print(f'replaying {len(rows)} samples from {args.bag} at {args.rate:g}x')
    sent = replay(rows, args.rate, subscribers=args.subscribers)
    print(f'published {sent} of {len(rows)} samples on /samples')
    return 0 if sent == len(rows) else 1
