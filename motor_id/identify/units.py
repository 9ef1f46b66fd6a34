"""Internal units of a fit: powers of two that bring extreme but finite data to order one.

The problem works in SI divided by powers of two chosen so that the sample period is
about 10 ms and the input and each output peak near one. Data whose magnitudes lie in
:data:`NORMAL_RANGE` (and periods in :data:`NORMAL_STEP`) keep every power at 2**0, so
that internal units are SI exactly; powers of two make the rescaling itself exact.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import overload, TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from motor_id.errors import DataError, IdentificationError
from motor_id.identify.result import Rescaling

if TYPE_CHECKING:
    from motor_id.recording import Recording

NORMAL_RANGE = (1e-6, 1e6)  # peak magnitudes used as they are; outside, rescaled
NORMAL_STEP = (1e-6, 1.0)   # median sample periods [s] used as they are; outside,
TYPICAL_STEP = 0.01         # rescaled to about this (what the default bounds suit)
QUANTITIES = ('time', 'input', 'speed', 'current')


def _exponent(peak: float, normal: tuple[float, float], typical: float = 1.0) -> int:
    """Power of two dividing a quantity whose peak magnitude is ``peak`` (0: none), so
    that it becomes about ``typical``."""
    if not np.isfinite(peak):
        raise DataError('the data hold magnitudes beyond the floating-point range')
    if peak == 0 or normal[0] <= peak <= normal[1]:
        return 0
    return int(np.round(np.log2(peak / typical)))


def parameter_exponents(exps: Mapping[str, int], input_kind: str) -> dict[str, int]:
    """Powers of two that turn SI parameters into internal ones (value * 2**e).

    Parameters
    ----------
    exps : dict
        Exponents of ``time``, ``input``, ``speed`` and ``current``.
    input_kind : {'voltage', 'torque'}

    Returns
    -------
    dict
        ``{parameter: exponent}``. With time scale T, input U, speed W and current I
        (and torque U I / W, so that K_T and K_b keep one unit): J W^2/(T U I),
        K W/U, B W^2/(U I), L_m I/(T U), R_m I/U; a torque plant: J W/(T U), B W/U.
    """
    t, u, w, i = (exps[k] for k in QUANTITIES)
    if input_kind == 'torque':
        return {'J': w - t - u, 'B': w - u}
    return {'J': 2 * w - t - u - i, 'K_T': w - u, 'K_b': w - u, 'B': 2 * w - u - i,
            'L_m': i - t - u, 'R_m': i - u}


@dataclass(frozen=True)
class InternalUnits:
    """Exponents of the internal units of one recording (all 0: SI)."""

    exponents: dict[str, int]
    input_kind: str = 'voltage'

    @classmethod
    def from_recording(cls, rec: Recording, has_effects: bool = False) -> InternalUnits:
        """Choose the units for a recording.

        Raises
        ------
        DataError
            The data need rescaling and the model has effect terms (whose parameters
            have units of their own): the user converts the data to SI instead.
        """
        with np.errstate(all='ignore'):
            dt = float(np.median(np.diff(rec.time)))
        exps = {'time': _exponent(dt, NORMAL_STEP, TYPICAL_STEP),
                'input': _exponent(float(np.max(np.abs(rec.input))), NORMAL_RANGE),
                'speed': _exponent(float(np.max(np.abs(rec.speed))), NORMAL_RANGE),
                'current': 0}
        if rec.current is not None:
            exps['current'] = _exponent(float(np.max(np.abs(rec.current))), NORMAL_RANGE)
        units = cls(exps, rec.input_kind)
        if has_effects and units.rescaled:
            raise DataError('the data are in extreme units (rescaled internally by '
                            f'{ {k: f"2^{v}" for k, v in exps.items() if v} }); effect '
                            'terms cannot be fitted so: convert the data to SI units')
        return units

    @property
    def rescaled(self) -> bool:
        """True when any quantity is rescaled."""
        return any(self.exponents.values())

    @property
    def parameters(self) -> dict[str, int]:
        """``{parameter: exponent}`` (see :func:`parameter_exponents`)."""
        return parameter_exponents(self.exponents, self.input_kind)

    def to_internal(self, name: str, value: float) -> float:
        """SI value of parameter ``name`` -> internal units (effect parameters: as is)."""
        return math.ldexp(float(value), self.parameters.get(name, 0))

    @overload
    def to_physical(self, name: str, value: float) -> float: ...

    @overload
    def to_physical(self, name: str, value: None) -> None: ...

    def to_physical(self, name: str, value: float | None) -> float | None:
        """Internal value of parameter ``name`` -> SI.

        Raises
        ------
        IdentificationError
            The SI value is outside the floating-point range.
        """
        e = self.parameters.get(name, 0)
        if e == 0 or value is None:
            return value
        out = math.ldexp(float(value), -e)
        if value != 0 and (out == 0 or not math.isfinite(out)):
            raise IdentificationError(f"{name} = {value:g} x 2^{-e} in the data's units is "
                                      'outside the floating-point range: convert the data '
                                      'to SI units')
        return out

    def signal(self, x: ArrayLike, quantity: str) -> np.ndarray:
        """A measured signal (time, input, speed, current) in internal units."""
        out: np.ndarray = np.ldexp(np.asarray(x, dtype=float), -self.exponents[quantity])
        return out

    def physical_signal(self, x: ArrayLike, quantity: str) -> np.ndarray:
        """An internal signal back in the data's units."""
        out: np.ndarray = np.ldexp(np.asarray(x, dtype=float), self.exponents[quantity])
        return out

    def rescaling(self) -> Rescaling | None:
        """The result's ``units`` block, or None when nothing was rescaled."""
        if not self.rescaled:
            return None
        return Rescaling(note='the data were rescaled internally by powers of two (extreme '
                              "units); every reported number is in the data's own units",
                         exponents=dict(self.exponents))
