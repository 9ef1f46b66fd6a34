"""Node tests: real driver / identifier processes, a real pty card, an rclpy client."""

import json
import os
import re
import signal
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from std_msgs.msg import Float64, Float64MultiArray, String
from std_srvs.srv import Trigger

from motor_id.bag import read_recording, read_samples
from motor_id.contracts import FLAG_PROFILE_END
from motor_id.excitation import paper_steps
from motor_id.model import MotorParams, Plant, transfer_coefficients
from motor_id.nodes import messages
from motor_id.simulate import simulate_recording
from motor_id.testing.procs import wait_until
from motor_id.testing.ros import latest_status, publish_samples, REPO, rows_of, stop_cleanly

T = np.arange(4000) * 0.01


def paper_rows(n=4000, seq0=0):
    """Rows of the paper's noise-free experiment (first ``n`` samples)."""
    rec = simulate_recording(Plant(), T, paper_steps(T))
    seq = seq0 + np.arange(4000)
    rows = np.column_stack([seq, rec.time, rec.input, rec.speed, rec.current,
                            np.zeros(4000)])
    return rows[:n]


def identifier_args(*params):
    args = ['-m', 'motor_id.nodes.identifier', '--ros-args']
    for p in params:
        args += ['-p', p]
    return args


def publish(client, rows, batch=100):
    """Publish rows on `samples` in batches once the identifier subscribes."""
    publish_samples(client, rows, batch)


def identify(client, node='identifier', timeout=60.0):
    return client.call(Trigger, f'/{node}/identify', timeout=timeout)


def driver_args(*params):
    args = ['-m', 'motor_id.nodes.driver', '--ros-args']
    for p in params:
        args += ['-p', p]
    return args


def card_args(link, *extra):
    return ['-m', 'motor_id.cli', 'card-sim', '--link', str(link)] + list(extra)


def test_driver_streams_contiguous_samples_and_records(client, launch, tmp_path):
    link = tmp_path / 'card'
    bag = tmp_path / 'run.mcap'
    launch('card', card_args(link, '--speedup', '5'))
    samples = client.collect(Float64MultiArray, 'samples', messages.SAMPLES_QOS)
    speeds = client.collect(Float64, 'speed', messages.CHANNEL_QOS)
    diags = client.collect(DiagnosticArray, '/diagnostics', messages.DIAGNOSTICS_QOS)
    drv = launch('driver', driver_args(f'device:={link}', 'excitation:=prbs',
                                       'duration:=3.0', f'record_path:={bag}',
                                       'autostart:=false'))
    drv.wait_for('device .* open')
    assert wait_until(lambda: len(samples) > 0, 20.0)
    assert client.call(Trigger, '/driver/start').success
    assert wait_until(lambda: np.any(rows_of(samples)[:, 5].astype(int) & FLAG_PROFILE_END),
                      30.0), drv.output()
    rows = rows_of(samples)
    assert rows.shape[0] > 300
    np.testing.assert_array_equal(np.diff(rows[:, 0]), 1.0)
    assert np.all(np.diff(rows[:, 1]) > 0)
    assert np.ptp(rows[:, 2]) > 10.0        # the prbs profile reached the card: +-9 V
    assert np.all(np.isfinite(rows[:, 4]))  # the card measures current
    assert len(speeds) > 100
    assert wait_until(lambda: latest_status(diags, 'motor_id: driver').get('link')
                      == 'connected', 5.0)
    st = latest_status(diags, 'motor_id: driver')
    assert int(st['frames_ok']) > 0 and st['frames_bad'] == '0' and st['lost'] == '0'
    stop_cleanly(drv)
    rec = read_recording(str(bag))
    assert len(rec) >= rows.shape[0]
    assert rec.meta['provenance']['excitation'] == 'prbs'
    assert not rec.meta['gaps']


