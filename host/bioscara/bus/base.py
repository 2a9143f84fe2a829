"""The bus interface every transport implements, with retries and link statistics on top."""

from __future__ import annotations

import re
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import CommError, ConfigError

if TYPE_CHECKING:
    from ..commander import Commander
from ..firmware.spec.protocol import wire_bits

RETRY_DELAYS_S = (0.0001, 0.001, 0.005)  # between attempts; the original waited only 50 us


@dataclass
class LinkStats:
    """Traffic to one address: transactions, failed attempts, transactions lost after all retries."""

    transactions: int = 0
    failed_attempts: int = 0
    comm_errors: int = 0
    bits: int = 0
    last_error: str = ""


@dataclass
class BusStats:
    links: dict[int, LinkStats] = field(default_factory=dict)

    def link(self, addr: int) -> LinkStats:
        return self.links.setdefault(addr, LinkStats())


class Bus(ABC):
    """An I2C bus as the joints see it.

    `transfer(addr, write, read_len)` is one transaction: write `write` (None: no write phase),
    repeated START, read `read_len` bytes (0: no read phase), STOP. It is retried up to `attempts`
    times; NACKs, timeouts, I/O errors and short reads then raise CommError. Calls are serialized,
    so a communicator thread and a command-line tool can share one bus.
    """

    scheme = ""
    # Whether joint_config_file & co. reach the joints' configuration files (the simulated joints');
    # a real bus reaches the I2C only, the files are on each board (its USB serial port).
    reaches_config_files = False

    def __init__(self, *, attempts: int = 3, speed_hz: int = 400_000) -> None:
        if attempts < 1:
            raise ValueError("attempts must be >= 1")
        self.attempts = attempts
        self.speed_hz = speed_hz
        self.stats = BusStats()
        self._lock = threading.RLock()
        self._closed = False

    @abstractmethod
    def _transfer_once(self, addr: int, write: bytes | None, read_len: int) -> bytes:
        """One attempt; raise OSError (or TimeoutError) on failure."""

    @abstractmethod
    def _probe(self, addr: int) -> bool:
        """True if `addr` acknowledges (a 0-byte write)."""

    def transfer(self, addr: int, write: bytes | None, read_len: int) -> bytes:
        if self._closed:
            raise CommError(f"bus {self.describe()} is closed")
        link = self.stats.link(addr)
        problem = ""
        with self._lock:
            for attempt in range(self.attempts):
                if attempt:
                    self.sleep(RETRY_DELAYS_S[min(attempt, len(RETRY_DELAYS_S)) - 1])
                try:
                    reply = self._transfer_once(addr, write, read_len)
                except (OSError, TimeoutError) as exc:
                    problem = _describe_error(exc)
                else:
                    if len(reply) == read_len:
                        link.transactions += 1
                        link.bits += wire_bits(len(write) if write is not None else 0, read_len)
                        return reply
                    problem = f"short read: {len(reply)} of {read_len} bytes"
                link.failed_attempts += 1
        link.comm_errors += 1
        link.last_error = problem
        raise CommError(f"I2C 0x{addr:02x} ({self.describe()}): {problem} "
                        f"(after {self.attempts} attempt{'s' if self.attempts > 1 else ''})")

    def write(self, addr: int, data: bytes) -> None:
        """A plain write transaction (no read phase)."""
        self.transfer(addr, data, 0)

    def scan(self, first: int = 0x08, last: int = 0x77) -> list[int]:
        """Addresses that acknowledge, like i2cdetect."""
        with self._lock:
            return [addr for addr in range(first, last + 1) if self._probe(addr)]

    def sleep(self, seconds: float) -> None:
        """Wait on the bus clock (virtual time on the simulated bus)."""
        time.sleep(seconds)

    def monotonic(self) -> float:
        """Seconds on the bus clock."""
        return time.monotonic()

    def describe(self) -> str:
        return self.scheme + ":"

    def joint_config_file(self, addr: int) -> bytes:
        """The configuration file (JSON bytes) of the joint at `addr`, where the bus reaches it."""
        raise ConfigError(self._no_config_file())

    def write_joint_config_file(self, addr: int, data: bytes) -> None:
        """Replace the joint's configuration file whole (ConfigError, and nothing changes, when its
        firmware would refuse it); the firmware reads it at its next boot (`reboot_joint`)."""
        raise ConfigError(self._no_config_file())

    def reboot_joint(self, addr: int, timeout: float = 10.0) -> None:
        """Restart the joint's firmware and wait (bus clock, at most `timeout` s) until it answers."""
        raise ConfigError(self._no_config_file())

    def _no_config_file(self) -> str:
        return (f"{self.describe()} reaches the joints' I2C only; a joint's configuration file is on its "
                f"board, reached over the board's USB serial port (`bioscara flash PORT --joint-config FILE`)")

    def _await_joint(self, addr: int, timeout: float) -> None:
        deadline = self.monotonic() + timeout
        while not self._probe(addr):
            if self.monotonic() >= deadline:
                raise CommError(f"the joint at 0x{addr:02x} did not come back within {timeout:g} s of its reboot")
            self.sleep(0.05)

    def arm_lock_path(self) -> Path | None:
        """The commander lock every process opening this bus shares (see commander.py); None
        for a bus no other process can reach (simulated joints inside this process)."""
        from ..paths import default_state_dir
        key = re.sub(r"[^A-Za-z0-9]+", "-", self.describe()).strip("-")
        return default_state_dir() / f"arm-{key}.lock"

    @property
    def commander(self) -> Commander | None:
        """Who commands the arm on this bus, as this process sees it (None: only this process
        reaches the bus, nothing to share)."""
        path = self.arm_lock_path()
        if path is None:
            return None
        from ..commander import commander_for
        return commander_for(path, self.describe())

    def close(self) -> None:
        """Release the bus; idempotent."""
        self._closed = True

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _describe_error(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.errno is not None:
        import errno as errno_names
        name = errno_names.errorcode.get(exc.errno, str(exc.errno))
        meaning = {121: "no ACK (NACK)", 6: "no ACK (NACK)", 110: "timeout", 5: "I/O error",
                   11: "arbitration lost", 74: "bad message"}.get(exc.errno, exc.strerror or "")
        return f"{name} {meaning}".strip()
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
