"""The experiment's pure core against the ways real robots' states differ from the
project's simulator: no velocity (the speed from the position), stamps on another clock,
a joint still moving when the experiment starts (no ROS)."""

import math

import numpy as np
import pytest

from motor_id.experiment.guard import Guard, StateSample
from motor_id.experiment.plan import build_plan
from motor_id.experiment.session import ExperimentSession
from motor_id.experiment.settings import ExperimentSettings
from motor_id.experiment.speed import central_speed, SPEED_ESTIMATE, SpeedFromPosition


def settings(tmp_path, **kw):
    return ExperimentSettings('j', '/ctrl/commands', 6.0, str(tmp_path / 'out'),
                              controller_joints=('j',), **kw)


@pytest.mark.parametrize('rate', [50.0, 250.0, 1000.0])
def test_the_speed_of_a_quantised_encoder_is_a_slope_not_a_count_difference(rate):
    rng = np.random.default_rng(1)
    counts = 4096 / (2 * math.pi)
    t = np.cumsum(rng.uniform(0.9, 1.1, int(2 * rate)) / rate)
    w = 20.0 * np.sin(2.0 * t)    # rad/s
    x = np.floor(-10.0 * np.cos(2.0 * t) * counts) / counts
    est = SpeedFromPosition()
    online = np.array([est.update(a, b) for a, b in zip(t, x, strict=True)])
    # at most half of the span late (15 ms, 0.6 rad/s here) plus the counts' noise
    err = online[10:] - w[10:]
    assert np.max(np.abs(err)) < 0.05 * 20.0, np.max(np.abs(err))
    offline = central_speed(t, x)
    assert np.std(offline[1:-1] - w[1:-1]) < 0.02 * 20.0 * max(1.0, rate / 250.0)
    assert est.update(t[-1], 123.0) == online[-1]   # not newer: not taken


def test_a_state_without_velocity_gets_the_speed_from_its_position(tmp_path):
    sess = ExperimentSession(settings(tmp_path, time_scale=0.1))
    sess.open()
    sess.start(0.0)
    x, w, t = 0.0, 0.0, 0.0
    true = {}
    while not sess.guard.finished and t < 60.0:
        true[t] = w
        cmd = sess.on_state(StateSample(t, t, x, math.nan))
        u = cmd if cmd is not None else sess.guard.command
        w += 0.01 * (u * 10.0 - w) / 0.1   # kV 0.1 V s/rad, tau 0.1 s
        x += 0.01 * w
        t += 0.01
    assert sess.guard.log.complete and sess.speed_derived
    rec = sess.close()
    assert rec is not None and rec.meta['speed_estimate'] == SPEED_ESTIMATE
    w_true = np.array([true[r.t] for r in sess.rows])
    # central differences of the position: off at the steps' corners only
    assert np.median(np.abs(rec.speed - w_true)) < 0.01 * np.max(np.abs(w_true))
    peak = max(t.peak_speed for t in sess.guard.log.tests)
    assert peak == pytest.approx(np.max(np.abs(w_true)), rel=0.05)


def test_stamps_on_another_clock_count_only_their_changes_as_latency(tmp_path):
    g = Guard(settings(tmp_path), build_plan('sysid', 6.0))
    g.start(0.0)
    rng = np.random.default_rng(2)
    for k in range(200):   # the robot's clock: seconds since it booted; ours: epoch
        t = 12.0 + 0.02 * k
        g.on_state(StateSample(t, t, 0.0, 0.0, lag=1.7e9 + 0.01 * rng.random()))
    timing = g.stats.timing()
    assert timing['state_latency'] < 0.01
    assert timing['allowed_latency'] < 0.2
    assert g.stats.other_clock


def test_the_baseline_waits_for_a_joint_still_falling_when_it_starts(tmp_path):
    g = Guard(settings(tmp_path), build_plan('sysid', 6.0))
    g.start(0.0)
    t = 0.0
    while g.phase == 'baseline' and t < 20.0:
        x = -1.0 + math.exp(-t / 0.8)    # settles onto -1 over a few seconds
        g.on_state(StateSample(t, t, x, -math.exp(-t / 0.8) / 0.8))
        t += 0.01
    assert g.phase != 'baseline'
    assert g.rest_position == pytest.approx(-1.0, abs=0.02)
    assert g.log.noise['position'] < 0.01
