"""A MicroPython board seen through mpremote: what it is, its files, its REPL.

`Board` is the interface `bioscara.firmware_flash` works against; `MpremoteBoard` is the real one (mpremote's
serial transport, raw REPL); tests also use an in-memory fake. Paths are absolute board paths.
"""

from __future__ import annotations

import ast
import contextlib
import errno
import io
import os
from dataclasses import dataclass
from typing import Callable, Iterable, Protocol

from .serial_port import open_problem

# Index: sys.implementation._mpy >> 10 (MicroPython docs, "MicroPython .mpy files").
ARCHS = (None, "x86", "x64", "armv6", "armv6m", "armv7m", "armv7em", "armv7emsp", "armv7emdp",
         "xtensa", "xtensawin", "rv32imc", "rv64imc")


def dotted(version: Iterable[int]) -> str:
    """(1, 26, 0) -> "1.26.0"."""
    return ".".join(str(v) for v in version)


class FlashError(OSError):
    """Deploying firmware failed or was refused; the message says why and what to do."""


@dataclass(frozen=True)
class BoardInfo:
    """What the board reports about itself (see PROBE), and the joint firmware already on it."""

    implementation: str  # sys.implementation.name: "micropython", "circuitpython", ...
    version: tuple[int, int, int]
    mpy: int  # sys.implementation._mpy; 0 if the board cannot load .mpy files
    small_int_bits: int  # 0 if unknown
    platform: str  # sys.platform, e.g. "rp2"
    machine: str  # os.uname().machine, e.g. "Raspberry Pi Pico with RP2040"
    i2c_target: bool  # machine.I2CTarget exists
    installed_firmware: tuple[int, int, int] | None = None
    installed_joint: str | None = None

    @property
    def mpy_version(self) -> int:
        return self.mpy & 0xFF

    @property
    def arch(self) -> str | None:
        index = self.mpy >> 10
        return ARCHS[index] if index < len(ARCHS) else None

    def describe(self) -> str:
        name = {"micropython": "MicroPython", "circuitpython": "CircuitPython"}.get(
            self.implementation, self.implementation)
        where = f" ({self.machine})" if self.machine else ""
        return f"{name} {dotted(self.version)} on {self.platform}{where}"


class Board(Protocol):
    """A MicroPython board's filesystem and REPL. Paths are absolute board paths ("/joint/app.mpy")."""

    port: str

    def info(self) -> BoardInfo: ...

    def hashes(self, paths: Iterable[str]) -> dict[str, str]:
        """SHA-256 (hex) of every file at or below each path; missing paths are left out."""

    def write(self, path: str, data: bytes, progress: Callable[[int], None] | None = None) -> None:
        """Create or replace a file, making its directories; `progress(bytes written so far)`."""

    def read(self, path: str) -> bytes | None: ...

    def remove(self, path: str) -> None: ...

    def rename(self, path: str, new_path: str) -> None:
        """Rename a file, replacing `new_path` in one filesystem operation (littlefs, FAT and POSIX
        all replace the target atomically), so a reader sees the old file or the new one, whole."""

    def check_import(self, module: str) -> None:
        """Import `module` afresh on the board; FlashError with the board's error if that fails."""

    def reset(self) -> None:
        """Soft reset into the normal REPL, so the board runs main.py; the connection ends."""

    def close(self) -> None:
        """End the connection, leaving the board running its main.py (idempotent)."""


# Runs on the board; prints one tuple literal. heap_lock makes every non-small int allocation fail,
# which finds the board's small-int width without knowing its object representation.
PROBE = """
import sys
try:
    import os
    _m = os.uname().machine
except Exception:
    _m = ''
try:
    import machine
    _t = hasattr(machine, 'I2CTarget')
except ImportError:
    _t = False
def _bits():
    try:
        import micropython
        micropython.heap_lock()
    except Exception:
        return 0
    k = 0
    try:
        while k < 64:
            x = 1 << k
            k += 1
    except MemoryError:
        micropython.heap_unlock()
        return k + 1
    micropython.heap_unlock()
    return 0
try:
    from joint.spec.version import FIRMWARE_VERSION as _v
    _v = tuple(_v)
except Exception:
    _v = None
try:
    import json
    with open('joint_config.json') as f:
        _j = json.load(f).get('joint')
except Exception:
    _j = None
print(repr((sys.implementation.name, tuple(sys.implementation.version[:3]),
            getattr(sys.implementation, '_mpy', 0), _bits(), sys.platform, _m, _t, _v, _j)))
"""

