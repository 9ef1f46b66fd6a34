"""Reader of WPILib DataLogs (``.wpilog``) of a SysId routine: its tests as runs of one recording.

Since 2024 WPILib's SysId reads DataLogs written on the robot by ``SysIdRoutineLog``:

- a string entry ``sysid-test-state-<log name>``, appended every robot loop with the test
  that runs (``quasistatic-forward``, ``quasistatic-reverse``, ``dynamic-forward``,
  ``dynamic-reverse``) and ``none`` when a test ends: it splits the log into runs;
- per motor, double entries ``voltage-<motor>-<log name>``, ``position-<motor>-<log
  name>`` (older releases ``distance-...``) and ``velocity-<motor>-<log name>``, whose
  metadata is the unit (``Volt``, ``Rotation``, ``Rotation per Second``, ``Meter``,
  ``Meter per Second``, ...).

Other loggers (CTRE SignalLogger, REV URCL, AdvantageKit) name their entries themselves;
:class:`LogEntries` names them instead: an entry by its full name or a unique ending
(behind a prefix such as ``NT:/`` or ``/RealOutputs/``), an element of an array entry
(``double[]``, ``float[]``, ``int64[]``) as ``NAME[i]``. A metadata that is a JSON object
(AdvantageKit's ``{"source": "AdvantageKit", "unit": "..."}``, NetworkTables' properties)
gives its ``unit``, or none. The test state may be written as SysIdRoutineLog writes it
(``quasistatic-forward``) or as the Java enum's name (``kQuasistaticForward``, ``kNone``);
unnamed, a string entry with ``sysid`` in its name that holds such states is the state.
Records carry their own timestamps [us]: the velocity entry is the time base, and each
velocity sample takes the voltage and position of its own robot loop: the last ones logged
up to half a loop after it, whatever order the loop logs them in (the ``hold`` rule of
:mod:`motor_id.data.align`, half a loop ahead). As in a SysId JSON row, a loop's voltage is
the input over the interval that starts at that loop's sample. A run holds the velocity
samples from half a loop before its first state record to half a loop before the record
that ends it. Positions and speeds are converted to SI: rad and rad/s, or m and m/s for a
linear unit.

:mod:`wpiutil` (robotpy-wpiutil) reads the file; it is imported on the first read.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
import math
import os
import re
from typing import Any

import numpy as np

from motor_id.data.align import held_command_index
from motor_id.data.log_units import parse_unit, UNIT_NAMES, unit_of, VOLTS
from motor_id.data.sysid import MIN_TEST_ROWS, sysid_recording
from motor_id.errors import DataError
from motor_id.recording import Recording

STATE_PREFIX = 'sysid-test-state-'
"""Name of SysIdRoutineLog's state entry, before the log name."""

STATES = ('quasistatic-forward', 'quasistatic-reverse', 'dynamic-forward', 'dynamic-reverse')
"""The test states of a routine; ``none`` ends a test."""

CHANNELS = ('voltage', 'position', 'velocity')
"""The per-motor entries (``position`` was ``distance`` in older releases)."""

_ALIASES = {'voltage': ('voltage',), 'position': ('position', 'distance'),
            'velocity': ('velocity',)}
_NUMERIC = ('double', 'float', 'int64')
_ARRAYS = ('double[]', 'float[]', 'int64[]')
_INDEXED = re.compile(r'^(.*)\[(\d+)\]$')


@dataclass(frozen=True)
class LogEntries:
    """Which motor, or which entries, of a DataLog to read (all optional).

    Attributes
    ----------
    motor : str
        The motor of a SysIdRoutineLog (its name, or ``<motor>-<log name>``).
    voltage, position, velocity, state : str
        Entry names for other loggers (the full name, or a unique ending of it).
    units : str
        The position unit (:data:`UNIT_NAMES`) of position and velocity entries whose
        metadata does not say it.
    joint : {'left', 'right'}
        A drivetrain's side: the motor whose name has this word.
    """

    motor: str | None = None
    voltage: str | None = None
    position: str | None = None
    velocity: str | None = None
    state: str | None = None
    units: str | None = None
    joint: str | None = None

    @property
    def named(self) -> dict[str, str]:
        """The entries given by name: ``{channel or 'state': name}``."""
        return {k: v for k in (*CHANNELS, 'state') if (v := getattr(self, k))}


