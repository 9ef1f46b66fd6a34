"""The host side without ROS: CardLink on loop:// and a pty, limits, host-played profiles."""

import argparse
import time

import numpy as np
import pytest

from motor_id.card import protocol as pr
from motor_id.card.faults import FaultConfig, FaultInjector
from motor_id.card.link import CardLink, GARBLED_BYTES, max_frame_rate, SampleClock
from motor_id.card.profile import profile_samples
from motor_id.card.session import HostProfile, Session
from motor_id.card.simulator import CardSimulator
from motor_id.card.supervisor import Limits, Supervisor
from motor_id.card.transport import TransportError
from motor_id.card.virtual_card import VirtualCard
from motor_id.cli import card_sim
from motor_id.contracts import FLAG_LIMIT, FLAG_PROFILE, FLAG_PROFILE_END
from motor_id.errors import ConfigError, MotorIdError


class Log:
    """Collects ``(level, text)`` lines the way a node's logger would."""

    def __init__(self):
        self.lines = []

    def __call__(self, level, text):
        self.lines.append((level, text))

    def count(self, part):
        return sum(part in text for _, text in self.lines)


def f32_sample(seq, rng, t_step=0.01, current=True):
    v, w, i = np.asarray(rng.normal(0.0, 3.0, 3), dtype=np.float32).astype(float)
    return pr.Sample(seq, seq * round(t_step * 1e6) / 1e6, float(v), float(w),
                     float(i) if current else float('nan'), pr.FLAG_CURRENT if current else 0)


def poll_until(link, done, timeout=10.0):
    """Poll ``link`` until ``done(batches)``; return all batches."""
    batches = []
    end = time.monotonic() + timeout
    while not done(batches):
        assert time.monotonic() < end, f'link did not deliver: {link.values()}'
        batches += link.poll()
    return batches


# ---------------------------------------------------------------------------------------
# CardLink on loop://


def test_link_loop_parses_tracks_and_batches():
    log = Log()
    seen = []
    link = CardLink('loop://', read_timeout=0.02, batch_size=7, sample_period=0.01,
                    log=log, on_sample=lambda s: seen.append(s.seq) or s)
    assert link.poll() == [] and link.is_open and link.state == 'connected'
    rng = np.random.default_rng(0)
    samples = [f32_sample(k, rng) for k in range(40)]
    order = list(range(40))
    order.remove(12)                 # lost
    order.insert(20, 20)             # duplicated
    order[30], order[31] = order[31], order[30]   # 31 overtakes 30: 30 is late
    link.port.write(b''.join(pr.encode_sample(samples[k]) for k in order))
    batches = poll_until(link, lambda b: sum(map(len, b)) >= 37)
    got = [s for b in batches for s in b]
    want = [samples[k] for k in range(40) if k not in (12, 30)]
    assert got == want
    assert seen == [s.seq for s in want]
    assert max(map(len, batches)) <= 7
    tr = link.tracker
    assert (tr.lost, tr.duplicates, tr.late) == (1, 1, 1)   # 12 lost; 30 late, not lost
    assert link.counts['frames_ok'] == 40
    values = link.values()
    assert values['frames_ok'] == 40 and values['link'] == 'connected'
    assert 'line_overload' not in values and link.capacity_warning == 'ok'
    # one log line per kind of fault
    assert log.count('lost before') == 1 and log.count('duplicate frame') == 1
    assert log.count('late frame') == 1
    link.close()
    assert not link.is_open


def test_link_sends_commands_and_routes_replies():
    replies = []
    log = Log()
    link = CardLink('loop://', read_timeout=0.02, log=log, on_reply=replies.append)
    with pytest.raises(TransportError, match='not open'):
        link.send(pr.Stop())
    link.poll()
    link.send(pr.Ping(5))   # loop:// reads it back: a host frame is garbage to the card side
    link.port.write(pr.encode_reply(pr.Reply('start_profile', 'unsupported', 3)) +
                    pr.encode_reply(pr.Reply('start_profile', 'unsupported', 4)))
    poll_until(link, lambda b: len(replies) == 2)
    assert replies[0] == pr.Reply('start_profile', 'unsupported', 3)
    assert link.counts['reply_unsupported'] == 2 and link.counts['commands_sent'] == 1
    assert log.count('answered unsupported to start_profile') == 1
    link.close()


