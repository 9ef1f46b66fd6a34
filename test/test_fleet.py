"""Fleet: drift rule, profile, discovery, generator physics, and motor-id fleet end to end."""

import dataclasses
import json
import os
import shutil
import subprocess

import numpy as np
import pytest

from motor_id.errors import ConfigError
from motor_id.fleet.config import parse_fleet_config
from motor_id.fleet.discover import find_recordings, robot_rule
from motor_id.fleet.drift import ChangePoint, DriftRule, series
from motor_id.fleet.live import drift_message, EstimateHistory
from motor_id.fleet.rows import EstimateRow, ParameterValue
from motor_id.fleet.siblings import compare_siblings
from motor_id.testing.fleet_gen import Drift, FleetSpec, generate_fleet, MotorTruth, simulate_motor

CHROMIUM = '/usr/bin/chromium'


def _series(rng, n, spread, size=0.0, onset=None, kind='step', fit_std=3e-4):
    """Estimates with uniform day-to-day scatter +-spread and an optional drift (a ramp
    over 5 recordings from ``onset``)."""
    x = np.exp(rng.uniform(-spread, spread, n))
    for d in range(n):
        if onset is not None and d >= onset:
            x[d] *= 1 + size * (1 if kind == 'step' else min(1, (d - onset + 1) / 5))
    x *= 1 + rng.normal(0, fit_std, n)
    return x, x * fit_std


def _days(n):
    return [f'2026-01-{d + 1:02d}T10:00:00Z' for d in range(n)]


def _fleet_scan(rule, histories):
    """scan() of each history with the scatter pooled over all of them (siblings)."""
    prepared = [series(_days(len(x)), x, s) for x, s in histories]
    pool = rule.pool(prepared)
    return [rule.scan_series(h, pool) for h in prepared]


# ------------------------------------------------------------------------- drift rule
def test_drift_steps_anywhere_are_found_and_dated_from_the_third_recording():
    """R_m-like scatter (+-2 % uniform), a +12 % step at every position of a 10-12
    recording history, three clean siblings: found, dated to the recording, and the
    siblings stay clean."""
    rng = np.random.default_rng(1)
    rule = DriftRule()
    for n in (10, 12):
        for onset in range(1, n - 1):
            hist = [_series(rng, n, 0.02, 0.12, onset)] + [_series(rng, n, 0.02)
                                                          for _ in range(3)]
            found = _fleet_scan(rule, hist)
            f = found[0]
            assert f.detected, (n, onset)
            assert len(f.change_points) == 1
            cp = f.change_points[0]
            assert abs(cp.index - onset) <= 1 and cp.since == _days(n)[cp.index]
            assert cp.kind == 'step'
            assert f.change == pytest.approx(0.12, abs=0.03)
            assert onset + 1 <= cp.flagged_index <= (onset + 5 if onset >= 3 else n - 1)
            assert not any(g.detected for g in found[1:])
    # the 3rd recording: K_T-like (+-0.6 %), -8 % from the 2nd, flagged on arrival of
    # the 3rd with 11 siblings (their 22 differences give the scatter)
    hist = [_series(rng, 3, 0.006, -0.08, 1)] + [_series(rng, 3, 0.006) for _ in range(11)]
    found = _fleet_scan(rule, hist)
    assert found[0].detected and found[0].change_points[0].index == 1
    assert not any(f.detected for f in found[1:])


def test_drift_a_change_at_the_second_recording_is_found_by_the_early_splits():
    """One recording before the change: R_m +8 % (about 7 day-to-day scatters) from the
    2nd of 12 recordings, three clean siblings. The splits of the first week are held to
    ``early_threshold`` (4.0) and find it, dated to the 2nd recording, in 19 of 20 seeded
    histories (measured 19); with the early splits off (the whole history's threshold
    5.3 alone) 5."""
    rng = np.random.default_rng(11)
    rule, off = DriftRule(), DriftRule(early=0)
    found = found_off = 0
    for _ in range(20):
        hist = [_series(rng, 12, 0.02, 0.08, 1)] + [_series(rng, 12, 0.02) for _ in range(3)]
        f = _fleet_scan(rule, hist)
        found += f[0].detected and [c.index for c in f[0].change_points] == [1]
        assert f[0].early_score is not None and f[0].early_threshold == 4.0
        assert not any(g.detected for g in f[1:])
        found_off += _fleet_scan(off, hist)[0].detected
    assert found >= 19 and found_off <= 10, (found, found_off)


