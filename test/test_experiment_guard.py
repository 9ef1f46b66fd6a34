"""The experiment's pure core: the plan, the guard's rules and the record, in closed loop
with a small joint written here from its equations (no ROS, no motor_id model code)."""

from dataclasses import dataclass
import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from motor_id.data.load import load_recording
from motor_id.errors import ConfigError
from motor_id.experiment.coast import CoastModel, OnlineModel, predict_coast
from motor_id.experiment.guard import Guard, limit_command, StateSample, StreamStats
from motor_id.experiment.plan import arrange, build_plan, LOW_STEP_FRACTION, STEP_FRACTION
from motor_id.experiment.session import EXPERIMENT, ExperimentSession, RECORDING
from motor_id.experiment.settings import ExperimentSettings, Travel


@dataclass
class Joint:
    """J dw/dt = K (V - K w) / R - B w - T_c sgn(w) - gravity, stick-slip at w = 0, hard
    stops; gravity T_g cos(x + offset) (arm) or T_g (elevator)."""

    J: float = 4e-5
    K: float = 0.02
    R: float = 0.5
    B: float = 1e-5
    Tc: float = 0.008
    Tg: float = 0.0
    offset: float = 0.0
    mechanism: str = 'simple'
    x: float = 0.0
    w: float = 0.0
    stop_low: float = -math.inf
    stop_high: float = math.inf

    def gravity(self):
        if self.mechanism == 'arm':
            return self.Tg * math.cos(self.x + self.offset)
        return self.Tg if self.mechanism == 'elevator' else 0.0

    def step(self, V, dt, n=20):
        h = dt / n
        for _ in range(n):
            drive = self.K * (V - self.K * self.w) / self.R - self.B * self.w - self.gravity()
            if self.w == 0.0 and abs(drive) <= self.Tc:
                continue
            sign = math.copysign(1.0, self.w if self.w != 0 else drive)
            w_new = self.w + h * (drive - self.Tc * sign) / self.J
            self.w = 0.0 if self.w != 0 and w_new * self.w < 0 else w_new
            self.x += h * self.w
            if not self.stop_low <= self.x <= self.stop_high:
                self.x = min(max(self.x, self.stop_low), self.stop_high)
                self.w = 0.0


def wheel():
    return Joint()


def arm(offset=0.4, **kw):
    j = Joint(J=0.1, K=1.0, R=1.0, B=0.05, Tc=0.3, Tg=3.0, offset=offset, mechanism='arm',
              **kw)
    j.x = -math.pi / 2 - offset
    return j


def elevator():
    # kV 10 V s/m, kA 0.5 V s^2/m, kG 1 V, kS 0.3 V: 0.6 m/s at 7 V, 1.2 m of travel
    return Joint(J=0.5, K=1.0, R=1.0, B=9.0, Tc=0.3, Tg=1.0, mechanism='elevator',
                 stop_low=0.0, stop_high=1.3)


def settings(tmp_path, mechanism='simple', **kw):
    kw.setdefault('controller_joints', ('j',))
    return ExperimentSettings('j', '/ctrl/commands', kw.pop('max_command', 12.0),
                              str(tmp_path / 'out'), mechanism=mechanism, **kw)


def run_loop(joint, st, period=0.01, delay=2, noise=(1e-4, 0.01), seed=0, t_max=120.0,
             silence_at=None):
    """Closed loop: each sample's command acts ``delay`` samples later. Returns the
    session and the positions the joint went through."""
    rng = np.random.default_rng(seed)
    sess = ExperimentSession(st)
    sess.open()
    sess.start(0.0)
    queue = [0.0] * delay
    t, u = 1000.0, 0.0
    xs, sent = [], []
    while not sess.guard.finished and t < 1000.0 + t_max:
        now = t - 1000.0
        if silence_at is not None and now >= silence_at:
            cmd = sess.guard.tick(now)
        else:
            s = StateSample(t, now, joint.x + noise[0] * rng.standard_normal(),
                            joint.w + noise[1] * rng.standard_normal(), lag=0.003)
            cmd = sess.on_state(s)
        if cmd is not None:
            u = cmd
            sent.append(cmd)
        queue.append(u)
        joint.step(queue.pop(0), period)
        xs.append(joint.x)
        t += period
    return sess, np.array(xs), np.array(sent)


# ---------------------------------------------------------------------------- the plan

