"""Opening a serial port (USB CDC of a bridge or a joint, or a simulator pseudo-terminal).

A port that is missing, busy or forbidden raises CommError with one line saying what to do.
"""

from __future__ import annotations

import errno

import serial

from .errors import CommError

DEFAULT_BAUD = 115200  # irrelevant for USB CDC and pseudo-terminals; real UARTs need the right one

try:
    import termios
    # What using an open port can raise: pyserial's SerialException is an OSError; a tty that
    # hung up (board reset, unplugged) raises termios.error from tcflush and friends.
    PORT_ERRORS: tuple[type[BaseException], ...] = (OSError, termios.error)
except ImportError:  # Windows
    PORT_ERRORS = (OSError,)


def open_port(path: str, *, baud: int = DEFAULT_BAUD, timeout: float | None = 0.1) -> serial.Serial:
    """Open `path` in exclusive mode (raw, no echo); `timeout` in s bounds each read."""
    try:
        return serial.Serial(path, baud, timeout=timeout, write_timeout=1.0, exclusive=True)
    except OSError as exc:  # SerialException, or an ioctl failing while the port is set up
        raise CommError(open_problem(path, exc)) from None
    except ValueError as exc:  # pyserial's answer to an impossible baud rate
        raise CommError(f"cannot open serial port {path}: {exc}") from None


def open_problem(path: str, exc: OSError) -> str:
    """One line explaining why `path` could not be opened."""
    code = exc.errno
    if code in (errno.ENOENT, errno.ENODEV, errno.ENXIO):
        return f"serial port {path} does not exist (is the board plugged in? try `ls /dev/ttyACM*`)"
    if code in (errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK):
        return f"serial port {path} is busy: another program (a console, mpremote, bioscara) has it open"
    if code == errno.EACCES:
        return f"no permission to open {path} (add your user to the 'dialout' group, then log in again)"
    return f"cannot open serial port {path}: {exc}"
