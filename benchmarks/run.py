#!/usr/bin/env python3
"""Benchmarks of motor_id against the tools users would pick instead, and the statistical limit.

Usage::

    python benchmarks/run.py [--json OUT] [--markdown OUT] [--quick] [--only SECTION ...]

Sections (in order): fit_speed, crlb, scaling, streaming, discrepancy, cold_start. Each
prints its tables and pass/fail targets; ``--json`` writes everything (with the date, the
git commit and the machine) and ``--markdown`` a readable summary. ``--quick`` runs every
section in a reduced form (seconds, not minutes) for smoke tests; its numbers are not
benchmarks, but its targets (looser, chosen to hold on a loaded 2-core machine) are
checked all the same.

Exit status: 0 when every target that was checked passed, 1 when one was missed or a
section failed with an error (the list is printed last), 2 for bad options.
"""

import argparse
import datetime
import importlib
import json
import os
import platform
import subprocess
import sys
import time
import traceback

from motor_id.blas import limit_threads, THREAD_VARIABLES

limit_threads()  # before a section loads numpy: one BLAS thread, as the product runs

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

SECTIONS = {
    'fit_speed': 'fit_speed',
    'crlb': 'crlb',
    'scaling': 'scaling',
    'streaming': 'streaming',
    'discrepancy': 'discrepancy_rates',
    'cold_start': 'cold_start',
    'data_io': 'data_io',
}
"""Section name -> module in this folder (each has ``TITLE`` and ``run(quick, ...)``)."""


def git_info():
    """Commit of the repository and whether tracked files differ from it."""
    def git(*args):
        return subprocess.run(['git', '-C', REPO] + list(args), capture_output=True,
                              text=True, timeout=10).stdout.strip()
    try:
        commit = git('rev-parse', 'HEAD') or None
        dirty = bool(git('status', '--porcelain', '--untracked-files=no'))
        branch = git('rev-parse', '--abbrev-ref', 'HEAD') or None
    except (OSError, subprocess.SubprocessError):
        return {'commit': None, 'dirty': None, 'branch': None}
    return {'commit': commit, 'dirty': dirty, 'branch': branch}


def _version(module):
    try:
        return importlib.import_module(module).__version__
    except (ImportError, AttributeError):
        return None


def machine_info():
    """CPU count, Python version, platform, library versions, BLAS threads."""
    cpu = None
    try:
        with open('/proc/cpuinfo') as fh:
            for line in fh:
                if line.startswith('model name'):
                    cpu = line.split(':', 1)[1].strip()
                    break
    except OSError:
        pass
    info = {'cpu_count': os.cpu_count(), 'cpu_model': cpu,
            'python': platform.python_version(), 'implementation':
            platform.python_implementation(), 'platform': platform.platform(),
            'versions': {m: _version(m) for m in
                         ('numpy', 'scipy', 'numba', 'pygad', 'cma', 'psutil')},
            'blas': None,
            'blas_threads_env': {v: os.environ.get(v) for v in THREAD_VARIABLES}}
    try:
        from threadpoolctl import threadpool_info
        info['blas'] = [{k: d.get(k) for k in ('internal_api', 'num_threads', 'version')}
                        for d in threadpool_info()]
    except ImportError:
        pass
    return info


def load_average():
    """1-minute load average (None where unavailable)."""
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return None


def run_section(name, quick, blas_one):
    """Run one section and return its record; failures become a status, not a crash."""
    module = importlib.import_module(SECTIONS[name])
    from common import Skip
    t0 = time.perf_counter()
    load0 = load_average()
    try:
        if name == 'fit_speed':
            rec = module.run(quick=quick, blas_one=blas_one)
        else:
            rec = module.run(quick=quick)
    except Skip as exc:
        rec = {'title': module.TITLE, 'status': f'skipped: {exc}'}
    except Exception as exc:  # noqa: BLE001 - report any failure and go on
        rec = {'title': module.TITLE, 'status': f'error: {type(exc).__name__}: {exc}',
               'traceback': traceback.format_exc()}
    rec['seconds'] = time.perf_counter() - t0
    rec['load_average'] = {'before': load0, 'after': load_average()}
    return rec


def print_section(number, name, rec, stream=sys.stdout):
    """Print one section's tables, targets and notes."""
    from common import render_table
    w = stream.write
    w(f'\n== {number}. {rec["title"]} [{name}] ==\n')
    if rec['status'] != 'ok':
        w(f'{rec["status"]}\n')
        return
    for table in rec.get('tables', []):
        w(f'\n{table["title"]}\n')
        w(render_table(table['columns'], table['rows']) + '\n')
    if rec.get('targets'):
        w('\ntargets\n')
        for t in rec['targets']:
            w(f'  [{_verdict(t)}] {t["name"]}: {_value(t)} (target {t["threshold"]})\n')
    w(f'({rec["seconds"]:.1f} s; load average {rec["load_average"]["before"]} -> '
      f'{rec["load_average"]["after"]})\n')


def _verdict(t):
    return {True: 'PASS', False: 'FAIL', None: 'info'}[t['pass']]


def _value(t):
    if t['value'] is None:
        return '-'
    if '%' in str(t['threshold']) and 'coverage' in t['name']:
        return f'{100 * t["value"]:.1f} %'
    return f'{t["value"]:.3g}{(" " + t["unit"]) if t["unit"] else ""}'


