"""`motor-id fit`: identify motor parameters from a CSV or MCAP recording."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping
import math
import os
import sys
import time
from typing import Any, TextIO, TYPE_CHECKING

import yaml

from motor_id import pipeline
from motor_id.cli.common import add_mechanism_argument, mechanism_for
from motor_id.cli.data_args import add_data_arguments, DATA_HELP, load_runs
from motor_id.effects import EFFECTS, parse_effect_args, role_params
from motor_id.errors import ConfigError
from motor_id.identify import FitSettings, Identifier, METHODS, parse_bounds, parse_fixed
from motor_id.output import plot_fit, write_json
from motor_id.simulate import warm_up

if TYPE_CHECKING:
    from motor_id.elman import FreeElmanOrderSelection
    from motor_id.identify import IdentificationResult
    from motor_id.recording import Recording

STATIC_FRICTION = next(spec.name for spec, _ in role_params('kS', 'torque'))
"""The dry-friction effect a SysId log is fitted with by default (the catalogue's first
whose parameter is the feedforward's kS as a torque: Coulomb friction)."""


def add_fit_arguments(parser: argparse.ArgumentParser) -> None:
    """Options shared by `fit` and `replay --offline`."""
    parser.add_argument('--resistance', '-R', type=float, metavar='R',
                        help='armature resistance R_m [Ohm] as measured (an ohmmeter '
                             'reading); with current data it is the prior of the estimate; '
                             'speed-only voltage data need none (R_m does not enter)')
    parser.add_argument('--resistance-tolerance', type=float, default=10.0, metavar='PCT',
                        help='how good --resistance is, in %% (the std of its Gaussian '
                             'prior; default 10)')
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
                        help='a known parameter value (an explicit extra assumption); '
                             '--fix R_m=R holds R_m fixed')
    parser.add_argument('--bounds', action='append', default=[], metavar='NAME=LO:HI',
                        help='search range of a parameter')
    parser.add_argument('--effect', action='append', default=[], metavar='NAME[=VALUE]',
                        help='add an effect term to the model and estimate its parameters '
                             f'(VALUE: the start); one of {", ".join(sorted(EFFECTS))}; '
                             'none: the linear model alone (a SysId log is fitted with '
                             f'{STATIC_FRICTION} unless --effect says otherwise)')
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
    parser.add_argument('--current-bandwidth', type=float, metavar='HZ',
                        help='current-loop crossover of the controller design [Hz]')
    parser.add_argument('--speed-bandwidth', type=float, metavar='HZ',
                        help='speed-loop crossover of the controller design [Hz]')
    parser.add_argument('--json', metavar='OUT', help='write the report as JSON')
    parser.add_argument('--yaml', metavar='OUT',
                        help='write the estimates and controller gains as a ROS 2 '
                             'parameters file (ros__parameters)')
    parser.add_argument('--plot', metavar='OUT.png', help='write plots')
    parser.add_argument('--quiet', '-q', action='store_true', help='no progress output')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """CLI arguments of `motor-id fit`."""
    parser.add_argument('data', metavar='DATA', nargs='+',
                        help=DATA_HELP + '; several: separate runs of one motor, fitted '
                             'together (shared parameters, an initial state per run)')
    add_fit_arguments(parser)
    add_mechanism_argument(parser)
    add_data_arguments(parser)


def progress_printer(quiet: bool, stream: TextIO | None = None
                     ) -> Callable[[int, int, float], bool]:
    """A GA progress callback that rewrites one status line on stderr."""
    stream = stream or sys.stderr
    start = time.perf_counter()

    def progress(gen: int, gens: int, best: float) -> bool:
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


def fit_settings(rec: Recording, args: argparse.Namespace) -> FitSettings:
    """The :class:`FitSettings` the options ask for (checked before any work)."""
    fixed = parse_fixed(args.fix, '--fix')
    tol = getattr(args, 'resistance_tolerance', 10.0)
    if not (math.isfinite(tol) and tol > 0):
        raise ConfigError(f'--resistance-tolerance must be a percentage > 0, got {tol}')
    for opt in ('current_bandwidth', 'speed_bandwidth'):
        hz = getattr(args, opt, None)
        if hz is not None and not (math.isfinite(hz) and hz > 0):
            raise ConfigError(f'--{opt.replace("_", "-")} must be a frequency > 0 Hz, '
                              f'got {hz}')
    effects = model_effects(rec, getattr(args, 'effect', []))
    # a parameter a least-squares refinement cannot move (a whole number of samples, a
    # grid step) is kept at the value given
    free = [f'{e}.{p.name}' for e in effects for p in EFFECTS[e].params if p.refined]
    settings = FitSettings(
        method=args.method, R_m=fixed.get('R_m', args.resistance), R_m_tolerance=tol / 100.0,
        tie=args.tie,
        population=args.population, generations=args.generations,
        crossover=args.crossover, mutation=args.mutation, random_state=args.seed,
        fixed=fixed or None,
        bounds=parse_bounds(args.bounds, '--bounds') or None, bootstrap=args.bootstrap,
        effects=effects or None, free_effects=free or None)
    settings.check_resistance(rec.input_kind, rec.has_current)
    return settings


