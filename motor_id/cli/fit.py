"""`motor-id fit`: identify motor parameters from a CSV or MCAP recording."""

import os
import sys
import time

from motor_id.data.load import load_recording
from motor_id.errors import ConfigError
from motor_id.identify import Identifier, METHODS, parse_bounds, parse_fixed
from motor_id.report import plot_fit, write_json


def add_fit_arguments(parser):
    """Options shared by `fit` and `replay --offline`."""
    parser.add_argument('--resistance', '-R', type=float, metavar='R',
                        help='known armature resistance R_m [Ohm] (voltage plants)')
    parser.add_argument('--method', choices=METHODS, default='zoh',
                        help='zoh: exact ZOH + GA + least squares (recommended); '
                             'euler: same with Euler discretisation; '
                             'paper: Euler, GA only, speed only (as published)')
    tie = parser.add_mutually_exclusive_group()
    tie.add_argument('--no-tie', dest='tie', action='store_false', default=None,
                     help='do not impose K_T = K_b')
    tie.add_argument('--tie', dest='tie', action='store_true',
                     help='impose K_T = K_b (default when current is measured)')
    parser.add_argument('--fix', action='append', default=[], metavar='NAME=VALUE',
                        help='a known parameter value (an explicit extra assumption)')
    parser.add_argument('--bounds', action='append', default=[], metavar='NAME=LO:HI',
                        help='search range of a parameter')
    parser.add_argument('--seed', type=int, default=0, help='GA random seed')
    parser.add_argument('--population', type=int, default=20)
    parser.add_argument('--generations', type=int, default=160)
    parser.add_argument('--crossover', type=float, default=0.75)
    parser.add_argument('--mutation', type=float, default=0.04)
    parser.add_argument('--bootstrap', type=int, default=0, metavar='N',
                        help='residual-bootstrap refits for 95 %% intervals')
    parser.add_argument('--order-selection', action='store_true',
                        help='also fit free linear Elman nets of order 1..4 (speed) and '
                             'report the minimum order that explains the data')
    parser.add_argument('--json', metavar='OUT', help='write the report as JSON')
    parser.add_argument('--plot', metavar='OUT.png', help='write plots')
    parser.add_argument('--quiet', '-q', action='store_true', help='no progress output')


def add_arguments(parser):
    """CLI arguments of `motor-id fit`."""
    parser.add_argument('data', metavar='DATA', help='CSV (time,voltage,speed[,current]) '
                                                     'or MCAP bag')
    add_fit_arguments(parser)


def progress_printer(quiet, stream=None):
    """A GA progress callback that rewrites one status line on stderr."""
    stream = stream or sys.stderr
    start = time.perf_counter()

    def progress(gen, gens, best):
        if quiet:
            return False
        if gen == 1 or gen % 10 == 0 or gen == gens:
            width = 30
            done = int(width * gen / gens)
            stream.write(f'\rGA [{"#" * done}{"." * (width - done)}] {gen}/{gens} '
                         f'best cost {best:.3e}  {time.perf_counter() - start:.2f} s')
            if gen == gens:
                stream.write('\n')
            stream.flush()
        return False
    return progress


def identify_and_report(rec, args, extra=None):
    """Run the identification on a recording and print / write what the options ask."""
    fixed = parse_fixed(args.fix, '--fix')
    r_m = args.resistance
    if 'R_m' in fixed:
        r_m = fixed.pop('R_m')
    if rec.input_kind == 'voltage' and r_m is None:
        raise ConfigError('--resistance R (the known armature resistance in Ohm) is required '
                          'for voltage-input data')
    est = Identifier(method=args.method, R_m=r_m, tie=args.tie, population=args.population,
                     generations=args.generations, crossover=args.crossover,
                     mutation=args.mutation, random_state=args.seed, fixed=fixed or None,
                     bounds=parse_bounds(args.bounds) or None, bootstrap=args.bootstrap)
    if not args.quiet:
        print(f'data: {len(rec)} samples, channels {", ".join(rec.channels())}, '
              f'{"regular" if rec.is_regular else "irregular"} sampling '
              f'(median {rec.sample_period * 1e3:.3g} ms)', file=sys.stderr)
    est.fit(rec, progress=progress_printer(args.quiet))
    res = est.result_
    report = res.to_dict()
    report['data'] = {'source': rec.meta.get('source'), 'samples': len(rec),
                      'sample_period': rec.sample_period, 'regular': rec.is_regular,
                      'channels': list(rec.channels()), 'input_kind': rec.input_kind}
    if extra:
        report.update(extra)
    print(res.summary())
    if getattr(args, 'order_selection', False):
        from motor_id.elman import FreeElmanOrderSelection
        sel = FreeElmanOrderSelection(random_state=args.seed).fit(rec.input, rec.speed)
        report['order_selection'] = sel.to_dict()
        print('minimum linear Elman order (speed): ' + str(sel.order_))
        for e in sel.evidence_:
            print(f'  order {e.order}: train RMS {e.train_rmse:.4g}  held-out RMS '
                  f'{e.validation_rmse:.4g}  AIC {e.aic:.1f}  BIC {e.bic:.1f}')
    if args.json:
        write_json(report, args.json)
        print(f'wrote {args.json}')
    if args.plot:
        plot_fit(res, args.plot, title=f'motor_id fit: {os.path.basename(str(args.data))}')
        print(f'wrote {args.plot}')
    return res, report


def run(args):
    """Read the data, fit, print the table, write JSON / plots."""
    rec = load_recording(args.data)
    identify_and_report(rec, args)
    return 0