def markdown(result):
    """The whole run as a markdown document."""
    from common import render_table
    m = result['machine']
    g = result['git']
    lines = ['# motor_id benchmarks', '',
             f'- date: {result["date"]}',
             f'- commit: `{g["commit"]}`' + (' (working tree had uncommitted changes)'
                                             if g['dirty'] else ''),
             f'- machine: {m["cpu_count"]} CPU(s) {m["cpu_model"] or ""}, Python '
             f'{m["python"]}, {m["platform"]}',
             '- libraries: ' + ', '.join(f'{k} {v}' for k, v in m['versions'].items() if v),
             f'- command: `{result["command"]}` ({result["seconds"]:.0f} s)', '']
    if result['quick']:
        lines += ['**--quick run: reduced sizes, the numbers are not benchmarks.**', '']
    for name, rec in result['sections'].items():
        k = list(SECTIONS).index(name) + 1
        lines += [f'## {k}. {rec["title"]}', '']
        if rec['status'] != 'ok':
            lines += [f'*{rec["status"]}*', '']
            continue
        for table in rec.get('tables', []):
            lines += [f'**{table["title"]}**', '',
                      render_table(table['columns'], table['rows'], markdown=True), '']
        if rec.get('targets'):
            lines += ['| target | value | threshold | result |', '|---|---:|---|---|']
            lines += [f'| {t["name"]} | {_value(t)} | {t["threshold"]} | {_verdict(t)} |'
                      for t in rec['targets']]
            lines.append('')
        for note in rec.get('notes', []):
            lines.append(f'- {note}')
        la = rec['load_average']
        lines += [f'- section time {rec["seconds"]:.0f} s, load average {la["before"]} -> '
                  f'{la["after"]}', '']
    return '\n'.join(lines)


def failures(result):
    """Missed targets and failed sections of a run, as printable lines."""
    out = []
    for name, rec in result['sections'].items():
        if rec['status'].startswith('error'):
            out.append(f'{name}: {rec["status"]}')
        for t in rec.get('targets', []) if rec['status'] == 'ok' else []:
            if t['pass'] is False:
                out.append(f'{name}: {t["name"]}: {_value(t)} (target {t["threshold"]})')
    return out


def main(argv=None):
    """Parse options, run the sections, print, write JSON / markdown.

    Returns 0 when every checked target passed, 1 otherwise (see :func:`failures`).
    """
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--json', metavar='OUT', help='write all results as JSON')
    parser.add_argument('--markdown', metavar='OUT', help='write a markdown summary')
    parser.add_argument('--quick', action='store_true',
                        help='reduced sizes for a smoke test (seconds)')
    parser.add_argument('--only', action='append', default=[], metavar='SECTION',
                        help=f'run only these sections (repeatable or comma-separated): '
                             f'{", ".join(SECTIONS)}')
    parser.add_argument('--blas-threads', type=int, metavar='N',
                        help='limit BLAS threads for the whole run (threadpoolctl)')
    args = parser.parse_args(argv)
    only = [s.strip() for item in args.only for s in item.split(',') if s.strip()]
    unknown = [s for s in only if s not in SECTIONS]
    if unknown:
        parser.error(f'unknown section(s) {unknown}; choose from {list(SECTIONS)}')
    names = [s for s in SECTIONS if not only or s in only]

    from functools import partial

    from common import blas_limit

    from motor_id.output import to_jsonable
    try:
        import threadpoolctl  # noqa: F401
        blas_one = partial(blas_limit, 1)
    except ImportError:
        blas_one = None
    started = time.perf_counter()
    extra = sys.argv[1:] if argv is None else list(argv)
    now = datetime.datetime.now(datetime.timezone.utc)
    result = {'date': now.isoformat(timespec='seconds'),
              'command': ' '.join(['python benchmarks/run.py'] + extra),
              'quick': args.quick, 'git': git_info(), 'machine': machine_info(),
              'blas_threads': args.blas_threads, 'sections': {}}
    print(f'motor_id benchmarks {result["date"]}  commit {result["git"]["commit"]}  '
          f'{result["machine"]["cpu_count"]} CPU(s), Python {result["machine"]["python"]}'
          + ('  [--quick: not benchmark numbers]' if args.quick else ''))
    with blas_limit(args.blas_threads):
        for k, name in enumerate(SECTIONS, 1):
            if name not in names:
                continue
            rec = run_section(name, args.quick, blas_one)
            result['sections'][name] = rec
            print_section(k, name, rec)
            sys.stdout.flush()
    result['seconds'] = time.perf_counter() - started
    print(f'\ntotal {result["seconds"]:.1f} s')
    if args.json:
        with open(args.json, 'w') as fh:
            json.dump(to_jsonable(result), fh, indent=1)
            fh.write('\n')
        print(f'wrote {args.json}')
    if args.markdown:
        with open(args.markdown, 'w') as fh:
            fh.write(markdown(result))
        print(f'wrote {args.markdown}')
    missed = failures(result)
    if missed:
        print(f'\n{len(missed)} target(s) missed or section(s) failed:')
        for line in missed:
            print(f'  {line}')
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