RAMP_AT_9 = [1.0, 0.982, 0.991, 1.008, 0.976, 0.987, 1.012, 1.005, 1.005, 1.053, 1.048, 1.089,
             1.109, 1.131, 1.123, 1.133, 1.134, 1.125, 1.129, 1.112, 1.105, 1.096, 1.13,
             1.101, 1.136, 1.108, 1.093, 1.102, 1.124, 1.122]
"""An R_m +12 % ramp over 5 recordings from the 9th (benchmarks/fleet_drift.py's
generator): the early splits once cut the regime before it again (a spurious step at the
7th) and the two changes' shapes overlapped (an empty level: ZeroDivisionError)."""


def test_drift_a_ramp_is_one_change_and_shapes_do_not_overlap():
    from motor_id.fleet.segment import shape_change
    x = np.array(RAMP_AT_9)
    for seed in range(5):
        rng = np.random.default_rng(seed)
        hist = [(x, x * 2.6e-4)] + [_series(rng, 30, 0.02, fit_std=2.6e-4) for _ in range(3)]
        f = _fleet_scan(DriftRule(), hist)[0]
        assert [(c.index, c.until_index, c.kind) for c in f.change_points] == [
            (8, 12, 'ramp')], seed
        assert f.change == pytest.approx(0.12, abs=0.01)
    # a change's onset is never before ``lo`` (the end of the change before it)
    y = np.log(x)
    w = np.full(y.size, 1.0 / 0.0115 ** 2)
    assert shape_change(y, w, 0, 9, 11, 30)[0] < 9
    assert shape_change(y, w, 0, 9, 11, 30, lo=9)[0] == 9


def test_drift_ramp_and_a_later_second_change_are_found():
    rng = np.random.default_rng(7)
    rule = DriftRule()
    for onset in (1, 3, 6):           # B-like: +-5 % scatter, +60 % over 5 recordings
        hist = [_series(rng, 12, 0.05, 0.6, onset, 'ramp')] + [
            _series(rng, 12, 0.05) for _ in range(3)]
        f = _fleet_scan(rule, hist)[0]
        assert f.detected and len(f.change_points) == 1
        cp = f.change_points[0]
        assert -1 <= cp.index - onset <= 4, cp
        assert cp.kind == 'ramp' and cp.until_index > cp.index
    x, s = _series(rng, 30, 0.02)     # -10 % from 8, then +15 % from 20
    x[8:] *= 0.9
    x[20:] *= 1.15
    f = _fleet_scan(rule, [(x, s)] + [_series(rng, 30, 0.02) for _ in range(3)])[0]
    assert [c.index for c in f.change_points] == [8, 20]
    assert [c.change for c in f.change_points] == pytest.approx([-0.1, 0.15], abs=0.02)
    assert f.since == _days(30)[20] and f.change == pytest.approx(0.15, abs=0.02)
    assert f.change_points[1].flagged_index <= 23


def test_drift_no_alarm_on_normal_scatter():
    rng = np.random.default_rng(2)
    rule = DriftRule()
    alarms = 0
    for spread in (0.02, 0.006, 0.05):
        for _ in range(25):
            alarms += sum(f.detected for f in _fleet_scan(
                rule, [_series(rng, 30, spread) for _ in range(4)]))
    assert alarms == 0


