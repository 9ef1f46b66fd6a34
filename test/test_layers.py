"""The import layers of .importlinter hold: lower modules never import higher ones."""

import os
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_import_layers_hold():
    exe = shutil.which('lint-imports', path=os.path.dirname(sys.executable)) \
        or shutil.which('lint-imports')
    if exe is None:
        pytest.fail('lint-imports (import-linter, in the [test] extra) is not installed')
    proc = subprocess.run([exe, '--config', os.path.join(ROOT, '.importlinter')], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert '0 broken' in proc.stdout, proc.stdout[-2000:]


def test_no_private_apis_of_other_packages():
    """No reach into mcap_ros2's or rclpy's private modules outside one fenced shim."""
    proc = subprocess.run(['git', 'grep', '-n', '-E',
                           r'mcap_ros2\._|implementation_singleton|\._callbacks',
                           '--', 'motor_id', 'test'], cwd=ROOT, capture_output=True,
                          text=True)
    hits = [ln for ln in proc.stdout.splitlines()
            if 'test_layers.py' not in ln and 'shim' not in ln.split(':', 1)[0]]
    assert not hits, '\n'.join(hits)
