"""The virtual card: exact plant continuation, commands, faults, the pty server and its CLI."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from motor_id.card import protocol as pr
from motor_id.card.faults import FaultConfig, FaultInjector
from motor_id.card.sequence import SequenceTracker
from motor_id.card.simulator import CardSimulator
from motor_id.card.stream import FrameParser
from motor_id.card.transport import open_transport, read_available, TransportError
from motor_id.card.virtual_card import VirtualCard
from motor_id.errors import ConfigError
from motor_id.excitation import make_excitation
from motor_id.model import PAPER_MOTOR, Plant
from motor_id.simulate import simulate_batch

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MEMORY_EFFECTS = {'sensor_lag': {'tau_s': 0.03}, 'input_delay': {'d': 3},
                  'coulomb_friction': {'T_c': 0.05}, 'resistance_drift': {}}


def _columns(samples):
    return {k: np.array([getattr(s, k) for s in samples])
            for k in ('seq', 't_card', 'voltage', 'speed', 'current', 'flags')}


def _resimulate(samples, plant, x0=None):
    c = _columns(samples)
    return c, simulate_batch(plant.params.to_dict(), c['t_card'], c['voltage'],
                             plant.input_kind, 'zoh', plant.effects, x0)


# ---------------------------------------------------------------------------------------
# VirtualCard: the card's logic without I/O


def test_stream_equals_one_simulation_across_commands_and_effects():
    plant = Plant(PAPER_MOTOR, 'voltage', MEMORY_EFFECTS)
    card = VirtualCard(plant, period=0.01, horizon=128)  # many re-plans
    out = card.samples(20)
    assert card.handle(pr.StartProfile('prbs', 5.0, 3, 4.0)).value == 20
    out += card.samples(450)
    card.handle(pr.SetVoltage(2.0))
    out += card.samples(200)
    assert card.handle(pr.SetPeriod(0.004)).status == 'ok'
    out += card.samples(300)
    card.handle(pr.Stop())
    out += card.samples(100)
    c, sim = _resimulate(out, plant)
    assert np.array_equal(c['seq'], np.arange(len(out)))
    np.testing.assert_allclose(np.diff(c['t_card'])[-350:], 0.004, rtol=1e-9)
    np.testing.assert_allclose(c['speed'], sim['speed'][0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(c['current'], sim['current'][0], rtol=0, atol=1e-9)
    assert np.abs(c['speed']).max() > 1.0  # the motor did move


def test_profile_voltages_and_flags():
    card = VirtualCard(period=0.01)
    card.samples(5)
    reply = card.handle(pr.StartProfile('prbs', 4.0, 11, 1.0))
    assert reply == pr.Reply('start_profile', 'ok', 5)
    c = _columns(card.samples(110))
    expected = make_excitation('prbs', np.arange(100) * 0.01, 4.0, 11).astype(np.float32)
    np.testing.assert_array_equal(c['voltage'][:100], expected)
    assert np.all(c['voltage'][100:] == 0.0)
    assert np.all(c['flags'][:100] & pr.FLAG_PROFILE)
    assert np.flatnonzero(c['flags'] & pr.FLAG_PROFILE_END).tolist() == [99]
    assert not np.any(c['flags'][100:] & pr.FLAG_PROFILE)


def test_command_replies():
    card = VirtualCard(period=0.01, max_input=24.0)
    assert card.samples(1)[0].flags & pr.FLAG_STARTUP
    assert not card.samples(1)[0].flags & pr.FLAG_STARTUP
    assert card.handle(pr.Ping(99)) == pr.Reply('ping', 'ok', 99)
    assert card.handle(pr.StartProfile('nope')).status == 'unknown_profile'
    assert card.handle(pr.StartProfile('prbs', 30.0)).status == 'bad_value'
    assert card.handle(pr.StartProfile('prbs', 3.0, 0, 0.0)).status == 'bad_value'
    assert card.handle(pr.SetVoltage(25.0)).status == 'bad_value'
    assert card.handle(pr.SetPeriod(1e-6)).status == 'bad_value'
    assert card.handle(pr.StartProfile('bipolar_steps', 3.0, 0, 1.0)).status == 'ok'
    assert card.handle(pr.SetPeriod(0.02)).status == 'busy'
    card.samples(100)
    assert card.handle(pr.SetPeriod(0.02)) == pr.Reply('set_period', 'ok', 102)
    s = card.samples(2)
    assert s[1].t_card - s[0].t_card == pytest.approx(0.02, abs=1e-12)
    with pytest.raises(ConfigError):
        card.handle(pr.Reply('stop'))


def test_watchdog_stops_a_profile_when_the_host_goes_silent():
    """Pings keep paper_steps running; 0.5 s of silence at 3.8 V stops it at 0 V (no 7 V
    at 16 s) and the stream stays one exact simulation across the stop."""
    plant = Plant(PAPER_MOTOR, 'voltage', MEMORY_EFFECTS)
    card = VirtualCard(plant, period=0.01, horizon=128, watchdog=0.5)
    out = card.samples(10)
    card.handle(pr.StartProfile('paper_steps', 9.0, 0, 40.0))
    while card.seq < 410:                      # the host pings every 100 ms up to 4.1 s
        out += card.samples(10)
        card.handle(pr.Ping(card.seq))
    last_ping = card.t_us
    out += card.samples(1800)                  # to 22 s: silence
    c, sim = _resimulate(out, plant)
    trip = card.last_trip
    assert card.watchdog_trips == 1 and trip.silence == pytest.approx(0.5, abs=1e-9)
    assert trip.last_command_us == last_ping and trip.t_us == last_ping + 500_000
    k = trip.seq
    assert np.all(c['voltage'][310:k] == np.float32(3.8)) and np.all(c['voltage'][k:] == 0)
    assert np.all(c['flags'][11:k] & pr.FLAG_PROFILE)
    assert not np.any(c['flags'][k:] & (pr.FLAG_PROFILE | pr.FLAG_PROFILE_END))
    np.testing.assert_allclose(c['speed'], sim['speed'][0], rtol=0, atol=1e-9)
    assert c['speed'][k] > 5.0 and abs(c['speed'][-1]) < 0.05 * c['speed'][k]   # stopped


def test_watchdog_stops_a_held_voltage_and_rearms_on_the_next_command():
    card = VirtualCard(period=0.01, watchdog=0.2)
    card.samples(3)
    card.handle(pr.SetVoltage(5.0), t_us=card.t_us - 5000)    # 5 ms before the next sample
    v = _columns(card.samples(30))['voltage']
    assert v.tolist() == [5.0] * 20 + [0.0] * 10               # 0 V from 195 ms on
    assert card.last_trip.silence == pytest.approx(0.205)
    card.handle(pr.SetVoltage(-2.0))
    v = _columns(card.samples(25))['voltage']
    assert v.tolist() == [-2.0] * 20 + [0.0] * 5 and card.watchdog_trips == 2
    card.handle(pr.Stop())
    card.samples(100)                                          # idle: nothing to stop
    card.handle(pr.StartProfile('bipolar_steps', 3.0, 0, 0.1))
    card.samples(100)                                          # ended before 0.2 s
    assert card.watchdog_trips == 2 and card.truth().watchdog == 0.2


def test_noise_is_seeded_and_sized():
    def run(seed):
        card = VirtualCard(speed_noise=0.05, current_noise=0.01, random_state=seed)
        return _columns(card.samples(2000))

    a, b, c = run(1), run(1), run(2)
    assert np.array_equal(a['speed'], b['speed']) and not np.array_equal(a['speed'], c['speed'])
    assert np.std(a['speed']) == pytest.approx(0.05, rel=0.1)  # motor at rest: pure noise
    assert np.std(a['current']) == pytest.approx(0.01, rel=0.1)


def test_torque_plant_has_no_current():
    card = VirtualCard(Plant(PAPER_MOTOR, 'torque'), with_current=True)
    card.handle(pr.SetVoltage(1.0))
    s = card.samples(10)
    assert all(not x.has_current for x in s) and s[-1].speed > 0
    assert card.truth().input_kind == 'torque'


def test_history_cut_continues_from_the_exact_state():
    card = VirtualCard(period=0.01, horizon=50, max_history=60)
    card.handle(pr.StartProfile('multisine', 6.0, 2, 5.0))
    out = card.samples(500)
    c, sim = _resimulate(out, Plant())
    np.testing.assert_allclose(c['speed'], sim['speed'][0], rtol=1e-9, atol=1e-9)


def test_truth_reports_plant_and_settings():
    plant = Plant(PAPER_MOTOR, 'voltage', {'coulomb_friction': {'T_c': 0.1}})
    truth = VirtualCard(plant, period=0.005, speed_noise=0.1).truth()
    assert truth.params == PAPER_MOTOR.to_dict()
    assert truth.effects == {'coulomb_friction': {'T_c': 0.1}}
    assert truth.period == 0.005 and truth.speed_noise == 0.1


# ---------------------------------------------------------------------------------------
# fault injection, exact counts without I/O


def _inject(config, n=3000, seed=0):
    card = VirtualCard(period=0.001)
    inj = FaultInjector(config, random_state=seed)
    data = b''.join(inj.apply(pr.encode_sample(s)) for s in card.samples(n))
    parser = FrameParser()
    tracker = SequenceTracker()
    items = parser.feed(data) + parser.flush()
    for item in items:
        if isinstance(item, pr.Sample):
            tracker.update(item.seq)
    return inj.stats, parser, tracker


def test_fault_counts_drop_duplicate_reorder():
    stats, parser, tr = _inject(FaultConfig(drop=0.02))
    assert stats['dropped'] > 20 and tr.lost == stats['dropped'] - (tr.last != 2999)
    stats, parser, tr = _inject(FaultConfig(duplicate=0.02))
    assert stats['duplicated'] > 20 and tr.duplicates == stats['duplicated'] and tr.lost == 0
    stats, parser, tr = _inject(FaultConfig(reorder=0.02))
    assert stats['reordered'] > 20 and tr.late == stats['reordered'] and tr.lost == 0
    assert not parser.errors and parser.garbage_bytes == 0


def test_fault_counts_bad_crc_and_garbage():
    stats, parser, tr = _inject(FaultConfig(bad_crc=0.02))
    assert stats['bad_crc'] > 20 and parser.errors == {'bad_crc': stats['bad_crc']}
    assert tr.lost == stats['bad_crc'] and parser.garbage_bytes == 0
    stats, parser, tr = _inject(FaultConfig(garbage=0.05, garbage_max=40))
    assert stats['garbage_bytes'] > 500 and parser.garbage_bytes == stats['garbage_bytes']
    assert tr.received == 3000 and tr.lost == 0 and not parser.errors


def test_fault_config_parsing():
    f = FaultConfig.parse(['garbage=0.1:8', 'drop=0.01', 'disconnect=2:0.5'])
    assert (f.garbage, f.garbage_max, f.drop, f.disconnect_every, f.disconnect_for) == \
        (0.1, 8, 0.01, 2.0, 0.5)
    assert f.any and not FaultConfig().any
    for bad, message in ((['drop=2'], 'probability'), (['drop=x'], 'needs a number'),
                         (['jitter=0.1'], 'unknown fault'), (['drop=0.1:3'], 'unknown fault')):
        with pytest.raises(ConfigError, match=message):
            FaultConfig.parse(bad)


# ---------------------------------------------------------------------------------------
# the card on a real pseudo-terminal


def _read_until(port, parser, done, timeout=60.0):
    """Parse what the card sends until ``done(items)``; ``timeout`` [s] is a failure
    bound (10 s was passed twice at a load average of ~24 on 2 cores)."""
    items = []
    end = time.monotonic() + timeout
    while not done(items):
        assert time.monotonic() < end, 'the simulated card did not deliver in time'
        items += parser.feed(read_available(port, 65536))
    return items


def test_pty_profile_matches_simulate_batch():
    plant = Plant(PAPER_MOTOR, 'voltage', {'sensor_lag': {'tau_s': 0.02}})
    with CardSimulator(plant, period=0.01, speedup=100.0, random_state=0) as sim:
        assert os.path.realpath(sim.path).startswith('/dev/pts/')
        port = open_transport(sim.path, timeout=0.05)
        try:
            port.write(pr.encode_command(pr.StartProfile('paper_steps', 9.0, 0, 32.0)))
            parser = FrameParser()
            items = _read_until(port, parser, lambda it: any(
                isinstance(s, pr.Sample) and s.flags & pr.FLAG_PROFILE_END for s in it))
        finally:
            port.close()
    samples = [s for s in items if isinstance(s, pr.Sample)]
    assert not parser.errors and parser.garbage_bytes == 0
    seqs = np.array([s.seq for s in samples])
    assert np.all(np.diff(seqs) == 1)
    reply = parser.replies.popleft()
    assert reply.command == 'start_profile' and reply.status == 'ok'
    profile = [s for s in samples if s.flags & pr.FLAG_PROFILE]
    assert len(profile) == 3200 and profile[0].seq == reply.value
    c, sim = _resimulate(profile, plant)
    np.testing.assert_array_equal(c['voltage'], np.float32(
        make_excitation('paper_steps', np.arange(3200) * 0.01)))
    # float32 on the wire: ~6e-8 relative
    np.testing.assert_allclose(c['speed'], sim['speed'][0], rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(c['current'], sim['current'][0], rtol=1e-6, atol=1e-5)
    assert c['speed'].max() > 10.0


def test_pty_watchdog_counts_wall_seconds_and_stops_the_profile():
    """At 4x real time a 0.25 s (wall) watchdog is 1 s of card time: the host pings
    every 50 ms into the 3.8 V step, then goes silent; 0 V follows 1 s (card) later."""
    with CardSimulator(period=0.01, speedup=4.0, watchdog=0.25, random_state=0) as sim:
        port = open_transport(sim.path, timeout=0.02)
        parser, samples = FrameParser(), []
        try:
            port.write(pr.encode_command(pr.StartProfile('paper_steps', 9.0, 0, 40.0)))
            pinged, end = 0.0, time.monotonic() + 60.0
            while not samples or samples[-1].t_card < 4.0:      # ping into the 3.8 V step
                assert time.monotonic() < end, 'the simulated card did not deliver in time'
                samples += [x for x in parser.feed(read_available(port, 65536))
                            if isinstance(x, pr.Sample)]
                if time.monotonic() - pinged > 0.05:
                    port.write(pr.encode_command(pr.Ping(len(samples))))
                    pinged = time.monotonic()
            items = _read_until(port, parser, lambda it: sim.card.watchdog_trips and any(
                isinstance(x, pr.Sample) and x.seq > sim.card.last_trip.seq + 100
                for x in it))
        finally:
            port.close()
        trip = sim.card.last_trip
    samples += [x for x in items if isinstance(x, pr.Sample)]
    assert sim.card.watchdog_trips == 1
    assert 1.0 <= trip.silence <= 1.0 + 0.01 + 1e-9            # card time, to a period
    v = {x.seq: x.voltage for x in samples}
    assert v[trip.seq - 1] == np.float32(3.8) and v[trip.seq] == 0.0
    assert all(v[q] == 0.0 for q in v if q >= trip.seq)


def test_pty_faults_reach_the_parser():
    faults = FaultConfig(garbage=0.02, drop=0.01, bad_crc=0.01, duplicate=0.01, reorder=0.01)
    with CardSimulator(speedup=0, faults=faults, random_state=5) as sim:
        port = open_transport(sim.path, timeout=0.05)
        parser, tracker = FrameParser(), SequenceTracker()
        first = None  # opening the port flushes what the card sent before
        try:
            end = time.monotonic() + 10.0
            while tracker.received < 8000 and time.monotonic() < end:
                for item in parser.feed(read_available(port, 65536)):
                    if isinstance(item, pr.Sample):
                        first = item.seq if tracker.update(item.seq).kind == 'first' else first
        finally:
            port.close()
        stats = sim.stats
    assert tracker.received >= 8000
    assert 0 < parser.errors['bad_crc'] <= stats['bad_crc']
    assert 0 < tracker.duplicates <= stats['duplicated']
    assert 0 < tracker.late <= stats['reordered']
    assert parser.garbage_bytes >= 0.8 * stats['garbage_bytes'] * tracker.last / stats['frames']
    # every sequence number up to the last one is accounted for
    assert tracker.received - tracker.duplicates + tracker.lost == tracker.last - first + 1
    assert tracker.lost >= 0.5 * (stats['dropped'] + stats['bad_crc']) * tracker.last \
        / stats['frames']


def test_pty_disconnect_comes_back_at_the_link(tmp_path):
    link = str(tmp_path / 'card')
    faults = FaultConfig(disconnect_every=0.4, disconnect_for=0.2)
    with CardSimulator(speedup=5.0, faults=faults, link=link, random_state=0) as sim:
        port = open_transport(link, timeout=0.05)
        parser, tracker = FrameParser(), SequenceTracker()
        events, vanished = [], False
        end = time.monotonic() + 5.0
        while sum(e.kind == 'gap' for e in events) < 1 and time.monotonic() < end:
            try:
                for item in parser.feed(read_available(port)):
                    events.append(tracker.update(item.seq))
            except TransportError:
                port.close()
                parser.reset()
                while True:
                    vanished |= not os.path.lexists(link)
                    try:
                        port = open_transport(link, timeout=0.05)
                        break
                    except TransportError:
                        time.sleep(0.01)
        port.close()
        stats = sim.stats
    assert vanished, 'the link should disappear while the card is away'
    gaps = [e for e in events if e.kind == 'gap']
    assert gaps and gaps[0].lost >= 0.1 / (0.01 / 5.0)  # ~0.2 s of samples at 500/s
    # samples taken while away are lost (more may be: what the pty held at the
    # disconnect, and what came before this reader reopened it, on a loaded machine)
    assert stats['disconnects'] >= 1 and stats['lost_offline'] >= 0.1 / (0.01 / 5.0)
    assert not os.path.lexists(link)  # removed on stop


def test_simulator_refuses_to_replace_a_file(tmp_path):
    target = tmp_path / 'real'
    target.write_text('keep me')
    with pytest.raises(ConfigError, match='not a symlink'):
        CardSimulator(link=str(target)).start()
    assert target.read_text() == 'keep me'


# ---------------------------------------------------------------------------------------
# command line


def _cli(*args):
    env = dict(os.environ, PYTHONPATH=REPO)
    return subprocess.Popen([sys.executable, '-m', 'motor_id.cli', 'card-sim', *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env, cwd=REPO)


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_cli_prints_the_path_and_stops_cleanly(tmp_path, sig):
    link = tmp_path / 'card'
    truth = tmp_path / 'truth.json'
    proc = _cli('--link', str(link), '--speedup', '20', '--effect', 'coulomb_friction=0.1',
                '--noise', '0.01', '--truth-out', str(truth), '--seed', '3')
    try:
        first = proc.stdout.readline().strip()
        assert first == str(link) and os.path.islink(link)
        port = open_transport(first, timeout=0.05)
        port.write(pr.encode_command(pr.Ping(7)))
        parser = FrameParser()
        _read_until(port, parser, lambda it: len(parser.replies) > 0)
        assert parser.replies[0] == pr.Reply('ping', 'ok', 7)
        port.close()
        assert '"T_c": 0.1' in truth.read_text()
    finally:
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert 'Traceback' not in err and not os.path.lexists(link)


# the signal lands while the main thread holds the lock of the event it waits on (in
# Condition._acquire_restore on a wake-up): a handler that sets that event deadlocks.
# That left a killed demo's card simulator running (its handler did so)
_SIGNAL_IN_A_LOCK = """
import os, signal, sys
from motor_id.card.simulator import CardSimulator
from motor_id.cli import main
fired = False
def hook(frame, event, arg):
    global fired
    if not fired and event == 'return' and frame.f_code.co_name == '_acquire_restore':
        fired = True
        os.kill(os.getpid(), signal.SIGTERM)
