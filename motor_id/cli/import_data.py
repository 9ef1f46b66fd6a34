"""`motor-id import`: convert measured data (emps, dunker, csv, any rosbag2, SysId) to MCAP."""

import argparse
import os
import sys

from motor_id.bag import write_recording
from motor_id.cli.data_args import add_data_arguments, load_from_args, log_entries_from_args
from motor_id.data.importers import load, SOURCES
from motor_id.data.load import load_recording
from motor_id.data.mapping import TopicMapping
from motor_id.errors import ConfigError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``motor-id import emps|dunker|csv|bag|sysid SRC OUT.mcap [--motor N] [options]``.

    ``sysid`` reads a SysId JSON log or a WPILib DataLog (``.wpilog``) of a SysId routine.
    """
    parser.add_argument('source', choices=SOURCES, help='kind of the input data')
    parser.add_argument('src', metavar='SRC',
                        help='input file (.mat, .csv, SysId .json or .wpilog) or rosbag2 '
                             'recording (.mcap, .db3, folder)')
    parser.add_argument('out', metavar='OUT.mcap', help='bag to write')
    parser.add_argument('--batch', type=int, default=50, help='rows per /samples message')
    parser.add_argument('--compression', choices=('zstd', 'lz4', 'none'), default='zstd')
    parser.add_argument('--force', action='store_true', help='replace OUT if it exists')
    add_data_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Convert, write the bag, print a one-line summary."""
    if not str(args.out).endswith('.mcap'):
        raise ConfigError(f'output must be an .mcap file, got {args.out!r}')
    if os.path.exists(args.out) and not args.force:
        raise ConfigError(f'{args.out} exists; pass --force to replace it')
    if args.source in ('csv', 'bag'):
        rec = load_from_args(args, args.src)
    elif args.source == 'sysid':
        rec = load_recording(args.src, mapping=TopicMapping(joint=args.joint),
                             log_entries=log_entries_from_args(args))
        for note in rec.meta.get('warnings') or ():
            print(f'warning: {args.src}: {note}', file=sys.stderr)
    else:
        rec = load(args.source, args.src, _dunker_motor(args))
    meta = {'import_command': _command(args)}
    if os.path.exists(args.out):
        os.remove(args.out)
    res = write_recording(rec, args.out, meta=meta, batch=args.batch,
                          compression=args.compression)
    size = os.path.getsize(args.out)
    span = rec.time[-1] - rec.time[0]
    print(f'{args.out}: {res.samples} samples over {span:.3f} s '
          f'({rec.input_kind} input), {res.messages} messages, {size} bytes')
    if len(rec.segment_ranges) > 1:
        names = rec.meta.get('segment_names') or []
        print(f'note: the bag holds the {len(rec.segment_ranges)} runs '
              f'({", ".join(names)}) one after another without their boundaries; fit '
              f'{os.path.basename(args.src)} itself to give each run its own initial state',
              file=sys.stderr)
    return 0


def _dunker_motor(args: argparse.Namespace) -> int:
    """The motor number of a Dunker file (``--motor`` 1, 2 or 3; default 1)."""
    if args.motor is None:
        return 1
    if args.source != 'dunker' or str(args.motor) not in ('1', '2', '3'):
        raise ConfigError(f'--motor {args.motor}: the motor of a Dunker file is 1, 2 or 3; '
                          "a DataLog's motor is read with import sysid")
    return int(args.motor)


def _command(args: argparse.Namespace) -> str:
    """The import command line, for the bag's metadata."""
    extra = ''
    if args.source == 'dunker':
        extra = f' --motor {_dunker_motor(args)}'
    elif args.source == 'sysid':
        for key in ('motor', 'voltage', 'position', 'velocity', 'state', 'units', 'joint'):
            if getattr(args, key, None) is not None:
                extra += f' --{key} {getattr(args, key)}'
    return (f'motor-id import {args.source} {os.path.basename(args.src)} '
            f'{os.path.basename(args.out)}{extra}')
