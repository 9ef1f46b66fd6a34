"""Data-source options shared by every subcommand that reads a recording."""

import argparse
from collections.abc import Iterable
import os
import sys
from typing import Any, TextIO

from motor_id.contracts import INPUT_KINDS
from motor_id.data.csv_io import DECIMALS, DELIMITERS, parse_columns
from motor_id.data.load import load_recording
from motor_id.data.log_units import UNIT_NAMES
from motor_id.data.mapping import load_profile, mapping_settings, PROFILE_KEYS
from motor_id.data.shift import detect_shift, shift_input
from motor_id.data.wpilog import LogEntries
from motor_id.errors import DataError
from motor_id.recording import Recording

DATA_HELP = ('CSV (time, voltage|torque|force, speed[, current]), a rosbag2 recording (an '
             '.mcap or .db3 file or a bag folder), a WPILib SysId log (.json, its four '
             'tests as four runs) or a WPILib DataLog of a SysId routine (.wpilog, each '
             'test a run)')


def add_data_arguments(parser: argparse.ArgumentParser, profile: bool = True) -> None:
    """Add the options that say how to read DATA (CSV columns, bag topics, alignment).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The subcommand's parser; its positional DATA argument stays its own.
    profile : bool
        Add ``--profile FILE`` (a subcommand that already has a ``--profile`` adds its
        own and sets ``args.profile`` to the file or None).
    """
    g = parser.add_argument_group('data source (CSV columns, bag topics, SysId side)')
    g.add_argument('--columns', metavar='ROLE=NAME,...',
                   help='CSV: map columns, e.g. time=t,input=u_cmd,speed=omega,current=i_a')
    g.add_argument('--delimiter', choices=DELIMITERS, metavar='CHAR',
                   help='CSV: the cell delimiter (default: found from the header; a '
                        'spreadsheet may write ;)')
    g.add_argument('--decimal', choices=DECIMALS, metavar='CHAR',
                   help='CSV: the decimal mark, . or , (default: a comma where the cells '
                        'hold commas and the delimiter is not one)')
    g.add_argument('--input-kind', choices=INPUT_KINDS,
                   help='plant kind when the input name cannot tell (torque: also force)')
    g.add_argument('--input', metavar='TOPIC[:FIELD]',
                   help='bag: plant input, e.g. /motor_voltage_cmd or /cmd:data[2]')
    g.add_argument('--speed', metavar='TOPIC[:FIELD]',
                   help='bag: measured speed, e.g. /joint_states:velocity')
    g.add_argument('--current', metavar='TOPIC[:FIELD]',
                   help='bag: measured current, e.g. /joint_states:effort')
    g.add_argument('--joint', metavar='NAME',
                   help='bag: JointState joint (name or index); SysId Drivetrain log: the '
                        'side, left or right')
    g.add_argument('--effort-is', choices=('current', 'torque'),
                   help='bag: what a JointState effort is (torque: a torque plant whose '
                        'input is the effort)')
    g.add_argument('--align', choices=('hold', 'next'), default=None,
                   help='bag: command held from its stamp (hold, default) or the command '
                        'published just after each measurement (next)')
    g.add_argument('--shift', type=int, default=None, metavar='N',
                   help='use input[k+N] at sample k (N > 0: the input was stamped late)')
    add_log_arguments(parser)
    if profile:
        g.add_argument('--profile', metavar='FILE',
                       help='YAML mapping profile (keys: input, speed, current, joint, '
                            'effort_is, align, input_kind, shift, columns); flags override')


