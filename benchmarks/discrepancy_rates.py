#!/usr/bin/env python3
"""Section 5: how often the discrepancy analysis names a hidden effect, on two generators.

Usage::

    python benchmarks/discrepancy_rates.py [--quick] [--cases N] [--jobs J]
        [--generator hidden|independent|both] [--noise 0.5,2,5] [--json OUT]
        [--markdown OUT] [--failures] [--exact-rm] [--no-cli] [--quiet] [--rerun JSON]

``benchmarks/run.py`` runs it as section ``discrepancy`` (``run(quick)``). ``--failures``
prints every miss with its truth, the verdict and the top candidates' held-out gains;
``--markdown`` writes the tables and that list (rewritten after every case while the
run lasts); ``--rerun`` runs only the failing cases of an earlier ``--json`` output.

Part A times ``motor-id analyze`` end to end (a fresh process, CSV in, JSON out) on
4,000 samples. Part B runs :class:`DiscrepancyAnalysis` on seeded cases of two
generators at each noise level (white noise on speed and current, the same fraction of
each channel's standard deviation):

- ``hidden``: :func:`motor_id.testing.hidden.make_case`, the project's own simulator
  (4,000 samples at 10 ms, the paper's motor perturbed);
- ``independent``: :mod:`motor_id.testing.independent_sim`, a second simulator written
  from the physics with no motor_id model code (industrial, servo and hobby motors,
  sample periods of 1-20 ms, 2,000-25,000 samples, stick-slip friction, an encoder
  counting over each period, a heated winding).

The case plan, the analysis of one case and the rates are
:mod:`motor_id.testing.discrepancy` (shared with ``test/test_independent_rates.py``),
where the terms (named, exact, false alarm, spurious second effect) are defined; this
script adds part A, the tables, the targets and the reports. ``--exact-rm`` tells the
analysis the true R_m instead of one off by 2-5 %.
"""

import datetime
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

from motor_id.blas import limit_threads

limit_threads()  # before numpy loads: one BLAS thread, as the product runs

# isort: split
from common import render_table, REPO, Skip, target  # noqa: E402
import numpy as np  # noqa: E402

from motor_id.testing.discrepancy import (  # noqa: E402
    build_plan,
    CaseRow,
    CaseSpec,
    DEFAULT_CASES,
    failure_lines,
    generator_effects,
    GENERATORS,
    is_failure,
    MAGNITUDE,
    NOISE_LEVELS,
    R_M_ERROR,
    rates,
    run_cases,
    TARGET_NOISE,
)

TITLE = 'Discrepancy analysis: hidden effects named, on two generators'
GENERATOR_TEXT = {
    'hidden': 'motor_id.testing.hidden.make_case: the paper motor perturbed, 4,000 samples '
              'at 10 ms, a random excitation',
    'independent': 'motor_id.testing.independent_sim.make_case: industrial / servo / hobby '
                   'motors, periods 1-20 ms, 2,000-25,000 samples, no motor_id model code',
}


def _cell(pair):
    k, n = pair
    return '-' if not n else f'{100 * k / n:.0f} % ({k}/{n})'


SUMMARY_ROWS = (('named', 'effects named (verdict or ambiguous)'),
                ('exact', 'exact verdict'),
                ('false_alarm', 'false alarms on clean cases'),
                ('spurious', 'spurious second effect'),
                ('grid_named', 'encoder-grid cases named'),
                ('errors', 'analysis errors'))


def summary_table(rows, noise, generators):
    """One noise level: a metric per row, the generators side by side."""
    per = {g: rates([r for r in rows if r.generator == g and r.noise == noise])
           for g in generators}
    out = []
    for key, label in SUMMARY_ROWS:
        out.append({'metric': label, **{g: _cell(getattr(per[g], key)) for g in generators}})
    for key, label in (('median_length', 'median record length [samples]'),
                       ('median_s', 'median analysis s (wall)'),
                       ('median_cpu_s', 'median analysis s (CPU)'),
                       ('max_s', 'max analysis s (wall)'),
                       ('median_param_error', 'median |parameter error|')):
        cells = {}
        for g in generators:
            v = getattr(per[g], key)
            cells[g] = ('-' if v is None else f'{100 * v:.1f} %' if 'param' in key
                        else f'{v:.0f}' if 'length' in key else f'{v:.1f}')
        out.append({'metric': label, **cells})
    return {'title': f'noise {100 * noise:g} % of each channel std: rates side by side',
            'columns': [('metric', 'metric', '')] + [(g, g, '') for g in generators],
            'rows': out}, per


