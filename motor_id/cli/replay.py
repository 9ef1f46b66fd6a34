"""`motor-id replay`: identify from a bag offline, or republish it into the ROS graph."""

import numpy as np

from motor_id.cli.fit import add_fit_arguments, identify_and_report
from motor_id.contracts import profile_span
from motor_id.errors import ConfigError


def add_arguments(parser):
    """CLI arguments of `motor-id replay`."""
    parser.add_argument('bag', metavar='BAG', help='MCAP recording (or rosbag2 directory)')
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument('--offline', action='store_true',
                      help='run the identification straight from the bag, no ROS graph '
                           '(the default)')
    mode.add_argument('--rate', type=float, metavar='X',
                      help='republish /samples into the graph at X times recorded speed')
    parser.add_argument('--subscribers', type=int, default=None, metavar='N',
                        help='--rate: wait (up to 30 s) for N matched subscribers before '
                             'publishing (default: up to 5 s for the first one)')
    parser.add_argument('--profile', action='store_true',
                        help='offline: fit only the last complete excitation profile')
    add_fit_arguments(parser)


def run(args):
    """Offline: the same report as `motor-id fit`; --rate: publish and exit."""
    from motor_id.bag import read_recording, read_samples
    if args.rate is not None:
        if not args.rate > 0:
            raise ConfigError(f'--rate must be > 0, got {args.rate}')
        if args.subscribers is not None and args.subscribers < 1:
            raise ConfigError(f'--subscribers must be >= 1, got {args.subscribers}')
        s = read_samples(args.bag)
        rows = np.column_stack([s[c] for c in ('seq', 't', 'voltage', 'speed', 'current',
                                               'flags')])
        from motor_id.nodes.replayer import replay
        print(f'replaying {len(rows)} samples from {args.bag} at {args.rate:g}x')
        sent = replay(rows, args.rate, subscribers=args.subscribers)
        print(f'published {sent} of {len(rows)} samples on /samples')
        return 0 if sent == len(rows) else 1
    rec = read_recording(args.bag)
    if args.profile:
        start, end = profile_span(read_samples(args.bag)['flags']) or (0, len(rec))
        rec = rec.slice(start, end)
    if rec.meta.get('gaps'):
        print(f'note: the bag has {len(rec.meta["gaps"])} gap(s) in its sequence numbers; '
              'time jumps over them (nothing is filled in)')
    identify_and_report(rec, args, extra={'bag': args.bag,
                                          'truth': rec.meta.get('truth')})
    return 0
