"""The arm hardware interface: lifecycle, per-joint command modes and the homing flow.

Follows the original ros2_control component (original-host-behaviour.md 6) with its bugs fixed:

* lifecycle calls, `read` and `write` are serialized by one lock (9.2.12);
* failures in activate/deactivate and in homing completion are raised, not swallowed (9.2.9);
* releasing velocity mode commands 0 RPM, so a joint never keeps turning (9.2.8);
* starting position mode takes the measured position as the command (no jump back);
* an error in `read`/`write` deactivates the arm (disables the joints) before it is raised, as the
  original's DEACTIVATE return made the controller manager do.

State and command values are plain floats per joint: `position` (rad or m; NaN while not homed),
`velocity` (units/s) and `home` (state: 1.0 homed, 0.0 not; command: +1/-1 start homing toward
that end stop, 0 abort or idle).
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from enum import Enum

from .bus.base import Bus
from .config import ArmConfig, JointConfig
from .errors import BioscaraError, CommError, IncorrectStateError, InvalidArgumentError, NotHomedError
from .firmware.spec import protocol as P
from .joint import BlockingCommand, Joint
from .link import Command

log = logging.getLogger("bioscara.arm")


class Lifecycle(Enum):
    UNCONFIGURED = "unconfigured"
    INACTIVE = "inactive"
    ACTIVE = "active"
    FINALIZED = "finalized"


class Mode(Enum):
    POSITION = "position"
    VELOCITY = "velocity"
    HOME = "home"


@dataclass
class JointValues:
    position: float = 0.0
    velocity: float = 0.0
    home: float = 0.0


@dataclass
class ArmJoint:
    config: JointConfig
    joint: Joint
    state: JointValues = field(default_factory=JointValues)
    command: JointValues = field(default_factory=JointValues)
    modes: set[Mode] = field(default_factory=set)


class LifecycleError(BioscaraError):
    """A lifecycle transition was asked for from the wrong state."""


def activate_joint(joint: Joint, config: JointConfig) -> None:
    """Enable with the configured currents, then stall detection (after SETUP, which turns it
    off) if the threshold is set, then the motion limits: the original's activate_joint."""
    joint.enable(config.drive_current, config.hold_current)
    if config.watchdog_ms:
        joint.set_watchdog(config.watchdog_ms)  # fed by every transaction of the control cycle
    if config.stall_threshold > 0:
        joint.enable_stallguard(config.stall_threshold)
    joint.set_max_acceleration(config.max_acceleration)
    joint.set_max_velocity(config.max_velocity)


def make_joint(config: JointConfig, bus: Bus, watch: bool = False) -> Joint:
    """The joint of `config` on `bus`; `watch`: one that only reads (see commander.py)."""
    return Joint(config.name, config.address, bus, reduction=config.reduction, min=config.min,
                 max=config.max, max_velocity=config.max_velocity,
                 homing_range_check=config.homing.range_tolerance if config.homing.check_range else None,
                 watch=watch)


PROTOCOLS = ("auto", "legacy", "v2")


