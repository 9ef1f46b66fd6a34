"""Opening the byte stream to a card: a serial device, a pseudo-terminal or ``loop://``."""

import serial

try:
    from termios import error as TermiosError  # noqa: N812 - the module's name for it
except ImportError:   # not POSIX: pyserial raises no termios errors there
    class TermiosError(Exception):  # type: ignore[no-redef]
        """Never raised: a stand-in where the termios module does not exist."""

from motor_id.errors import ConfigError, MotorIdError


class TransportError(MotorIdError):
    """The card's device cannot be opened, read or written (absent, vanished, busy)."""


def open_transport(url: str, baudrate: int = 115200,
                   timeout: float | None = 0.1) -> serial.SerialBase:
    """Open a card connection with :func:`serial.serial_for_url`.

    Parameters
    ----------
    url : str
        A device path (``/dev/ttyACM0``, a pty such as ``/dev/pts/5`` or a symlink to
        one) or a pyserial URL (``loop://`` for tests, ``socket://host:port``, ...).
    baudrate : int
        Line rate [bit/s]; ignored by ptys and ``loop://``.
    timeout : float or None
        Read timeout [s]; ``read`` returns what arrived within it (None blocks).

    Returns
    -------
    serial.SerialBase
        An open port; ``read``/``write`` raise :class:`serial.SerialException` when the
        device goes away (use :func:`read_available` to get a :class:`TransportError`).

    Raises
    ------
    ConfigError
        Bad ``baudrate`` or ``timeout``.
    TransportError
        The device does not exist or cannot be opened.
    """
    if not isinstance(url, str) or not url:
        raise ConfigError(f'the card URL must be a non-empty string, got {url!r}')
    if not isinstance(baudrate, int) or baudrate <= 0:
        raise ConfigError(f'baudrate must be a positive integer, got {baudrate!r}')
    if timeout is not None and not timeout >= 0:
        raise ConfigError(f'timeout must be >= 0 seconds or None, got {timeout!r}')
    try:
        return serial.serial_for_url(url, baudrate=baudrate, timeout=timeout)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise TransportError(f'cannot open {url}: {exc}') from exc


def read_available(port: serial.SerialBase, max_bytes: int = 4096) -> bytes:
    """Read what the port has (waiting at most its timeout for the first byte).

    Parameters
    ----------
    port : serial.SerialBase
    max_bytes : int

    Returns
    -------
    bytes
        Possibly empty when nothing arrived within the timeout.

    Raises
    ------
    TransportError
        The device vanished or failed; close the port and open it again.
    """
    try:
        waiting = port.in_waiting
        data: bytes = port.read(max(1, min(max_bytes, waiting)))
        return data
    except (serial.SerialException, OSError) as exc:
        raise TransportError(f'read from {port.name or port.port} failed: {exc}') from exc


def write_all(port: serial.SerialBase, data: bytes) -> None:
    """Write ``data`` and wait until it is sent; :class:`TransportError` on failure.

    A pseudo-terminal whose other end closed fails the wait (``tcdrain``) with a
    ``termios.error``, which is no ``OSError``: it is a lost device too.
    """
    try:
        port.write(data)
        port.flush()
    except (serial.SerialException, OSError, TermiosError) as exc:
        raise TransportError(f'write to {port.name or port.port} failed: {exc}') from exc
