"""Results of the discrepancy analysis: scored models, the report, its summary and plots."""

from __future__ import annotations

from dataclasses import dataclass, field
import math
import os
from typing import Any, TYPE_CHECKING

from motor_id.analysis.feedforward import controller_block, ControllerBlock
from motor_id.contracts import units_of
from motor_id.identify.validation import run_lines, RunScore
from motor_id.output import attach_units
from motor_id.records import finite, optional, Record, written

if TYPE_CHECKING:
    from motor_id.analysis.diagnostics import ResidualBlock
    from motor_id.analysis.inverse_dynamics import InverseDynamicsFit
    from motor_id.analysis.measurement import LatticeEvidence
    from motor_id.analysis.selection import Ambiguity
    from motor_id.analysis.simulation_result import SimulationStage
    from motor_id.identify.result import Estimate, FitQuality, Resistance


def _without_components(_value: object, evidence: object) -> bool:
    return not getattr(evidence, 'components', None)


@dataclass(frozen=True, kw_only=True)
class DynamicEvidence(Record):
    """How a dynamic candidate did (a :class:`ModelScore`'s JSON ``evidence``): its
    errors, the held-out blocks it improved, its extra parameters and BIC change; for a
    combination each effect's gains (``components``) over its ``reference``."""

    kind: str = 'dynamic'
    heldout_error: float = written(finite)
    train_error: float = written(finite)
    heldout_blocks_improved: float
    extra_parameters: int
    delta_bic: float = written(finite)
    at_search_limit: list[str]
    implausible: str
    significant: bool
    seconds: float
    failed: str = optional('', when='empty')
    components: dict[str, dict[str, float]] = optional({}, when='empty')
    reference: str = optional('linear', when=_without_components)
    gain_over_reference: float = optional(0.0, when=_without_components, json=finite)


@dataclass
class ModelScore:
    """One candidate model (one effect or a combination) and how it did.

    ``failed`` holds the reason when the fit could not produce a finite model (an
    exception, a diverging simulation); such a model is never significant.
    ``components`` (combinations) maps each effect to its own gain alone and its
    marginal gain on top of the others.
    """

    name: str
    effects: dict
    parameters: dict = field(default_factory=dict)
    gain: float = 0.0
    heldout_error: float = math.inf
    train_error: float = math.inf
    block_wins: float = 0.0
    n_extra: int = 0
    delta_bic: float = 0.0
    significant: bool = False
    at_bound: list = field(default_factory=list)
    implausible: str = ''
    failed: str = ''
    components: dict = field(default_factory=dict)
    reference: str = 'linear'
    gain_over_reference: float = 0.0
    physical: dict = field(default_factory=dict, repr=False)
    x0: dict = field(default_factory=dict, repr=False)
    prediction: dict = field(default_factory=dict, repr=False)
    seconds: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """The report's ``effects`` entry: name, parameters, gain, evidence."""
        ev = DynamicEvidence(
            heldout_error=self.heldout_error, train_error=self.train_error,
            heldout_blocks_improved=self.block_wins, extra_parameters=self.n_extra,
            delta_bic=self.delta_bic, at_search_limit=self.at_bound,
            implausible=self.implausible, significant=self.significant,
            seconds=self.seconds, failed=self.failed, components=self.components,
            reference=self.reference, gain_over_reference=self.gain_over_reference)
        return {'name': self.name, 'parameters': self.parameters,
                'gain': _finite(self.gain), 'evidence': ev.to_dict()}


def _finite(v: float | None) -> float | None:
    """None for a non-finite number (JSON has no inf)."""
    return float(v) if v is not None and math.isfinite(v) else None


def _estimates_json(params: dict[str, Estimate]) -> dict[str, object]:
    return {k: v.to_dict() for k, v in params.items()}


@dataclass(frozen=True, kw_only=True)
class Baseline(Record):
    """The linear model refitted on all data: its parameters, fit and held-out error."""

    parameters: dict[str, Estimate] = written(_estimates_json)
    fit: FitQuality
    heldout_error: float


