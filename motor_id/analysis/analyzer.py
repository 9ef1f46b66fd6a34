"""The discrepancy analysis: what the linear model misses, which named effect explains it.

Steps (each in its own module): measurement grids from the values themselves
(:mod:`.measurement`); the held-out split (:mod:`.heldout`); the linear model and, with
the current measured, the resistance profile (here); every dynamic candidate of
:data:`motor_id.effects.EFFECTS` alone (:mod:`.candidates`), then the verdict, a second
effect only when it beats the best one-effect model on held-out data, ambiguity
(:mod:`.search`, :mod:`.selection`; the fits of a step on :mod:`.workers`); final fits,
diagnostics and the inverse-dynamics estimate (:mod:`.assembly`, :mod:`.outcome`,
:mod:`.inverse_dynamics`); the report (:mod:`.report`); with a measured position, the
simulation-error stage (:mod:`.simulation_fit`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import contextlib
import time
from typing import Any, cast, TYPE_CHECKING

import numpy as np

from motor_id.analysis import selection
from motor_id.analysis.assembly import build_report, chosen_by_stage, EXPLAINS, NO_EFFECT
from motor_id.analysis.candidates import CandidateFitter
from motor_id.analysis.context import RecordContext
from motor_id.analysis.diagnostics import map_summary, steady_state_map
from motor_id.analysis.heldout import HeldOutSplit
from motor_id.analysis.inverse_dynamics import electrical_evidence, ElectricalEvidence
from motor_id.analysis.measurement import find_measurement_effects
from motor_id.analysis.search import CandidateSearch
from motor_id.analysis.simulation_fit import simulation_stage
from motor_id.analysis.workers import FitPool
from motor_id.effects import count_reading, EFFECTS
from motor_id.errors import (
    ConfigError,
    DataError,
    FIT_ERRORS,
    IdentificationError,
    MotorIdError,
)
from motor_id.identify.determinacy import ADEQUATE_FIT
from motor_id.identify.mechanism import check_mechanism
from motor_id.identify.scales import data_scales, default_max_delay
from motor_id.identify.settings import require_resistance
from motor_id.identify.space import resistance_enters, SPEED_ONLY_R_M
from motor_id.identify.validation import RunScore, SavedModel, validate
from motor_id.metrics import noise_floor

if TYPE_CHECKING:
    from motor_id.analysis.report import DiscrepancyReport, ModelScore
    from motor_id.analysis.simulation_result import SimulationStage
    from motor_id.recording import Recording

CANDIDATES = tuple(e for e, spec in EFFECTS.items()
                   if not spec.extends and not spec.simulation_only and not spec.mechanism)
"""Candidate effects, in catalogue order (the more common first); a mechanism's gravity is
never one (it is in the base model of a record of that mechanism)."""


class DiscrepancyAnalysis:
    """Find the named effect that the linear model misses.

    Parameters
    ----------
    R_m : float, optional
        Known armature resistance [Ohm] (voltage plants). With the current measured
        every fit estimates it under the prior N(R_m, (R_m_tolerance R_m)^2)
        (:class:`motor_id.identify.Identifier`), so an ohmmeter's error is not taken
        for heating, a brush drop or a dead zone.
    candidates : sequence of str, optional
        Effects to try; default every effect of the catalogue that applies.
    random_state : int or None
        Seed of the base model's GA.
    min_gain : float
        Smallest held-out gain (relative cut of the held-out error) that counts.
    ambiguity : float
        Candidates whose held-out error is within this fraction of the winner's are
        reported as indistinguishable.
    max_effects : int
        Largest number of dynamic effects combined.
    structure_ratio : float
        Held-out error above this multiple of the noise floor counts as unexplained.
    n_blocks : int
        Number of blocks of the held-out split.
    max_delay : int, optional
        Largest input delay tried [samples]; default min(40, N / 25).
    generations : int
        GA generations of the base fit (100: its best cost settles by generation 40-60
        on the records tried, and the refinement from its three best starts follows).
    pool_size : int
        Second effects are tried from this many best single effects.
    starts : int
        Distinct grid points each candidate's refinement starts from.
    R_m_tolerance : float
        Relative standard deviation of the prior on R_m (with the current measured).
    init_samples : int
        With a measured position, the model is also fitted and its refinements chosen by
        simulation error (:mod:`.simulation_fit`), each block simulated from a state set
        by its first ``init_samples`` samples; 0 skips that stage.
    jobs : int
        Processes the candidate fits of each step run on (:class:`.workers.FitPool`:
        forked workers, the same results); 1 fits in this process, as a caller with
        threads of its own (a ROS node) must.
    mechanism : {'simple', 'elevator', 'arm'}
        What the joint moves (:data:`motor_id.effects.MECHANISMS`): an elevator's or an
        arm's gravity is in the base model, fitted with it from the start (never a
        candidate, never rejected); an effect it excludes (a constant load, for an
        elevator) is not tried. An arm needs the measured position.

    Examples
    --------
    A motor with dry friction (T_c = 0.1 N m), 10 s of voltage steps both ways; only
    friction is tried here, to keep the example quick:

    >>> import numpy as np
    >>> from motor_id import DiscrepancyAnalysis
    >>> from motor_id.excitation import bipolar_steps
    >>> from motor_id.model import Plant
    >>> from motor_id.simulate import simulate_recording
    >>> from motor_id.testing.recordings import SI_MOTOR
    >>> t = np.arange(1000) * 0.01
    >>> plant = Plant(SI_MOTOR, 'voltage', {'coulomb_friction': {'T_c': 0.1}})
    >>> rec = simulate_recording(plant, t, bipolar_steps(t), 0.005, 0.01, random_state=2)
    >>> analysis = DiscrepancyAnalysis(R_m=2.3, candidates=['coulomb_friction'])
    >>> report = analysis.fit(rec).report_
    >>> report.verdict, report.adequate
    ('coulomb_friction', True)
    >>> round(report.parameters['coulomb_friction.T_c']['value'], 2)
    0.1
    """

    def __init__(self, R_m: float | None = None, candidates: Sequence[str] | None = None,
                 random_state: int | None = 0, min_gain: float = 0.05,
                 ambiguity: float = 0.03, max_effects: int = 3, structure_ratio: float = 1.5,
                 n_blocks: int = 10, max_delay: int | None = None, generations: int = 100,
                 pool_size: int = 4, starts: int = 2, R_m_tolerance: float = 0.10,
                 init_samples: int = 20, jobs: int = 1, mechanism: str = 'simple') -> None:
        self.R_m = R_m
        self.candidates = candidates
        self.random_state = random_state
        self.min_gain = min_gain
        self.ambiguity = ambiguity
        self.max_effects = max_effects
        self.structure_ratio = structure_ratio
        self.n_blocks = n_blocks
        self.max_delay = max_delay
        self.generations = generations
        self.pool_size = pool_size
        self.starts = starts
        self.R_m_tolerance = R_m_tolerance
        self.init_samples = init_samples
        self.jobs = jobs
        self.mechanism = mechanism

    def fit(self, rec: Recording, progress: Callable[[str], object] | None = None
            ) -> DiscrepancyAnalysis:
        """Run the analysis.

        Parameters
        ----------
        rec : Recording
        progress : callable, optional
            ``progress(message)`` for each step (the CLI prints them to stderr).

        Returns
        -------
        self
            With ``report_`` (:class:`DiscrepancyReport`).
        """
        with _single_blas_thread(), np.errstate(all='ignore'):
            return self._fit(rec, progress)

    # ------------------------------------------------------------------ steps
    def _say(self, msg: str) -> None:
        if self._progress is not None:
            self._progress(msg)

    def _resistance(self, rec: Recording) -> float | None:
        """The R_m the fits are given: the given one, or where the record cannot see it
        (speed-only voltage data) none, so that the fits use
        :data:`~motor_id.identify.space.SPEED_ONLY_R_M` and no output depends on it."""
        if rec.input_kind == 'voltage' and not resistance_enters('voltage', rec.has_current):
            return None   # the fits then use SPEED_ONLY_R_M
        return self.R_m

    def _check(self, rec: Recording) -> list[str]:
        rec.validate()  # also rejects corrupt cells (1e300) whose squares would overflow
        require_resistance(self.R_m, rec.input_kind, rec.has_current)
        if len(rec) < 10 * self.n_blocks:
            raise DataError(f'too few samples for a held-out analysis: {len(rec)} '
                            f'(need at least {10 * self.n_blocks})')
        names = self.candidates if self.candidates is not None else CANDIDATES
        for n in names:
            if n not in EFFECTS:
                raise ConfigError(f'unknown candidate effect {n!r}; known: {sorted(EFFECTS)}')
        gravity = check_mechanism(rec, self.mechanism)
        excluded = set(EFFECTS[gravity].excludes) | {gravity} if gravity else set()
        return [n for n in names if rec.input_kind in EFFECTS[n].kinds and n not in excluded
                and not EFFECTS[n].mechanism]

    def _setup(self, rec: Recording, names: Sequence[str]) -> RecordContext:
        meas, meas_evidence = find_measurement_effects(rec)
        meas = [m for m in meas if m.name in names]
        quant = {m.evidence.channel: (m.q, m.evidence.offset) for m in meas}
        for m in meas:
            self._say(f'  {m.name}: values on a grid of {m.q:.5g} (coherence '
                      f'{m.evidence.coherence:.3f}, p = {m.evidence.p_value:.2g})')
        split = HeldOutSplit(rec, self.n_blocks, quant)
        electrical: ElectricalEvidence | None = None
        if rec.input_kind == 'voltage' and rec.has_current:
            try:
                electrical = electrical_evidence(rec)
            except FIT_ERRORS as exc:
                electrical = ElectricalEvidence(failed=str(exc))
        max_delay = self.max_delay if self.max_delay is not None else \
            default_max_delay(len(rec))
        fitter = CandidateFitter(rec, split, self._resistance(rec), self.random_state,
                                 self.starts, max_delay, self.R_m_tolerance, self.mechanism)
        steady = selection.steady_offset(map_summary(steady_state_map(rec)))
        return RecordContext(
            rec=rec, split=split, fitter=fitter, measurement=meas,
            measurement_evidence=meas_evidence, electrical=electrical,
            at_once=selection.responds_at_once(rec, noise_floor(rec.speed)),
            one_way=selection.one_direction(rec), steady=steady,
            offsets_alike=selection.offsets_alike(rec, noise_floor(rec.speed), steady))

    def _linear(self, ctx: RecordContext, search: CandidateSearch) -> ModelScore:
        rec = ctx.rec
        self._say(f'fitting the linear model ({len(rec)} samples, '
                  f'{100 * np.mean(ctx.split.test):.0f} % held out)')
        f = ctx.fitter
        try:
            base = f.fit_linear(self.generations)
        except FIT_ERRORS as exc:
            raise IdentificationError(f'the linear model cannot be fitted: {exc}') from None
        if base.failed:
            raise IdentificationError(f'the linear model cannot be fitted: {base.failed}')
        base = self._speed_reading(ctx, base)
        ctx.resistance = f.resistance
        counted = any(m.name in count_reading() for m in ctx.measurement)
        given = f.settings.R_m
        r_m = given if given is not None else base.physical.get('R_m', SPEED_ONLY_R_M)
        f.scales = data_scales(rec, base.physical, r_m, float(rec.time[-1] - rec.time[0]),
                               float(np.median(np.diff(rec.time))), f.max_delay, counted)
        if ctx.electrical:
            f.extra_starts = dict(ctx.electrical.start)
        base.significant = False
        # a grid that cannot rank its points gets spread starts only when the linear
        # model leaves structure to explain (on a clean record they cost time for nothing)
        f.spread = search.structure(base)
        self._say(f'  held-out error {base.heldout_error:.4g} '
                  f'(noise floor {ctx.split.floor:.4g})')
        return base

    def _speed_reading(self, ctx: RecordContext, base: ModelScore) -> ModelScore:
        """Speed on an encoder grid: read at the samples, or a count difference?

        A count difference is the mean speed over the sample period (half a period
        behind the sampled speed, and smoothed); a quantised speed sensor reads the
        speed at the sample. The linear model is fitted both ways and the reading with
        the lower held-out error holds for every model of the analysis (an unmodelled
        reading would otherwise be credited to a dynamic effect).
        """
        grid = next((m for m in ctx.measurement if m.name in count_reading()), None)
        if grid is None:
            return base
        f = ctx.fitter
        kept = (f.resistance, f.linear_estimator, f.physical_bounds)
        f.reading = count_reading()
        counted: ModelScore | None
        try:
            counted = f.fit_linear(self.generations)
        except FIT_ERRORS as exc:
            counted = None
            self._say(f'  the speed as a count difference cannot be fitted ({exc})')
        better = counted is not None and not counted.failed and \
            counted.heldout_error < base.heldout_error
        grid.extra['counted'] = 1.0 if better else 0.0
        grid.extra['reading_heldout_error'] = {
            'sampled': base.heldout_error,
            'count difference': counted.heldout_error if counted is not None else None}
        self._say('  speed reading: ' + (
            'a count difference (the mean over each sample period)' if better else
            'sampled at the sample instants') + f' (held-out error {base.heldout_error:.4g}'
            ' sampled, ' + (f'{counted.heldout_error:.4g}' if counted is not None else '-')
            + ' counted)')
        if better:
            return cast('ModelScore', counted)
        f.reading = {}
        f.resistance, f.linear_estimator, f.physical_bounds = kept
        return base

    def _fit(self, rec: Recording, progress: Callable[[str], object] | None
             ) -> DiscrepancyAnalysis:
        t_start = time.perf_counter()
        self._progress = progress
        names = self._check(rec)
        ctx = self._setup(rec, names)
        with FitPool(ctx.fitter, self.jobs) as fits:
            search = CandidateSearch(
                ctx, fits, CANDIDATES, [n for n in names if EFFECTS[n].category == 'dynamic'],
                self._say, min_gain=self.min_gain, ambiguity=self.ambiguity,
                max_effects=self.max_effects, structure_ratio=self.structure_ratio,
                pool_size=self.pool_size)
            base = self._linear(ctx, search)
            singles = search.singles(base)
            chosen, ranked = search.select(base, singles)
        self.report_ = build_report(ctx, base, chosen, ranked, self._say,
                                    n_blocks=self.n_blocks, min_gain=self.min_gain,
                                    ambiguity=self.ambiguity,
                                    unexplained=search.structure(chosen))
        self.report_.mechanism = self.mechanism
        # by simulation error where a position is measured, and on a SysId log with
        # none (its users need kS, kV and kA, which speed alone determines)
        if (rec.has_position or 'sysid' in rec.meta) and self.init_samples:
            model = SavedModel.from_report(self.report_.to_dict(), use_simulation=False)
            self.report_.simulation = simulation_stage(
                rec, model, self.init_samples, min_gain=self.min_gain, progress=self._say,
                jobs=self.jobs)
            self.report_.verdict = _late_starts(self.report_.verdict,
                                                self.report_.simulation)
            _stage_warnings(self.report_, self.report_.simulation)
            self.report_.chosen = chosen_by_stage(self.report_.chosen,
                                                  self.report_.simulation)
        self.report_.runs = _run_scores(self.report_, rec)
        if rec.input_kind == 'voltage' and not resistance_enters('voltage', rec.has_current):
            self.report_.resistance = str(self.report_.parameters['R_m'].get('reason')) + (
                '' if self.R_m is None else f'; the given {self.R_m:g} Ohm is not used')
        self.report_.seconds = time.perf_counter() - t_start
        return self


def _late_starts(verdict: str, sim: SimulationStage) -> str:
    """The verdict with its input delay named a start latency where the simulation
    stage found that only the starts are late (:func:`.simulation_fit.simulation_stage`
    swapped the delay for the latency: the equation-error stage has no latency)."""
    effects = sim.model.effects if sim.model is not None else {}
    if 'start_latency' in effects and 'input_delay' not in effects:
        return '+'.join('start_latency' if n == 'input_delay' else n
                        for n in verdict.split('+'))
    return verdict


def _stage_warnings(report: DiscrepancyReport, sim: SimulationStage) -> None:
    """What the simulation-error stage says of the report (in place): a stage with no
    sound model makes it inadequate (no feedforward constants, and why); a stage that
    left the analysis' model for a simpler one says so; and the report's adequacy is
    that of the model it presents, the stage's (:func:`_stage_adequacy`)."""
    if sim.failed:
        why = f'the simulation-error stage found no model: {sim.failed}'
        report.warnings.insert(0 if report.adequate else len(report.warnings), why)
        report.adequate = False
        return
    if sim.fallback:
        report.warnings.append(f'simulation error: {sim.fallback}')
    _stage_adequacy(report, sim)


