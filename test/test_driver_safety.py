"""The driver and a simulated card as processes on real DDS: limits, profiles, joint_states."""

import os
import re
import signal
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import Trigger
import yaml

from motor_id.card import protocol as pr
from motor_id.card.profile import profile_samples
from motor_id.card.stream import FrameParser
from motor_id.card.transport import open_transport, read_available
from motor_id.contracts import FLAG_LIMIT, FLAG_PROFILE, FLAG_PROFILE_END
from motor_id.nodes import messages
from motor_id.nodes.driver import PARAMETERS
from motor_id.testing.procs import wait_until
from motor_id.testing.ros import latest_status, REPO, rows_of, settle, stop_cleanly

DRIVER = 'motor_id: driver'
BEST_EFFORT = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)


def driver_args(*params, ros_args=()):
    args = ['-m', 'motor_id.nodes.driver', '--ros-args', *ros_args]
    for p in params:
        args += ['-p', p]
    return args


def card_args(link, *extra):
    return ['-m', 'motor_id.cli', 'card-sim', '--link', str(link)] + list(extra)


def flags_of(rows):
    return rows[:, 5].astype(np.int64)


def status(diags):
    return latest_status(diags, DRIVER)


def start_card_and_driver(client, launch, tmp_path, card_extra=(), *params):
    link = tmp_path / 'card'
    diags = client.collect(DiagnosticArray, '/diagnostics', messages.DIAGNOSTICS_QOS)
    samples = client.collect(Float64MultiArray, 'samples', messages.SAMPLES_QOS)
    launch('card', card_args(link, *card_extra))
    drv = launch('driver', driver_args(f'device:={link}', 'publish_channels:=false', *params))
    drv.wait_for('device .* open')
    assert wait_until(lambda: len(samples) > 0, 20.0), drv.output()
    return drv, diags, samples


def test_over_speed_stops_the_excitation_until_reset(client, launch, tmp_path):
    """paper_steps at 9 V reaches ~14 rad/s; a 5 rad/s limit trips at the 3.8 V step."""
    drv, diags, samples = start_card_and_driver(
        client, launch, tmp_path, ('--speedup', '4'), 'excitation:=paper_steps',
        'max_speed:=5.0')
    assert client.call(Trigger, '/driver/start').success
    assert wait_until(lambda: status(diags).get('limit_state') == 'tripped', 30.0), \
        (status(diags), drv.output())
    st = status(diags)
    assert st['limit_tripped'] == 'speed' and float(st['limit_value']) > 5.0
    assert float(st['limit_threshold']) == 5.0
    drv.wait_for(r'stopped the excitation: speed limit: \|5\.\d+\| rad/s > 5 rad/s')
    n = rows_of(samples).shape[0]
    assert wait_until(lambda: rows_of(samples).shape[0] > n + 100, 10.0)
    rows = rows_of(samples)
    limited = np.flatnonzero(flags_of(rows) & FLAG_LIMIT)
    first = limited[0]
    assert np.all(np.diff(limited) == 1) and limited[-1] == rows.shape[0] - 1   # latched
    assert abs(rows[first, 3]) > 5.0 and np.all(np.abs(rows[:first, 3]) <= 5.0)
    assert np.all(rows[first + 20:, 2] == 0.0)           # the card holds 0 V ...
    assert abs(rows[-1, 3]) < abs(rows[first, 3])        # ... and the motor slows down
    resp = client.call(Trigger, '/driver/reset')
    assert resp.success and 'was: speed limit' in resp.message
    n = rows_of(samples).shape[0]
    assert wait_until(lambda: rows_of(samples).shape[0] > n + 50, 10.0)
    assert not np.any(flags_of(rows_of(samples)[n + 10:]) & FLAG_LIMIT)
    assert wait_until(lambda: status(diags).get('limit_state') == 'armed', 5.0)
    assert drv.stderr().count('stopped the excitation') == 1
    stop_cleanly(drv)