@dataclass(frozen=True, kw_only=True)
class ChosenBlock(Record):
    """The chosen model: the one the report's feedforward (``controller``) and ``motor-id
    validate`` use. Its name (the linear one: ``'none'`` as the search names it,
    ``'linear'`` as the stage does), its estimator, its effects' values and its fit on
    all data (None for the linear model, where that fit failed, or for the simulation
    stage's model, whose fit per run is the report's ``runs``); for a
    closed-loop torque record whose headline is the inverse-dynamics estimate, the
    output-error parameters it replaced. Where the simulation stage chose the model
    (:func:`.assembly.chosen_by_stage`), ``equation_error`` holds the search's chosen
    model, whose values the report's ``parameters`` are."""

    name: str
    estimator: str
    effects: dict[str, dict[str, float]]
    fit: FitQuality | None
    output_error_parameters: dict[str, dict[str, Any]] | None = optional()
    equation_error: ChosenBlock | None = optional()

    @property
    def search(self) -> ChosenBlock:
        """The search's chosen model (the equation-error one): the report's
        ``parameters``, the fit on all data, the candidate of that name."""
        return self.equation_error or self


@dataclass(frozen=True, kw_only=True)
class HeldoutBlock(Record):
    """The held-out scheme and the errors on it (RMS over channel std)."""

    scheme: str
    by_run: bool
    fraction: float
    blocks: list[tuple[int, int]]
    base_error: float
    final_error: float
    noise_floor: float
    min_gain: float
    resistance: Resistance | None


@dataclass
class DiscrepancyReport:
    """The analysis result; :meth:`to_dict` is the ``--json`` shape.

    ``verdict`` names the chosen dynamic effects and then the measurement effects found,
    joined by ``+`` (``'none'`` when there are neither); ``effects`` lists the
    measurement effects first, then every dynamic model tried (chosen first). ``linear``:
    the record is of a linear axis (constants per metre). ``runs``: the chosen model
    simulated on each run of the record from its input alone (as ``motor-id validate``
    scores it), by name. ``resistance``: why R_m does not enter (speed-only voltage data),
    or None. Every constant of :meth:`to_dict` carries its ``unit``.
    """

    verdict: str
    effects: list
    unexplained: bool
    ambiguous_with: list[Ambiguity]
    parameters: dict
    baseline: Baseline
    chosen: ChosenBlock
    diagnostics: ResidualBlock
    heldout: HeldoutBlock
    input_kind: str
    channels: tuple
    measurement: dict[str, LatticeEvidence] = field(default_factory=dict)
    failed: list = field(default_factory=list)
    inverse_dynamics: InverseDynamicsFit | None = None
    plot_data: dict = field(default_factory=dict, repr=False)
    seconds: float = 0.0
    adequate: bool = True
    warnings: list = field(default_factory=list)
    simulation: SimulationStage | None = None
    linear: bool = False
    runs: tuple[RunScore, ...] = ()
    mechanism: str = 'simple'
    resistance: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (the documented keys first)."""
        d: dict[str, Any] = {'verdict': self.verdict, 'adequate': bool(self.adequate),
             'warnings': list(self.warnings),
             'effects': [e.to_dict() for e in self.effects],
             'unexplained': self.unexplained,
             'ambiguous_with': [a.to_dict() for a in self.ambiguous_with],
             'parameters': self.parameters,
             'baseline': self.baseline.to_dict(),
             'chosen': self.chosen.to_dict(),
             'measurement': {ch: ev.to_dict() for ch, ev in self.measurement.items()},
             'failed': self.failed,
             'diagnostics': self.diagnostics.to_dict(),
             'heldout': self.heldout.to_dict(),
             'input_kind': self.input_kind,
             'channels': list(self.channels),
             'seconds': self.seconds}
        if self.inverse_dynamics is not None:
            d['inverse_dynamics'] = self.inverse_dynamics.to_dict()
        if self.simulation is not None:
            d['simulation'] = self.simulation.to_dict()
        controller = self.controller()
        if controller is not None:
            d['controller'] = controller.to_dict()
        if self.runs:
            d['runs'] = [r.to_dict() for r in self.runs]
        if self.resistance:
            d['resistance'] = {'enters': False, 'note': self.resistance}
        return attach_units(d, self.input_kind, self.linear)

    def controller(self) -> ControllerBlock | None:
        """The ``controller`` block of the chosen model, of a voltage or a torque plant
        (:func:`.feedforward.controller_block`); None without that model."""
        return controller_block(self.simulation, self.input_kind, self.linear,
                                self.mechanism)

    def summary(self) -> str:
        """A readable report for people."""
        lines = _fit_lines(self) + _diagnostic_lines(self.diagnostics)
        lines += _measurement_lines(self) + _candidate_lines(self)
        lines += _parameter_lines(self) + _simulation_lines(self.simulation,
                                                            units_of(self.input_kind,
                                                                     self.linear))
        lines += run_lines(self.runs)
        if self.resistance:
            lines.append(f'R_m: {self.resistance}')
        if not self.adequate:
            lines.append('MODEL INADEQUATE: ' + self.warnings[0])
        for w in self.warnings[(0 if self.adequate else 1):]:
            lines.append('warning: ' + w)
        lines.append(f'analysis time {self.seconds:.2f} s')
        return '\n'.join(lines)


def _simulation_lines(sim: SimulationStage | None,
                      units: dict[str, str] | None = None) -> list[str]:
    """The simulation-error stage: held readings, each candidate's held-out RMSE, the
    chosen model's gains, and its estimates with their error bars."""
    if not sim:
        return []
    lines = [f'simulation error ({", ".join(sim.channels)}; each block from its first '
             f'{sim.init_samples} samples, or from rest), held-out RMSE:']
    for ch, ev in sim.held_readings.items():
        if ev.found:
            lines.append(f'  held readings on {ch}: {ev.reason}; scored at the fresh '
                         'samples only')
    for c in sim.candidates:
        err = '; '.join(x for x in (', '.join(f'{ch} {v:.4g}' for ch, v in
                                             c.heldout_rmse.items()), c.failed,
                                    c.start and f'from {c.start}') if x)
        mark = '*' if c.name == sim.chosen else ' '
        lines.append(f'  {mark} {c.name:<58} {err}')
    if sim.fallback:
        lines.append(f'  fell back: {sim.fallback}')
    if sim.gains:
        lines.append('  gains on the held-out blocks: ' + ', '.join(
            f'{k} {100 * v:.1f} %' for k, v in sim.gains.items()))
    est = sim.estimates
    if sim.model and est and est.parameters:
        lines.append(f'  chosen, {sim.chosen}, refitted on every block (error bars: the '
                     'largest of Gauss-Newton, block sandwich and halves):')
        for name, e in est.parameters.items():
            lines.append(f'    {name:<28} ' + (
                f'{e.value:.5g} +- {e.std:.3g}' if e.determined else
                f'{"-":>10}  not determined ({e.note})'))
        for title, derived in (('SysId constants: ', est.combinations),
                               ('friction by direction: ', est.friction)):
            if derived:
                lines.append('  ' + title + ', '.join(
                    f'{e.name} {e.value:.4g} +- {e.std:.2g}'
                    + (f' {(units or {})[e.name]}' if e.name in (units or {}) else '')
                    + ('' if e.determined else f' ({e.note})')
                    for e in derived))
    elif sim.model:
        vals = {**sim.model.parameters,
                **{f'{e}.{p}': v for e, d in sim.model.effects.items()
                   for p, v in d.items()}}
        lines.append(f'  chosen, {sim.chosen}, refitted on every block (no error bars: '
                     f'{(est.failed if est else "") or "not computed"}): ' + ', '.join(
                         f'{k} {v:.5g}' for k, v in vals.items()))
    return lines


