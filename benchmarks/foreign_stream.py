"""The foreign robot's state stream as `motor-id experiment` receives it, alone or with a
busy process per core beside it (real processes over DDS).

    python benchmarks/foreign_stream.py [--rounds 3] [--burn] [--kind wheel,arm]

Each round runs the robot of ``test/test_foreign_robot.py`` (the wheel at 250 Hz started
after the experiment; the arm at 50 Hz, Float64, stamps of its own clock) and the
experiment's plan on it without the analysis (``--no-identify``), with the default 0.25 s
watchdog. It prints, per kind: the exits, the largest gap between two states received
(the receive times in the experiment's recording), the longest gap between two instants
the robot measured (its truth file: the robot's own stall) and the robot process's CPU
share.
"""

import argparse
import json
import os
from pathlib import Path
import signal
import sys
import time

import numpy as np
from rosbags.highlevel import AnyReader
from rosproc import run_rounds

from motor_id.testing.foreign_robot import READY_LINE
from motor_id.testing.procs import Process
from motor_id.testing.ros import ros_env

TOPIC = '/forward_command_controller/commands'
SETUPS = {
    'wheel': (['-p', 'kind:=wheel'], ['--joint', 'shooter_wheel', '--time-scale', '0.5']),
    'arm': (['-p', 'kind:=arm', '-p', 'command_type:=float64', '-p', 'stamp:=boot',
             '-p', 'rate_hz:=50.0', '-p', 'start:=0.4'],
            ['--joint', 'shoulder', '--mechanism', 'arm', '--travel=-2.1:1.9',
             '--command-type', 'float64']),
}
"""The robot's parameters and the experiment's options, as the tests give them."""


def receive_gap(bag: Path) -> float:
    """The largest gap between two joint states received [s]."""
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == '/joint_states']
        t = np.array([t for _, t, _ in reader.messages(connections=conns)]) * 1e-9
    return float(np.max(np.diff(t))) if len(t) > 1 else float('nan')


def one_round(kind: str, folder: Path, domain: int) -> dict:
    """One robot, one experiment without the analysis; the stream's figures."""
    import psutil
    env = ros_env(domain)
    robot_params, options = SETUPS[kind]
    exp = Process(['-m', 'motor_id.cli', 'experiment', '--command-topic', TOPIC,
                   '--max-command', '6', '--out', str(folder / 'out'), '--no-identify',
                   '--start-timeout', '240', *options], env, folder, 'experiment')
    robot = Process(['-m', 'motor_id.testing.foreign_robot', '--ros-args', *robot_params,
                     '-p', f'truth_file:={folder / "truth.json"}'], env, folder, 'robot')
    try:
        robot.wait_for(READY_LINE, timeout=240)
        cpu0 = sum(psutil.Process(robot.pid).cpu_times()[:2])
        wall0 = time.monotonic()
        code = exp.wait(timeout=600)
        cpu = (sum(psutil.Process(robot.pid).cpu_times()[:2]) - cpu0) / \
            (time.monotonic() - wall0)
        robot.stop(signal.SIGINT)
        truth = json.loads((folder / 'truth.json').read_text())
        log = json.loads((folder / 'out' / 'experiment.json').read_text())
        return {'kind': kind, 'exit': code, 'stop': log.get('stop_reason'),
                'gap': receive_gap(folder / 'out' / 'recording.mcap'),
                'wait': truth['states']['longest_gap'], 'cpu': cpu}
    finally:
        for proc in (exp, robot):
            proc.close()


def main(argv: list[str] | None = None) -> int:
    """Run the rounds and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--rounds', type=int, default=3)
    ap.add_argument('--burn', action='store_true', help='a busy process per core beside')
    ap.add_argument('--kind', default='wheel,arm', help='wheel, arm or both (comma)')
    args = ap.parse_args(argv)
    kinds = [k for k in args.kind.split(',') if k]
    rows, burners = run_rounds(args.rounds, kinds, one_round, 'fs', args.burn)
    print(f'load average {os.getloadavg()[0]:.1f}, {burners} burners, '
          f'{args.rounds} rounds')
    print(f'{"robot":<6} {"exits":>10} {"largest receive gap [s]":>24} '
          f'{"robot gap [s]":>18} {"robot CPU [%]":>14}')
    for kind in kinds:
        mine = [r for r in rows if r['kind'] == kind]
        exits = ','.join(str(r['exit']) for r in mine)
        print(f'{kind:<6} {exits:>10} {max(r["gap"] for r in mine):>24.3f} '
              f'{max(r["wait"] for r in mine):>18.3f} '
              f'{100 * max(r["cpu"] for r in mine):>14.1f}')
    for r in rows:
        if r['exit'] != 0:
            print(f'{r["kind"]}: exit {r["exit"]}: {r["stop"]}')
    print('(largest over the rounds; the watchdog stops the experiment at 0.25 s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
