"""Section 5: discrepancy analysis, its wall time and its hit / false-alarm rates.

Part A times ``motor-id analyze`` end to end (a fresh process, CSV in, JSON out) on
4,000 samples. Part B runs :class:`motor_id.discrepancy.DiscrepancyAnalysis` on cases of
the hidden-effect generator :mod:`motor_id.hidden` at three noise levels: half of the
cases carry one named effect of :data:`motor_id.model.EFFECTS` drawn at random, half
none. A *hit* is a verdict that
contains the hidden effect; a *false alarm* is any effect reported on a linear motor.
"""

from concurrent.futures import ProcessPoolExecutor
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

from common import REPO, Skip, target
from motor_id.recording import write_csv

TITLE = 'Discrepancy analysis: wall time and hit / false-alarm rates'
NOISE_LEVELS = ((0.005, 0.01), (0.02, 0.04), (0.05, 0.1))
"""Speed and current noise std as fractions of each channel's std (motor_id.hidden's
default, x4 and x10)."""
GENERATOR = ('motor_id.hidden.make_case: a perturbed paper motor (K_T = K_b), one random '
             'effect in its detectable range or none, a random excitation and amplitude')


def _require():
    try:
        from motor_id.discrepancy import DiscrepancyAnalysis  # noqa: F401
        from motor_id.hidden import make_case  # noqa: F401
    except ImportError as exc:
        raise Skip(f'the discrepancy analysis is not available ({exc})') from None


def make_case(seed, noise, with_effect, n=4000, effect=None, excitation=None):
    """One case of :func:`motor_id.hidden.make_case`: ``(rec, hidden effect or None, R_m)``."""
    from motor_id.hidden import make_case as hidden_case

    if effect is None:
        effect = None if with_effect else 'none'
    rec, case = hidden_case(seed, effect=effect, excitation=excitation, n_samples=n,
                            noise=tuple(noise))
    return rec, (None if case.effect == 'none' else case.effect), case.known['R_m']


def _analyse(job):
    """Worker: one analysis -> a result row (runs in a child process)."""
    from motor_id.discrepancy import DiscrepancyAnalysis

    seed, noise, with_effect, n, candidates = job
    rec, hidden, r_m = make_case(seed, noise, with_effect, n)
    t0 = time.perf_counter()
    ana = DiscrepancyAnalysis(R_m=r_m, candidates=candidates, random_state=seed)
    ana.fit(rec)
    rep = ana.report_
    found = [] if rep.verdict == 'none' else rep.verdict.split('+')
    ambiguous = [a['name'] for a in rep.ambiguous_with]
    return {'seed': seed, 'noise': f'{noise[0]:.1%}/{noise[1]:.1%}', 'hidden': hidden,
            'verdict': rep.verdict,
            'ambiguous_with': ambiguous, 'unexplained': rep.unexplained,
            'hit': hidden is not None and hidden in found,
            'hit_or_ambiguous': hidden is not None and (hidden in found
                                                        or hidden in ambiguous),
            'first_is_hidden': hidden is not None and bool(found) and found[0] == hidden,
            'false_alarm': hidden is None and bool(found),
            'seconds': time.perf_counter() - t0}


def time_cli(tmp, n, with_effect, candidates=None):
    """Wall time of ``motor-id analyze`` in a fresh process on one CSV of n samples."""
    rec, hidden, r_m = make_case(7, NOISE_LEVELS[0], with_effect, n,
                                 effect='coulomb_friction' if with_effect else 'none',
                                 excitation='bipolar_steps')
    csv = os.path.join(tmp, f'case_{int(with_effect)}.csv')
    js = os.path.join(tmp, f'case_{int(with_effect)}.json')
    write_csv(rec, csv)
    env = dict(os.environ)
    env['PYTHONPATH'] = REPO + os.pathsep + env.get('PYTHONPATH', '')
    args = [sys.executable, '-m', 'motor_id.cli', 'analyze', csv, '-R', repr(r_m),
            '--json', js, '--quiet']
    if candidates:
        args += ['--candidates', ','.join(candidates)]
    t0 = time.perf_counter()
    proc = subprocess.run(args, env=env, capture_output=True, text=True, timeout=900)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f'motor-id analyze failed ({proc.returncode}): '
                           f'{proc.stderr[-1500:]}')
    with open(js) as fh:
        rep = json.load(fh)
    return {'case': f'{n} samples, ' + (f'hidden {hidden}' if hidden else 'linear motor'),
            'wall_s': wall, 'analysis_s': rep.get('seconds'), 'verdict': rep['verdict'],
            'correct': rep['verdict'].split('+')[0] == (hidden or 'none')}


