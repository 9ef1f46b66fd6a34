"""motor_id: identify a DC motor's physical parameters from voltage, speed and current.

The few names a user needs, each with an example in its docstring:

- load a recording: :func:`load_recording` (CSV, rosbag2, SysId log) into a
  :class:`Recording`;
- fit: :class:`Identifier` (``Identifier(R_m=2.3).fit(rec).result_``, an
  :class:`IdentificationResult`; its settings are one validated :class:`FitSettings`),
  or :func:`fit_report` for the full :class:`FitReport` (the fit, the data and the
  controller block: kS, kV, kA, loop gains);
- analyze: :class:`DiscrepancyAnalysis` (``.fit(rec).report_``, a
  :class:`DiscrepancyReport`): which named effect the linear model misses;
- validate: :func:`validate` a :class:`SavedModel` on another recording
  (a :class:`Validation`);
- the errors: :class:`MotorIdError` and its children.

Importing the package is cheap: the names load on first use (PEP 562), and the package
sets no environment variable (the command line and the nodes limit BLAS threads:
:mod:`motor_id.blas`).

Examples
--------
>>> import motor_id
>>> 'Identifier' in motor_id.__all__
True
>>> issubclass(motor_id.DataError, motor_id.MotorIdError)
True
"""

from __future__ import annotations

import importlib
from typing import Any, TYPE_CHECKING

from motor_id.errors import (
    BagError,
    ConfigError,
    DataError,
    IdentificationError,
    MotorIdError,
    ProtocolError,
)

if TYPE_CHECKING:
    from motor_id.analysis.analyzer import DiscrepancyAnalysis
    from motor_id.analysis.report import DiscrepancyReport
    from motor_id.data.load import load_recording
    from motor_id.identify.estimator import Identifier
    from motor_id.identify.result import IdentificationResult
    from motor_id.identify.settings import FitSettings
    from motor_id.identify.validation import SavedModel, validate, Validation
    from motor_id.pipeline import fit_report, FitReport
    from motor_id.recording import Recording

__version__ = '0.1.0'

_LAZY = {
    'load_recording': 'motor_id.data.load',
    'Recording': 'motor_id.recording',
    'Identifier': 'motor_id.identify.estimator',
    'IdentificationResult': 'motor_id.identify.result',
    'FitSettings': 'motor_id.identify.settings',
    'fit_report': 'motor_id.pipeline',
    'FitReport': 'motor_id.pipeline',
    'DiscrepancyAnalysis': 'motor_id.analysis.analyzer',
    'DiscrepancyReport': 'motor_id.analysis.report',
    'SavedModel': 'motor_id.identify.validation',
    'validate': 'motor_id.identify.validation',
    'Validation': 'motor_id.identify.validation',
}
"""Public name -> the module it lives in, imported on first use."""

__all__ = [
    'BagError', 'ConfigError', 'DataError', 'DiscrepancyAnalysis', 'DiscrepancyReport',
    'fit_report', 'FitReport', 'FitSettings', 'IdentificationError', 'IdentificationResult',
    'Identifier', 'load_recording', 'MotorIdError', 'ProtocolError', 'Recording', 'SavedModel',
    'validate', 'Validation',
]


def __getattr__(name: str) -> Any:
    """Import a public name's module on first use (PEP 562)."""
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
