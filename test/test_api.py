"""The public API: ``import motor_id`` is cheap and changes nothing, its names resolve, and
their examples (doctests) run."""

import doctest
import importlib
import os
import re
import subprocess
import sys

import pytest

import motor_id

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLE_MODULES = sorted({'motor_id', 'motor_id.errors', *(
    getattr(motor_id, name).__module__ for name in motor_id.__all__)})
"""Every module that holds a public name: their examples are the API's documentation."""
MIN_EXAMPLE_LINES = 10
"""Issue 29 item 4: at least this many doctest lines among the public names."""
STARTING_POINTS = ('load_recording', 'Recording', 'Identifier', 'fit_report',
                   'DiscrepancyAnalysis', 'validate', 'MotorIdError')
"""Load a recording, fit, analyze, validate, the errors: each shows how it is used."""


def _fresh(code, **env):
    """Run ``code`` in a fresh interpreter with the BLAS variables unset (then ``env``)."""
    base = {k: v for k, v in os.environ.items()
            if k not in ('OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS')}
    base['PYTHONPATH'] = ROOT + os.pathsep + base.get('PYTHONPATH', '')
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          env={**base, **env}, timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout.split()


def test_import_is_cheap_and_sets_nothing():
    """``import motor_id`` loads neither numpy nor a submodule but the errors, and leaves
    the BLAS variables unset."""
    out = _fresh('import os, sys, motor_id\n'
                 "print('numpy' in sys.modules, os.environ.get('OPENBLAS_NUM_THREADS'),\n"
                 "      sorted(m for m in sys.modules if m.startswith('motor_id')))")
    assert out == ['False', 'None', "['motor_id',", "'motor_id.errors']"]


def test_entry_points_limit_blas_threads():
    """The nodes set one BLAS thread before numpy loads; a value already set stays."""
    code = ('import os, sys, motor_id.nodes\n'
            "print('numpy' in sys.modules, os.environ['OPENBLAS_NUM_THREADS'],"
            " os.environ['MKL_NUM_THREADS'])")
    assert _fresh(code) == ['False', '1', '1']
    assert _fresh(code, OPENBLAS_NUM_THREADS='2') == ['False', '2', '1']


