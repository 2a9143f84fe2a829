"""Hardware PWM through the Linux sysfs interface (/sys/class/pwm/pwmchipN/pwmM)."""

from __future__ import annotations

import errno
import math
import os
import time
from collections.abc import Callable
from pathlib import Path

from .errors import CommError, IncorrectStateError, InvalidArgumentError

DEFAULT_ROOT = "/sys/class/pwm"
_POLL_S = 0.01


class SysfsPWM:
    """One PWM channel. Times are in ns, as sysfs takes them.

    `root` is the sysfs class directory (tests point it at a fake tree). After an export the kernel
    creates pwmM/ and udev then hands its files to the gpio group, so `start` waits up to
    `export_timeout_s` for pwmM/period to become writable, using `clock` and `sleep`.
    """

    def __init__(self, chip: int, channel: int, frequency_hz: float, root: str | os.PathLike[str] = DEFAULT_ROOT,
                 *, export_timeout_s: float = 2.0, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        if not (math.isfinite(frequency_hz) and 0 < frequency_hz <= 1e9):
            raise InvalidArgumentError(f"PWM frequency {frequency_hz!r} Hz must be within (0, 1e9]")
        self.chip_dir = Path(root) / f"pwmchip{chip}"
        self.channel = channel
        self.channel_dir = self.chip_dir / f"pwm{channel}"
        self.period_ns = round(1e9 / frequency_hz)
        self._export_timeout_s = export_timeout_s
        self._clock = clock
        self._sleep = sleep
        self._started = False
        self._exported_by_us = False

    def start(self, duty_ns: int = 0) -> None:
        """Export the channel if needed, set period and duty cycle, and enable the output."""
        self._check_duty(duty_ns)
        if not self.chip_dir.is_dir():
            raise CommError(f"PWM chip {self.chip_dir} does not exist: enable hardware PWM with 'dtoverlay=pwm' "
                            "(or 'dtoverlay=pwm-2chan') in /boot/firmware/config.txt and reboot")
        if not self._writable():
            self._export()
            self._wait_for_channel()
        # The kernel refuses a duty cycle longer than the period at every step, so the order depends on
        # the duty cycle left over from before.
        if self._read_int("duty_cycle") > self.period_ns:
            self._write("duty_cycle", duty_ns)
            self._write("period", self.period_ns)
        else:
            self._write("period", self.period_ns)
            self._write("duty_cycle", duty_ns)
        self._write("enable", 1)
        self._started = True

    def set_duty_ns(self, duty_ns: int) -> None:
        """Set the on-time of each period, 0..period_ns."""
        self._check_duty(duty_ns)
        if not self._started:
            raise IncorrectStateError(f"{self.channel_dir} is not started")
        self._write("duty_cycle", duty_ns)

    def stop(self) -> None:
        """Disable the output (the line stays low). Nothing happens when it is not running."""
        if self._started:
            self._write("enable", 0)
            self._started = False

    def close(self) -> None:
        """Stop, and unexport the channel if this object exported it. Safe to call more than once."""
        self.stop()
        if self._exported_by_us:
            self._exported_by_us = False
            self._write_file(self.chip_dir / "unexport", self.channel)

    def _check_duty(self, duty_ns: int) -> None:
        if isinstance(duty_ns, bool) or not isinstance(duty_ns, int) or not 0 <= duty_ns <= self.period_ns:
            raise InvalidArgumentError(f"PWM duty cycle {duty_ns!r} ns must be an integer 0..{self.period_ns}")

    def _writable(self) -> bool:
        return os.access(self.channel_dir / "period", os.W_OK)

    def _export(self) -> None:
        try:
            self._write_file(self.chip_dir / "export", self.channel)
            self._exported_by_us = True
        except CommError as e:
            if not (isinstance(e.__cause__, OSError) and e.__cause__.errno == errno.EBUSY):
                raise
            # EBUSY: already exported, by someone else or by an earlier run; it is not ours to unexport.

    def _wait_for_channel(self) -> None:
        deadline = self._clock() + self._export_timeout_s
        while not self._writable():
            if self._clock() >= deadline:
                state = "is not writable" if self.channel_dir.is_dir() else "did not appear"
                raise CommError(f"{self.channel_dir}/period {state} within {self._export_timeout_s:g} s of the "
                                "export (on a Raspberry Pi the user needs to be in the 'gpio' group)")
            self._sleep(_POLL_S)

    def _read_int(self, name: str) -> int:
        path = self.channel_dir / name
        try:
            return int(path.read_text().strip())
        except (OSError, ValueError) as e:
            raise CommError(f"cannot read {path}: {e}") from e

    def _write(self, name: str, value: int) -> None:
        self._write_file(self.channel_dir / name, value)

    @staticmethod
    def _write_file(path: Path, value: int) -> None:
        """Write one number with a single write(2), where sysfs reports its errors."""
        data = str(value).encode()
        try:
            fd = os.open(path, os.O_WRONLY | os.O_TRUNC)
            try:
                written = os.write(fd, data)
            finally:
                os.close(fd)
        except OSError as e:
            raise CommError(f"cannot write {value} to {path}: {e.strerror or e}") from e
        if written != len(data):
            raise CommError(f"short write of {value} to {path} ({written} of {len(data)} bytes)")
