"""The package builds with colcon and its installed console scripts start (Jazzy layout)."""

import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from motor_id.testing.procs import domain_id
from motor_id.testing.ros import REPO, ros_env

COLCON = shutil.which('colcon') or os.path.join(os.path.dirname(sys.executable), 'colcon')


@pytest.fixture(scope='module')
def workspace(tmp_path_factory):
    ws = tmp_path_factory.mktemp('ws')
    (ws / 'src').mkdir()
    os.symlink(REPO, ws / 'src' / 'motor_id')
    proc = subprocess.run([COLCON, 'build', '--packages-select', 'motor_id'], cwd=ws,
                          capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, PYTHONDONTWRITEBYTECODE='1'))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return ws


def installed(ws, *cmd, domain, timeout=60, run_for=None):
    """Run an installed script with the workspace sourced, as `ros2 run` would."""
    env = ros_env(domain)
    env['PYTHONPATH'] = env['PYTHONPATH'].replace(REPO + os.pathsep, '')
    script = ' '.join(cmd)
    proc = subprocess.Popen(['bash', '-c', f'source {ws}/install/setup.bash && cd / && '
                             f'exec {script}'], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    if run_for:
        time.sleep(run_for)
        proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=timeout)
    return proc.returncode, out, err


def test_colcon_installs_console_scripts_and_data(workspace):
    lib = workspace / 'install' / 'motor_id' / 'lib' / 'motor_id'
    for name in ('driver', 'identifier', 'motor-id'):
        assert (lib / name).exists(), name
    share = workspace / 'install' / 'motor_id' / 'share' / 'motor_id'
    assert (share / 'package.xml').exists()
    assert (share / 'config' / 'driver.yaml').exists()
    assert (share / 'config' / 'identifier.yaml').exists()
    assert (workspace / 'install' / 'motor_id' / 'share' / 'ament_index' / 'resource_index'
            / 'packages' / 'motor_id').exists()


def test_installed_identifier_runs_and_stops_on_sigint(workspace):
    lib = workspace / 'install' / 'motor_id' / 'lib' / 'motor_id'
    share = workspace / 'install' / 'motor_id' / 'share' / 'motor_id'
    rc, out, err = installed(workspace, str(lib / 'identifier'), '--ros-args', '--params-file',
                             str(share / 'config' / 'identifier.yaml'),
                             domain=domain_id('colcon-ident'), run_for=4.0)
    assert rc == 0, out + err
    assert 'Traceback' not in err


def test_installed_driver_rejects_a_bad_parameter(workspace):
    lib = workspace / 'install' / 'motor_id' / 'lib' / 'motor_id'
    rc, out, err = installed(workspace, str(lib / 'driver'), '--ros-args', '-p',
                             'sample_period:=-1.0', domain=domain_id('colcon-driver'))
    assert rc != 0
    assert 'sample_period' in out + err and 'Traceback' not in err


def test_installed_cli_runs_from_the_workspace(workspace, tmp_path):
    lib = workspace / 'install' / 'motor_id' / 'lib' / 'motor_id'
    rc, out, err = installed(workspace, str(lib / 'motor-id'), 'simulate', '--out',
                             str(tmp_path / 'x.csv'), '--samples', '100',
                             domain=domain_id('colcon-cli'))
    assert rc == 0, err
    assert (tmp_path / 'x.csv').exists()
