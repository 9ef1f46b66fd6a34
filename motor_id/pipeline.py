"""One path from a recording to the full fit report: estimates, data, controller block.

The CLI (``motor-id fit``, ``replay --offline``) prints and writes a :class:`FitReport`;
the identifier node publishes one. Nothing else assembles fit reports, so the JSON, the
ROS parameters file and the node's parameters say the same thing.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
import math
from typing import Any

from motor_id.controller import from_identification, to_ros_parameters
from motor_id.errors import MotorIdError
from motor_id.identify import Identifier
from motor_id.identify.result import IdentificationResult
from motor_id.recording import Recording
from motor_id.report import attach_units, to_jsonable


def data_block(rec: Recording, **extra: Any) -> dict[str, Any]:
    """What the report says about the data it was fitted to."""
    out = {'source': rec.meta.get('source'), 'samples': len(rec),
           'sample_period': rec.sample_period, 'regular': rec.is_regular,
           'channels': list(rec.channels()), 'input_kind': rec.input_kind,
           'runs': len(rec.segment_ranges), 'linear': rec.linear}
    out.update(extra)
    return out


@dataclass
class FitReport:
    """A fit with everything a user gets from it.

    Attributes
    ----------
    result : IdentificationResult
    data : dict
        :func:`data_block` of the recording.
    controller : dict or None
        The controller design (``ControllerDesign.to_dict()``), None when there is none.
    controller_error : str or None
        Why there is no controller design.
    extra : dict
        Further top-level keys (a shift check, the bag, the hardware id, units).
    """

    result: IdentificationResult
    data: dict[str, Any]
    controller: dict[str, Any] | None = None
    controller_error: str | None = None
    controller_summary: str = ''
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def adequate(self) -> bool:
        """The model explains enough of the record (see :mod:`.identify.determinacy`)."""
        return bool(self.result.adequate)

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` shape (docs/user-guide.md): the fit, ``data``, ``controller``,
        extras; every constant with its ``unit`` (:func:`motor_id.report.attach_units`)."""
        d = self.result.to_dict()
        d['data'] = dict(self.data)
        if self.controller is not None:
            d['controller'] = self.controller
        elif self.controller_error is not None:
            d['controller'] = {'error': self.controller_error}
        d.update(self.extra)
        return attach_units(d, self.result.input_kind, bool(self.data.get('linear')))

    def to_ros_parameters(self, node_name: str = '/**', unknown: str = 'omit'
                          ) -> dict[str, Any]:
        """``{node: {'ros__parameters': {...}}}``: ``estimate.NAME``, ``estimate.NAME_std``
        and ``controller.*``.

        Parameters
        ----------
        node_name : str
        unknown : {'omit', 'nan'}
            What an unknown value becomes: left out (a parameters file: ROS parameters
            have no null) or NaN (a node's declared parameter that must always exist).
        """
        params: dict[str, float] = {}
        for name, p in self.result.to_dict()['parameters'].items():
            for key, v in ((name, p.get('value')), (f'{name}_std', p.get('std'))):
                if v is not None:
                    params[f'estimate.{key}'] = float(v)
                elif unknown == 'nan':
                    params[f'estimate.{key}'] = math.nan
        if self.controller is not None:
            flat = to_ros_parameters(self.controller, node_name)[node_name]
            params.update(flat['ros__parameters'])
        return {node_name: {'ros__parameters': params}}

    def summary(self) -> str:
        """The fit's table and the controller's, for people."""
        parts = [self.result.summary()]
        if self.controller_summary:
            parts.append(self.controller_summary)
        elif self.controller_error:
            parts.append(f'controller design not possible: {self.controller_error}')
        return '\n'.join(parts)


def controller_for(report: Mapping[str, Any], sample_period: float | None,
                   options: Mapping[str, Any] | None = None
                   ) -> tuple[dict[str, Any] | None, str | None, str]:
    """``(design dict, error, summary)`` of the controller design for a fit report."""
    kw = dict(options or {})
    if sample_period is not None:
        kw['sample_period'] = sample_period
    try:
        design = from_identification(to_jsonable(dict(report)), **kw)
    except MotorIdError as exc:  # the fit stands; say why there is no design
        return None, str(exc), ''
    return design.to_dict(), None, design.summary()


def fit_report(rec: Recording, identifier: Identifier, *,
             controller_options: Mapping[str, Any] | None = None,
             sample_period: float | None = None,
             progress: Callable[[int, int, float], bool | None] | None = None,
             data: Mapping[str, Any] | None = None,
             extra: Mapping[str, Any] | None = None) -> FitReport:
    """Fit ``rec`` and build the full report.

    Parameters
    ----------
    rec : Recording
    identifier : Identifier
        Its settings; it is fitted here (``identifier.result_`` afterwards).
    controller_options : dict, optional
        Keyword arguments of :func:`motor_id.controller.from_identification` (loop
        bandwidths).
    sample_period : float, optional
        The controller's sample period (default: the record's median period).
    progress : callable, optional
        Passed to :meth:`Identifier.fit`.
    data, extra : dict, optional
        More keys for the ``data`` block and the top level.

    Raises
    ------
    MotorIdError
        The fit itself failed (bad data or settings, no finite result).

    Examples
    --------
    >>> from motor_id import fit_report, Identifier
    >>> from motor_id.testing.recordings import paper_recording, SI_MOTOR
    >>> rec = paper_recording(SI_MOTOR, speed_noise=0.005, current_noise=0.01, seed=1)
    >>> report = fit_report(rec, Identifier(R_m=2.3, random_state=0))
    >>> report.adequate
    True
    >>> ff = report.controller['feedforward']
    >>> round(ff['kV']['value'], 3), ff['units']['kV']
    (0.667, 'V s/rad')
    >>> sorted(report.to_dict())[:4]
    ['adequate', 'assumptions', 'channels', 'controller']
    """
    identifier.fit(rec, progress=progress)
    res = identifier.result_
    block = data_block(rec, **dict(data or {}))
    head = res.to_dict()
    head['data'] = block
    period = sample_period if sample_period is not None else rec.sample_period
    design, error, text = controller_for(head, period, controller_options)
    return FitReport(result=res, data=block, controller=design, controller_error=error,
                     controller_summary=text, extra=dict(extra or {}))
