"""`motor-id demo --robot wheel|arm|elevator`: the simulated ros2_control robot and
`motor-id experiment` on its joint, end to end, as a user would run them.

Two processes on a ROS domain of their own (LOCALHOST discovery): the robot
(:mod:`motor_id.testing.sim_robot`, on the independent physics) and the experiment
(``motor-id experiment`` with the limits a user would give: a command limit, a travel
window inside the hard stops, a speed limit). The identified feedforward constants are
printed beside the robot's true ones, from its truth file.

Ctrl-C, SIGTERM and SIGHUP stop it alike (exit 130): the experiment is stopped first and
waited for (it sends 0 to the joint), then the robot; a further signal meanwhile is
ignored, so the stop always ends this way. Killed itself (SIGKILL), the demo's children
get SIGTERM from the kernel (:mod:`motor_id.lifeline`): the experiment sends 0 and ends,
the robot ends.
"""

import argparse
from collections.abc import Iterator
import contextlib
from dataclasses import dataclass
import json
import os
import random
import re
import signal
import subprocess
from typing import TYPE_CHECKING

from motor_id.errors import ConfigError, MotorIdError
from motor_id.lifeline import STOP_SIGNALS

if TYPE_CHECKING:
    from motor_id.testing.procs import Process, Processes
    from motor_id.testing.sim_joint import JointTruth

TOPIC = '/forward_command_controller/commands'
"""The simulated robot's command topic (its default controller)."""

OUTPUTS = ('recording.mcap', 'report.json', 'experiment.json', 'truth.json')


@dataclass(frozen=True)
class RobotDemo:
    """What a user gives ``motor-id experiment`` for one simulated mechanism.

    Attributes
    ----------
    joint : str
        The joint identified (by its JointState name).
    mechanism : str
        ``--mechanism`` (simple, arm, elevator).
    max_command : float
        ``--max-command`` [V].
    max_speed : float
        ``--max-speed`` [rad/s, or m/s].
    travel : str
        ``--travel LO:HI`` inside the robot's hard stops ('' for none: a wheel).
    """

    joint: str
    mechanism: str
    max_command: float
    max_speed: float
    travel: str = ''

    def experiment_args(self, out: str, time_scale: float, seed: int,
                        watchdog: float | None = None) -> list[str]:
        """The ``motor-id experiment`` command line (``watchdog``: its default if None)."""
        args = ['-m', 'motor_id.cli', 'experiment', '--joint', self.joint,
                '--command-topic', TOPIC, '--max-command', f'{self.max_command:g}',
                '--mechanism', self.mechanism, '--max-speed', f'{self.max_speed:g}',
                '--time-scale', f'{time_scale:g}', '--seed', str(seed),
                '--start-timeout', '120', '--out', out]
        if watchdog is not None:
            args += ['--watchdog', f'{watchdog:g}']
        if self.travel:
            args.append(f'--travel={self.travel}')
        return args


ROBOTS = {
    # free speed ~285 rad/s at 6 V; no stops
    'wheel': RobotDemo('wheel_joint', 'simple', 6.0, 400.0),
    # hard stops -2.4, 1.4 rad; hangs at -1.92 rad; ~2.5 rad/s at 4 V (6 V: shorter tests,
    # kS undetermined in 3 of 8 runs; 4 V: 3 of 3 and 3 of 3 with both cores busy)
    'arm': RobotDemo('arm_joint', 'arm', 4.0, 6.0, '-2.3:1.3'),
    # hard stops 0, 1.2 m; rests on the bottom one; ~0.8 m/s at 6 V
    'elevator': RobotDemo('elevator_joint', 'elevator', 6.0, 1.5, '-0.05:1.15'),
}

FAST_TIME_SCALE = 0.4
"""``--fast``: the plan's tests 0.4 times as long (about 15 s instead of 40 s)."""

_LOG_LINE = re.compile(r'^\[(?:INFO|WARN|ERROR|FATAL)\] \[[\d.]+\] \[[\w.]+\]: (.*)$')


def _say(text: str) -> None:
    print(text, flush=True)


