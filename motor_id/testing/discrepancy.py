"""Hidden-effect cases on two generators, the discrepancy analysis on each, and its rates.

The case plan shared by ``benchmarks/discrepancy_rates.py`` (the benchmark's tables) and
``test/test_independent_rates.py`` (the targets in the test run). Generators:

- ``hidden``: :func:`motor_id.testing.hidden.make_case`, the project's own simulator
  (4,000 samples at 10 ms, the paper's motor perturbed);
- ``independent``: :mod:`motor_id.testing.independent_sim`, a second simulator written
  from the physics with no motor_id model code (industrial, servo and hobby motors,
  sample periods of 1-20 ms, 2,000-25,000 samples).

Each round of cases hides every effect of the generator once and adds four clean cases;
the motor class cycles through the three classes. The analysis is told R_m off by a
seeded 2-5 % of either sign (as an ohmmeter would be), unless ``exact_rm``.

Definitions: an effect is *named* when the hidden effect is in the verdict or in
``ambiguous_with``; the verdict is *exact* when it is the hidden effect alone; a *false
alarm* is any verdict but ``none`` on a clean case; a *spurious second effect* is a
compound verdict (``a+b``) on a case with one hidden effect; *encoder-grid cases* hide
``speed_quantization``. The parameter error is ``found / true - 1`` of the effect's
magnitude (the analysis' value from the verdict's model, else from the effect's own
candidate model) for named effects.
"""

from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field, replace
import math
import multiprocessing
import time
from typing import Any

import numpy as np

from motor_id.analysis import DiscrepancyAnalysis
from motor_id.blas import limit_threads
from motor_id.recording import Recording
from motor_id.testing import independent_sim
from motor_id.testing.hidden import make_case as make_hidden_case
from motor_id.testing.hidden import VOLTAGE_EFFECTS

GENERATORS = ('hidden', 'independent')
"""The case generators: this package's simulator and the independent one."""
NOISE_LEVELS = (0.005, 0.02, 0.05)
"""Speed and current white-noise std, as a fraction of each channel's std."""
TARGET_NOISE = (0.005, 0.02)
"""The issue's targets hold on the independent generator at these noise levels."""
CLEAN_PER_ROUND = 4
"""Clean cases in each round (which also hides every effect of the generator once)."""
R_M_ERROR = (0.02, 0.05)
"""Relative error of the resistance the analysis is told: uniform magnitude, either sign."""
DEFAULT_CASES = 16
"""Cases per generator and noise level (one round of the independent generator)."""
MAGNITUDE = {'coulomb_friction': 'T_c', 'load_torque': 'T_L', 'quadratic_load': 'k_q',
             'brush_drop': 'V_b', 'dead_zone': 'V_dz', 'voltage_saturation': 'V_max',
             'input_delay': 'd', 'sensor_lag': 'tau_s', 'speed_quantization': 'q',
             'current_quantization': 'q_i', 'resistance_drift': 'k_h', 'resonance': 'f_r'}
"""The parameter whose relative error is reported for each effect (analysis names)."""
PARAM_OFF = 0.3
"""A named effect whose parameter is off by more than this is listed among the failures."""


@dataclass(frozen=True)
class CaseSpec:
    """One benchmark case: everything needed to regenerate it in a worker process."""

    generator: str
    seed: int
    noise: float
    effect: str
    motor_class: str | None = None
    n_samples: int | None = None
    r_m_error: float = 0.0


@dataclass(frozen=True)
class CaseFacts:
    """What a generated case hides and how it was generated (never shown to the analysis).

    Attributes
    ----------
    effect : str
        The hidden effect ('none' for a clean case).
    effect_params : dict
        The hidden effect's parameters by name.
    motor_class, excitation : str
    sample_period : float
        [s]
    n_samples : int
    R_m : float
        The true resistance [ohm].
    R_m_told_error : float
        Relative error of the resistance told to the analysis.
    """

    effect: str
    effect_params: dict[str, float]
    motor_class: str
    excitation: str
    sample_period: float
    n_samples: int
    R_m: float
    R_m_told_error: float


