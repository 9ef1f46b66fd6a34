"""The linters hold: ruff (ruff.toml) and mypy (mypy.ini) pass, as import-linter does."""

import os
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _tool(name):
    """The executable ``name`` of this interpreter's environment (the [test] extra)."""
    exe = shutil.which(name, path=os.path.dirname(sys.executable)) or shutil.which(name)
    if exe is None:
        pytest.fail(f'{name} (in the [test] extra) is not installed')
    return exe


def _run(args):
    proc = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-6000:] + proc.stderr[-2000:]


def test_ruff_passes():
    _run([_tool('ruff'), 'check', '--no-cache', 'motor_id', 'test', 'benchmarks'])


def test_mypy_passes():
    _run([_tool('mypy'), '--config-file', os.path.join(ROOT, 'mypy.ini'), 'motor_id'])