def _stage_adequacy(report: DiscrepancyReport, sim: SimulationStage) -> None:
    """Judge the report (in place) on the simulation-error model, the one its feedforward
    constants and validation come from: on its held-out blocks it must explain
    :data:`~motor_id.identify.determinacy.ADEQUATE_FIT` % of the speed, simulated from
    each block's start.

    The equation-error stage's verdict on the same record can differ: its held-out fit
    is of a model without the stage's effects, and of the speed's sample-to-sample
    course, which white speed noise dominates (the 2023 Miami drivetrain's SysId log:
    25.5 and 48.8 % there, its wheels slipping; the stage's two masses 93.8 and 93.5 %).
    Where the stage's model is adequate and that one was not, the equation-error
    parameters stay not determined and the warning says which model is which."""
    fit = sim.heldout_fit.get('speed')
    if fit is None or not np.isfinite(fit):
        return
    told = (f'the simulation-error model ({sim.chosen}) explains {fit:.1f} % of the '
            'speed on the held-out blocks, simulated from the start of each')
    if not report.adequate and fit >= ADEQUATE_FIT and report.warnings \
            and report.warnings[0].startswith(EXPLAINS):
        report.adequate = True
        report.warnings[0] = (report.warnings[0].replace(EXPLAINS, 'the equation-error '
                                                         'model explains (held out)')
                              .replace(NO_EFFECT, told + ', and is the model reported'))
    elif report.adequate and fit < ADEQUATE_FIT:
        report.adequate = False
        report.warnings.insert(0, f'{told} (an adequate model explains at least '
                               f'{ADEQUATE_FIT:.0f} %): its feedforward constants do not '
                               f'describe the record; {NO_EFFECT}')


def _run_scores(report: DiscrepancyReport, rec: Recording) -> tuple[RunScore, ...]:
    """The reported model simulated on each run of the record, as ``motor-id validate``
    scores it (nothing where it cannot be simulated: the report says so elsewhere)."""
    try:
        return validate(SavedModel.from_report(report.to_dict()), rec).runs
    except MotorIdError:
        return ()


def _single_blas_thread() -> contextlib.AbstractContextManager[Any]:
    """Limit BLAS to one thread: the analysis does many small solves, where threads only
    contend (a no-op without threadpoolctl)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return contextlib.nullcontext()
    return threadpool_limits(1)
