"""CSV recordings: a vectorised reader with column mapping, and the writer."""

import csv
import itertools
import os
import re
from typing import Any

import numpy as np

from motor_id.contracts import INPUT_KINDS
from motor_id.errors import ConfigError, DataError
from motor_id.recording import bad_magnitude, MIN_SAMPLES, Recording

ROLES = ('time', 'input', 'speed', 'current', 'position')
"""Channels a column can be mapped to (``--columns ROLE=NAME,...``)."""
INPUT_NAMES = {'voltage': 'voltage', 'torque': 'torque', 'force': 'torque'}
"""Input column names recognised without a mapping, and the plant kind each one sets."""
DELIMITERS = (',', ';', '\t', '|')
"""Cell delimiters a CSV may use (found from its header, or given)."""
DECIMALS = ('.', ',')
"""Decimal marks (a comma only with another delimiter, as spreadsheets write)."""


def parse_columns(text: str | dict[str, str] | None) -> dict[str, str]:
    """Parse a column mapping ``time=t,input=u_cmd,speed=omega,current=i_a``.

    Parameters
    ----------
    text : str or dict or None
        The option value (or an already parsed dict, e.g. from a profile).

    Returns
    -------
    dict
        ``{role: column name}`` (names lower-cased, as headers are matched
        case-insensitively); empty when ``text`` is empty.

    Raises
    ------
    ConfigError
        An item without ``=``, an unknown role or a role given twice.
    """
    if not text:
        return {}
    items = text.items() if isinstance(text, dict) else (
        item.partition('=')[::2] for item in str(text).split(',') if item.strip())
    out = {}
    for role, name in items:
        role, name = str(role).strip().lower(), str(name).strip().lower()
        if role not in ROLES or not name:
            raise ConfigError(f'columns wants ROLE=NAME items with ROLE one of '
                              f'{", ".join(ROLES)}; got {role!r}={name!r}',
                              params=('columns',))
        if role in out:
            raise ConfigError(f'columns maps {role!r} twice', params=('columns',))
        out[role] = name
    return out


def read_csv(path: str | os.PathLike[str], min_samples: int = MIN_SAMPLES,
             columns: str | dict[str, str] | None = None,
             input_kind: str | None = None, delimiter: str | None = None,
             decimal: str | None = None) -> Recording:
    """Read a recording from CSV with a header naming its columns.

    Columns ``time`` [s], the input and ``speed`` [rad/s] are required, ``current`` [A]
    and ``position`` [rad] (or [m]) optional; other columns are ignored. The input
    column is named ``voltage`` [V] (voltage plant), ``torque`` [N m] or ``force`` [N]
    (torque plant), or mapped with ``columns``. Comma-separated, or as a spreadsheet
    exports it where the decimal mark is a comma: ``;`` between cells and ``0,5`` for one
    half (the delimiter is found from the header, a ``sep=;`` first line or
    ``delimiter``; the decimal comma from the cells or ``decimal``). Lines starting with
    ``#`` are comments (``# input_kind: torque`` sets the plant kind); a UTF-8 byte-order
    mark is accepted.

    Parameters
    ----------
    path : str or os.PathLike
    min_samples : int
    columns : dict or str, optional
        ``{role: header name}`` for roles ``time, input, speed, current, position`` (see
        :func:`parse_columns`); unmapped roles use the standard names.
    input_kind : {'voltage', 'torque'}, optional
        Overrides the kind given by a comment or by the input column's name.
    delimiter : {',', ';', '\\t', '|'}, optional
        The cell delimiter (default: found from the header).
    decimal : {'.', ','}, optional
        The decimal mark (default: ``,`` where the delimiter is not a comma and the
        cells hold commas, else ``.``).

    Returns
    -------
    Recording
        Validated; ``meta['csv_dialect']`` says the delimiter and decimal mark of a file
        that is not plain comma-separated.

    Raises
    ------
    DataError
        With the file, line and reason: a missing column, a wrong delimiter, a
        non-numeric cell, NaN/inf, an overflowing magnitude, non-increasing time, too
        few samples, a constant input or speed.

    Notes
    -----
    The kind of the plant is, by precedence: ``input_kind``, a ``# input_kind:``
    comment, the input column's name (``torque`` / ``force`` -> torque), voltage.
    """
    path = str(path)
    columns = parse_columns(columns)
    if input_kind is not None and input_kind not in INPUT_KINDS:
        raise ConfigError(f'input kind must be voltage or torque, got {input_kind!r}')
    meta, body, linenos = _split_lines(path)
    if body and body[0].replace(' ', '').lower().startswith('sep=') and delimiter is None:
        delimiter = body[0].strip()[4:5] or None   # a spreadsheet's delimiter hint line
        body, linenos = body[1:], linenos[1:]
    if not body:
        raise DataError(f'{path}: empty file, expected a header line '
                        f'with columns time, voltage (or torque, force), speed')
    dialect = _dialect(path, body, delimiter, decimal)
    if dialect != (',', '.'):
        meta['csv_dialect'] = {'delimiter': dialect[0], 'decimal': dialect[1]}
        table = str.maketrans({dialect[0]: ',', **({',': '.'} if dialect[1] == ',' else {})})
        body = [line.translate(table) for line in body]
    header_line, header = int(linenos[0]), body[0]
    names = [c.strip().lower() for c in next(csv.reader([header]))]
    cols, input_name = _find_columns(path, header_line, header, names, columns)
    kind = (input_kind or meta.pop('input_kind', None)
            or INPUT_NAMES.get(input_name or '', 'voltage'))
    meta.pop('input_kind', None)
    if kind not in INPUT_KINDS:
        raise DataError(f'{path}: input_kind must be voltage or torque, got {kind!r}')
    if kind == 'voltage' and INPUT_NAMES.get(input_name or '') == 'torque':
        raise DataError(f'{path}: the input column {input_name!r} is a {input_name}, not a '
                        'voltage; drop the voltage input kind')
    data = _parse_body(path, linenos[1:], body[1:], names, cols)
    time = data['time']
    dt = np.diff(time)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        k = bad[0] + 1
        what = 'duplicate time stamp' if dt[bad[0]] == 0 else 'time goes backwards'
        raise DataError(f'{path}:{linenos[1 + k]}: {what} (t = {time[k]:g} after '
                        f'{time[k - 1]:g})')
    if columns:
        meta['columns'] = {role: names[j] for role, j in cols.items()}
    rec = Recording(time, data['input'], data['speed'], data.get('current'), kind, meta,
                    position=data.get('position'))
    try:
        return rec.validate(min_samples)
    except DataError as exc:
        raise DataError(f'{path}: {exc}') from None