start = CardSimulator.start
def start_then_hook(self):
    out = start(self)
    sys.setprofile(hook)    # the main thread's calls from now on
    return out
CardSimulator.start = start_then_hook
sys.exit(main(sys.argv[1:]))
"""


def test_cli_stops_at_0_v_on_a_signal_that_lands_while_its_main_thread_holds_a_lock():
    proc = subprocess.Popen([sys.executable, '-c', _SIGNAL_IN_A_LOCK, 'card-sim',
                             '--speedup', '10'], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONPATH=REPO))
    try:
        out, err = proc.communicate(timeout=120)   # a failure bound: it hung for good
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    lines = out.splitlines()
    assert lines[0].startswith('/dev/pts/') and lines[-1].startswith('stopped: 0 V from seq')


def test_stop_puts_the_card_at_0_v_first():
    """A profile runs at 9 V; stop(): the card holds 0 V from the next sample, as a
    host's Stop would, and nothing drives it."""
    sim = CardSimulator(period=0.01, speedup=50.0, random_state=0).start()
    try:
        port = open_transport(sim.path, timeout=0.05)
        port.write(pr.encode_command(pr.StartProfile('paper_steps', 9.0, 0, 40.0)))
        parser = FrameParser()
        _read_until(port, parser, lambda it: any(
            isinstance(x, pr.Sample) and x.voltage == np.float32(9.0) for x in it),
            timeout=60.0)
        port.close()
    finally:
        sim.stop()
    assert sim.halted_at is not None and sim.halted_at <= sim.card.seq
    assert not sim.card.profile_running and not sim.running and not sim.connected
    assert [x.voltage for x in sim.card.samples(50)] == [0.0] * 50


def test_cli_user_errors_are_one_line():
    proc = _cli('--fault', 'disconnect=1')
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 2 and out == ''
    assert err.strip().startswith('motor-id card-sim: error:') and 'needs --link' in err
    assert len(err.strip().splitlines()) == 1
