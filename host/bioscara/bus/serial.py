"""The HIL bridge transport: `serial:/dev/ttyACM0`, a USB MicroPython board running hil_bridge as
I2C controller, or the simulator server's pseudo-terminal (`bioscara sim --pty`).

One request is outstanding at a time. Every transfer gets a new sequence number, kept by its
retries (the bridge answers a repeated request from its cache instead of running it again), and
input older than the request is discarded before it is sent, so an answer is only ever taken for
the transfer it answers; late answers to earlier transfers are counted as stale and dropped. Garbage, corrupted
and truncated frames are skipped by the shared frame parser (counted in `link`). A port that
disappears (the bridge was reset or unplugged) is reopened by the next transfer.
"""

from __future__ import annotations

import errno
import os
import time
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qsl

import serial

from ..errors import CommError, ConfigError, InvalidArgumentError
from ..hil_bridge import framing as F
from ..serial_port import DEFAULT_BAUD, PORT_ERRORS, open_port
from .base import Bus

# Per attempt. A healthy bridge answers within a few ms; what matters is that a lost request or
# answer is retried well inside the joints' 50 ms deadman, which every joint of the arm would
# otherwise fire while the host waits. A bridge-side I2C timeout (50 ms) still reaches the host:
# its answer carries the transfer's SEQ, so the retry that is waiting for it accepts it.
DEFAULT_TIMEOUT_S = 0.02
HANDSHAKE_TIMEOUT_S = 0.25  # a board that was just opened may still be busy
SCAN_TIMEOUT_S = 2.0  # a healthy scan of 112 addresses; a stuck bus answers TIMEOUT sooner
QUIET_S = 0.005  # a frame that pauses this long is truncated; also the longest single read

# Bridge status -> errno of the OSError the base class retries and reports (Linux adapters' codes).
_STATUS_ERRNO = {F.NACK: errno.EREMOTEIO, F.TIMEOUT: errno.ETIMEDOUT, F.BUS_ERROR: errno.EIO,
                 F.BAD_FRAME: errno.EBADMSG}


@dataclass(frozen=True)
class BridgeVersion:
    protocol: int
    firmware: tuple[int, int, int]
    max_data: int  # bytes per transaction phase
    i2c_hz: int  # the bridge's I2C clock


@dataclass
class SerialLinkStats:
    """What crossed the serial link: requests, and every kind of trouble it survived."""

    requests: int = 0
    timeouts: int = 0  # attempts with no matching answer in time
    damaged: int = 0  # attempts given up at once because the answer was damaged
    stale: int = 0  # answers to an earlier transfer, dropped by sequence number
    crc_errors: int = 0
    bad_lengths: int = 0
    truncated: int = 0  # frames that stopped half way
    skipped_bytes: int = 0  # garbage between frames
    bad_frames: int = 0  # requests the bridge could not execute
    reconnects: int = 0

    @property
    def resyncs(self) -> int:
        """Frames abandoned to look for the next start marker."""
        return self.crc_errors + self.bad_lengths + self.truncated


