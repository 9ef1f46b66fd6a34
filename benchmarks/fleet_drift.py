"""Fleet drift: recordings to detect a change by size and position, dating, false alarms per
motor-year, on histories from the fleet generator (no bags: the generator's true
parameters per day plus each parameter's fit error).

    .venv/bin/python benchmarks/fleet_drift.py [--quick] [--motor-years N] [--reps N]
                                               [--json OUT]

Histories come from :func:`motor_id.testing.fleet_gen.motor_truths` (wheel motors with a
5 % unit spread; day to day the ambient temperature, uniform +-5 K per robot and day,
moves R_m +-2 %, K_T +-0.6 %, B +-5 %, plus a small jitter per parameter) with each
estimate off by its fit error (the median relative standard error of the end-to-end
fleet run, benchmarks/fleet.py: ``FIT_ERROR``) and carrying it as its error bar. Every
motor is tested as ``motor-id fleet`` tests it: at each recording, on the data known
then, with the day-to-day scatter pooled over its siblings (the same wheel on the other
robots of its fleet).

1. **Detection.** A change at every position of a 30-recording history (the 2nd
   recording on), per kind and size; the drifting motor has 3 clean siblings (a 4-robot
   fleet) or 7 (an 8-robot fleet), one per robot. Per cell: the median number of recordings
   from the onset to the first flag (the onset recording counting 1), the share flagged
   by the 30th recording, and the share dated right on the whole history (steps: within
   one recording of the onset; ramps: -1..+4); and a new robot commissioned among 3
   siblings with ``JOINED`` days of history (the scatter known from its first day).
   The share of changes at the 2nd recording flagged by the 10th and the 30th.
2. **Operator fleets**, changes not planted by hand: fleets of 4 robots x 2 wheels x
   10-12 days with 3 drifts drawn by ``random_drifts`` (on the 2nd to the 7th
   recording) from a seed drawn afresh at each run (``--seed`` repeats one), through
   ``fleet_findings`` as ``motor-id fleet`` runs it.
3. **False alarms.** Clean fleets of 4 robots x 2 wheels, a year of daily recordings;
   a motor-year is a false alarm when any of its parameters (J, K_T, B, L_m, R_m; K_b is
   K_T's twin) is flagged at any recording of the year. Siblings by name (3 each), by one
   ``type:`` (7 each; a robot's two wheels share its temperature, so their differences
   are not independent), and single motors with no siblings (the identifier node's live
   history).
"""

import argparse
import json
import secrets
import sys
import time

import numpy as np

TITLE = 'Fleet drift: detection by size and position, false alarms per motor-year'
FIT_ERROR = {'J': 3.6e-4, 'K_T': 1.5e-4, 'B': 2.4e-3, 'L_m': 1.2e-3, 'R_m': 2.6e-4}
"""Median relative standard error of each parameter in the end-to-end fleet run (160
fits of 20 s generated recordings)."""
KINDS = (('R_m', 0.05, 'step'), ('R_m', 0.08, 'step'), ('R_m', 0.12, 'step'),
         ('K_T', -0.05, 'step'), ('R_m', 0.12, 'ramp'), ('B', 0.60, 'ramp'))
POSITIONS = (1, 2, 3, 4, 6, 8, 12, 18, 25)
DAYS = 30
JOINED = 60
"""Days of the siblings' histories before a new robot's first recording."""


def _history(rule, truths, parameter, rng, first=0):
    """A prepared history (motor_id.fleet.drift.Series) of one motor's parameter, from
    day ``first`` on."""
    from motor_id.fleet.drift import series
    x = np.array([getattr(m, parameter) for m in truths])[first:]
    s = FIT_ERROR[parameter]
    x = x * (1 + rng.normal(0, s, x.size))
    days = [f'{d:04d}' for d in range(first, first + x.size)]
    return series(days, x, x * s)


