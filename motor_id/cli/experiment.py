"""`motor-id experiment`: identify one joint of a live ROS 2 robot through its controller.

Runs the experiment node in this process (:func:`motor_id.nodes.experiment.run`), starts
it as soon as the joint's state and the controller's joints are known, and exits with its
code: 0 identified, 2 a bad setting or no start, 3 a safety stop, 4 not identified, 5 an
error, 128 + N on signal N (0 commanded in every case).
"""

import argparse

from motor_id.contracts import INPUT_KINDS
from motor_id.effects import MECHANISMS
from motor_id.experiment.settings import (
    COMMAND_TYPES,
    ExperimentSettings,
    PLANS,
    Travel,
    WATCHDOG,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """CLI arguments of `motor-id experiment`."""
    parser.add_argument('--joint', required=True, help='the joint, by its JointState name')
    parser.add_argument('--command-topic', required=True, metavar='TOPIC',
                        help="the controller's command topic, e.g. "
                             '/forward_command_controller/commands')
    parser.add_argument('--max-command', required=True, type=float, metavar='X',
                        help='no command exceeds this magnitude [V, or N m / N]')
    parser.add_argument('--out', required=True, metavar='DIR',
                        help='output folder: recording.mcap, report.json, experiment.json')
    parser.add_argument('--controller-joints', default='', metavar='A,B,...',
                        help="the controller's joints in order (default: read from the "
                             "controller node's joints parameter)")
    parser.add_argument('--command-type', default='multi_array', choices=COMMAND_TYPES)
    parser.add_argument('--state-topic', default='/joint_states', metavar='TOPIC')
    parser.add_argument('--input-kind', default='voltage', choices=INPUT_KINDS)
    parser.add_argument('--mechanism', default='simple', choices=MECHANISMS)
    parser.add_argument('--travel', default='', metavar='LO:HI',
                        help='the window the joint stays in [rad, or m] (arm, elevator: '
                             'required)')
    parser.add_argument('--max-speed', type=float, default=0.0, metavar='W',
                        help='a test ends above this speed [rad/s, or m/s]')
    parser.add_argument('--plan', default='sysid', choices=PLANS)
    parser.add_argument('--resistance', '-R', type=float, default=0.0, metavar='OHM',
                        help='armature resistance as measured (optional: speed alone '
                             'cannot tell it, the feedforward constants do not need it)')
    parser.add_argument('--time-scale', type=float, default=1.0, metavar='S',
                        help="multiply the plan's durations (default 1)")
    parser.add_argument('--watchdog', type=float, default=WATCHDOG, metavar='SEC',
                        help='state silent or late this long stops it (default '
                             f'{WATCHDOG:g} s)')
    parser.add_argument('--start-timeout', type=float, default=30.0, metavar='SEC',
                        help='give up if the state or the controller joints are not '
                             'known within this time (default 30 s)')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--no-identify', action='store_true',
                        help='record only (analyse later with motor-id analyze)')
    parser.add_argument('--jobs', '-j', type=int, metavar='N',
                        help='processes for the analysis (default: every usable core)')


def run(args: argparse.Namespace) -> int:
    """Check the settings, run the node with them, return its exit code."""
    values = {
        'joint': args.joint, 'command_topic': args.command_topic,
        'max_command': float(args.max_command), 'out': args.out,
        'controller_joints': args.controller_joints, 'command_type': args.command_type,
        'state_topic': args.state_topic, 'input_kind': args.input_kind,
        'mechanism': args.mechanism, 'travel': args.travel,
        'max_speed': float(args.max_speed), 'plan': args.plan,
        'resistance': float(args.resistance), 'watchdog': float(args.watchdog),
        'time_scale': float(args.time_scale), 'seed': int(args.seed),
        'identify': not args.no_identify}
    if args.travel:
        Travel.parse(args.travel)
    ExperimentSettings.from_parameters(values)   # a bad flag: one line, exit 2
    from rclpy.parameter import Parameter

    from motor_id.nodes.experiment import run as run_node
    overrides = [Parameter(k, value=v) for k, v in values.items()]
    overrides += [Parameter('autostart', value=True),
                  Parameter('start_timeout', value=float(args.start_timeout))]
    return run_node(['motor-id-experiment'], overrides, jobs=args.jobs)
