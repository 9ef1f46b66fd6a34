"""The README's main command end to end, replaying its bag, and stopping it any way."""

import json
import os
import signal
import subprocess
import sys

import psutil
import pytest

from motor_id.bag import bag_info, read_recording
from motor_id.testing.procs import domain_id, Process, wait_until
from motor_id.testing.ros import REPO, ros_env


@pytest.fixture(scope='module')
def demo(tmp_path_factory):
    """The README's command at its own speed (10x; --fast's 4,000 samples/s through three
    Python processes is more than two busy cores carry)."""
    out = tmp_path_factory.mktemp('demo')
    env = ros_env(domain_id('test_demo'))
    proc = subprocess.run([sys.executable, '-m', 'motor_id.cli', 'demo', '--out', str(out),
                           '--domain', env['ROS_DOMAIN_ID']], env=env,
                          capture_output=True, text=True, timeout=600)
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


# ---------------------------------------------------------------------------------------
# stopping the demo: every child gone, the bag closed


def _start_demo(tmp_path, name):
    """The demo at 10x real time, up to its profile's start; its three children."""
    out = tmp_path / name
    env = ros_env(domain_id(f'test_demo_{name}'))
    demo = Process(['-m', 'motor_id.cli', 'demo', '--out', str(out), '--domain',
                    env['ROS_DOMAIN_ID']], env, tmp_path, name)
    demo.wait_for(r'^driver: .*profile started', timeout=180.0, stream='stdout')
    kids = psutil.Process(demo.pid).children(recursive=True)
    names = sorted(next(a for a in k.cmdline() if a.startswith('motor_id.')) for k in kids)
    assert names == ['motor_id.cli', 'motor_id.nodes.driver', 'motor_id.nodes.identifier'], [
        k.cmdline() for k in kids]
    return demo, out, kids


def _gone(proc):
    try:
        return proc.status() == psutil.STATUS_ZOMBIE   # ended, not yet reaped by init
    except psutil.NoSuchProcess:
        return True


def _clean_logs(out):
    """No child printed a traceback or used a destroyed ROS entity."""
    for name in ('card', 'driver', 'identifier'):
        err = (out / f'{name}.err').read_text()
        assert 'Traceback' not in err and 'Destroyable' not in err, (name, err)


def _bag_closed(out):
    info = bag_info(out / 'demo.mcap')
    assert info.complete, info.problem
    assert len(read_recording(out / 'demo.mcap')) > 0


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGHUP])
def test_demo_stops_on_sigterm_and_sighup_as_on_ctrl_c(tmp_path, sig):
    """SIGTERM and SIGHUP mid-profile: the demo ends as on Ctrl-C (exit 130), its card,
    driver and identifier end before it does, cleanly, and the bag is closed."""
    demo, out, kids = _start_demo(tmp_path, signal.Signals(sig).name)
    demo.send_signal(sig)
    code = demo.finish(90.0)           # a failure bound: it takes a few seconds
    assert not demo.killed, demo.output()
    assert code == 130 and 'interrupted' in demo.stderr(), demo.output()
    assert all(_gone(k) for k in kids)
    _clean_logs(out)
    _bag_closed(out)


def test_demo_children_die_with_their_killed_parent(tmp_path):
    """SIGKILL of the demo: the kernel sends its children SIGTERM (the parent-death
    signal), and they stop as cleanly as on Ctrl-C, the driver closing the bag."""
    demo, out, kids = _start_demo(tmp_path, 'KILL')
    os.kill(demo.pid, signal.SIGKILL)
    assert demo.finish(30.0) == -signal.SIGKILL
    assert wait_until(lambda: all(_gone(k) for k in kids), 90.0), [
        (k.pid, k.cmdline()) for k in kids if not _gone(k)]
    _clean_logs(out)
    _bag_closed(out)
