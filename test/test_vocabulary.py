"""One home per word: input kinds, units, methods and columns are defined once."""

from pathlib import Path
import re

PACKAGE = Path(__file__).resolve().parents[1] / 'motor_id'
SOURCES = sorted(p for p in PACKAGE.rglob('*.py') if 'testing' not in p.parts)


def _hits(pattern):
    rx = re.compile(pattern)
    return [f'{p.relative_to(PACKAGE.parent)}:{k}' for p in SOURCES
            for k, line in enumerate(p.read_text().splitlines(), 1) if rx.search(line)]


def test_input_kinds_are_defined_once_in_contracts():
    assert _hits(r'^INPUT_KINDS\s*=') == ['motor_id/contracts.py:' +
                                          str(_line('motor_id/contracts.py', 'INPUT_KINDS ='))]
    assert _hits(r"\(\s*'voltage',\s*'torque'\s*\)") == [
        'motor_id/contracts.py:' + str(_line('motor_id/contracts.py', 'INPUT_KINDS ='))]


def test_parameter_units_have_one_home():
    # a dict spelling a parameter's unit ('K_T': 'N m/A') lives only in contracts.UNITS
    found = _hits(r"'K_T':\s*'N m/A'")
    assert found == ['motor_id/contracts.py:' +
                     str(_line('motor_id/contracts.py', "'J': 'kg m^2', 'K_T'"))], found


def test_method_lists_are_defined_once_each():
    assert [h.split(':')[0] for h in _hits(r'^METHODS\s*=')] == ['motor_id/identify/problem.py']
    assert [h.split(':')[0] for h in _hits(r'^DISCRETISATIONS\s*=')] == ['motor_id/model.py']


def test_sample_columns_are_named_not_numbered_where_rows_are_handled():
    # the driver, the buffer, the bag reader and the replayer index sample rows through
    # contracts' column constants, never a literal column number
    rx = re.compile(r'\[\s*:\s*,\s*[0-5]\s*\]')
    files = ['nodes/driver.py', 'data/buffer.py', 'bag/reader.py', 'bag/writer.py',
             'nodes/replayer.py', 'nodes/messages.py']
    found = [f'{f}:{k}' for f in files
             for k, line in enumerate((PACKAGE / f).read_text().splitlines(), 1)
             if rx.search(line)]
    assert found == [], found


def _line(rel, text):
    lines = (PACKAGE.parent / rel).read_text().splitlines()
    return next(k for k, line in enumerate(lines, 1) if text in line)