def _dialect(path: str, body: list[str], delimiter: str | None,
             decimal: str | None) -> tuple[str, str]:
    """``(delimiter, decimal mark)``: the ones given, or found from the header and cells."""
    if delimiter is not None and delimiter not in DELIMITERS:
        raise ConfigError(f'delimiter must be one of {", ".join(map(repr, DELIMITERS))}, '
                          f'got {delimiter!r}', params=('delimiter',))
    if decimal is not None and decimal not in DECIMALS:
        raise ConfigError(f'decimal must be "." or ",", got {decimal!r}',
                          params=('decimal',))
    if delimiter is None:
        counts = {d: body[0].count(d) for d in DELIMITERS}
        delimiter = max(DELIMITERS, key=lambda d: (counts[d], d == ','))
        if counts[delimiter] == 0:
            delimiter = ','
    if decimal is None:
        sample = body[1:51]
        decimal = ',' if delimiter != ',' and any(',' in line for line in sample) else '.'
        if decimal == ',' and any('.' in line for line in sample):
            raise DataError(f'{path}: cells hold both "." and "," (thousands separators?); '
                            'say which is the decimal mark (decimal)', params=('decimal',))
    if delimiter == decimal:
        raise ConfigError(f'{path}: the delimiter and the decimal mark cannot both be '
                          f'{delimiter!r}')
    return delimiter, decimal


def _split_lines(path: str | os.PathLike[str]) -> tuple[dict[str, Any], list[str], np.ndarray]:
    """Comment metadata, the non-comment lines of a text file and their line numbers."""
    try:
        with open(path, encoding='utf-8-sig', newline='') as fh:
            lines = fh.read().splitlines()
    except OSError as exc:
        raise DataError(f'{path}: cannot read ({exc.strerror})') from exc
    except UnicodeDecodeError as exc:
        raise DataError(f'{path}: not a text CSV file (expected UTF-8)') from exc
    meta: dict[str, Any] = {'source': path}
    # only blank, comment or indented lines need a closer look (one cheap pass)
    special = [i for i, line in enumerate(lines) if not line or line[0] in '# \t']
    drop = []
    for i in special:
        s = lines[i].strip()
        if not s:
            drop.append(i)
        elif s[0] == '#':
            key, sep, value = s[1:].partition(':')
            if sep:
                meta[key.strip()] = value.strip()
            drop.append(i)
    linenos = np.delete(np.arange(1, len(lines) + 1), drop)
    if len(drop) <= 64:         # a few comment lines: delete in place
        for i in reversed(drop):
            del lines[i]
    else:
        dropped = set(drop)
        lines = [line for i, line in enumerate(lines) if i not in dropped]
    return meta, lines, linenos


