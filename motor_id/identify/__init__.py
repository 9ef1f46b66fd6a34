"""Identification of the motor parameters: the problem, the estimator, its uncertainty.

Methods
-------
``zoh`` (recommended)
    Exact zero-order-hold model, the paper's GA, then a bounded least-squares refinement
    from the GA's best individuals; every measured channel is used.
``euler``
    As ``zoh`` but with the paper's first-order discretisation (to show its bias).
``paper``
    The paper as published: Euler, GA only, speed channel only.

Modules: :mod:`.problem` (what is minimised: :class:`IdentificationProblem`), :mod:`.space`
(its free parameters, bounds and search coordinates), :mod:`.estimator`
(:class:`Identifier`: GA + refinement), :mod:`.settings` (:class:`FitSettings`, validated
once, and the one R_m check), :mod:`.uncertainty` (covariance, identifiability,
bootstrap), :mod:`.result` (:class:`Estimate`, :class:`IdentificationResult`),
:mod:`.parsing` (``--fix`` / ``--bounds`` items).
"""

from motor_id.identify.estimator import Identifier
from motor_id.identify.parsing import parse_bounds, parse_fixed
from motor_id.identify.problem import IdentificationProblem, METHODS
from motor_id.identify.result import Estimate, IdentificationResult
from motor_id.identify.settings import FitSettings, require_resistance
from motor_id.identify.space import DEFAULT_BOUNDS, TORQUE_BOUNDS, TORQUE_FREE, VOLTAGE_FREE

__all__ = ['DEFAULT_BOUNDS', 'Estimate', 'FitSettings', 'IdentificationProblem',
           'IdentificationResult', 'Identifier', 'METHODS', 'parse_bounds', 'parse_fixed',
           'require_resistance', 'TORQUE_BOUNDS', 'TORQUE_FREE', 'VOLTAGE_FREE']
