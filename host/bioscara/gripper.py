"""The servo parallel gripper: width commands, a position estimate and the saved last position.

Width w (m) maps to the servo angle α = reduction · (w − offset) degrees, and the angle to the pulse
on-time t_on = α / 90 · 500 + 1500 µs, clamped to [servo_min_us, servo_max_us]. The PWM duty cycle is
that on-time, duty_ns = 1000 · t_on, at any frequency (at 50 Hz it is t_on / 200 of the 20 ms period).

A hobby servo reports nothing back, so `get_position()` is an estimate: it moves from where it was
toward the latest command at `servo_speed` m/s and stops there. (The original reported the command
as a step 1 s late.)

The last position is kept across runs in `state_file` as 4 bytes, a little-endian float32, as the
original's last_pos.b. The default location is $XDG_STATE_HOME/bioscara/ (~/.local/state/bioscara/),
with separate files for the real and the mock gripper.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import struct
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import ClassVar, Self

from .config import GripperConfig
from .errors import BioscaraError, CommError, InvalidArgumentError, NotEnabledError, NotInitError
from .paths import default_state_dir
from .pwm import DEFAULT_ROOT, SysfsPWM

log = logging.getLogger("bioscara.gripper")

_STATE_FORMAT = "<f"
_START_TRIES = 3
_START_RETRY_S = 0.01


def servo_pulse_us(config: GripperConfig, width: float) -> float:
    """Servo pulse on-time in µs for a width in m, clamped to the servo's pulse range."""
    angle = config.reduction * (width - config.offset)  # degrees
    return min(max(angle / 90.0 * 500.0 + 1500.0, config.servo_min_us), config.servo_max_us)


class BaseGripper:
    """Gripper logic without hardware: clamping, the position estimate and the saved position.

    Widths are in m, velocities in m/s, `clock` returns seconds. Use `close()` or a `with` block to
    disable (saving the position) and release the hardware.
    """

    state_name: ClassVar[str] = "gripper_position"  # file name in the default state directory

    def __init__(self, config: GripperConfig, clock: Callable[[], float] = time.monotonic) -> None:
        self.config = config
        self.state_file = (Path(config.state_file).expanduser() if config.state_file
                           else default_state_dir() / self.state_name)
        self._clock = clock
        self._enabled = False
        # Estimate: a ramp from _from (at time _since) toward _target at servo_speed; None until enabled.
        self._target: float | None = None
        self._from = 0.0
        self._since = 0.0

    @property
    def enabled(self) -> bool:
        return self._enabled

    def init(self) -> None:
        """Acquire the hardware (nothing to do without hardware)."""

    def deinit(self) -> None:
        """Release the hardware (nothing to do without hardware)."""

    def enable(self) -> None:
        """Drive the servo to the saved position (init_pos if there is no valid one). No-op when enabled."""
        if self._enabled:
            return
        width = self.load_position()
        self._start_output(width)
        self._target = self._from = width
        self._since = self._clock()
        self._enabled = True

    def disable(self) -> None:
        """Stop driving the servo and save the estimated position. No-op when disabled."""
        if not self._enabled:
            return
        width = self.get_position()
        self._target = self._from = width  # without pulses the servo stops where it is
        self._enabled = False
        try:
            self._stop_output()
        finally:
            self._save_position(width)

    def set_position(self, width: float) -> None:
        """Command a width in m, clamped to [min, max]. NaN or inf raise InvalidArgumentError and change nothing."""
        if not math.isfinite(width):
            raise InvalidArgumentError(f"width {width!r} m is not a finite number", joint="gripper")
        if not self._enabled:
            raise NotEnabledError("not enabled", joint="gripper")
        width = min(max(width, self.config.min), self.config.max)
        self._command(width)
        now = self._clock()
        self._from = self._estimate(now)
        self._target = width
        self._since = now

    def get_position(self) -> float:
        """Estimated width in m."""
        return self._estimate(self._clock())

    def get_velocity(self) -> float:
        """Velocity of the estimated width in m/s: ±servo_speed while moving, else 0."""
        target = self._known_target()
        remaining = target - self._estimate(self._clock())
        return math.copysign(self.config.servo_speed, remaining) if remaining else 0.0

    def close(self) -> None:
        """Disable (saving the position) and release the hardware. Safe to call more than once."""
        try:
            self.disable()
        finally:
            self.deinit()

    def __enter__(self) -> Self:
        self.init()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def load_position(self) -> float:
        """The saved width in m, or init_pos (with a warning) when the file is missing or not valid."""
        fallback = self.config.init_pos
        try:
            with open(self.state_file, "rb") as f:
                data = f.read(struct.calcsize(_STATE_FORMAT) + 1)
        except FileNotFoundError:
            log.warning("no saved gripper position in %s; using init_pos %g m", self.state_file, fallback)
            return fallback
        except OSError as e:
            log.warning("cannot read %s (%s); using init_pos %g m", self.state_file, e.strerror or e, fallback)
            return fallback
        if len(data) != struct.calcsize(_STATE_FORMAT):
            size = f"{len(data)} bytes" if len(data) <= 4 else "more than 4 bytes"
            log.warning("%s holds %s, not a 4-byte position; using init_pos %g m", self.state_file, size, fallback)
            return fallback
        width: float = struct.unpack(_STATE_FORMAT, data)[0]
        lo, hi = _float32(self.config.min), _float32(self.config.max)
        if not lo <= width <= hi:  # also refuses NaN
            log.warning("saved gripper position %r m in %s is outside %g..%g m; using init_pos %g m",
                        width, self.state_file, self.config.min, self.config.max, fallback)
            return fallback
        # float32 rounding can put a saved limit just outside the float64 one.
        return min(max(width, self.config.min), self.config.max)

    def _save_position(self, width: float) -> None:
        """Write the width atomically: a crash leaves either the old file or the new one."""
        directory = self.state_file.parent
        try:
            directory.mkdir(parents=True, exist_ok=True)
            _remove_stale_temporaries(self.state_file)
            # Named after this process, so a writer that was killed half way is recognised (and its
            # file removed) by the next save, whichever process makes it.
            tmp = directory / f".{self.state_file.name}.{os.getpid()}.tmp"
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()  # ours from an earlier, interrupted save (or a dead process with our pid)
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            try:
                with os.fdopen(fd, "wb") as f:
                    f.write(struct.pack(_STATE_FORMAT, width))
                    f.flush()
                    os.fsync(f.fileno())
                os.replace(tmp, self.state_file)
            except BaseException:
                with contextlib.suppress(OSError):
                    os.unlink(tmp)
                raise
            _fsync_dir(directory)
        except OSError as e:
            raise BioscaraError(f"cannot save the position to {self.state_file}: {e.strerror or e}",
                                joint="gripper") from e

    def _estimate(self, now: float) -> float:
        target = self._known_target()
        travelled = self.config.servo_speed * max(now - self._since, 0.0)
        if abs(target - self._from) <= travelled:
            return target
        return self._from + math.copysign(travelled, target - self._from)

    def _known_target(self) -> float:
        if self._target is None:
            raise NotEnabledError("the position is unknown until the gripper is enabled", joint="gripper")
        return self._target

    # Hardware hooks, called with a clamped width in m.
    def _start_output(self, width: float) -> None:
        """Start driving the servo at `width`."""

    def _command(self, width: float) -> None:
        """Drive the servo toward `width`."""

    def _stop_output(self) -> None:
        """Stop driving the servo."""


