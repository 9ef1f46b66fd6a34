"""Section 5: discrepancy analysis, its wall time and its hit / false-alarm rates.

Part A times ``motor-id analyze`` end to end (a fresh process, CSV in, JSON out) on
4,000 samples. Part B runs :class:`motor_id.discrepancy.DiscrepancyAnalysis` on
recordings from a hidden-effect generator at three noise levels: half of the cases
carry one named effect of :data:`motor_id.model.EFFECTS`, half none. A *hit* is a
verdict that contains the hidden effect; a *false alarm* is any effect reported on a
linear motor.
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
from motor_id.excitation import make_excitation
from motor_id.model import EFFECTS, MotorParams, PAPER_MOTOR
from motor_id.recording import Recording, write_csv
from motor_id.simulate import simulate_batch

TITLE = 'Discrepancy analysis: wall time and hit / false-alarm rates'
MOTOR = MotorParams(J=PAPER_MOTOR.J, K_T=0.65, K_b=0.65, B=PAPER_MOTOR.B, L_m=PAPER_MOTOR.L_m,
                    R_m=PAPER_MOTOR.R_m)
"""K_T = K_b, so that the linear base fit (default tie) is not itself a discrepancy."""
NOISE_LEVELS = (0.005, 0.02, 0.05)
EXCITATION = 'bipolar_steps'


def _require():
    try:
        from motor_id.discrepancy import DiscrepancyAnalysis  # noqa: F401
    except ImportError as exc:
        raise Skip(f'motor_id.discrepancy is not available ({exc})') from None


def simulate_case(effects, noise, seed, n=4000, dt=0.01):
    """:data:`MOTOR` with ``effects`` on ``bipolar_steps``, white noise of ``noise`` x std."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    u = make_excitation(EXCITATION, t)
    out = simulate_batch(MOTOR.to_dict(), t, u, 'voltage', 'zoh', effects)
    s, c = out['speed'][0], out['current'][0]
    return Recording(t, u, s + noise * np.std(s) * rng.standard_normal(n),
                     c + noise * np.std(c) * rng.standard_normal(n), 'voltage',
                     {'truth': MOTOR.to_dict(), 'effects': effects, 'noise': noise})


def own_case(seed, noise, with_effect, n=4000):
    """One case of this benchmark's hidden-effect generator.

    With ``with_effect`` one effect applicable to a voltage plant is drawn (seeded)
    and given its catalogue default magnitude.

    Returns
    -------
    rec : Recording
    hidden : str or None
        The effect's name.
    """
    rng = np.random.default_rng(seed)
    names = sorted(k for k, e in EFFECTS.items() if 'voltage' in e.kinds)
    hidden = str(rng.choice(names)) if with_effect else None
    effects = {hidden: EFFECTS[hidden].defaults()} if hidden else {}
    return simulate_case(effects, noise, seed + 1, n), hidden


def generator_name():
    """Which hidden-effect generator this section uses."""
    try:
        import motor_id.hidden  # noqa: F401
    except ImportError:
        return 'benchmark generator (motor_id.hidden not available)'
    return 'benchmark generator (motor_id.hidden present but not wired in yet)'


def _analyse(job):
    """Worker: one analysis -> a result row (runs in a child process)."""
    from motor_id.discrepancy import DiscrepancyAnalysis

    seed, noise, with_effect, n, candidates = job
    rec, hidden = own_case(seed, noise, with_effect, n)
    t0 = time.perf_counter()
    ana = DiscrepancyAnalysis(R_m=MOTOR.R_m, candidates=candidates, random_state=seed)
    ana.fit(rec)
    rep = ana.report_
    found = [] if rep.verdict == 'none' else rep.verdict.split('+')
    ambiguous = [a['name'] for a in rep.ambiguous_with]
    return {'seed': seed, 'noise': noise, 'hidden': hidden, 'verdict': rep.verdict,
            'ambiguous_with': ambiguous, 'unexplained': rep.unexplained,
            'hit': hidden is not None and hidden in found,
            'hit_or_ambiguous': hidden is not None and (hidden in found
                                                        or hidden in ambiguous),
            'first_is_hidden': hidden is not None and bool(found) and found[0] == hidden,
            'false_alarm': hidden is None and bool(found),
            'seconds': time.perf_counter() - t0}


def time_cli(tmp, n, with_effect, candidates=None):
    """Wall time of ``motor-id analyze`` in a fresh process on one CSV of n samples."""
    hidden = 'coulomb_friction' if with_effect else None
    rec = simulate_case({hidden: {'T_c': 0.05}} if hidden else {}, 0.01, 7, n)
    csv = os.path.join(tmp, f'case_{int(with_effect)}.csv')
    js = os.path.join(tmp, f'case_{int(with_effect)}.json')
    write_csv(rec, csv)
    env = dict(os.environ)
    env['PYTHONPATH'] = REPO + os.pathsep + env.get('PYTHONPATH', '')
    args = [sys.executable, '-m', 'motor_id.cli', 'analyze', csv, '-R', str(MOTOR.R_m),
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
    cases = 1 if quick else 6          # per noise level, with and without an effect each
    levels = NOISE_LEVELS[:1] if quick else NOISE_LEVELS
    candidates = ['coulomb_friction', 'load_torque'] if quick else None
    gen_name = generator_name()
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
        r = _rates([x for x in rows if x['noise'] == noise])
        r['noise'] = f'{noise:.1%}'
        rate_rows.append(r)
    total = _rates(rows)
    cli_lin = cli_rows[0]['wall_s']
    return {
        'title': TITLE,
        'status': 'ok',
        'settings': {'samples': n, 'sample_period': 0.01, 'excitation': EXCITATION,
                     'motor': MOTOR.to_dict(), 'noise_levels': list(levels),
                     'cases_per_level': {'with_effect': cases, 'linear': cases},
                     'generator': gen_name, 'candidates': candidates or 'all',
                     'workers': workers},
        'tables': [
            {'title': '`motor-id analyze` end to end (fresh process: start-up, CSV, '
                      'analysis, JSON)',
             'columns': [('case', 'case', ''), ('wall_s', 'wall s', '.2f'),
                         ('analysis_s', 'analysis s', '.2f'), ('verdict', 'verdict', ''),
                         ('correct', 'correct', '')],
             'rows': cli_rows},
            {'title': 'hit / false-alarm rates per noise level (noise = fraction of each '
                      'channel std)',
             'columns': [('noise', 'noise', ''), ('cases_with_effect', 'effect cases', 'd'),
                         ('hit_rate', 'hit', '%'),
                         ('hit_or_ambiguous_rate', 'hit or ambiguous', '%'),
                         ('first_is_hidden_rate', 'first = hidden', '%'),
                         ('cases_linear', 'linear cases', 'd'),
                         ('false_alarm_rate', 'false alarm', '%'),
                         ('median_s', 'median s', '.1f')],
             'rows': rate_rows},
            {'title': 'cases', 'columns': [
                ('seed', 'seed', 'd'), ('noise', 'noise', '.3f'), ('hidden', 'hidden', ''),
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
            f'generator: {gen_name}; each effect case draws one effect applicable to a '
            'voltage plant (seeded) at its catalogue default magnitude; the motor has '
            'K_T = K_b so that the linear fit with the default tie is exact',
            'hit: the verdict contains the hidden effect; "hit or ambiguous": or the '
            'report lists it as indistinguishable from the winner; false alarm: any '
            'effect reported on a linear motor',
            f'the analyses of part B run in {workers} worker process(es) in parallel',
        ],
        'cases': rows,
    }