def test_current_spike_trips_the_current_limit(client, launch, tmp_path):
    """One sample reads 45 A (a spike every 4 card seconds): the 20 A limit stops the
    running profile; ~/start re-arms the limits and runs the profile again."""
    drv, diags, samples = start_card_and_driver(
        client, launch, tmp_path, ('--speedup', '2', '--fault', 'current_spike=4:45'),
        'excitation:=prbs', 'duration:=100.0', 'max_current:=20.0')
    assert client.call(Trigger, '/driver/start').success

    def tripped_while_running():
        rows = rows_of(samples)
        nine = np.flatnonzero(np.abs(rows[:, 2]) == 9.0)
        if not nine.size:
            return False
        limited = np.flatnonzero(flags_of(rows[nine[0]:]) & FLAG_LIMIT)
        return limited.size and rows.shape[0] > nine[0] + limited[0] + 50
    assert wait_until(tripped_while_running, 30.0), (status(diags), drv.output())
    rows = rows_of(samples)
    begin = np.flatnonzero(np.abs(rows[:, 2]) == 9.0)[0]
    spike = begin + np.flatnonzero(rows[begin:, 4] == 45.0)[0]
    flags = flags_of(rows)
    assert flags[spike] & FLAG_LIMIT and not np.any(flags[begin:spike] & FLAG_LIMIT)
    assert np.all(flags[spike:] & FLAG_LIMIT)                       # latched
    assert np.all(rows[spike + 20:, 2] == 0.0)                      # profile stopped
    assert wait_until(lambda: status(diags).get('limit_tripped') == 'current', 5.0)
    st = status(diags)
    assert float(st['limit_value']) == 45.0 and float(st['limit_threshold']) == 20.0
    assert st['limit_seq'] == str(int(rows[spike, 0]))
    resp = client.call(Trigger, '/driver/start')
    assert resp.success, resp.message
    n = rows_of(samples).shape[0]
    assert wait_until(lambda: np.any(np.abs(rows_of(samples)[n:, 2]) == 9.0), 10.0)
    assert int(status(diags)['limit_trips']) >= 1
    stop_cleanly(drv)


def test_external_commands_best_effort_clamped_and_watchdog(client, launch, tmp_path):
    """A best-effort publisher reaches the driver; 50 V is clamped to max_voltage; when
    the commands stop the watchdog holds 0 V (flagged), and the next command resumes."""
    drv, diags, samples = start_card_and_driver(
        client, launch, tmp_path, ('--speedup', '1'), 'excitation:=external',
        'max_voltage:=6.0', 'command_timeout_s:=0.4')
    pub = client.node.create_publisher(Float64, 'voltage_command', BEST_EFFORT)
    assert wait_until(lambda: pub.get_subscription_count() > 0, 20.0)

    def follows(value, expect):
        pub.publish(Float64(data=value))
        rows = rows_of(samples[-3:])
        return rows.shape[0] and rows[-1, 2] == expect and not flags_of(rows)[-1] & FLAG_LIMIT
    assert wait_until(lambda: follows(4.5, 4.5), 10.0, interval=0.1)
    assert wait_until(lambda: follows(50.0, 6.0), 10.0, interval=0.1)
    assert wait_until(lambda: int(status(diags).get('commands_clamped', 0)) >= 1, 5.0)
    drv.wait_for('voltage command 50 V clamped to 6 V')
    # silence: within the timeout (plus a read period) the card is at 0 V, flagged
    n = rows_of(samples).shape[0]
    assert wait_until(lambda: rows_of(samples).shape[0] > n + 150, 10.0)
    rows = rows_of(samples)[n:]
    held = np.flatnonzero(flags_of(rows) & FLAG_LIMIT)
    assert held.size and held[0] <= 80, held[:3]    # 0.4 s at 100 samples/s, plus latency
    assert np.all(rows[held[0] + 10:, 2] == 0.0)
    assert wait_until(lambda: status(diags).get('limit_state') == 'watchdog', 5.0)
    assert int(status(diags)['watchdog_trips']) == 1
    drv.wait_for(r'no voltage_command for 0\.4 s: holding 0 V')
    assert wait_until(lambda: follows(2.0, 2.0), 10.0, interval=0.1)
    assert wait_until(lambda: status(diags).get('limit_state') == 'armed', 5.0)
    stop_cleanly(drv)