# Runs on the board: forget the joint modules loaded so far (PROBE's), then import anew.
IMPORT_CHECK = """
import sys
for _k in list(sys.modules):
    if _k == 'joint' or _k.startswith('joint.'):
        del sys.modules[_k]
import {module}
"""


# Runs on the board: "PATH SHA256" for every file at or below each root (missing roots: nothing).
HASH_TREES = """
import os, hashlib, binascii
def _walk(p):
    try:
        m = os.stat(p)[0]
    except OSError:
        return
    if m & 0x4000:
        for n in os.listdir(p):
            _walk(p + '/' + n)
        return
    h = hashlib.sha256()
    b = bytearray(512)
    with open(p, 'rb') as f:
        while True:
            n = f.readinto(b)
            if not n:
                break
            h.update(b[:n])
    print(p, binascii.hexlify(h.digest()).decode())
for _r in {roots!r}:
    _walk(_r)
"""


def parse_probe(output: str) -> BoardInfo:
    """The BoardInfo from PROBE's output."""
    try:
        fields = ast.literal_eval(output.strip().splitlines()[-1])
        return BoardInfo(*fields)
    except (ValueError, SyntaxError, TypeError, IndexError):
        raise FlashError(f"the board's answer to the probe is not understood: {output.strip()[:80]!r}") from None


