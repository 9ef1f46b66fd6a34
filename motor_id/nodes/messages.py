"""The only place that knows ROS message types: conversions and the QoS profiles."""

from collections.abc import Iterable, Mapping
import json
import math
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from numpy.typing import ArrayLike, NDArray
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray, MultiArrayDimension, String

from motor_id.contracts import (  # noqa: F401  (topic names re-exported for the nodes)
    batch_rows,
    CHANNEL_DEPTH,
    CHANNEL_TOPICS,
    DIAGNOSTICS_DEPTH,
    DIAGNOSTICS_TOPIC,
    ESTIMATE_TOPIC,
    JOINT_STATES_TOPIC,
    LATCHED_DEPTH,
    REPORT_TOPIC,
    SAMPLES_DEPTH,
    SAMPLES_TOPIC,
    units_of,
    VOLTAGE_COMMAND_TOPIC,
)
from motor_id.contracts import SAMPLE_COLUMNS as COLUMNS
from motor_id.contracts import SAMPLES_LABEL as ROW_LABEL
from motor_id.errors import DataError
from motor_id.output import to_jsonable

SAMPLES_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=SAMPLES_DEPTH,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
"""Sample batches: reliable with a real depth, so a slow subscriber loses nothing."""

CHANNEL_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=CHANNEL_DEPTH,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
"""Per-channel Float64 topics (for plotting tools) and the voltage command."""

LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=LATCHED_DEPTH,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""Results (estimate, report): a late subscriber still gets the last one."""

ROBOT_DEPTH = 1000
"""Queue of the robot's own topics (JointState, command) for the live topics input."""


def robot_qos(reliable: bool, depth: int = ROBOT_DEPTH) -> QoSProfile:
    """QoS for a robot topic: reliable only when every publisher found is reliable.

    A reliable subscription never matches a best-effort (sensor-data) publisher; a
    best-effort one matches both, so it is the choice whenever any publisher is
    best-effort. ``depth`` messages are kept for a subscriber that fell behind (the
    older ones are lost).
    """
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=(ReliabilityPolicy.RELIABLE if reliable
                                   else ReliabilityPolicy.BEST_EFFORT),
                      durability=DurabilityPolicy.VOLATILE)


def all_reliable(endpoints: Iterable[Any]) -> bool:
    """Whether every endpoint (``TopicEndpointInfo``) offers reliable delivery."""
    return bool(endpoints) and all(
        e.qos_profile.reliability == ReliabilityPolicy.RELIABLE for e in endpoints)


TYPE_NAMES = {Float64MultiArray: 'std_msgs/msg/Float64MultiArray',
              Float64: 'std_msgs/msg/Float64', JointState: 'sensor_msgs/msg/JointState'}
"""The graph's names of the message types the identifier subscribes."""

JOINT_FIELDS = ('position', 'velocity', 'effort')


def joint_value(msg: JointState, index: int, field: str) -> float:
    """``msg.<field>[index]`` of a JointState as float, NaN when the array is short."""
    values = getattr(msg, field)
    return float(values[index]) if index < len(values) else math.nan