def _fit_lines(rep: DiscrepancyReport) -> list[str]:
    h = rep.heldout
    lines = [f'linear model: held-out error {h.base_error:.4g} '
             f'(noise floor {h.noise_floor:.4g}; errors are RMS / channel std)']
    search = rep.chosen.search
    for ch, m in rep.baseline.fit.channels.items():
        after = ''
        if search.fit:
            after = (f' -> {search.fit.channels[ch].fit_percent:.2f} % '
                     f'with {search.name}')
        lines.append(f'  {ch} fit on all data: {m.fit_percent:.2f} %{after}')
    return lines


def _diagnostic_lines(diag: ResidualBlock) -> list[str]:
    lines: list[str] = []
    for ch, dd in diag.residual.items():
        lines.append(f'  {ch} residual: {100 * dd.autocorrelation_outside:.0f} % of '
                     f'autocorrelation lags and {100 * dd.cross_correlation_outside:.0f}'
                     f' % of input cross-correlation lags outside the 99 % band')
        top = sorted(diag.binned[ch].items(), key=lambda kv: -kv[1].explained)[:3]
        lines.append('    binned means explain ' + ', '.join(
            f'{k} {100 * v.explained:.0f} %' for k, v in top) + ' of its variance')
    ms = diag.steady_state
    if ms and ms.n_points:
        parts: list[str] = []
        for side, fit in (('positive', ms.positive), ('negative', ms.negative)):
            if fit is not None:
                z = fit.zero_speed_input
                parts.append(f'{side} side: speed = {fit.slope:.4g} u '
                             f'{fit.intercept:+.4g}' +
                             ('' if z is None else f' (zero at u = {z:.4g})'))
        lines.append(f'  steady-state map: {ms.n_points} plateau(s)' +
                     (('; ' + '; '.join(parts)) if parts else ''))
    el = diag.electrical
    if el and el.favoured:
        lines.append(f'  electrical equation error favours {el.favoured} among '
                     f'{", ".join(sorted(el.explained))}')
    return lines