def test_card_stops_the_profile_when_the_driver_is_killed(client, launch, tmp_path):
    """SIGKILL of the driver 3.8 V into paper_steps (card at 4x real time, its watchdog
    0.5 s of wall clock = 2 s of card time): the pings stop, the card is at 0 V within
    its watchdog time of the last one, and stays there: no 7 V at 16 s, no 9 V at 28 s."""
    link = tmp_path / 'card'
    samples = client.collect(Float64MultiArray, 'samples', messages.SAMPLES_QOS)
    card = launch('card', card_args(link, '--speedup', '4', '--watchdog', '0.5'))
    drv = launch('driver', driver_args(f'device:={link}', 'publish_channels:=false',
                                       'excitation:=paper_steps'))
    drv.wait_for('device .* open')
    assert client.call(Trigger, '/driver/start').success
    assert wait_until(lambda: np.sum(rows_of(samples)[:, 2] == np.float32(3.8)) > 100, 60.0), \
        drv.output()
    t_seen = rows_of(samples)[-1, 1]            # card time the driver was still alive at
    killed_at = time.monotonic()
    os.kill(drv.pid, signal.SIGKILL)
    assert drv.finish(30.0) == -signal.SIGKILL
    m = card.wait_for(r'watchdog: no command for ([\d.]+) s of card time: 0 V from seq (\d+) '
                      r'at card time ([\d.]+) s \(monotonic clock ([\d.]+) s\)', 60.0,
                      stream='stdout')
    silence, trip_seq, t_trip = float(m[1]), int(m[2]), float(m[3])
    assert 2.0 <= silence <= 2.0 + 0.01 + 1e-3                    # the watchdog, to a period
    assert t_seen < t_trip                                       # the driver's death tripped it
    print(f'0 V at the card {float(m[4]) - killed_at:.3f} s (wall) after SIGKILL')
    port = open_transport(str(link), timeout=0.05)               # the card, heard directly
    parser, after = FrameParser(), []
    try:
        end = time.monotonic() + 60.0
        while not after or after[-1].t_card < 30.0:              # past the 7 V and 9 V steps
            assert time.monotonic() < end, 'the card stopped streaming'
            after += [x for x in parser.feed(read_available(port, 65536))
                      if isinstance(x, pr.Sample) and x.seq >= trip_seq]
    finally:
        port.close()
    assert all(x.voltage == 0.0 and not x.flags & FLAG_PROFILE for x in after)
    assert card.stdout().count('watchdog:') == 1


def test_profile_beyond_max_voltage_is_refused_at_start(launch):
    proc = launch('driver', driver_args('device:=loop://', 'amplitude:=9.0',
                                        'max_voltage:=6.0'))
    assert proc.wait(20.0) == 2
    err = proc.stderr()
    assert 'parameter amplitude: 9 V exceeds max_voltage 6 V' in err, err
    assert 'Traceback' not in err


def test_driver_plays_the_profile_for_a_card_without_profiles(client, launch, tmp_path):
    drv, diags, samples = start_card_and_driver(
        client, launch, tmp_path, ('--speedup', '1', '--no-profiles'), 'excitation:=prbs',
        'duration:=3.0', 'amplitude:=5.0', 'seed:=4')
    resp = client.call(Trigger, '/driver/start')
    assert resp.success, resp.message
    assert wait_until(lambda: np.any(flags_of(rows_of(samples)) & FLAG_PROFILE_END), 20.0), \
        drv.output()
    drv.wait_for('the card has no built-in profiles: the driver plays prbs')
    rows = rows_of(samples)
    on = np.flatnonzero(flags_of(rows) & FLAG_PROFILE)
    assert on.size == 300 and np.all(np.diff(rows[on, 0]) == 1)
    want = profile_samples('prbs', 5.0, 4, 3.0, 0.01)
    got = rows[on, 2]
    # the card applies each command a few samples after the host's schedule (link latency)
    best = max(range(20), key=lambda lag: np.mean(got[lag:] == want[:want.size - lag]))
    assert np.mean(got[best:] == want[:want.size - best]) > 0.95, best
    assert wait_until(lambda: status(diags).get('profile_source') == 'driver', 5.0)
    n = rows_of(samples).shape[0]
    assert wait_until(lambda: rows_of(samples).shape[0] > n + 30, 10.0)
    assert np.all(rows_of(samples)[-20:, 2] == 0.0)     # 0 V after the profile
    stop_cleanly(drv)


def test_line_capacity_warning(client, launch, tmp_path):
    """100 samples/s of 34-byte frames need 34000 bit/s: 9600 baud cannot carry them."""
    drv, diags, samples = start_card_and_driver(
        client, launch, tmp_path, ('--speedup', '1'), 'excitation:=external', 'baud:=9600')
    drv.wait_for(r'100 samples/s of 34-byte frames need 34000 bit/s but the line runs at '
                 r'9600 bit/s \(at most 28 frames/s\)')
    assert wait_until(lambda: 'line_overload' in status(diags), 5.0)
    assert 'raise baud or sample_period' in status(diags)['line_overload']
    assert wait_until(lambda: rows_of(samples).shape[0] > 150, 10.0)
    assert drv.stderr().count('frames will be lost') == 1
    stop_cleanly(drv)


