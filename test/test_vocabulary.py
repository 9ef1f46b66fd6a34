"""One home per word: input kinds, units, methods, parameter names and sample columns are
defined once (contracts / model) and imported everywhere; a new literal copy fails here.

The checks read the code (``ast``), not the docstrings: ``{'voltage', 'torque'}`` in a
numpydoc type line names the choices, it does not copy them. ``motor_id/testing`` is left
out of the literal checks: the independent simulator and the generators state what they
need on purpose, apart from the product. The tests state their expectations themselves.
"""

import ast
import functools
import importlib
from pathlib import Path
import re

from motor_id.contracts import (
    CHANNEL_TOPICS,
    channel_units,
    INPUT_KINDS,
    SAMPLE_COLUMNS,
    TORQUE_UNITS,
    UNITS,
)
from motor_id.identify.problem import METHODS
from motor_id.model import DISCRETISATIONS, PARAM_NAMES

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = sorted(p for folder in ('motor_id', 'benchmarks') for p in (ROOT / folder).rglob('*.py')
                 if 'testing' not in p.parts)
"""Where a literal copy of a word is an error: the package but its test support, and the
benchmarks."""
EVERYWHERE = sorted(p for folder in ('motor_id', 'test', 'benchmarks')
                    for p in (ROOT / folder).rglob('*.py'))
"""Where an import must name a word's home."""
PENDING: dict[tuple[str, str], str] = {}
"""Known copies still to be removed: ``(module, what)``; the test fails once one is gone,
so that its entry goes too."""

HOMES = {
    'input kinds': ('motor_id/contracts.py',),
    'methods': ('motor_id/model.py',),
    'parameter names': ('motor_id/model.py',),
    'units': ('motor_id/contracts.py',),
    'sample columns': ('motor_id/contracts.py',),
}


def _rel(path):
    return path.relative_to(ROOT).as_posix()


@functools.cache
def _tree(path):
    return ast.parse(path.read_text(encoding='utf-8'), str(path))


def _strings(node):
    return {e.value for e in node.elts if isinstance(e, ast.Constant) and isinstance(e.value, str)}


def _collections(path):
    """Tuple, list and set literals of ``path`` with the strings they hold."""
    for node in ast.walk(_tree(path)):
        if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
            yield node, _strings(node)


def _copies(word, contains):
    """``{module: [line, ...]}`` of collection literals outside the word's home for which
    ``contains(strings)`` holds."""
    found = {}
    for path in PRODUCT:
        rel = _rel(path)
        if rel in HOMES[word]:
            continue
        for node, strings in _collections(path):
            if contains(strings):
                found.setdefault(rel, []).append(node.lineno)
    return found


def _check(word, found):
    pending = {m for (m, w) in PENDING if w == word}
    new = {m: lines for m, lines in found.items() if m not in pending}
    assert not new, f'{word} copied (import them from {" / ".join(HOMES[word])}): {new}'
    gone = sorted(pending - set(found))
    assert not gone, f'no longer a copy of the {word}: remove {gone} from PENDING'


def _assigned(name):
    """Modules that assign ``name`` at module level."""
    return sorted(_rel(p) for p in PRODUCT for node in _tree(p).body
                  if isinstance(node, (ast.Assign, ast.AnnAssign))
                  for target in (node.targets if isinstance(node, ast.Assign) else [node.target])
                  if isinstance(target, ast.Name) and target.id == name)


def test_input_kinds_are_defined_once_in_contracts():
    assert _assigned('INPUT_KINDS') == ['motor_id/contracts.py']
    _check('input kinds', _copies('input kinds', lambda s: set(INPUT_KINDS) <= s))


def test_method_lists_are_defined_once_each():
    assert _assigned('METHODS') == ['motor_id/identify/problem.py']
    assert _assigned('DISCRETISATIONS') == ['motor_id/model.py']
    _check('methods', _copies('methods', lambda s: set(DISCRETISATIONS) <= s))
    assert set(DISCRETISATIONS) < set(METHODS)


def test_parameter_names_are_defined_once_in_the_model():
    # a selection of a few symbols ('J', 'B', 'K_T' to unpack an equation) is no copy; all
    # of them, or all but one, is the list written again
    assert _assigned('PARAM_NAMES') == ['motor_id/model.py']
    _check('parameter names', _copies(
        'parameter names', lambda s: len(s & set(PARAM_NAMES)) >= len(PARAM_NAMES) - 1))


