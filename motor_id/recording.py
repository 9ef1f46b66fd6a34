"""One in-memory recording (time + channels), its validation, and the CSV reader/writer."""

import csv
from dataclasses import dataclass, field
import math

import numpy as np

from motor_id.errors import DataError

REQUIRED_COLUMNS = ('time', 'voltage', 'speed')
OPTIONAL_COLUMNS = ('current',)
MIN_SAMPLES = 20


@dataclass
class Recording:
    """Samples of one experiment.

    Attributes
    ----------
    time : ndarray
        Sample times [s], strictly increasing (may be irregular).
    input : ndarray
        The plant input: armature voltage [V] for a voltage plant, or applied torque
        [N m] (force [N] for a linear axis) when ``input_kind == 'torque'``.
    speed : ndarray
        Measured speed [rad/s] (or [m/s] for a linear axis).
    current : ndarray or None
        Measured armature current [A], when the card has it.
    input_kind : {'voltage', 'torque'}
    meta : dict
        Provenance and notes, carried into reports and bags.
    """

    time: np.ndarray
    input: np.ndarray
    speed: np.ndarray
    current: np.ndarray = None
    input_kind: str = 'voltage'
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.time = np.asarray(self.time, dtype=float)
        self.input = np.asarray(self.input, dtype=float)
        self.speed = np.asarray(self.speed, dtype=float)
        if self.current is not None:
            self.current = np.asarray(self.current, dtype=float)

    def __len__(self):
        return self.time.size

    @property
    def has_current(self):
        """True when a current channel is present."""
        return self.current is not None

    @property
    def sample_period(self):
        """Median sample interval [s]."""
        return float(np.median(np.diff(self.time)))

    @property
    def is_regular(self):
        """True when all intervals are equal to within 1 ppm."""
        dt = np.diff(self.time)
        return bool(np.ptp(dt) <= 1e-6 * np.mean(dt))

    def channels(self):
        """Names of the output channels present: speed, and current if measured."""
        return ('speed', 'current') if self.has_current else ('speed',)

    def slice(self, start, stop):
        """A new recording with samples ``start:stop``."""
        cur = None if self.current is None else self.current[start:stop]
        return Recording(self.time[start:stop], self.input[start:stop],
                         self.speed[start:stop], cur, self.input_kind, dict(self.meta))

    def validate(self, min_samples=MIN_SAMPLES):
        """Raise :class:`DataError` with a one-line reason if the data cannot be fitted.

        Checks equal lengths, finite values, strictly increasing time, enough samples and
        an input that actually varies.
        """
        n = self.time.size
        for name in ('input', 'speed') + (('current',) if self.has_current else ()):
            arr = getattr(self, name)
            if arr.shape != self.time.shape:
                raise DataError(f'channel {name!r} has {arr.size} samples but time has {n}')
        if n < min_samples:
            raise DataError(f'too few samples: {n} (need at least {min_samples})')
        for name in ('time', 'input', 'speed') + (('current',) if self.has_current else ()):
            arr = getattr(self, name)
            bad = np.flatnonzero(~np.isfinite(arr))
            if bad.size:
                raise DataError(f'channel {name!r} has {bad.size} NaN/inf value(s), '
                                f'first at sample {bad[0]}')
        dt = np.diff(self.time)
        bad = np.flatnonzero(dt <= 0)
        if bad.size:
            k = bad[0] + 1
            raise DataError(f'time is not strictly increasing at sample {k} '
                            f'(t = {self.time[k - 1]:g} then {self.time[k]:g})')
        if np.ptp(self.input) <= 1e-12 * max(1.0, np.max(np.abs(self.input))):
            raise DataError('no excitation: the input is constant '
                            f'({self.input[0]:g} throughout); use a varying input')
        return self

    def to_dict(self):
        """Plain lists for JSON."""
        d = {'time': self.time.tolist(), 'input': self.input.tolist(),
             'speed': self.speed.tolist(), 'input_kind': self.input_kind, 'meta': self.meta}
        if self.has_current:
            d['current'] = self.current.tolist()
        return d