@dataclass
class _Entry:
    """One entry of the log: its start record and its records (timestamps in us)."""

    name: str
    type: str
    metadata: str
    times: list[int] = field(default_factory=list)
    values: list[Any] = field(default_factory=list)


@dataclass(frozen=True)
class _Motor:
    """The chosen entries: one per channel (position may be missing), the state entry."""

    label: str
    channels: dict[str, _Entry]
    state: _Entry


def is_wpilog(path: str | os.PathLike[str]) -> bool:
    """True for a path the tools read as a WPILib DataLog: a ``.wpilog`` file."""
    return str(path).lower().endswith('.wpilog') and not os.path.isdir(path)


def load_wpilog(path: str | os.PathLike[str], entries: LogEntries | None = None) -> Recording:
    """Read the SysId routine of a WPILib DataLog as a voltage-input recording of runs.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.wpilog``.
    entries : LogEntries, optional
        The motor (where the log holds several), a drivetrain side, or the entries of
        another logger.

    Returns
    -------
    Recording
        Validated; ``input`` the logged voltage [V], ``speed`` [rad/s] or [m/s],
        ``position`` [rad] or [m] (when logged), no current; each test a run.
        ``meta['segment_names']`` names the test of each run (a test run again gets
        ``#2``, ...), ``meta['sysid']`` the log name, the motor, the entries, the
        units of the log and ``si_to_units`` (the log's position units per SI unit),
        ``meta['warnings']`` what was dropped.

    Raises
    ------
    DataError
        Not a DataLog, no state entry, no motor or several without ``motor``, a named
        entry the log lacks, a unit that is not known, no run with enough samples.
    """
    path = str(path)
    sel = entries or LogEntries()
    warnings: list[str] = []
    log = _read(path, _wanted(sel), warnings)
    chosen = _choose(path, log, sel)
    scales = _units(path, chosen, sel.units)
    runs, names = _runs(path, chosen, scales, warnings)
    return sysid_recording(
        path, runs, names, warnings, 'WPILib DataLog (SysId routine)', scales.linear,
        {'test': None, 'units': scales.unit, 'motor': chosen.label,
         'entries': {k: e.name for k, e in chosen.channels.items()}
         | {'state': chosen.state.name},
         'si_to_units': 1.0 / scales.position, 'linear': scales.linear})


# ------------------------------------------------------------------------------ reading

def _wanted(sel: LogEntries) -> Callable[[str], bool]:
    """Which entries' records to keep: SysIdRoutineLog's names, and the ones named."""
    named = tuple(_split_index(v)[0] for v in sel.named.values())
    pattern = re.compile(r'(^|/)(sysid-test-state-|voltage-|position-|distance-|velocity-)'
                         r'|sysid', re.IGNORECASE)

    def wanted(name: str) -> bool:
        return bool(pattern.search(name)) or any(name.endswith(n) for n in named)
    return wanted


def _read(path: str, wanted: Callable[[str], bool], warnings: list[str]) -> dict[str, _Entry]:
    """Every entry's start record, and the records of the wanted ones, by entry name.

    A record that cannot be decoded (a corrupt or cut file) ends the reading: what came
    before it is kept and a warning says where it stopped.
    """
    from wpiutil.log import DataLogReader
    try:
        reader = DataLogReader(path)
    except FileNotFoundError as exc:
        raise DataError(f'{path}: no such file') from exc
    except (OSError, RuntimeError) as exc:
        raise DataError(f'{path}: cannot read ({exc})') from exc
    if not reader.isValid():
        raise DataError(f'{path}: not a WPILib DataLog (no "WPILOG" header)')
    by_id: dict[int, _Entry] = {}
    keep: dict[int, _Entry] = {}
    out: dict[str, _Entry] = {}
    count, last_t = 0, 0
    for record in reader:
        try:
            eid = record.getEntry()
            if record.isControl():
                _control(record, by_id, keep, out, wanted)
            elif eid in keep:
                _append(record, keep[eid])
            elif eid not in by_id:
                raise TypeError(f'record of entry {eid}, which was never started')
            last_t = record.getTimestamp()
        except (TypeError, ValueError, UnicodeDecodeError) as exc:
            warnings.append(f'the log is corrupt after record {count} (t = {last_t * 1e-6:.6f}'
                            f' s: {exc}); the records before it are read, the rest ignored')
            break
        count += 1
    return out


