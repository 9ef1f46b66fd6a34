"""Candidate fits on worker processes: the same report as in one process."""

import os

import pytest

from motor_id.analysis import DiscrepancyAnalysis
from motor_id.analysis.workers import FitPool, FitTask, usable_cores
from motor_id.effects import EFFECTS, SCALES
from motor_id.testing.hidden import make_case


def _without_timings(d):
    if isinstance(d, dict):
        return {k: _without_timings(v) for k, v in d.items() if k != 'seconds'}
    if isinstance(d, list):
        return [_without_timings(v) for v in d]
    return d


def test_two_jobs_give_the_report_of_one():
    """Every fit of every step (singles, restarts, extensions) is the same on workers:
    the reports agree bit for bit (timings aside)."""
    rec, case = make_case(401, 'brush_drop')
    reports = []
    for jobs in (1, 2):
        rep = DiscrepancyAnalysis(R_m=case.known['R_m'], jobs=jobs).fit(rec).report_
        reports.append(_without_timings(rep.to_dict()))
    assert reports[0]['verdict'] != 'none'
    assert reports[0] == reports[1]


def test_the_pool_fits_on_forked_workers_in_task_order():
    """Tasks come back in order, from processes other than the caller's; the fitter's
    settings of the moment travel with each task (a worker forked earlier keeps none)."""

    class Fitter:
        scales, extra_starts, physical_bounds, spread, reading = (
            dict.fromkeys(SCALES, 1.0), {}, {}, False, {})

        def fit(self, name, ref, prior=None, seed=None):
            return name, os.getpid(), self.spread

    fitter = Fitter()
    names = list(EFFECTS)[:6]   # the workers take the largest start grids first
    with FitPool(fitter, jobs=2) as pool:
        first = list(pool.map([FitTask(names[0], None), FitTask('resonance', None)]))
        fitter.spread = True
        out = list(pool.map([FitTask(n, None) for n in names]))
    assert [o[0] for o in first + out] == [names[0], 'resonance'] + names
    assert not any(o[2] for o in first) and all(o[2] for o in out)
    if pool.jobs > 1:   # fork is available
        assert all(o[1] != os.getpid() for o in first + out)
    with FitPool(fitter, jobs=1) as pool:
        assert [o[1] for o in pool.map([FitTask(n, None) for n in names[:2]])] == \
            [os.getpid()] * 2
    assert usable_cores() >= 1


@pytest.mark.parametrize('jobs', [0, -1])
def test_cli_rejects_a_job_count_below_one(jobs, tmp_path, capsys):
    from motor_id.cli import main
    from motor_id.data.csv_io import write_csv
    rec, case = make_case(3, 'none')
    path = tmp_path / 'rec.csv'
    write_csv(rec, path)
    code = main(['analyze', str(path), '-R', str(case.known['R_m']), '--jobs', str(jobs),
                 '-q'])
    assert code != 0
    assert '--jobs' in capsys.readouterr().err
