"""`motor-id bag`: inspect an MCAP recording or recover a truncated one."""

import argparse
import json
import os

from motor_id.bag import bag_info, DEFAULT_CHUNK_SIZE, recover
from motor_id.bag.info import BagInfo
from motor_id.errors import BagError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Subcommands ``info BAG`` and ``recover BAG OUT``."""
    sub = parser.add_subparsers(dest='action', metavar='ACTION', required=True)
    info = sub.add_parser('info', help='topics, types, counts, duration, integrity')
    info.add_argument('bag', metavar='BAG', help='an .mcap file')
    info.add_argument('--json', action='store_true', help='print the summary as JSON')
    rec = sub.add_parser('recover', help='salvage every complete chunk of a truncated or '
                                         'damaged bag (e.g. its writer was killed) into a '
                                         'clean file')
    rec.add_argument('bag', metavar='BAG', help='the damaged .mcap file')
    rec.add_argument('out', metavar='OUT', help='the clean .mcap file to write')
    rec.add_argument('--force', action='store_true', help='replace OUT if it exists')
    rec.add_argument('--chunk-size', type=int, default=DEFAULT_CHUNK_SIZE, metavar='BYTES',
                     help='chunk size of the output (default %(default)s)')


def run(args: argparse.Namespace) -> int:
    """Run the chosen action; returns the exit code."""
    if args.action == 'info':
        info = bag_info(args.bag)
        print(json.dumps(info.to_dict(), indent=2) if args.json else format_info(info))
        return 0
    if os.path.exists(args.out) and not args.force:
        raise BagError(f'{args.out} exists; pass --force to replace it')
    res = recover(args.bag, args.out, chunk_size=args.chunk_size)
    state = 'was complete' if res.was_complete else f'was damaged: {res.problem}'
    print(f'{args.bag} {state}')
    print(f'recovered {res.messages} message(s) from {res.chunks} complete chunk(s) '
          f'into {res.out}')
    for topic, count in sorted(res.topics.items()):
        print(f'  {topic:<28} {count}')
    if res.chunks_lost or res.bytes_dropped or res.orphans:
        print(f'lost: {res.chunks_lost} corrupt chunk(s), {res.bytes_dropped} byte(s) '
              f'of cut tail, {res.orphans} message(s) without a channel')
    return 0


def format_info(info: BagInfo) -> str:
    """Human-readable text of :func:`motor_id.bag.bag_info`."""
    lines = [
        f'file:        {info.path} ({info.size_bytes} bytes)',
        f'profile:     {info.profile}   library: {info.library}',
        f'ros distro:  {info.ros_distro or "-"}',
        f'messages:    {info.messages} in {info.chunks} chunk(s), compression '
        f'{", ".join(info.compression) or "-"}',
        f'duration:    {info.duration_s:.3f} s (log time {info.start_ns} .. '
        f'{info.end_ns} ns)',
        'integrity:   ' + ('complete' if info.complete else
                           f'DAMAGED: {info.problem}; try: motor-id bag recover '
                           f'{info.path} OUT.mcap'),
        'topics:',
    ]
    width = max([len(t.topic) for t in info.topics] + [5])
    for t in info.topics:
        lines.append(f'  {t.topic:<{width}}  {t.count:>8}  {t.type} ({t.encoding})')
    return '\n'.join(lines)
