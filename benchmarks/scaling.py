"""Section 3: how the fit time grows with the record length and the population size."""

from common import paper_recording, PAPER_SETUP, target
import numpy as np

from motor_id.identify import Identifier

TITLE = 'Scaling: fit time vs record length and population size'


def _fit(rec, population, generations, repeats):
    """Best-of-``repeats`` GA and total fit times of one Identifier setting."""
    ga_s, total_s, evals = [], [], 0
    for k in range(repeats):
        idf = Identifier(population=population, generations=generations, random_state=k,
                         **PAPER_SETUP).fit(rec)
        ga_s.append(idf.result_.ga.seconds)
        total_s.append(idf.result_.seconds)
        evals = idf.result_.ga.evaluations
    return min(ga_s), min(total_s), evals


def _slope(x, y):
    """Least-squares slope of log y against log x."""
    return float(np.polyfit(np.log(x), np.log(y), 1)[0])


def run(quick=False):
    """Run the section; returns the section record."""
    sizes = (400, 800, 1600) if quick else (1000, 3000, 10000, 30000, 100000)
    pops = (10, 20) if quick else (10, 20, 40, 80, 160)
    generations = 10 if quick else 160
    n_pop = 800 if quick else 4000
    warm = paper_recording(n=500, dt=0.1, seed=99)
    Identifier(generations=2, **PAPER_SETUP).fit(warm)  # JIT and imports out of timings
    size_rows = []
    for n in sizes:
        rec = paper_recording(n=n, noise=0.005, seed=n)
        ga, total, evals = _fit(rec, 20, generations, 1 if quick or n > 10000 else 3)
        size_rows.append({'samples': n, 'ga_seconds': ga, 'fit_seconds': total,
                          'evaluations': evals,
                          'ns_per_sample_eval': 1e9 * ga / (evals * n)})
    pop_rows = []
    rec = paper_recording(n=n_pop, noise=0.005, seed=1)
    for p in pops:
        ga, total, evals = _fit(rec, p, generations, 1 if quick else 2)
        pop_rows.append({'population': p, 'ga_seconds': ga, 'fit_seconds': total,
                         'evaluations': evals, 'us_per_eval': 1e6 * ga / evals})
    ns = np.array([r['samples'] for r in size_rows], dtype=float)
    slope_ga = _slope(ns, [r['ga_seconds'] for r in size_rows])
    slope_fit = _slope(ns, [r['fit_seconds'] for r in size_rows])
    big = ns >= (800 if quick else 3000)
    slope_ga_big = _slope(ns[big], np.array([r['ga_seconds'] for r in size_rows])[big])
    slope_pop = _slope([r['population'] for r in pop_rows],
                       [r['ga_seconds'] for r in pop_rows])
    return {
        'title': TITLE,
        'status': 'ok',
        'settings': {'generations': generations, 'population_for_sizes': 20,
                     'samples_for_populations': n_pop, 'sample_period': 0.01,
                     'identifier': PAPER_SETUP, 'timing': 'best of 3 fits up to 10k '
                     'samples, 1 fit above; best of 2 for the population sweep'},
        'tables': [
            {'title': 'record length (population 20, GA and whole Identifier.fit)',
             'columns': [('samples', 'samples', 'd'), ('ga_seconds', 'GA s', '.3f'),
                         ('fit_seconds', 'fit s', '.3f'), ('evaluations', 'evals', 'd'),
                         ('ns_per_sample_eval', 'ns/sample/eval', '.1f')],
             'rows': size_rows},
            {'title': f'population size ({generations} generations, {n_pop} samples)',
             'columns': [('population', 'population', 'd'), ('ga_seconds', 'GA s', '.3f'),
                         ('fit_seconds', 'fit s', '.3f'), ('evaluations', 'evals', 'd'),
                         ('us_per_eval', 'us/eval', '.1f')],
             'rows': pop_rows},
        ],
        'slopes': {'ga_vs_samples': slope_ga, 'ga_vs_samples_large': slope_ga_big,
                   'fit_vs_samples': slope_fit, 'ga_vs_population': slope_pop},
        'targets': [
            target('slope of log GA time vs log samples (all sizes)', slope_ga, '~1',
                   abs(slope_ga - 1) <= 0.15 if not quick else None),
            target('slope of log GA time vs log samples (>= 3k samples)', slope_ga_big,
                   '~1', abs(slope_ga_big - 1) <= 0.15 if not quick else None),
            target('slope of log fit time vs log samples (all sizes)', slope_fit, '~1',
                   None),
            target('slope of log GA time vs log population', slope_pop,
                   '<= 1.15 (linear or better)',
                   slope_pop <= 1.15 if not quick else None),
        ],
        'notes': ['records longer than 40 s repeat the Eq. 14 steps; 10 ms sampling',
                  '"~1" passes within +-0.15; the population slope passes at or below '
                  '1.15 (fixed costs per generation make it sub-linear: 0.83-0.85 '
                  'measured); the fit-time slope is informative only '
                  '(the iteration count of the refinement varies with the data)'],
    }