def _find_columns(path: str | os.PathLike[str], header_line: int, header: str,
                  names: list[str], columns: dict[str, str]) -> tuple[dict[str, int], str | None]:
    """Header index of each role present, and the name of the input column."""
    wanted: dict[str, str | None] = {}
    for role in ROLES:
        if role in columns:
            wanted[role] = columns[role]
        elif role == 'input':
            found = [n for n in INPUT_NAMES if n in names]
            if len(found) > 1:
                raise DataError(f'{path}:{header_line}: the header has several input '
                                f'columns ({", ".join(found)}); choose one with columns '
                                "'input=NAME'", params=('columns',))
            wanted[role] = found[0] if found else None
        else:
            wanted[role] = role
    missing = []
    for role in ('time', 'input', 'speed'):
        name = wanted[role]
        if name is None:
            missing.append('voltage (or torque, force)')
        elif name not in names:
            missing.append(name)
    for role in ('current', 'position'):
        if role in columns and columns[role] not in names:
            missing.append(columns[role])
    if missing:
        hint = ''
        if len(names) == 1 and re.search(r'[^\w\s]', header):
            hint = (' (the file looks delimited by something other than '
                    f'{", ".join(map(repr, DELIMITERS))})')
        elif all(_is_number(c) for c in names):
            hint = ' (the first line holds numbers: the header is missing)'
        elif columns:
            hint = f' (columns present: {", ".join(names)})'
        else:
            hint = " (map other names with columns 'time=T,input=U,speed=W,current=I')"
        raise DataError(f'{path}:{header_line}: missing column(s) {", ".join(missing)} in '
                        f'header {header.strip()!r}{hint}', params=('columns',))
    cols = {role: names.index(name) for role, name in wanted.items()
            if name is not None and name in names}
    return cols, wanted['input']


def _parse_body(path: str | os.PathLike[str], linenos: np.ndarray, lines: list[str],
                names: list[str], cols: dict[str, int]) -> dict[str, np.ndarray]:
    """Numeric columns of the data lines (vectorised; a slow pass only to name an error)."""
    width = len(names)
    n = len(lines)
    joined = ','.join(lines)
    rows = list(csv.reader(lines)) if '"' in joined else None
    if rows is None:
        counts = np.fromiter(map(str.count, lines, itertools.repeat(',', n)), dtype=np.int64,
                             count=n)
        bad = np.flatnonzero(counts != width - 1)
        if bad.size:
            k = int(bad[0])
            raise DataError(f'{path}:{linenos[k]}: {counts[k] + 1} cell(s), header has '
                            f'{width}')
        flat = joined.split(',') if n else []
    else:
        for k, cells in enumerate(rows):
            if len(cells) != width:
                raise DataError(f'{path}:{linenos[k]}: {len(cells)} cell(s), header '
                                f'has {width}')
        flat = [cell for cells in rows for cell in cells]
    data = {}
    first_bad = []
    for role, j in cols.items():
        cells = flat[j::width]
        try:
            values = np.fromiter(map(float, cells), dtype=float, count=n)
        except ValueError:
            k = _first_non_number(cells)
            first_bad.append((k, list(cols).index(role), 'text', role, cells[k].strip()))
            continue
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            k = int(bad[0])
            first_bad.append((k, list(cols).index(role), 'nan', role, cells[k].strip()))
        else:
            found = bad_magnitude(values, relative=role != 'time')
            if found:
                first_bad.append((found[0], list(cols).index(role), found[1], role, ''))
        data[role] = values
    if first_bad:
        k, _, what, role, cell = min(first_bad)
        where = f'{path}:{linenos[k]}: column {names[cols[role]]!r}'
        if what == 'text':
            raise DataError(f'{where} has non-numeric value {cell!r}')
        if what == 'nan':
            raise DataError(f'{where} is {cell} (NaN/inf)')
        raise DataError(f'{where}: {what}')
    return data


def write_csv(rec: Recording, path: str | os.PathLike[str],
              comments: dict[str, Any] | None = None) -> None:
    """Write a recording as CSV (``time,voltage|torque,speed[,current][,position]``).

    Parameters
    ----------
    rec : Recording
    path : str or os.PathLike
    comments : dict, optional
        Written as ``# key: value`` lines before the header.
    """
    name = 'voltage' if rec.input_kind == 'voltage' else 'torque'
    extra = [(k, v) for k, v in (('current', rec.current), ('position', rec.position))
             if v is not None]
    cols = ['time', name, 'speed'] + [k for k, _ in extra]
    arr = np.column_stack([rec.time, rec.input, rec.speed] + [v for _, v in extra])
    with open(path, 'w', newline='') as fh:
        if rec.input_kind != 'voltage':
            fh.write(f'# input_kind: {rec.input_kind}\n')
        for key, value in (comments or {}).items():
            fh.write(f'# {key}: {value}\n')
        fh.write(','.join(cols) + '\n')
        fh.writelines(','.join(map(repr, row)) + '\n' for row in arr.tolist())


def _first_non_number(cells: list[str], block: int = 4096) -> int:
    """Index of the first cell float() refuses (block-wise: one C pass, one short scan)."""
    for start in range(0, len(cells), block):
        chunk = cells[start:start + block]
        try:
            list(map(float, chunk))
        except ValueError:
            return start + next(k for k, cell in enumerate(chunk) if not _is_number(cell))
    return next(k for k, cell in enumerate(cells) if not _is_number(cell))


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True

