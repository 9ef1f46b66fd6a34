"""How fast `motor-id experiment` commands 0: after SIGTERM, SIGINT, SIGHUP and after the
joint states stop, on the simulated robot (real processes over DDS).

    python benchmarks/experiment_stop.py [--rounds 3] [--burn] [--json OUT]

Each round starts the simulated wheel and the experiment, waits until the experiment
commands a non-zero value, then sends the signal to the experiment (or freezes the robot
with SIGSTOP: no more joint states) at a random moment of the plan. Delays are read from
the experiment's own recording (the send time of its first 0 after the cause) and from
the robot's truth file (the receive time of that 0); the target is 0.5 s. ``--burn``
runs a busy process per core beside it.
"""

import argparse
import json
import os
from pathlib import Path
import random
import signal
import statistics
import sys
import time

from rosbags.highlevel import AnyReader
from rosproc import run_rounds

from motor_id.testing.procs import Process
from motor_id.testing.ros import ros_env
from motor_id.testing.sim_joint import READY, sim_robot_args

TOPIC = '/forward_command_controller/commands'
CAUSES = ('SIGTERM', 'SIGINT', 'SIGHUP', 'states stop')


def sent_commands(bag: Path) -> list[tuple[float, float]]:
    """(send time [s, wall clock], value) of every command in the recording."""
    out = []
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == TOPIC]
        for conn, t, raw in reader.messages(connections=conns):
            out.append((t * 1e-9, float(reader.deserialize(raw, conn.msgtype).data[1])))
    return out


def first_zero(times_values: list[tuple[float, float]], t0: float) -> float | None:
    """Seconds from ``t0`` to the first 0 at or after it."""
    return next((t - t0 for t, v in times_values if t >= t0 and v == 0.0), None)


def one_round(cause: str, folder: Path, domain: int, rng: random.Random) -> dict:
    """One start, one cause, the delays."""
    env = ros_env(domain)
    robot = Process(sim_robot_args('wheel', truth_file=str(folder / 'truth.json')), env,
                    folder, 'robot')
    exp = None
    try:
        robot.wait_for(READY, timeout=180)
        exp = Process(['-m', 'motor_id.cli', 'experiment', '--joint', 'wheel_joint',
                       '--command-topic', TOPIC, '--max-command', '6', '--out',
                       str(folder / 'out'), '--no-identify', '--start-timeout', '180'],
                      env, folder, 'experiment')
        exp.wait_for('test quasistatic-forward started', timeout=240)
        time.sleep(rng.uniform(0.5, 8.0))
        t_cause = time.time()
        if cause == 'states stop':
            robot.proc.send_signal(signal.SIGSTOP)
        else:
            exp.proc.send_signal(getattr(signal, cause))
        if cause == 'states stop':   # resume once it stopped: the 0 must reach it then
            exp.wait_for('stopped: watchdog', timeout=60)
            robot.proc.send_signal(signal.SIGCONT)
        code = exp.wait(timeout=120)
        sent = sent_commands(folder / 'out' / 'recording.mcap')
        with AnyReader([folder / 'out' / 'recording.mcap']) as reader:
            conns = [c for c in reader.connections if c.topic == '/joint_states']
            last_state = max(t for _, t, _ in reader.messages(connections=conns)) * 1e-9
        t0 = last_state if cause == 'states stop' else t_cause
        robot.stop(signal.SIGINT)
        truth = json.loads((folder / 'truth.json').read_text())
        received = [(c['time'], c['values'][1]) for c in truth['commands']]
        after = [v for t, v in sent if t >= t0 + (first_zero(sent, t0) or 0.0)]
        return {'cause': cause, 'exit': code, 'sent': first_zero(sent, t0),
                'received': None if cause == 'states stop' else first_zero(received, t0),
                'only_zero_after': all(v == 0.0 for v in after),
                'last_received': received[-1][1] if received else None}
    finally:
        for proc in (exp, robot):
            if proc is not None:
                proc.close()


def main(argv: list[str] | None = None) -> int:
    """Run the rounds and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--rounds', type=int, default=3)
    ap.add_argument('--burn', action='store_true', help='a busy process per core beside')
    ap.add_argument('--json', metavar='OUT')
    args = ap.parse_args(argv)
    rng = random.Random(0)
    rows, burners = run_rounds(args.rounds, CAUSES,
                               lambda c, f, d: one_round(c, f, d, rng), 'stop', args.burn)
    print(f'load average {os.getloadavg()[0]:.1f}, {burners} burners')
    print(f'{"cause":<12} {"rounds":>6} {"0 sent after [s]":>24} {"0 received after [s]":>24}'
          f' {"only 0 after":>12} {"robot ends at 0":>15}')
    for cause in CAUSES:
        mine = [r for r in rows if r['cause'] == cause]
        sent = [r['sent'] for r in mine if r['sent'] is not None]
        recv = [r['received'] for r in mine if r['received'] is not None]

        def spread(xs: list[float]) -> str:
            return f'{min(xs):.3f} / {statistics.median(xs):.3f} / {max(xs):.3f}' if xs \
                else 'none'
        print(f'{cause:<12} {len(mine):>6} {spread(sent):>24} {spread(recv):>24} '
              f'{str(all(r["only_zero_after"] for r in mine)):>12} '
              f'{str(all(r["last_received"] == 0.0 for r in mine)):>15}')
    print('(min / median / max; target: 0 within 0.5 s of the signal, or of the last joint '
          'state; a frozen robot gets the 0 when it resumes)')
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