def read_csv(path, min_samples=MIN_SAMPLES):
    """Read a recording from CSV with a header naming its columns.

    Columns ``time`` [s], ``voltage`` [V], ``speed`` [rad/s] are required, ``current`` [A]
    optional; other columns are ignored. Comma-separated; lines starting with ``#`` are
    comments (``# input_kind: torque`` switches the plant kind).

    Raises
    ------
    DataError
        With the file, line and reason: a missing column, a wrong delimiter, a
        non-numeric cell, NaN/inf, non-increasing time, too few samples, no excitation.
    """
    path = str(path)
    try:
        with open(path, newline='') as fh:
            lines = fh.read().splitlines()
    except OSError as exc:
        raise DataError(f'{path}: cannot read ({exc.strerror})') from None
    except UnicodeDecodeError:
        raise DataError(f'{path}: not a text CSV file') from None
    meta = {'source': path}
    body = []
    for lineno, line in enumerate(lines, 1):
        s = line.strip()
        if not s:
            continue
        if s.startswith('#'):
            key, sep, value = s[1:].partition(':')
            if sep:
                meta[key.strip()] = value.strip()
            continue
        body.append((lineno, line))
    if not body:
        raise DataError(f'{path}: empty file, expected a header line '
                        f'with columns {", ".join(REQUIRED_COLUMNS)}')
    header_line, header = body[0]
    names = [c.strip().lower() for c in next(csv.reader([header]))]
    missing = [c for c in REQUIRED_COLUMNS if c not in names]
    if missing:
        hint = ''
        if len(names) == 1 and any(d in header for d in ';\t|'):
            hint = ' (the file looks delimited by something other than commas)'
        elif all(_is_number(c) for c in names):
            hint = ' (the first line holds numbers: the header is missing)'
        raise DataError(f'{path}:{header_line}: missing column(s) {", ".join(missing)} in '
                        f'header {header.strip()!r}{hint}')
    cols = {c: names.index(c) for c in REQUIRED_COLUMNS + OPTIONAL_COLUMNS if c in names}
    data = {c: [] for c in cols}
    for lineno, line in body[1:]:
        cells = next(csv.reader([line]))
        if len(cells) != len(names):
            raise DataError(f'{path}:{lineno}: {len(cells)} cell(s), header has {len(names)}')
        for c, j in cols.items():
            cell = cells[j].strip()
            try:
                value = float(cell)
            except ValueError:
                raise DataError(f'{path}:{lineno}: column {c!r} has non-numeric value '
                                f'{cell!r}') from None
            if not math.isfinite(value):
                raise DataError(f'{path}:{lineno}: column {c!r} is {cell} (NaN/inf)')
            data[c].append(value)
    time = np.asarray(data['time'])
    dt = np.diff(time)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        k = bad[0] + 1
        lineno = body[1 + k][0]
        what = 'duplicate time stamp' if dt[bad[0]] == 0 else 'time goes backwards'
        raise DataError(f'{path}:{lineno}: {what} (t = {time[k]:g} after {time[k - 1]:g})')
    kind = meta.pop('input_kind', 'voltage')
    if kind not in ('voltage', 'torque'):
        raise DataError(f'{path}: input_kind must be voltage or torque, got {kind!r}')
    rec = Recording(time, np.asarray(data['voltage']), np.asarray(data['speed']),
                    np.asarray(data['current']) if 'current' in data else None, kind, meta)
    try:
        return rec.validate(min_samples)
    except DataError as exc:
        raise DataError(f'{path}: {exc}') from None


def write_csv(rec, path, comments=None):
    """Write a recording as CSV (``time,voltage,speed[,current]``) with ``#`` comments."""
    cols = ['time', 'voltage', 'speed'] + (['current'] if rec.has_current else [])
    arr = np.column_stack([rec.time, rec.input, rec.speed]
                          + ([rec.current] if rec.has_current else []))
    with open(path, 'w', newline='') as fh:
        if rec.input_kind != 'voltage':
            fh.write(f'# input_kind: {rec.input_kind}\n')
        for key, value in (comments or {}).items():
            fh.write(f'# {key}: {value}\n')
        fh.write(','.join(cols) + '\n')
        for row in arr:
            fh.write(','.join(repr(float(v)) for v in row) + '\n')


def _is_number(text):
    try:
        float(text)
    except ValueError:
        return False
    return True
