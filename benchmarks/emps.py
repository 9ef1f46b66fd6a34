"""The EMPS nonlinear benchmark by its own protocol (issue 19).

Protocol (Janot, Gautier, Brunot 2019, Workshop on Nonlinear System Identification
Benchmarks): train on ``DATA_EMPS.mat`` only; on the test record ``DATA_EMPS_PULSES.mat``
simulate the load position ``qm`` from the input ``vir`` alone, the first 20 samples
available to set the initial state, and report the RMSE of ``qm`` in millimetres over
the remaining samples.

This script trains ``motor-id analyze`` (the library behind it) on the training record,
then scores three models with ``motor-id validate --init-samples 20`` (the library
behind it):

- the project's model fitted by simulation error (``simulation.model`` of the report);
- the project's equation-error model (the inverse dynamics of the closed-loop record,
  which the analysis starts from);
- the benchmark's published reference model (inverse dynamics, least squares).

The test record is not in ``../shared/data`` today (it comes with the benchmark's own
download, ``EMPS.zip`` of the Nonlinear System Identification Benchmarks); pass it with
``--test PATH`` or put it at ``../shared/data/emps/DATA_EMPS_PULSES.mat``. Without it the
script still runs the same protocol on a split of the training record (train on its first
60 %, test on the last 40 %), labelled as such: that is no benchmark figure.

After the scores, and deciding nothing about the model, two diagnostics:

- ``record shift`` (with the test record): the same inverse dynamics fitted on each
  record alone, the friction force each gives at the trajectory's speeds, and what each
  record's own inverse-dynamics model scores on the test record. It shows what limits any
  model trained on the training record alone: the axis' friction differs between the two
  experiments.
- ``--spread``: the simulation-error stage with other block counts (the record cut into
  3 to 12 blocks instead of 6), each trained on the training record alone: how much the
  figure depends on that setting.

Usage: ``python benchmarks/emps.py [--test PATH] [--spread] [--json OUT]``.
"""

import argparse
import json
import math
from pathlib import Path
import sys
import time

import numpy as np

from motor_id.analysis import DiscrepancyAnalysis
from motor_id.analysis.inverse_dynamics import inverse_dynamics
from motor_id.analysis.simulation_fit import simulation_stage
from motor_id.data.importers import load_emps
from motor_id.identify.validation import SavedModel, validate
from motor_id.recording import Recording

DATA = Path(__file__).resolve().parents[2] / 'shared' / 'data' / 'emps'
TRAIN = DATA / 'DATA_EMPS.mat'
TEST = DATA / 'DATA_EMPS_PULSES.mat'
INIT = 20
PUBLISHED = [
    ('CT-SUBNET (Beintema et al., continuous-time subspace encoder)', 4.61),
]
"""Published test RMSE [mm] on DATA_EMPS_PULSES.mat."""
REFERENCE = SavedModel('torque', {'J': 95.1089, 'B': 203.5034},
                       {'coulomb_friction': {'T_c': 20.3935},
                        'load_torque': {'T_L': -3.1648}}, 'published reference model')
"""The benchmark's reference model: M qdd + Fv qd + Fc sign(qd) + OF = gtau vir."""


def _say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def train(rec: Recording) -> tuple[dict, SavedModel, SavedModel, float]:
    """Analyse ``rec``: (report, simulation-error model, equation-error model, seconds)."""
    t0 = time.perf_counter()
    rep = DiscrepancyAnalysis(init_samples=INIT).fit(rec, progress=_say).report_.to_dict()
    seconds = time.perf_counter() - t0
    return (rep, SavedModel.from_report(rep, 'simulation error'),
            SavedModel.from_report(rep, 'equation error', use_simulation=False), seconds)


def score(model: SavedModel, rec: Recording) -> float:
    """Test RMSE of qm [mm] by the protocol."""
    return 1e3 * validate(model, rec, INIT).channels['position']['rmse']