def test_a_write_to_a_pty_whose_card_end_closed_is_a_lost_device():
    """tcdrain on a pty whose other end closed raises termios.error, no OSError."""
    import termios

    from motor_id.card.transport import write_all

    class Port:
        name = 'fake'

        def write(self, data):
            return len(data)

        def flush(self):
            raise termios.error(5, 'Input/output error')
    with pytest.raises(TransportError, match='Input/output error'):
        write_all(Port(), b'x')


def test_link_notes_when_the_last_command_went_out():
    link = CardLink('loop://', read_timeout=0.02)
    assert link.last_sent == -np.inf
    link.poll()
    before = time.monotonic()
    link.send(pr.Stop())
    assert before <= link.last_sent <= time.monotonic()
    link.close()


def test_link_reports_a_garbled_line_once():
    log = Log()
    link = CardLink('loop://', read_timeout=0.02, baudrate=57600, log=log)
    link.poll()
    rng = np.random.default_rng(1)
    junk = rng.integers(0, 255, 3 * GARBLED_BYTES)
    junk[junk >= 0xA5] += 1
    link.port.write(junk.astype(np.uint8).tobytes())
    poll_until(link, lambda b: link.state == 'garbled')
    link.port.write(pr.encode_sample(f32_sample(0, rng)))
    poll_until(link, lambda b: b)
    assert link.state == 'connected'
    assert log.count('check the baud rate (the driver uses 57600 bit/s)') == 1
    assert link.parser.garbage_bytes == junk.size
    link.close()


def test_line_capacity_warns_once_when_the_rate_exceeds_the_baud_rate():
    assert max_frame_rate(115200, 34) == pytest.approx(338.82, abs=0.01)
    log = Log()
    link = CardLink('loop://', read_timeout=0.02, baudrate=115200, sample_period=0.001,
                    log=log)
    link.poll()
    rng = np.random.default_rng(2)
    link.port.write(b''.join(pr.encode_sample(f32_sample(k, rng, 0.001)) for k in range(5)))
    poll_until(link, lambda b: sum(map(len, b)) == 5)
    assert '1000 samples/s of 34-byte frames need 340000 bit/s' in link.capacity_warning
    assert 'at most 339 frames/s' in link.capacity_warning
    assert link.values()['line_overload'] == link.capacity_warning
    assert log.count('frames will be lost') == 1
    # without current the frames are 30 bytes: 3000 frames/s fit 921600 bit/s, not 3900
    for period, baud, ok in ((1 / 3000, 921600, True), (1 / 3900, 921600, False)):
        quiet = CardLink('loop://', read_timeout=0.02, baudrate=baud, sample_period=period)
        quiet.poll()
        quiet.port.write(pr.encode_sample(f32_sample(0, rng, current=False)))
        poll_until(quiet, lambda b: b)
        assert (quiet.capacity_warning == 'ok') == ok, quiet.capacity_warning
        quiet.close()
    link.close()


def test_link_backs_off_while_the_device_is_missing(tmp_path):
    log = Log()
    link = CardLink(str(tmp_path / 'nothing'), backoff_max=0.2, log=log)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 1.0:
        assert link.poll() == []
    # 0.05 + 0.1 + 0.2 + 0.2 ... : about 6 attempts in a second, not hundreds
    assert 4 <= link.counts['open_failed'] <= 9, link.counts
    assert link.state == 'disconnected'
    assert log.count('cannot open') == 1


# ---------------------------------------------------------------------------------------
# CardLink on a real pty with a simulated card


def test_link_survives_disconnects_of_a_pty_card(tmp_path):
    path = str(tmp_path / 'card')
    log = Log()
    opened = []
    faults = FaultConfig(disconnect_every=0.6, disconnect_for=0.3)
    with CardSimulator(speedup=5.0, faults=faults, link=path, random_state=0):
        link = CardLink(path, read_timeout=0.02, backoff_max=0.1, log=log,
                        on_open=lambda: opened.append(time.monotonic()) or
                        link.send(pr.SetPeriod(0.01)))
        batches = poll_until(link, lambda b: link.counts['opened'] >= 3 and
                             sum(map(len, b)) > 200, 15.0)
        link.close()
    rows = np.array([(s.seq, s.t_card) for b in batches for s in b])
    assert np.all(np.diff(rows[:, 0]) >= 1) and np.all(np.diff(rows[:, 1]) > 0)
    assert np.any(np.diff(rows[:, 0]) > 1)     # samples sent while away are missing
    assert link.counts['lost_device'] >= 2 and len(opened) == link.counts['opened']
    assert link.tracker.lost > 0
    # a line per outage: lost, reopened (and perhaps one failed open)
    assert log.count('device lost') == link.counts['lost_device']
    assert log.count('reopened') == link.counts['opened'] - 1