def effect_table(rows, generators, levels):
    """Per effect: named / cases at each noise level and generator, parameter error."""
    effects = []
    for g in generators:
        for e in generator_effects(g) + ('none',):
            if e not in effects:
                effects.append(e)
    cols = [('effect', 'effect', '')]
    out = []
    for e in effects:
        row = {'effect': e}
        for g in generators:
            for lv in levels:
                rs = [r for r in rows if r.generator == g and r.noise == lv
                      and r.effect == e and not r.generator_error]
                key = 'false_alarm' if e == 'none' else 'named'
                k = sum(bool(r[key]) for r in rs)
                row[f'{g}@{lv}'] = f'{k}/{len(rs)}' if rs else '-'
            errs = [abs(r.param_error) for r in rows if r.generator == g
                    and r.effect == e and r.param_error is not None]
            row[f'{g}:err'] = f'{100 * float(np.median(errs)):.1f} %' if errs else '-'
            found = [r for r in rows if r.generator == g and r.effect == e]
            row[f'{g}:exact'] = (f'{sum(r.exact for r in found)}/{len(found)}'
                                 if found and e != 'none' else '-')
        out.append(row)
    for g in generators:
        cols += [(f'{g}@{lv}', f'{g[:3]} {100 * lv:g}%', '') for lv in levels]
        cols += [(f'{g}:exact', f'{g[:3]} exact', ''),
                 (f'{g}:err', f'{g[:3]} |param err|', '')]
    return {'title': 'per effect: named / cases at each noise level (clean cases: false '
                     'alarms / cases), exact verdicts over all levels, median |relative '
                     'error| of the found magnitude',
            'columns': cols, 'rows': out}


# ------------------------------------------------------------------ part A: the CLI

def time_cli(tmp, n, with_effect, candidates=None):
    """Wall time of ``motor-id analyze`` in a fresh process on one CSV of n samples."""
    from motor_id.data.csv_io import write_csv
    from motor_id.testing.hidden import make_case

    rec, case = make_case(7, effect='coulomb_friction' if with_effect else 'none',
                          excitation='bipolar_steps', n_samples=n, noise=(0.005, 0.005))
    hidden = case.effect if with_effect else None
    csv = os.path.join(tmp, f'case_{int(with_effect)}.csv')
    js = os.path.join(tmp, f'case_{int(with_effect)}.json')
    write_csv(rec, csv)
    env = dict(os.environ)
    env['PYTHONPATH'] = REPO + os.pathsep + env.get('PYTHONPATH', '')
    args = [sys.executable, '-m', 'motor_id.cli', 'analyze', csv, '-R',
            repr(case.known['R_m']), '--json', js, '--quiet']
    if candidates:
        args += ['--candidates', ','.join(candidates)]
    t0 = time.perf_counter()
    proc = subprocess.run(args, env=env, capture_output=True, text=True, timeout=900,
                          check=False)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f'motor-id analyze failed ({proc.returncode}): '
                           f'{proc.stderr[-1500:]}')
    with open(js) as fh:
        rep = json.load(fh)
    return {'case': f'{n} samples, ' + (f'hidden {hidden}' if hidden else 'linear motor'),
            'wall_s': wall, 'analysis_s': rep.get('seconds'), 'verdict': rep['verdict'],
            'correct': rep['verdict'].split('+')[0] == (hidden or 'none')}


# ---------------------------------------------------------------------- the section


