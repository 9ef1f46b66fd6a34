"""`motor-id analyze`: find what the linear model misses and extend it."""

import os
import sys

from motor_id.data.load import load_recording
from motor_id.analysis import DiscrepancyAnalysis, plot_report
from motor_id.errors import ConfigError

def add_arguments(parser):
    """CLI arguments of `motor-id analyze`."""
    parser.add_argument('data', metavar='DATA', help='CSV (time,voltage,speed[,current]) '
                                                     'or MCAP bag')
    parser.add_argument('--resistance', '-R', type=float, metavar='R',
                        help='known armature resistance R_m [Ohm] (voltage plants)')
    parser.add_argument('--json', metavar='OUT', help='write the report as JSON')
    parser.add_argument('--plot', metavar='OUT.png', help='write the plots')
    parser.add_argument('--seed', type=int, default=0, help='GA seed of the linear fit')
    parser.add_argument('--candidates', metavar='NAMES',
                        help='comma-separated effects to try (default: all that apply)')
    parser.add_argument('--min-gain', type=float, default=0.05,
                        help='smallest held-out gain that counts (default 0.05)')
    parser.add_argument('--quiet', '-q', action='store_true', help='no progress output')


def run(args):
    """Analyse the recording, print the report, write JSON / plots."""
    rec = load_recording(args.data)
    cands = None
    if args.candidates:
        cands = [c.strip() for c in args.candidates.split(',') if c.strip()]
    if rec.input_kind == 'voltage' and args.resistance is None:
        raise ConfigError('--resistance R (the known armature resistance in Ohm) is required '
                          'for voltage-input data')

    def progress(msg):
        if not args.quiet:
            print(msg, file=sys.stderr, flush=True)

    progress(f'data: {len(rec)} samples, channels {", ".join(rec.channels())}, '
             f'{rec.input_kind} input, {"regular" if rec.is_regular else "irregular"} '
             f'sampling (median {rec.sample_period * 1e3:.3g} ms)')
    ana = DiscrepancyAnalysis(R_m=args.resistance, candidates=cands, random_state=args.seed,
                              min_gain=args.min_gain)
    ana.fit(rec, progress=progress)
    rep = ana.report_
    print(rep.summary())
    if args.json:
        from motor_id.report import write_json
        out = rep.to_dict()
        out['data'] = {'source': rec.meta.get('source', str(args.data)), 'samples': len(rec)}
        write_json(out, args.json)
        print(f'wrote {args.json}')
    if args.plot:
        plot_report(rep, args.plot, title=f'motor-id analyze: {os.path.basename(args.data)}')
        print(f'wrote {args.plot}')
    return 0
