"""`motor-id experiment` against a robot written apart from the project's simulator
(:mod:`motor_id.testing.foreign_robot`: its own physics, and the quirks of real
ros2_control robots: joints shuffled on every message, no velocity, no effort, stamps
unset or on another clock, other state rates, latency, a controller of more joints or of
Float64), in real processes over DDS. The issue's targets: wheel kV within 5 %, kA 20 %,
kS 0.03 V; arm kG 10 %, offset 0.1 rad, kV 10 %, kS 0.1 V, kA 30 %, never past the
travel.

Every wait is on an event (a log line, an exit), never a fixed time.
"""

import json
import signal

import pytest

from motor_id.experiment.outcome import EXIT_OK
from motor_id.testing.foreign_robot import READY_LINE

TOPIC = '/forward_command_controller/commands'
MAX = 6.0

WATCHDOG = '1.0'
"""The experiment's state watchdog [s] here: these tests are about the targets, with room
for a shared machine (the states' largest gap seen by the experiment with a burner per
core, load average 15-18: 25-53 ms); the 0.25 s default is tested in
test_experiment_node."""


def robot_args(tmp_path, kind, **params):
    args = ['-m', 'motor_id.testing.foreign_robot', '--ros-args', '-p', f'kind:={kind}',
            '-p', f'truth_file:={tmp_path / "truth.json"}']
    for name, value in params.items():
        text = str(value).lower() if isinstance(value, bool) else \
            '[' + ','.join(f"'{v}'" for v in value) + ']' if isinstance(value, list) \
            else str(value)
        args += ['-p', f'{name}:={text}']
    return args


def experiment_args(tmp_path, joint, *extra, time_scale=1.0):
    return ['-m', 'motor_id.cli', 'experiment', '--joint', joint, '--command-topic', TOPIC,
            '--max-command', str(MAX), '--out', str(tmp_path / 'out'),
            '--time-scale', str(time_scale), '--start-timeout', '240',
            '--watchdog', WATCHDOG, *extra]


def results(tmp_path):
    truth = json.loads((tmp_path / 'truth.json').read_text())
    report = json.loads((tmp_path / 'out' / 'report.json').read_text())
    ff = report['controller']['feedforward']
    return truth, {k: v['value'] for k, v in ff.items()}


@pytest.mark.slow   # a minute or more of a live robot. 2026-11-28 (load average 16-34):
# 3 of 3 passed once the experiment kept 10 states queued, not 1000 (kV -0.7..+0.3 %, kA
# +15..+19 %, kS 0.243-0.257); before, 2 runs stopped on a 0.6-0.85 s backlog of states
# ('stale state'), and 3 were not identified while the robot still sent a stall's states
# in a burst. With the commands' interval means (7e1ab8f): kS 0.2504, kV 0.0350, kA
# 0.0060 (exact; +12 % at 3.5 error bars before), input delay 5.02 samples (its 20 ms)
def test_wheel_on_a_foreign_robot_meets_the_targets(launch, tmp_path):
    # the experiment first, the robot after it; no velocity, no stamps, shuffled joints,
    # 250 Hz with 20 ms latency, a controller of three joints read from its parameter
    exp = launch('experiment', experiment_args(tmp_path, 'shooter_wheel', time_scale=0.5))
    exp.wait_for('call ~/start|autostart', timeout=120)
    robot = launch('robot', robot_args(tmp_path, 'wheel'))
    code = exp.wait(timeout=900)
    assert code == EXIT_OK, exp.output()
    robot.wait_for(READY_LINE, timeout=5)
    robot.stop(signal.SIGINT)
    truth, found = results(tmp_path)
    true = truth['feedforward']
    assert found['kV'] == pytest.approx(true['kV'], rel=0.05)
    assert found['kA'] == pytest.approx(true['kA'], rel=0.20)
    assert found['kS'] == pytest.approx(true['kS'], abs=0.03)
    received = truth['commands']
    assert max(abs(v) for c in received for v in c['values']) <= MAX
    assert received[-1]['values'] == [0.0, 0.0, 0.0]
    assert all(c['values'][1] == c['values'][2] == 0.0 for c in received)


@pytest.mark.slow   # a minute or more of a live robot. kA was the open gap until the
# recording took each interval's input as the mean of the commands over it and its tests
# as one input stream (7e1ab8f): the robot's 20 ms latency, hidden in stamps of its own
# clock, had gone into kA (+20 to +45 % on seven recordings); the analysis now finds it as
# an input delay. 2026-11-28: passed, kA 0.0452 +- 0.008 (-9.5 %), input delay 1.31
# samples; kS 0.199, kV 0.904, kG 1.001, offset -0.300; the seven older recordings
# re-analysed: kA -15 to +29 %, within 1.7 error bars (docs/experiment.md)
@pytest.mark.parametrize('quirks', [
    dict(command_type='float64', stamp='boot', rate_hz=50.0, latency=0.02, start=0.4),
])
def test_arm_on_a_foreign_robot_meets_the_targets(launch, tmp_path, quirks):
    robot = launch('robot', robot_args(tmp_path, 'arm', **quirks))
    robot.wait_for(READY_LINE, timeout=180)
    extra = ['--mechanism', 'arm', '--travel=-2.1:1.9']
    if quirks.get('command_type') == 'float64':
        extra += ['--command-type', 'float64']
    exp = launch('experiment', experiment_args(tmp_path, 'shoulder', *extra))
    code = exp.wait(timeout=900)
    assert code == EXIT_OK, exp.output()
    robot.stop(signal.SIGINT)
    truth, found = results(tmp_path)
    true = truth['feedforward']
    assert -2.1 <= truth['position']['min'] and truth['position']['max'] <= 1.9
    assert found['kG'] == pytest.approx(true['kG'], rel=0.10)
    assert found['offset'] == pytest.approx(true['offset'], abs=0.1)
    assert found['kV'] == pytest.approx(true['kV'], rel=0.10)
    assert found['kS'] == pytest.approx(true['kS'], abs=0.1)
    assert found['kA'] == pytest.approx(true['kA'], rel=0.30)
