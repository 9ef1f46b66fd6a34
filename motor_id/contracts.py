"""The one home of the contracts between modules: sample rows, flags, topics, units, QoS.

The driver, the identifier, the bag writer and reader, the ring buffer and the serial
protocol all read these names from here; none of them writes its own copy.

Sample rows
    Every sample travels as one row of :data:`SAMPLE_COLUMNS`: card sequence number, card
    time [s], plant input (armature voltage [V], or torque [N m] / force [N] for a
    torque-input plant), speed [rad/s] (or [m/s]), current [A] (NaN when the card has
    none) and the status flags. On the ``samples`` topic and in bags a batch of rows is a
    row-major ``std_msgs/msg/Float64MultiArray`` with ``layout.dim[0] = ('samples', n,
    6 n)``, ``layout.dim[1] = (SAMPLES_LABEL, 6, 6)`` and ``data_offset = 0``.
"""

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

SAMPLE_COLUMNS = ('seq', 't', 'voltage', 'speed', 'current', 'flags')
"""Columns of a sample row (the wire and bag name of the input column stays 'voltage')."""
SEQ, T, INPUT, SPEED, CURRENT, FLAGS = range(len(SAMPLE_COLUMNS))
"""Column indices of :data:`SAMPLE_COLUMNS`."""
SAMPLES_LABEL = ','.join(SAMPLE_COLUMNS)
"""``layout.dim[1].label`` of a sample batch."""
BATCH_LABEL = 'samples'
"""``layout.dim[0].label`` of a sample batch."""

# Status flags as the samples carry them (the card's frame flags, bit for bit).
FLAG_CURRENT = 0x0001
"""A current value is present."""
FLAG_PROFILE = 0x0002
"""The input comes from a running excitation profile."""
FLAG_PROFILE_END = 0x0004
"""Last sample of an excitation profile."""
FLAG_STARTUP = 0x0008
"""First sample after the card (re)started; its sequence restarts here."""
FLAG_OVERRUN = 0x0010
"""The card missed a sampling deadline before this sample (its time stamp is exact)."""
FLAG_LIMIT = 0x0020
"""A safety limit (voltage, speed, current, watchdog) forced the output to 0 V."""
FLAG_NAMES = {FLAG_CURRENT: 'current', FLAG_PROFILE: 'profile',
              FLAG_PROFILE_END: 'profile_end', FLAG_STARTUP: 'startup',
              FLAG_OVERRUN: 'overrun', FLAG_LIMIT: 'limit'}

# Topics (relative names: they land under the node's namespace).
SAMPLES_TOPIC = 'samples'
CHANNEL_TOPICS = ('voltage', 'speed', 'current')
CHANNEL_COLUMNS = dict(zip(CHANNEL_TOPICS, (INPUT, SPEED, CURRENT), strict=True))
"""The sample column each channel topic carries."""
JOINT_STATES_TOPIC = 'joint_states'
VOLTAGE_COMMAND_TOPIC = 'voltage_command'
DIAGNOSTICS_TOPIC = '/diagnostics'
DiagnosticValue = str | int | float | bool | None
"""A value of a diagnostic key/value pair (sent as text in ``diagnostic_msgs/KeyValue``)."""
ESTIMATE_TOPIC = 'estimate'
REPORT_TOPIC = 'report'
# The same topics as a bag records them (absolute names).
BAG_SAMPLES_TOPIC = '/samples'
BAG_META_TOPIC = '/motor_id/meta'
BAG_POSITION_TOPIC = '/motor_id/position'
"""A recording's measured position, when it has one: batches of ``(seq, position)`` rows
(Float64MultiArray, second dimension labelled :data:`POSITION_LABEL`), beside the
``/samples`` rows of the same sequence numbers."""
POSITION_LABEL = 'seq,position'
BAG_ESTIMATE_TOPIC = '/identifier/estimate'

# QoS depths, in one place: a slow subscriber of samples loses nothing within this depth.
SAMPLES_DEPTH = 10000
CHANNEL_DEPTH = 100
DIAGNOSTICS_DEPTH = 10
LATCHED_DEPTH = 1

INPUT_KINDS = ('voltage', 'torque')
"""What drives a plant: the armature voltage, or a torque (force) from a current-controlled
drive."""

UNITS = {
    'J': 'kg m^2', 'K_T': 'N m/A', 'K_b': 'V s/rad', 'B': 'N m s/rad', 'L_m': 'H',
    'R_m': 'Ohm', 'time': 's', 'input': 'V', 'speed': 'rad/s', 'current': 'A',
    'kS': 'V', 'kV': 'V s/rad', 'kA': 'V s^2/rad', 'kG': 'V', 'offset': 'rad',
}
"""SI units of the parameters and channels of a voltage plant."""
TORQUE_UNITS = {'J': 'kg m^2 (or kg)', 'B': 'N m s/rad (or N s/m)', 'input': 'N m (or N)',
                'kS': 'N m', 'kV': 'N m s/rad', 'kA': 'N m s^2/rad', 'kG': 'N m'}
"""Units that differ for a torque- (or force-) input plant."""


LINEAR_SUBSTITUTIONS = (('kg m^2 (or kg)', 'kg'), ('N m s/rad (or N s/m)', 'N s/m'),
                        ('N m (or N)', 'N'), ('kg m^2', 'kg'), ('N m', 'N'), ('rad', 'm'))