def test_sysid_plan_ramps_and_steps_each_way_within_the_limit():
    plan = build_plan('sysid', 6.0)
    assert [t.name for t in plan.tests] == ['quasistatic-forward', 'quasistatic-reverse',
                                            'dynamic-forward', 'dynamic-reverse',
                                            'dynamic-forward-low', 'dynamic-reverse-low']
    assert [t.direction for t in plan.tests] == [1, -1] * 3
    ramp, step = plan.tests[0], plan.tests[2]
    assert ramp.command(0.0) == 0.0
    assert ramp.command(ramp.duration * 0.5) == pytest.approx(3.0, rel=1e-12)
    assert ramp.command(ramp.duration) == 0.0   # over: 0
    assert step.command(0.1) == pytest.approx(STEP_FRACTION * 6.0, rel=1e-12)
    assert plan.tests[4].command(0.1) == pytest.approx(LOW_STEP_FRACTION * 6.0, rel=1e-12)
    assert plan.tests[1].command(1.0) < 0 and plan.tests[3].command(1.0) < 0
    assert plan.peak() <= 6.0
    assert all(t.rest_before for t in plan.tests)


def test_a_test_toward_the_edge_the_joint_rests_at_follows_the_one_away_from_it():
    plan = build_plan('sysid', 12.0)
    assert arrange(plan, True, True) == plan == arrange(plan, False, False)
    up = arrange(plan, room_low=False, room_high=True)   # an elevator on its bottom
    assert [(t.name, t.rest_before) for t in up.tests] == [
        ('quasistatic-forward', True), ('quasistatic-reverse', False),
        ('dynamic-forward', True), ('dynamic-reverse', False),
        ('dynamic-forward-low', True), ('dynamic-reverse-low', False)]
    down = arrange(plan, room_low=True, room_high=False)
    assert [(t.name, t.rest_before) for t in down.tests] == [
        ('quasistatic-reverse', True), ('quasistatic-forward', False),
        ('dynamic-reverse', True), ('dynamic-forward', False),
        ('dynamic-reverse-low', True), ('dynamic-forward-low', False)]
    prbs = build_plan('prbs', 12.0)
    assert arrange(prbs, False, True) == prbs


@pytest.mark.parametrize('kind', ['prbs', 'multisine'])
def test_prbs_and_multisine_segments_repeat_with_the_seed(kind):
    a = build_plan(kind, 5.0, seed=3)
    b = build_plan(kind, 5.0, seed=3)
    c = build_plan(kind, 5.0, seed=4)
    t = np.linspace(0, a.tests[0].duration - 1e-6, 500)
    ua = [a.tests[0].command(x) for x in t]
    assert ua == [b.tests[0].command(x) for x in t]
    assert ua != [c.tests[0].command(x) for x in t]
    assert max(abs(v) for v in ua) <= STEP_FRACTION * 5.0 + 1e-12
    assert min(ua) < 0 < max(ua)


def test_settings_errors_say_what_to_give():
    with pytest.raises(ConfigError, match='travel LO:HI') as exc:
        ExperimentSettings('j', '/c/commands', 1.0, 'out', mechanism='arm')
    assert exc.value.params == ('travel',)   # the command line adds its flag, --travel
    with pytest.raises(ConfigError, match='max command'):
        ExperimentSettings('j', '/c/commands', 0.0, 'out')
    with pytest.raises(ConfigError, match='not among the controller joints'):
        ExperimentSettings('j', '/c/commands', 1.0, 'out', controller_joints=('a', 'b'))
    with pytest.raises(ConfigError, match='LO:HI'):
        Travel.parse('1.5')
    with pytest.raises(ConfigError, match='LO < HI'):
        Travel.parse('2:1')
    assert ExperimentSettings('j', '/arm_controller/commands', 1.0, 'o').controller_node \
        == '/arm_controller'


def test_limit_command_clamps_and_zeroes_what_is_not_a_number():
    assert limit_command(13.0, 12.0) == 12.0
    assert limit_command(-13.0, 12.0) == -12.0
    assert limit_command(3.5, 12.0) == 3.5
    assert limit_command(math.nan, 12.0) == 0.0
    assert limit_command(math.inf, 12.0) == 0.0


# ---------------------------------------------------------------------------- the guard

def sample(t, x=0.0, w=0.0, lag=0.0):
    return StateSample(t, t, x, w, lag=lag)


def test_nothing_is_commanded_before_start(tmp_path):
    g = Guard(settings(tmp_path), build_plan('sysid', 12.0))
    assert g.on_state(sample(1.0)) is None
    assert g.tick(100.0) is None
    assert g.phase == 'idle'
    assert g.start(1.0) == 0.0
    assert g.on_state(sample(1.01)) == 0.0