def add_log_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options that pick a motor, or the entries, of a WPILib DataLog."""
    g = parser.add_argument_group('WPILib DataLog (.wpilog): SysIdRoutineLog entries are '
                                  'found by name; other loggers name theirs')
    g.add_argument('--motor', metavar='NAME',
                   help='.wpilog: the motor, where the log holds several (import dunker: '
                        'the motor number, 1 to 3)')
    g.add_argument('--voltage', metavar='ENTRY', help='.wpilog: the applied voltage entry')
    g.add_argument('--position', metavar='ENTRY', help='.wpilog: the position entry')
    g.add_argument('--velocity', metavar='ENTRY', help='.wpilog: the velocity entry')
    g.add_argument('--state', metavar='ENTRY',
                   help='.wpilog: the test-state entry (quasistatic-forward, ..., none)')
    g.add_argument('--units', choices=UNIT_NAMES,
                   help=".wpilog: the position unit where the entries' metadata lacks it")


def log_entries_from_args(args: argparse.Namespace) -> LogEntries | None:
    """The DataLog selection the options give (None: none given)."""
    keys = ('motor', 'voltage', 'position', 'velocity', 'state', 'units')
    values = {k: getattr(args, k, None) for k in keys}
    if all(v is None for v in values.values()):
        return None
    return LogEntries(**{k: None if v is None else str(v) for k, v in values.items()})


def settings_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """The merged data settings: the profile's values overridden by the flags.

    Returns
    -------
    dict
        Keys ``columns, input_kind, shift, mapping`` (a :class:`TopicMapping`).
    """
    prof = getattr(args, 'profile', None)
    merged = load_profile(prof) if isinstance(prof, str) and prof else {}
    for key in PROFILE_KEYS:
        value = getattr(args, key, None)
        if value is not None:
            merged[key] = value
    mapping, shift = mapping_settings(merged, f'--profile {prof}' if prof else 'options')
    return {'columns': parse_columns(merged.get('columns')),
            'input_kind': merged.get('input_kind'), 'shift': shift, 'mapping': mapping}


def load_from_args(args: argparse.Namespace, path: str | None = None, validate: bool = True,
                   stream: TextIO | None = None) -> Recording:
    """Read the recording the options describe, check it, report a time shift.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed with :func:`add_data_arguments`.
    path : str, optional
        The data path (default ``args.data``).
    validate : bool
        Validate (``Recording.validate``) and check for a shift between input and
        output; a shift found without ``--shift`` is printed as a warning with the fix.
    stream : file, optional
        Where the warning goes (default stderr).

    Returns
    -------
    motor_id.recording.Recording
    """
    path = str(args.data if path is None else path)
    s = settings_from_args(args)
    rec = load_recording(path, columns=s['columns'], input_kind=s['input_kind'],
                         mapping=s['mapping'], log_entries=log_entries_from_args(args),
                         delimiter=getattr(args, 'delimiter', None),
                         decimal=getattr(args, 'decimal', None))
    for note in rec.meta.get('warnings') or ():
        print(f'warning: {path}: {note}', file=stream or sys.stderr)
    if s['shift']:
        rec = shift_input(rec, s['shift'])
    if not validate:
        return rec
    try:
        rec.validate()
    except DataError as exc:
        text = str(exc)
        raise DataError(text if text.startswith(path) else f'{path}: {text}') from None
    if s['shift'] is None and len(rec) >= 40:
        check = detect_shift(rec)
        rec.meta['shift_check'] = check.to_dict()
        if check.samples:
            print(f'warning: {path}: {check.message()}', file=stream or sys.stderr)
    return rec


def load_runs(args: argparse.Namespace, paths: Iterable[str] | None = None,
              stream: TextIO | None = None) -> Recording:
    """Read one or several recordings of one motor (separate runs) as one recording.

    Each path is read and checked as by :func:`load_from_args`; several are joined with
    :meth:`motor_id.recording.Recording.concatenate` (shared parameters, an initial
    state per run). A file that holds several runs itself (a SysId log's four tests)
    keeps them as runs; ``meta['segment_names']`` names every run then.
    """
    paths = [str(p) for p in (paths if paths is not None else args.data)]
    recs = [load_from_args(args, path=p, stream=stream) for p in paths]
    if len(recs) == 1:
        return recs[0]
    names: list[str] = []
    for path, r in zip(paths, recs, strict=True):
        inner = r.meta.get('segment_names') or [''] * len(r.segment_ranges)
        names += [f'{os.path.basename(path)}:{name}' if name else os.path.basename(path)
                  for name in inner]
    rec = Recording.concatenate(recs)   # a file of several runs keeps them
    rec.meta['source'] = ', '.join(paths)
    if len(names) > len(recs):
        rec.meta['segment_names'] = names
    return rec
