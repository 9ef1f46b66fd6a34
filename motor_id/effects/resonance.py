"""A compliant shaft between motor and load (a two-mass system)."""

from collections.abc import Mapping

from motor_id.effects.spec import EffectParam, EffectSpec

ALIAS = 0.8
"""A mode above this fraction of the Nyquist frequency is an alias, not a resonance."""


def aliased(values: Mapping[str, float], scales: Mapping[str, float]) -> str:
    """Why a resonance is an alias of the sampling ('' when it is not).

    A resonance at or near the Nyquist frequency (half the sample rate) cannot be told
    from an alias of anything faster, nor from a discrete-time artefact of the fit.
    """
    rate = scales.get('per_sample')
    if not values or not rate or 'f_r' not in values:
        return ''
    nyquist = 0.5 * rate
    if values['f_r'] >= ALIAS * nyquist:
        return (f'a resonance at {values["f_r"]:.3g} Hz is at or above {ALIAS:.0%} of the '
                f'Nyquist frequency ({nyquist:.3g} Hz): an alias, not a physical mode')
    return ''


SLOWEST = 3.0
"""Fewest periods of a mode over the whole record: a slower one is a drift, not a mode."""


def implausible(values: Mapping[str, float], scales: Mapping[str, float]) -> str:
    """Why a fitted resonance is not one ('' when it may be): an alias of the sampling
    (:func:`aliased`), or a mode of fewer than :data:`SLOWEST` periods over the whole
    record (the least the equation-error search tries). A SysId routine of an arm with
    no coupling at all had taken one of 0.029 Hz, a period of 34 s: it fitted a slow
    drift, cut the held-out error by 63 % and put kA 185 % high."""
    why = aliased(values, scales)
    per_record = scales.get('per_record')
    if why or not values or not per_record or 'f_r' not in values:
        return why
    if values['f_r'] < SLOWEST * per_record:
        return (f'a resonance at {values["f_r"]:.3g} Hz makes fewer than {SLOWEST:g} '
                'periods over the record: a drift, not a mode')
    return ''


SPEC = EffectSpec(
    'resonance', 'two-mass shaft: J_m = J/(1+r), J_l = J r/(1+r), k_s = J_l (2 pi f_r)^2, '
    'c_s = 2 zeta sqrt(k_s J_l)',
    (EffectParam('r', '-', 1.0, 0.01, 100.0, 'one', (0.25, 4.0, 3)),
     EffectParam('f_r', 'Hz', 4.0, 0.01, 1e3, 'per_sample', ((3.0, 'per_record'), 0.2, 10),
                 ((3.0, 'per_record'), 0.5)),
     EffectParam('zeta', '-', 0.05, 0.0, 5.0, 'one', (0.03, 0.15, 2))),
    description='a compliant shaft between motor and load (or any damped coupling of two '
    'masses: a drivetrain whose wheels slip on the floor, the robot behind them)',
    plant_term=True,
    check=implausible,
    stage_rule='always')
