"""`motor-id demo --robot`: the simulated ros2_control robot and `motor-id experiment` on
its joint, end to end, as a user runs it (the wheel: slow; test_experiment_node has it
too); and stopping the arm demo any way mid-experiment.

Real processes over DDS on the module's ROS domain; every wait is on an event (a line of
the demo's output, an exit), never a fixed time.
"""

import json
import os
import signal
import subprocess
import sys
import time

import psutil
import pytest
from rosbags.highlevel import AnyReader

from motor_id.cli.demo_robot import ROBOTS
from motor_id.testing.procs import Process, wait_until
from motor_id.testing.ros import ros_env

TOPIC = '/forward_command_controller/commands'
ZERO_WITHIN = 0.5
"""Seconds from the signal to the demo to 0 received by the robot."""


def demo_args(out, domain, robot='wheel'):
    # the tests share the machine: the watchdog the demo had for it
    return ['-m', 'motor_id.cli', 'demo', '--robot', robot, '--fast', '--out', str(out),
            '--domain', str(domain), '--watchdog', '0.5']


def feedforward(out):
    report = json.loads((out / 'report.json').read_text())
    truth = json.loads((out / 'truth.json').read_text())
    return report['controller']['feedforward'], truth['feedforward'], truth


def run_demo(out, domain, robot):
    proc = subprocess.run([sys.executable, *demo_args(out, domain, robot)],
                          env=ros_env(domain), capture_output=True, text=True, timeout=900)
    lines = [x for x in proc.stdout.splitlines() if ' gain ' not in x
             and 'simulation error:' not in x]     # the analysis' candidates, shortened
    assert proc.returncode == 0, '\n'.join(lines) + proc.stderr[-3000:]
    assert 'Traceback' not in proc.stdout + proc.stderr
    return proc


def check_table(proc, found, true, names):
    """The printed table: each identified value, its error bar and the true one on one
    line; no other constant."""
    rows = {line.split()[0]: line.split() for line in proc.stdout.splitlines()
            if line.split() and line.split()[0] in ('kS', 'kV', 'kA', 'kG', 'offset')}
    assert sorted(rows) == sorted(names)
    for name in names:
        assert found[name]['std'] > 0 and found[name]['unit'] == true[name]['unit']
        row = rows[name]
        assert float(row[1]) == pytest.approx(found[name]['value'], rel=1e-3)
        assert float(row[2]) == pytest.approx(found[name]['std'], rel=0.05)
        assert float(row[3]) == pytest.approx(true[name]['value'], rel=1e-3)


def check_outputs(out, robot, controller_joints):
    limit = ROBOTS[robot].max_command
    truth = json.loads((out / 'truth.json').read_text())
    assert truth['commands'][-1]['values'] == [0.0] * controller_joints
    assert max(abs(v) for c in truth['commands'] for v in c['values']) <= limit
    log = json.loads((out / 'experiment.json').read_text())
    assert log['complete'] and log['max_command'] == limit
    with AnyReader([out / 'recording.mcap']) as reader:
        assert {TOPIC, '/joint_states', '/samples'} <= {c.topic for c in reader.connections}
    return truth


# was slow (issue 26): about 1 arm recording in 4 sent the simulation stage into a
# diverged model (resonance at 1 kHz) with every constant not determined; the stage now
# leaves such a model for the simpler rival (test_simulation_guard, on such a recording);
# 10 of 10 runs passed at a load average of 17 on 2 cores (none of them met that model)
def test_arm_demo_identifies_gravity_and_the_feedforward(tmp_path, ros_domain):
    """The issue's targets on the simulated arm, and never past its travel."""
    out = tmp_path / 'arm'
    proc = run_demo(out, ros_domain, 'arm')
    found, true, _ = feedforward(out)
    assert found['kG']['value'] == pytest.approx(true['kG']['value'], rel=0.10)
    assert found['offset']['value'] == pytest.approx(true['offset']['value'], abs=0.1)
    assert found['kV']['value'] == pytest.approx(true['kV']['value'], rel=0.10)
    assert found['kS']['value'] == pytest.approx(true['kS']['value'], abs=0.1)
    assert found['kA']['value'] == pytest.approx(true['kA']['value'], rel=0.30)
    check_table(proc, found, true, ('kS', 'kV', 'kA', 'kG', 'offset'))
    truth = check_outputs(out, 'arm', 3)
    assert -2.3 <= truth['position']['min'] and truth['position']['max'] <= 1.3