def _rates(rows):
    eff = [r for r in rows if r['hidden'] is not None]
    lin = [r for r in rows if r['hidden'] is None]
    mean = (lambda v: float(np.mean(v)) if v else None)
    return {'cases_with_effect': len(eff), 'cases_linear': len(lin),
            'hit_rate': mean([r['hit'] for r in eff]),
            'hit_or_ambiguous_rate': mean([r['hit_or_ambiguous'] for r in eff]),
            'first_is_hidden_rate': mean([r['first_is_hidden'] for r in eff]),
            'false_alarm_rate': mean([r['false_alarm'] for r in lin]),
            'median_s': float(np.median([r['seconds'] for r in rows]))}


def run(quick=False):
    """Run the section; returns the section record."""
    _require()
    n = 1000 if quick else 4000
    cases = 1 if quick else 10         # per noise level, with and without an effect each
    levels = NOISE_LEVELS[:1] if quick else NOISE_LEVELS
    candidates = ['coulomb_friction', 'load_torque'] if quick else None
    tmp = tempfile.mkdtemp(prefix='motor_id_bench_')
    try:
        cli_rows = [time_cli(tmp, n, False, candidates), time_cli(tmp, n, True, candidates)]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    jobs = [(1000 * k + j, noise, bool(j % 2), n, candidates)
            for k, noise in enumerate(levels) for j in range(2 * cases)]
    workers = max(1, min(os.cpu_count() or 1, len(jobs)))
    with ProcessPoolExecutor(max_workers=workers) as pool:
        rows = list(pool.map(_analyse, jobs))
    rate_rows = []
    for noise in levels:
        label = f'{noise[0]:.1%}/{noise[1]:.1%}'
        r = _rates([x for x in rows if x['noise'] == label])
        r['noise'] = label
        rate_rows.append(r)
    total = _rates(rows)
    cli_lin = cli_rows[0]['wall_s']
    return {
        'title': TITLE,
        'status': 'ok',
        'settings': {'samples': n, 'sample_period': 0.01, 'noise_levels': list(levels),
                     'cases_per_level': {'with_effect': cases, 'linear': cases},
                     'generator': GENERATOR, 'candidates': candidates or 'all',
                     'workers': workers},
        'tables': [
            {'title': '`motor-id analyze` end to end (fresh process: start-up, CSV, '
                      'analysis, JSON)',
             'columns': [('case', 'case', ''), ('wall_s', 'wall s', '.2f'),
                         ('analysis_s', 'analysis s', '.2f'), ('verdict', 'verdict', ''),
                         ('correct', 'correct', '')],
             'rows': cli_rows},
            {'title': 'hit / false-alarm rates per noise level (speed/current noise std as '
                      'a fraction of each channel std)',
             'columns': [('noise', 'noise', ''), ('cases_with_effect', 'effect cases', 'd'),
                         ('hit_rate', 'hit', '%'),
                         ('hit_or_ambiguous_rate', 'hit or ambiguous', '%'),
                         ('first_is_hidden_rate', 'first = hidden', '%'),
                         ('cases_linear', 'linear cases', 'd'),
                         ('false_alarm_rate', 'false alarm', '%'),
                         ('median_s', 'median s', '.1f')],
             'rows': rate_rows},
            {'title': 'cases', 'columns': [
                ('seed', 'seed', 'd'), ('noise', 'noise', ''), ('hidden', 'hidden', ''),
                ('verdict', 'verdict', ''), ('hit', 'hit', ''),
                ('false_alarm', 'false alarm', ''), ('seconds', 's', '.1f')],
             'rows': [{**r, 'hidden': r['hidden'] or '-'} for r in rows]},
        ],
        'targets': [
            target(f'motor-id analyze wall time, {n} samples, linear motor', cli_lin,
                   'informative', None, 's'),
            target('hit rate over all noise levels', total['hit_rate'], 'informative',
                   None),
            target('false-alarm rate over all noise levels', total['false_alarm_rate'],
                   'informative', None),
        ],
        'totals': total,
        'notes': [
            f'generator: {GENERATOR}; R_m is given to the analysis as the generator '
            'states it (case.known); the CLI timing cases use bipolar_steps, a linear motor '
            'and one with Coulomb friction',
            'hit: the verdict contains the hidden effect; "hit or ambiguous": or the '
            'report lists it as indistinguishable from the winner; false alarm: any '
            'effect reported on a linear motor',
            f'the analyses of part B run in {workers} worker process(es) in parallel',
        ],
        'cases': rows,
    }