def targets_for(rows, cli_rows):
    """The issue's targets (independent generator, 0.5-2 % noise) and informative ones."""
    ind = rates([r for r in rows if r.generator == 'independent'
                 and r.noise in TARGET_NOISE])
    hid = rates([r for r in rows if r.generator == 'hidden'
                 and r.noise in TARGET_NOISE])
    four = [r for r in rows if r.length == 4000 and r.seconds is not None]
    med4 = float(np.median([r.seconds for r in four])) if four else None
    cpu4 = float(np.median([r.cpu_seconds for r in four])) if four else None

    def check(value, ok):
        return None if value is None else ok(value)

    scope = 'independent generator, 0.5-2 % noise, R_m off 2-5 %'
    out = [
        target(f'effects named ({scope})', ind.rate('named'), '>= 95 %',
               check(ind.rate('named'), lambda v: v >= 0.95)),
        target(f'false alarms on clean cases ({scope})', ind.rate('false_alarm'), '0',
               check(ind.rate('false_alarm'), lambda v: v == 0)),
        target(f'spurious second effects ({scope})', ind.rate('spurious'),
               '<= 1 per 20 cases', check(ind.rate('spurious'), lambda v: v <= 0.05)),
        target(f'encoder-grid cases named ({scope})', ind.rate('grid_named'), '100 %',
               check(ind.rate('grid_named'), lambda v: v == 1.0)),
        target('median analysis time on 4,000 samples (wall)', med4, '< 5 s',
               check(med4, lambda v: v < 5.0), 's'),
        target('median analysis CPU time on 4,000 samples (one process)', cpu4,
               'informative', None, 's'),
        target('effects named (hidden generator, 0.5-2 % noise)', hid.rate('named'),
               'informative', None),
        target('false alarms (hidden generator, 0.5-2 % noise)', hid.rate('false_alarm'),
               'informative', None),
    ]
    if cli_rows:
        out.append(target(f'motor-id analyze wall time, {cli_rows[0]["case"]}',
                          cli_rows[0]['wall_s'], 'informative', None, 's'))
    return out


def cli_timings(quick, candidates):
    """Part A: ``motor-id analyze`` on a clean case (and, unless quick, one with friction)."""
    n = 1000 if quick else 4000
    tmp = tempfile.mkdtemp(prefix='motor_id_bench_')
    try:
        out = [time_cli(tmp, n, False, candidates)]
        if not quick:
            out.append(time_cli(tmp, n, True, candidates))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def cli_table(cli_rows):
    """The table of part A."""
    return {'title': '`motor-id analyze` end to end (fresh process: start-up, CSV, analysis, '
                     'JSON)',
            'columns': [('case', 'case', ''), ('wall_s', 'wall s', '.2f'),
                        ('analysis_s', 'analysis s', '.2f'), ('verdict', 'verdict', ''),
                        ('correct', 'correct', '')],
            'rows': cli_rows}


def _notes(rows, generators, exact_rm, jobs):
    notes = [f'{g}: {GENERATOR_TEXT[g]}' for g in generators]
    notes += [
        "noise: white, the stated fraction of each channel's std on speed and current; "
        + ('R_m told exactly' if exact_rm else
           'R_m told off by a seeded 2-5 % of either sign'),
        ('named: the hidden effect is in the verdict or in ambiguous_with; exact: the '
         'verdict is the hidden effect alone; spurious: a compound verdict on a case with '
         'one hidden effect; encoder-grid: speed_quantization cases'),
        (f'{len(rows)} analyses in {jobs} process(es); the same command gives the same '
         "cases (seeds in the JSON); CPU time is the analysis process's own, wall time "
         'includes waiting for a loaded machine'),
        'magnitudes compared: ' + ', '.join(f'{e} {p}' for e, p in MAGNITUDE.items()),
    ]
    gen_fail = sum(bool(r.generator_error) for r in rows)
    if gen_fail:
        notes.append(f'{gen_fail} case(s) could not be generated and are left out of the '
                     'rates (listed among the failures)')
    return notes