def test_watchdog_stops_with_zero_when_states_stop(tmp_path):
    g = Guard(settings(tmp_path), build_plan('sysid', 12.0))
    g.start(0.0)
    for k in range(10):
        g.on_state(sample(0.01 * k))
    assert g.tick(0.09 + 0.2) is None
    assert g.tick(0.09 + 0.26) == 0.0
    assert g.phase == 'stopped' and g.log.safety_stop
    assert g.log.stop_reason.startswith('watchdog: no state of joint j for 0.26')
    assert g.on_state(sample(0.5)) is None   # nothing after the stop


def test_states_stamped_late_stop_it(tmp_path):
    g = Guard(settings(tmp_path), build_plan('sysid', 12.0))
    g.start(0.0)
    for k in range(10):
        assert g.on_state(sample(0.01 * k, lag=0.02)) == 0.0
    assert g.on_state(sample(0.2, lag=0.02 + 0.3)) == 0.0
    assert g.phase == 'stopped' and 'stale state' in g.log.stop_reason


def test_a_sample_not_newer_than_the_last_is_ignored(tmp_path):
    g = Guard(settings(tmp_path), build_plan('sysid', 12.0))
    g.start(0.0)
    assert g.on_state(sample(1.0)) == 0.0
    assert g.on_state(sample(1.0)) is None
    assert g.on_state(sample(0.5)) is None
    assert g.log.ignored_samples == 2


def test_a_joint_resting_outside_its_travel_never_moves(tmp_path):
    st = settings(tmp_path, 'arm', travel=Travel(0.0, 1.0))
    j = arm()   # hangs at -1.97
    sess, _, sent = run_loop(j, st)
    assert sess.guard.log.safety_stop
    assert 'outside the travel' in sess.guard.log.stop_reason
    assert np.all(sent == 0.0)


# ---------------------------------------------------------------------------- closed loop

def test_wheel_runs_the_plan_within_the_command_limit(tmp_path):
    st = settings(tmp_path, max_command=6.0, time_scale=0.3)
    sess, _, sent = run_loop(wheel(), st)
    log = sess.guard.log
    assert log.stop_reason == 'complete' and not log.safety_stop
    assert [t.end_reason for t in log.tests] == ['complete'] * 6
    assert np.max(np.abs(sent)) <= 6.0
    assert np.max(np.abs(sent)) == pytest.approx(6.0, rel=0.02)
    assert log.clamped == 0
    assert sent[0] == 0.0 and sent[-1] == 0.0
    assert [t.direction * t.peak_command for t in log.tests] == pytest.approx(
        [6.0, -6.0, 3.6, -3.6, 1.8, -1.8], rel=0.02)


def test_max_speed_ends_the_test(tmp_path):
    st = settings(tmp_path, max_command=6.0, time_scale=0.3, max_speed=100.0)
    sess, _, _ = run_loop(wheel(), st)
    tests = sess.guard.log.tests
    # the low steps (1.8 V, 89 rad/s) stay below the limit
    assert [t.end_reason for t in tests] == ['max_speed'] * 4 + ['complete'] * 2
    assert all(100.0 < t.peak_speed < 120.0 for t in tests[:4])
    assert sess.guard.log.limits_reached()[0] == 'quasistatic-forward: max_speed'


@pytest.mark.parametrize('offset,lo,hi', [(0.4, -1.5, 1.5), (-0.3, -1.0, 1.8),
                                          (1.0, -1.8, 0.9), (0.0, -0.6, 0.6)])
def test_an_arm_never_passes_its_travel(tmp_path, offset, lo, hi):
    j = arm(offset)
    rest = j.x
    st = settings(tmp_path, 'arm', travel=Travel(rest + lo, rest + hi), time_scale=0.5)
    sess, xs, sent = run_loop(j, st)
    log = sess.guard.log
    assert log.stop_reason == 'complete', log.to_dict()
    assert rest + lo <= xs.min() and xs.max() <= rest + hi
    assert np.max(np.abs(sent)) <= 12.0
    # each test moved the arm toward its own edge
    moved = [t for t in log.tests if t.end_reason != 'no_room']
    assert moved and all(t.end_reason in ('travel_high', 'travel_low', 'complete')
                         for t in moved)


