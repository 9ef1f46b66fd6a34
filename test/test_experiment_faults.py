"""An error inside `motor-id experiment` mid-test, caused from outside in a real process:
the recording outgrows the file size limit of the process (RLIMIT_FSIZE, as a full disk
would stop it), so writing it raises. The last command is then 0, the exit code is 5
with the error named, and no process is left behind.

Every wait is on an event (a message, an exit), never a fixed time.
"""

import json
import signal
import sys
import threading
import time

import psutil
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray

from motor_id.experiment.outcome import EXIT_ERROR
from motor_id.testing.procs import wait_until
from motor_id.testing.sim_joint import READY, sim_robot_args

TOPIC = '/forward_command_controller/commands'
FILE_LIMIT = 120_000
"""Bytes a file of the experiment may grow to: a few seconds of the recording."""
LIMITED = ('import resource, runpy, sys; '
           'resource.setrlimit(resource.RLIMIT_FSIZE, ({0}, {0})); '
           "sys.argv = ['motor-id'] + sys.argv[1:]; "
           "runpy.run_module('motor_id.cli', run_name='__main__', alter_sys=True)")


class Commands:
    """Each command a bystander receives: (monotonic time, the wheel's value)."""

    def __init__(self, client):
        self.values = []
        self.lock = threading.Lock()
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        client.subscribe(Float64MultiArray, TOPIC, qos, self._on)

    def _on(self, msg):
        with self.lock:
            self.values.append((time.monotonic(), msg.data[1]))

    def moving(self):
        with self.lock:
            return any(abs(v) > 0.1 for _, v in self.values)

    def last(self):
        with self.lock:
            return self.values[-1][1] if self.values else None


def test_an_error_mid_test_commands_0_exits_5_and_leaves_nothing(client, launch, tmp_path):
    seen = Commands(client)
    robot = launch('robot', sim_robot_args('wheel', truth_file=str(tmp_path / 'truth.json')))
    robot.wait_for(READY, timeout=180)
    exp = launch('experiment', [
        sys.executable, '-c', LIMITED.format(FILE_LIMIT), 'experiment', '--joint',
        'wheel_joint', '--command-topic', TOPIC, '--max-command', '6', '--out',
        str(tmp_path / 'out'), '--start-timeout', '180'])
    assert wait_until(seen.moving, 240.0), exp.output()
    family = [psutil.Process(exp.pid)] + psutil.Process(exp.pid).children(recursive=True)
    code = exp.wait(timeout=600)
    out = exp.output()
    assert code == EXIT_ERROR, out
    assert 'File too large' in out or 'EFBIG' in out, out
    gone, alive = psutil.wait_procs(family, timeout=5)
    assert not alive
    robot.stop(signal.SIGINT)
    # the robot's record: the last command it received is 0, and it did move before

    received = json.loads((tmp_path / 'truth.json').read_text())['commands']
    assert any(abs(c['values'][1]) > 0.1 for c in received)
    assert received[-1]['values'] == [0.0, 0.0]
    assert seen.last() == 0.0