"""How a rotary unit reads on a linear axis (in this order): torque becomes force, an
inertia a mass, an angle a length."""


def linear_unit(unit: str) -> str:
    """The unit ``unit`` of a rotary axis as it reads on a linear one (``V s/rad`` ->
    ``V s/m``, ``N m/A`` -> ``N/A``, ``kg m^2`` -> ``kg``, ``rad/s`` -> ``m/s``)."""
    for rotary, linear in LINEAR_SUBSTITUTIONS:
        unit = unit.replace(rotary, linear)
    return unit


def units_of(input_kind: str = 'voltage', linear: bool = False) -> dict[str, str]:
    """SI units by parameter (and channel) name for a ``voltage`` or ``torque`` plant, of a
    rotary axis or (``linear``) a linear one: speed in m/s, kV in V s/m, K_T in N/A."""
    units = dict(UNITS)
    if input_kind == 'torque':
        units.update(TORQUE_UNITS)
    if linear:
        units = {k: linear_unit(u) for k, u in units.items()}
    return units


def channel_units(input_kind: str = 'voltage', linear: bool = False,
                  position: bool = False) -> dict[str, str]:
    """Units of a recording's channels by sample column name (a bag's ``meta['units']``).

    Parameters
    ----------
    input_kind : {'voltage', 'torque'}
        The input is a voltage [V], or a torque [N m] (a force [N] on a linear axis).
    linear : bool
        A linear axis: speed in m/s (and position in m).
    position : bool
        Add the unit of a measured position.

    Returns
    -------
    dict
        ``t``, ``voltage`` (the input column), ``speed``, ``current``, ``flags`` [and
        ``position``].
    """
    force = 'N' if linear else 'N m'
    units = {'t': UNITS['time'], 'voltage': UNITS['input'] if input_kind == 'voltage' else force,
             'speed': 'm/s' if linear else UNITS['speed'], 'current': UNITS['current'],
             'flags': '1'}
    if position:
        units['position'] = 'm' if linear else 'rad'
    return units


def profile_span(flags: ArrayLike) -> tuple[int, int] | None:
    """Sample range ``(start, end)`` of the last complete excitation profile.

    Parameters
    ----------
    flags : array_like of int
        Status flags per sample (:data:`FLAG_PROFILE`, :data:`FLAG_PROFILE_END`).

    Returns
    -------
    (int, int) or None
        ``flags[start:end]`` is the profile; ``start == 0`` means it may have begun
        before the first sample. None when no profile has ended.
    """
    flags = np.asarray(flags).astype(np.int64)
    ends = np.flatnonzero(flags & FLAG_PROFILE_END)
    if ends.size == 0:
        return None
    end = int(ends[-1])
    off = np.flatnonzero((flags[:end] & FLAG_PROFILE) == 0)
    start = int(off[-1]) + 1 if off.size else 0
    return start, end + 1


def batch_rows(labels: Sequence[str], sizes: Sequence[int], data_offset: int,
               values: ArrayLike) -> NDArray[np.float64]:
    """Rows of a sample batch from its ``Float64MultiArray`` parts, checked against the contract.

    Both the live subscriber and the bag reader apply this one rule: two dimensions,
    the second labelled :data:`SAMPLES_LABEL` with size 6, ``data_offset`` 0 and
    exactly ``size0 * 6`` values.

    Parameters
    ----------
    labels : sequence of str
        ``layout.dim[k].label``.
    sizes : sequence of int
        ``layout.dim[k].size``.
    data_offset : int
    values : array_like of float
        ``data``.

    Returns
    -------
    ndarray, shape (n, 6)

    Raises
    ------
    ValueError
        With a one-line reason naming what differs from the contract (callers re-raise
        it as their own domain error).
    """
    width = len(SAMPLE_COLUMNS)
    array = np.asarray(values, dtype=float)
    found = list(zip(labels, sizes, strict=False))
    if len(found) != 2 or sizes[1] != width or labels[1] != SAMPLES_LABEL:
        raise ValueError(f'layout {found} is not (n, {width}) rows of {SAMPLES_LABEL}')
    if data_offset != 0:
        raise ValueError(f'data_offset is {data_offset}; sample batches use 0')
    n = int(sizes[0])
    if array.size != n * width:
        raise ValueError(f'layout declares {n} rows but data holds {array.size} values '
                         f'(need {n * width})')
    return array.reshape(n, width)


SEQ_MODULUS = 2 ** 32
"""Card sequence numbers are uint32 and wrap at this modulus."""


def seq_step(prev: ArrayLike, seq: ArrayLike,
             modulus: int = SEQ_MODULUS) -> int | NDArray[np.int64]:
    """Signed distance from sequence number ``prev`` to ``seq``, across the wrap.

    The one rule of sequence arithmetic, shared by the driver's tracker, the ring buffer
    and the bag reader: 1 is the next sample, 0 a duplicate, more than 1 a gap, negative
    a sample from the past (late, or a card restart).

    Parameters
    ----------
    prev, seq : int or array_like of int
    modulus : int

    Returns
    -------
    int or ndarray
        In ``[-modulus / 2, modulus / 2)``.
    """
    d = np.mod(np.asarray(seq, dtype=np.int64) - np.asarray(prev, dtype=np.int64), modulus)
    d = np.where(d >= modulus // 2, d - modulus, d)
    return int(d) if d.ndim == 0 else d
