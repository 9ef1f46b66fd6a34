"""Node tests: real driver / identifier processes, a real pty card, an rclpy client."""

import json
import os
import signal
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger

from motor_id.excitation import paper_steps
from motor_id.model import Plant
from motor_id.nodes import messages
from motor_id.simulate import simulate_recording
from rosutil import Client, domain_id, Process, REPO, ros_env, wait_until

DOMAIN = domain_id(__name__)
T = np.arange(4000) * 0.01


def paper_rows(n=4000, seq0=0):
    """Rows of the paper's noise-free experiment (first ``n`` samples)."""
    rec = simulate_recording(Plant(), T, paper_steps(T))
    seq = seq0 + np.arange(4000)
    rows = np.column_stack([seq, rec.time, rec.voltage, rec.speed, rec.current,
                            np.zeros(4000)])
    return rows[:n]


@pytest.fixture(scope='module')
def client():
    c = Client(DOMAIN, 'test_nodes_client')
    yield c
    c.close()


@pytest.fixture
def launch(tmp_path):
    """Start node processes (``launch(name, args)``); all are killed at the end."""
    procs = []

    def start(name, args, **env):
        p = Process(args, ros_env(DOMAIN, **env), tmp_path, name)
        procs.append(p)
        return p
    yield start
    for p in procs:
        p.close()


def identifier_args(*params):
    args = ['-m', 'motor_id.nodes.identifier', '--ros-args']
    for p in params:
        args += ['-p', p]
    return args


def publish(client, rows, batch=100):
    """Publish rows on `samples` in batches once the identifier subscribes."""
    pub = getattr(client, '_samples_pub', None)
    if pub is None:
        pub = client.node.create_publisher(Float64MultiArray, 'samples',
                                           messages.SAMPLES_QOS)
        client._samples_pub = pub
    assert wait_until(lambda: pub.get_subscription_count() > 0, 20.0)
    for k in range(0, rows.shape[0], batch):
        pub.publish(messages.rows_to_msg(rows[k:k + batch]))


def identify(client, node='identifier', timeout=60.0):
    return client.call(Trigger, f'/{node}/identify', timeout=timeout)


def stop_cleanly(proc, sig=signal.SIGINT):
    code = proc.stop(sig)
    err = proc.stderr()
    assert 'Traceback' not in err, err
    assert code == 0, f'{proc.name} exit {code}:\n{proc.output()}'


def test_identifier_refuses_without_usable_data(client, launch):
    proc = launch('identifier', identifier_args('generations:=20'))
    resp = identify(client)
    assert not resp.success and 'empty' in resp.message
    rows = paper_rows()
    publish(client, rows[:50])
    assert wait_until(lambda: 'too few' in identify(client).message, 10.0)
    resp = identify(client)
    assert not resp.success and 'too few samples: 50' in resp.message
    const = rows[50:600].copy()
    const[:, 2] = 0.0   # 0 V throughout the window (plus the first 50 rows at 0 V too)
    publish(client, const)
    assert wait_until(lambda: 'no excitation' in identify(client).message, 10.0)
    stop_cleanly(proc, signal.SIGTERM)


def test_identifier_refuses_nan_and_gaps(client, launch):
    proc = launch('identifier', identifier_args('generations:=20'))
    rows = paper_rows()
    bad = rows[:1000].copy()
    bad[500, 3] = np.nan
    publish(client, bad)
    assert wait_until(lambda: 'NaN' in identify(client).message, 10.0)
    stop_cleanly(proc)

    proc = launch('identifier2', identifier_args('generations:=20'))
    gap = np.delete(rows, np.arange(1000, 1010), axis=0)
    publish(client, gap)
    assert wait_until(lambda: 'gap' in identify(client).message, 10.0)
    resp = identify(client)
    assert not resp.success and '10 frame(s) lost' in resp.message
    stop_cleanly(proc)


def test_identifier_fits_and_latches_estimate(client, launch):
    proc = launch('identifier', identifier_args('generations:=60'))
    rows = paper_rows()
    publish(client, rows)
    assert wait_until(lambda: 'from 4000 samples' in identify(client).message, 20.0), \
        proc.output()
    # a late subscriber still gets the latched estimate and report
    estimates = client.collect(DiagnosticArray, '/identifier/estimate',
                               messages.LATCHED_QOS)
    reports = client.collect(String, '/identifier/report', messages.LATCHED_QOS)
    assert wait_until(lambda: estimates and reports, 10.0)
    values = messages.msg_to_estimate(estimates[-1])
    assert values['J_determined'] == 'true'
    assert float(values['L_m']) == pytest.approx(0.0345, rel=1e-3)
    assert float(values['K_b']) == pytest.approx(0.64, rel=1e-3)
    report = json.loads(reports[-1].data)
    assert report['data']['samples'] == 4000
    assert report['parameters']['B']['determined']
    stop_cleanly(proc)


def test_samples_flow_during_a_fit_and_second_call_is_refused(client, launch):
    proc = launch('identifier', identifier_args('generations:=1500'))
    diags = client.collect(DiagnosticArray, '/diagnostics', messages.DIAGNOSTICS_QOS)
    rows = paper_rows()
    publish(client, rows[:3000])
    proc.wait_for('identifier ready')
    assert wait_until(lambda: any(
        messages.msg_to_estimate(d).get('received') == '3000' for d in diags), 10.0)
    first = client.call_async(Trigger, '/identifier/identify')
    proc.wait_for('fitting 3000 samples')
    second = identify(client)
    assert not second.success and 'already running' in second.message
    publish(client, rows[3000:])
    assert wait_until(lambda: any(
        messages.msg_to_estimate(d).get('received') == '4000' and
        messages.msg_to_estimate(d).get('fit_running') == 'true' for d in diags), 20.0), \
        'samples were not received while the fit ran'
    assert wait_until(first.done, 60.0)
    assert first.result().success, first.result().message
    stop_cleanly(proc)


@pytest.mark.parametrize('param, name', [
    ('R_m:=-1.0', 'R_m'), ('method:=newton', 'method'), ('window_s:=60', 'window_s'),
    ('tie_kt_kb:=maybe', 'tie_kt_kb'), ('population:=1', 'population'),
])
def test_identifier_bad_parameter_stops_with_message(launch, param, name):
    proc = launch('identifier', identifier_args(param))
    code = proc.wait(20.0)
    err = proc.stderr()
    assert code != 0
    assert f'parameter {name}' in err and 'allowed' in err, err
    assert 'Traceback' not in err, err


def test_identifier_params_file_loads(launch):
    path = os.path.join(REPO, 'config', 'identifier.yaml')
    proc = launch('identifier', ['-m', 'motor_id.nodes.identifier', '--ros-args',
                                 '--params-file', path, '-p', 'window_s:=12.5'])
    proc.wait_for('identifier ready: method zoh, window 12.5 s, R_m 2.3 Ohm')
    stop_cleanly(proc)


def test_identifier_sigint_during_fit_exits_cleanly(client, launch):
    proc = launch('identifier', identifier_args('generations:=100000'))
    publish(client, paper_rows())
    time.sleep(0.5)
    fut = client.call_async(Trigger, '/identifier/identify')
    proc.wait_for('fitting 4000 samples')
    t0 = time.monotonic()
    stop_cleanly(proc)
    assert time.monotonic() - t0 < 10.0
    del fut