def _measurement_lines(rep: DiscrepancyReport) -> list[str]:
    lines: list[str] = []
    for ch, ev in rep.measurement.items():
        if ev.found:
            lines.append(f'measurement: {ch} on a grid of {ev.q:.5g} (coherence '
                         f'{ev.coherence:.3f} over {ev.n_moving} moving samples, '
                         f'p = {ev.p_value:.2g})' + (f'; {ev.note}' if ev.note else ''))
        elif ev.q > 0 and ev.coherence >= 0.5:
            lines.append(f'measurement: {ch}: {ev.reason}')
    for e in rep.effects:
        if e.to_dict()['evidence']['kind'] == 'measurement' and 'counts_per_revolution' \
                in e.extra:
            lines.append(f'  implied encoder resolution: '
                         f'{e.extra["counts_per_revolution"]:.4g} counts per revolution')
        extra = getattr(e, 'extra', None) or {}
        errs = extra.get('reading_heldout_error')
        if errs:
            how = ('a count difference (the mean speed over each sample period)'
                   if extra.get('counted') else 'sampled at the sample instants')
            other = errs.get('count difference')
            lines.append(f'  speed reading: {how}; linear model held-out error '
                         f'{errs["sampled"]:.4g} sampled, '
                         + (f'{other:.4g}' if other is not None else '-') + ' counted')
    return lines


def _candidate_lines(rep: DiscrepancyReport) -> list[str]:
    lines = [f'{"candidate":<42}{"gain":>8}{"held-out":>11}  parameters']
    for e in rep.effects:
        d = e.to_dict()
        if d['evidence']['kind'] == 'measurement':
            continue
        pv = ', '.join(f'{k.split(".")[-1]}={v["value"]:.4g}'
                       for k, v in e.parameters.items() if v.get('value') is not None)
        if e.failed:
            lines.append(f'{e.name:<42}{"failed":>8}{"":>11}  {e.failed}')
            continue
        flag = '' if e.significant else '  (not significant)'
        lines.append(f'{e.name:<42}{100 * e.gain:>7.1f}%{e.heldout_error:>11.4g}  '
                     f'{pv}{flag}')
        for comp, g in e.components.items():
            lines.append(f'    {comp}: alone {100 * g["alone"]:.1f} %, on top of the '
                         f'rest {100 * g["marginal"]:.1f} %')
    lines.append(f'verdict: {rep.verdict}')
    for a in rep.ambiguous_with:
        gain = '' if a.gain is None else f' (gain {100 * a.gain:.1f} %)'
        lines.append(f'  cannot be told apart from {a.name} with this excitation'
                     f'{gain}; to separate them: {a.experiment}')
    h = rep.heldout
    ratio = h.final_error / h.noise_floor if h.noise_floor > 0 else float('inf')
    lines.append(f'unexplained structure: {"yes" if rep.unexplained else "no"} '
                 f'(held-out error {ratio:.2f} x noise floor)')
    return lines


def _parameter_lines(rep: DiscrepancyReport) -> list[str]:
    search = rep.chosen.search
    lines = [f'parameters under the chosen model ({search.estimator}):'
             if search is rep.chosen else
             f'parameters under the equation-error model, {search.name} '
             f'({search.estimator}); the chosen model, {rep.chosen.name}, is the '
             'simulation stage one (below):']
    for k, v in rep.parameters.items():
        if v.get('value') is None:
            lines.append(f'  {k:<24}{"-":>14}  not determined')
        else:
            std = '' if v.get('std') is None else f' +- {v["std"]:.3g}'
            lines.append(f'  {k:<24}{v["value"]:>14.6g}{std}')
    idm = rep.inverse_dynamics
    if idm and not idm.failed:
        lines.append(f'inverse dynamics (equation error, {idm.model}, filter '
                     f'{idm.cutoff:.3g} Hz): relative error '
                     f'{100 * idm.relative_error:.2f} %' +
                     ('' if idm.physical else
                      '; NOT physical (negative inertia or friction): the derivative '
                      'of this speed is too noisy or too coarsely sampled'))
        for k, v in idm.parameters.items():
            lines.append(f'  {k:<24}{v.value:>14.6g} +- {v.std:.3g}')
    return lines