def test_joint_states_follow_the_samples(client, launch, tmp_path):
    joints = client.collect(JointState, 'joint_states', messages.CHANNEL_QOS)
    drv, _diags, samples = start_card_and_driver(
        client, launch, tmp_path, ('--speedup', '1'), 'excitation:=bipolar_steps',
        'duration:=5.0', 'joint_name:=left_wheel')
    assert client.call(Trigger, '/driver/start').success
    assert wait_until(lambda: rows_of(samples).shape[0] > 300 and len(joints) > 300, 60.0)
    stop_cleanly(drv)
    settle(joints, samples)     # what is still on its way in the client arrives
    rows = rows_of(samples)
    js = list(joints)
    assert all(j.name == ['left_wheel'] for j in js)
    # stamp = card time + a fixed offset: found from a joint state moving at a speed that
    # one sample alone has (the last batch of samples may be lost when the driver exits
    # while its joint states arrive); then the messages are paired by card time (a
    # message either subscription lost under load costs one pair, not the alignment)
    def ns(j):
        return j.header.stamp.sec * 10 ** 9 + j.header.stamp.nanosec

    offset = None
    for j in reversed(js):
        same = rows[(rows[:, 3] == j.velocity[0]) & (rows[:, 4] == j.effort[0])]
        if j.velocity[0] != 0.0 and same.shape[0] == 1:
            offset = ns(j) - round(same[0, 1] * 1e9)
            break
    assert offset is not None, "no joint state matches exactly one sample's values"
    by_time = {round(r[1] * 1e9): r for r in rows}
    pairs = [(j, by_time[ns(j) - offset]) for j in js if ns(j) - offset in by_time]
    k = len(pairs)
    assert k > 300 and k >= min(len(js), rows.shape[0]) - 5
    js, part = [j for j, _ in pairs], np.array([r for _, r in pairs])
    speed = np.array([j.velocity[0] for j in js])
    np.testing.assert_array_equal(speed, part[:, 3])
    np.testing.assert_array_equal([j.effort[0] for j in js], part[:, 4])
    stamps = np.array([j.header.stamp.sec * 10 ** 9 + j.header.stamp.nanosec for j in js])
    # stamps keep the card's sample spacing exactly (10 ms), not the arrival jitter
    np.testing.assert_array_equal(np.diff(stamps), np.diff(np.round(part[:, 1] * 1e9)))
    position = np.array([j.position[0] for j in js])
    steps = 0.5 * (part[1:, 3] + part[:-1, 3]) * np.diff(part[:, 1])
    seq_next = np.diff(part[:, 0]) == 1  # the position integrates every sample the driver
    np.testing.assert_allclose(np.diff(position)[seq_next], steps[seq_next], atol=1e-9)
    assert np.ptp(speed) > 1.0


def test_one_parameter_file_serves_any_node_name(launch, tmp_path):
    """config/driver.yaml is keyed /**: a renamed node in a namespace still loads it."""
    with open(os.path.join(REPO, 'config', 'driver.yaml')) as fh:
        text = fh.read()
    assert re.search(r'^/\*\*:\n  ros__parameters:', text, re.MULTILINE)
    changed = tmp_path / 'driver.yaml'
    changed.write_text(text.replace('sample_period: 0.01 ', 'sample_period: 0.02 ')
                       .replace('max_voltage: 12.0 ', 'max_voltage: 11.0 '))
    proc = launch('driver', ['-m', 'motor_id.nodes.driver', '--ros-args',
                             '-r', '__node:=left_driver', '-r', '__ns:=/robot',
                             '--params-file', str(changed),
                             '-p', f'device:={tmp_path / "none"}'])
    proc.wait_for(r'\[robot\.left_driver\]: driver started: device .*none, excitation '
                  r'paper_steps, period 0\.02 s, max_voltage 11 V')
    stop_cleanly(proc)


def test_parameter_file_lists_every_driver_parameter_with_its_default():
    """config/driver.yaml names each parameter once, with the node's default (device
    aside), so the file documents what the node does without it; autostart is off."""
    with open(os.path.join(REPO, 'config', 'driver.yaml')) as fh:
        params = yaml.safe_load(fh)
    assert list(params) == ['/**']
    values = params['/**']['ros__parameters']
    assert set(values) == {s.name for s in PARAMETERS}
    for spec in PARAMETERS:
        if spec.name != 'device':
            assert values[spec.name] == spec.default, spec.name
    assert values['autostart'] is False