def test_drift_alarms_are_the_test_run_at_each_recording():
    """alarms() scores every look at once; each equals scan() of the history up to it."""
    rng = np.random.default_rng(5)
    rule = DriftRule()
    for r in range(30):
        n = int(rng.integers(3, 25))
        x, s = _series(rng, n, 0.02, 0.06 if r % 2 else 0.0, n // 2)
        if r % 3 == 0:
            x[int(rng.integers(0, n))] *= 1.3
        h = series(_days(n), x, s)
        a, e = rule.alarms(h)
        assert np.isnan(a[:2]).all()
        for last in range(2, n):
            f = rule.scan(_days(n)[:last + 1], x[:last + 1], s[:last + 1])
            assert f.score == pytest.approx(a[last], abs=1e-9)
            assert f.early_score == pytest.approx(e[last], abs=1e-9)


def test_drift_one_bad_estimate_is_not_a_drift():
    rng = np.random.default_rng(3)
    x, s = _series(rng, 20, 0.02)
    x[12] *= 1.5          # one bad recording, far off
    f = DriftRule().scan(_days(20), x, s)
    assert not f.detected and f.outliers == (12,)
    x, s = _series(rng, 20, 0.02)
    x[-1] *= 1.5          # the latest, far off: waits for the next
    f = DriftRule().scan(_days(20), x, s)
    assert not f.detected and f.outliers == (19,)
    x = np.append(x, x[-1])   # ... which confirms it
    f = DriftRule().scan(_days(21), x, np.append(s, s[-1]))
    assert f.detected and f.change_points[0].index == 19 and f.outliers == ()


def test_scatter_pooled_over_siblings_is_robust_to_their_changes():
    rng = np.random.default_rng(8)
    tau = 0.0115
    hist = [series(_days(30), *_series(rng, 30, 0.02, 0.3 if k == 0 else 0.0, 10, fit_std=0))
            for k in range(6)]
    sc = DriftRule().pool(hist).at()
    assert sc.tau == pytest.approx(tau, rel=0.15)
    assert sc.differences == 6 * 29 and sc.dof == pytest.approx(0.6 * 174)
    assert DriftRule().pool(hist).at(_days(30)[2]).differences == 12
    # two wheels of one robot: their differences at one recording count once (dof)
    same = DriftRule().pool(hist[:2], ['robot_00', 'robot_00']).at()
    assert same.differences == 58 and same.dof == pytest.approx(0.6 * 29)


def test_drift_says_why_a_short_or_fixed_history_is_not_tested():
    f = DriftRule().scan(_days(2), [1.0, 1.01], [0.01] * 2)
    assert not f.detected and 'needs 3' in f.reason
    f = DriftRule().scan(_days(12), [2.3] * 12, [0.0] * 12)
    assert not f.detected and 'not estimated' in f.reason


def test_drift_results_are_typed_and_json_ready():
    rng = np.random.default_rng(9)
    x, s = _series(rng, 15, 0.02, 0.2, 6)
    f = DriftRule().scan(_days(15), x, s)
    with pytest.raises(dataclasses.FrozenInstanceError):
        f.detected = False
    d = json.loads(json.dumps(f.to_dict()))
    assert set(d['change_points'][0]) == {f.name for f in dataclasses.fields(ChangePoint)}
    assert not any(k.startswith('_') for k in d['change_points'][0])


def test_drift_rule_settings_are_checked():
    with pytest.raises(ConfigError, match='threshold'):
        DriftRule(threshold=0)
    with pytest.raises(ConfigError, match='ramp_gap'):
        DriftRule(ramp_gap=-1)
    with pytest.raises(ConfigError, match='unknown key'):
        DriftRule.from_dict({'h': 3})


def test_siblings_report_the_odd_motor_and_say_when_too_few():
    rng = np.random.default_rng(6)
    levels = [(float(np.exp(rng.normal(0, 0.05))), 0.005) for _ in range(10)]
    assert not any(f.outlier for f in compare_siblings(levels, 4.0))
    odd = [(levels[0][0] * 1.8, 0.005)] + levels[1:]
    found = compare_siblings(odd, 4.0)
    assert found[0].outlier and found[0].siblings == 9
    assert found[0].deviation == pytest.approx(0.8, abs=0.15)
    assert not any(f.outlier for f in found[1:])
    few = compare_siblings(odd[:3], 4.0)
    assert not any(f.outlier for f in few) and 'needs 3' in few[0].reason


# ------------------------------------------------------------------------- profile
def test_profile_parses_defaults_and_refuses_unknown_keys():
    prof = parse_fleet_config({
        'motors': {'left': {'input': '/l', 'joint': 'left', 'resistance': 1.2}},
        'defaults': {'speed': '/joint_states:velocity', 'effort_is': 'current'},
        'fit': {'seed': 3}, 'drift': {'threshold': 6.0}})
    m = prof.motors[0]
    assert (m.name, m.speed, m.effort_is, m.resistance) == (
        'left', '/joint_states:velocity', 'current', 1.2)
    assert prof.fit.seed == 3 and prof.drift.threshold == 6.0
    assert prof.settings_hash(m, False) != prof.settings_hash(m, True)
    assert prof.groups() == {'left': 'left'}
    # type: siblings across names; it decides no fit (the settings hash is the same)
    typed = parse_fleet_config({'motors': {
        'left': {'input': '/l', 'joint': 'left', 'resistance': 1.2, 'type': 'wheel'},
        'right': {'input': '/r', 'joint': 'right', 'resistance': 1.2, 'type': 'wheel'}},
        'defaults': {'speed': '/joint_states:velocity', 'effort_is': 'current'},
        'fit': {'seed': 3}})
    assert typed.groups() == {'left': 'wheel', 'right': 'wheel'}
    assert typed.settings_hash(typed.motors[0], False) == prof.settings_hash(m, False)
    with pytest.raises(ConfigError, match='motor left: type must be a name'):
        parse_fleet_config({'motors': {'left': {'type': 3}}})
    with pytest.raises(ConfigError, match='motor left: unknown key.*resistence'):
        parse_fleet_config({'motors': {'left': {'resistence': 1.2}}})
    with pytest.raises(ConfigError, match='"motors:"'):
        parse_fleet_config({'wheel_left': {}})
    with pytest.raises(ConfigError, match='resistance must be a number > 0'):
        parse_fleet_config({'motors': {'left': {'resistance': -1}}})


# ------------------------------------------------------------------------- generator
def test_generator_physics_matches_an_ode_solver():
    from scipy.integrate import solve_ivp
    p = MotorTruth()
    period = 0.01
    rng = np.random.default_rng(0)
    u = np.repeat(rng.uniform(-12, 12, 20), 15)
    w, i = simulate_motor(p, u, period)

    def f(t, x):
        v = u[min(int(t / period), len(u) - 1)]
        return [(p.K_T * x[1] - p.B * x[0]) / p.J, (v - p.R_m * x[1] - p.K_T * x[0]) / p.L_m]
    t = np.arange(len(u)) * period
    ref = solve_ivp(f, (0, t[-1]), [0.0, 0.0], t_eval=t, max_step=period / 20, rtol=1e-9,
                    atol=1e-12)
    np.testing.assert_allclose(w, ref.y[0], atol=1e-4 * np.ptp(w))
    np.testing.assert_allclose(i, ref.y[1], atol=1e-4 * np.ptp(i))
    # Coulomb friction slows the motor and holds it still under a small voltage
    wc, _ = simulate_motor(MotorTruth(T_c=0.05), u, period)
    assert np.mean(np.abs(wc)) < np.mean(np.abs(w))
    still, _ = simulate_motor(MotorTruth(T_c=0.05), np.full(50, 0.1), period)
    assert np.all(still == 0.0)


def test_generated_bags_read_back_through_the_profile(tmp_path):
    from motor_id.fleet.task import read_motor, Task
    spec = FleetSpec(robots=1, days=1, duration_s=2.0)
    truth = generate_fleet(spec, tmp_path)
    prof = parse_fleet_config(truth.profile)
    rec_path = truth.recordings[0].path
    assert os.path.isfile(os.path.join(rec_path, 'metadata.yaml'))
    task = Task(rec_path, 'robot_00', 0, 0, prof.motors[1], prof.fit, False, 'x')
    rec = read_motor(task)
    assert len(rec) == 200 and rec.input_kind == 'voltage'
    assert np.all(np.abs(rec.input) <= spec.max_voltage)
    assert rec.meta['time_origin_ns'] == truth.recordings[0].start_ns


def test_task_with_analysis_names_the_generators_friction(tmp_path):
    """--analyze: the discrepancy analysis runs in the task; Coulomb friction written by
    the generator (not by motor_id.model) is named in the verdict."""
    from motor_id.fleet.run import plan
    from motor_id.fleet.task import run_task
    truth = generate_fleet(FleetSpec(robots=1, days=1, motors=('m',), duration_s=8.0,
                                     nominal=MotorTruth(T_c=0.05)), tmp_path)
    task = plan(find_recordings([str(tmp_path)]), parse_fleet_config(truth.profile),
                analyze=True)[0]
    row = run_task(task)
    assert isinstance(row, EstimateRow), row
    assert 'coulomb_friction' in row.verdict and row.unexplained is False
    assert row.parameter('K_T').determined and row.seconds > 0


# ------------------------------------------------------------------------- discovery
def test_recordings_found_in_folders_files_and_globs(tmp_path):
    spec = FleetSpec(robots=2, days=2, duration_s=0.5, motors=('m',))
    generate_fleet(spec, tmp_path / 'logs')
    loose = tmp_path / 'loose' / 'robot_09'
    loose.mkdir(parents=True)
    generate_fleet(FleetSpec(robots=1, days=1, duration_s=0.5, motors=('m',),
                             layout='file'), tmp_path / 'x')
    shutil.copy(next((tmp_path / 'x' / 'robot_00').glob('*.mcap')), loose / 'day.mcap')
    recs = find_recordings([str(tmp_path / 'logs'), str(loose / '*.mcap')])
    assert [r.robot for r in recs] == ['robot_00', 'robot_00', 'robot_01', 'robot_01',
                                       'robot_09']
    # a file inside a bag folder stands for the folder; duplicates are one recording
    inner = next((tmp_path / 'logs' / 'robot_00').glob('*/*.mcap'))
    assert find_recordings([str(inner), str(inner.parent)])[0].path == str(inner.parent)
    assert robot_rule(r'regex:(?P<robot>robot_\d+)_')('/a/robot_07_2026-01-01') == 'robot_07'
    assert robot_rule('parent:2')('/logs/site_a/robot_01/bag') == 'site_a'
    with pytest.raises(ConfigError, match='no such file'):
        find_recordings([str(tmp_path / 'nothing')])
    with pytest.raises(ConfigError, match='robot_from grandma: want'):
        robot_rule('grandma')


# ------------------------------------------------------------------------- live history
def test_estimate_history_appends_and_finds_a_drift(tmp_path):
    hist = EstimateHistory(str(tmp_path / 'h' / 'history.jsonl'), robot='r', motor='m')
    rng = np.random.default_rng(4)
    for d, v in enumerate(np.r_[0.3 * (1 + rng.uniform(-0.005, 0.005, 9)), [0.27] * 3]):
        hist.append({'K_T': ParameterValue(value=v, std=1e-5, determined=True),
                     'J': ParameterValue(value=None, std=None, determined=False)},
                    _days(12)[d])
    with open(hist.path, 'a') as fh:
        fh.write('not json\n')
    rows = {d.parameter: d for d in hist.check()}
    assert hist.skipped_ == 1
    assert rows['K_T'].detected and rows['K_T'].since == '2026-01-10'
    assert rows['K_T'].change == pytest.approx(-0.1, abs=0.01)
    assert not rows['J'].detected
    assert drift_message(hist.check()).startswith('drift: K_T -10.')


# ------------------------------------------------------------------------- end to end
@pytest.fixture(scope='module')
def small_fleet(tmp_path_factory):
    """2 robots x 1 motor x 11 days; robot_01's R_m +25 % from day 7; one truncated bag
    and one without the command topic."""
    spec = FleetSpec(robots=2, days=11, motors=('wheel_left',), duration_s=6.0,
                     drifts=(Drift('robot_01', 'wheel_left', 'R_m', 0.25, 7),),
                     broken=(('robot_00', 2, 'truncated'), ('robot_00', 4, 'no_command')),
                     seed=11)
    root = tmp_path_factory.mktemp('fleet')
    truth = generate_fleet(spec, root / 'logs')
    return root, truth


@pytest.fixture(scope='module')
def fleet_run(small_fleet):
    """`motor-id fleet` on the small fleet with one embedded worker, and its output."""
    from motor_id.cli import main
    root, truth = small_fleet
    out = root / 'out'
    code = main(['fleet', str(root / 'logs'), '--config', str(root / 'logs' / 'fleet.yaml'),
                 '--out', str(out), '--workers', '1', '-q'])
    return out, code


def test_fleet_fits_every_motor_and_records_failures(fleet_run, small_fleet):
    import pyarrow.parquet as pq

    from motor_id.fleet.rows import COLUMNS
    out, code = fleet_run
    assert code == 0
    rows = pq.read_table(out / 'estimates.parquet').to_pylist()
    assert len(rows) == 20 and list(rows[0]) == list(COLUMNS)
    truth = small_fleet[1]
    for r in rows:
        day = int(r['recording'][-2:]) - 5      # robot_NN_2026-01-DD, day 0 is the 5th
        true = truth.truth[(r['robot'], 'wheel_left')][day]
        assert r['R_m'] == pytest.approx(true.R_m, rel=0.01)
        assert r['K_T'] == pytest.approx(true.K_T, rel=0.01)
        assert r['R_m_determined'] and r['adequate'] and r['R_m_std'] > 0
        assert r['start_time'].date().isoformat() == r['recording'][-10:]
    failed = json.loads((out / 'failed.json').read_text())
    assert {(f['stage'], f['recording'][-10:]) for f in failed} == {
        ('read', '2026-01-07'), ('read', '2026-01-09')}
    assert any('/wheel_left_cmd' in f['reason'] for f in failed)
    with open(out / 'estimates.csv') as fh:
        assert len(fh.read().splitlines()) == 21


def test_fleet_store_reads_back_what_it_wrote(fleet_run, tmp_path):
    """The typed rows and failures go through Parquet, CSV and JSON and back unchanged:
    a store reopened and rewritten writes the same bytes."""
    from motor_id.fleet.store import ResultStore
    out, _ = fleet_run
    copy = tmp_path / 'copy'
    shutil.copytree(out, copy)
    store = ResultStore(copy)
    assert len(store.rows) == 20 and len(store.failures) == 2
    assert all(isinstance(r, EstimateRow) for r in store.rows.values())
    store.flush(force=True)
    for name in ('estimates.csv', 'failed.json'):
        assert (copy / name).read_bytes() == (out / name).read_bytes(), name
    assert ResultStore(copy).sorted_rows() == store.sorted_rows()


def test_fleet_names_the_drifting_motor_parameter_and_date(fleet_run):
    out, _ = fleet_run
    drift = json.loads((out / 'drift.json').read_text())
    keys = {'robot', 'motor', 'parameter', 'detected', 'change', 'since', 'z', 'baseline',
            'latest'}
    assert all(keys <= set(d) for d in drift)
    found = [(d['robot'], d['parameter'], d['since']) for d in drift if d['detected']]
    assert found == [('robot_01', 'R_m', '2026-01-12')]
    assert drift[0]['change'] == pytest.approx(0.25, abs=0.04)
    assert len(drift) == 2 * 6


def test_fleet_rerun_fits_only_new_recordings(fleet_run, small_fleet):
    from motor_id.fleet.config import load_fleet_config
    from motor_id.fleet.engine import DaskEngine
    from motor_id.fleet.run import run_fleet
    root, truth = small_fleet
    out, _ = fleet_run
    work = root / 'rerun'
    shutil.copytree(out, work)
    logs = root / 'logs'
    prof = load_fleet_config(str(logs / 'fleet.yaml'))
    extra = root / 'more'
    generate_fleet(FleetSpec(robots=1, days=1, motors=('wheel_left',), duration_s=6.0,
                             start='2026-01-20', seed=5), extra)
    with DaskEngine(workers=1) as engine:
        res = run_fleet([str(logs), str(extra / 'robot_00')], prof, str(work), engine=engine)
        assert (res.tasks, res.skipped, res.done, res.failed) == (23, 22, 1, 0)
        # a changed profile fits everything again
        prof2 = parse_fleet_config({**truth.profile, 'fit': {'seed': 1}})
        res = run_fleet([str(extra)], prof2, str(work), engine=engine, report=False)
        assert (res.tasks, res.skipped, res.done) == (1, 0, 1)


def test_fleet_runs_on_an_existing_scheduler(small_fleet, tmp_path):
    import dask
    import distributed

    from motor_id.cli import main
    from motor_id.fleet.engine import WORKER_CONFIG
    root, _ = small_fleet
    with dask.config.set(WORKER_CONFIG), distributed.LocalCluster(
            n_workers=1, threads_per_worker=1, host='127.0.0.1',
            dashboard_address='127.0.0.1:0') as cluster:
        code = main(['fleet', str(root / 'logs' / 'robot_01' / '*2026-01-1[45]'),
                     '--profile', str(root / 'logs' / 'fleet.yaml'), '--out',
                     str(tmp_path), '--scheduler', cluster.scheduler_address, '-q'])
    assert code == 0
    assert len((tmp_path / 'estimates.csv').read_text().splitlines()) == 3


def test_fleet_cli_errors_are_one_line(tmp_path, capsys):
    from motor_id.cli import main
    prof = tmp_path / 'p.yaml'
    prof.write_text('motors: {m: {input: /c}}\n')
    assert main(['fleet', str(tmp_path / 'none'), '--profile', str(prof), '--out',
                 str(tmp_path / 'o')]) == 2
    assert 'no such file or directory' in capsys.readouterr().err


def _chromium(*args, timeout=60):
    profile = f'/tmp/motor-id-chromium-{os.getpid()}-{np.random.default_rng().integers(1e9)}'
    cmd = [CHROMIUM, '--headless', '--no-sandbox', '--disable-gpu',
           '--disable-background-networking', '--disable-component-update', '--disable-sync',
           '--no-first-run', f'--user-data-dir={profile}', *args]
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    finally:
        shutil.rmtree(profile, ignore_errors=True)


@pytest.mark.skipif(not os.path.exists(CHROMIUM),
                    reason='needs Debian chromium at /usr/bin/chromium (apt-get install -y '
                           'chromium; .ci/run installs it)')
def test_report_opens_in_a_headless_browser(fleet_run, tmp_path):
    import re
    out, _ = fleet_run
    page = out / 'report.html'
    text = page.read_text()
    assert not re.search(r'(src|href)\s*=\s*["\']?(https?:|//)|url\(|@import', text)
    assert 'http' not in text            # nothing to fetch, not even a namespace URL
    dom = _chromium('--dump-dom', page.as_uri()).stdout
    assert 'data-ready="1"' in dom      # the page's script ran
    assert '2 motors' in dom and '1 drifting' in dom and '2 failed tasks' in dom
    assert "0 outside their siblings' spread" in dom and 'id="siblings-none"' in dom
    first = re.search(r'<tbody><tr class="(\w*)" data-robot="(\w+)" data-motor="(\w+)"',
                      dom)
    assert first.groups() == ('drift', 'robot_01', 'wheel_left')   # worst first
    assert dom.count('<svg') >= 2 * 5 and 'class="change-point"' in dom
    assert 'File end magic is invalid' in dom or 'not a readable' in dom
    shot = tmp_path / 'report.png'
    _chromium(f'--screenshot={shot}', '--window-size=1200,900', page.as_uri())
    from PIL import Image
    img = np.asarray(Image.open(shot).convert('RGB'), dtype=float)
    assert img.shape[:2] == (900, 1200)
    red = (img[..., 0] > 200) & (img[..., 1] < 240) & (img[..., 2] < 240) & \
        (img[..., 0] - img[..., 2] > 8)
    assert red.mean() > 0.001          # the drifting motor's row is shaded


@pytest.mark.slow
def test_fleet_meets_the_detection_targets_on_a_held_out_fleet(tmp_path):
    """The issue's targets on a held-out fleet: 4 robots x 2 wheels x 10-12 days, R_m
    +-2 % from day to day, K_T -8 % (step), B +60 % (ramp), R_m +12 % (step) from days
    drawn in the first week; each flagged on its parameter, steps dated within one
    recording, the ramp within -1..+4; no clean wheel flagged; the page marks each."""
    from motor_id.fleet.run import run_fleet
    from motor_id.testing.fleet_gen import drift_benchmark_spec, score_detection
    spec = drift_benchmark_spec(seed=23)
    truth = generate_fleet(spec, tmp_path / 'logs')
    res = run_fleet([str(tmp_path / 'logs')], parse_fleet_config(truth.profile),
                    str(tmp_path / 'out'), workers=2)
    assert res.failed == 0
    rows, false, clean_series = score_detection(spec, res.drift)
    assert clean_series == (spec.robots * 2 - len(spec.drifts)) * 6 and false == []
    for r in rows:
        lo, hi = (-1, 4) if 'ramp' in r.drift else (-1, 1)
        assert r.flagged and r.dated is not None and lo <= r.dated <= hi, r
        assert r.other_flags == '-', r
    page = (tmp_path / 'out' / 'report.html').read_text()
    assert page.count('class="change-point"') >= 3 and 'class="change-point ramp"' in page