def test_command_line_limits_blas_threads(monkeypatch):
    """``motor-id`` sets them first thing, before a subcommand's module loads."""
    from motor_id.cli import main
    for var in ('OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
        monkeypatch.delenv(var, raising=False)
    with pytest.raises(SystemExit):
        main(['--no-such-command'])
    assert os.environ['OPENBLAS_NUM_THREADS'] == '1'
    assert os.environ['MKL_NUM_THREADS'] == '1'


def test_public_names_resolve():
    """Every name of ``__all__`` is an attribute with a docstring, listed by ``dir``."""
    for name in motor_id.__all__:
        obj = getattr(motor_id, name)
        assert obj.__doc__, name
        assert name in dir(motor_id)
    with pytest.raises(AttributeError, match='no_such_name'):
        motor_id.no_such_name  # noqa: B018


@pytest.mark.parametrize('module', EXAMPLE_MODULES)
def test_examples_run(module):
    """The module's examples give the outputs they show (rounded values, fixed seeds)."""
    mod = importlib.import_module(module)
    result = doctest.testmod(mod, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
                             verbose=False, report=True)
    assert result.failed == 0, f'{result.failed} of {result.attempted} examples failed'


def test_public_names_have_examples():
    """Each name a user starts from shows an example (the results they return are shown
    there too), and the examples add up to at least MIN_EXAMPLE_LINES lines."""
    finder = doctest.DocTestFinder(recurse=False)
    counts = {name: sum(len(t.examples) for t in finder.find(getattr(motor_id, name), name))
              for name in motor_id.__all__}
    for name in STARTING_POINTS:
        assert counts[name] >= 2, f'{name} shows no example'
    assert sum(counts.values()) >= MIN_EXAMPLE_LINES, counts


def test_readme_python_example_runs(tmp_path, monkeypatch, capsys):
    """The README's Python example runs as printed, on two simulated CSV runs of a motor
    with dry friction (1,000 samples each, so that it stays quick)."""
    import numpy as np

    from motor_id.data.csv_io import write_csv
    from motor_id.excitation import bipolar_steps
    from motor_id.model import Plant
    from motor_id.simulate import simulate_recording
    from motor_id.testing.recordings import SI_MOTOR

    with open(os.path.join(ROOT, 'README.md'), encoding='utf-8') as fh:
        blocks = re.findall(r'```python\n(.*?)```', fh.read(), re.S)
    assert len(blocks) == 1
    t = np.arange(1000) * 0.01
    plant = Plant(SI_MOTOR, 'voltage', {'coulomb_friction': {'T_c': 0.1}})
    for name, seed in (('motor.csv', 1), ('other_run.csv', 2)):
        write_csv(simulate_recording(plant, t, bipolar_steps(t), 0.005, 0.01,
                                     random_state=seed), tmp_path / name)
    monkeypatch.chdir(tmp_path)
    scope = {}
    exec(compile(blocks[0], 'README.md', 'exec'), scope)
    out = capsys.readouterr().out
    assert scope['analysis'].verdict == 'coulomb_friction', out
    kv = scope['ff'].kV
    assert kv.std < 0.05 * kv.value, out
    assert scope['ff'].units['kV'] == 'V s/rad', out
    assert scope['score'].channels['speed']['fit_percent'] > 95, out


def test_fit_errors_cover_what_a_fit_raises():
    """One tuple of what a failed fit may raise (issue 29 item 5: there were two, with
    different contents): numpy's LinAlgError and scipy's RuntimeError included, a bug's
    TypeError or an interrupt not."""
    import numpy as np

    from motor_id.errors import FIT_ERRORS, IdentificationError
    for exc in (np.linalg.LinAlgError('singular'), FloatingPointError('overflow'),
                IdentificationError('diverges'), RuntimeError('solver')):
        assert isinstance(exc, FIT_ERRORS), exc
    for exc in (TypeError('bug'), KeyboardInterrupt(), AttributeError('bug')):
        assert not isinstance(exc, FIT_ERRORS), exc


FLAGS_PENDING: set[str] = set()
"""Modules whose raises still name command-line flags (issue 29 item 5): none since the
experiment's settings name their parameters; the test fails once one of them names none,
so that its entry goes too."""


def _raises_naming_flags():
    """``{module: [line, ...]}`` of raises outside motor_id/cli whose text names a flag."""
    import ast

    found = {}
    for folder, _, names in os.walk(os.path.join(ROOT, 'motor_id')):
        rel_folder = os.path.relpath(folder, ROOT).replace(os.sep, '/')
        if rel_folder.startswith('motor_id/cli'):
            continue
        for name in sorted(n for n in names if n.endswith('.py')):
            rel = f'{rel_folder}/{name}'
            with open(os.path.join(ROOT, rel), encoding='utf-8') as fh:
                tree = ast.parse(fh.read())
            for node in ast.walk(tree):
                if isinstance(node, ast.Raise) and node.exc is not None and any(
                        isinstance(c, ast.Constant) and isinstance(c.value, str)
                        and re.search(r'(?<![\w-])--[a-z]', c.value)
                        for c in ast.walk(node.exc)):
                    found.setdefault(rel, []).append(node.lineno)
    return found


def test_the_library_names_parameters_not_flags():
    """Outside motor_id/cli an error names a setting as the library calls it (``R_m``,
    ``init_samples``) and lists it in ``params``; the command line adds its flags."""
    found = _raises_naming_flags()
    new = {k: v for k, v in found.items() if k not in FLAGS_PENDING}
    assert not new, f'raises naming command-line flags: {new}'
    assert not FLAGS_PENDING - set(found), 'these name no flag now: remove them from pending'


def test_command_line_adds_its_flags():
    """``params`` become the subcommand's flags; a flag the subcommand lacks is left out."""
    from motor_id.cli.flags import flag_hint
    from motor_id.errors import ConfigError

    exc = ConfigError('R_m is required', params=('R_m', 'init_samples', 'R_m'))
    assert exc.params == ('R_m', 'init_samples', 'R_m') and str(exc) == 'R_m is required'
    assert flag_hint(exc.params) == ' (command line: -R/--resistance, --init-samples)'
    fleet_help = 'usage: motor-id fleet [--profile FLEET.yaml] [--robot-from RULE] [--out DIR]'
    assert flag_hint(('speed', 'robot_from', 'out_dir'), fleet_help) == \
        ' (command line: --robot-from, --out)'
    assert flag_hint(('input',), 'usage: ... [--input-kind KIND]') == ''
    assert flag_hint(()) == ''
