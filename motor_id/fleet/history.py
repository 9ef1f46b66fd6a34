"""Per robot, motor and parameter: the history of estimates and what the drift rule says.

Only rows whose fit is adequate and whose parameter is determined enter a history (an
inadequate fit says the model does not explain that recording; its numbers are not a
measurement of the motor).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

from motor_id.fleet.drift import DriftRule
from motor_id.model import PARAM_NAMES, PARAM_UNITS

UNITS = PARAM_UNITS

Row = dict[str, Any]
"""A result row (motor_id.fleet.store.COLUMNS) or a drift row."""


def histories(rows: Iterable[Row], parameters: Sequence[str] = PARAM_NAMES
              ) -> dict[tuple[str, str], dict[str, list[tuple[Any, ...]]]]:
    """``{(robot, motor): {parameter: [(start_time, value, std, recording), ...]}}`` in
    time order, from result rows (adequate fits, determined parameters)."""
    out: dict[tuple[str, str], dict[str, list[tuple[Any, ...]]]] = {}
    for r in sorted(rows, key=lambda r: (r['start_time'] or '', r['recording'])):
        per = out.setdefault((r['robot'], r['motor']), {p: [] for p in parameters})
        if r.get('adequate') is False:
            continue
        for p in parameters:
            v = r.get(p)
            if v is None or r.get(f'{p}_determined') is False:
                continue
            per[p].append((r['start_time'], v, r.get(f'{p}_std'), r['recording']))
    return out


def drift_table(rows: Iterable[Row], rule: DriftRule | None = None,
                parameters: Sequence[str] = PARAM_NAMES) -> list[Row]:
    """The rows of drift.json: one per robot, motor and parameter.

    Parameters
    ----------
    rows : iterable of dict
        Result rows (:data:`motor_id.fleet.store.COLUMNS`).
    rule : DriftRule, optional

    Returns
    -------
    list of dict
        ``{"robot", "motor", "parameter", "detected", "change", "since", "z",
        "baseline", "latest", "n", "change_points", "reason"}``, drifting ones first
        (largest |z| first), then by robot, motor, parameter.
    """
    rule = rule or DriftRule()
    table = []
    for (robot, motor), per in histories(rows, parameters).items():
        for p in parameters:
            h = per.get(p, [])
            found = rule.scan([t for t, _, _, _ in h], [v for _, v, _, _ in h],
                              [s for _, _, s, _ in h])
            d = found.to_dict()
            since = d['since'][:10] if d['since'] else None
            table.append({'robot': robot, 'motor': motor, 'parameter': p,
                          'detected': d['detected'], 'change': d['change'], 'since': since,
                          'z': d['z'], 'baseline': d['baseline'], 'latest': d['latest'],
                          'n': d['n'], 'change_points': d['change_points'],
                          'reason': d['reason'], 'unit': UNITS.get(p, '')})
    table.sort(key=lambda r: (not r['detected'], -abs(r['z'] or 0.0) if r['detected'] else 0,
                              r['robot'], r['motor'], PARAM_NAMES.index(r['parameter'])
                              if r['parameter'] in PARAM_NAMES else 99))
    return table
