"""Load a recording from any file the tools accept (CSV, rosbag2, SysId log, DataLog), by path."""

from dataclasses import replace
import os
from typing import TYPE_CHECKING

from motor_id.data.csv_io import read_csv
from motor_id.data.sysid import is_sysid_log, load_sysid
from motor_id.data.wpilog import is_wpilog, load_wpilog, LogEntries
from motor_id.errors import ConfigError
from motor_id.recording import Recording

if TYPE_CHECKING:  # the bag modules load only when a bag is read
    from motor_id.data.mapping import TopicMapping


def load_recording(path: str | os.PathLike[str], columns: str | dict[str, str] | None = None,
                   input_kind: str | None = None,
                   mapping: 'TopicMapping | None' = None,
                   log_entries: LogEntries | None = None, delimiter: str | None = None,
                   decimal: str | None = None) -> Recording:
    """Read a recording from a CSV file, a rosbag2 recording or a WPILib SysId log.

    Parameters
    ----------
    path : str or os.PathLike
        A directory (rosbag2 folder), ``*.mcap`` or ``*.db3``: a bag, read by
        :func:`motor_id.data.rosbag.read_bag`; ``*.json``: a SysId log
        (:func:`motor_id.data.sysid.load_sysid`, its four tests as four runs);
        ``*.wpilog``: a WPILib DataLog of a SysId routine
        (:func:`motor_id.data.wpilog.load_wpilog`, each test a run); anything else: CSV
        (:func:`motor_id.data.csv_io.read_csv`).
    columns : dict or str, optional
        CSV only: column mapping ``{role: name}``.
    input_kind : {'voltage', 'torque'}, optional
        Plant kind when the names cannot tell (CSV, or a bag mapping).
    mapping : motor_id.data.mapping.TopicMapping, optional
        Bags: the topic/field mapping (None or empty: the ``/samples`` topic); a SysId
        log or a DataLog takes only its ``joint`` (the side of a drivetrain).
    log_entries : motor_id.data.wpilog.LogEntries, optional
        A DataLog's motor, or its entries (refused for any other file).
    delimiter, decimal : str, optional
        CSV only: the cell delimiter and the decimal mark (default: found in the file).

    Returns
    -------
    motor_id.recording.Recording
        Validated for CSV and SysId logs; a bag's recording is validated by the caller.

    Examples
    --------
    A CSV as a user has it: a header naming ``time`` [s], the input (``voltage`` [V]),
    ``speed`` [rad/s] and, where measured, ``current`` [A]. Here one is written from a
    simulated record of the paper's motor:

    >>> import os, tempfile
    >>> from motor_id import load_recording
    >>> from motor_id.data.csv_io import write_csv
    >>> from motor_id.testing.recordings import paper_recording
    >>> folder = tempfile.mkdtemp()
    >>> path = os.path.join(folder, 'motor.csv')
    >>> write_csv(paper_recording(), path)
    >>> with open(path) as fh:
    ...     print(fh.readline().strip())
    time,voltage,speed,current
    >>> rec = load_recording(path)
    >>> len(rec), rec.input_kind, rec.channels()
    (4000, 'voltage', ('speed', 'current'))
    >>> round(rec.sample_period, 6)
    0.01
    """
    joint = None if mapping is None else mapping.joint
    if (delimiter or decimal) and (is_wpilog(path) or is_sysid_log(path)):
        raise ConfigError(f'{path}: delimiter and decimal describe a CSV file',
                          params=('delimiter', 'decimal'))
    if is_wpilog(path):
        _check_sysid_options(path, columns, input_kind, mapping)
        entries = log_entries or LogEntries()
        if joint is not None:
            entries = replace(entries, joint=joint)
        return load_wpilog(path, entries)
    if log_entries is not None and log_entries != LogEntries():
        raise ConfigError(f'{path}: log_entries (motor, voltage, position, velocity, state, '
                          'units) pick the entries of a WPILib DataLog (.wpilog)',
                          params=('motor', 'voltage', 'position', 'velocity', 'state',
                                  'units'))
    if is_sysid_log(path):
        _check_sysid_options(path, columns, input_kind, mapping)
        return load_sysid(path, joint=joint)
    from motor_id.data.mapping import TopicMapping
    from motor_id.data.rosbag import is_rosbag, read_bag
    if is_rosbag(path):
        if columns or delimiter or decimal:
            raise ConfigError('columns, delimiter and decimal describe CSV files; a bag is '
                              "mapped by the mapping's input, speed and current",
                              params=('columns', 'delimiter', 'decimal', 'input', 'speed',
                                      'current'))
        mapping = mapping or TopicMapping()
        if input_kind is not None:
            mapping.input_kind = input_kind
        return read_bag(path, mapping)
    if mapping is not None and not mapping.is_empty:
        raise ConfigError(f"{path}: the mapping's input, speed, current and effort_is map bag "
                          'topics; for a CSV map its columns with columns '
                          "'time=T,input=U,speed=W'",
                          params=('input', 'speed', 'current', 'effort_is', 'columns'))
    return read_csv(path, columns=columns, input_kind=input_kind, delimiter=delimiter,
                    decimal=decimal)


def _check_sysid_options(path: str | os.PathLike[str],
                         columns: str | dict[str, str] | None, input_kind: str | None,
                         mapping: 'TopicMapping | None') -> None:
    """ConfigError for the CSV and bag options that a SysId log cannot take."""
    if columns:
        raise ConfigError(f'{path}: a SysId log has fixed columns; columns maps CSV columns',
                          params=('columns',))
    if input_kind not in (None, 'voltage'):
        raise ConfigError(f'{path}: a SysId log has voltage input, not {input_kind}')
    if mapping is not None and not mapping.is_empty:
        raise ConfigError(f"{path}: the mapping's input, speed, current and effort_is map bag "
                          "topics; a SysId log takes only the mapping's joint (left or right, "
                          'a drivetrain)',
                          params=('input', 'speed', 'current', 'effort_is', 'joint'))