def stamp_seconds(stamp: Any) -> float:
    """A ``builtin_interfaces/Time`` in seconds (0.0 for an unset stamp)."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


DIAGNOSTICS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DIAGNOSTICS_DEPTH,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)

OK, WARN, ERROR, STALE = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR,
                          DiagnosticStatus.STALE)


def rows_to_msg(rows: ArrayLike) -> Float64MultiArray:
    """A batch of sample rows -> ``std_msgs/Float64MultiArray`` (CONTRACTS.md layout).

    Parameters
    ----------
    rows : array_like, shape (n, 6)
        Columns seq, t [s], voltage [V], speed [rad/s], current [A], flags.
    """
    rows = np.asarray(rows, dtype=float).reshape(-1, len(COLUMNS))
    n = rows.shape[0]
    msg = Float64MultiArray()
    msg.layout.dim = [
        MultiArrayDimension(label='samples', size=n, stride=len(COLUMNS) * n),
        MultiArrayDimension(label=ROW_LABEL, size=len(COLUMNS), stride=len(COLUMNS)),
    ]
    msg.layout.data_offset = 0
    msg.data = rows.ravel().tolist()
    return msg


def msg_to_rows(msg: Float64MultiArray) -> NDArray[np.float64]:
    """``Float64MultiArray`` -> ndarray (n, 6); :class:`DataError` if the layout is wrong.

    The rule is :func:`motor_id.contracts.batch_rows`, the same the bag reader applies.
    """
    dims = msg.layout.dim
    try:
        return batch_rows([d.label for d in dims], [d.size for d in dims],
                          msg.layout.data_offset, msg.data)
    except ValueError as exc:
        raise DataError(f'samples message: {exc}') from None


def float_msg(value: float) -> Float64:
    """A ``std_msgs/Float64``."""
    return Float64(data=float(value))


def _fmt(value: Any) -> str:
    if value is None:
        return ''
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else str(value)
    return str(value)


DiagnosticValue = int | float | bool | str | None
"""A diagnostic key's value (written as its string)."""


def status(name: str, level: int, message: str,
           values: Mapping[str, DiagnosticValue] | None = None,
           hardware_id: str = '') -> DiagnosticStatus:
    """One ``diagnostic_msgs/DiagnosticStatus`` with string key/values."""
    st = DiagnosticStatus(level=level, name=name, message=str(message),
                          hardware_id=str(hardware_id))
    st.values = [KeyValue(key=str(k), value=_fmt(v)) for k, v in (values or {}).items()]
    return st


def diagnostic_array(stamp: Any, statuses: Iterable[DiagnosticStatus]) -> DiagnosticArray:
    """``diagnostic_msgs/DiagnosticArray`` of the given statuses stamped ``stamp``."""
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = list(statuses)
    return msg


def estimate_values(report: Mapping[str, Any]) -> dict[str, DiagnosticValue]:
    """Flatten a fit report dict into ordered key/values.

    Keys are ``NAME``, ``NAME_std``, ``NAME_unit`` (SI, from
    :data:`motor_id.contracts.UNITS`), ``NAME_determined`` for each parameter, then
    ``fit_percent_<channel>``, ``method`` and ``samples`` when present.
    """
    values: dict[str, DiagnosticValue] = {}
    units = units_of(report.get('input_kind', 'voltage'))
    for name, p in report.get('parameters', {}).items():
        values[name] = p.get('value')
        values[f'{name}_std'] = p.get('std')
        values[f'{name}_unit'] = units.get(name, '')
        values[f'{name}_determined'] = bool(p.get('determined'))
    for ch, m in report.get('fit', {}).get('channels', {}).items():
        if 'fit_percent' in m:
            values[f'fit_percent_{ch}'] = m['fit_percent']
    if 'method' in report:
        values['method'] = report['method']
    data = report.get('data', {})
    if 'samples' in data:
        values['samples'] = data['samples']
    return values


def estimate_to_msg(stamp: Any, report: Mapping[str, Any], summary: str = '',
                    name: str = 'motor_id: estimate', hardware_id: str = '') -> DiagnosticArray:
    """The latched estimate: a DiagnosticArray with one status holding the parameters."""
    values = estimate_values(report)
    undetermined = [k for k, p in report.get('parameters', {}).items()
                    if not p.get('determined')]
    level = WARN if undetermined else OK
    message = ('parameters estimated' if not undetermined
               else f'not determined by the data: {", ".join(undetermined)}')
    if summary:
        values['summary'] = summary
    return diagnostic_array(stamp, [status(name, level, message, values, hardware_id)])


def msg_to_estimate(msg: DiagnosticArray) -> dict[str, str]:
    """Read an estimate DiagnosticArray back into ``{key: str}`` (first status)."""
    if not msg.status:
        return {}
    return {kv.key: kv.value for kv in msg.status[0].values}


def report_msg(report: Mapping[str, Any]) -> String:
    """The full fit report as JSON in a ``std_msgs/String`` (NaN/inf become null)."""
    return String(data=json.dumps(to_jsonable(report)))