SHIFT_SPEEDS = (-0.1, -0.05, 0.05, 0.1)
"""Speeds [m/s] at which :func:`record_shift` compares the friction force of the records
(the trajectory's plateaus lie between 0.04 and 0.13 m/s each way)."""
SPREAD_BLOCKS = (3, 4, 6, 9, 12)
"""Block counts of :func:`block_spread` (the stage's default is 6)."""


def inverse_dynamics_model(rec: Recording) -> SavedModel:
    """The reference model's structure fitted by inverse dynamics on ``rec`` alone."""
    p = {k: v.value for k, v in inverse_dynamics(
        rec, ('coulomb_friction', 'load_torque')).parameters.items()}
    return SavedModel('torque', {'J': p['J'], 'B': p['B']},
                      {'coulomb_friction': {'T_c': p['coulomb_friction.T_c']},
                       'load_torque': {'T_L': p['load_torque.T_L']}},
                      f'inverse dynamics of {rec.meta.get("source", "the record")}')


def friction_force(model: SavedModel, v: float) -> float:
    """The force [N] ``model`` needs to hold the speed ``v`` [m/s] (friction and load)."""
    e = model.effects
    return (model.parameters['B'] * v + math.copysign(e['coulomb_friction']['T_c'], v)
            + e['load_torque']['T_L'])


def record_shift(train_rec: Recording, test_rec: Recording) -> dict:
    """The same inverse dynamics on each record: friction force at :data:`SHIFT_SPEEDS`
    and each record's model scored on the test record (a diagnostic, never a score: the
    protocol forbids fitting on the test record)."""
    models = {'train': inverse_dynamics_model(train_rec),
              'test': inverse_dynamics_model(test_rec)}
    return {'force_n': {name: {f'{v:+.2f}': friction_force(m, v) for v in SHIFT_SPEEDS}
                        for name, m in models.items()},
            'mass_kg': {name: m.parameters['J'] for name, m in models.items()},
            'test_rmse_mm': {name: score(m, test_rec) for name, m in models.items()}}


def block_spread(train_rec: Recording, report: dict, tests: dict[str, Recording]) -> list:
    """The simulation-error stage from the report's equation-error model with each
    block count of :data:`SPREAD_BLOCKS`, trained on ``train_rec`` alone; each chosen
    model scored on ``tests``."""
    start = SavedModel.from_report(report, 'equation error', use_simulation=False)
    rows = []
    for n in SPREAD_BLOCKS:
        _say(f'spread: the simulation-error stage on {n} blocks')
        sim = simulation_stage(train_rec, start, INIT, n_blocks=n, halves=False)
        model = SavedModel.from_report({'parameters': {}, 'simulation': sim})
        rows.append({'blocks': n, 'chosen': sim['chosen'],
                     'rmse_mm': {name: score(model, r) for name, r in tests.items()}})
    return rows


def run_protocol(train_rec: Recording, tests: dict[str, Recording], spread: bool = False
                 ) -> dict:
    """Train on ``train_rec``; score every model on every record of ``tests``."""
    rep, sim, eq, seconds = train(train_rec)
    rows = []
    for model in (sim, eq, REFERENCE):
        row = {'model': model.source, 'effects': sorted(model.effects),
               'parameters': model.parameters,
               'effect_parameters': model.effects,
               'rmse_mm': {name: score(model, r) for name, r in tests.items()}}
        rows.append(row)
    out = {'train_samples': len(train_rec), 'analysis_seconds': seconds,
           'chosen': (rep.get('simulation') or {}).get('chosen'),
           'friction': (rep.get('simulation') or {}).get('friction'), 'rows': rows}
    if spread:
        out['spread'] = block_spread(train_rec, rep, tests)
    return out


