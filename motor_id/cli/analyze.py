"""`motor-id analyze`: find what the linear model misses and extend it."""

import argparse
import os
import sys

from motor_id.analysis import DiscrepancyAnalysis, plot_report
from motor_id.analysis.workers import usable_cores
from motor_id.cli.common import add_mechanism_argument, mechanism_for
from motor_id.cli.data_args import add_data_arguments, DATA_HELP, load_runs
from motor_id.errors import ConfigError
from motor_id.identify.settings import require_resistance


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """CLI arguments of `motor-id analyze`."""
    parser.add_argument('data', metavar='DATA', nargs='+',
                        help=DATA_HELP + '; several: separate runs of one motor (the last '
                             'is held out whole)')
    parser.add_argument('--resistance', '-R', type=float, metavar='R',
                        help='armature resistance R_m [Ohm] as measured (voltage plants); '
                             'with current data it is the prior of the estimate; speed-only '
                             'data need none (R_m does not enter)')
    parser.add_argument('--resistance-tolerance', type=float, default=10.0, metavar='PCT',
                        help='how good --resistance is, in %% (default 10)')
    parser.add_argument('--json', metavar='OUT', help='write the report as JSON')
    parser.add_argument('--plot', metavar='OUT.png', help='write the plots')
    parser.add_argument('--seed', type=int, default=0, help='GA seed of the linear fit')
    parser.add_argument('--candidates', metavar='NAMES',
                        help='comma-separated effects to try (default: all that apply)')
    parser.add_argument('--min-gain', type=float, default=0.05,
                        help='smallest held-out gain that counts (default 0.05)')
    parser.add_argument('--jobs', '-j', type=int, metavar='N',
                        help='processes for the candidate fits (default: every usable core; '
                             'the results are the same)')
    parser.add_argument('--quiet', '-q', action='store_true', help='no progress output')
    add_mechanism_argument(parser)
    add_data_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Analyse the recording, print the report, write JSON / plots."""
    rec = load_runs(args)
    cands = None
    if args.candidates:
        cands = [c.strip() for c in args.candidates.split(',') if c.strip()]
    require_resistance(args.resistance, rec.input_kind, rec.has_current)   # before any work

    def progress(msg: str) -> None:
        if not args.quiet:
            print(msg, file=sys.stderr, flush=True)

    progress(f'data: {len(rec)} samples, channels {", ".join(rec.channels())}, '
             f'{rec.input_kind} input, {"regular" if rec.is_regular else "irregular"} '
             f'sampling (median {rec.sample_period * 1e3:.3g} ms)')
    if not 0 < args.resistance_tolerance <= 100:
        raise ConfigError('--resistance-tolerance takes a percentage in (0, 100], got '
                          f'{args.resistance_tolerance:g}')
    if args.jobs is not None and args.jobs < 1:
        raise ConfigError(f'--jobs takes a number of processes >= 1, got {args.jobs}')
    ana = DiscrepancyAnalysis(R_m=args.resistance, candidates=cands, random_state=args.seed,
                              min_gain=args.min_gain,
                              R_m_tolerance=args.resistance_tolerance / 100.0,
                              jobs=args.jobs or usable_cores(),
                              mechanism=mechanism_for(args, rec))
    ana.fit(rec, progress=progress)
    rep = ana.report_
    print(rep.summary())
    if not rep.adequate:
        print(f'motor-id analyze: the model is inadequate for this record: '
              f'{rep.warnings[0]}', file=sys.stderr)
    if args.json:
        from motor_id.output import write_json
        out = rep.to_dict()
        out['data'] = {'source': rec.meta.get('source', str(args.data[0])),
                       'samples': len(rec), 'runs': len(rec.segment_ranges)}
        if 'shift_check' in rec.meta:
            out['data']['shift_check'] = rec.meta['shift_check']
        write_json(out, args.json)
        print(f'wrote {args.json}')
    if args.plot:
        name = ', '.join(os.path.basename(str(p).rstrip(os.sep)) for p in args.data)
        plot_report(rep, args.plot, title=f'motor-id analyze: {name}')
        print(f'wrote {args.plot}')
    return 0
