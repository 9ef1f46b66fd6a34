"""Domain exceptions: every error the core raises derives from MotorIdError."""


class MotorIdError(Exception):
    """Base class of all errors raised by motor_id."""


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
