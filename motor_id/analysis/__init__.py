"""Discrepancy analysis: which named effect the linear DC-motor model misses, and the gain."""

from motor_id.analysis.analyzer import CANDIDATES, DiscrepancyAnalysis
from motor_id.analysis.diagnostics import map_summary, steady_state_map
from motor_id.analysis.heldout import binned_means, heldout_mask
from motor_id.analysis.inverse_dynamics import electrical_evidence, inverse_dynamics
from motor_id.analysis.measurement import lattice_evidence
from motor_id.analysis.report import DiscrepancyReport, ModelScore, plot_report
from motor_id.metrics import noise_floor

__all__ = ['CANDIDATES', 'DiscrepancyAnalysis', 'DiscrepancyReport', 'ModelScore',
           'binned_means', 'electrical_evidence', 'heldout_mask', 'inverse_dynamics',
           'lattice_evidence', 'map_summary', 'noise_floor', 'plot_report',
           'steady_state_map']