def test_an_arm_hanging_near_its_low_stop_goes_down_from_up_there(tmp_path):
    # room toward LO from the rest: none; each test toward LO follows one toward HI
    j = arm(0.35)
    rest = j.x
    j.stop_low = rest - 0.45
    st = settings(tmp_path, 'arm', travel=Travel(rest - 0.4, rest + 3.3), time_scale=0.5)
    sess, xs, _ = run_loop(j, st)
    log = sess.guard.log
    assert log.stop_reason == 'complete', log.to_dict()
    assert rest - 0.4 <= xs.min() and xs.max() <= rest + 3.3
    assert [(t.direction, t.samples > 0) for t in log.tests] == [(1, True), (-1, True)] * 3
    down = [t for t in log.tests if t.direction < 0]
    assert all(t.position_high - t.position_low > 1.0 for t in down)


def test_an_arm_with_little_damping_still_stays_inside(tmp_path):
    # a torque-like drive: the back-EMF brakes little, the arm swings far when released
    j = arm(0.2)
    j.K, j.R, j.B = 0.3, 1.0, 0.02
    rest = j.x
    st = settings(tmp_path, 'arm', travel=Travel(rest - 1.4, rest + 1.4), max_command=20.0,
                  time_scale=0.5)
    sess, xs, _ = run_loop(j, st)
    assert rest - 1.4 <= xs.min() and xs.max() <= rest + 1.4, sess.guard.log.to_dict()


def test_an_elevator_goes_up_and_down_inside_its_travel(tmp_path):
    j = elevator()
    st = settings(tmp_path, 'elevator', travel=Travel(0.0, 1.2))
    sess, xs, _ = run_loop(j, st)
    log = sess.guard.log
    assert log.stop_reason == 'complete', log.to_dict()
    assert xs.max() <= 1.2 and xs.min() >= 0.0
    ups = [t for t in log.tests if t.direction > 0]
    downs = [t for t in log.tests if t.direction < 0]
    assert all(t.position_high > 0.5 for t in ups)
    assert all(t.position_high - t.position_low > 0.3 for t in downs)


def test_the_coast_of_a_known_model_ends_where_the_joint_stops():
    # dw/dt = 20 u - w / tau: from w0 the joint coasts w0 tau; the command u acts for
    # the latency L first: + 20 u L tau
    tau, L = 0.05, 0.02
    m = CoastModel('simple', (20.0, -1 / tau, 0.0), 1e-3)
    c = predict_coast(m, 0.0, 10.0, 0.0, L)
    assert c.high == pytest.approx(10.0 * tau, rel=0.01)
    c = predict_coast(m, 0.0, 10.0, 5.0, L)
    assert c.high == pytest.approx(10.0 * tau + 100.0 * L * tau, rel=0.01)
    assert c.low == 0.0 and c.modelled
    # no model: the speed held for the latency and a second
    c = predict_coast(None, 1.0, -2.0, 0.0, 0.1)
    assert (c.low, c.high) == pytest.approx((1.0 - 2.2, 1.0))