class Arm:
    """The four joints of the arm behind one bus, driven in read/write cycles.

    `protocol`: "auto" moves every joint whose IDENTITY says it can to protocol v2 when the arm
    is configured (one transaction per joint per cycle), "legacy" keeps the original register
    map, "v2" requires it.

    `watch=True`: an arm this program only reads, beside any program that commands it (it never
    activates, and reads without disturbing the commander: commander.py). Otherwise configuring
    makes this program the bus's commander (ArmBusyError while another one is).

    As a context manager (`with open_arm() as arm:`) it is configured on entry and, on exit
    (an exception or Ctrl-C included), stops every joint, disables the active ones and lets go.
    """

    def __init__(self, config: ArmConfig, bus: Bus, protocol: str = "auto", *, watch: bool = False) -> None:
        if protocol not in PROTOCOLS:
            raise InvalidArgumentError(f"protocol must be one of {', '.join(PROTOCOLS)}, not {protocol!r}")
        self.config = config
        self.bus = bus
        self.protocol = protocol
        self.lifecycle = Lifecycle.UNCONFIGURED
        self.watch = watch
        self.joints = {name: ArmJoint(jc, make_joint(jc, bus, watch)) for name, jc in config.joints.items()}
        self.fault: BioscaraError | None = None
        self.owns_bus = False  # closed with the arm (set by `open_arm` when it opened the bus)
        self._lock = threading.RLock()

    def __enter__(self) -> Arm:
        if self.lifecycle is Lifecycle.UNCONFIGURED:
            self.configure()
        return self

    def __exit__(self, *exc: object) -> None:
        """Stop every joint, disable them if active, let go of them (and of the bus if `open_arm`
        opened it). Every step is tried; a failure is logged, the exception in flight wins."""
        try:
            if self.lifecycle in (Lifecycle.INACTIVE, Lifecycle.ACTIVE) and not self.watch:
                self._try(self.stop)
            if self.lifecycle is Lifecycle.ACTIVE:
                self._try(self.deactivate)
        finally:
            self.release()
            if self.owns_bus:
                self.bus.close()

    def __getitem__(self, name: str) -> ArmJoint:
        try:
            return self.joints[name]
        except KeyError:
            raise InvalidArgumentError(f"no joint {name!r}; the arm has {', '.join(self.joints)}") from None

    # ---- lifecycle ----

    def _expect(self, action: str, *states: Lifecycle) -> None:
        if self.lifecycle not in states:
            allowed = " or ".join(s.value for s in states)
            raise LifecycleError(f"cannot {action} while {self.lifecycle.value} (needs {allowed})")

    def configure(self) -> None:
        """Connect to every joint (restoring homing offsets); states are NaN until the first read,
        commands zero."""
        with self._lock:
            self._expect("configure", Lifecycle.UNCONFIGURED)
            opened = []
            try:
                for aj in self.joints.values():
                    aj.joint.init()
                    opened.append(aj)
                    if not self.watch:
                        self._choose_protocol(aj.joint)
            except BioscaraError:
                for aj in opened:
                    aj.joint.close()
                raise
            for aj in self.joints.values():
                # not read yet: NaN, never a position the joint does not have (the panel showed 0 rad)
                aj.state, aj.command, aj.modes = JointValues(math.nan, math.nan), JointValues(), set()
            self.fault = None
            self.lifecycle = Lifecycle.INACTIVE

    def _choose_protocol(self, joint: Joint) -> None:
        if self.protocol == "legacy":
            return
        supported = joint.identity().protocol >= P.PROTOCOL_VERSION
        if supported:
            try:
                joint.use_v2()
            except CommError as exc:
                if self.protocol == "v2":
                    raise
                # A port without a memory-mode target (CircuitPython) keeps serving legacy.
                log.warning("joint %s stays on the legacy map: %s", joint.name, exc.detail)
                joint.check_com()
        elif self.protocol == "v2":
            raise IncorrectStateError("the joint's firmware does not serve protocol v2", joint=joint.name)

    def cleanup(self) -> None:
        with self._lock:
            self._expect("clean up", Lifecycle.INACTIVE)
            for aj in self.joints.values():
                aj.joint.close()
            self.lifecycle = Lifecycle.UNCONFIGURED

    def release(self) -> None:
        """Let go of every joint whatever the lifecycle, without motor I/O: each returns to the
        legacy map, a joint left holding keeps holding (see `Joint.close`). Idempotent."""
        with self._lock:
            for aj in self.joints.values():
                aj.joint.close()
            self.lifecycle = Lifecycle.UNCONFIGURED

    def activate(self) -> None:
        """Enable every joint with its limits; commands start at the measured position, velocity 0."""
        with self._lock:
            self._expect("activate", Lifecycle.INACTIVE)
            if self.watch:
                raise LifecycleError("this program only watches the arm: it cannot activate it")
            touched: list[ArmJoint] = []
            try:
                for aj in self.joints.values():
                    aj.modes = set()
                    touched.append(aj)  # before enabling: a half-activated joint is rolled back too
                    self._activate_joint(aj)
            except BioscaraError:
                for aj in touched:
                    self._try(aj.joint.disable)
                raise
            self.lifecycle = Lifecycle.ACTIVE
            self.read()
            for aj in self.joints.values():
                aj.command = JointValues(aj.state.position, 0.0, 0.0)

    def deactivate(self) -> None:
        """Disable every joint (freewheeling). Tries all joints; raises the first failure."""
        with self._lock:
            self._expect("deactivate", Lifecycle.ACTIVE)
            self.lifecycle = Lifecycle.INACTIVE
            self._disable_all()

    def shutdown(self) -> None:
        with self._lock:
            if self.lifecycle is Lifecycle.ACTIVE:
                self.deactivate()
            if self.lifecycle is Lifecycle.INACTIVE:
                self.cleanup()
            self.lifecycle = Lifecycle.FINALIZED
            log.info("shut down")

    def recover(self) -> None:
        """The lifecycle's error transition: disable and disconnect, ending unconfigured if that worked."""
        with self._lock:
            try:
                if self.lifecycle is Lifecycle.ACTIVE:
                    self.lifecycle = Lifecycle.INACTIVE
                    self._disable_all()
                if self.lifecycle is Lifecycle.INACTIVE:
                    self.cleanup()
            except BioscaraError:
                self.lifecycle = Lifecycle.FINALIZED
                raise

    def _disable_all(self) -> None:
        first = None
        for aj in self.joints.values():
            aj.modes = set()
            try:
                self._deactivate_joint(aj)
            except BioscaraError as exc:
                log.error("failed to disable joint %s: %s", aj.config.name, exc)
                first = first or exc
        if first is not None:
            raise first

    @staticmethod
    def _try(action: Callable[[], object]) -> None:
        try:
            action()
        except BioscaraError as exc:
            log.error("%s", exc)

    # ---- per-joint helpers (the original's activate_joint / deactivate_joint / homing) ----

    def _activate_joint(self, aj: ArmJoint) -> None:
        activate_joint(aj.joint, aj.config)

    def _deactivate_joint(self, aj: ArmJoint) -> None:
        aj.joint.disable()

    def _release_for_homing(self, aj: ArmJoint) -> None:
        """Home mode starts: disable the joint until its homing starts, or with `homing.hold` only
        stop it, energized at the hold current, so a back-drivable load cannot fall meanwhile."""
        if aj.config.homing.hold:
            aj.joint.stop()
        else:
            aj.joint.disable()

    def _start_homing(self, aj: ArmJoint, direction: float) -> None:
        homing = aj.config.homing
        self._activate_joint(aj)
        aj.joint.set_max_acceleration(homing.acceleration)
        aj.joint.start_homing(math.copysign(homing.speed, direction), homing.threshold, homing.current)
        log.info("started homing joint %s", aj.config.name)

    def _stop_homing(self, aj: ArmJoint) -> bool:
        """Restore limits, stop, verify; True if the joint ended homed. Then freewheel."""
        jc, joint = aj.config, aj.joint
        joint.set_max_acceleration(jc.max_acceleration)
        joint.set_max_velocity(jc.max_velocity)
        joint.stop()
        try:
            joint.post_homing()
            homed = True
        except NotHomedError:
            homed = False
        self._deactivate_joint(aj)
        log.info("finished homing joint %s: %s", jc.name, "homed" if homed else "not homed")
        return homed

    # ---- cycle ----

    def read(self) -> None:
        """Refresh every joint's state (2 transactions per joint); finish homings that ended."""
        with self._lock:
            self._expect("read", Lifecycle.INACTIVE, Lifecycle.ACTIVE)
            first: BioscaraError | None = None
            for aj in self.joints.values():
                try:
                    self._read_joint(aj)
                except BioscaraError as exc:  # the other joints' states stay fresh
                    first = first or exc
            if first is not None:
                self._fault(first)
                raise first

    def cycle(self) -> None:
        """One read/write cycle (the write only while active): every joint's setpoint is built
        first (its mode's command, through the guards), then each joint gets one exchange over
        its link carrying it (protocol v2: one transaction; legacy: the command, then two reads)."""
        with self._lock:
            self._expect("read", Lifecycle.INACTIVE, Lifecycle.ACTIVE)
            first: BioscaraError | None = None
            setpoints: dict[str, Command | None] = {}
            for name, aj in self.joints.items():
                try:
                    setpoints[name] = self._setpoint(aj)
                except BioscaraError as exc:
                    aj.state.home = 1.0 if aj.joint.is_homed() else 0.0  # the guards' fresh flags
                    first = first or exc
            for name, setpoint in setpoints.items():
                try:
                    self._exchange(self.joints[name], setpoint)
                except BioscaraError as exc:  # the other joints' states stay fresh
                    first = first or exc
            if first is not None:
                self._fault(first)
                raise first

    def _setpoint(self, aj: ArmJoint) -> Command | None:
        """The command this cycle carries for `aj`: its position or velocity setpoint; homing
        starts and stops are commands of their own, sent (and their verdicts awaited) here."""
        if self.lifecycle is not Lifecycle.ACTIVE:
            return None
        setpoint = None
        for mode in aj.modes:
            if mode is Mode.POSITION:
                setpoint = aj.joint.position_command(aj.command.position)
            elif mode is Mode.VELOCITY:
                setpoint = aj.joint.velocity_command(aj.command.velocity)
            else:
                self._write_mode(aj, mode)
        return setpoint

    def _exchange(self, aj: ArmJoint, setpoint: Command | None) -> None:
        joint = aj.joint
        sample = joint.cycle(setpoint)
        if sample is not None:  # None: no fresh state this cycle, the last one stands
            aj.state.position, aj.state.velocity = sample
        aj.state.home = 1.0 if joint.is_homed() else 0.0
        self._finish_homing(aj)

    def _read_joint(self, aj: ArmJoint) -> None:
        joint = aj.joint
        try:
            aj.state.position = joint.get_position()
        except NotHomedError:
            aj.state.position = math.nan
        aj.state.velocity = joint.get_velocity()
        aj.state.home = 1.0 if joint.is_homed() else 0.0
        self._finish_homing(aj)

    def _finish_homing(self, aj: ArmJoint) -> None:
        joint = aj.joint
        if (joint.current_blocking is BlockingCommand.HOME and not joint.is_busy()
                and self.lifecycle is Lifecycle.ACTIVE):
            if self._stop_homing(aj):
                aj.state.position = joint.get_position()  # in the frame of the new offset
            else:
                log.warning("homing of %s ended without reaching the end stop", aj.config.name)
            aj.command.home = 0.0
            aj.state.home = 1.0 if joint.is_homed() else 0.0

    def write(self) -> None:
        """Send the commands of every joint's active mode."""
        with self._lock:
            self._expect("write", Lifecycle.ACTIVE)
            try:
                for aj in self.joints.values():
                    for mode in aj.modes:
                        self._write_mode(aj, mode)
            except BioscaraError as exc:
                self._fault(exc)
                raise

    def _write_mode(self, aj: ArmJoint, mode: Mode) -> None:
        joint = aj.joint
        if mode is Mode.POSITION:
            joint.set_position(aj.command.position)
        elif mode is Mode.VELOCITY:
            joint.set_velocity(aj.command.velocity)
        elif aj.command.home == 0.0:
            if joint.current_blocking is BlockingCommand.HOME:
                self._stop_homing(aj)
        elif joint.current_blocking is BlockingCommand.NONE:
            self._start_homing(aj, aj.command.home)
        elif joint.current_blocking is not BlockingCommand.HOME:
            raise IncorrectStateError(f"busy with {joint.current_blocking.name}", joint=aj.config.name)

    def _fault(self, exc: BioscaraError) -> None:
        """An error in the cycle: remember why; if active, disable the joints (best effort)."""
        self.fault = exc
        if self.lifecycle is not Lifecycle.ACTIVE:
            log.debug("read failed while inactive: %s", exc)
            return
        log.error("arm fault, disabling joints: %s", exc)
        self.lifecycle = Lifecycle.INACTIVE
        try:
            self._disable_all()
        except BioscaraError as disable_error:
            log.error("could not disable every joint after the fault: %s", disable_error)

    def stop(self) -> None:
        """STOP every joint at once (aborting homing), then take every joint out of position and
        velocity mode so the next cycle sends no motion. Tries all joints; raises the first failure."""
        with self._lock:
            first: BioscaraError | None = None
            for aj in self.joints.values():
                try:
                    aj.joint.stop()
                except BioscaraError as exc:
                    first = first or exc
            for aj in self.joints.values():
                aj.modes -= {Mode.POSITION, Mode.VELOCITY}
                aj.command.velocity = 0.0
                aj.command.home = 0.0
            if first is not None:
                raise first

    # ---- command modes ----

    def switch_modes(self, start: Iterable[str] = (), stop: Iterable[str] = ()) -> None:
        """Start/stop command interfaces named "<joint>/<mode>" (one active mode per joint).

        Validated as a whole first (nothing changes if any part is refused), then performed:
        starting `home` disables the joint and clears its trigger, stopping `home` re-enables it,
        stopping `velocity` commands 0, starting `position` holds the measured position.
        """
        with self._lock:
            starting = [self._interface(name) for name in start]
            stopping = [self._interface(name) for name in stop]
            new_modes = {name: set(aj.modes) for name, aj in self.joints.items()}
            for aj, mode in stopping:
                if mode is Mode.HOME and aj.joint.current_blocking is BlockingCommand.HOME:
                    raise IncorrectStateError("homing is still ongoing", joint=aj.config.name)
                if mode not in new_modes[aj.config.name]:
                    log.warning("%s/%s was not started", aj.config.name, mode.value)
                new_modes[aj.config.name].discard(mode)
            for aj, mode in starting:
                if mode in new_modes[aj.config.name]:
                    raise IncorrectStateError(f"{mode.value} is already active", joint=aj.config.name)
                new_modes[aj.config.name].add(mode)
            for name, modes in new_modes.items():
                if len(modes) > 1:
                    listed = ", ".join(sorted(m.value for m in modes))
                    raise IncorrectStateError(f"only one command mode may be active, not {listed}", joint=name)
                if modes & {Mode.POSITION, Mode.VELOCITY} and not self.joints[name].joint.is_homed():
                    mode = next(iter(modes))
                    raise NotHomedError(f"cannot start {mode.value} mode before homing", joint=name)
            self._perform_switch(starting, stopping, new_modes)

    def _perform_switch(self, starting: list[tuple[ArmJoint, Mode]], stopping: list[tuple[ArmJoint, Mode]],
                        new_modes: dict[str, set[Mode]]) -> None:
        """Commit the modes, then every joint's step; the first failure faults the arm and is raised."""
        for name, modes in new_modes.items():
            self.joints[name].modes = modes
        active = self.lifecycle is Lifecycle.ACTIVE
        first: BioscaraError | None = None
        steps: list[Callable[[], object]] = []
        for aj, mode in stopping:
            if mode is Mode.VELOCITY:
                aj.command.velocity = 0.0
                if active:
                    steps.append(aj.joint.stop)  # 0 RPM without the guards a disabled joint would trip
            elif mode is Mode.HOME and active:
                steps.append(lambda aj=aj: self._activate_joint(aj))
        for aj, mode in starting:
            if mode is Mode.HOME:
                aj.command.home = 0.0
                if active:
                    steps.append(lambda aj=aj: self._release_for_homing(aj))
            elif mode is Mode.POSITION:
                aj.command.position = aj.state.position
                if math.isfinite(aj.state.position):  # hold it where it stands, onto the limit
                    aj.command.position = min(max(aj.state.position, aj.joint.min), aj.joint.max)
            else:
                aj.command.velocity = 0.0
        for step in steps:
            try:
                step()
            except BioscaraError as exc:
                first = first or exc
        if first is not None:
            self._fault(first)  # a joint that cannot be reached or enabled: stop the arm
            raise first

    def _interface(self, name: str) -> tuple[ArmJoint, Mode]:
        joint, _, mode = name.partition("/")
        try:
            return self[joint], Mode(mode)
        except ValueError:
            raise InvalidArgumentError(f"unknown command interface {name!r} "
                                       "(use <joint>/position, /velocity or /home)") from None

    def check_command(self, joint: str, mode: str, value: float) -> None:
        """InvalidArgumentError if the joint would refuse `value` at the next write (which would
        fault the arm): non-finite, outside the limits, or a home trigger other than +1/-1/0."""
        j = self[joint].joint
        if not math.isfinite(value):
            raise InvalidArgumentError(f"{mode} command must be finite, got {value}", joint=joint)
        if mode == Mode.POSITION.value:
            j.within_limits(value)
        if mode == Mode.VELOCITY.value and abs(value) > j.max_velocity:
            raise InvalidArgumentError(f"|velocity| {abs(value):g} exceeds max_velocity {j.max_velocity:g}",
                                       joint=joint)
        if mode == Mode.HOME.value and value not in (-1.0, 0.0, 1.0):
            raise InvalidArgumentError(f"home takes +1, -1 (toward that end stop) or 0 (abort), got {value:g}",
                                       joint=joint)

    def set_command(self, joint: str, mode: str, value: float) -> None:
        """Set a command value (it is sent by the next `write` if that mode is active)."""
        self.check_command(joint, mode, value)
        with self._lock:
            setattr(self[joint].command, Mode(mode).value, float(value))
