"""A live motor's history of estimates in a JSON-lines file, checked by the fleet's drift rule.

The identifier node appends one line per fit (``{"time", "parameters": {NAME: {"value",
"std", "determined"}}, "adequate"}``) and asks :meth:`EstimateHistory.check` which
parameters drift: the same histories and rule as ``motor-id fleet``
(:func:`motor_id.fleet.history.drift_table`), so a live WARN and a fleet report agree.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
import json
import os

from motor_id.errors import ConfigError
from motor_id.fleet.drift import DriftRule
from motor_id.fleet.history import drift_table, DriftRow
from motor_id.fleet.rows import EstimateRow, ParameterValue
from motor_id.model import PARAM_NAMES


class EstimateHistory:
    """One motor's estimates on disk, and the drift they show.

    Parameters
    ----------
    path : str
        JSON-lines file; created on the first :meth:`append`, lines that cannot be read
        are skipped (and counted in ``skipped_``).
    rule : DriftRule, optional
    robot, motor : str
        Names for the drift rows.
    """

    def __init__(self, path: str, rule: DriftRule | None = None, robot: str = '',
                 motor: str = '') -> None:
        self.path = str(path)
        self.rule = rule or DriftRule()
        self.robot = robot
        self.motor = motor
        self.skipped_ = 0

    def append(self, parameters: Mapping[str, ParameterValue], time_iso: str,
               adequate: bool = True) -> None:
        """Add a fit's parameters as one line.

        Parameters
        ----------
        parameters : mapping of str to ParameterValue
            The fit's estimates by name (value, std, determined); a name missing is
            written as not determined.
        time_iso : str
            When the data were taken (ISO 8601, UTC).
        adequate : bool
            The fit's model explains the record (:attr:`IdentificationResult.adequate`).
        """
        params = {}
        for name in PARAM_NAMES:
            p = parameters.get(name) or ParameterValue()
            params[name] = {'value': p.value, 'std': p.std, 'determined': bool(p.determined)}
        line = {'time': time_iso, 'parameters': params,
                'adequate': bool(adequate)}
        try:
            folder = os.path.dirname(self.path)
            if folder:
                os.makedirs(folder, exist_ok=True)
            with open(self.path, 'a', encoding='utf-8') as fh:
                fh.write(json.dumps(line) + '\n')
        except OSError as exc:
            raise ConfigError(f'history_file {self.path}: cannot write ({exc.strerror})') \
                from None

    def rows(self) -> list[EstimateRow]:
        """The history as result rows (what :mod:`motor_id.fleet.history` reads)."""
        out: list[EstimateRow] = []
        self.skipped_ = 0
        try:
            fh = open(self.path, encoding='utf-8')
        except FileNotFoundError:
            return out
        except OSError as exc:
            raise ConfigError(f'history_file {self.path}: cannot read ({exc.strerror})') \
                from None
        with fh:
            for k, text in enumerate(fh):
                try:
                    line = json.loads(text)
                    params = {name: ParameterValue(
                        value=_number(p.get('value')), std=_number(p.get('std')),
                        determined=bool(p.get('determined', True)))
                        for name, p in line['parameters'].items()}
                    row = EstimateRow(robot=self.robot, motor=self.motor,
                                      recording=f'{self.path}:{k + 1}',
                                      start_time=str(line['time']), parameters=params,
                                      adequate=bool(line.get('adequate', True)))
                except (ValueError, KeyError, TypeError, AttributeError):
                    self.skipped_ += 1
                    continue
                out.append(row)
        return out

    def check(self) -> list[DriftRow]:
        """Drift rows (:func:`motor_id.fleet.history.drift_table`) of this history (its
        own day-to-day scatter: a live motor has no siblings here)."""
        return drift_table(self.rows(), self.rule)


def _number(v: object) -> float | None:
    """A JSON number (None stays None; anything else is refused)."""
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise TypeError(f'not a number: {v!r}')
    return float(v)


def drift_message(rows: Iterable[DriftRow]) -> str:
    """One line naming every drifting parameter and its change ('' when none)."""
    parts = [f'{d.parameter} {(d.change or 0.0) * 100:+.1f} % since {d.since} '
             f'(z {d.z or 0.0:.1f})' for d in rows if d.detected]
    return ('drift: ' + '; '.join(parts)) if parts else ''
