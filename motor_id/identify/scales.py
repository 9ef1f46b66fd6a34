"""The data scales of one recording: the sizes an effect's start grid and search range are
multiples of (:data:`motor_id.effects.SCALES`)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from motor_id.recording import Recording


def data_scales(rec: Recording, physical: Mapping[str, float], R_m: float | None, T: float,
                dt: float, max_delay: int, counted: bool = False) -> dict[str, float]:
    """The scales of :data:`motor_id.effects.SCALES` measured on one recording.

    ``counted``: the speed sits on an encoder grid (a count difference per period).
    """
    u_max = float(np.max(np.abs(rec.input))) or 1.0
    w_max = float(np.max(np.abs(rec.speed))) or 1.0
    tau = physical['K_T'] * u_max / physical['R_m'] if rec.input_kind == 'voltage' \
        else u_max
    i_rms = float(np.sqrt(np.mean(rec.current ** 2))) if rec.current is not None \
        else u_max / (R_m or 1.0)
    i_rms = i_rms or 1.0
    return {'one': 1.0, 'torque': tau, 'input': u_max, 'speed': w_max,
            'torque/speed': tau / w_max, 'torque/speed^2': tau / w_max ** 2, 'record': T,
            'sample': dt,
            'per_record': 1.0 / T, 'per_sample': 1.0 / dt,
            'heating': (R_m or 1.0) / (i_rms ** 2 * T), 'max_delay': float(max_delay),
            'current': float(np.std(rec.current)) if rec.current is not None else 1.0,
            'lag_floor': dt if counted else 0.5 * dt}


def default_max_delay(n_samples: int) -> int:
    """The longest input delay [samples] an effect's grid covers on a record of
    ``n_samples``: a 25th of it, 2 to 40."""
    return int(min(40, max(2, n_samples // 25)))