def _control(record: Any, by_id: dict[int, _Entry], keep: dict[int, _Entry],
             out: dict[str, _Entry], wanted: Callable[[str], bool]) -> None:
    """Apply a start, finish or set-metadata record."""
    if record.isStart():
        start = record.getStartData()
        entry = out.get(start.name) or _Entry(start.name, start.type, start.metadata)
        by_id[start.entry] = entry
        if wanted(start.name):
            keep[start.entry] = entry
        out[start.name] = entry
    elif record.isSetMetadata():
        meta = record.getSetMetadataData()
        if meta.entry in by_id:
            by_id[meta.entry].metadata = meta.metadata
    elif record.isFinish():
        eid = record.getFinishEntry()
        by_id.pop(eid, None)
        keep.pop(eid, None)
    else:
        raise TypeError('unknown control record')


def _append(record: Any, entry: _Entry) -> None:
    """Decode one data record of a kept entry (numbers and strings; others are skipped)."""
    if entry.type == 'double':
        value: Any = record.getDouble()
    elif entry.type == 'float':
        value = record.getFloat()
    elif entry.type == 'int64':
        value = float(record.getInteger())
    elif entry.type == 'string':
        value = record.getString()
    elif entry.type in _ARRAYS:
        value = list({'double[]': record.getDoubleArray, 'float[]': record.getFloatArray,
                      'int64[]': record.getIntegerArray}[entry.type]())
    else:
        return
    entry.times.append(record.getTimestamp())
    entry.values.append(value)


# ------------------------------------------------------------------------ choosing entries

def _split_index(name: str) -> tuple[str, int | None]:
    """``('NAME', i)`` of ``'NAME[i]'``; ``(name, None)`` otherwise."""
    match = _INDEXED.match(name.strip())
    return (match.group(1), int(match.group(2))) if match else (name.strip(), None)


def _find(path: str, log: dict[str, _Entry], name: str, what: str,
          types: tuple[str, ...]) -> _Entry:
    """The entry called ``name`` or, failing that, the one entry whose name ends with it;
    ``NAME[i]``: element ``i`` of an array entry, as an entry of its own."""
    base, index = _split_index(name)
    if index is not None or (base in log and log[base].type in _ARRAYS):
        return _element(path, _find_one(path, log, base, what, _ARRAYS), index, what)
    return _find_one(path, log, name, what, types)


def _element(path: str, entry: _Entry, index: int | None, what: str) -> _Entry:
    """Element ``index`` of each record of an array entry (NaN where a record is short)."""
    sizes = sorted({len(v) for v in entry.values}) or [0]
    if index is None:
        raise DataError(f'{path}: the {what} entry {entry.name!r} holds {entry.type} (arrays '
                        f'of {"-".join(map(str, sizes[::max(len(sizes) - 1, 1)]))}); name '
                        f'one element: {entry.name}[0] .. {entry.name}[{max(sizes[-1] - 1, 0)}]',
                        params=(what,))
    if index >= sizes[-1]:
        raise DataError(f'{path}: the {what} entry {entry.name!r} has no element {index} '
                        f'(its arrays hold {sizes[-1]})', params=(what,))
    values = [float(v[index]) if index < len(v) else math.nan for v in entry.values]
    return _Entry(f'{entry.name}[{index}]', entry.type[:-2], entry.metadata,
                  list(entry.times), values)


def _find_one(path: str, log: dict[str, _Entry], name: str, what: str,
              types: tuple[str, ...]) -> _Entry:
    """The entry called ``name`` or, failing that, the one entry whose name ends with it."""
    found = [log[name]] if name in log else [
        e for n, e in log.items() if n.endswith(name) and n[-len(name) - 1:-len(name)]
        in ('/', ':', '')]
    if len(found) != 1:
        pool = [n for n, e in log.items()
                if e.type in types or (types == _NUMERIC and e.type in _ARRAYS)]
        how = 'no' if not found else f'{len(found)} entries match'
        raise DataError(f'{path}: {how} {what} entry {name!r} ({"/".join(types)} entries: '
                        f'{_listing(pool)})')
    if found[0].type in _ARRAYS and types is not _ARRAYS:
        return _element(path, found[0], None, what)
    if found[0].type not in types:
        raise DataError(f'{path}: the {what} entry {found[0].name!r} holds {found[0].type}, '
                        f'not {" or ".join(types)}', params=(what,))
    return found[0]