class SerialBus(Bus):
    """I2C through the HIL bridge on serial port `port`; `timeout` in s per attempt."""

    scheme = "serial"

    def __init__(self, port: str, *, baud: int = DEFAULT_BAUD, timeout: float = DEFAULT_TIMEOUT_S,
                 **kwargs: Any) -> None:
        super().__init__(**kwargs)
        if not timeout > 0:
            raise InvalidArgumentError(f"serial timeout must be > 0 s, got {timeout}")
        self.port = port
        self.baud = baud
        self.timeout = timeout
        self._parser = F.FrameParser()
        self._stats = SerialLinkStats()
        self._frame = bytearray(F.MAX_FRAME)
        # One sequence number per transfer, shared by its retries, so the bridge recognises a retry
        # and replays its answer instead of doing the I2C work again (a HOME or a relative move
        # twice). A random start keeps a new process from matching the previous one's last request.
        self._seq = os.urandom(1)[0]
        self._fresh_seq = True
        self._serial: serial.Serial | None = open_port(port, baud=baud, timeout=min(timeout, QUIET_S))
        try:
            self.version = self._handshake()
        except BaseException:
            self._serial.close()
            raise

    @classmethod
    def from_target(cls, target: str, **kwargs: Any) -> SerialBus:
        """The bus for the part of a `serial:` URL after the colon: PORT[?baud=N&timeout=S]."""
        path, _, query = target.partition("?")
        if not path:
            raise ConfigError("serial: needs a port, e.g. serial:/dev/ttyACM0")
        try:
            options = parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query))
        except ValueError:
            raise ConfigError(f"serial: cannot read the options {query!r}; use ?baud=N&timeout=S") from None
        for key, value in options:
            if key not in ("baud", "timeout"):
                raise ConfigError(f"serial: unknown option {key!r}; use baud= or timeout=")
            try:
                kwargs[key] = int(value) if key == "baud" else float(value)
            except ValueError:
                raise ConfigError(f"serial: {key}={value!r} is not a number") from None
        return cls(path, **kwargs)

    def _handshake(self) -> BridgeVersion:
        try:
            _, data = self._ask(F.VERSION, b"", (F.OK,), max(self.timeout, HANDSHAKE_TIMEOUT_S))
        except CommError as exc:
            raise CommError(f"no HIL bridge answers on {self.port} ({exc.detail}); is the bridge "
                            "firmware running, and is this not a joint's debug port?") from None
        if len(data) != F.VERSION_BYTES or data[0] != F.PROTOCOL:
            raise CommError(f"the bridge on {self.port} speaks framing protocol {data[0] if data else '?'}, "
                            f"this host {F.PROTOCOL}: flash the bridge firmware of this release")
        return BridgeVersion(data[0], (data[1], data[2], data[3]), data[4], int.from_bytes(data[5:9], "little"))

    def _ask(self, kind: int, payload: bytes, accept: tuple[int, ...],
             timeout: float | None = None) -> tuple[int, bytes]:
        """A request outside the base class's retries: up to `attempts` tries for a status in `accept`."""
        problem = ""
        with self._lock:
            self._fresh_seq = True
            for _ in range(self.attempts):
                try:
                    status, data = self._request(kind, payload, timeout)
                except (OSError, TimeoutError) as exc:
                    problem = str(exc)
                    continue
                if status in accept:
                    return status, data
                problem = f"the bridge answered {F.status_name(status)}"
        raise CommError(problem)

    @property
    def link(self) -> SerialLinkStats:
        """Link statistics, including the frame parser's counts."""
        p = self._parser
        s = self._stats
        return SerialLinkStats(s.requests, s.timeouts, s.damaged, s.stale, p.crc_errors, p.bad_lengths,
                               p.truncated, p.skipped, s.bad_frames, s.reconnects)

    def describe(self) -> str:
        return f"serial:{self.port}"

    def close(self) -> None:
        with self._lock:
            if self._serial is not None:
                self._serial.close()
                self._serial = None
            super().close()

    # ---- transactions ----

    def transfer(self, addr: int, write: bytes | None, read_len: int) -> bytes:
        with self._lock:
            self._fresh_seq = True
            return super().transfer(addr, write, read_len)

    def _transfer_once(self, addr: int, write: bytes | None, read_len: int) -> bytes:
        self._check(addr, write, read_len)
        if write is None:
            status, data = self._request(F.READ, bytes((addr, read_len)))
        else:
            status, data = self._request(F.XFER, bytes((addr, read_len)) + write)
        self._raise_for(status, addr)
        return data

    def _probe(self, addr: int) -> bool:
        status, _ = self._ask(F.XFER, bytes((addr, 0)), (F.OK, F.NACK))
        return status == F.OK

    def scan(self, first: int = 0x08, last: int = 0x77) -> list[int]:
        """Addresses that acknowledge, from one SCAN request (the bridge scans 0x08..0x77)."""
        _, bitmap = self._ask(F.SCAN, b"", (F.OK,), SCAN_TIMEOUT_S)
        if len(bitmap) != F.SCAN_BYTES:
            raise CommError(f"the bridge on {self.port} sent a {len(bitmap)}-byte SCAN answer")
        return [a for a in range(first, last + 1) if bitmap[a >> 3] & (1 << (a & 7))]

    def _check(self, addr: int, write: bytes | None, read_len: int) -> None:
        if not 0 <= addr <= 0x7F:
            raise InvalidArgumentError(f"I2C address 0x{addr:x} is not a 7-bit address")
        if not 0 <= read_len <= F.MAX_DATA or write is not None and len(write) > F.MAX_DATA:
            raise InvalidArgumentError(f"the bridge moves at most {F.MAX_DATA} bytes per phase")
        if write is None and read_len == 0:
            raise InvalidArgumentError("a transaction needs a write or a read phase")

    def _raise_for(self, status: int, addr: int) -> None:
        if status == F.OK:
            return
        if status == F.BAD_FRAME:
            self._stats.bad_frames += 1
        code = _STATUS_ERRNO.get(status, errno.EIO)
        raise OSError(code, f"bridge: {F.status_name(status)} at 0x{addr:02x}")

    # ---- the serial link ----

    def _request(self, kind: int, payload: bytes, timeout: float | None = None) -> tuple[int, bytes]:
        """Send one request, return (status, data) of its answer; TimeoutError if none comes."""
        port = self._connected()
        if self._fresh_seq:
            self._seq = (self._seq + 1) & 0xFF
            self._fresh_seq = False
        timeout = self.timeout if timeout is None else timeout
        frame = self._frame
        frame[F.HEADER:F.HEADER + len(payload)] = payload
        size = F.seal(frame, kind, self._seq, len(payload))
        parser = self._parser
        try:
            port.reset_input_buffer()  # nothing received before the request can answer it
            parser.reset()
            port.write(frame[:size])
        except PORT_ERRORS as exc:
            raise self._lost(exc) from None
        self._stats.requests += 1
        deadline = time.monotonic() + timeout
        broken, skipped = self._broken_frames(), parser.skipped
        while True:
            try:
                chunk = port.read(port.in_waiting or 1)
            except PORT_ERRORS as exc:
                raise self._lost(exc) from None
            if not chunk and parser.partial:
                parser.expire()  # a silent stretch inside a frame: it was truncated
            answer = self._answer_in(chunk, kind | F.RESPONSE)
            if answer is not None:
                return answer
            if self._broken_frames() != broken or (not chunk and not parser.partial and parser.skipped != skipped):
                # The answer came and was damaged (or its start byte was): nothing else will come,
                # so the retry goes out now rather than after the timeout.
                self._stats.damaged += 1
                raise OSError(errno.EBADMSG, "the bridge's answer was damaged on the serial link")
            if time.monotonic() >= deadline:
                self._stats.timeouts += 1
                raise TimeoutError(f"no answer from the bridge within {timeout * 1000:.0f} ms")

    def _broken_frames(self) -> int:
        p = self._parser
        return p.crc_errors + p.bad_lengths + p.truncated

    def _answer_in(self, chunk: bytes, kind: int) -> tuple[int, bytes] | None:
        """Feed `chunk` to the parser; (status, data) of the answer to the current request, if any."""
        parser = self._parser
        pos = 0
        while True:
            pos = parser.feed(chunk, pos)
            if not parser.ready:
                return None
            buf = parser.buf
            match = parser.kind == kind and parser.seq == self._seq and parser.payload_len >= 1
            answer = (buf[F.HEADER], bytes(buf[F.HEADER + 1:parser.size - 2]))
            parser.release()
            if match:
                return answer
            self._stats.stale += 1

    def _connected(self) -> serial.Serial:
        if self._serial is None:
            try:
                self._serial = open_port(self.port, baud=self.baud, timeout=min(self.timeout, QUIET_S))
            except CommError as exc:  # an attempt that failed: the base class retries and counts it
                raise OSError(errno.ENODEV, exc.detail) from None
            self._stats.reconnects += 1
        return self._serial

    def _lost(self, exc: Exception) -> OSError:
        """The port failed (unplugged, reset): close it so the next attempt reopens it."""
        if self._serial is not None:
            try:
                self._serial.close()
            except PORT_ERRORS:
                pass
            self._serial = None
        return OSError(errno.EIO, f"serial port {self.port} failed: {exc}")
