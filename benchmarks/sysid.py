#!/usr/bin/env python3
"""WPILib SysId's own feedforward fit against motor_id's model on a SysId log (issue 19).

For one SysId log (``sysid_data.json``, or a ``.wpilog`` of a SysId routine: its four
tests, quasistatic ramps and voltage steps, forward and backward) this prints, test by
test, how well each model simulates the measured velocity from the logged voltage alone:
the fit ``100 (1 - ||y - y_sim|| / ||y - mean y||)`` over each test after its first two
samples (the ones that set the initial state of motor_id's model), and the constants kS,
kV, kA of each model in the log's units.

- SysId: the method of WPILib's SysId as it fits these logs (2022-2023: its data
  preparation, then OLS of acceleration on velocity, voltage and sign;
  :mod:`motor_id.testing.sysid_ols`), and the discrete form of SysId 2021
  (``v[k+1] = a v[k] + b V[k] + c sgn(v[k])``). Each simulated as SysId plots it: from
  the test's first velocity, every interval discretised exactly.
- motor_id: ``motor-id analyze LOG --json`` (``--fit-only``: ``motor-id fit LOG
  --effect coulomb_friction --json``) in a child process, then its
  saved model simulated on every test with :func:`motor_id.identify.validation.validate`
  (each test a run from its first samples: the per-test fit % that ``motor-id validate``
  and the analyze report print). Its kS, kV, kA are the report's
  ``controller.feedforward``, the constants the CLI prints (a constant the record does not
  determine is printed as such, with its interval).

Usage::

    python benchmarks/sysid.py [--log PATH] [--json OUT] [--fit-only] [--resistance R]
                               [--joint left|right] [--motor NAME] [--timeout S]
                               [--voltage E --velocity E [--position E] [--state E]
                                [--units UNIT]]

The log defaults to ``../shared/data/sysid/sysid_data.json`` beside the repository; the
script says so and exits with status 2 when it is absent. Progress lines go to stderr, the
tables to stdout.
"""

import argparse
import json
import math
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

from common import render_table
import numpy as np

from motor_id.data.load import load_recording
from motor_id.data.mapping import TopicMapping
from motor_id.data.wpilog import LogEntries
from motor_id.errors import MotorIdError
from motor_id.identify.validation import SavedModel, validate
from motor_id.metrics import normalised_fit
from motor_id.output import to_jsonable
from motor_id.testing.sysid_ols import fit_acceleration, fit_discrete, prepare

REPO = Path(__file__).resolve().parents[1]
DEFAULT_LOG = REPO.parent / 'shared' / 'data' / 'sysid' / 'sysid_data.json'
UNIT_SYMBOLS = {'Meters': 'm', 'Feet': 'ft', 'Inches': 'in', 'Radians': 'rad',
                'Rotations': 'rot', 'Degrees': 'deg'}
ENTRY_FLAGS = ('motor', 'voltage', 'position', 'velocity', 'state', 'units')
"""The .wpilog options passed on to :class:`LogEntries` and to motor-id as they are."""
INIT_SAMPLES = 2
"""Samples at the start of each test left out of every score (motor_id's model sets its
unmeasured current from them)."""


def progress(msg, t0=None):
    """A progress line on stderr (with the seconds since ``t0``)."""
    tail = '' if t0 is None else f' ({time.perf_counter() - t0:.1f} s)'
    print(f'[sysid benchmark] {msg}{tail}', file=sys.stderr, flush=True)


def per_test_fit(rec, simulated):
    """Fit % of a simulated speed per test, after its first :data:`INIT_SAMPLES`."""
    out = {}
    for name, (a, b) in zip(rec.meta['segment_names'], rec.segment_ranges, strict=True):
        y, yh = rec.speed[a + INIT_SAMPLES:b], simulated[a + INIT_SAMPLES:b]
        out[name] = normalised_fit(y, yh) if np.all(np.isfinite(yh)) else math.nan
    return out


