"""Domain exceptions: every error the core raises derives from MotorIdError."""

from collections.abc import Sequence


class MotorIdError(Exception):
    """Base class of all errors raised by motor_id.

    The library names a setting by its parameter name (``R_m``, ``init_samples``, a
    mapping's ``speed``), never by a command-line flag; ``params`` lists the names a
    message is about, and the command line adds its flags for them
    (:func:`motor_id.cli.flags.flag_hint`).

    Parameters
    ----------
    *args
        The message.
    params : sequence of str, optional
        The parameters the message names, as the library calls them.

    Examples
    --------
    Bad input gets a specific child of this class, with a message that names the problem:

    >>> from motor_id import DataError, MotorIdError, Recording
    >>> rec = Recording([0.0, 0.01, 0.02], [1.0, 1.0, 1.0], [0.0, float('nan'), 0.2])
    >>> try:
    ...     rec.validate(min_samples=3)
    ... except MotorIdError as exc:
    ...     print(type(exc).__name__, isinstance(exc, ValueError))
    DataError True
    """

    def __init__(self, *args: object, params: Sequence[str] = ()) -> None:
        super().__init__(*args)
        self.params = tuple(params)


class DataError(MotorIdError, ValueError):
    """Input data is malformed or unusable (missing column, NaN, no excitation, ...)."""


class ConfigError(MotorIdError, ValueError):
    """A setting or parameter is out of range or inconsistent."""


class ProtocolError(MotorIdError):
    """A serial frame or command cannot be decoded; ``kind`` names the fault."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(f'{kind}: {message}')
        self.kind = kind


class BagError(MotorIdError):
    """An MCAP recording is missing, truncated, corrupt or lacks the expected topics."""


class IdentificationError(MotorIdError):
    """The fit cannot run or did not produce a usable result."""


FIT_ERRORS = (MotorIdError, ArithmeticError, ValueError, RuntimeError)
"""What a numerical fit may raise where a failed fit is a result and not the end (a
candidate of the discrepancy analysis, a model of its simulation-error stage): the
domain errors, overflow and division by zero, bad values (numpy's ``LinAlgError`` is a
``ValueError``) and solvers' ``RuntimeError``. Each is recorded as a failed fit with its
reason, and the analysis goes on."""