def detection(rule, reps, siblings, seed=1, joined=0, kinds=KINDS):
    """Rows of the detection table: one per kind, a cell per onset position (the
    drifting motor's robot ``joined`` days after its siblings' first recording)."""
    from motor_id.testing.fleet_gen import Drift, FleetSpec, motor_truths
    rng = np.random.default_rng(seed)
    rows = []
    for param, size, kind in kinds:
        row = {'change': f'{param} {size * 100:+.0f} % {kind}'}
        dated_ok = flagged = total = early = 0
        for onset in POSITIONS:
            delays = []
            for _ in range(reps):
                spec = FleetSpec(robots=siblings + 1, motors=('wheel',), days=DAYS + joined,
                                 drifts=(Drift('robot_00', 'wheel', param, size,
                                               onset + joined, kind, ramp_days=5),),
                                 seed=int(rng.integers(2 ** 31)))
                truths = motor_truths(spec, rng)
                hist = [_history(rule, truths[k], param, rng, joined if j == 0 else 0)
                        for j, k in enumerate(sorted(truths))]
                pool = rule.pool(hist)
                hit = np.flatnonzero(rule.flags(hist[0], pool))
                early += bool(hit.size and hit[0] < onset)
                after = hit[hit >= onset]
                delays.append(int(after[0]) - onset + 1 if after.size else np.inf)
                total += 1
                if not after.size:
                    continue
                flagged += 1
                f = rule.scan_series(hist[0], pool)
                near = min((c.index - onset for c in f.change_points), key=abs,
                           default=None)
                lo, hi = (-1, 4) if kind == 'ramp' else (-1, 1)
                dated_ok += near is not None and lo <= near <= hi
            med = float(np.median(delays))
            row[f'p{onset}'] = f'{med:.0f}' if np.isfinite(med) else '-'
            if onset == POSITIONS[0]:
                row['first10'] = float(np.mean(np.array(delays) <= 10 - onset))
                row['first30'] = float(np.mean(np.isfinite(delays)))
        row['flagged'] = flagged / total
        row['dated'] = dated_ok / max(flagged, 1)
        row['early'] = early
        rows.append(row)
    return rows


OPERATOR_DRIFTS = (('K_T', -0.08), ('R_m', 0.12), ('B', 0.6), ('R_m', 0.08), ('K_T', -0.05))
"""What ``operator_fleets`` draws from (sign kept, size scaled by 0.8-1.2)."""


def operator_fleets(rule, fleets, seed):
    """Fleets as an operator gets them: 4 robots x 2 wheels x 10-12 daily recordings,
    3 drifts drawn by :func:`motor_id.testing.fleet_gen.random_drifts` (motor, parameter
    and size from ``OPERATOR_DRIFTS``, step or 5-day ramp, onset on the 2nd to the 7th
    recording), every estimate of every parameter through
    :func:`motor_id.fleet.history.fleet_findings` (the command's own path). ``seed``
    is not one the rule was tuned on. Returns the counts."""
    from motor_id.fleet.history import fleet_findings
    from motor_id.fleet.rows import EstimateRow, ParameterValue
    from motor_id.testing.fleet_gen import FleetSpec, motor_truths, random_drifts, score_detection
    rng = np.random.default_rng(seed)
    got = {'drifts': 0, 'flagged': 0, 'dated': 0, 'first_week': 0, 'first_week_flagged': 0,
           'wrong_parameter': 0, 'clean_series': 0, 'false': 0, 'detect': [],
           'missed': []}
    for _ in range(fleets):
        spec = FleetSpec(robots=4, days=int(rng.integers(10, 13)),
                         seed=int(rng.integers(2 ** 31)))
        spec = FleetSpec(robots=4, days=spec.days, seed=spec.seed,
                         drifts=random_drifts(spec, rng, 3, OPERATOR_DRIFTS, first=1, last=6))
        truths = motor_truths(spec, rng)
        rows = []
        for (robot, motor), days in truths.items():
            for day, m in enumerate(days):
                params = {}
                for p, err in FIT_ERROR.items():
                    v = getattr(m, p) * (1 + rng.normal(0, err))
                    params[p] = ParameterValue(value=v, std=v * err, determined=True)
                rows.append(EstimateRow(robot=robot, motor=motor, recording=f'{robot}/{day}',
                                        start_time=f'2026-01-{day + 1:02d}T10:00:00Z',
                                        parameters=params, adequate=True))
        spec = FleetSpec(robots=4, days=spec.days, seed=spec.seed, drifts=spec.drifts,
                         start='2026-01-01')
        found, false, clean = score_detection(spec, fleet_findings(rows, rule).drift)
        for dr, r in zip(spec.drifts, found, strict=True):
            got['drifts'] += 1
            got['first_week'] += dr.onset <= 6
            got['flagged'] += r['flagged']
            got['first_week_flagged'] += r['flagged'] and dr.onset <= 6
            lo, hi = (-1, 4) if dr.kind == 'ramp' else (-1, 1)
            got['dated'] += r['flagged'] and lo <= r['dated'] <= hi
            got['wrong_parameter'] += r['other_flags'] != '-'
            if r['flagged']:
                got['detect'].append(r['detect'])
            else:
                got['missed'].append(f'{r["drift"]} @{dr.onset + 1} of {spec.days}')
        got['clean_series'] += clean
        got['false'] += len(false)
    return got