class MockGripper(BaseGripper):
    """A gripper without hardware, with its own default state file so it never moves the real one's."""

    state_name = "mock_gripper_position"


class Gripper(BaseGripper):
    """The real gripper: a hobby servo on a sysfs hardware PWM channel."""

    def __init__(self, config: GripperConfig, clock: Callable[[], float] = time.monotonic, *,
                 pwm_root: str | os.PathLike[str] = DEFAULT_ROOT, sleep: Callable[[float], None] = time.sleep
                 ) -> None:
        super().__init__(config, clock)
        self._pwm_root = pwm_root
        self._sleep = sleep
        self._pwm: SysfsPWM | None = None

    def init(self) -> None:
        """Open the PWM channel (it is exported and started by enable)."""
        if self._pwm is None:
            self._pwm = SysfsPWM(self.config.pwm_chip, self.config.pwm_channel, self.config.frequency_hz,
                                 self._pwm_root, clock=self._clock, sleep=self._sleep)

    def deinit(self) -> None:
        """Disable if enabled, then close the PWM channel."""
        if self._pwm is not None:
            try:
                self.disable()
            finally:
                pwm, self._pwm = self._pwm, None
                pwm.close()

    def _require_pwm(self) -> SysfsPWM:
        if self._pwm is None:
            raise NotInitError("the PWM is not open; call init() first", joint="gripper")
        return self._pwm

    def _duty_ns(self, width: float) -> int:
        return round(servo_pulse_us(self.config, width) * 1000.0)

    def _start_output(self, width: float) -> None:
        pwm = self._require_pwm()
        for attempt in range(1, _START_TRIES + 1):
            try:
                pwm.start(self._duty_ns(width))
                return
            except CommError:
                if attempt == _START_TRIES:
                    raise
                self._sleep(_START_RETRY_S)

    def _command(self, width: float) -> None:
        self._require_pwm().set_duty_ns(self._duty_ns(width))

    def _stop_output(self) -> None:
        self._require_pwm().stop()


def _float32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


def _fsync_dir(directory: Path) -> None:
    """Make a rename in `directory` durable."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _remove_stale_temporaries(state_file: Path) -> None:
    """Delete the temporary files of saves whose process is gone (killed between write and rename)."""
    for tmp in state_file.parent.glob(f".{state_file.name}.*.tmp"):
        pid = tmp.name[len(state_file.name) + 2:-len(".tmp")]
        if pid.isdigit() and int(pid) != os.getpid() and _alive(int(pid)):
            continue
        with contextlib.suppress(OSError):
            tmp.unlink()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # it exists, owned by someone else
        return True
    return True
