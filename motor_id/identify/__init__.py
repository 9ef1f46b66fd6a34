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

Modules: :mod:`.problem` (what is minimised: :class:`IdentificationProblem`),
:mod:`.estimator` (:class:`Identifier`: GA + refinement), :mod:`.uncertainty`
(covariance, identifiability, bootstrap), :mod:`.result` (:class:`Estimate`,
:class:`IdentificationResult`), :mod:`.parsing` (``--fix`` / ``--bounds`` items).
"""

from motor_id.identify.estimator import Identifier
from motor_id.identify.parsing import parse_bounds, parse_fixed
from motor_id.identify.problem import (
                                       DEFAULT_BOUNDS,
                                       IdentificationProblem,
                                       METHODS,
                                       TORQUE_BOUNDS,
                                       TORQUE_FREE,
                                       VOLTAGE_FREE,
)
from motor_id.identify.result import Estimate, IdentificationResult

__all__ = ['DEFAULT_BOUNDS', 'Estimate', 'IdentificationProblem', 'IdentificationResult',
           'Identifier', 'METHODS', 'parse_bounds', 'parse_fixed', 'TORQUE_BOUNDS',
           'TORQUE_FREE', 'VOLTAGE_FREE']
