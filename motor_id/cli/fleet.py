"""`motor-id fleet`: every motor of every recording on Dask, histories, drift, a report."""

from __future__ import annotations

import argparse
import sys
import time
from typing import TextIO

from motor_id.fleet.config import load_fleet_config
from motor_id.fleet.discover import ROBOT_RULES
from motor_id.fleet.rows import TaskResult
from motor_id.fleet.run import Progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """CLI arguments of `motor-id fleet`."""
    parser.add_argument('recordings', nargs='*', metavar='RECORDING',
                        help='rosbag2 recordings: bag folders, .mcap / .db3 files, folders '
                             'to search, globs (none: recompute drift and the report from '
                             'DIR)')
    parser.add_argument('--config', '--profile', dest='config', required=True,
                        metavar='FLEET.yaml',
                        help='the fleet configuration: motors: {NAME: {input, speed, '
                             'current, joint, effort_is, resistance, ...}} (docs/fleet.md; '
                             '--profile is its former name)')
    parser.add_argument('--out', required=True, metavar='DIR',
                        help='results: estimates.parquet, estimates.csv, failed.json, '
                             'drift.json, siblings.json, report.html')
    parser.add_argument('--workers', type=int, metavar='N',
                        help='worker processes of the embedded cluster (default: cores)')
    parser.add_argument('--scheduler', metavar='ADDRESS',
                        help='run on an existing Dask scheduler (tcp://host:8786)')
    parser.add_argument('--analyze', action='store_true',
                        help='also run the discrepancy analysis per recording and motor')
    parser.add_argument('--robot-from', default='parent', metavar='RULE',
                        help=f'robot name from the path: {ROBOT_RULES}')
    parser.add_argument('--retry-failed', action='store_true',
                        help='fit again the tasks that failed on their data before')
    parser.add_argument('--quiet', '-q', action='store_true', help='no progress line')


def progress_line(quiet: bool, stream: TextIO | None = None) -> Progress:
    """A progress callback: tasks done / failed / left and the rate, on stderr."""
    stream = stream or sys.stderr
    tty = stream.isatty()
    state = {'start': time.perf_counter(), 'last': 0.0}

    def progress(done: int, failed: int, left: int, result: TaskResult | None) -> None:
        if quiet:
            return
        now = time.perf_counter()
        total = done + failed + left
        finished = left == 0
        if not (tty or finished or result is None or now - state['last'] >= 5.0):
            return
        state['last'] = now
        elapsed = now - state['start']
        width = 30
        filled = int(width * (done + failed) / max(total, 1))
        rate = (done + failed) / elapsed * 60 if elapsed > 0 and done + failed else 0.0
        text = (f'[{"#" * filled}{"." * (width - filled)}] {done} done, {failed} failed, '
                f'{left} left  {rate:.0f}/min  {elapsed:.0f} s')
        stream.write(('\r' + text) if tty else (text + '\n'))
        if tty and finished:
            stream.write('\n')
        stream.flush()
    return progress


def run(args: argparse.Namespace) -> int:
    """Run the fleet, print the drifting motors and where the files are."""
    from motor_id.fleet.run import run_fleet
    config = load_fleet_config(args.config)
    res = run_fleet(args.recordings, config, args.out, workers=args.workers,
                    scheduler=args.scheduler, analyze=args.analyze,
                    robot_from=args.robot_from, retry_failed=args.retry_failed,
                    progress=progress_line(args.quiet))
    if args.recordings:
        print(f'{res.tasks} task(s): {res.done} fitted, {res.failed} failed, '
              f'{res.skipped} already in {args.out}; {res.seconds:.1f} s')
    drifting = res.drifting()
    if drifting:
        print(f'drifting ({len(drifting)}):')
        for d in drifting:
            f = d.finding
            print(f'  {d.robot} {d.motor} {d.parameter}: {(d.change or 0.0) * 100:+.1f} % '
                  f'since {d.since} (z {d.z or 0.0:.1f}; {f.baseline:.4g} -> '
                  f'{f.latest:.4g} {d.unit})')
    else:
        print('no drift detected')
    odd = res.odd()
    if odd:
        print(f"outside their siblings' spread ({len(odd)}):")
        for s in odd:
            g = s.finding
            print(f'  {s.robot} {s.motor} {s.parameter}: {g.level:.4g} {s.unit}, '
                  f"{(g.deviation or 0.0) * 100:+.1f} % from {g.siblings} siblings' "
                  f'{g.reference:.4g} (spread {(g.spread or 0.0) * 100:.1f} %, score '
                  f'{g.score:.1f})')
    for name in ('estimates', 'csv', 'drift', 'siblings', 'report'):
        if name in res.files:
            print(f'wrote {res.files[name]}')
    return 1 if res.failed and not res.done else 0
