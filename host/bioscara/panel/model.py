"""What the panel shows and does, without a screen: views of the arm and the actions of its buttons.

The panel's display never waits on the bus. `PanelModel` keeps the communicator cycling (its own
thread) and runs every action in one worker thread, in order; the display reads `view()`, which
only copies values the cycle already has. Tests build it with `threaded=False`: actions then run
at once in the caller and the cycle advances only through `step()`, in the bus's virtual time.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from ..arm import Arm, Lifecycle, Mode
from ..communicator import Communicator
from ..config import ArmConfig
from ..errors import (BioscaraError, CommError, IncorrectStateError, InvalidArgumentError, NotEnabledError,
                      StalledError)
from ..firmware.spec import protocol as P
from ..gripper import BaseGripper

log = logging.getLogger("bioscara.panel")

SIGNALS = ("position", "velocity", "following_error")


class GripperState:
    NONE = "none"
    UNCONFIGURED = "unconfigured"
    INACTIVE = "inactive"
    ACTIVE = "active"


@dataclass(frozen=True)
class JointView:
    name: str
    unit: str  # "rad" or "m"
    position: float  # joint units; NaN while not homed
    velocity: float  # joint units per second
    command: float  # the position command, joint units (NaN without position mode)
    flags: int
    mode: str  # "position", "velocity", "home" or "off"
    homed: bool
    known: bool  # the joint has been read since the arm was configured (else flags and homed mean nothing yet)
    fault: str | None  # the cause of this joint's fault: stall, deadman, limit, lost link, ...
    link: str  # "ok" or why the last transfer failed
    transactions: int
    lost: int  # transactions lost after every retry

    @property
    def flag_names(self) -> str:
        return P.describe_flags(self.flags)


@dataclass(frozen=True)
class PanelView:
    bus: str
    lifecycle: str
    gripper: str
    gripper_width: float  # m, NaN without a gripper
    position_control: bool  # every joint in position mode
    homing_control: bool  # every joint in home mode
    can_position: bool  # the position controller may be activated now
    can_homing: bool
    rate_hz: float
    jitter_us: float
    overruns: int
    cycles: int
    fault: str | None
    busy: str | None  # the action running in the worker, if any
    joints: tuple[JointView, ...]


def fault_cause(exc: BaseException) -> str:
    """A fault's cause in the operator's words."""
    if isinstance(exc, StalledError):
        return "stall"
    if isinstance(exc, NotEnabledError):
        return "deadman (joint not enabled)"
    if isinstance(exc, CommError):
        return "lost link"
    if isinstance(exc, InvalidArgumentError) and "outside" in str(exc):
        return "limit"
    return getattr(exc, "detail", str(exc))


class PanelModel:
    """The arm, its communicator and gripper behind the panel's buttons.

    `history` seconds of the live signals are kept for the plot (one sample per cycle, newest last).
    """

    def __init__(self, config: ArmConfig, arm: Arm, gripper: BaseGripper | None = None, *,
                 frequency: float = 100.0, threaded: bool = True, history: float = 10.0) -> None:
        self.config = config
        self.arm = arm
        self.gripper = gripper
        self.gripper_state = GripperState.NONE if gripper is None else GripperState.UNCONFIGURED
        self.comm = Communicator(arm, frequency, realtime_priority=None)
        self.threaded = threaded
        self.messages: deque[str] = deque(maxlen=50)  # the newest; `said` counts every one
        self.said = 0
        self.busy: str | None = None
        self.samples: deque[tuple[float, dict[str, float]]] = deque(maxlen=max(2, int(history * frequency)))
        self._links: dict[str, tuple[int, int, bool]] = {}  # per joint: transactions, lost, link down
        self._subscription = self.comm.subscribe(maxlen=self.samples.maxlen or 2)
        self._actions: queue.Queue[tuple[str, Callable[[], object]] | None] = queue.Queue()
        self._worker: threading.Thread | None = None
        if threaded:
            self._worker = threading.Thread(target=self._work, name="bioscara-panel-actions", daemon=True)
            self._worker.start()
            self.comm.start()

    # ---- running actions ----

    def submit(self, name: str, action: Callable[[], object]) -> None:
        """Run `action` after the ones before it; its failure becomes a message, never an exception."""
        if self.threaded:
            self._actions.put((name, action))
        else:
            self._run(name, action)

    def _work(self) -> None:
        while (item := self._actions.get()) is not None:
            self._run(*item)

    def _run(self, name: str, action: Callable[[], object]) -> None:
        self.busy = name
        try:
            action()
            self.say(f"{name}: done")
        except BioscaraError as exc:
            self.say(f"{name}: {exc.message}")
        except Exception as exc:  # a bug: report it on the panel instead of killing the worker
            log.exception("%s failed", name)
            self.say(f"{name}: unexpected error: {exc!r}")
        finally:
            self.busy = None

    def say(self, message: str) -> None:
        self.messages.append(message)
        self.said += 1

    def step(self, seconds: float) -> None:
        """Without threads: cycle the arm for `seconds` of bus time (faults do not end it)."""
        self.comm.run_for(seconds, stop_on_fault=False)

    def close(self) -> None:
        """Stop the cycle and the worker, then shut the arm down (joints disabled) and the gripper."""
        if self._worker is not None:
            self._actions.put(None)
            self._worker.join(5.0)
        self.comm.stop()
        try:
            if self.arm.lifecycle is not Lifecycle.FINALIZED:
                self.arm.shutdown()
        except BioscaraError as exc:
            log.error("shutting the arm down: %s", exc)
        if self.gripper is not None and self.gripper_state is not GripperState.UNCONFIGURED:
            self.gripper.close()

    # ---- the view ----

    def view(self) -> PanelView:
        """What the display shows now (values of the last cycle; never touches the bus)."""
        self._take_samples()
        arm = self.arm
        stats = self.comm.stats
        modes = [aj.modes for aj in arm.joints.values()]
        position = all(Mode.POSITION in m for m in modes)
        homing = all(Mode.HOME in m for m in modes)
        active = arm.lifecycle is Lifecycle.ACTIVE
        any_home = any(Mode.HOME in m for m in modes)
        any_motion = any(m & {Mode.POSITION, Mode.VELOCITY} for m in modes)
        width = math.nan
        if self.gripper is not None and self.gripper_state is GripperState.ACTIVE:
            width = self.gripper.get_position()
        return PanelView(
            bus=self.arm.bus.describe(), lifecycle=arm.lifecycle.value, gripper=self.gripper_state,
            gripper_width=width, position_control=position, homing_control=homing,
            can_position=active and not any_home, can_homing=active and not any_motion,
            rate_hz=stats.rate, jitter_us=stats.jitter * 1e6, overruns=stats.overruns, cycles=stats.cycles,
            fault=fault_cause(arm.fault) if arm.fault is not None else None, busy=self.busy,
            joints=tuple(self._joint_view(name) for name in arm.joints))

    def _joint_view(self, name: str) -> JointView:
        aj = self.arm[name]
        link = self.arm.bus.stats.link(aj.config.address)
        seen = self._links.get(name)
        failed = seen is not None and (link.transactions == seen[0] and link.comm_errors > seen[1] or
                                       link.transactions == seen[0] and seen[2])
        self._links[name] = (link.transactions, link.comm_errors, failed)
        fault = None
        if aj.joint.flags & P.FLAG_STALL:
            fault = "stall"
        elif failed:
            fault = "lost link"
        elif (self.arm.fault is not None and getattr(self.arm.fault, "joint", None) == name
              and not isinstance(self.arm.fault, CommError)):  # a lost link shows while it is lost
            fault = fault_cause(self.arm.fault)
        mode = next(iter(aj.modes)).value if aj.modes else "off"
        known = self.arm.lifecycle in (Lifecycle.INACTIVE, Lifecycle.ACTIVE)  # read every cycle
        return JointView(
            name=name, unit="m" if aj.config.type == "prismatic" else "rad",
            position=aj.state.position if known else math.nan, velocity=aj.state.velocity if known else math.nan,
            command=aj.command.position if Mode.POSITION in aj.modes else math.nan,
            flags=aj.joint.flags, mode=mode, homed=known and aj.joint.is_homed(), known=known, fault=fault,
            link=f"lost: {link.last_error}" if failed else "ok",
            transactions=link.transactions, lost=link.comm_errors)

    def _take_samples(self) -> None:
        # Before the arm is configured the cycle reads nothing: its values are placeholders, not 0 rad.
        known = self.arm.lifecycle in (Lifecycle.INACTIVE, Lifecycle.ACTIVE)
        for snapshot in self._subscription.drain():
            values: dict[str, float] = {}
            for name, sample in snapshot.joints.items():
                values[f"{name}/position"] = sample.position if known else math.nan
                values[f"{name}/velocity"] = sample.velocity if known else math.nan
                command = self.arm[name].command.position
                values[f"{name}/following_error"] = (command - sample.position
                                                     if Mode.POSITION in self.arm[name].modes else math.nan)
            self.samples.append((snapshot.time, values))

    # ---- the buttons ----

    def lifecycle_action(self) -> str | None:
        """The one lifecycle transition the arm's state allows (the original panel's button)."""
        return {Lifecycle.UNCONFIGURED: "configure", Lifecycle.INACTIVE: "activate",
                Lifecycle.ACTIVE: "deactivate"}.get(self.arm.lifecycle)

    def lifecycle(self) -> None:
        action = self.lifecycle_action()
        if action is not None:
            self.submit(action, getattr(self.arm, action))

    def gripper_action(self) -> str | None:
        return {GripperState.UNCONFIGURED: "configure", GripperState.INACTIVE: "activate",
                GripperState.ACTIVE: "deactivate"}.get(self.gripper_state)

    def gripper_lifecycle(self) -> None:
        gripper = self.gripper
        action = self.gripper_action()
        if gripper is None or action is None:
            return

        def transition() -> None:
            if action == "configure":
                gripper.init()
                self.gripper_state = GripperState.INACTIVE
            elif action == "activate":
                gripper.enable()
                self.gripper_state = GripperState.ACTIVE
            else:
                gripper.disable()
                self.gripper_state = GripperState.INACTIVE
        self.submit(f"gripper {action}", transition)

    def set_gripper(self, width: float) -> None:
        """Command the gripper width in m (clamped to its range by the gripper)."""
        if self.gripper is None:
            self.say("the configuration has no gripper")
            return
        gripper = self.gripper
        self.submit(f"gripper width {width * 1000:.1f} mm", lambda: gripper.set_position(width))

    def toggle_controller(self, mode: Mode) -> None:
        """Activate or deactivate the position or homing controller on every joint, with the
        original's rule: the two exclude each other, and both need the arm active."""
        interfaces = [f"{name}/{mode.value}" for name in self.arm.joints]
        if all(mode in aj.modes for aj in self.arm.joints.values()):
            self.submit(f"{mode.value} control off", lambda: self.arm.switch_modes(stop=interfaces))
            return

        def activate() -> None:
            if self.arm.lifecycle is not Lifecycle.ACTIVE:
                raise IncorrectStateError("activate the arm first")
            missing = [f"{name}/{mode.value}" for name, aj in self.arm.joints.items() if mode not in aj.modes]
            self.arm.switch_modes(start=missing)
        self.submit(f"{mode.value} control on", activate)

    def home(self, name: str, direction: int) -> None:
        """Start homing `name` toward an end stop (+1/-1), or abort it (0), through its home mode."""
        def trigger() -> None:
            if Mode.HOME not in self.arm[name].modes:
                raise IncorrectStateError("activate the homing controller first", joint=name)
            self.arm.set_command(name, "home", float(direction))
        what = {1: "toward +", -1: "toward -", 0: "stop"}[direction]
        self.submit(f"home {name} {what}", trigger)

    def home_all(self) -> None:
        """Home every joint toward its configured end stop."""
        def trigger() -> None:
            for name, aj in self.arm.joints.items():
                if Mode.HOME not in aj.modes:
                    raise IncorrectStateError("activate the homing controller first", joint=name)
            for name, aj in self.arm.joints.items():
                self.arm.set_command(name, "home", float(aj.config.homing.direction))
        self.submit("home all", trigger)

    def go_to(self, name: str, target: float) -> None:
        """Position move of one joint to `target` (joint units), within its limits."""
        def move() -> None:
            self.arm.check_command(name, "position", target)
            aj = self.arm[name]
            if Mode.POSITION not in aj.modes:
                self.arm.switch_modes(start=[f"{name}/position"], stop=[f"{name}/{m.value}" for m in aj.modes])
            self.arm.set_command(name, "position", target)
        self.submit(f"{name} to {target:g}", move)

    def jog(self, name: str, step: float) -> None:
        """Move one joint by `step` (joint units) from its command, stopping at its limits."""
        aj = self.arm[name]
        base = aj.command.position if Mode.POSITION in aj.modes else aj.state.position
        if not math.isfinite(base):
            self.say(f"jog {name}: not homed")
            return
        self.go_to(name, min(max(base + step, aj.joint.min), aj.joint.max))

    def stop(self) -> None:
        """STOP every joint now, ahead of any queued action: motion and homing end, modes drop out
        of position and velocity so no new motion is sent."""
        def stop_all() -> None:
            self.arm.stop()
        if self.threaded:
            threading.Thread(target=self._run, args=("STOP", stop_all), daemon=True).start()
        else:
            self._run("STOP", stop_all)
