"""Results of the simulation-error stage: the candidates, the estimates, the stage.

:func:`.simulation_fit.simulation_stage` returns a :class:`SimulationStage`;
:mod:`.simulation_uncertainty` gives its :class:`StageEstimates`. ``to_dict`` writes the
report's ``simulation`` block.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import TYPE_CHECKING

from motor_id.records import finite, omit_if_failed, optional, Record, written

if TYPE_CHECKING:
    from motor_id.analysis.frames import FrameEvidence

STAGE_METHOD = ('least squares on the simulation error of each block, simulated from the '
                'input alone from a state set by its first samples')
ESTIMATES_METHOD = ('the largest of the Gauss-Newton, the block-sandwich and the halves '
                    'standard deviations (halves: |a - b| / 2 of the refits on each half '
                    'of the blocks)')


@dataclass(kw_only=True)
class SimCandidate(Record):
    """One model fitted on simulation error (refined in place while the stage runs)."""

    name: str
    parameters: dict[str, float] = field(default_factory=dict)
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    train_rmse: dict[str, float] = field(default_factory=dict)
    heldout_rmse: dict[str, float] = field(default_factory=dict)
    heldout_cost: float = written(finite, math.inf)
    nfev: int = 0
    failed: str = optional('', when='empty')
    polished_from: str = optional('', when='empty')
    """A larger candidate this one was refitted from (:func:`._polish`), if any."""
    start: str = optional('', when='empty')
    """Where its fit started when not from the analysis' model (its winding and its
    mechanics exchanged: :func:`.simulation_fit._poles_swapped`)."""

    @property
    def scored(self) -> bool:
        """Fitted, with a finite held-out cost."""
        return not self.failed and math.isfinite(self.heldout_cost)


@dataclass(frozen=True, kw_only=True)
class ParameterEstimate(Record):
    """A free parameter of the stage's model (SI; effect parameters as ``effect.param``):
    its value, error bar (None when not determined), the Gauss-Newton/sandwich part of
    it, the two halves' values and why it is not determined."""

    value: float
    std: float | None
    std_model: float | None
    determined: bool
    halves: tuple[float, float] | None = optional()
    note: str = optional('', when='empty')


@dataclass(frozen=True, kw_only=True)
class DerivedEstimate(Record):
    """A quantity of the model (a SysId constant, friction by direction) with its
    delta-method error bar floored by the halves' spread; one not determined has the
    ``interval`` of two error bars and a ``note``."""

    name: str
    value: float
    std_model: float
    determined: bool
    halves: tuple[float, float] | None = optional()
    std: float
    std_delay: float | None = optional()
    """The part of ``std`` from a whole-sample delay (in quadrature; see
    :mod:`.simulation_uncertainty`), where the model has one."""
    interval: tuple[float, float] | None = optional()
    note: str = optional('', when='empty')


@dataclass(frozen=True, kw_only=True)
class StageEstimates(Record):
    """Values, error bars and determinacy of the stage's chosen model
    (:func:`.simulation_uncertainty.stage_estimates`), or why there are none."""

    method: str = optional('', when='empty')
    parameters: dict[str, ParameterEstimate] | None = optional()
    combinations: tuple[DerivedEstimate, ...] | None = optional()
    """WPILib SysId's constants (a voltage plant; None for a torque plant)."""
    friction: tuple[DerivedEstimate, ...] = optional((), when='empty')
    failed: str = optional('', when='empty')


@dataclass(frozen=True, kw_only=True)
class StageModel(Record):
    """The chosen model refitted on every block (SI), as ``motor-id validate`` reads it
    (:meth:`motor_id.identify.validation.SavedModel.from_report`)."""

    input_kind: str
    parameters: dict[str, float]
    effects: dict[str, dict[str, float]]


@dataclass(frozen=True, kw_only=True)
class SimulationStage(Record):
    """The simulation-error stage (:func:`.simulation_fit.simulation_stage`).

    ``candidates`` were each fitted on the training blocks and scored on the held-out
    ones; ``model`` is the chosen one refitted on every block, ``estimates`` its error
    bars, ``rmse`` its RMSE on every block, ``gains`` the share of the held-out error
    each of its effects removes. A stage that fitted nothing sound has ``failed`` and no
    ``chosen`` model; ``fallback`` says why it left the analysis' model, where it did.
    """

    method: str = STAGE_METHOD
    channels: tuple[str, ...]
    init_samples: int
    blocks: tuple[tuple[int, int], ...]
    heldout_blocks: tuple[tuple[int, int], ...]
    min_gain: float
    held_readings: dict[str, FrameEvidence]
    candidates: tuple[SimCandidate, ...]
    chosen: str | None = None
    gains: dict[str, float] = optional({}, when=omit_if_failed)
    model: StageModel | None = None
    estimates: StageEstimates | None = optional(None, when=omit_if_failed)
    friction: dict[str, float] | None = optional(None, when=omit_if_failed)
    rmse: dict[str, float] = optional({}, when=omit_if_failed)
    heldout_fit: dict[str, float] = optional({}, when='empty')
    """The chosen model as fitted on the training blocks, simulated on the held-out ones:
    its normalised fit % per channel (what the report's adequacy is judged on)."""
    failed: str = optional('', when='empty')
    fallback: str = optional('', when='empty')
    """Why the stage searched from the model without the analysis' extra effects
    (:func:`.simulation_guard.reduced_model`), where it did."""