def _unit_literals(path):
    """Lines of dict literals that give a parameter or a channel its unit string."""
    names = set(UNITS) | set(TORQUE_UNITS) | set(SAMPLE_COLUMNS) | {'position'}
    units = set(UNITS.values()) | set(TORQUE_UNITS.values()) | {
        u for kind in INPUT_KINDS for linear in (False, True)
        for u in channel_units(kind, linear, position=True).values()}
    for node in ast.walk(_tree(path)):
        if not isinstance(node, ast.Dict):
            continue
        for key, value in zip(node.keys, node.values, strict=True):
            options = [value.body, value.orelse] if isinstance(value, ast.IfExp) else [value]
            if isinstance(key, ast.Constant) and key.value in names and any(
                    isinstance(v, ast.Constant) and v.value in units for v in options):
                yield node.lineno
                break


def test_the_internal_resistance_of_speed_only_records_has_one_home():
    # speed-only voltage data cannot tell R_m: every fit of them (fit, analyze, the
    # experiment's report) runs at identify.space.SPEED_ONLY_R_M, and no module keeps a
    # nominal resistance of its own (the experiment's NOMINAL_R was one)
    assert _assigned('SPEED_ONLY_R_M') == ['motor_id/identify/space.py']
    nominal = re.compile(r'(?i)^_?(nominal_r(_m)?|r(_m)?_nominal|nominal_resistance)$')
    copies = sorted(_rel(p) for p in PRODUCT for node in ast.walk(_tree(p))
                    if isinstance(node, (ast.Assign, ast.AnnAssign))
                    for target in (node.targets if isinstance(node, ast.Assign)
                                   else [node.target])
                    if isinstance(target, ast.Name) and nominal.match(target.id))
    assert not copies, f'a nominal resistance besides SPEED_ONLY_R_M: {copies}'


def test_units_have_one_home():
    # {'speed': 'rad/s'} or {'K_T': 'N m/A'} anywhere but contracts is a second unit table;
    # contracts.UNITS, TORQUE_UNITS, units_of and channel_units are the one
    found = {}
    for path in PRODUCT:
        if _rel(path) not in HOMES['units']:
            lines = list(_unit_literals(path))
            if lines:
                found[_rel(path)] = lines
    _check('units', found)


def _handles_rows(path):
    """A module that builds, reads or moves sample rows."""
    text = path.read_text(encoding='utf-8')
    return any(word in text for word in (
        'SAMPLE_COLUMNS', 'batch_rows', 'rows_to_msg', 'msg_to_rows', 'write_samples',
        'sample_rows', 'SAMPLES_LABEL'))


def _column_literals(path):
    """Lines that index a row by a column number (``rows[:, 3]``, ``rows[k, 1]``) or map a
    column name to its number (``{'speed': 3}``)."""
    width = len(SAMPLE_COLUMNS)

    def column_number(node):
        return isinstance(node, ast.Constant) and type(node.value) is int \
            and -width <= node.value < width

    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Tuple) \
                and len(node.slice.elts) == 2 and column_number(node.slice.elts[1]):
            yield node.lineno
        elif isinstance(node, ast.Dict) and any(
                isinstance(k, ast.Constant) and k.value in SAMPLE_COLUMNS + CHANNEL_TOPICS
                and column_number(v) for k, v in zip(node.keys, node.values, strict=True)):
            yield node.lineno


def test_sample_columns_are_named_not_numbered_where_rows_are_handled():
    # the driver, the buffer, the bag reader and writer, the replayer, the messages index
    # sample rows through contracts' column constants (SEQ, T, INPUT, SPEED, CURRENT,
    # FLAGS, CHANNEL_COLUMNS), never a literal column number
    assert _assigned('SAMPLE_COLUMNS') == ['motor_id/contracts.py']
    handling = [p for p in PRODUCT if _handles_rows(p) and _rel(p) not in HOMES['sample columns']]
    assert {'motor_id/nodes/driver.py', 'motor_id/data/buffer.py', 'motor_id/bag/reader.py',
            'motor_id/bag/writer.py', 'motor_id/nodes/replayer.py',
            'motor_id/nodes/messages.py'} <= {_rel(p) for p in handling}
    found = {_rel(p): lines for p in handling if (lines := list(_column_literals(p)))}
    _check('sample columns', found)