def run(quick=False, cases=None, jobs=1, generators=GENERATORS, levels=None,
        candidates=None, exact_rm=False, cli=True, progress=None, specs=None):
    """Run the section; returns the section record (tables, targets, notes, cases).

    Parameters
    ----------
    quick : bool
        Two cases per generator at 0.5 % noise, two candidates, short records (a smoke
        test; the numbers are not benchmarks).
    cases : int, optional
        Cases per generator and noise level (default :data:`DEFAULT_CASES`).
    jobs : int
        Worker processes for the analyses.
    generators : sequence of str
        Among :data:`GENERATORS`.
    levels : sequence of float, optional
        Noise levels (fractions of each channel's std); default :data:`NOISE_LEVELS`.
    candidates : sequence of str, optional
        Candidate effects of the analysis (default all).
    exact_rm : bool
        Tell the analysis the true R_m.
    cli : bool
        Time ``motor-id analyze`` end to end (part A).
    progress : callable, optional
        ``progress(done, total, row)`` after each case.
    specs : list of CaseSpec, optional
        Run these cases instead of the plan (generators and levels follow from them).
    """
    if specs is not None:
        generators = {s.generator for s in specs}
        levels = sorted({s.noise for s in specs})
    levels = tuple(levels or ((NOISE_LEVELS[0],) if quick else NOISE_LEVELS))
    if quick and candidates is None:
        candidates = ['coulomb_friction', 'load_torque']
    generators = tuple(g for g in GENERATORS if g in generators)
    if specs is None:
        specs = build_plan(quick, cases, generators, levels, exact_rm)
    cli_rows = cli_timings(quick, candidates) if cli else []
    rows = run_cases(specs, candidates, jobs, progress)
    tables = [cli_table(cli_rows)] if cli_rows else []
    per_level = {}
    for lv in levels:
        table, per = summary_table(rows, lv, generators)
        tables.append(table)
        per_level[str(lv)] = per
    tables.append(effect_table(rows, generators, levels))
    targets = targets_for(rows, cli_rows)
    if quick:  # a handful of cases: the numbers are not rates, nothing is checked
        targets = [t if t['pass'] is None else
                   dict(t, threshold=f'{t["threshold"]} (not checked in --quick)',
                        **{'pass': None}) for t in targets]
    notes = _notes(rows, generators, exact_rm, jobs)
    return {
        'title': TITLE,
        'status': 'ok',
        'settings': {'generators': list(generators), 'noise_levels': list(levels),
                     'cases_per_level': None if quick else (cases or DEFAULT_CASES),
                     'candidates': candidates or 'all', 'jobs': jobs,
                     'r_m_error': None if exact_rm else list(R_M_ERROR)},
        'tables': tables,
        'targets': targets,
        'rates': per_level,
        'notes': notes,
        'cases': rows,
    }


def markdown_report(rec, command):
    """The section as markdown: the tables, the targets, then every failure."""
    now = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds')
    lines = ['# Discrepancy rates: latest run', '', f'- date: {now}',
             f'- command: `{command}`', '']
    for table in rec['tables']:
        lines += [f'**{table["title"]}**', '',
                  render_table(table['columns'], table['rows'], markdown=True), '']
    lines += ['| target | value | threshold | result |', '|---|---:|---|---|']
    for t in rec['targets']:
        v = '-' if t['value'] is None else f'{t["value"]:.3g}'
        res = {True: 'PASS', False: 'FAIL', None: 'info'}[t['pass']]
        lines.append(f'| {t["name"]} | {v} | {t["threshold"]} | {res} |')
    lines += ['', *[f'- {n}' for n in rec['notes']], '', '## Failures', '',
              "Each: why, generator, seed, noise, truth (the analysis' parameter names), "
              'motor, sample period, length, excitation, R_m error told; then the verdict '
              'and the three dynamic candidates with the largest held-out gain. Regenerate '
              'a case with `make_recording(CaseSpec(...))` of benchmarks/'
              'discrepancy_rates.py (the JSON has every spec).', '']
    lines += failure_lines(rec['cases']) or ['(none)']
    return '\n'.join(lines) + '\n'


def rerun_specs(path):
    """The cases of an earlier ``--json`` output that failed (see :func:`is_failure`)."""
    with open(path) as fh:
        rows = json.load(fh)['cases']
    fields = [f for f in CaseSpec.__dataclass_fields__]
    verdict = ('error', 'false_alarm', 'named', 'spurious', 'exact', 'ambiguous',
               'param_error')
    return [spec for spec, r in ((CaseSpec(**{f: r[f] for f in fields}), r) for r in rows)
            if is_failure(CaseRow(spec, **{k: r[k] for k in verdict}))]


def _levels(text):
    try:
        vals = [float(x) / 100.0 for x in text.split(',') if x.strip()]
    except ValueError:
        vals = []
    if not vals or any(not 0.0 <= v < 1.0 for v in vals):
        raise ValueError(f'--noise takes percentages separated by commas, e.g. 0.5,2,5; '
                         f'got {text!r}')
    return vals