def sysid_side(rec):
    """SysId's two fits, their constants and their simulated speed per test."""
    prep = prepare(rec)
    out = {}
    for label, fit in (('SysId', fit_acceleration(prep)),
                       ('SysId 2021 discrete', fit_discrete(prep))):
        sim = np.empty(len(rec))
        for a, b in rec.segment_ranges:
            sim[a:b] = fit.simulate(rec.time[a:b], rec.input[a:b], rec.speed[a])
        out[label] = {'gains': {'kS': fit.kS, 'kV': fit.kV, 'kA': fit.kA},
                           'fit_percent': per_test_fit(rec, sim), 'details': fit.to_dict()}
    return out


def run_motor_id(log, out_json, args):
    """``motor-id analyze`` (or ``fit``) on the log in a child process; its seconds."""
    cmd = [sys.executable, '-m', 'motor_id.cli', 'fit' if args.fit_only else 'analyze',
           str(log), '--json', str(out_json)]
    if args.resistance is not None:
        cmd += ['--resistance', repr(args.resistance)]
    if args.fit_only:
        cmd += ['--effect', 'coulomb_friction', '-q']
    if args.joint:
        cmd += ['--joint', args.joint]
    for flag in ENTRY_FLAGS:
        if getattr(args, flag):
            cmd += [f'--{flag}', getattr(args, flag)]
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get('PYTHONPATH',
                                                                                 ''))
    shown = ' '.join(['motor-id'] + [a if a != str(out_json) else 'OUT.json'
                                     for a in cmd[3:]])
    t0 = time.perf_counter()
    progress(f'running {shown} (its progress below)')
    proc = subprocess.run(cmd, stdout=sys.stderr, stderr=sys.stderr, env=env,
                          timeout=args.timeout, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f'{shown} exited with {proc.returncode}')
    return time.perf_counter() - t0, shown


def report_gains(report):
    """kS, kV, kA as the report gives them (``controller.feedforward``, what the CLI
    prints), and the interval of each one the record does not determine."""
    ff = (report.get('controller') or {}).get('feedforward') or {}
    gains, undetermined = {}, {}
    for k in ('kS', 'kV', 'kA'):
        entry = ff.get(k) or {}
        gains[k] = entry.get('value')
        if gains[k] is None:
            gains[k] = entry.get('particular_value', math.nan)
            undetermined[k] = entry.get('interval')
    return gains, undetermined


def motor_id_side(rec, log, args):
    """motor_id's model: fitted by the CLI, simulated per test by validation (the scores
    that ``motor-id validate`` and the analyze report give each run)."""
    with tempfile.TemporaryDirectory() as tmp:
        out_json = Path(tmp) / 'model.json'
        seconds, command = run_motor_id(log, out_json, args)
        report = json.loads(out_json.read_text())
    model = SavedModel.from_report(report, source=command)
    val = validate(model, rec, INIT_SAMPLES)
    gains, undetermined = report_gains(report)
    return {'command': command, 'seconds': seconds, 'gains': gains,
            'undetermined': undetermined, 'effects': model.effects,
            'parameters': model.parameters,
            'fit_percent': {r.name: r.channels['speed']['fit_percent'] for r in val.runs},
            'fit_percent_all': val.channels['speed']['fit_percent'],
            'report_runs': {r['name']: r['channels']['speed']['fit_percent']
                            for r in report.get('runs') or []},
            'verdict': report.get('verdict')}