@dataclass(frozen=True)
class Candidate:
    """One dynamic model of the analysis, as a failure listing shows it."""

    name: str
    gain: float | None
    significant: bool
    blocks_improved: float | None
    failed: str
    implausible: str
    at_limit: list[str]
    parameters: dict[str, float | None]


@dataclass(frozen=True)
class CaseRow:
    """One analysed case: its spec, its truth, the verdict and how it compares.

    ``named``: the hidden effect is in the verdict or in ``ambiguous``; ``exact``: the
    verdict is the hidden effect alone; ``spurious``: a compound verdict on a case with
    one hidden effect; ``false_alarm``: any verdict but ``none`` on a clean case;
    ``param_error``: ``param_found / param_true - 1`` of the effect's magnitude.
    """

    spec: CaseSpec
    truth: CaseFacts | None = None
    verdict: str | None = None
    found: list[str] = field(default_factory=list)
    ambiguous: list[str] = field(default_factory=list)
    named: bool = False
    exact: bool = False
    spurious: bool = False
    false_alarm: bool = False
    param: str | None = None
    param_true: float | None = None
    param_found: float | None = None
    param_error: float | None = None
    seconds: float | None = None
    top: list[Candidate] = field(default_factory=list)
    own: Candidate | None = None
    unexplained: bool | None = None
    cpu_seconds: float | None = None
    measurement: dict[str, str] = field(default_factory=dict)
    R_m_found_error: float | None = None
    length: int | None = None
    error: str = ''
    generator_error: bool = False

    @property
    def generator(self) -> str:
        """The spec's generator."""
        return self.spec.generator

    @property
    def seed(self) -> int:
        """The spec's seed."""
        return self.spec.seed

    @property
    def noise(self) -> float:
        """The spec's noise level."""
        return self.spec.noise

    @property
    def effect(self) -> str:
        """The hidden effect of the spec ('none' for a clean case)."""
        return self.spec.effect

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the spec's fields, then the row's (a benchmark's ``cases``)."""
        out = {**asdict(self.spec), **asdict(self)}
        del out['spec']
        if not self.generator_error:
            del out['generator_error']
        return out


@dataclass(frozen=True)
class Rates:
    """Counts and rates of a set of rows: ``(k, n)`` pairs and ``k / n`` (None: n = 0)."""

    cases: int
    effect_cases: int
    clean_cases: int
    named: tuple[int, int]
    exact: tuple[int, int]
    false_alarm: tuple[int, int]
    spurious: tuple[int, int]
    grid_named: tuple[int, int]
    errors: tuple[int, int]
    median_s: float | None
    median_cpu_s: float | None
    median_length: float | None
    max_s: float | None
    median_param_error: float | None

    def rate(self, key: str) -> float | None:
        """``k / n`` of the pair ``key`` (None when n is 0)."""
        k, n = getattr(self, key)
        return k / n if n else None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the fields, then ``<pair>_rate`` for each pair."""
        out = asdict(self)
        for key in RATE_PAIRS:
            out[key + '_rate'] = self.rate(key)
        return out


RATE_PAIRS = ('named', 'exact', 'false_alarm', 'spurious', 'grid_named', 'errors')
"""The ``(k, n)`` pairs of :class:`Rates`."""


def generator_effects(generator: str) -> tuple[str, ...]:
    """Effects a generator can hide, in its own order."""
    if generator == 'hidden':
        return tuple(VOLTAGE_EFFECTS)
    return tuple(independent_sim.EFFECTS)


def r_m_error(seed: int) -> float:
    """The seeded relative error of the told resistance: +-U(2 %, 5 %)."""
    rng = np.random.default_rng([int(seed), 0x5E5])
    return float(rng.choice([-1.0, 1.0]) * rng.uniform(*R_M_ERROR))


def plan(generator: str, noise: float, n_cases: int, seed0: int = 0,
         max_samples: int | None = None, exact_rm: bool = False,
         effects: Sequence[str] | None = None) -> list[CaseSpec]:
    """The seeded case list of one generator at one noise level.

    Parameters
    ----------
    generator : {'hidden', 'independent'}
    noise : float
        Noise std as a fraction of each channel's std.
    n_cases : int
        Number of cases; rounds of every effect once plus :data:`CLEAN_PER_ROUND` clean
        cases are cut to this length.
    seed0 : int
        Seed of the first case; case k has seed ``seed0 + k``.
    max_samples : int, optional
        Independent generator: draw the length log-uniform in [2000, max_samples]
        instead of leaving it to the generator (2,000-25,000).
    exact_rm : bool
        Tell the analysis the true R_m instead of one off by 2-5 %.
    effects : sequence of str, optional
        Effects of a round (default every effect of the generator).

    Returns
    -------
    list of CaseSpec
    """
    effects = tuple(effects or generator_effects(generator))
    order = effects + ('none',) * CLEAN_PER_ROUND
    classes = ('industrial', 'servo', 'hobby')
    specs = []
    for k in range(int(n_cases)):
        seed = int(seed0) + k
        n = None
        motor_class = None
        if generator == 'independent':
            motor_class = classes[k % len(classes)]
            if max_samples is not None:
                rng = np.random.default_rng([seed, 0x1E5])
                n = int(round(math.exp(rng.uniform(math.log(2000),
                                                   math.log(max(max_samples, 2000))))))
        specs.append(CaseSpec(generator, seed, float(noise), order[k % len(order)],
                              motor_class, n, 0.0 if exact_rm else r_m_error(seed)))
    return specs


def make_recording(spec: CaseSpec) -> tuple[Recording, CaseFacts, float]:
    """Generate a case: ``(recording, its truth, R_m told to the analysis)``."""
    if spec.generator == 'hidden':
        rec, case = make_hidden_case(spec.seed, effect=spec.effect, n_samples=4000,
                                     noise=(spec.noise, spec.noise))
        d = case.to_dict()
        r_true = float(d['motor']['R_m'])
        r_known = float(d['known']['R_m'])
        if spec.r_m_error == 0.0:
            r_known = r_true
        elif abs(r_known / r_true - 1.0) < 1e-9:  # the generator tells the exact value
            r_known = r_true * (1.0 + spec.r_m_error)
        motor_class = 'paper (perturbed)'
    elif spec.generator == 'independent':
        data, truth_case = independent_sim.make_case(
            spec.seed, effect=spec.effect, motor_class=spec.motor_class,
            n_samples=spec.n_samples, noise=spec.noise, r_m_error=spec.r_m_error)
        rec = independent_sim.to_recording(data)
        d = truth_case.to_dict()
        r_true = float(d['motor']['R'])
        r_known = float(data.known['R_m'])
        motor_class = d['motor_class']
    else:
        raise ValueError(f'unknown generator {spec.generator!r}; choose from {GENERATORS}')
    truth = CaseFacts(d['effect'], d['effect_params'], motor_class, d['excitation'],
                      d['sample_period'], d['n_samples'], r_true, r_known / r_true - 1.0)
    return rec, truth, r_known


def _value(v: Any) -> float | None:
    if isinstance(v, dict):
        v = v.get('value')
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _lookup(params: Mapping[str, Any] | None, effect: str, name: str) -> float | None:
    """``effect.name`` (or ``name``) from a parameter mapping, as a float or None."""
    if not params:
        return None
    for key in (f'{effect}.{name}', name):
        if key in params:
            return _value(params[key])
    if isinstance(params.get(effect), dict) and name in params[effect]:
        return _value(params[effect][name])
    return None


def found_parameter(rep: Any, effect: str, found: Sequence[str]) -> float | None:
    """The analysis' value of the effect's magnitude (verdict model first), or None."""
    name = MAGNITUDE.get(effect)
    if name is None:
        return None
    if effect in found:
        v = _lookup(rep.parameters, effect, name)
        if v is not None:
            return v
    for e in rep.effects:
        if getattr(e, 'name', None) == effect:
            v = _lookup(e.parameters, effect, name)
            if v is not None:
                return v
    return None


def _compact(params: Mapping[str, Any] | None, limit: int = 4) -> dict[str, float | None]:
    out = {}
    for k, v in list((params or {}).items())[:limit]:
        x = _value(v)
        out[k] = None if x is None else float(f'{x:.4g}')
    return out


def _candidate(d: Mapping[str, Any]) -> Candidate:
    """A candidate from the JSON form of an analysis' effect entry."""
    ev = d.get('evidence', {})
    return Candidate(name=d['name'], gain=_value(d.get('gain')),
                     significant=bool(ev.get('significant')),
                     blocks_improved=_value(ev.get('heldout_blocks_improved')),
                     failed=ev.get('failed', ''), implausible=ev.get('implausible', ''),
                     at_limit=ev.get('at_search_limit') or [],
                     parameters=_compact(d.get('parameters')))


def top_candidates(rep: Any, k: int = 3, effect: str | None = None,
                   ) -> tuple[list[Candidate], Candidate | None]:
    """The k dynamic models with the largest held-out gain, and ``effect``'s own model.

    Returns
    -------
    top : list of Candidate
    own : Candidate or None
        The same for the single-effect model of ``effect`` when it is not in ``top``.
    """
    rows = [_candidate(e.to_dict()) for e in rep.effects
            if e.to_dict().get('evidence', {}).get('kind') != 'measurement']
    rows.sort(key=lambda r: -(r.gain if r.gain is not None else -math.inf))
    top = rows[:k]
    own = next((r for r in rows[k:] if r.name == effect), None)
    return top, own


def _measurement_notes(rep: Any) -> dict[str, str]:
    """Per channel: grid found or the reason why not (the lattice evidence)."""
    out = {}
    for ch, m in (getattr(rep, 'measurement', None) or {}).items():
        out[ch] = f'found q = {m.q:.4g}' if m.found and m.q else (m.reason or '')
    return out


def _names(entries: Iterable[Any] | None) -> list[str]:
    return [getattr(a, 'name', str(a)) for a in entries or []]


def analyse(spec: CaseSpec, candidates: Sequence[str] | None = None) -> CaseRow:
    """Generate and analyse one case; returns its row."""
    hidden = None if spec.effect == 'none' else spec.effect
    try:
        rec, truth, r_known = make_recording(spec)
    except Exception as exc:  # noqa: BLE001 - a generator failure is a row, not a crash
        return CaseRow(spec, error=f'generator: {type(exc).__name__}: {exc}',
                       generator_error=True)
    # the spec's n_samples stays as planned (None: drawn); the row's length is the truth's
    row = CaseRow(spec, truth=truth, length=truth.n_samples)
    try:
        t0, c0 = time.perf_counter(), time.process_time()
        ana = DiscrepancyAnalysis(R_m=r_known, candidates=candidates, random_state=spec.seed)
        ana.fit(rec)
        seconds = time.perf_counter() - t0
        row = replace(row, seconds=seconds, cpu_seconds=time.process_time() - c0)
    except Exception as exc:  # noqa: BLE001 - an analysis crash is a miss, listed
        return replace(row, error=f'analysis: {type(exc).__name__}: {exc}')
    rep = ana.report_
    found = [] if rep.verdict == 'none' else rep.verdict.split('+')
    amb = _names(rep.ambiguous_with)
    top, own = top_candidates(rep, effect=hidden)
    r_found = _lookup(rep.parameters, '', 'R_m')
    row = replace(row, verdict=rep.verdict, found=found, ambiguous=amb, top=top, own=own,
                  unexplained=bool(rep.unexplained), measurement=_measurement_notes(rep),
                  R_m_found_error=None if r_found is None else r_found / truth.R_m - 1.0)
    if hidden is None:
        return replace(row, false_alarm=bool(found))
    named = hidden in found or hidden in amb
    row = replace(row, named=named, exact=found == [hidden], spurious=len(found) > 1)
    name = MAGNITUDE.get(hidden)
    true_v = _value(truth.effect_params.get(name)) if name else None
    if true_v is not None:
        row = replace(row, param=name, param_true=true_v)
        if named:
            v = found_parameter(rep, hidden, found)
            row = replace(row, param_found=v, param_error=(
                v / true_v - 1.0 if v is not None and true_v != 0.0 else None))
    return row


def _analyse_job(job: tuple[CaseSpec, Sequence[str] | None]) -> CaseRow:
    spec, candidates = job
    return analyse(spec, candidates)


def run_cases(specs: Sequence[CaseSpec], candidates: Sequence[str] | None = None,
              jobs: int = 1,
              progress: Callable[[int, int, CaseRow], None] | None = None,
              ) -> list[CaseRow]:
    """Analyse every case (in ``jobs`` worker processes); rows in the order of ``specs``.

    Workers start from a fork server (a clean process, not a fork of a caller that may
    run threads); every case is seeded, so the rows do not depend on ``jobs``.
    """
    work = [(s, candidates) for s in specs]
    rows = []
    if jobs <= 1:
        for k, job in enumerate(work):
            rows.append(_analyse_job(job))
            if progress:
                progress(k + 1, len(work), rows[-1])
        return rows
    limit_threads()   # the fork server is a fresh process: one BLAS thread per worker
    with ProcessPoolExecutor(max_workers=jobs,
                             mp_context=multiprocessing.get_context('forkserver')) as pool:
        for k, row in enumerate(pool.map(_analyse_job, work)):
            rows.append(row)
            if progress:
                progress(k + 1, len(work), row)
    return rows


def _pair(rows: list[CaseRow], key: str) -> tuple[int, int]:
    return (sum(bool(getattr(r, key)) for r in rows), len(rows))


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def rates(rows: Iterable[CaseRow]) -> Rates:
    """Counts and rates of a set of rows (generator failures excluded)."""
    rows = [r for r in rows if not r.generator_error]
    eff = [r for r in rows if r.effect != 'none']
    clean = [r for r in rows if r.effect == 'none']
    grid = [r for r in eff if r.effect == 'speed_quantization']
    secs = [r.seconds for r in rows if r.seconds is not None]
    return Rates(
        cases=len(rows), effect_cases=len(eff), clean_cases=len(clean),
        named=_pair(eff, 'named'), exact=_pair(eff, 'exact'),
        false_alarm=_pair(clean, 'false_alarm'), spurious=_pair(eff, 'spurious'),
        grid_named=_pair(grid, 'named'), errors=_pair(rows, 'error'),
        median_s=_median(secs),
        median_cpu_s=_median([r.cpu_seconds for r in rows if r.cpu_seconds is not None]),
        median_length=_median([r.length for r in rows if r.length]),
        max_s=float(np.max(secs)) if secs else None,
        median_param_error=_median([abs(r.param_error) for r in eff
                                    if r.param_error is not None]))


def is_failure(row: CaseRow) -> str:
    """Why a row is listed among the failures ('' when it is not)."""
    if row.error:
        return 'error'
    if row.effect == 'none':
        return 'false alarm' if row.false_alarm else ''
    if not row.named:
        return 'missed'
    if row.spurious:
        return 'spurious second effect'
    if not row.exact:
        return 'named only as ambiguous' if row.effect in row.ambiguous else 'inexact'
    if row.param_error is not None and abs(row.param_error) > PARAM_OFF:
        return f'parameter off by {100 * row.param_error:+.0f} %'
    return ''


def _fmt_params(params: Mapping[str, Any] | None) -> str:
    return ', '.join(f'{k}={v:.4g}' if isinstance(v, (int, float)) else f'{k}={v}'
                     for k, v in (params or {}).items()) or '-'


def _candidate_line(c: Candidate, label: str = '') -> str:
    flags = [f for f, on in (('significant', c.significant),
                             (f'failed: {c.failed}', c.failed),
                             (f'implausible: {c.implausible}', c.implausible),
                             (f'at limit {c.at_limit}', c.at_limit)) if on]
    gain = '-' if c.gain is None else f'{c.gain:.3f}'
    blocks = '' if c.blocks_improved is None else f', blocks {c.blocks_improved:.2f}'
    return (f'  - {c.name}{label}: gain {gain}{blocks}'
            + (f' ({"; ".join(flags)})' if flags else '')
            + f' {_fmt_params(c.parameters)}')


def _case_head(r: CaseRow, why: str) -> str:
    t = r.truth
    head = (f'- **{why}** [{r.generator} seed {r.seed}, noise {100 * r.noise:g} %] '
            f'truth `{r.effect}`')
    if t:
        head += (f' ({_fmt_params(t.effect_params)}); {t.motor_class}, '
                 f'T = {1e3 * t.sample_period:.3g} ms, n = {t.n_samples}, '
                 f'{t.excitation}, R_m told {100 * t.R_m_told_error:+.1f} %')
    return head


def failure_lines(rows: Iterable[CaseRow]) -> list[str]:
    """Markdown lines: one bullet per failing case with truth, verdict and top candidates."""
    lines = []
    for r in rows:
        why = is_failure(r)
        if not why:
            continue
        lines.append(_case_head(r, why))
        if r.error:
            lines.append(f'  - {r.error}')
            continue
        found = ('' if r.param_found is None else
                 f'; found {r.param} = {r.param_found:.4g} vs true {r.param_true:.4g}')
        lines.append(f'  - verdict `{r.verdict}`, ambiguous with {r.ambiguous or "-"}, '
                     f'unexplained {r.unexplained}, {r.seconds:.1f} s{found}')
        if r.R_m_found_error is not None:
            lines.append(f'  - R_m used by the analysis: {100 * r.R_m_found_error:+.1f} % '
                         'from the truth')
        if r.effect in ('speed_quantization', 'current_quantization', 'none'):
            lines += [f'  - {ch} grid: {note}' for ch, note in r.measurement.items()]
        lines += [_candidate_line(c) for c in r.top]
        if r.own:
            lines.append(_candidate_line(r.own, ' (the truth; not in the top 3)'))
    return lines


def build_plan(quick: bool = False, cases: int | None = None,
               generators: Sequence[str] = GENERATORS,
               levels: Sequence[float] = NOISE_LEVELS, exact_rm: bool = False) -> list[CaseSpec]:
    """Every case of a run, seeded: the same arguments give the same cases."""
    specs = []
    for gi, g in enumerate(GENERATORS):
        if g not in generators:
            continue
        for lv in levels:
            seed0 = 100000 * (gi + 1) + int(round(lv * 1e4)) * 100
            if quick:
                specs += [CaseSpec(g, seed0, lv, 'coulomb_friction', 'servo',
                                   3000 if g == 'independent' else None,
                                   0.0 if exact_rm else r_m_error(seed0)),
                          CaseSpec(g, seed0 + 1, lv, 'none', 'industrial',
                                   2000 if g == 'independent' else None,
                                   0.0 if exact_rm else r_m_error(seed0 + 1))]
            else:
                specs += plan(g, lv, cases or DEFAULT_CASES, seed0, exact_rm=exact_rm)
    return specs