def test_driver_survives_missing_device_and_disconnects(client, launch, tmp_path):
    link = tmp_path / 'card'
    diags = client.collect(DiagnosticArray, '/diagnostics', messages.DIAGNOSTICS_QOS)
    samples = client.collect(Float64MultiArray, 'samples', messages.SAMPLES_QOS)
    drv = launch('driver', driver_args(f'device:={link}', 'reopen_backoff_max:=0.3',
                                       'excitation:=bipolar_steps', 'duration:=100.0'))
    drv.wait_for('cannot open')
    launch('card', card_args(link, '--speedup', '2', '--fault', 'disconnect=1.5:0.5'))
    drv.wait_for('device .* open')
    drv.wait_for('device lost', timeout=10.0)
    drv.wait_for('reopened', timeout=10.0)

    def recovered():
        st = latest_status(diags, 'motor_id: driver')
        return (st.get('link') == 'connected' and int(st.get('device_lost', 0)) >= 1 and
                int(st.get('opens', 0)) >= 2)
    assert wait_until(recovered, 15.0), latest_status(diags, 'motor_id: driver')
    n = rows_of(samples).shape[0]
    assert wait_until(lambda: rows_of(samples).shape[0] > n + 50, 10.0)
    rows = rows_of(samples)
    assert np.all(np.diff(rows[:, 1]) > 0)  # one card, time keeps going across reopens
    assert np.any(np.diff(rows[:, 0]) > 1)  # the frames sent while away are missing
    assert drv.output().count('device lost') == 1    # logged once per outage kind...
    stop_cleanly(drv, signal.SIGTERM)


def test_driver_counts_bad_frames_and_drops_duplicates(client, launch, tmp_path):
    link = tmp_path / 'card'
    diags = client.collect(DiagnosticArray, '/diagnostics', messages.DIAGNOSTICS_QOS)
    samples = client.collect(Float64MultiArray, 'samples', messages.SAMPLES_QOS)
    launch('card', card_args(link, '--speedup', '5', '--seed', '3', '--fault', 'garbage=0.05',
                             '--fault', 'bad_crc=0.03', '--fault', 'drop=0.03',
                             '--fault', 'duplicate=0.03', '--fault', 'reorder=0.03'))
    drv = launch('driver', driver_args(f'device:={link}', 'duration:=100.0'))

    def counted():
        st = latest_status(diags, 'motor_id: driver')
        return all(int(st.get(k, 0)) > 0 for k in ('frames_bad', 'lost', 'duplicates',
                                                    'garbage_bytes', 'late'))
    assert wait_until(counted, 20.0), latest_status(diags, 'motor_id: driver')
    rows = rows_of(samples)
    assert np.all(np.diff(rows[:, 0]) >= 1)     # published seq strictly increasing
    st = latest_status(diags, 'motor_id: driver')
    assert st['link'] == 'connected'
    stop_cleanly(drv)


def test_driver_forwards_external_voltage_commands(client, launch, tmp_path):
    link = tmp_path / 'card'
    samples = client.collect(Float64MultiArray, 'samples', messages.SAMPLES_QOS)
    launch('card', card_args(link, '--speedup', '2'))
    drv = launch('driver', driver_args(f'device:={link}', 'excitation:=external'))
    drv.wait_for('device .* open')
    pub = client.node.create_publisher(Float64, 'voltage_command', messages.CHANNEL_QOS)
    assert wait_until(lambda: pub.get_subscription_count() > 0, 20.0)

    def follows():
        pub.publish(Float64(data=4.5))
        rows = rows_of(samples[-5:])
        return rows.shape[0] and rows[-1, 2] == 4.5
    assert wait_until(follows, 10.0, interval=0.2)
    stop_cleanly(drv)


@pytest.mark.parametrize('param, name', [
    ('excitation:=sine', 'excitation'), ('baud:=0', 'baud'), ('device:=', 'device'),
    ('sample_period:=-0.01', 'sample_period'),
])
def test_driver_bad_parameter_stops_with_message(launch, param, name):
    args = driver_args(param) if param != 'device:=' else \
        ['-m', 'motor_id.nodes.driver', '--ros-args', '-p', "device:=''"]
    proc = launch('driver', args)
    code = proc.wait(20.0)
    err = proc.stderr()
    assert code != 0
    assert f'parameter {name}' in err, err
    assert 'Traceback' not in err, err


def test_driver_params_file_loads(launch, tmp_path):
    path = os.path.join(REPO, 'config', 'driver.yaml')
    proc = launch('driver', ['-m', 'motor_id.nodes.driver', '--ros-args', '--params-file',
                             path, '-p', f'device:={tmp_path / "none"}'])
    proc.wait_for('driver started: device .*none, excitation paper_steps, period 0.01 s')
    stop_cleanly(proc)


