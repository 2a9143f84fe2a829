"""The simulated bus: joints running the real firmware on simulated steppers, in virtual time.

Each transaction advances the virtual clock by its wire time at `speed_hz`, and `sleep()` advances
it without waiting, so scenarios run deterministically and much faster than real time. With
`realtime=True` the simulation follows the wall clock instead (interactive tools, the pty server).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from ..firmware.sim.bus import SimJointBus
from ..firmware.sim.clock import VirtualClock
from ..firmware.sim import mechanics
from ..firmware.config import schema as firmware_config
from ..firmware.sim.joint import SimJoint, shipped_data
from ..firmware.sim.stepper import SimStepper
from ..transmission import Transmission
from ..errors import ConfigError
from .base import Bus

log = logging.getLogger("bioscara.sim")


@dataclass(frozen=True)
class SimJointSpec:
    """Where a simulated joint sits: its firmware identity and its mechanics in joint units.

    The link starts at `start`; walls stand at the joint limits `min` and `max` (the end stops
    homing drives into), mapped to motor angle through `reduction` (rad of motor per joint unit).
    The mechanics (inertia, transmission, backlash, gravity, encoder) are the arm's
    (firmware.sim.mechanics) for `payload_kg`, with `noise` "nominal" or "harsh".
    """

    firmware_joint: str  # J1..J4
    address: int
    reduction: float
    min: float
    max: float
    start: float
    deadman_ms: int | None = None  # the joint firmware's own setting; None: its shipped config's
    payload_kg: float = 0.0
    noise: str = "nominal"

    @property
    def transmission(self) -> Transmission:
        """Joint units <-> this simulated motor's angle, 0 where the link starts."""
        return Transmission(self.reduction, self.start)

    def motor_degrees(self, position: float) -> float:
        return self.transmission.motor_degrees(position)


def build_joint(spec: SimJointSpec, clock: VirtualClock, seed: int, port: str,
                write: Callable[[str], None]) -> SimJoint:
    """The simulated joint of `spec`: its firmware, with the shipped configuration of its joint
    (firmware/joint/config/J1..J4.json) at the spec's address, on a stepper walled in at the joint
    limits, logging its console lines through `write`."""
    stepper = SimStepper(clock, seed=seed, **mechanics.stepper_kwargs(spec.firmware_joint, spec.payload_kg,
                                                                       spec.noise))
    low, high = sorted((spec.motor_degrees(spec.min), spec.motor_degrees(spec.max)))
    stepper.set_end_stops(low, high)
    data, path = shipped_data(spec.firmware_joint, spec.address, spec.deadman_ms)
    return SimJoint(firmware_config.parse(data, path), clock, stepper, port=port, write=write, config_data=data)


class SimBus(Bus):
    scheme = "sim"
    reaches_config_files = True

    def __init__(self, joints: Sequence[SimJointSpec], *, seed: int = 1, realtime: bool = False,
                 port: str = "rp2", **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.realtime = realtime
        self.clock = VirtualClock()
        self.sim = SimJointBus(self.clock, bus_hz=self.speed_hz)
        self.specs = {spec.address: spec for spec in joints}
        for i, spec in enumerate(joints):
            self.sim.add(build_joint(spec, self.clock, seed + i, port, log.info))
        self.sim.boot()  # in virtual time: the joints answer from the first transfer on
        self._wall_start = time.monotonic()
        self._virtual_start = self.clock.now_us

    def describe(self) -> str:
        return "sim:" + ("realtime" if self.realtime else "virtual")

    def arm_lock_path(self) -> None:
        return None  # these joints live in this process: no other program reaches them

    def joint(self, address: int) -> SimJoint:
        """The simulated joint at `address` (to inject collisions, reboot it, look at its rotor)."""
        joint = self.sim.joint_at(address)
        if joint is None:
            raise KeyError(f"no simulated joint at 0x{address:02x}")
        return joint

    def joint_config_file(self, addr: int) -> bytes:
        with self._lock:
            return bytes(self.joint(addr).config_file())

    def write_joint_config_file(self, addr: int, data: bytes) -> None:
        with self._lock:
            try:
                self.joint(addr).write_config_file(data)
            except ValueError as exc:
                raise ConfigError(f"the joint refuses the configuration: {exc}") from None

    def reboot_joint(self, addr: int, timeout: float = 10.0) -> None:
        with self._lock:
            self.joint(addr).power_cycle()
        self._await_joint(addr, timeout)

    def joint_position(self, address: int) -> float:
        """True joint position (joint units) from the simulated link (not the rotor: the
        transmission's compliance and backlash lie between them)."""
        return self.specs[address].transmission.position(self.joint(address).stepper.load_angle())

    def _catch_up(self) -> None:
        if self.realtime:
            elapsed_us = int((time.monotonic() - self._wall_start) * 1e6)
            with self._lock:
                self.sim.run_until(self._virtual_start + elapsed_us)

    def _transfer_once(self, addr: int, write: bytes | None, read_len: int) -> bytes:
        self._catch_up()
        return self.sim.transfer(addr, write, read_len)

    def _probe(self, addr: int) -> bool:
        self._catch_up()
        try:
            self.sim.transfer(addr, b"", 0)
        except OSError:
            return False
        return True

    def sleep(self, seconds: float) -> None:
        if self.realtime:
            time.sleep(seconds)
            self._catch_up()
        else:
            with self._lock:  # the simulation is one state: one thread advances it at a time
                self.sim.sleep(seconds)

    def monotonic(self) -> float:
        if self.realtime:
            self._catch_up()
        return self.clock.now_us / 1e6

    def run_for(self, seconds: float) -> None:
        """Advance the simulation (virtual mode), e.g. while a rebooted joint boots again."""
        with self._lock:
            self.sim.sleep(seconds)