# ---------------------------------------------------------------------------------------
# limits, watchdog, host profiles (no I/O)


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_supervisor_trips_latches_and_flags():
    sent = []
    sup = Supervisor(Limits(max_voltage=10.0, max_speed=5.0, max_current=2.0), sent.append)
    ok = pr.Sample(0, 0.0, 4.0, 4.9, 1.9)
    assert sup.on_sample(ok) == (ok, None) and not sent
    s, trip = sup.on_sample(pr.Sample(1, 0.01, 4.0, -5.5, 1.0))
    assert trip.limit == 'speed' and trip.value == -5.5 and trip.threshold == 5.0
    assert trip.seq == 1 and s.flags & FLAG_LIMIT and sent == [pr.Stop()]
    assert 'speed limit: |-5.5| rad/s > 5 rad/s at seq 1' in trip.describe()
    s, again = sup.on_sample(pr.Sample(2, 0.02, 0.0, 9.0, 9.0))
    assert again is None and s.flags & FLAG_LIMIT and len(sent) == 1   # latched, once
    assert sup.command(3.0) is None and sup.refused == 1
    assert sup.values()['limit_tripped'] == 'speed'
    sup.reset()
    assert not sup.on_sample(ok)[0].flags & FLAG_LIMIT
    assert sup.on_sample(pr.Sample(3, 0.03, 1.0, 0.0, 2.5))[1].limit == 'current'
    sup.reset()
    assert sup.on_sample(pr.Sample(4, 0.04, 10.5, 0.0, 0.0))[1].limit == 'voltage'
    sup.reset()
    no_current = pr.Sample(5, 0.05, 1.0, 0.0)
    assert sup.on_sample(no_current)[1] is None
    off = Supervisor(Limits(max_voltage=10.0), sent.append)   # 0 switches speed/current off
    assert off.on_sample(pr.Sample(0, 0.0, 1.0, 1e6, 1e6))[1] is None


def test_limits_clamp_and_refuse_profiles():
    lim = Limits(max_voltage=6.0)
    assert (lim.clamp(50.0), lim.clamp(-7.0), lim.clamp(2.5)) == (6.0, -6.0, 2.5)
    with pytest.raises(ConfigError, match='amplitude 9 V exceeds max_voltage 6 V'):
        lim.check_profile('prbs', 9.0)
    lim.check_profile('prbs', 6.0)
    sup = Supervisor(lim, lambda c: None)
    assert sup.command(50.0) == 6.0 and sup.clamped == 1
    for bad in ({'max_voltage': 0.0}, {'max_speed': -1.0}, {'command_timeout': float('nan')}):
        with pytest.raises(ConfigError):
            Limits(**bad)


def test_watchdog_holds_zero_volts_until_the_next_command():
    sent, clock = [], FakeClock()
    sup = Supervisor(Limits(command_timeout=0.5), sent.append, clock=clock)
    clock.t = 10.0
    assert not sup.check_watchdog()        # not armed before the first command
    assert sup.command(3.0) == 3.0
    clock.t = 10.4
    assert not sup.check_watchdog()
    clock.t = 10.6
    assert sup.check_watchdog() and sent == [pr.SetVoltage(0.0)]
    assert not sup.check_watchdog() and len(sent) == 1      # once per silence
    s, trip = sup.on_sample(pr.Sample(0, 0.0, 0.0, 0.0))
    assert trip is None and s.flags & FLAG_LIMIT and sup.values()['limit_state'] == 'watchdog'
    assert sup.command(2.0) == 2.0 and not sup.holding_zero
    assert sup.watchdog_trips == 1