def _parser():
    import argparse
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true', help='a few cases (smoke test)')
    parser.add_argument('--cases', type=int, metavar='N',
                        help=f'cases per generator and noise level (default {DEFAULT_CASES})')
    parser.add_argument('--jobs', type=int, default=1, metavar='J',
                        help='worker processes (default 1)')
    parser.add_argument('--generator', choices=('hidden', 'independent', 'both'),
                        default='both')
    parser.add_argument('--noise', default=None, metavar='LEVELS',
                        help='noise levels in percent, comma-separated (default 0.5,2,5)')
    parser.add_argument('--json', metavar='OUT', help='write the section record as JSON')
    parser.add_argument('--markdown', metavar='OUT',
                        help='write tables, targets and every failure as markdown')
    parser.add_argument('--failures', action='store_true',
                        help='print every miss: truth, verdict, top candidates')
    parser.add_argument('--exact-rm', action='store_true',
                        help='tell the analysis the true R_m (default: off by 2-5 %%)')
    parser.add_argument('--no-cli', action='store_true',
                        help='skip timing `motor-id analyze` end to end')
    parser.add_argument('--quiet', action='store_true', help='no per-case progress')
    parser.add_argument('--rerun', metavar='JSON',
                        help='run only the failing cases of an earlier --json output')
    return parser


def _progress(args, command):
    """The per-case callback: a progress line, and the failures so far as markdown."""
    done_rows = []

    def progress(done, total, row):
        done_rows.append(row)
        if not args.quiet:
            secs = '' if row.seconds is None else f', {row.seconds:.1f} s'
            print(f'[{done}/{total}] {row.generator} seed {row.seed} '
                  f'{100 * row.noise:g} % n={row.length} {row.effect} -> '
                  f'{row.verdict} ({is_failure(row) or "ok"}{secs})', file=sys.stderr,
                  flush=True)
        if args.markdown and done < total:
            with open(args.markdown, 'w') as fh:
                fh.write(f'# Discrepancy rates: run in progress ({done}/{total} cases)\n\n'
                         f'- command: `{command}`\n\n## Failures so far\n\n'
                         + '\n'.join(failure_lines(done_rows) or ['(none)']) + '\n')
    return progress


def _print_record(rec, failures):
    for table in rec['tables']:
        print(f'\n{table["title"]}')
        print(render_table(table['columns'], table['rows']))
    print('\ntargets')
    for t in rec['targets']:
        v = '-' if t['value'] is None else f'{t["value"]:.3g}'
        res = {True: 'PASS', False: 'FAIL', None: 'info'}[t['pass']]
        print(f'  [{res}] {t["name"]}: {v} (target {t["threshold"]})')
    print(f'({rec["seconds"]:.0f} s)')
    if failures:
        print('\nfailures')
        print('\n'.join(failure_lines(rec['cases'])) or '(none)')


def main(argv=None):
    """Command line: run the section, print its tables, write JSON / markdown.

    Returns 0, or 2 when the analysis cannot be imported (bad options exit with 2 too).
    """
    from motor_id.output import write_json

    parser = _parser()
    args = parser.parse_args(argv)
    specs = None
    if args.rerun:
        try:
            specs = rerun_specs(args.rerun)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            parser.error(f'--rerun: cannot read failing cases from {args.rerun}: {exc}')
        if not specs:
            print(f'no failing cases in {args.rerun}')
            return 0
    try:
        levels = _levels(args.noise) if args.noise else None
    except ValueError as exc:
        parser.error(str(exc))
    if args.cases is not None and args.cases < 1:
        parser.error('--cases must be >= 1')
    if args.jobs < 1:
        parser.error('--jobs must be >= 1')
    generators = GENERATORS if args.generator == 'both' else (args.generator,)
    command = ' '.join(['python benchmarks/discrepancy_rates.py'] +
                       (sys.argv[1:] if argv is None else list(argv)))
    t0 = time.perf_counter()
    try:
        rec = run(args.quick, args.cases, args.jobs, generators, levels,
                  exact_rm=args.exact_rm, cli=not args.no_cli and specs is None,
                  progress=_progress(args, command), specs=specs)
    except Skip as exc:
        print(f'skipped: {exc}', file=sys.stderr)
        return 2
    rec['seconds'] = time.perf_counter() - t0
    _print_record(rec, args.failures)
    if args.json:
        write_json({**rec, 'cases': [r.to_dict() for r in rec['cases']],
                    'rates': {lv: {g: r.to_dict() for g, r in per.items()}
                              for lv, per in rec['rates'].items()}}, args.json)
    if args.markdown:
        with open(args.markdown, 'w') as fh:
            fh.write(markdown_report(rec, command))
    return 0


if __name__ == '__main__':
    sys.exit(main())