def _listing(names: list[str], most: int = 12) -> str:
    shown = sorted(names)[:most]
    more = f', ... ({len(names)} in all)' if len(names) > most else ''
    return (', '.join(shown) or 'none') + more


def _state_entries(log: dict[str, _Entry]) -> dict[str, _Entry]:
    """SysIdRoutineLog's state entries by log name."""
    out = {}
    for name, entry in log.items():
        match = re.search(r'(?:^|/)sysid-test-state-(.+)$', name)
        if match and entry.type == 'string':
            out[match.group(1)] = entry
    return out


def _routine_motors(log: dict[str, _Entry],
                    states: dict[str, _Entry]) -> dict[tuple[str, str], dict[str, _Entry]]:
    """``{(motor, log name): {channel: entry}}`` of SysIdRoutineLog's motor entries."""
    motors: dict[tuple[str, str], dict[str, _Entry]] = {}
    for name, entry in log.items():
        if entry.type not in _NUMERIC:
            continue
        base = name.rsplit('/', 1)[-1]
        for log_name in states:
            for channel, prefixes in _ALIASES.items():
                for prefix in prefixes:
                    head, tail = f'{prefix}-', f'-{log_name}'
                    if base.startswith(head) and base.endswith(tail) and \
                            len(base) > len(head) + len(tail):
                        motor = base[len(head):-len(tail)]
                        motors.setdefault((motor, log_name), {}).setdefault(channel, entry)
    return {k: v for k, v in motors.items() if 'voltage' in v and 'velocity' in v}


def _choose(path: str, log: dict[str, _Entry], sel: LogEntries) -> _Motor:
    """The entries to read: the named ones, or the one motor of a SysIdRoutineLog."""
    states = _state_entries(log)
    named = sel.named
    given = [c for c in CHANNELS if c in named]
    if given:
        missing = [c for c in ('voltage', 'velocity') if c not in named]
        if missing:
            raise DataError(f'{path}: entries given by name need voltage and velocity '
                            f'(missing: {", ".join(missing)})', params=tuple(missing))
        chans = {c: _find(path, log, named[c], c, _NUMERIC) for c in given}
        return _Motor(label=named['velocity'], channels=chans,
                      state=_state(path, log, states, sel.state))
    motors = _routine_motors(log, states)
    if sel.state is not None:
        state = _find(path, log, sel.state, 'state', ('string',))
        motors = {k: v for k, v in motors.items() if states.get(k[1]) is state}
    if not motors:
        numeric = [n for n, e in log.items() if e.type in _NUMERIC + _ARRAYS]
        raise DataError(f'{path}: no SysIdRoutineLog motor (entries voltage-<motor>-<log '
                        f'name> and velocity-<motor>-<log name> beside a {STATE_PREFIX}<log '
                        f'name> entry); for another logger name the entries voltage, '
                        f'velocity, position and state (numeric entries: '
                        f'{_listing(numeric)})',
                        params=('voltage', 'velocity', 'position', 'state'))
    key = _pick_motor(path, motors, sel)
    return _Motor(label=f'{key[0]} (log {key[1]})', channels=motors[key], state=states[key[1]])


def _state(path: str, log: dict[str, _Entry], states: dict[str, _Entry],
           name: str | None) -> _Entry:
    """The state entry: the one named, or the log's only SysIdRoutineLog state entry."""
    if name is not None:
        return _find(path, log, name, 'state', ('string',))
    if len(states) == 1:
        return next(iter(states.values()))
    guess = [e for n, e in log.items() if e.type == 'string' and 'sysid' in n.lower()
             and any(state_name(str(v)) in STATES for v in e.values)]
    if not states and len(guess) == 1:   # AdvantageKit's Logger.recordOutput("SysIdState")
        return guess[0]
    strings = [n for n, e in log.items() if e.type == 'string']
    raise DataError(f'{path}: {"several" if states else "no"} {STATE_PREFIX}<log name> '
                    f'entries; name the test-state entry (state; string entries: '
                    f'{_listing(strings)})', params=('state',))