def test_card_driver_identifier_recover_the_motor(client, launch, tmp_path):
    """End to end: noise-free card, the paper's excitation, the ZOH fit."""
    truth = MotorParams(J=0.052, K_T=0.66, K_b=0.66, B=0.002, L_m=0.0345, R_m=2.3)
    params = tmp_path / 'motor.json'
    params.write_text(json.dumps(truth.to_dict()))
    link = tmp_path / 'card'
    diags = client.collect(DiagnosticArray, '/diagnostics', messages.DIAGNOSTICS_QOS)
    samples = client.collect(Float64MultiArray, 'samples', messages.SAMPLES_QOS)
    launch('card', card_args(link, '--speedup', '10', '--params', str(params)))
    ident = launch('identifier', identifier_args('select:=profile', 'window_s:=120.0'))
    drv = launch('driver', driver_args(f'device:={link}', 'autostart:=false',
                                       'publish_channels:=false'))   # 1000 samples/s
    assert wait_until(lambda: int(latest_status(diags, 'motor_id: identifier')
                                  .get('received', 0)) > 0, 60.0), ident.output()
    resp = client.call(Trigger, '/driver/start')
    assert resp.success, resp.message
    assert wait_until(lambda: np.any(rows_of(samples[-20:])[:, 5].astype(int)
                                     & FLAG_PROFILE_END), 120.0), drv.output()
    ok, text = client.identify()   # it may get the profile's last rows after us
    assert ok, text
    assert 'from 4000 samples' in text
    reports = client.collect(String, '/identifier/report', messages.LATCHED_QOS)
    assert wait_until(lambda: reports, 10.0)
    report = json.loads(reports[-1].data)
    est = {k: v['value'] for k, v in report['parameters'].items()}
    for name in ('J', 'K_T', 'K_b', 'B', 'L_m'):
        assert est[name] == pytest.approx(getattr(truth, name), rel=0.01), name
    coeffs = transfer_coefficients(truth.to_dict(), channels=('speed', 'current'))
    for c in report['identifiable_combinations']:
        if c['name'] in coeffs:
            assert c['value'] == pytest.approx(coeffs[c['name']], rel=1e-3)
    for proc in (drv, ident):
        stop_cleanly(proc)


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


def test_identifier_uses_fixed_values_and_bounds(client, launch):
    """`fix` is an assumption the fit keeps; with J known and no tie the paper's motor
    (K_T != K_b) is recovered exactly; `bounds` reach the GA."""
    proc = launch('identifier', identifier_args(
        'generations:=60', 'tie_kt_kb:=false', 'fix:=J=0.052',
        'bounds:=K_T=0.1:2, K_b=0.1:2, B=1e-5:0.05, L_m=1e-3:0.1'))
    publish(client, paper_rows())
    assert wait_until(lambda: 'from 4000 samples' in identify(client).message, 20.0), \
        proc.output()
    reports = client.collect(String, '/identifier/report', messages.LATCHED_QOS)
    assert wait_until(lambda: reports, 10.0)
    params = json.loads(reports[-1].data)['parameters']
    assert params['J']['value'] == 0.052 and params['J']['std'] in (0, 0.0, None)
    for name, truth in (('K_T', 0.66), ('K_b', 0.64), ('B', 0.002), ('L_m', 0.0345)):
        assert params[name]['determined']
        assert params[name]['value'] == pytest.approx(truth, rel=1e-3), name
    stop_cleanly(proc)