class MpremoteBoard:
    """A board on a serial port, through mpremote's transport in raw-REPL mode.

    `root` is where the board's "/" is (the MicroPython unix port in tests runs in a directory);
    `soft_reset` resets the board on connecting, as mpremote does, to stop main.py and start from a
    clean heap (the unix port cannot); `timeout` in s bounds waiting for the REPL.
    """

    def __init__(self, port: str, *, root: str = "/", soft_reset: bool = True, timeout: float = 10.0) -> None:
        try:
            from mpremote.transport import TransportError
            from mpremote.transport_serial import SerialTransport
        except ImportError:
            raise FlashError("mpremote is not installed (pip install mpremote)") from None
        self.port = port
        check_port(port)
        if port.startswith("/dev/pts/"):
            _check_answers(port, timeout)
        self._root = root.rstrip("/") + "/"
        self._errors: tuple[type[Exception], ...] = (TransportError,)
        try:
            self._transport = SerialTransport(port)
        except TransportError as exc:
            raise FlashError(f"cannot open {port}: {exc}") from None
        said = io.StringIO()
        try:
            with contextlib.redirect_stdout(said):  # mpremote prints what it saw instead of the prompt
                self._transport.enter_raw_repl(soft_reset=soft_reset, timeout_overall=timeout)
        except TransportError:
            self._transport.close()
            seen = said.getvalue().strip()  # the repr of the bytes received, b'' for none
            raise FlashError(f"no MicroPython REPL on {port}" + (f" (it sent {seen[:60]})" if seen != "b''" else "")
                             + ": is MicroPython installed, and is no other program using the port?") from None
        self._open = True

    def _path(self, path: str) -> str:
        return self._root + path.lstrip("/")

    def _exec(self, code: str, doing: str) -> str:
        try:
            return self._transport.exec(code).decode(errors="replace")
        except self._errors as exc:
            raise FlashError(f"{doing} on {self.port} failed: {_last_line(exc)}") from None

    def info(self) -> BoardInfo:
        return parse_probe(self._exec(PROBE, "probing the board"))

    def hashes(self, paths: Iterable[str]) -> dict[str, str]:
        # One script walks and hashes everything on the board: a round trip per file (stat, then
        # hash) would cost a flash a hundred USB round trips.
        roots = [self._path(path) for path in paths]
        output = self._exec(HASH_TREES.format(roots=roots), "reading the files")
        found: dict[str, str] = {}
        for line in output.splitlines():
            path, _, digest = line.rpartition(" ")
            if path.startswith(self._root):
                found["/" + path[len(self._root):]] = digest
        return found

    def write(self, path: str, data: bytes, progress: Callable[[int], None] | None = None) -> None:
        try:
            parent = ""
            for part in path.strip("/").split("/")[:-1]:
                parent += "/" + part
                if not self._transport.fs_isdir(self._path(parent)):
                    self._transport.fs_mkdir(self._path(parent))
            self._transport.fs_writefile(self._path(path), data,
                                         progress_callback=(lambda done, _total: progress(done)) if progress else None)
        except (OSError, *self._errors) as exc:
            raise FlashError(f"writing {path} on {self.port} failed: {_last_line(exc)}") from None

    def read(self, path: str) -> bytes | None:
        """The file's bytes, or None if the board has no such file."""
        try:
            if not self._transport.fs_exists(self._path(path)):
                return None
            return bytes(self._transport.fs_readfile(self._path(path)))
        except (OSError, *self._errors) as exc:
            raise FlashError(f"reading {path} on {self.port} failed: {_last_line(exc)}") from None

    def remove(self, path: str) -> None:
        try:
            self._transport.fs_rmfile(self._path(path))
        except (OSError, *self._errors) as exc:
            raise FlashError(f"removing {path} on {self.port} failed: {_last_line(exc)}") from None

    def rename(self, path: str, new_path: str) -> None:
        self._exec(f"import os\nos.rename({self._path(path)!r}, {self._path(new_path)!r})",
                   f"renaming {path} to {new_path}")

    def check_import(self, module: str) -> None:
        try:
            self._transport.exec(IMPORT_CHECK.format(module=module))
        except self._errors as exc:
            raise FlashError(f"the firmware does not load on the board (import {module}): {_last_line(exc)}") from None

    def reset(self) -> None:
        self.close()

    def close(self) -> None:
        """Soft-reset and disconnect: the board runs its main.py again (mpremote would leave it
        stopped, but a dry run or a refusal must not stop a running joint)."""
        if not self._open:
            return
        self._open = False
        with contextlib.suppress(OSError, *self._errors):  # best effort: the port may be gone
            self._transport.exit_raw_repl()
            self._transport.serial.write(b"\x04")  # Ctrl-D in the normal REPL: soft reset, runs main.py
        self._transport.close()


def check_port(port: str) -> None:
    """FlashError, in one line, when the serial port `port` does not exist (a Windows COMn is
    left to the open); nothing is sent, so a joint running on it goes on running."""
    if not os.path.exists(port) and not port.upper().startswith("COM"):
        raise FlashError(open_problem(port, FileNotFoundError(errno.ENOENT, port)))


def _check_answers(port: str, timeout: float) -> None:
    """FlashError unless something answers Ctrl-C on `port` within `timeout` s. mpremote reads a
    /dev/pts/* port without a timeout, so a pseudo-terminal nothing answers on (a simulated joint's
    console, someone's shell) would hang the flash for good; a REPL answers with its prompt."""
    import time

    from .errors import BioscaraError
    from .serial_port import open_port

    try:
        serial_port = open_port(port, timeout=0.05)
    except BioscaraError as exc:
        raise FlashError(exc.detail) from None
    try:
        serial_port.write(b"\r\x03")  # Ctrl-C: a REPL (or a program it interrupts) answers at once
        deadline = time.monotonic() + timeout
        while not serial_port.read(64):
            if time.monotonic() > deadline:
                raise FlashError(f"no MicroPython REPL on {port}: nothing answered within {timeout:g} s "
                                 "(is it a board's port? `bioscara ports` says what each port is)")
    except OSError as exc:
        raise FlashError(f"cannot use {port}: {exc}") from None
    finally:
        serial_port.close()


def _last_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[-1] if text else type(exc).__name__


def open_board(port: str) -> Board:
    """The board on serial port `port` (the CLI's seam: tests replace it with a fake)."""
    return MpremoteBoard(port)
