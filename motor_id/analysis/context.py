"""What the analysis knows about one record before it fits a candidate.

The held-out split, the candidate fitter, the measurement grids found in the values
and the evidence the record gives by itself (the electrical equation, steps the speed
answers at once, one direction of motion, static offsets in the steady states). The
candidate search (:mod:`.search`) and the report assembly (:mod:`.assembly`) read it;
the analysis (:mod:`.analyzer`) builds it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from motor_id.analysis.candidates import CandidateFitter
    from motor_id.analysis.heldout import HeldOutSplit
    from motor_id.analysis.inverse_dynamics import ElectricalEvidence
    from motor_id.analysis.measurement import LatticeEvidence, MeasurementEffect
    from motor_id.identify.result import Resistance
    from motor_id.recording import Recording


@dataclass
class RecordContext:
    """One record as the candidate search and the report see it.

    Attributes
    ----------
    rec : Recording
    split : HeldOutSplit
        Training and held-out samples, noise floors, the error measures.
    fitter : CandidateFitter
        Fits the linear model and each candidate on the training blocks.
    measurement : list of MeasurementEffect
        Measurement effects (value grids) found in the values themselves.
    measurement_evidence : dict of LatticeEvidence
        The evidence of every measurement channel (grid found or not).
    electrical : ElectricalEvidence or None
        The electrical equation's evidence (voltage plants with the current measured).
    at_once : bool
        The speed answers input steps within one sample (no delay of 2 or more).
    one_way : bool
        The speed kept one sign.
    steady : (float, float) or None
        Zero-speed inputs of the steady-state map that point to a static offset.
    offsets_alike : bool
        The record cannot tell apart the effects that show a static offset
        (:func:`.selection.offsets_alike`).
    resistance : Resistance or None
        The linear fit's resistance block (with the current measured).
    """

    rec: Recording
    split: HeldOutSplit
    fitter: CandidateFitter
    measurement: list[MeasurementEffect]
    measurement_evidence: dict[str, LatticeEvidence]
    electrical: ElectricalEvidence | None
    at_once: bool
    one_way: bool
    steady: tuple[float, float] | None
    offsets_alike: bool = False
    resistance: Resistance | None = None