def test_host_profile_reproduces_the_cards_own_profile():
    """A card without profiles, driven by HostProfile without latency, plays exactly the
    voltages the card's built-in profile plays (one profile definition)."""
    card = VirtualCard(period=0.01, profiles=False)
    assert card.handle(pr.StartProfile('multisine', 5.0, 3, 2.0)).status == 'unsupported'
    host = HostProfile('multisine', 5.0, 3, 2.0, 0.01)
    out = []
    for _ in range(260):
        sample, value = host.on_sample(card.step())
        out.append(sample)
        if value is not None:
            card.handle(pr.SetVoltage(value))
    flags = np.array([s.flags for s in out])
    volts = np.array([s.voltage for s in out])
    on = np.flatnonzero(flags & FLAG_PROFILE)
    assert on.size == 200 and on[0] == 1 and np.all(np.diff(on) == 1)
    assert np.flatnonzero(flags & FLAG_PROFILE_END).tolist() == [200]
    np.testing.assert_array_equal(volts[on], profile_samples('multisine', 5.0, 3, 2.0, 0.01))
    assert np.all(volts[201:] == 0.0) and host.done
    ref = VirtualCard(period=0.01)
    ref.handle(pr.StartProfile('multisine', 5.0, 3, 2.0))
    np.testing.assert_array_equal(volts[on], [s.voltage for s in ref.samples(200)])


def test_current_spike_fault_hits_one_sample_per_period():
    inj = FaultInjector(FaultConfig(spike_every=0.5, spike_current=40.0))
    card = VirtualCard(period=0.01)
    out = [inj.sample(s) for s in card.samples(200)]
    spikes = [s.seq for s in out if s.current == 40.0]
    assert spikes == [50, 100, 150] and inj.stats['spikes'] == 3
    assert FaultConfig.parse(['current_spike=2:30']) == FaultConfig(spike_every=2.0,
                                                                     spike_current=30.0)
    with pytest.raises(ConfigError, match='unknown fault'):
        FaultConfig.parse(['drop=0.1:3'])


def test_sample_clock_keeps_card_spacing_and_integrates_speed():
    clock = SampleClock()
    stamps = [clock.update(pr.Sample(k, 5.0 + 0.01 * k, 0.0, 2.0), 1_000_000_000_000 + k * 37)
              for k in range(101)]
    assert stamps[0] == 1_000_000_000_000
    assert np.all(np.diff(stamps) == 10_000_000)     # card spacing, not arrival jitter
    assert clock.position == pytest.approx(2.0, abs=1e-12)   # 2 rad/s for 1 s
    again = clock.update(pr.Sample(0, 0.0, 0.0, 1.0), 2_000_000_000_000)   # card restarted
    assert again == 2_000_000_000_000 and clock.position == 0.0


def test_card_sim_no_profiles_option():
    parser = argparse.ArgumentParser()
    card_sim.add_arguments(parser)
    sim = card_sim.simulator_from_args(parser.parse_args(['--no-profiles']))
    assert sim.truth().profiles is False
    assert sim.card.handle(pr.StartProfile('prbs')).status == 'unsupported'
    sim = card_sim.simulator_from_args(parser.parse_args(['--fault', 'current_spike=1']))
    assert sim.faults.spike_every == 1.0 and sim.faults.spike_current == 50.0
    assert sim.card.handle(pr.StartProfile('prbs')).status == 'ok'


class FakeLink:
    """What a Session needs of a CardLink: send, last_sent and fault (here no command
    ever counts as recent, so every keep_alive pings while the card drives)."""

    def __init__(self):
        self.sent, self.faults = [], []
        self.last_sent = -np.inf

    def send(self, command):
        self.sent.append(command)

    def fault(self, kind, text, level='warning'):
        self.faults.append(kind)


def test_session_plays_the_profile_itself_when_the_card_cannot():
    link, log = FakeLink(), Log()
    session = Session(link, Limits(max_voltage=10.0, max_speed=50.0), 'prbs', 5.0, 1, 0.5,
                      period=0.01, autostart=True, log=log)
    session.on_open()
    assert link.sent == [pr.SetPeriod(0.01), pr.StartProfile('prbs', 5.0, 1, 0.5)]
    session.on_reply(pr.Reply('start_profile', 'unsupported', 0))
    assert session.host_profile is not None and not session.card_profiles
    assert log.count('the card has no built-in profiles: the driver plays prbs') == 1
    card = VirtualCard(period=0.01, profiles=False)
    out = []
    for _ in range(80):
        n = len(link.sent)
        out.append(session.on_sample(card.step()))
        for cmd in link.sent[n:]:
            card.handle(cmd)
    assert sum(bool(s.flags & FLAG_PROFILE) for s in out) == 50
    assert session.host_profile is None and log.count('profile done') == 1
    assert session.values()['profile_source'] == 'driver'
    # a second start goes straight to the host profile
    assert session.start() == 'started prbs (played by the driver)'
    assert link.sent[-1] == pr.Stop()