def _pick_motor(path: str, motors: dict[tuple[str, str], dict[str, _Entry]],
                sel: LogEntries) -> tuple[str, str]:
    """The motor the selection names (by name, ``<motor>-<log name>``, or side)."""
    keys = sorted(motors)
    if sel.motor is not None:
        want = sel.motor.strip()
        keys = [k for k in keys if want in (k[0], f'{k[0]}-{k[1]}')]
        if not keys:
            raise DataError(f'{path}: no motor {want!r} (motors: {_motor_list(motors)})')
    if sel.joint is not None:
        side = sel.joint.strip().lower()
        keys = [k for k in keys if side in re.split(r'[^a-z0-9]+', k[0].lower())]
        if not keys:
            raise DataError(f'{path}: no motor of side {side!r} (motors: '
                            f'{_motor_list(motors)})')
    if len(keys) > 1:
        raise DataError(f'{path}: the log holds several motors: {_motor_list(motors)}; pick '
                        'one (motor)', params=('motor',))
    return keys[0]


def _motor_list(motors: dict[tuple[str, str], dict[str, _Entry]]) -> str:
    logs = {k[1] for k in motors}
    return ', '.join(m if len(logs) == 1 else f'{m}-{log}' for m, log in sorted(motors))


# ---------------------------------------------------------------------------------- units

@dataclass(frozen=True)
class _Scales:
    """SI per log unit of the position and the velocity, the position unit, linear."""

    position: float
    velocity: float
    unit: str
    linear: bool


def _units(path: str, chosen: _Motor, override: str | None) -> _Scales:
    """The log's units from the entries' metadata (or ``override``), checked."""
    volts = chosen.channels['voltage']
    if unit_of(volts.metadata).lower() not in VOLTS:
        raise DataError(f'{path}: the voltage entry {volts.name!r} is in '
                        f'{volts.metadata!r}, not volts')
    scales: dict[str, tuple[float, bool]] = {}
    for channel in ('position', 'velocity'):
        entry = chosen.channels.get(channel)
        if entry is None:
            continue
        text = override if override is not None else unit_of(entry.metadata)
        if not text.strip():
            raise DataError(f'{path}: the {channel} entry {entry.name!r} has no unit in its '
                            f'metadata; give the position unit (units: '
                            f'{", ".join(UNIT_NAMES)})', params=('units',))
        parsed = parse_unit(text, speed=channel == 'velocity' and override is None)
        if parsed is None:
            raise DataError(f'{path}: unknown unit {text!r} of the {channel} entry '
                            f'{entry.name!r} (known: {", ".join(UNIT_NAMES)}, and each '
                            'per second)')
        scales[channel] = parsed
    if len({linear for _, linear in scales.values()}) > 1:
        raise DataError(f'{path}: position and velocity disagree: one is a length, the other '
                        f'an angle ({unit_of(chosen.channels["position"].metadata)!r}, '
                        f'{unit_of(chosen.channels["velocity"].metadata)!r})')
    v_scale, linear = scales['velocity']
    if 'position' in scales:
        unit = (override or unit_of(chosen.channels['position'].metadata)).strip()
        return _Scales(scales['position'][0], v_scale, unit, linear)
    unit = override or re.split(r'\s*(?:/|\bper\b)\s*',
                                unit_of(chosen.channels['velocity'].metadata))[0]
    per_unit = parse_unit(unit)
    return _Scales(per_unit[0] if per_unit else v_scale, v_scale, unit.strip(), linear)


# ----------------------------------------------------------------------------------- runs

def _series(entry: _Entry) -> tuple[np.ndarray, np.ndarray]:
    """Times [us] and values of a numeric entry, sorted by time, repeated times dropped."""
    t = np.asarray(entry.times, dtype=np.int64)
    v = np.asarray(entry.values, dtype=float)
    order = np.argsort(t, kind='stable')
    t, v = t[order], v[order]
    keep = np.ones(t.size, dtype=bool)
    keep[1:] = np.diff(t) > 0
    return t[keep], v[keep]


def state_name(value: str) -> str:
    """A test state as SysIdRoutineLog writes it: ``quasistatic-forward`` (also written as
    the Java enum's name, ``kQuasistaticForward``, or ``QUASISTATIC_FORWARD``), ``none``."""
    text = value.strip()
    if text in STATES or text == 'none':
        return text
    words = re.sub(r'^k(?=[A-Z])', '', text)
    words = re.sub(r'(?<=[a-z0-9])(?=[A-Z])', '-', words).replace('_', '-').lower()
    return words if words in STATES or words == 'none' else text