def run(args: argparse.Namespace) -> int:
    """Run the robot demo end to end; the experiment's exit code (0: identified)."""
    demo = ROBOTS[args.robot]
    if args.params:
        raise ConfigError('--params sets the card motor; the simulated robot has its own '
                          '(see docs/sim_robot.md)')
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    for name in OUTPUTS:
        with contextlib.suppress(FileNotFoundError):
            os.remove(os.path.join(out, name))
    domain = args.domain or random.SystemRandom().randint(1, 101)
    if not 0 <= domain <= 232:
        raise ConfigError(f'--domain must be in 0..232, got {domain}')
    from motor_id.nodes.shm import clean_stale_shm
    from motor_id.testing.procs import Processes, ros_env
    from motor_id.testing.sim_joint import read_truth, READY, sim_robot_args
    cleaned = clean_stale_shm()
    truth_file = os.path.join(out, 'truth.json')
    kids = Processes(ros_env(domain), out)
    _say(f'demo: ROS_DOMAIN_ID={domain}, LOCALHOST discovery; logs in {out}'
         + (f'; removed {len(cleaned)} stale Fast DDS shared-memory file(s)'
            if cleaned else ''))
    try:
        robot = kids.start('robot', sim_robot_args(args.robot, truth_file=truth_file,
                                                   seed=args.seed))
        robot.wait_for(READY, timeout=180.0)
        _say(f'robot:      simulated {args.robot} ready ({TOPIC}, /joint_states)')
        exp_args = demo.experiment_args(
            out, FAST_TIME_SCALE if args.fast else 1.0, args.seed, args.watchdog)
        _say('experiment: motor-id ' + ' '.join(exp_args[3:]))
        code = _follow(kids.start('experiment', exp_args), robot)
    finally:
        _stop(kids)
    truth = read_truth(truth_file)
    _print_results(out, truth, demo.mechanism, code)
    return code


def _follow(exp: 'Process', robot: 'Process') -> int:
    """Echo the experiment's progress lines until it exits; its exit code."""
    seen = 0
    while True:
        ended = exp.proc.poll() is not None
        lines = exp.stderr().splitlines()
        for line in lines[seen:]:
            m = _LOG_LINE.match(line)
            _say(f'  {m.group(1) if m else line}')
        seen = len(lines)
        if ended:
            return int(exp.proc.returncode)
        robot.check()
        with contextlib.suppress(subprocess.TimeoutExpired):
            exp.proc.wait(0.5)


@contextlib.contextmanager
def _signals_ignored() -> Iterator[None]:
    """A second Ctrl-C, SIGTERM or SIGHUP cannot cut the stop short."""
    old = {sig: signal.signal(sig, signal.SIG_IGN) for sig in STOP_SIGNALS}
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def _stop(kids: 'Processes') -> None:
    """The experiment first (SIGINT: it sends 0 and ends), then the robot; each killed if
    it hangs."""
    with _signals_ignored():
        exp = kids.get('experiment')
        if exp is not None and exp.alive():
            _say('stopping:   the experiment (0 to the joint), then the robot')
            exp.stop(signal.SIGINT, timeout=30.0)
        kids.close(timeout=15.0)


def _print_results(out: str, truth: 'JointTruth', mechanism: str, code: int) -> None:
    """The identified constants beside the true ones; the files written."""
    from motor_id.analysis.feedforward import FeedforwardConstant
    path = os.path.join(out, 'report.json')
    if not os.path.exists(path):
        raise MotorIdError(f'the experiment exited {code} without a report; see '
                           f'{os.path.join(out, "experiment.err")}')
    with open(path, encoding='utf-8') as fh:
        report = json.load(fh)
    found = {name: FeedforwardConstant.from_dict(entry) for name, entry in
             ((report.get('controller') or {}).get('feedforward') or {}).items()}
    _say('')
    _say(f'{"constant":<9}{"identified":>12}{"+/- std":>10}{"true":>11}{"error":>9}'
         f'{"/std":>7}  unit')
    names = ('kS', 'kV', 'kA') + (('kG',) if mechanism != 'simple' else ()) + (
        ('offset',) if mechanism == 'arm' else ())
    for name in names:
        t, unit = truth.feedforward[name], truth.units[name]
        f = found.get(name)
        if f is None or f.value is None:
            _say(f'{name:<9}{"not determined":>22}{t:>11.4g}{"":>16}  {unit}')
            continue
        err = f.value - t
        rel = f'{100 * err / t:+.1f}%' if t and name != 'offset' \
            else f'{err:+.3f}'
        std = f.std
        _say(f'{name:<9}{f.value:>12.4g}{"" if std is None else f"{std:.2g}":>10}'
             f'{t:>11.4g}{rel:>9}{"" if not std else f"{err / std:+.1f}":>7}'
             f'  {unit if f.unit is None else f.unit}')
    last = truth.commands[-1].values if truth.commands else None
    _say(f'\nthe robot received {len(truth.commands)} commands, the last '
         f'{last}; position {truth.position_min:.3g} .. {truth.position_max:.3g}')
    written = [n for n in OUTPUTS if os.path.exists(os.path.join(out, n))]
    _say(f'wrote {", ".join(os.path.join(out, n) for n in written)}')
    if code != 0:
        _say(f'the experiment exited {code} (see experiment.json and experiment.err)')
