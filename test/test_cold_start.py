"""Cold start: numba kernels come from the on-disk cache, heavy imports wait until used."""

import json
import os
import subprocess
import sys

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

WARM_UP = ('import json; from motor_id import simulate; '
           'print(json.dumps(simulate.warm_up().to_dict()))')


def _fresh(code, **env):
    """Run ``code`` in a new Python process; returns the JSON it printed last."""
    full_env = dict(os.environ, PYTHONPATH=REPO + os.pathsep + os.environ.get('PYTHONPATH', ''),
                    **env)
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          env=full_env, timeout=300, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_second_fresh_process_loads_every_kernel_from_the_cache(tmp_path):
    cache = tmp_path / 'numba-cache'  # as NUMBA_CACHE_DIR for a read-only install
    first = _fresh(WARM_UP, NUMBA_CACHE_DIR=str(cache))
    second = _fresh(WARM_UP, NUMBA_CACHE_DIR=str(cache))
    assert first['compiled'] == 4 and first['kernels'] == 4
    assert second['compiled'] == 0 and second['kernels'] == 4
    assert second['cache_dir'].startswith(str(cache))
    assert any(name.endswith('.nbi') for _, _, files in os.walk(cache) for name in files)


def test_default_cache_is_used_by_the_next_fresh_process():
    # numba's own choice: __pycache__ next to the module, or its user-wide directory
    _fresh(WARM_UP)  # compiles only if simulate.py changed since the last run
    again = _fresh(WARM_UP)
    assert again['compiled'] == 0 and again['kernels'] == 4
    assert os.path.isdir(again['cache_dir'])


def test_core_modules_import_without_numba_scipy_or_matplotlib():
    code = ('import json, sys\n'
            'import motor_id.elman, motor_id.excitation, motor_id.ga, motor_id.metrics\n'
            'import motor_id.model, motor_id.simulate\n'
            'print(json.dumps(sorted(m for m in ("numba", "scipy", "matplotlib") '
            'if m in sys.modules)))')
    assert _fresh(code) == []


def test_warm_up_in_process_reports_ready_kernels():
    from motor_id import simulate

    first = simulate.warm_up()
    again = simulate.warm_up()
    assert first.kernels == again.kernels == 4
    assert again.compiled == 0
    assert again.seconds >= 0.0 and list(again.to_dict()) == ['seconds', 'compiled',
                                                              'kernels', 'cache_dir']
