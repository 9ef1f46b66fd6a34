"""The motor-id CLI as a user runs it: real subprocesses, files in tmp_path."""

import json
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def motor_id(*args, check=True):
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get('PYTHONPATH', ''))
    proc = subprocess.run([sys.executable, '-m', 'motor_id.cli', *map(str, args)],
                          capture_output=True, text=True, env=env, timeout=300)
    if check and proc.returncode != 0:
        raise AssertionError(f'exit {proc.returncode}\n{proc.stdout}\n{proc.stderr}')
    return proc


@pytest.fixture(scope='module')
def paper_csv(tmp_path_factory):
    d = tmp_path_factory.mktemp('cli')
    params = d / 'motor.json'
    params.write_text(json.dumps({'J': 0.052, 'K_T': 0.66, 'K_b': 0.66, 'B': 0.002,
                                  'L_m': 0.0345, 'R_m': 2.3}))
    out = d / 'paper.csv'
    motor_id('simulate', '--params', params, '--excitation', 'paper_steps', '--out', out,
             '--noise', '0.005,0.01', '--seed', '4')
    return out


def test_fit_prints_table_and_writes_json_and_plot(paper_csv, tmp_path):
    js, png = tmp_path / 'fit.json', tmp_path / 'fit.png'
    proc = motor_id('fit', paper_csv, '--resistance', '2.3', '--json', js, '--plot', png)
    assert 'identifiability: rank 4 of 4' in proc.stdout
    assert 'not determined' not in proc.stdout
    assert 'GA [' in proc.stderr  # progress while the GA runs
    report = json.loads(js.read_text())
    assert set(report['parameters']) == {'J', 'K_T', 'K_b', 'B', 'L_m', 'R_m'}
    for name, truth in (('J', 0.052), ('K_T', 0.66), ('L_m', 0.0345)):
        p = report['parameters'][name]
        assert p['determined'] and abs(p['value'] - truth) < max(4 * p['std'], 0.01 * truth)
    assert report['ga']['evaluations'] == 3200 and len(report['ga']['history']) == 160
    assert png.stat().st_size > 20000 and png.read_bytes()[:4] == b'\x89PNG'


def test_fit_speed_only_says_not_determined(tmp_path):
    out = tmp_path / 's.csv'
    motor_id('simulate', '--out', out, '--no-current', '--noise', '0.005', '--samples', '1500')
    js = tmp_path / 'f.json'
    proc = motor_id('fit', out, '-R', '2.3', '--method', 'paper', '--json', js, '-q')
    assert proc.stdout.count('not determined by this data') == 5
    report = json.loads(js.read_text())
    assert all(report['parameters'][n]['value'] is None for n in ('J', 'K_T', 'K_b', 'B'))
    assert len(report['identifiable_combinations']) == 3


def test_user_errors_are_one_line_exit_2(tmp_path):
    bad = tmp_path / 'bad.csv'
    bad.write_text('time,voltage\n0,1\n')
    proc = motor_id('fit', bad, '-R', '2.3', check=False)
    assert proc.returncode == 2
    assert proc.stderr.strip().count('\n') == 0 and 'missing column(s) speed' in proc.stderr
    assert 'Traceback' not in proc.stderr
    proc = motor_id('fit', tmp_path / 'none.csv', '-R', '2.3', check=False)
    assert proc.returncode == 2 and 'cannot read' in proc.stderr
    proc = motor_id('simulate', '--out', tmp_path / 'x.csv', '--effect', 'nonsense=1',
                    check=False)
    assert proc.returncode == 2 and "unknown effect 'nonsense'" in proc.stderr