def _table(title: str, result: dict, columns: list[str]) -> None:
    print(f'\n{title}')
    print(f'  trained on {result["train_samples"]} samples in '
          f'{result["analysis_seconds"]:.1f} s; simulation-error model: {result["chosen"]}')
    if result.get('friction'):
        print('  friction by direction: ' + ', '.join(
            f'{k} {v:.4g}' for k, v in result['friction'].items()))
    head = f'  {"model":<62}' + ''.join(f'{c:>16}' for c in columns)
    print(head)
    for row in result['rows']:
        print(f'  {row["model"]:<62}' + ''.join(f'{row["rmse_mm"][c]:>13.3f} mm'
                                                for c in columns))
    if result.get('spread'):
        print('  the simulation-error stage with other block counts (trained alike):')
        for row in result['spread']:
            label = f'{row["blocks"]:>2} blocks: {row["chosen"]}'
            print(f'    {label:<60}' + ''.join(f'{row["rmse_mm"][c]:>13.3f} mm'
                                              for c in columns))
        vals = [row['rmse_mm'][columns[0]] for row in result['spread']]
        print(f'    {columns[0]}: {min(vals):.2f} to {max(vals):.2f} mm, median '
              f'{float(np.median(vals)):.2f} mm')


def _shift_table(shift: dict) -> None:
    print('\nrecord shift (diagnostic, decides nothing): the inverse dynamics of each record '
          'alone')
    print(f'  {"record":<8}{"M [kg]":>10}' + ''.join(f'{"F(" + k + " m/s)":>16}'
                                                   for k in shift['force_n']['train'])
          + f'{"its model on the test":>24}')
    for name in ('train', 'test'):
        print(f'  {name:<8}{shift["mass_kg"][name]:>10.2f}'
              + ''.join(f'{f:>14.2f} N' for f in shift['force_n'][name].values())
              + f'{shift["test_rmse_mm"][name]:>21.2f} mm')
    d = [shift['force_n']['test'][k] - shift['force_n']['train'][k]
         for k in shift['force_n']['train']]
    print('  the test record needs ' + ', '.join(f'{x:+.2f} N' for x in d) + ' more force '
          'at the same speeds: friction the training record cannot show')


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--train', default=str(TRAIN), help='DATA_EMPS.mat')
    ap.add_argument('--test', default=str(TEST), help='DATA_EMPS_PULSES.mat')
    ap.add_argument('--json', help='write the results as JSON')
    ap.add_argument('--spread', action='store_true',
                    help='also run the simulation-error stage with other block counts')
    args = ap.parse_args(argv)
    if not Path(args.train).exists():
        print(f'benchmarks/emps.py: the training record {args.train} is missing',
              file=sys.stderr)
        return 2
    full = load_emps(args.train)
    out: dict = {'protocol': f'simulate qm from vir alone; the first {INIT} samples set the '
                 'initial state; RMSE of qm over the remaining samples',
                 'published_test_rmse_mm': dict(PUBLISHED)}
    if Path(args.test).exists():
        _say('benchmark: training on DATA_EMPS.mat, testing on DATA_EMPS_PULSES.mat')
        test = load_emps(args.test)
        res = run_protocol(full, {'test': test, 'train': full}, args.spread)
        out['benchmark'] = res
        _table('EMPS benchmark: RMSE of qm, test record DATA_EMPS_PULSES.mat', res,
               ['test', 'train'])
        print('  published:')
        for name, v in PUBLISHED:
            print(f'  {name:<62}{v:>13.3f} mm')
        out['record_shift'] = record_shift(full, test)
        _shift_table(out['record_shift'])
    else:
        print(f'\nthe test record {args.test} is missing: no benchmark figure (put '
              'DATA_EMPS_PULSES.mat there or pass --test PATH)')
    split = int(0.6 * len(full))
    _say('split: training on the first 60 % of DATA_EMPS.mat, testing on the last 40 %')
    res = run_protocol(full.slice(0, split), {'last 40 %': full.slice(split, None),
                                              'first 60 %': full.slice(0, split)},
                       args.spread)
    out['split'] = res
    _table('the same protocol on a split of DATA_EMPS.mat (train: first 60 %; NOT the '
           "benchmark's test record)", res, ['last 40 %', 'first 60 %'])
    if args.json:
        with open(args.json, 'w') as fh:
            json.dump(out, fh, indent=2, default=lambda o: np.asarray(o).tolist())
        print(f'wrote {args.json}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