def false_alarms(rule, fleets, robots, days=365, seed=2, by_type=False):
    """Motor-years flagged on clean generated fleets (``robots`` x 2 wheels each;
    ``robots`` 1: single motors, no siblings; ``by_type``: both wheels of every robot
    siblings, as with one ``type:``, though a robot's two wheels share its temperature)."""
    from motor_id.testing.fleet_gen import FleetSpec, motor_truths
    rng = np.random.default_rng(seed)
    motor_years = flagged = param_years = param_flags = 0
    per_param = dict.fromkeys(FIT_ERROR, 0)
    for _ in range(fleets):
        spec = FleetSpec(robots=robots, days=days, seed=int(rng.integers(2 ** 31)))
        truths = motor_truths(spec, rng)
        hit_motor = dict.fromkeys(truths, False)
        for param in FIT_ERROR:
            for wheel in (('all',) if by_type else spec.motors):
                keys = [k for k in sorted(truths) if by_type or k[1] == wheel]
                hist = [_history(rule, truths[k], param, rng) for k in keys]
                pool = rule.pool(hist, [k[0] for k in keys])
                for k, h in zip(keys, hist, strict=True):
                    hit = bool(rule.flags(h, pool).any())
                    hit_motor[k] |= hit
                    param_flags += hit
                    per_param[param] += hit
                    param_years += 1
        motor_years += len(truths)
        flagged += sum(hit_motor.values())
    return {'motor_years': motor_years * days / 365, 'flagged': flagged,
            'param_years': param_years, 'param_flags': param_flags, 'per_param': per_param}


def siblings(rule, groups, sizes=(4, 8, 10, 20), offs=(0.25, 0.5, 0.8), seed=4):
    """Motors odd among their siblings: the share of clean motor parameters reported,
    and of motors off by ``offs`` from the first day, per group size (the generator's
    5 % unit spread, each level with a 0.5 % standard error)."""
    from motor_id.fleet.siblings import compare_siblings
    rng = np.random.default_rng(seed)
    rows = []
    for n in sizes:
        clean = hits = 0
        found = dict.fromkeys(offs, 0)
        for _ in range(groups):
            lv = np.exp(rng.normal(0, 0.05, n) + rng.normal(0, 0.005, n))
            res = compare_siblings([(float(v), 0.005) for v in lv], rule.sibling_threshold)
            clean += n
            hits += sum(f.outlier for f in res)
            for off in offs:
                odd = lv.copy()
                odd[0] *= 1 + off
                res = compare_siblings([(float(v), 0.005) for v in odd],
                                       rule.sibling_threshold)
                found[off] += res[0].outlier
        rows.append({'motors': n, 'false': hits / clean,
                     **{f'off{int(o * 100)}': found[o] / groups for o in offs}})
    return rows


def _upper95(k, n):
    """One-sided 95 % upper bound of a rate from k events in n (exact Poisson)."""
    from scipy import stats
    return float(stats.chi2.ppf(0.95, 2 * (k + 1)) / 2 / n)


