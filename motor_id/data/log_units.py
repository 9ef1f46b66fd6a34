"""Unit names as logs write them (WPILib's units in a DataLog's entry metadata, plural,
abbreviated, ``per Second`` or ``/s`` for speeds, JSON metadata): their SI values."""

from __future__ import annotations

import json
import math
import re

_ANGLE = {'rotation': 2.0 * math.pi, 'revolution': 2.0 * math.pi, 'rot': 2.0 * math.pi,
          'rev': 2.0 * math.pi, 'radian': 1.0, 'rad': 1.0, 'degree': math.pi / 180.0,
          'deg': math.pi / 180.0}
_LENGTH = {'meter': 1.0, 'metre': 1.0, 'm': 1.0, 'centimeter': 0.01, 'cm': 0.01,
           'millimeter': 0.001, 'mm': 0.001, 'foot': 0.3048, 'feet': 0.3048, 'ft': 0.3048,
           'inch': 0.0254, 'inches': 0.0254, 'in': 0.0254}
_PER_TIME = {'second': 1.0, 'sec': 1.0, 's': 1.0, 'minute': 1.0 / 60.0, 'min': 1.0 / 60.0}
_SHORT_SPEEDS = {'rps': 'rotation per second', 'rpm': 'rotation per minute',
                 'mps': 'meter per second', 'fps': 'foot per second'}
VOLTS = ('', 'v', 'volt', 'volts')
"""A voltage entry's units (none: volts)."""
UNIT_NAMES = ('Rotation', 'Radian', 'Degree', 'Meter', 'Foot', 'Inch')
"""Position units :class:`LogEntries`' ``units`` takes (any spelling the metadata may use
is read too: plural, abbreviated, ``per Second`` or ``/s`` for speeds)."""


def unit_of(metadata: str) -> str:
    """The unit an entry's metadata names: the text itself, or the ``unit`` of a JSON
    object (AdvantageKit's ``{"source": "AdvantageKit", "unit": "Volt"}``; '' without)."""
    text = metadata.strip()
    if not text.startswith('{'):
        return text
    try:
        obj = json.loads(text)
    except ValueError:
        return text
    unit = obj.get('unit', obj.get('units', '')) if isinstance(obj, dict) else ''
    return unit.strip() if isinstance(unit, str) else ''


def parse_unit(text: str, speed: bool = False) -> tuple[float, bool] | None:
    """SI value of one ``text`` unit and whether it is a length; None when not known.

    ``speed``: a speed unit (``Rotation per Second``, ``m/s``, ``rpm``): the SI value of
    one unit per second; otherwise a position unit (``Rotation``, ``Meter``, ``deg``).
    """
    words = text.strip().lower()
    words = _SHORT_SPEEDS.get(words, words)
    per = 1.0
    if speed:
        parts = re.split(r'\s*(?:/|\bper\b)\s*', words)
        if len(parts) != 2 or _singular(parts[1]) not in _PER_TIME:
            return None
        words, per = parts[0], _PER_TIME[_singular(parts[1])]
    name = _singular(words)
    if name in _ANGLE:
        return _ANGLE[name] * per, False
    if name in _LENGTH:
        return _LENGTH[name] * per, True
    return None


def _singular(word: str) -> str:
    word = word.strip()
    if word in _LENGTH or word in _ANGLE or word in _PER_TIME:
        return word
    return word[:-1] if word.endswith('s') else word
