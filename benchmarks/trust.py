"""Error bars on real recordings and the analysis' cost relative to a fit (issue 16).

Prints two tables:

1. Repeat-record agreement on the Dunker robot (``../shared/data``): for each motor, the
   identification vs the validation record and the halves of each record, the z-score
   ``(a - b) / sqrt(s_a^2 + s_b^2)`` of J and B with the Gauss-Newton stds and with the
   reported (robust) stds, and the share of pairs within |z| <= 3 (target: >= 80 %).
2. Wall time of ``motor-id analyze`` over ``motor-id fit`` on the same file, each a fresh
   process, median of ``--repeat`` runs, measured in this run (target: <= 5x).

Usage: ``python benchmarks/trust.py [--repeat N] [--quick]``.
"""

import argparse
import math
from pathlib import Path
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from motor_id.data.csv_io import write_csv
from motor_id.data.importers import load_dunker, load_emps
from motor_id.identify import Identifier, uncertainty

DATA = Path(__file__).resolve().parents[2] / 'shared' / 'data'
DUNKER = DATA / 'dunker_gr42x25'


def _fit(rec, robust=True):
    """Fit; with ``robust=False`` report Gauss-Newton stds (the sandwich switched off)."""
    if robust:
        return Identifier(random_state=0).fit(rec).result_
    keep = uncertainty.combine
    uncertainty.combine = lambda gn, rob: gn
    try:
        return Identifier(random_state=0).fit(rec).result_
    finally:
        uncertainty.combine = keep


def _z(a, b, p):
    ea, eb = a.parameters[p], b.parameters[p]
    if ea.value is None or eb.value is None:
        return math.nan
    return (ea.value - eb.value) / math.hypot(ea.std, eb.std)


def agreement():
    """Rows of table 1."""
    rows = []
    for m in (1, 2, 3):
        ident = load_dunker(DUNKER / 'data_for_identification_without_integral.csv', m)
        val = load_dunker(DUNKER / 'validation_data.csv', m)
        pairs = {'ident vs validation': (ident, val)}
        for name, r in (('ident halves', ident), ('validation halves', val)):
            n = len(r)
            pairs[name] = (r.slice(0, n // 2), r.slice(n // 2, n))
        for name, (a, b) in pairs.items():
            fits = {rb: (_fit(a, rb), _fit(b, rb)) for rb in (False, True)}
            for p in ('J', 'B'):
                rows.append((f'motor {m}', name, p, _z(*fits[False], p), _z(*fits[True], p)))
    return rows


def _wall(args, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, '-m', 'motor_id.cli', *args, '-q'], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def cost(repeat, quick):
    """Rows of table 2: (record, fit s, analyze s, ratio)."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        files = {'Dunker motor 1 (2291 samples, jittered)':
                 load_dunker(DUNKER / 'data_for_identification_without_integral.csv', 1)}
        if not quick:
            files['EMPS (24841 samples)'] = load_emps(DATA / 'emps' / 'DATA_EMPS.mat')
        for k, (name, rec) in enumerate(files.items()):
            path = Path(tmp) / f'rec{k}.csv'
            write_csv(rec, path)
            fit = _wall(['fit', str(path)], repeat)
            ana = _wall(['analyze', str(path)], repeat)
            rows.append((name, fit, ana, ana / fit))
    return rows


def main(argv=None):
    """Print both tables."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--repeat', type=int, default=3)
    ap.add_argument('--quick', action='store_true', help='the Dunker record only')
    args = ap.parse_args(argv)
    if not DUNKER.exists():
        print(f'{DUNKER} not present: nothing to measure')
        return 0
    with np.errstate(all='ignore'):
        rows = agreement()
    print('| motor | pair | param | z (Gauss-Newton) | z (reported) |')
    print('|---|---|---|---|---|')
    for m, name, p, zg, zr in rows:
        print(f'| {m} | {name} | {p} | {zg:+.2f} | {zr:+.2f} |')
    zg = np.abs([r[3] for r in rows])
    zr = np.abs([r[4] for r in rows])
    print(f'\nwithin |z| <= 3: Gauss-Newton {np.mean(zg <= 3):.0%}, reported '
          f'{np.mean(zr <= 3):.0%} of {len(rows)} pairs (target >= 80 %); median |z| '
          f'{np.median(zg):.2f} -> {np.median(zr):.2f}\n')
    print('| record | fit [s] | analyze [s] | analyze / fit |')
    print('|---|---|---|---|')
    for name, f, a, r in cost(args.repeat, args.quick):
        print(f'| {name} | {f:.2f} | {a:.2f} | {r:.1f}x |')
    print('(target: analyze <= 5x fit; wall times of fresh processes, medians)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