def test_the_online_model_learns_a_decay():
    rng = np.random.default_rng(1)
    m = OnlineModel('simple', 0.03)
    w, t = 0.0, 0.0
    for k in range(600):
        u = 5.0 if (k // 100) % 2 == 0 else 0.0
        m.add(t, 0.0, w + 0.01 * rng.standard_normal(), u)
        w += 0.01 * (20.0 * u - w / 0.05)
        t += 0.01
    fit = m.fitted()
    assert fit is not None
    assert fit.time_constant() == pytest.approx(0.05, rel=0.25)


def test_states_that_arrive_late_teach_the_online_model_what_drove_the_joint(tmp_path):
    # a busy machine: every 0.4 s the states stall for 0.24 s and then arrive at once,
    # each decided on when it arrives; the joint ran on the command sent before it was
    # measured (J 4e-5, K 0.02, R 0.5, B 1e-5: tau 0.049 s, 1000 rad/s^2 per volt).
    # Paired with the command decided on the state before (what was never applied), the
    # model took tau for 0.196 s and the gain for 263 (measured)
    rng = np.random.default_rng(0)
    joint = wheel()
    sess = ExperimentSession(settings(tmp_path, watchdog=1.0))
    sess.open()
    sess.start(0.0)
    u, t, k, held = 0.0, 0.0, 0, []
    while not sess.guard.finished and t < 60.0:
        held.append(StateSample(t, 0.0, joint.x + 1e-4 * rng.standard_normal(),
                                joint.w + 0.01 * rng.standard_normal()))
        if k % 40 < 15 or k % 40 == 39:   # delivered now
            for s in held:
                late = t + 0.003 - s.t
                cmd = sess.on_state(StateSample(s.t, t + 0.003, s.position, s.velocity,
                                                lag=late))
                if cmd is not None:
                    sess.note_sent(t + 0.004, cmd)
                    u = cmd
            held = []
        joint.step(u, 0.01)
        t, k = t + 0.01, k + 1
    assert [x.end_reason for x in sess.guard.log.tests] == ['complete'] * 6
    fit = sess.guard.model.fitted()
    assert fit is not None
    assert fit.time_constant() == pytest.approx(0.049, rel=0.15)
    assert fit.theta[0] == pytest.approx(1000.0, rel=0.15)
    assert sess.guard.sent.at(-1.0, 9.0) == 0.0   # before anything was sent
    # experiment.json says so: 20 states of each stall over 0.05 s late, up to 0.24 s
    timing = sess.guard.stats.timing()
    assert timing['late_states'] >= 0.45 * k   # 20 of every 40 samples (less the end)
    assert timing['latest_state'] == pytest.approx(0.24, abs=0.011)


def test_a_state_that_arrives_late_lengthens_the_coast_by_its_lag():
    # the arm demo on a busy machine: states 0.28 s late while the median lag was 5 ms;
    # the coast from such a state starts where the arm was 0.28 s ago (it went 0.014 rad
    # past its travel once, on the median lag)
    stats = StreamStats()
    last = None
    for k in range(50):
        s = StateSample(0.01 * k, 0.01 * k + 0.005, 0.0, 0.0, lag=0.005)
        stats.lateness(s)
        stats.add(s, last)
        last = s
    assert stats.latency(0.285) - stats.latency() == pytest.approx(0.28, abs=1e-12)
    assert stats.latency(0.001) == stats.latency()


# ---------------------------------------------------------------------------- the record

def test_the_recording_reads_as_runs_with_position_and_the_log_is_written(tmp_path):
    st = settings(tmp_path, max_command=6.0, time_scale=0.3)
    sess, _, _ = run_loop(wheel(), st)
    rec = sess.close()
    out = Path(st.out)
    back = load_recording(out / RECORDING)
    assert len(back) == len(rec) == len(sess.rows)
    assert back.segments == rec.segments and len(back.segments) == 6
    np.testing.assert_allclose(back.position, rec.position, rtol=0, atol=0)
    np.testing.assert_allclose(back.input, [r.command for r in sess.rows], rtol=0, atol=0)
    assert back.current is None   # no -R: speed only
    assert back.meta['segment_names'] == [t.name for t in sess.guard.plan.tests]
    log = json.loads((out / EXPERIMENT).read_text())
    assert log['stop_reason'] == 'complete' and log['complete']
    assert [t['end_reason'] for t in log['tests']] == ['complete'] * 6
    assert log['tests'][0]['start'] < log['tests'][0]['end'] < log['tests'][1]['start']
    assert log['max_command'] == 6.0 and log['limits_reached'] == []
    assert log['timing']['sample_period'] == pytest.approx(0.01, rel=1e-6)


def test_messages_as_sent_and_received_are_in_the_bag_for_rosbags(tmp_path):
    from rosbags.highlevel import AnyReader

    from motor_id.bag.schemas import serialize
    st = settings(tmp_path, max_command=6.0, time_scale=0.3)
    sess = ExperimentSession(st)
    sess.open()
    js = serialize('sensor_msgs/msg/JointState', {
        'header': {'stamp': {'sec': 5, 'nanosec': 10}}, 'name': ['j'],
        'position': [0.5], 'velocity': [1.5], 'effort': [0.1]})
    cmd = serialize('std_msgs/msg/Float64MultiArray', {'data': [2.0]})
    sess.record_message('/joint_states', 'sensor_msgs/msg/JointState', js, 5_000_000_010)
    sess.record_message('/ctrl/commands', 'std_msgs/msg/Float64MultiArray', cmd,
                        5_000_000_020)
    sess.close()
    with AnyReader([Path(st.out) / RECORDING]) as reader:
        got = {c.topic: reader.deserialize(raw, c.msgtype)
               for c, _, raw in reader.messages()}
    assert list(got['/joint_states'].position) == [0.5]
    assert list(got['/ctrl/commands'].data) == [2.0]


def test_topics_given_to_open_are_declared_before_their_first_message(tmp_path):
    # the node declares its state and command topics at the start, so the first state's
    # arrival does no schema work (it took 0.4-0.63 s, the experiment then saw a stale
    # burst of states and stopped); a message of another type on them is refused
    from rosbags.highlevel import AnyReader

    from motor_id.bag.schemas import serialize
    from motor_id.errors import BagError
    st = settings(tmp_path)
    sess = ExperimentSession(st)
    sess.open({'/joint_states': 'sensor_msgs/msg/JointState',
               '/ctrl/commands': 'std_msgs/msg/Float64'})
    assert sess.bag is not None
    with pytest.raises((ConfigError, BagError), match='Float64'):
        sess.bag.write_serialized('/ctrl/commands', 'std_msgs/msg/Float64MultiArray',
                                  serialize('std_msgs/msg/Float64MultiArray',
                                            {'data': [1.0]}), 1)
    sess.close()
    with AnyReader([Path(st.out) / RECORDING]) as reader:
        declared = {c.topic: c.msgtype for c in reader.connections}
    assert declared == {'/joint_states': 'sensor_msgs/msg/JointState',
                        '/ctrl/commands': 'std_msgs/msg/Float64'}


def test_the_input_is_the_mean_of_the_commands_over_each_interval_as_they_left(tmp_path):
    from motor_id.experiment.session import Row
    sess = ExperimentSession(settings(tmp_path))
    t = 100.0 + 0.01 * np.arange(30)
    sess.rows = [Row(tk, 9.0, 0.0, 0.0, math.nan, 0) for tk in t]   # decided: 9 everywhere
    # sent 14 ms after each sample (4 ms into the interval after the next sample), value =
    # sample number: over [t_k, t_k+1) sample k-2's for 0.4 of it, then sample k-1's
    sess.sent = [(tk + 0.014, float(k)) for k, tk in enumerate(t)]
    rec = sess.recording()
    np.testing.assert_allclose(rec.input[2:], np.arange(2.0, 30.0) - 1.4, atol=1e-9)
    assert rec.input[0] == rec.input[1] == 0.0   # nothing sent before, then sample 0's 0
    sess.sent = []
    np.testing.assert_array_equal(sess.recording().input, 9.0)


def test_a_test_cut_short_before_the_model_knew_the_joint_runs_again():
    from motor_id.experiment.plan import repeat_later
    plan = arrange(build_plan('sysid', 12.0), room_low=False, room_high=True)
    again = repeat_later(plan, 0)   # quasistatic-forward and its chained reverse
    assert [(t.name, t.rest_before) for t in again.tests[6:]] == [
        ('quasistatic-forward', True), ('quasistatic-reverse', False)]
    assert [t.name for t in repeat_later(plan, 3).tests[6:]] == ['dynamic-reverse']


def test_a_torque_plants_feedforward_comes_from_its_parameters():
    # the analysis' own controller block (one assembly for analyze and the experiment)
    from motor_id.analysis.feedforward import controller_block
    from motor_id.analysis.simulation_result import ParameterEstimate, StageEstimates

    def est(value, std):
        return ParameterEstimate(value=value, std=std, std_model=std, determined=True)

    params = {'J': est(1e-3, 1e-6), 'B': est(2e-5, 2e-6),
              'coulomb_friction.T_c': est(0.12, 5e-4)}

    def block(p):
        # the stage's chosen model and its estimates, all the block reads of it
        sim = SimpleNamespace(chosen='coulomb_friction', estimates=StageEstimates(parameters=p))
        return controller_block(sim, 'torque', False, 'simple')
    ff = block(params).to_dict()['feedforward']
    assert ff['kS'] == {'value': 0.12, 'std': 5e-4, 'unit': 'N m'}
    assert ff['kV'] == {'value': 2e-5, 'std': 2e-6, 'unit': 'N m s/rad'}
    assert ff['kA'] == {'value': 1e-3, 'std': 1e-6, 'unit': 'N m s^2/rad'}
    del params['coulomb_friction.T_c']
    kS = block(params).feedforward['kS']
    assert kS.value == 0.0 and kS.std is None
    from motor_id.experiment.outcome import ExperimentBlock, ExperimentReport, feedforward_line
    line = feedforward_line(ExperimentReport(experiment=ExperimentBlock(
        joint='j', mechanism='simple', input_kind='torque'),
        analysis=SimpleNamespace(controller=lambda: block(params))))
    assert line.startswith('kS 0 N m (the chosen model has no Coulomb friction), kV 2e-05 +- ')