def run(quick=False, reps=None, motor_years=None, op_seed=None, stream=sys.stdout):
    """Run everything; returns the record (tables and targets)."""
    from common import target

    from motor_id.fleet.drift import DriftRule
    rule = DriftRule()

    def say(msg):
        print(msg, file=stream, flush=True)
    reps = reps or (6 if quick else 60)
    t0 = time.perf_counter()
    say(f'detection: {len(KINDS)} kinds x {len(POSITIONS)} positions x {reps} histories ...')
    det = {f'{n} siblings': detection(rule, reps, n) for n in ((3,) if quick else (3, 7))}
    say(f'detection: a new robot among 3 siblings with {JOINED} days of history ...')
    det[f'a new robot, 3 siblings with {JOINED} days of history'] = detection(
        rule, reps, 3, joined=JOINED)
    op_seed = secrets.randbits(31) if op_seed is None else op_seed
    n_op = 20 if quick else 300
    say(f'operator fleets: {n_op} fleets, seed {op_seed} ...')
    op = operator_fleets(rule, n_op, op_seed)
    t_det = time.perf_counter() - t0
    n_fleet = max(1, (motor_years or (40 if quick else 800)) // 8)
    say(f'false alarms: {n_fleet} clean fleets x 8 wheels x 365 days ...')
    fa = false_alarms(rule, n_fleet, 4)
    say(f'false alarms: {n_fleet // 2} clean fleets x 8 wheels of one type x 365 days ...')
    fa8 = false_alarms(rule, max(1, n_fleet // 2), 4, seed=3, by_type=True)
    n_single = max(1, n_fleet // 2)
    say(f'false alarms: {n_single} x 2 single motors (no siblings) x 365 days ...')
    fa1 = false_alarms(rule, n_single, 1)
    t_fa = time.perf_counter() - t0 - t_det
    sib = siblings(rule, 200 if quick else 4000)
    fa_rows = []
    for what, f in (('4-robot fleets (3 siblings)', fa),
                    ('4-robot fleets, one type (7 siblings)', fa8),
                    ('single motors (no siblings)', fa1)):
        fa_rows.append({'what': what, 'motor_years': f['motor_years'], 'flagged': f['flagged'],
                        'per100': 100 * f['flagged'] / f['motor_years'],
                        'upper95': 100 * _upper95(f['flagged'], f['motor_years']),
                        'param_flags': f['param_flags'],
                        'params': ', '.join(f'{p} {v}' for p, v in f['per_param'].items())})
    cols = [('change', 'change', 's'), *((f'p{p}', f'@{p + 1}', 's') for p in POSITIONS),
            ('first10', f'@{POSITIONS[0] + 1} by 10th', '.0%'),
            ('first30', f'@{POSITIONS[0] + 1} by {DAYS}th', '.0%'),
            ('flagged', 'flagged', '.0%'), ('dated', 'dated', '.0%'),
            ('early', 'flags before onset', 'd')]
    tables = [{'title': f'recordings to detect (median; "@k": the change from the k-th '
                        f'recording of {DAYS}), {n}', 'columns': cols, 'rows': rows}
              for n, rows in det.items()]
    detect = np.array(op['detect'])
    tables.append({
        'title': f'operator fleets (not tuned on: seed {op_seed}): 4 robots x 2 wheels x '
                 '10-12 days, 3 drifts each drawn by random_drifts on the 2nd-7th recording',
        'columns': [('fleets', 'fleets', 'd'), ('drifts', 'drifts', 'd'),
                    ('flagged', 'flagged', 'd'), ('dated', 'dated right', 'd'),
                    ('median', 'recordings to detect (median)', '.0f'),
                    ('p90', '(90 %)', '.0f'), ('wrong', 'other parameters flagged', 'd'),
                    ('clean', 'clean histories', 'd'), ('false', 'flagged', 'd'),
                    ('missed', 'missed', 's')],
        'rows': [{'fleets': n_op, 'drifts': op['drifts'], 'flagged': op['flagged'],
                  'dated': op['dated'],
                  'median': float(np.median(detect)) if detect.size else float('nan'),
                  'p90': float(np.percentile(detect, 90)) if detect.size else float('nan'),
                  'wrong': op['wrong_parameter'], 'clean': op['clean_series'],
                  'false': op['false'], 'missed': '; '.join(op['missed'])}]})
    tables.append({'title': 'false alarms (a year of daily recordings per motor)',
                   'columns': [('what', 'what', 's'), ('motor_years', 'motor-years', '.0f'),
                               ('flagged', 'flagged', 'd'),
                               ('per100', 'per 100 motor-years', '.2f'),
                               ('upper95', '95 % upper bound', '.2f'),
                               ('param_flags', 'parameter-years flagged', 'd'),
                               ('params', 'by parameter', 's')],
                   'rows': fa_rows})
    tables.append({'title': f'against the siblings (sibling_threshold {rule.sibling_threshold}; '
                            'unit spread 5 %): share of clean motor parameters reported, '
                            'and of a motor off from its first day by +25/50/80 %',
                   'columns': [('motors', 'motors in the group', 'd'),
                               ('false', 'clean reported', '.2e'),
                               ('off25', '+25 %', '.0%'), ('off50', '+50 %', '.0%'),
                               ('off80', '+80 %', '.0%')],
                   'rows': sib})
    rate = fa_rows[0]['per100']
    big = [r for n, rows in det.items() for r in rows if '12' in r['change'] or 'B' in
           r['change']]
    op_rate = op['flagged'] / max(op['drifts'], 1)
    targets = [
        target('false alarms per 100 motor-years (4-robot fleets)', rate, '<= 1',
               rate <= 1.0),
        target('12 % steps and B ramps flagged by the 30th recording',
               min(r['flagged'] for r in big) * 100, '100 %',
               all(r['flagged'] == 1.0 for r in big), '%'),
        target('operator fleets: drifts flagged', op_rate * 100, '(issue: every one)',
               None, '%'),
        target('operator fleets: clean histories flagged', op['false'], '0',
               op['false'] == 0, ''),
        target('dated right (steps +-1, ramps -1..+4), 12 % steps and B ramps',
               min(r['dated'] for r in big) * 100, '>= 95 %',
               all(r['dated'] >= 0.95 for r in big), '%'),
    ]
    return {'title': TITLE, 'status': 'ok', 'tables': tables, 'targets': targets,
            'settings': {'rule': rule.to_dict(), 'reps': reps, 'days': DAYS,
                         'fit_error': FIT_ERROR, 'operator_seed': op_seed},
            'seconds': {'detection': t_det, 'false_alarms': t_fa}}


def _print(rec, stream=sys.stdout):
    from common import render_table
    print(f'== {rec["title"]}', file=stream)
    for k, v in rec['settings'].items():
        print(f'  {k}: {v}', file=stream)
    for t in rec['tables']:
        print(f'\n{t["title"]}', file=stream)
        print(render_table(t['columns'], t['rows']), file=stream)
    print('\ntargets:', file=stream)
    for t in rec['targets']:
        mark = {True: 'PASS', False: 'FAIL', None: '-'}[t['pass']]
        print(f'  [{mark}] {t["name"]}: {t["value"]:.3g} {t["unit"]} ({t["threshold"]})',
              file=stream)
    print(f'seconds: {rec["seconds"]}', file=stream)


def main(argv=None):
    """Command line: run, print the tables and targets, write JSON."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--quick', action='store_true', help='a small smoke run (not a measure)')
    p.add_argument('--reps', type=int, help='histories per cell of the detection table')
    p.add_argument('--motor-years', type=int, help='clean motor-years in fleets')
    p.add_argument('--seed', type=int, help='seed of the operator fleets (default: drawn '
                   'afresh each run, and printed)')
    p.add_argument('--json', metavar='OUT', help='write the record as JSON')
    args = p.parse_args(argv)
    rec = run(quick=args.quick, reps=args.reps, motor_years=args.motor_years,
              op_seed=args.seed)
    _print(rec)
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as fh:
            json.dump(rec, fh, indent=1, default=float)
    return 0 if all(t['pass'] is not False for t in rec['targets']) else 1


if __name__ == '__main__':
    sys.exit(main())
