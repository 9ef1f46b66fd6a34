"""Smoke test of benchmarks/run.py: the --quick run prints every section, writes JSON and
exits non-zero when a target it checks is missed."""

import json
import os
import subprocess
import sys

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(REPO, 'benchmarks', 'run.py')
SECTIONS = ('fit_speed', 'crlb', 'scaling', 'streaming', 'discrepancy', 'cold_start',
            'data_io')


@pytest.mark.slow   # every section end to end (ROS nodes, fresh processes): about 20 s
def test_benchmarks_quick_run_writes_tables_and_json(tmp_path):
    out = tmp_path / 'bench.json'
    md = tmp_path / 'bench.md'
    env = dict(os.environ, PYTHONPATH=REPO + os.pathsep + os.environ.get('PYTHONPATH', ''))
    proc = subprocess.run([sys.executable, SCRIPT, '--quick', '--json', str(out),
                           '--markdown', str(md)], cwd=str(tmp_path), env=env,
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout + proc.stderr  # 1: a target was missed
    for k, name in enumerate(SECTIONS, 1):
        assert f'== {k}. ' in proc.stdout and f'[{name}]' in proc.stdout, proc.stdout
    result = json.loads(out.read_text())
    assert result['quick'] is True
    assert result['date'] and 'commit' in result['git']
    assert result['machine']['cpu_count'] >= 1 and result['machine']['python']
    assert list(result['sections']) == list(SECTIONS)
    for name, sec in result['sections'].items():
        status = sec['status']
        assert status == 'ok' or status.startswith('skipped: '), \
            (name, status, sec.get('traceback'))
        if status != 'ok':
            continue
        assert sec['tables'], name
        for table in sec['tables']:
            keys = [c[0] for c in table['columns']]
            assert table['rows'], (name, table['title'])
            for row in table['rows']:
                assert set(keys) <= set(row), (name, table['title'], keys, sorted(row))
        for t in sec['targets']:
            assert {'name', 'value', 'threshold', 'pass'} <= set(t)
    fit = result['sections']['fit_speed']
    methods = {r['method'] for r in fit['tables'][0]['rows']}
    assert {'motor_id GA', 'pygad (1 solution / call)', 'scipy DE (vectorized)', 'pycma',
            'scipy least_squares (defaults)'} <= methods
    assert md.read_text().startswith('# motor_id benchmarks')


def test_benchmarks_only_selects_sections(tmp_path):
    out = tmp_path / 'bench.json'
    proc = subprocess.run([sys.executable, SCRIPT, '--quick', '--only', 'crlb',
                           '--json', str(out)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert list(json.loads(out.read_text())['sections']) == ['crlb']
    bad = subprocess.run([sys.executable, SCRIPT, '--only', 'nonsense'],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and 'unknown section' in bad.stderr


def _load_run_module():
    import importlib.util
    spec = importlib.util.spec_from_file_location('bench_run', SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_benchmarks_exit_status_reports_a_missed_target(tmp_path, monkeypatch):
    bench = _load_run_module()

    def fake_section(name, quick, blas_one):
        ok = {'name': 'fast enough', 'value': 0.1, 'threshold': '< 0.2 s', 'unit': 's',
              'pass': True}
        info = {**ok, 'name': 'informative', 'pass': None}
        missed = {**ok, 'name': 'too slow', 'value': 0.5, 'pass': name == 'crlb'}
        return {'title': name, 'status': 'ok', 'tables': [], 'seconds': 0.0,
                'targets': [ok, info, missed],
                'load_average': {'before': None, 'after': None}}

    monkeypatch.setattr(bench, 'run_section', fake_section)
    assert bench.main(['--quick', '--only', 'crlb']) == 0
    assert bench.main(['--quick', '--only', 'crlb,scaling']) == 1
    result = {'sections': {'scaling': fake_section('scaling', True, None),
                           'crlb': {'status': 'error: RuntimeError: boom'}}}
    lines = bench.failures(result)
    assert lines == ['scaling: too slow: 0.5 s (target < 0.2 s)',
                     'crlb: error: RuntimeError: boom']
