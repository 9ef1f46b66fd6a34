"""The README's main command end to end, and replaying its bag."""

import json
import os
import subprocess
import sys

import pytest

from motor_id.testing.procs import domain_id
from motor_id.testing.ros import REPO, ros_env


@pytest.fixture(scope='module')
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp('demo')
    env = ros_env(domain_id('test_demo'))
    proc = subprocess.run([sys.executable, '-m', 'motor_id.cli', 'demo', '--out', str(out),
                           '--fast', '--domain', env['ROS_DOMAIN_ID']], env=env,
                          capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return out, proc


def test_demo_recovers_the_card_parameters(demo):
    out, proc = demo
    report = json.loads((out / 'report.json').read_text())
    truth = report['truth']
    for name in ('J', 'K_T', 'K_b', 'B', 'L_m'):
        p = report['parameters'][name]
        assert p['determined']
        assert p['value'] == pytest.approx(truth[name], rel=0.01), name
        assert abs(p['value'] - truth[name]) <= 5 * p['std'], name
    assert report['ga']['evaluations'] == 3200
    assert 'truth' in proc.stdout and 'Traceback' not in proc.stderr
    png = (out / 'fit.png').read_bytes()
    assert png[:4] == b'\x89PNG' and len(png) > 20000


def test_demo_bag_opens_in_a_second_reader(demo):
    out, _ = demo
    from pathlib import Path

    from rosbags.highlevel import AnyReader
    from rosbags.typesys import get_typestore, Stores
    store = get_typestore(Stores.ROS2_JAZZY)
    rows = 0
    with AnyReader([Path(out / 'demo.mcap')], default_typestore=store) as reader:
        conns = [c for c in reader.connections if c.topic == '/samples']
        assert conns and conns[0].msgtype == 'std_msgs/msg/Float64MultiArray'
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            rows += len(msg.data) // 6
    assert rows >= 4000


def test_replay_offline_gives_the_same_fit(demo, tmp_path):
    out, _ = demo
    js = tmp_path / 'replay.json'
    env = dict(os.environ, PYTHONPATH=REPO)
    proc = subprocess.run([sys.executable, '-m', 'motor_id.cli', 'replay',
                           str(out / 'demo.mcap'), '--offline', '--profile', '-R', '2.3', '-q',
                           '--json', str(js)], capture_output=True, text=True, env=env,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    live = json.loads((out / 'report.json').read_text())['parameters']
    offline = json.loads(js.read_text())['parameters']
    for name in ('J', 'K_T', 'B', 'L_m'):
        assert offline[name]['value'] == pytest.approx(live[name]['value'], rel=2e-3), name