def _tests(path: str, state: _Entry, end_us: int,
           warnings: list[str]) -> list[tuple[str, int, int]]:
    """``(state, first record, record that ends it)`` of each test in the state entry."""
    order = np.argsort(np.asarray(state.times, dtype=np.int64), kind='stable')
    times = [int(state.times[i]) for i in order]
    values = [state_name(str(state.values[i])) for i in order]
    out: list[tuple[str, int, int]] = []
    unknown: set[str] = set()
    k = 0
    while k < len(values):
        j = k
        while j + 1 < len(values) and values[j + 1] == values[k]:
            j += 1
        if values[k] in STATES:
            end = times[j + 1] if j + 1 < len(values) else end_us
            if j + 1 == len(values):
                warnings.append(f'the log ends during {values[k]} (no "none" after it: '
                                'the file was cut, or is corrupt from there); that test is '
                                'read to its last sample')
            out.append((values[k], times[k], end))
        elif values[k] != 'none':
            unknown.add(values[k])
        k = j + 1
    if unknown:
        warnings.append(f'unknown test state(s) {", ".join(sorted(unknown))} in '
                        f'{state.name!r} ignored (known: {", ".join(STATES)}, none)')
    if not out:
        raise DataError(f'{path}: the state entry {state.name!r} holds no test ('
                        f'{len(values)} record(s); tests are {", ".join(STATES)})')
    return out


def _aligned(t_ref: np.ndarray, entry: _Entry, period_us: float) -> np.ndarray:
    """The values of ``entry`` each reference time takes: its own robot loop's.

    The last value logged up to half a loop after the reference time (the ``hold`` rule of
    :func:`motor_id.data.align.held_command_index` half a loop ahead): the entries of one
    loop are logged microseconds apart, in any order, and loops are a period apart.
    """
    t, v = _series(entry)
    idx = held_command_index(t_ref + period_us / 2, t, 'hold')
    return np.where(idx >= 0, v[np.maximum(idx, 0)], np.nan)


def _runs(path: str, chosen: _Motor, scales: _Scales,
          warnings: list[str]) -> tuple[list[Recording], list[str]]:
    """One recording per test, in SI; runs with too few samples dropped with a warning."""
    t_w, w = _series(chosen.channels['velocity'])
    if t_w.size < 2:
        raise DataError(f'{path}: the velocity entry {chosen.channels["velocity"].name!r} '
                        f'has {t_w.size} sample(s)')
    period = float(np.median(np.diff(t_w)))
    volts = _aligned(t_w, chosen.channels['voltage'], period)
    pos = _aligned(t_w, chosen.channels['position'], period) * scales.position \
        if 'position' in chosen.channels else None
    finite = np.isfinite(volts) & np.isfinite(w) & (True if pos is None else np.isfinite(pos))
    runs: list[Recording] = []
    names: list[str] = []
    for test, t_a, t_b in _tests(path, chosen.state, int(t_w[-1] + period), warnings):
        window = (t_w >= t_a - period / 2) & (t_w < t_b - period / 2)
        inside = window & finite
        repeat = sum(1 for n in names if n.split('#')[0] == test)
        name = test if not repeat else f'{test}#{repeat + 1}'
        n, lost = int(inside.sum()), int((window & ~finite).sum())
        if n < MIN_TEST_ROWS:
            warnings.append(f'test {name!r} at t = {t_a * 1e-6:.3f} s dropped: {n} '
                            f'sample(s), fewer than {MIN_TEST_ROWS}')
            continue
        if lost:
            warnings.append(f'test {name!r}: {lost} sample(s) without a finite voltage, '
                            'position and velocity left out')
        runs.append(Recording(t_w[inside] * 1e-6, volts[inside], w[inside] * scales.velocity,
                              input_kind='voltage',
                              position=None if pos is None else pos[inside],
                              meta={'source': f'{os.path.basename(path)}:{name}'}))
        names.append(name)
    if not runs:
        raise DataError(f'{path}: no test has at least {MIN_TEST_ROWS} samples ('
                        + '; '.join(warnings) + ')')
    return runs, names
