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

The test record is not in ``../shared/data`` today; pass it with ``--test PATH`` or put
it at ``../shared/data/emps/DATA_EMPS_PULSES.mat``. Without it the script still runs the
same protocol on a split of the training record (train on its first 60 %, test on the
last 40 %), labelled as such: that is no benchmark figure.

Usage: ``python benchmarks/emps.py [--test PATH] [--json OUT]``.
"""

import argparse
import json
from pathlib import Path
import sys
import time

import numpy as np

from motor_id.analysis import DiscrepancyAnalysis
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


def run_protocol(train_rec: Recording, tests: dict[str, Recording]) -> dict:
    """Train on ``train_rec``; score every model on every record of ``tests``."""
    rep, sim, eq, seconds = train(train_rec)
    rows = []
    for model in (sim, eq, REFERENCE):
        row = {'model': model.source, 'effects': sorted(model.effects),
               'parameters': model.parameters,
               'effect_parameters': model.effects,
               'rmse_mm': {name: score(model, r) for name, r in tests.items()}}
        rows.append(row)
    return {'train_samples': len(train_rec), 'analysis_seconds': seconds,
            'chosen': (rep.get('simulation') or {}).get('chosen'),
            'friction': (rep.get('simulation') or {}).get('friction'), 'rows': rows}


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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--train', default=str(TRAIN), help='DATA_EMPS.mat')
    ap.add_argument('--test', default=str(TEST), help='DATA_EMPS_PULSES.mat')
    ap.add_argument('--json', help='write the results as JSON')
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
        res = run_protocol(full, {'test': load_emps(args.test), 'train': full})
        out['benchmark'] = res
        _table('EMPS benchmark: RMSE of qm, test record DATA_EMPS_PULSES.mat', res,
               ['test', 'train'])
        print('  published:')
        for name, v in PUBLISHED:
            print(f'  {name:<62}{v:>13.3f} mm')
    else:
        print(f'\nthe test record {args.test} is missing: no benchmark figure (put '
              'DATA_EMPS_PULSES.mat there or pass --test PATH)')
    split = int(0.6 * len(full))
    _say('split: training on the first 60 % of DATA_EMPS.mat, testing on the last 40 %')
    res = run_protocol(full.slice(0, split), {'last 40 %': full.slice(split, None),
                                              'first 60 %': full.slice(0, split)})
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
