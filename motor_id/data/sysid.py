"""Reader of WPILib SysId logs (``sysid_data.json``): the four tests as one recording.

A SysId log (the JSON that WPILib's SysId application saved, 2021-2023) holds four tests
of one mechanism, each a separate run from rest: quasistatic voltage ramps forward and
backward (``slow-forward``, ``slow-backward``) and voltage steps forward and backward
(``fast-forward``, ``fast-backward``). Its top level::

    {"sysid": true, "test": "Simple" | "Arm" | "Elevator" | "Drivetrain",
     "units": "Meters" | "Feet" | "Inches" | "Radians" | "Rotations" | "Degrees",
     "unitsPerRotation": float,
     "slow-forward": [[t, V, position, velocity], ...], ...}

with Drivetrain rows ``[t, V_left, V_right, pos_left, pos_right, vel_left, vel_right,
angle, rate]``. As SysId reads it (``AnalysisManager::PrepareGeneralData`` multiplies
every position and velocity by ``unitsPerRotation``), the logged positions are in
rotations and the velocities in rotations per second of the encoder (the robot projects
SysId generated log encoder rotations); ``unitsPerRotation`` converts them to the user's
``units``. This reader goes on to SI: rad and rad/s for the angular units, m and m/s for
the linear ones.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from typing import Any

import numpy as np

from motor_id.contracts import channel_units
from motor_id.effects import MECHANISMS
from motor_id.errors import DataError
from motor_id.recording import Recording

TESTS = ('slow-forward', 'slow-backward', 'fast-forward', 'fast-backward')
"""The four tests of a SysId log, in the order they are joined."""

TEST_TYPES = ('Simple', 'Arm', 'Elevator', 'Drivetrain')
"""Mechanisms (the log's ``test``) this reader accepts."""

JOINTS = ('left', 'right')
"""Sides of a Drivetrain log."""

SI_PER_UNIT = {'Meters': 1.0, 'Feet': 0.3048, 'Inches': 0.0254,
               'Radians': 1.0, 'Rotations': 2.0 * math.pi, 'Degrees': math.pi / 180.0}
"""SI value (m or rad) of one of each SysId unit."""

LINEAR_UNITS = ('Meters', 'Feet', 'Inches')

MIN_TEST_ROWS = 10
"""A test with fewer rows is dropped (with a warning in ``meta['warnings']``)."""

_COLUMNS = {
    'general': ('t', 'V', 'position', 'velocity'),
    'Drivetrain': ('t', 'V_left', 'V_right', 'pos_left', 'pos_right', 'vel_left',
                   'vel_right', 'angle', 'rate'),
}
_SIDE_COLUMNS = {None: (1, 2, 3), 'left': (1, 3, 5), 'right': (2, 4, 6)}
"""Columns of (voltage, position, velocity) per joint."""


def is_sysid_log(path: str | os.PathLike[str]) -> bool:
    """True for a path the tools read as a SysId log: a ``.json`` file.

    Any ``.json`` file goes to :func:`load_sysid`, which says what is wrong when the
    file is not a SysId log (no ``"sysid": true`` at its top level).
    """
    return str(path).lower().endswith('.json') and not os.path.isdir(path)


def load_sysid(path: str | os.PathLike[str], joint: str | None = None) -> Recording:
    """Read a WPILib SysId log as a voltage-input recording of four runs.

    Parameters
    ----------
    path : str or os.PathLike
        The SysId JSON (``sysid_data*.json``).
    joint : {'left', 'right'}, optional
        The side of a Drivetrain log (required there, refused elsewhere).

    Returns
    -------
    Recording
        Validated; ``input`` the logged voltage [V], ``speed`` [rad/s] or [m/s],
        ``position`` [rad] or [m], no current. Each test is a run
        (:meth:`Recording.concatenate`; its times shifted to follow the previous one).
        ``meta['segment_names']`` names the test of each run, ``meta['sysid']`` holds the
        log's ``test``, ``units``, ``unitsPerRotation``, the joint and ``si_to_units``:
        the log's units per SI unit (a gain per unit speed in the log's units is the SI
        gain divided by it: ``kV_log = kV_SI / si_to_units``); ``meta['mechanism']`` the
        mechanism of an Arm or Elevator log (``arm``, ``elevator``; None otherwise).

    Raises
    ------
    DataError
        Not JSON, not a SysId log, a missing test, a malformed row, non-finite values,
        time not increasing within a test, unknown units or mechanism, a Drivetrain log
        without a joint or with an unknown one, no test with enough rows.
    """
    path = str(path)
    log = _read_json(path)
    test_type, units, per_rotation = _header(path, log)
    joint = _check_joint(path, test_type, joint)
    scale = per_rotation * SI_PER_UNIT[units]
    runs: list[Recording] = []
    names: list[str] = []
    warnings: list[str] = []
    for name in TESTS:
        rows = _rows(path, log, name, test_type)
        if rows.shape[0] < MIN_TEST_ROWS:
            warnings.append(f'test {name!r} dropped: {rows.shape[0]} row(s), fewer than '
                            f'{MIN_TEST_ROWS}')
            continue
        runs.append(_run(path, rows, name, joint, scale))
        names.append(name)
    if not runs:
        raise DataError(f'{path}: no test has at least {MIN_TEST_ROWS} rows ('
                        + '; '.join(warnings) + ')')
    return sysid_recording(
        path, runs, names, warnings, 'WPILib SysId log', units in LINEAR_UNITS,
        {'test': test_type, 'units': units, 'unitsPerRotation': per_rotation,
         'joint': joint, 'si_to_units': 1.0 / SI_PER_UNIT[units], 'log_to_si': scale},
        mechanism=test_type.lower() if test_type.lower() in MECHANISMS[1:] else None)


def sysid_recording(path: str, runs: list[Recording], names: list[str], warnings: list[str],
                    fmt: str, linear: bool, sysid: dict[str, Any], **meta: Any) -> Recording:
    """The validated recording of a SysId routine's tests, one run each.

    Parameters
    ----------
    path : str
        The log (named in the meta and in an error).
    runs, names : list
        The tests as recordings, and their SysId names.
    warnings : list of str
        What the reader dropped or repaired (kept in ``meta['warnings']``).
    fmt : str
        The log's format, for ``meta['format']``.
    linear : bool
        Whether the axis is linear (metres): the channels' units.
    sysid : dict
        ``meta['sysid']``: the log's units and where they come from.
    **meta
        More meta keys (a JSON log's ``mechanism``).

    Returns
    -------
    Recording
        Validated; a :class:`DataError` names ``path``.
    """
    runs = _position_checked(runs, linear, warnings)
    rec = Recording.concatenate(runs)
    rec.meta = {
        'source': os.path.basename(path),
        'format': fmt,
        'sysid': sysid,
        'segment_names': names,
        'segment_offsets': [float(x) for x in rec.meta.get('segment_offsets', [0.0])],
        **meta,
        'units': {k: u for k, u in channel_units(
            'voltage', linear, position=rec.has_position).items()
            if k not in ('current', 'flags')},
    }
    if warnings:
        rec.meta['warnings'] = warnings
    try:
        return rec.validate()
    except DataError as exc:
        raise DataError(f'{path}: {exc}') from exc


def _read_json(path: str) -> dict[str, Any]:
    """The log's top level; DataError for a missing file, bad JSON or not a SysId log."""
    try:
        with open(path, encoding='utf-8') as fh:
            log = json.load(fh)
    except FileNotFoundError as exc:
        raise DataError(f'{path}: no such file') from exc
    except OSError as exc:
        raise DataError(f'{path}: cannot read ({exc.strerror})') from exc
    except UnicodeDecodeError as exc:
        raise DataError(f'{path}: not JSON (not UTF-8 text)') from exc
    except json.JSONDecodeError as exc:
        raise DataError(f'{path}: not JSON ({exc.msg} at line {exc.lineno} column '
                        f'{exc.colno})') from exc
    if not isinstance(log, dict):
        raise DataError(f'{path}: not a WPILib SysId log (the top level is a '
                        f'{type(log).__name__}, not an object)')
    if log.get('sysid') is not True:
        found = 'missing' if 'sysid' not in log else f'{log["sysid"]!r}'
        raise DataError(f'{path}: not a WPILib SysId log ("sysid" is {found}, not true)')
    return log


POSITION_AGREEMENT = 0.1
"""Largest relative difference between the logged position's rate and the logged velocity
(their least-squares ratio over every test) for the position to be kept."""


def _position_checked(runs: list[Recording], linear: bool,
                      warnings: list[str]) -> list[Recording]:
    """The runs, without their positions where the positions' rate disagrees with the
    velocity (a gear ratio or a unit applied to one of them only), with a warning.

    The ratio is ``sum(dp * w dt) / sum((w dt)^2)`` over every interval of every test (``w``
    the interval's mean velocity): 1 where they agree, whatever the noise.
    """
    positions = [r.position for r in runs]
    if not runs or any(p is None for p in positions):
        return runs
    num = den = 0.0
    for r, p in zip(runs, positions, strict=True):
        step = 0.5 * (r.speed[1:] + r.speed[:-1]) * np.diff(r.time)
        num += float(np.diff(np.asarray(p)) @ step)
        den += float(step @ step)
    ratio = num / den if den > 0 else 1.0
    if abs(ratio - 1.0) <= POSITION_AGREEMENT:
        return runs
    unit = 'm' if linear else 'rad'
    warnings.append(f'the logged position does not follow the logged velocity: its rate is '
                    f'{ratio:.4g} x the velocity (a gear ratio or a unit applied to one of '
                    f'them only?); the position is left out and the speed, in {unit}/s, '
                    'taken as logged (a mechanism that reads the position cannot be fitted)')
    return [dataclasses.replace(r, position=None) for r in runs]


def _header(path: str, log: dict[str, Any]) -> tuple[str, str, float]:
    """``(test, units, unitsPerRotation)``, checked."""
    test_type = log.get('test')
    if test_type not in TEST_TYPES:
        raise DataError(f'{path}: unsupported SysId test {test_type!r}; this reader takes '
                        f'{", ".join(TEST_TYPES)}')
    units = log.get('units')
    if units not in SI_PER_UNIT:
        raise DataError(f'{path}: unknown units {units!r}; SysId logs use '
                        f'{", ".join(SI_PER_UNIT)}')
    per_rotation = log.get('unitsPerRotation')
    if (isinstance(per_rotation, bool) or not isinstance(per_rotation, (int, float))
            or not math.isfinite(per_rotation) or per_rotation <= 0):
        raise DataError(f'{path}: "unitsPerRotation" must be a finite number > 0, got '
                        f'{per_rotation!r}')
    return test_type, units, float(per_rotation)


def _check_joint(path: str, test_type: str, joint: str | None) -> str | None:
    """The joint in lower case: required for a Drivetrain log, refused for others."""
    if test_type != 'Drivetrain':
        if joint is not None:
            raise DataError(f'{path}: joint selects a side of a Drivetrain log; this is '
                            f'a {test_type} log (leave joint out)', params=('joint',))
        return None
    if joint is None:
        raise DataError(f"{path}: a Drivetrain log has two sides: give joint 'left' or "
                        "'right'", params=('joint',))
    side = str(joint).strip().lower()
    if side not in JOINTS:
        raise DataError(f'{path}: unknown joint {joint!r} of a Drivetrain log; choose '
                        f'{" or ".join(JOINTS)}')
    return side


def _rows(path: str, log: dict[str, Any], name: str, test_type: str) -> np.ndarray:
    """The test's rows as a float array (n, width), checked row by row."""
    if name not in log:
        present = [t for t in TESTS if t in log]
        raise DataError(f'{path}: test {name!r} missing (found '
                        f'{", ".join(present) or "none of the four tests"})')
    rows = log[name]
    if not isinstance(rows, list):
        raise DataError(f'{path}: test {name!r} is a {type(rows).__name__}, not a list of '
                        'rows')
    columns = _COLUMNS['Drivetrain' if test_type == 'Drivetrain' else 'general']
    width = len(columns)
    for k, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != width:
            got = f'{len(row)} values' if isinstance(row, list) else type(row).__name__
            raise DataError(f'{path}: test {name!r} row {k}: {got}, a {test_type} row has '
                            f'{width} ({", ".join(columns)})')
        for j, v in enumerate(row):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise DataError(f'{path}: test {name!r} row {k}: {columns[j]} is {v!r}, '
                                'not a number')
    arr = np.array(rows, dtype=float).reshape(len(rows), width)
    bad = np.argwhere(~np.isfinite(arr))
    if bad.size:
        k, j = (int(i) for i in bad[0])
        raise DataError(f'{path}: test {name!r} row {k}: {columns[j]} is {arr[k, j]} '
                        f'({bad.shape[0]} non-finite value(s) in the test)')
    dt = np.diff(arr[:, 0])
    back = np.flatnonzero(dt <= 0)
    if back.size:
        k = int(back[0]) + 1
        raise DataError(f'{path}: test {name!r}: time is not increasing at row {k} '
                        f'(t = {arr[k - 1, 0]:.9g} then {arr[k, 0]:.9g})')
    return arr


def _run(path: str, rows: np.ndarray, name: str, joint: str | None,
         scale: float) -> Recording:
    """One test as a recording in SI units."""
    iv, ip, iw = _SIDE_COLUMNS[joint]
    return Recording(rows[:, 0], rows[:, iv], rows[:, iw] * scale,
                     input_kind='voltage', position=rows[:, ip] * scale,
                     meta={'source': f'{os.path.basename(path)}:{name}'})