@pytest.mark.slow
def test_wheel_demo_identifies_the_feedforward(tmp_path, ros_domain):
    out = tmp_path / 'wheel'
    proc = run_demo(out, ros_domain, 'wheel')
    found, true, _ = feedforward(out)
    assert found['kV']['value'] == pytest.approx(true['kV']['value'], rel=0.05)
    assert found['kA']['value'] == pytest.approx(true['kA']['value'], rel=0.20)
    assert found['kS']['value'] == pytest.approx(true['kS']['value'], abs=0.05)
    check_table(proc, found, true, ('kS', 'kV', 'kA'))
    check_outputs(out, 'wheel', 2)


# ---------------------------------------------------------------------------------------
# stopping the demo: 0 at the joint, every child gone


def start_moving(tmp_path, ros_domain, name):
    """The arm demo up to its second test (the arm has moved); the demo and its
    children."""
    out = tmp_path / 'out'
    demo = Process(demo_args(out, ros_domain, 'arm'), ros_env(ros_domain), tmp_path, name)
    demo.wait_for(r'^  test quasistatic-reverse started', timeout=300.0, stream='stdout')
    kids = psutil.Process(demo.pid).children(recursive=True)
    names = sorted(next(a for a in k.cmdline() if a.startswith('motor_id.')) for k in kids)
    assert names == ['motor_id.cli', 'motor_id.testing.sim_robot'], [
        k.cmdline() for k in kids]
    return demo, out, kids


def gone(proc):
    try:
        return proc.status() == psutil.STATUS_ZOMBIE   # ended, not yet reaped by init
    except psutil.NoSuchProcess:
        return True


def last_sent(out):
    """The last command the experiment sent (its recording)."""
    with AnyReader([out / 'recording.mcap']) as reader:
        conns = [c for c in reader.connections if c.topic == TOPIC]
        msgs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(conns)]
    return list(msgs[-1].data)


@pytest.mark.parametrize('sig', [signal.SIGTERM,
                                 pytest.param(signal.SIGINT, marks=pytest.mark.slow),
                                 pytest.param(signal.SIGHUP, marks=pytest.mark.slow)])
def test_a_signal_mid_experiment_leaves_the_joint_at_0_and_nothing_running(
        tmp_path, ros_domain, sig):
    demo, out, kids = start_moving(tmp_path, ros_domain, signal.Signals(sig).name)
    t_wall = time.time()
    demo.send_signal(sig)
    code = demo.finish(120.0)          # a failure bound
    assert not demo.killed, demo.output()
    assert code == 130 and 'interrupted' in demo.stderr(), demo.output()
    assert all(gone(k) for k in kids), [k.cmdline() for k in kids if not gone(k)]
    truth = json.loads((out / 'truth.json').read_text())
    commands = truth['commands']
    zero = [0.0, 0.0, 0.0]
    assert any(c['values'][1] != 0.0 for c in commands if c['time'] < t_wall)
    assert commands[-1]['values'] == zero
    after = [c for c in commands if c['time'] >= t_wall]
    first_zero = next(c['time'] for c in after if c['values'] == zero)
    assert first_zero - t_wall <= ZERO_WITHIN, first_zero - t_wall
    assert all(c['values'] == zero for c in after if c['time'] >= first_zero)
    assert -2.3 <= truth['position']['min'] and truth['position']['max'] <= 1.3
    log = json.loads((out / 'experiment.json').read_text())
    assert log['stop_reason'] == 'signal SIGINT'     # the demo stops it as Ctrl-C does
    for name in ('experiment', 'robot'):
        assert 'Traceback' not in (out / f'{name}.err').read_text(), name


def test_killed_demo_leaves_its_children_stopping_cleanly(tmp_path, ros_domain):
    """SIGKILL of the demo: the kernel sends the experiment and the robot SIGTERM; the
    experiment sends 0 and writes its outputs, nothing is left running."""
    demo, out, kids = start_moving(tmp_path, ros_domain, 'KILL')
    os.kill(demo.pid, signal.SIGKILL)
    assert demo.finish(30.0) == -signal.SIGKILL
    assert wait_until(lambda: all(gone(k) for k in kids), 120.0), [
        (k.pid, k.cmdline()) for k in kids if not gone(k)]
    log = json.loads((out / 'experiment.json').read_text())
    assert log['stop_reason'] == 'signal SIGTERM'
    assert last_sent(out) == [0.0, 0.0, 0.0]
    assert (out / 'truth.json').exists()     # the robot ended cleanly too