def model_effects(rec: Recording, items: list[str]) -> dict[str, dict[str, float]]:
    """The effects of ``--effect`` (``none``: the linear model alone); on a SysId log
    given none, Coulomb friction: a SysId routine measures static friction, and its kS is
    part of the feedforward the log is for (without it kV and kA take up the friction)."""
    if [i.strip().lower() for i in items] == ['none']:
        return {}
    if not items and rec.meta.get('sysid') and rec.input_kind == 'voltage':
        return {STATIC_FRICTION: {}}
    return parse_effect_args(items)


def controller_options(args: argparse.Namespace, input_kind: str) -> dict[str, float]:
    """The controller design's loop bandwidths the options ask for."""
    kw: dict[str, float] = {}
    if getattr(args, 'current_bandwidth', None) is not None and input_kind == 'voltage':
        kw['current_bandwidth_hz'] = args.current_bandwidth
    if getattr(args, 'speed_bandwidth', None) is not None:
        kw['speed_bandwidth_hz'] = args.speed_bandwidth
    return kw


def write_yaml(data: Any, path: str) -> None:
    """Write ``data`` with PyYAML's safe_dump."""
    try:
        with open(path, 'w') as fh:
            yaml.safe_dump(data, fh, default_flow_style=False, sort_keys=False)
    except OSError as exc:
        raise ConfigError(f'{path}: cannot write ({exc.strerror})') from None


def _order_selection(rec: Recording, args: argparse.Namespace) -> FreeElmanOrderSelection:
    """The free Elman net's order selection on the speed, printed."""
    from motor_id.elman import FreeElmanOrderSelection
    sel = FreeElmanOrderSelection(random_state=args.seed).fit(rec.input, rec.speed)
    print('minimum linear Elman order (speed): ' + str(sel.order_))
    for e in sel.evidence_:
        print(f'  order {e.order}: train RMS {e.train_rmse:.4g}  held-out RMS '
              f'{e.validation_rmse:.4g}  AIC {e.aic:.1f}  BIC {e.bic:.1f}')
    return sel


def identify_and_report(rec: Recording, args: argparse.Namespace,
                        extra: Mapping[str, Any] | None = None
                        ) -> tuple[IdentificationResult, dict[str, Any]]:
    """Run the identification on a recording and print / write what the options ask."""
    est = Identifier(fit_settings(rec, args))
    effects = est.settings.effects
    if not args.quiet and effects and not getattr(args, 'effect', []):
        print(f'model: linear + {", ".join(effects)} (a SysId log measures static '
              'friction: its kS is part of the feedforward; --effect none fits the linear '
              'model alone)', file=sys.stderr)
    if not args.quiet:
        print(f'data: {len(rec)} samples, channels {", ".join(rec.channels())}, '
              f'{"regular" if rec.is_regular else "irregular"} sampling '
              f'(median {rec.sample_period * 1e3:.3g} ms)', file=sys.stderr)
    fit = pipeline.fit_report(rec, est, progress=progress_printer(args.quiet),
                            controller_options=controller_options(args, rec.input_kind),
                            extra=extra, mechanism=mechanism_for(args, rec))
    res = fit.result
    if not fit.adequate:
        print(f'motor-id fit: the model is inadequate for this record: {res.warnings[0]}',
              file=sys.stderr)
    print(fit.summary())
    report = fit.to_dict()
    if getattr(args, 'order_selection', False):
        report['order_selection'] = _order_selection(rec, args).to_dict()
    if args.json:
        write_json(report, args.json)
        print(f'wrote {args.json}')
    if getattr(args, 'yaml', None):
        write_yaml(fit.to_ros_parameters(), args.yaml)
        print(f'wrote {args.yaml}')
    if args.plot:
        names = ', '.join(os.path.basename(str(p)) for p in _paths(args.data))
        plot_fit(res, args.plot, title=f'motor_id fit: {names}', linear=rec.linear)
        print(f'wrote {args.plot}')
    return res, report


def _paths(data: str | list[str] | tuple[str, ...]) -> list[str] | tuple[str, ...]:
    return data if isinstance(data, (list, tuple)) else [data]


def run(args: argparse.Namespace) -> int:
    """Read the data, fit, print the table, write JSON / plots."""
    warm_up()   # load (or compile once) the simulation kernels before the GA's clock starts
    rec = load_runs(args)
    extra = {'shift_check': rec.meta['shift_check']} if 'shift_check' in rec.meta else None
    identify_and_report(rec, args, extra=extra)
    return 0