def test_samples_flow_during_a_fit_and_second_call_is_refused(client, launch):
    proc = launch('identifier', identifier_args('generations:=5000'))
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
    ('bounds:=J=1:0.1', 'bounds'), ('bounds:=B=0:1', 'bounds'), ('bounds:=R_m=1:3', 'bounds'),
    ('fix:=J=-0.05', 'fix'), ('fix:=Q=1', 'fix'), ('fix:=R_m=2', 'fix'),
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


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGHUP])
def test_driver_and_identifier_stop_as_on_ctrl_c(client, launch, tmp_path, sig):
    """SIGTERM and SIGHUP end both nodes as Ctrl-C does: exit 0, no traceback, no use of a
    destroyed entity (stop_cleanly), the driver's recording closed with what it read;
    sent twice (as the parent-death signal of a dying parent comes), it is no harder."""
    link, bag = tmp_path / 'card', tmp_path / 'rec.mcap'
    samples = client.collect(Float64MultiArray, 'samples', messages.SAMPLES_QOS)
    launch('card', card_args(link, '--speedup', '5'))
    drv = launch('driver', driver_args(f'device:={link}', 'excitation:=paper_steps',
                                       'autostart:=true', f'record_path:={bag}'))
    ident = launch('identifier', identifier_args('period_s:=0.5', 'min_samples:=100'))
    assert wait_until(lambda: rows_of(samples).shape[0] > 300, 60.0), drv.output()
    ident.wait_for('fitting', 60.0)     # the timer's fits run: a signal may meet one
    for proc in (ident, drv):
        proc.send_signal(sig)
        stop_cleanly(proc, sig)
    assert len(read_recording(bag)) >= rows_of(samples).shape[0] - 20


def test_identifier_sigint_during_fit_exits_cleanly(client, launch):
    proc = launch('identifier', identifier_args('generations:=100000'))
    diags = client.collect(DiagnosticArray, '/diagnostics', messages.DIAGNOSTICS_QOS)
    publish(client, paper_rows())
    assert wait_until(lambda: latest_status(diags, 'motor_id: identifier').get(
        'received') == '4000', 60.0), proc.output()      # all in: the fit takes them all
    fut = client.call_async(Trigger, '/identifier/identify')
    proc.wait_for('fitting 4000 samples', 60.0)
    t0 = time.monotonic()
    stop_cleanly(proc)
    assert time.monotonic() - t0 < 30.0       # the GA stops at its next generation
    del fut


PAPER_BAG = os.path.join(REPO, 'bags', 'sim_card_paper.mcap')


def replay_args(rate, *extra):
    return ['-m', 'motor_id.cli', 'replay', PAPER_BAG, '--rate', str(rate)] + list(extra)


def test_replay_rate_feeds_a_live_identifier(client, launch):
    """`motor-id replay BAG --rate X` republishes the bag; a live identifier fits it."""
    rows = read_samples(PAPER_BAG).seq.size
    proc = launch('identifier', identifier_args('generations:=60', 'window_s:=1000.0'))
    proc.wait_for('identifier ready')
    # this client's own samples subscriptions (earlier tests) count as subscribers too:
    # the replay waits until the identifier is matched as well
    assert wait_until(lambda: any(i.node_name == 'identifier' for i in
                                  client.node.get_subscriptions_info_by_topic('/samples')),
                      20.0)
    subs = client.node.count_subscribers('/samples')
    rep = launch('replay', replay_args(20, '--subscribers', str(subs)))
    assert rep.wait(90.0) == 0, rep.output()
    assert f'published {rows} of {rows} samples on /samples' in rep.stdout()
    assert 'Traceback' not in rep.stderr(), rep.stderr()
    resp = identify(client)
    assert resp.success, resp.message
    # subscribers matched late would only shorten the record at its start, never gap it
    fitted = int(re.search(r'identified from (\d+) samples', resp.message).group(1))
    assert rows - 200 <= fitted <= rows, resp.message
    stop_cleanly(proc)


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_replay_stops_cleanly_on_a_signal(client, launch, sig):
    got = client.collect(Float64MultiArray, 'samples', messages.SAMPLES_QOS)
    rep = launch('replay', replay_args(1))
    rep.wait_for('replaying')
    assert wait_until(lambda: got, 20.0), rep.output()   # replaying, at 1x: 87 s to go
    time.sleep(1.0)
    t0 = time.monotonic()
    code = rep.stop(sig)
    assert time.monotonic() - t0 < 10.0
    published = re.search(r'published (\d+) of (\d+) samples', rep.stdout())
    assert published, rep.output()
    assert 0 < int(published.group(1)) < int(published.group(2))
    assert code == 1   # not everything was published, and it says how much
    assert 'Traceback' not in rep.stderr(), rep.stderr()