def plot_report(report: DiscrepancyReport, path: str | os.PathLike[str],
                title: str | None = None) -> None:
    """Residuals before/after, the steady-state map and the gain per candidate, as PNG.

    Parameters
    ----------
    report : DiscrepancyReport
    path : str or Path
        PNG file to write.
    title : str, optional
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    pd = report.plot_data
    chans = list(pd['channels'])
    fig, axes = plt.subplots(2, 2, figsize=(13, 9), squeeze=False)
    for k, ch in enumerate(chans[:2]):
        _plot_residual(axes[0, k], report, k, ch)
    _plot_map(axes[0, 1] if len(chans) < 2 else axes[1, 1], report)
    _plot_gains(axes[1, 0], report)
    if len(chans) < 2:
        _plot_channel(axes[1, 1], report)
    fig.suptitle(title or 'motor_id discrepancy analysis')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_residual(ax: Any, report: DiscrepancyReport, k: int, ch: str) -> None:
    pd = report.plot_data
    t = pd['time']
    ax.plot(t, pd['ys'][k] - pd['base'][k], lw=0.7, label='linear model')
    search = report.chosen.search
    if search.name != 'none':
        ax.plot(t, pd['ys'][k] - pd['chosen'][k], lw=0.7, label=search.name)
    ylo, yhi = ax.get_ylim()
    ax.fill_between(t, ylo, yhi, where=pd['test'], color='0.9', zorder=0, label='held out')
    ax.set_ylim(ylo, yhi)
    ax.set_title(f'{ch} residual (measured - simulated)')
    ax.set_xlabel('time [s]')
    ax.legend(loc='best', fontsize=8)


def _plot_map(ax: Any, report: DiscrepancyReport) -> None:
    pts = report.plot_data['points']
    if pts:
        u = [p.input for p in pts]
        ax.plot(u, [p.speed for p in pts], 'o', label='measured plateaus')
        ax.plot(u, [p.speed_linear for p in pts], 'x', label='linear model')
        if pts[0].speed_chosen is not None:
            ax.plot(u, [p.speed_chosen for p in pts], '+', ms=10,
                    label=report.chosen.search.name)
        ax.legend(loc='best', fontsize=8)
    ax.set_title('steady-state map')
    units = units_of(report.input_kind, report.linear)
    ax.set_xlabel(f'input [{units["input"]}]')
    ax.set_ylabel(f'speed [{units["speed"]}]')


def _plot_gains(ax: Any, report: DiscrepancyReport) -> None:
    items = [e for e in report.effects if e.to_dict()['evidence']['kind'] == 'dynamic']
    items = [e for e in items if '+' not in e.name] + [e for e in items if '+' in e.name]
    gains = [0.0 if e.failed else 100 * e.gain for e in items]
    colors = ['tab:red' if e.failed else 'tab:blue' if e.name == report.chosen.search.name else
              'tab:green' if e.significant else 'tab:gray' for e in items]
    ax.barh(range(len(items)), gains, color=colors)
    ax.set_yticks(range(len(items)))
    ax.set_yticklabels([e.name for e in items], fontsize=7)
    ax.invert_yaxis()
    ax.axvline(100 * report.heldout.min_gain, color='k', ls='--', lw=0.8)
    ax.set_xlabel('held-out gain [%] (blue: chosen, green: significant, red: failed)')
    ax.set_title(f'gain per candidate; verdict: {report.verdict}')


def _plot_channel(ax: Any, report: DiscrepancyReport) -> None:
    pd = report.plot_data
    t = pd['time']
    ax.plot(t, pd['ys'][0], lw=0.8, color='k', label='measured')
    ax.plot(t, pd['base'][0], lw=0.8, label='linear model')
    if report.chosen.search.name != 'none':
        ax.plot(t, pd['chosen'][0], lw=0.8, ls='--', label=report.chosen.search.name)
    ax.set_title(f'{pd["channels"][0]}: measured and simulated')
    ax.set_xlabel('time [s]')
    ax.legend(loc='best', fontsize=8)
