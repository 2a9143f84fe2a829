"""One joint controller on the bus: the original BaseJoint/Joint API, in Python naming.

Every method sends exactly the original's transaction (original-host-behaviour.md 2.4) and converts
units through the joint's `Transmission`. Differences from the original, all fixes of its bugs (9.2):

* positions outside [min, max] and velocities above `max_velocity` are rejected with
  INVALID_ARGUMENT and never sent; bad values of any kind never reach the wire;
* velocity and acceleration limits use |reduction|; the homing RPM is rounded, not truncated;
* enabled/homed guards use flags no older than `flags_max_age` (the control cycle's read refreshes
  them, so a write in the same cycle costs no extra transaction; stale flags cost one PING);
* flags are only taken from successful transfers; every wait has a timeout;
* a rejected homing call changes nothing (the offset is taken only once homing succeeded);
* `get_position` raises NotHomedError instead of returning 0.0 when the joint is not homed;
* `init` twice is harmless; `close` is explicit and idempotent.

The joint is reached through a `link.Link` (legacy map, protocol v2, or watched from beside
another program's commands) and never asks which: commands are built once (`Command`, with the
guards and unit conversion) and handed to the link, refusals come back as one kind of error.
A joint that commands (the default) makes this program the bus's commander (commander.py) while
it is open; a watching joint (`watch=True`) never commands and never changes the joint's protocol.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass
from enum import Enum, IntEnum
from typing import Any

from .bus.base import Bus
from .errors import (
    BioscaraError, CommError, IncorrectStateError, InvalidArgumentError, NotEnabledError, NotHomedError,
    NotInitError, StalledError,
)
from .firmware.spec import protocol as P
from .firmware.spec import protocol_v2 as V
from .link import Command, LegacyLink, Link, LinkRejected, V2Link, WatchedLink
from .transmission import Transmission

log = logging.getLogger("bioscara.joint")

CACHED_FLAGS = P.FLAG_STALL | P.FLAG_BUSY | P.FLAG_NOTHOMED | P.FLAG_NOTENABLED
V2_SWITCH_S = 0.001  # one pass of the joint's main loop
V2_SWITCH_TIMEOUT_S = 0.05  # the slowest pass the chip shows, a garbage collection included
# A joint resting at its end stop reads a hair beyond it: encoder noise and error at rest, and the
# float32 motor degrees of the wire. Positions this close (motor degrees) beyond a limit count as
# on it (they are clamped onto it), so holding a joint where it stands never fails.
LIMIT_SLACK_DEG = 0.5


class BrakeMode(IntEnum):
    FREEWHEEL = P.BRAKE_FREEWHEEL
    COOLBRAKE = P.BRAKE_COOLBRAKE
    HARDBRAKE = P.BRAKE_HARDBRAKE


class BlockingCommand(Enum):
    NONE = 0
    HOME = P.HOME


class WaitTimeoutError(BioscaraError):
    """A joint stayed BUSY longer than the caller allowed."""


@dataclass(frozen=True)
class Identity:
    protocol: int
    firmware: tuple[int, int, int]
    joint_id: int
    spec_hash: int

    @property
    def firmware_version(self) -> str:
        return ".".join(str(v) for v in self.firmware)

    @property
    def spec_matches(self) -> bool:
        """True if the joint was built from the same protocol spec as this host."""
        return self.spec_hash == P.SPEC_HASH


@dataclass(frozen=True)
class RejectInfo:
    reason: int
    register: int
    count: int

    @property
    def text(self) -> str:
        reg = P.BY_ADDR[self.register]
        name = reg.name if reg else f"0x{self.register:02x}"
        return f"{name}: {P.reject_string(self.reason)}"


class Joint:
    """A joint controller at `address` on `bus`.

    Positions are in joint units (rad for revolute joints, m for prismatic ones), velocities in
    units/s, accelerations in units/s^2, currents in percent of the driver's full scale.
    """

    def __init__(self, name: str, address: int, bus: Bus, *, reduction: float = 1.0,
                 min: float = -math.inf, max: float = math.inf, max_velocity: float = math.inf,
                 flags_max_age: float = 0.02, homing_range_check: float | None = None,
                 watch: bool = False) -> None:
        if not min < max:
            raise InvalidArgumentError(f"min ({min}) must be below max ({max})", joint=name)
        self.name = name
        self.address = address
        self.bus = bus
        self.min = min
        self.max = max
        self.max_velocity = max_velocity
        self.flags_max_age = flags_max_age
        self.homing_range_check = homing_range_check  # tolerance (joint units); None: no check
        self.watchdog_ms = 0  # what the joint's WATCHDOG was last set to by this host
        self._start_position: float | None = None
        self._homing_refused = False  # the last homing found an implausible stop
        self.transmission = Transmission(reduction)
        self.flags = P.FLAGS_AT_BOOT
        self.flags_time = -math.inf
        self.current_blocking = BlockingCommand.NONE
        self._homing_offset = 0.0
        self._open = False
        self.watch = watch
        self.link: Link = LegacyLink(bus, address, name)
        # The latest state read, in wire units, and when (bus clock): what a commander publishes.
        self.position_deg = math.nan
        self.velocity_rpm = math.nan
        self.state_time = -math.inf
        self.cached_identity: Identity | None = None
        # Why the joint disabled itself, when it did so without this host asking (None: it did
        # not): its deadman (with this host's silence before), a stall, or a reboot.
        self.disabled_cause: str | None = None
        self.homing_failure: str | None = None  # why the last homing ended without the end stop
        self._disabling = False  # this host is disabling the joint: NOTENABLED is its own doing
        self._offset_stale = False  # a watched joint was homed (by its commander): read the new offset
        self._commanded_by: object = None  # a watched joint's commander at the last cycle

    def __repr__(self) -> str:
        return f"Joint({self.name!r}, 0x{self.address:02x}, flags={P.describe_flags(self.flags)})"

    # ---- lifecycle ----

    def init(self) -> None:
        """Check communication; restore the homing offset if the joint is still homed."""
        if self._open:
            return
        commander = self.bus.commander
        if self.watch and commander is not None:
            self.link = WatchedLink(self.bus, self.address, self.name, commander)
        elif commander is not None:
            commander.claim()  # ArmBusyError if another program commands this bus
            commander.publish(self.published_state)
        self._open = True
        self.current_blocking = BlockingCommand.NONE  # whatever ran before is the joint's past now
        try:
            try:
                self.check_com()
            except CommError:
                raise
            except BioscaraError:  # it answers, but not in the legacy map: left in v2 by a host?
                self._restore_legacy()
            if self.is_homed():
                self.transmission = self.transmission.with_offset(self.get_homing_offset())
        except BioscaraError:
            self._let_go()
            raise

    def _restore_legacy(self) -> None:
        """The joint serves v2 with no host commanding it (a program that did was killed): take it
        over and return it to the legacy map. A watching joint does so as a commander for that
        moment only, and not at all while another program commands."""
        if not self.watch:
            if not self.take_over_v2():
                raise CommError("the joint answers neither the legacy map nor protocol v2", joint=self.name)
            self.use_legacy()
            return
        commander = self.bus.commander
        if commander is not None:
            commander.claim()
        watched, self.link = self.link, LegacyLink(self.bus, self.address, self.name)
        try:
            if not self.take_over_v2():
                raise CommError("the joint answers neither the legacy map nor protocol v2", joint=self.name)
            self.use_legacy()
        finally:
            self.link = watched
            if commander is not None:
                commander.release()
        self.check_com()

    def _let_go(self) -> None:
        """Closed: no longer this program's to command."""
        was_open, self._open = self._open, False
        commander = self.bus.commander
        if was_open and not self.watch and commander is not None:
            commander.withdraw(self.published_state)
            commander.release()

    def close(self) -> None:
        """Stop using the joint (no motor I/O; call `disable` first to de-energize). Idempotent.

        A joint speaking v2 is returned to the legacy map, so any host can take over at once; if
        that fails (bus down) it returns by itself after protocol_v2.SILENCE_MS. A watchdog this
        host turned on is turned off first, unless the joint is busy (homing): a joint left
        holding keeps holding, as it would for the original host (whose deadman covers velocity
        only), and a homing this host started stops when it is gone."""
        if self.watchdog_ms and self._open and not self.flags & P.FLAG_BUSY:
            try:
                self.set_watchdog(0)
            except BioscaraError as exc:
                log.info("joint %s keeps its watchdog: %s", self.name, exc)
        if isinstance(self.link, V2Link) and self._open:
            try:
                self.use_legacy()
            except BioscaraError as exc:
                log.info("joint %s left in protocol v2: %s", self.name, exc)
        self._let_go()
        self.current_blocking = BlockingCommand.NONE
        if not isinstance(self.link, WatchedLink):
            self.link = LegacyLink(self.bus, self.address, self.name)

    # ---- protocol ----

    @property
    def protocol(self) -> str:
        """"v2" while the joint speaks the memory-mapped protocol, "legacy" in the original map,
        "watched" for a watching joint."""
        return self.link.name

    def use_v2(self) -> None:
        """Switch the joint to protocol v2 (the legacy PROTOCOL register), then sync with it."""
        self._require_open()
        if isinstance(self.link, V2Link):
            return
        self._command(P.PROTOCOL, V.PROTOCOL_V2)
        self.bus.sleep(2 * V2_SWITCH_S)  # the joint switches in its next main-loop pass
        link = V2Link(self.bus, self.address, self.name)
        self._take_flags(link.sync().flags)
        self.link = link

    def use_legacy(self) -> None:
        """Return the joint to the legacy register map (the v2 PROTOCOL command). The joint
        keeps serving v2 until this host has read the verdict, then switches in a main-loop
        pass: the legacy PING that follows is the confirmation."""
        self._require_open()
        link = self.link
        if not isinstance(link, V2Link):
            return
        problem: BioscaraError | None = None
        for _ in range(3):
            try:
                link.command(Command(P.PROTOCOL, P.register(P.PROTOCOL).encode(V.PROTOCOL_LEGACY)))
            except CommError as exc:
                problem = exc  # perhaps only the verdict was lost: the PING below tells
            self.link = LegacyLink(self.bus, self.address, self.name)
            try:
                self._await_legacy()
                return
            except BioscaraError as exc:
                problem = exc
                self.link = link
        raise CommError(f"the joint did not return to the legacy map ({problem.detail if problem else ''})",
                        joint=self.name)

    def _await_legacy(self) -> None:
        """PING until the joint answers in the legacy map, up to V2_SWITCH_TIMEOUT_S."""
        deadline = self.bus.monotonic() + V2_SWITCH_TIMEOUT_S
        while True:
            self.bus.sleep(V2_SWITCH_S)
            try:
                self.check_com()
                return
            except BioscaraError:
                if self.bus.monotonic() >= deadline:
                    raise

    def take_over_v2(self) -> bool:
        """True (now speaking v2) if the joint already serves v2, left so by an earlier host."""
        self._require_open()
        link = V2Link(self.bus, self.address, self.name)
        try:
            self._take_flags(link.sync(attempts=4).flags)
        except BioscaraError:
            return False
        self.link = link
        return True

    @contextlib.contextmanager
    def visit_legacy(self) -> Iterator[None]:
        """Reads of registers the v2 state block does not carry (diagnostics, the homing check):
        the joint speaks the legacy map for the block's length, then v2 again if it did."""
        was_v2 = isinstance(self.link, V2Link)
        self.use_legacy()
        try:
            yield
        finally:
            if was_v2:
                self.use_v2()

    deinit = close

    def __enter__(self) -> Joint:
        self.init()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def is_open(self) -> bool:
        return self._open

    @property
    def offset(self) -> float:
        return self.transmission.offset

    # ---- flags ----

    def is_homed(self) -> bool:
        return not self.flags & P.FLAG_NOTHOMED and not self._homing_refused

    def is_enabled(self) -> bool:
        return not self.flags & P.FLAG_NOTENABLED

    def is_stalled(self) -> bool:
        return bool(self.flags & P.FLAG_STALL)

    def is_busy(self) -> bool:
        return bool(self.flags & P.FLAG_BUSY)

    def get_flags(self) -> int:
        """Refresh the flags with a PING; returns them."""
        self._read(P.register(P.PING))
        return self.flags

    def check_com(self) -> None:
        (ack,) = self._read(P.register(P.PING))
        if ack != P.ACK:
            raise BioscaraError(f"PING answered 0x{ack:02x}, expected 'O'", joint=self.name)

    # ---- commands ----

    def enable(self, drive_current: int, hold_current: int) -> None:
        """Energize with currents in % (0..100); also turns stall detection off, as SETUP does."""
        self._disabling = False
        self._command(P.SETUP, drive_current, hold_current, 0, 0)
        self.disabled_cause = None
        if not self.is_enabled():
            raise NotEnabledError("still not enabled after SETUP", joint=self.name)

    def disable(self) -> None:
        """Stop, zero both currents and freewheel. Tries every step; raises the first failure."""
        first: BioscaraError | None = None
        self._disabling = True
        for step in (self.stop, lambda: self.set_hold_current(0), lambda: self.set_drive_current(0),
                     lambda: self.set_brake_mode(BrakeMode.FREEWHEEL)):
            try:
                step()
            except BioscaraError as exc:
                first = first or exc
        self.current_blocking = BlockingCommand.NONE  # its STOP aborted any homing
        if first is not None:
            raise first

    def set_watchdog(self, milliseconds: int) -> None:
        """Stop every motion (velocity, positioning, homing, orientation check) when this host is
        silent for `milliseconds`; 0 restores the original's deadman (velocity only, 50 ms)."""
        self._command(P.WATCHDOG, milliseconds)
        self.watchdog_ms = milliseconds

    def stop(self) -> None:
        """RPM 0; also aborts a running homing (the firmware clears BUSY)."""
        self._command(P.STOP, 0)

    def disable_closed_loop(self) -> None:
        self._command(P.DISABLECLOSEDLOOP, 0)

    def set_drive_current(self, percent: int) -> None:
        self._command(P.SETCURRENT, percent)

    def set_hold_current(self, percent: int) -> None:
        self._command(P.SETHOLDCURRENT, percent)

    def set_brake_mode(self, mode: BrakeMode | int) -> None:
        self._command(P.SETBRAKEMODE, int(mode))

    def set_max_acceleration(self, acceleration: float) -> None:
        """Motion acceleration limit, joint units/s^2 (> 0)."""
        self._command(P.SETMAXACCELERATION, self._positive(acceleration, "acceleration"))

    def set_max_velocity(self, velocity: float) -> None:
        """Positioning velocity limit, joint units/s (> 0)."""
        self._command(P.SETMAXVELOCITY, self._positive(velocity, "velocity"))

    def _positive(self, value: float, what: str) -> float:
        if not (math.isfinite(value) and value > 0):
            raise InvalidArgumentError(f"max {what} must be a positive number, got {value}", joint=self.name)
        return self.transmission.motor_limit(value)

    def enable_stallguard(self, sensitivity: int) -> None:
        """Stall detection with threshold sensitivity x 10 (0..255); call after `enable`."""
        self._command(P.ENABLESTALLGUARD, sensitivity)

    def get_position(self) -> float:
        """Joint position (rad or m). Raises NotHomedError if the joint is not homed."""
        (degrees,) = self._read(P.register(P.ANGLEMOVED))
        if not self.is_homed():
            raise NotHomedError("position is meaningless before homing", joint=self.name)
        self._follow_homing()
        return self.transmission.position(degrees)

    def _follow_homing(self) -> None:
        """A watched joint that another program homed: take the offset that homing stored."""
        if self._offset_stale:
            self._offset_stale = False
            self.transmission = self.transmission.with_offset(self.get_homing_offset())

    @property
    def limit_slack(self) -> float:
        """How far beyond min/max (joint units) a position still counts as on the limit."""
        return math.radians(LIMIT_SLACK_DEG) / abs(self.transmission.reduction)

    def within_limits(self, position: float) -> float:
        """`position` clamped onto [min, max] if it lies within `limit_slack` of them; raises
        InvalidArgumentError if it is farther out or not finite."""
        slack = self.limit_slack
        if not (math.isfinite(position) and self.min - slack <= position <= self.max + slack):
            raise InvalidArgumentError(f"position {position:g} is outside [{self.min:g}, {self.max:g}]",
                                       joint=self.name)
        return min(max(position, self.min), self.max)

    def set_position(self, position: float) -> None:
        """Move to `position` (joint units) within [min, max] (see `within_limits`)."""
        self._check_stall(self._send(self.position_command(position)))

    def position_command(self, position: float) -> Command:
        """MOVETOANGLE to `position` (joint units), after the guards: for `set_position` or `cycle`."""
        position = self.within_limits(position)
        self._require_enabled_and_homed()
        return self._build(P.MOVETOANGLE, self.transmission.motor_degrees(position))

    def get_velocity(self) -> float:
        """Encoder velocity, joint units/s."""
        (rpm,) = self._read(P.register(P.GETENCODERRPM))
        return self.transmission.velocity(rpm)

    def set_velocity(self, velocity: float) -> None:
        """Turn at `velocity` (joint units/s); |velocity| <= max_velocity."""
        self._check_stall(self._send(self.velocity_command(velocity)))

    def velocity_command(self, velocity: float) -> Command:
        """SETRPM for `velocity` (joint units/s), after the guards: for `set_velocity` or `cycle`."""
        if not (math.isfinite(velocity) and abs(velocity) <= self.max_velocity):
            raise InvalidArgumentError(f"velocity {velocity} exceeds the limit {self.max_velocity}", joint=self.name)
        self._require_enabled_and_homed()
        return self._build(P.SETRPM, self.transmission.motor_rpm(velocity))

    def cycle(self, setpoint: Command | None = None) -> tuple[float, float] | None:
        """One control cycle over whichever link the joint speaks: `setpoint` (built by
        `position_command`/`velocity_command`, or None) out, the state in. Returns (position,
        velocity) in joint units (position NaN while not homed), or None if no intact, fresh state
        arrived this time (protocol v2; the last one stands)."""
        self._require_open()
        if setpoint is not None and self.watch:
            raise IncorrectStateError(f"{setpoint.name}: this program only watches the joint", joint=self.name)
        state = self._over_link(lambda link: link.cycle(setpoint))
        if state is None:
            return None
        self._take_state(state.flags, state.position_deg, state.velocity_rpm)
        if setpoint is not None:
            self._check_stall(state.flags)
        if self.watch:
            # While another program commands, its offset may change (it homes): take it with every
            # state it publishes, and once more from the joint after it has gone.
            holder = getattr(self.link, "holder", None)
            if holder is not None or self._commanded_by is not None:
                self._offset_stale = True
            self._commanded_by = holder
        if self.is_homed():
            self._follow_homing()
        position = self.transmission.position(state.position_deg) if self.is_homed() else math.nan
        return position, self.transmission.velocity(state.velocity_rpm)

    def move_steps(self, steps: int) -> None:
        """Relative move in the stepper's microsteps (1/256 full step); allowed before homing."""
        self._require_enabled()
        self._check_stall(self._command(P.MOVESTEPS, steps))

    def check_orientation(self, degrees: float = 2.0, *, timeout: float = 30.0) -> None:
        """The firmware's wiring check by +/- `degrees` of motor angle; blocks until done."""
        self._require_enabled()
        self._command(P.CHECKORIENTATION, degrees)
        self.wait_while_busy(0.01, timeout)
        self._check_stall(self.flags)

    # ---- homing ----

    def home(self, velocity: float, sensitivity: int, current: int, *, timeout: float = 600.0) -> None:
        """Blocking homing: start, wait until the joint is no longer busy, verify."""
        self.start_homing(velocity, sensitivity, current)
        try:
            self.wait_while_busy(0.1, timeout)
        except BioscaraError:
            self.current_blocking = BlockingCommand.NONE
            self.stop()
            raise
        self.post_homing()

    def start_homing(self, velocity: float, sensitivity: int, current: int) -> None:
        """Start driving into the end stop at `velocity` (joint units/s; its sign picks the end stop).

        `sensitivity` is the |PID error| end-stop threshold (0..255), `current` the homing drive
        current in %. Nothing changes if the call is rejected.
        """
        if self.current_blocking is not BlockingCommand.NONE:
            raise IncorrectStateError(f"{self.current_blocking.name} is still running", joint=self.name)
        rpm = self.transmission.motor_rpm(velocity) if math.isfinite(velocity) else math.nan
        if not (1.0 <= abs(rpm) <= 250.0):
            raise InvalidArgumentError(f"homing velocity {velocity} is {rpm:.2f} motor RPM, "
                                       "outside 1..250", joint=self.name)
        self._require_enabled()
        self._start_position = None
        self.homing_failure = None
        if self.homing_range_check is not None and self.is_homed():
            self._start_position = self.get_position()
        self._command(P.HOME, 1 if rpm > 0 else 0, round(abs(rpm)), sensitivity, current)
        self.current_blocking = BlockingCommand.HOME
        self._homing_offset = self.max if velocity > 0 else self.min

    def post_homing(self) -> None:
        """After BUSY dropped: verify the joint is homed and store the offset on the joint."""
        if self.current_blocking is not BlockingCommand.HOME:
            raise IncorrectStateError("no homing was started", joint=self.name)
        self.current_blocking = BlockingCommand.NONE
        self.get_flags()
        self._homing_refused = False
        if not self.is_homed():
            if self.disabled_cause:
                self.homing_failure = self.disabled_cause
            else:
                with self.visit_legacy():  # HOMINGRESULT is not in the v2 state block
                    (outcome,) = self._read(P.register(P.HOMINGRESULT))
                self.homing_failure = P.homing_outcome_string(outcome) if outcome else "the end stop was not reached"
            raise NotHomedError(f"homing ended, not homed: {self.homing_failure}", joint=self.name)
        if self.homing_range_check is not None:
            self._check_homed_range(self.homing_range_check)
        self.transmission = self.transmission.with_offset(self._homing_offset)
        self._command(P.HOMEOFFSET, self._homing_offset)

    def _check_homed_range(self, tolerance: float) -> None:
        """The stop homing found must be plausible: no farther than the joint's range from where it
        started, and (when the joint was homed before) about where the end stop was expected."""
        with self.visit_legacy():  # HOMINGTRAVEL is not in the v2 state block
            (travel,) = self._read(P.register(P.HOMINGTRAVEL))
        scale = math.degrees(abs(self.transmission.reduction))  # motor degrees per joint unit
        slack = tolerance * scale + 2.0 * LIMIT_SLACK_DEG
        problem = None
        if abs(travel) > (self.max - self.min) * scale + slack:
            problem = (f"homing travelled {abs(travel):.1f} motor degrees, more than the joint's "
                       f"whole range ({(self.max - self.min) * scale:.1f})")
        elif self._start_position is not None:
            expected = abs(self._homing_offset - self._start_position) * scale
            if abs(abs(travel) - expected) > slack:
                problem = (f"homing stopped {abs(travel):.1f} motor degrees from its start; the end "
                           f"stop was {expected:.1f} away (an obstacle?)")
        if problem is not None:
            self._homing_refused = True
            raise NotHomedError(problem + ": not taken as homed", joint=self.name)

    def get_homing_offset(self) -> float:
        """The offset stored on the joint by the last homing (joint units)."""
        self._require_open()
        if not self.is_homed():
            raise NotHomedError("no homing offset before homing", joint=self.name)
        (offset,) = self._read(P.register(P.HOMEOFFSET))
        return offset

    def wait_while_busy(self, period: float, timeout: float) -> None:
        """Poll the flags every `period` s (faster if the watchdog needs it) until BUSY drops;
        WaitTimeoutError after `timeout` s."""
        if self.watchdog_ms:
            period = min(period, self.watchdog_ms / 4000.0)
        deadline = self.bus.monotonic() + timeout
        while True:
            self.bus.sleep(period)
            self.get_flags()
            if not self.is_busy():
                return
            if self.bus.monotonic() >= deadline:
                raise WaitTimeoutError(f"still busy after {timeout:g} s", joint=self.name)

    # ---- extensions ----

    def identity(self) -> Identity:
        """Protocol and firmware version, joint id and spec hash (firmware of this project only)."""
        protocol, major, minor, patch, joint_id, spec_hash = self._read(P.register(P.IDENTITY))
        self.cached_identity = Identity(protocol, (major, minor, patch), joint_id, spec_hash)
        return self.cached_identity

    def last_reject(self) -> RejectInfo:
        """Why the joint last rejected a frame."""
        return RejectInfo(*self._read(P.register(P.LASTERROR)))

    def read_register(self, name: str) -> tuple[float | int, ...]:
        """Read any readable register by name; returns its decoded payload."""
        reg = P.register(name)
        if not reg.readable:
            raise InvalidArgumentError(f"{reg.name} is not readable", joint=self.name)
        return self._read(reg)

    def write_register(self, name: str, *values: float | int) -> int:
        """Write any writable register by name without the API's guards; returns the reply flags."""
        reg = P.register(name)
        return self._command(reg.addr, *values)

    # ---- transactions ----

    def _require_open(self) -> None:
        if not self._open:
            raise NotInitError("joint is not initialized (call init())", joint=self.name)

    def _fresh_flags(self) -> None:
        if self.bus.monotonic() - self.flags_time > self.flags_max_age:
            self.get_flags()

    def _require_enabled(self) -> None:
        self._require_open()
        self._fresh_flags()
        if not self.is_enabled():
            why = f" ({self.disabled_cause})" if self.disabled_cause else ""
            raise NotEnabledError(f"not enabled{why}", joint=self.name)

    def _require_enabled_and_homed(self) -> None:
        self._require_enabled()
        if not self.is_homed():
            raise NotHomedError("not homed", joint=self.name)

    def _check_stall(self, flags: int) -> None:
        if flags & P.FLAG_STALL:
            raise StalledError("stall detected: the motor stopped", joint=self.name)

    def _take_flags(self, flags: int) -> None:
        now = self.bus.monotonic()
        was = self.flags
        self.flags = flags & CACHED_FLAGS
        if self.watch and was & P.FLAG_NOTHOMED and not flags & P.FLAG_NOTHOMED:
            self._offset_stale = True
        if flags & P.FLAG_NOTENABLED and not was & P.FLAG_NOTENABLED and not self._disabling and not self.watch:
            self.disabled_cause = self._why_disabled(was, flags, now - self.flags_time)
            log.warning("joint %s: %s", self.name, self.disabled_cause)
        self.flags_time = now

    def _why_disabled(self, was: int, flags: int, silence_s: float) -> str:
        """Why an enabled joint is found disabled without this host asking: the joint's own
        flags tell a stall or a reboot; otherwise its deadman, with how long this host had been
        silent (`silence_s`: since the previous answer) against the joint's timeout."""
        if flags & P.FLAG_STALL:
            return "the joint disabled itself: stall detection stopped it"
        if flags & P.FLAG_NOTHOMED and not was & P.FLAG_NOTHOMED:
            return "the joint rebooted (it lost its homing)"
        timeout_ms = self.watchdog_ms or 50
        silent_ms = silence_s * 1000.0
        if silent_ms >= timeout_ms:
            return (f"the joint disabled itself: its deadman, after {silent_ms:.0f} ms without traffic from "
                    f"this host (its timeout is {timeout_ms} ms)")
        return (f"the joint disabled itself (its deadman or another program; this host's traffic was "
                f"{silent_ms:.0f} ms apart, its timeout {timeout_ms} ms)")

    def _take_state(self, flags: int, position_deg: float, velocity_rpm: float) -> None:
        self._take_flags(flags)
        self.position_deg, self.velocity_rpm, self.state_time = position_deg, velocity_rpm, self.flags_time

    def published_state(self) -> dict[str, Any]:
        """What this joint's commander serves to watching programs (commander.py): the latest
        flags, position and velocity read (wire units), the homing offset and identity."""
        identity = self.cached_identity
        return {self.name: {
            "address": self.address, "protocol": self.protocol, "flags": self.flags,
            "position_deg": self.position_deg, "velocity_rpm": self.velocity_rpm,
            "offset": self.transmission.offset, "read": math.isfinite(self.state_time),
            "age_s": self.bus.monotonic() - self.state_time if math.isfinite(self.state_time) else None,
            "identity": None if identity is None else [identity.protocol, *identity.firmware,
                                                       identity.joint_id, identity.spec_hash]}}

    def _over_link(self, exchange: Any) -> Any:
        """`exchange(link)` on the joint's link; refusals become this package's errors. A link
        that lost the joint (protocol v2 after a reboot or a host silence) is swapped for the
        legacy map if the joint answers there, and the exchange is tried once more."""
        link = self.link
        try:
            return exchange(link)
        except LinkRejected as exc:
            raise self._error(exc) from None
        except CommError:
            if not link.lost or not self._lost_v2():
                raise
        try:
            return exchange(self.link)
        except LinkRejected as exc:
            raise self._error(exc) from None

    def _read(self, reg: P.Register) -> tuple:
        self._require_open()
        values, flags = self._over_link(lambda link: link.read(reg))
        if reg.addr == P.ANGLEMOVED:
            self._take_state(flags, values[0], self.velocity_rpm)
        elif reg.addr == P.GETENCODERRPM:
            self._take_state(flags, self.position_deg, values[0])
        elif reg.addr != P.PING or values[0] == P.ACK:
            # A PING answered without 'O' is not the legacy map (a joint between maps answers
            # zeros): its flags byte says nothing, and taking it would report a false reboot.
            self._take_flags(flags)
        return values

    def _build(self, addr: int, *values: float | int) -> Command:
        reg = P.register(addr)
        try:
            return Command(reg.addr, reg.encode(*values))
        except ValueError as exc:
            raise InvalidArgumentError(str(exc), joint=self.name) from None

    def _command(self, addr: int, *values: float | int) -> int:
        """Write a register, returning the reply flags (which already show the command's effect)."""
        self._require_open()
        return self._send(self._build(addr, *values))

    def _send(self, command: Command) -> int:
        if self.watch:
            raise IncorrectStateError(f"{command.name}: this program only watches the joint", joint=self.name)
        flags = self._over_link(lambda link: link.command(command))
        self._take_flags(flags)
        return flags

    def _error(self, exc: LinkRejected) -> BioscaraError:
        """The one map from a joint's refusal (its v2 verdict, or legacy reason translated) to an error."""
        self._take_flags(exc.flags)
        if exc.reason == V.REASON_BUSY:
            return IncorrectStateError(exc.detail, joint=self.name)
        if exc.reason == V.REASON_DISABLED and exc.flags & P.FLAG_STALL:
            return StalledError(exc.detail, joint=self.name)
        if exc.reason == V.REASON_DISABLED:
            why = f" ({self.disabled_cause})" if self.disabled_cause else ""
            return NotEnabledError(exc.detail + why, joint=self.name)
        if exc.reason in (V.REASON_VALUE, V.REASON_COMMAND):
            return InvalidArgumentError(exc.detail, joint=self.name)
        return BioscaraError(exc.detail, joint=self.name)

    def _lost_v2(self) -> bool:
        """The joint answers v2 exchanges with garbage: if it speaks legacy now (it rebooted, or
        fell back after a silence), continue in legacy (True); its flags say what it lost."""
        link = self.link
        self.link = LegacyLink(self.bus, self.address, self.name)
        try:
            self.check_com()
        except BioscaraError:
            self.link = link  # still not legacy: noise on the bus, keep trying v2
            if isinstance(link, V2Link):
                link.bad_in_a_row = 0
            return False
        log.warning("joint %s serves the legacy map again (reboot or host silence)", self.name)
        return True