def test_session_refuses_and_clamps():
    link = FakeLink()
    with pytest.raises(ConfigError, match='exceeds max_voltage'):
        Session(link, Limits(max_voltage=5.0), 'paper_steps', 9.0)
    session = Session(link, Limits(max_voltage=5.0, max_current=1.0), 'external')
    session.command(7.0)
    assert link.sent == [pr.SetVoltage(5.0)] and link.faults == ['command_clamped']
    session.on_sample(pr.Sample(0, 0.0, 5.0, 1.0, 3.0))
    assert link.sent[-1] == pr.Stop()
    session.command(1.0)
    assert link.sent[-1] == pr.Stop() and link.faults[-1] == 'command_refused'
    assert 'was: current limit' in session.reset()
    session.command(1.0)
    assert link.sent[-1] == pr.SetVoltage(1.0)


def test_host_profile_ends_even_when_its_last_frames_are_lost():
    host = HostProfile('paper_steps', 9.0, 0, 0.5, 0.01)      # 50 samples
    card = VirtualCard(period=0.01, profiles=False)
    out = []
    for s in card.samples(70):
        if 45 <= s.seq <= 53:      # the frames around the profile's end never arrive
            continue
        out.append(host.on_sample(s)[0])
    ends = [s.seq for s in out if s.flags & FLAG_PROFILE_END]
    assert ends == [54] and host.done
    assert [s.seq for s in out if s.flags & FLAG_PROFILE] == list(range(1, 45)) + [54]


def _pings(link, session):
    n = len(link.sent)
    session.keep_alive()
    return [c for c in link.sent[n:] if isinstance(c, pr.Ping)]


def test_session_pings_while_the_card_drives_the_motor():
    link = FakeLink()
    session = Session(link, Limits(max_voltage=10.0, max_speed=5.0), 'paper_steps', 9.0,
                      duration=0.05, keepalive=0.1)
    assert not session.driving and not _pings(link, session)      # idle: no pings
    session.start()
    assert session.driving and len(_pings(link, session)) == 1
    session.on_sample(pr.Sample(1, 0.01, 0.0, 0.0, flags=pr.FLAG_PROFILE | pr.FLAG_PROFILE_END))
    assert not session.driving and not _pings(link, session)      # the profile ended
    session.start()
    session.on_reply(pr.Reply('start_profile', 'busy', 2))
    assert not session.driving                                     # refused: not running
    session.start()
    session.on_sample(pr.Sample(3, 0.03, 3.8, 6.0, flags=pr.FLAG_PROFILE))   # over speed
    assert not session.driving and link.sent[-1] == pr.Stop()
    assert session.values()['keepalive_pings'] == 1
    off = Session(FakeLink(), Limits(), 'paper_steps', 9.0, keepalive=0.0)
    off.start()
    assert off.driving and not _pings(off.link, off)               # pings switched off


def test_session_pings_under_a_non_zero_external_command_and_closes_at_zero_volts():
    link = FakeLink()
    session = Session(link, Limits(max_voltage=10.0, command_timeout=0.5), 'external')
    session.command(2.0)
    assert session.driving and len(_pings(link, session)) == 1
    session.command(0.0)
    assert not session.driving
    session.command(3.0)
    session.close()
    assert link.sent[-1] == pr.Stop() and not session.driving
    session.command(4.0)                                           # dropped: closed
    assert link.sent[-1] == pr.Stop()
    with pytest.raises(MotorIdError, match='shutting down'):
        session.start()


def test_session_notices_a_card_that_abandoned_its_profile():
    """A flagged profile sample, then one without the flag and no end flag: the card's
    watchdog stopped it; said once, as an error; no more pings."""
    link = FakeLink()
    session = Session(link, Limits(), 'paper_steps', 9.0, duration=40.0)
    session.start()
    session.on_sample(pr.Sample(0, 0.00, 0.0, 0.0))                       # not yet flagged
    assert session.driving and not link.faults
    session.on_sample(pr.Sample(1, 0.01, 3.8, 1.0, flags=pr.FLAG_PROFILE))
    session.on_sample(pr.Sample(2, 0.02, 0.0, 1.0))
    assert not session.driving and link.faults == ['card_abandoned_profile']