def _modules():
    """``{dotted name: path}`` of motor_id's modules (packages as their ``__init__``)."""
    out = {}
    for path in (ROOT / 'motor_id').rglob('*.py'):
        parts = path.relative_to(ROOT).with_suffix('').parts
        out['.'.join(parts[:-1] if parts[-1] == '__init__' else parts)] = path
    return out


def test_names_are_imported_from_their_home():
    """``from motor_id.a import NAME`` where ``a`` only imported NAME itself (a flag through
    the protocol, an effect through the model) names a second home; import it from where it
    is defined. A package's ``__init__`` is its public face and may be imported from."""
    modules = _modules()
    defined, imported = {}, {}
    for name, path in modules.items():
        body = _tree(path).body
        defined[name] = {t.id for node in body if isinstance(node, (ast.Assign, ast.AnnAssign))
                         for t in (node.targets if isinstance(node, ast.Assign)
                                   else [node.target]) if isinstance(t, ast.Name)} | {
            node.name for node in body
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))}
        imported[name] = {a.asname or a.name: (node.module, a.name) for node in body
                          if isinstance(node, ast.ImportFrom) and node.module
                          for a in node.names}

    def home(module, name, depth=0):
        if name in defined.get(module, ()) or depth > 20:
            return module
        source = imported.get(module, {}).get(name)
        return home(*source, depth + 1) if source and source[0] in modules else module

    found = {}
    for path in EVERYWHERE:
        for node in ast.walk(_tree(path)):
            if isinstance(node, ast.ImportFrom) and node.module in modules \
                    and modules[node.module].name != '__init__.py':
                for alias in node.names:
                    where = home(node.module, alias.name)
                    if where != node.module:
                        found.setdefault((_rel(path), f'import {alias.name} from '
                                          f'{node.module}'), where)
    pending = {k for k in PENDING if k[1].startswith('import ')}
    new = {k: v for k, v in found.items() if k not in pending}
    assert not new, 'import these from their home: ' + ', '.join(
        f'{m}: {what} (home {where})' for (m, what), where in sorted(new.items()))
    gone = sorted(pending - set(found))
    assert not gone, f'imported from the home now: remove {gone} from PENDING'


EFFECT_HOME = ROOT / 'motor_id' / 'effects'
"""Where each effect lives: one module per effect (``motor_id/effects/<name>.py``)."""
MAX_EFFECT_LITERALS = 15
MAX_EFFECT_MODULES = 3
"""Most effect names written as string literals outside the effects' home and the test
support, and most modules they may be in (issue 29): other code finds an effect by its
entry's attributes and its parameters' roles, never by its name."""


def _effect_literals():
    """``{module: count}`` of quoted effect names (``'dead_zone'``, as ``grep`` finds
    them: code, docstrings and comments alike) in motor_id outside the home and testing."""
    from motor_id.effects import EFFECTS

    names = '|'.join(sorted(EFFECTS, key=len, reverse=True))
    pattern = re.compile(rf"'({names})'")
    found = {}
    for path in sorted((ROOT / 'motor_id').rglob('*.py')):
        if 'testing' in path.parts or EFFECT_HOME in path.parents:
            continue
        n = len(pattern.findall(path.read_text(encoding='utf-8')))
        if n:
            found[_rel(path)] = n
    return found


def test_each_effect_lives_in_one_home():
    from motor_id.effects import EFFECTS

    found = _effect_literals()
    assert sum(found.values()) <= MAX_EFFECT_LITERALS and len(found) <= MAX_EFFECT_MODULES, (
        f'effect names written outside motor_id/effects/ ({sum(found.values())} in '
        f'{len(found)} modules; at most {MAX_EFFECT_LITERALS} in {MAX_EFFECT_MODULES}): '
        f'{found}; read the entry (EFFECTS[name].<hook>, a parameter role) instead')
    # every entry sits in its own module, named after it
    for name, spec in EFFECTS.items():
        assert (EFFECT_HOME / f'{name}.py').exists(), f'{name} has no module of its own'
        assert importlib.import_module(f'motor_id.effects.{name}').SPEC is spec
    assert not (ROOT / 'motor_id' / 'effects.py').exists()