def tables(rec, models):
    """The two tables (per-test fit %, constants) as ``(title, columns, rows)``."""
    names = list(models)
    keys = [f'm{k}' for k in range(len(names))]
    fit_cols = [('test', 'test', 's'), ('samples', 'samples', 'd')]
    fit_cols += [(k, n, '.1f') for k, n in zip(keys, names, strict=True)]
    rows = []
    for test, (a, b) in zip(rec.meta['segment_names'], rec.segment_ranges, strict=True):
        row = {'test': test, 'samples': b - a - INIT_SAMPLES}
        row.update({k: models[n]['fit_percent'][test] for k, n in zip(keys, names,
                                                                     strict=True)})
        rows.append(row)
    units = rec.meta['sysid']['units']
    per = rec.meta['sysid']['si_to_units']
    unit = UNIT_SYMBOLS.get(units, units)
    gain_cols = [('model', 'model', 's'), ('kS', 'kS [V]', '.4g'),
                 ('kV', f'kV [V s/{unit}]', '.4g'), ('kA', f'kA [V s^2/{unit}]', '.4g')]
    gain_rows = []
    for n in names:
        row = {'model': n, 'kS': models[n]['gains']['kS'],
               'kV': models[n]['gains']['kV'] / per, 'kA': models[n]['gains']['kA'] / per}
        for k, interval in (models[n].get('undetermined') or {}).items():
            # a constant the record does not determine (the analyze report says so)
            row[k] = 'not determined' + (f' ({interval[0] / (per if k != "kS" else 1):.2g}'
                                         f' .. {interval[1] / (per if k != "kS" else 1):.2g})'
                                         if interval else '')
        gain_rows.append(row)
    return [('simulated velocity: fit % per test, from the logged voltage alone', fit_cols,
             rows),
            (f"feedforward constants in the log's units ({units})", gain_cols, gain_rows)]


def parse(argv):
    """The options."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument('--log', default=str(DEFAULT_LOG), metavar='PATH',
                    help=f'the SysId log (default {DEFAULT_LOG})')
    ap.add_argument('--json', default='sysid_benchmark.json', metavar='OUT',
                    help='where to write the numbers (default sysid_benchmark.json)')
    ap.add_argument('--fit-only', action='store_true',
                    help='motor-id fit (with Coulomb friction) instead of motor-id analyze')
    ap.add_argument('--resistance', type=float, default=None, metavar='R',
                    help='R_m [Ohm] given to motor-id (default none: a speed-only log '
                         'cannot see it, and no output depends on it)')
    ap.add_argument('--joint', choices=('left', 'right'), help='side of a Drivetrain log')
    ap.add_argument('--motor', metavar='NAME', help='.wpilog: the motor, where it has several')
    for flag in ENTRY_FLAGS[1:-1]:
        ap.add_argument(f'--{flag}', metavar='ENTRY',
                        help=f'.wpilog of another logger: the {flag} entry')
    ap.add_argument('--units', metavar='UNIT',
                    help='.wpilog: the position unit where the metadata lacks it')
    ap.add_argument('--timeout', type=float, default=3600.0, metavar='S',
                    help='give up on motor-id after S seconds (default 3600)')
    return ap.parse_args(argv)


def main(argv=None):
    """Run both sides, print the tables, write the JSON."""
    args = parse(argv)
    log = Path(args.log)
    if not log.is_file():
        print(f'{log}: no SysId log there; pass --log PATH', file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    try:
        entries = {k: getattr(args, k) for k in ENTRY_FLAGS if getattr(args, k)}
        rec = load_recording(log, mapping=TopicMapping(joint=args.joint),
                             log_entries=LogEntries(**entries) if entries else None)
    except MotorIdError as exc:
        print(f'sysid benchmark: {exc}', file=sys.stderr)
        return 2
    progress(f'{log.name}: {len(rec)} samples in {len(rec.segment_ranges)} tests', t0)
    models = sysid_side(rec)
    progress('SysId fits done', t0)
    try:
        ours = motor_id_side(rec, log, args)
    except (RuntimeError, subprocess.TimeoutExpired) as exc:
        print(f'sysid benchmark: {exc}', file=sys.stderr)
        return 1
    models['motor_id ' + ('fit' if args.fit_only else 'analyze')] = ours
    progress('motor_id model simulated', t0)
    result = {'log': str(log), 'units': rec.meta['sysid'], 'init_samples': INIT_SAMPLES,
              'seconds': time.perf_counter() - t0, 'models': models}
    for title, cols, rows in tables(rec, models):
        print(f'\n{title}')
        print(render_table(cols, rows))
    print(f'\nmotor_id: {ours["command"]} took {ours["seconds"]:.1f} s')
    with open(args.json, 'w') as fh:
        json.dump(to_jsonable(result), fh, indent=1)
        fh.write('\n')
    print(f'wrote {args.json}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
