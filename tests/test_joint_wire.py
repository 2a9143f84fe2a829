"""The smbus2 transport puts exactly the original driver's transactions on the wire.

Only the `SMBus` object is faked: it records each `i2c_rdwr` call's messages and forwards them to
simulated joints running the real firmware, so every reply is a real one.
"""

from __future__ import annotations

import ctypes
import math
import struct

import pytest
from smbus2 import i2c_msg

from bioscara.bus.sim import SimBus, SimJointSpec
from bioscara.bus.smbus import SMBusBus
from bioscara.errors import CommError
from bioscara.joint import BrakeMode, Joint

J2 = SimJointSpec("J2", 0x12, -1570.79632679, -0.0016, 0.338, 0.333)
I2C_M_RD = 0x0001


class FakeSMBus:
    """Stands in for smbus2.SMBus: records messages, answers through the simulated bus."""

    def __init__(self, sim: SimBus) -> None:
        self.sim = sim
        self.calls: list[list[tuple[str, int, bytes | int]]] = []

    def i2c_rdwr(self, *messages: i2c_msg) -> None:
        call = []
        write: bytes | None = None
        read: i2c_msg | None = None
        for m in messages:
            if m.flags & I2C_M_RD:
                read = m
                call.append(("read", m.addr, m.len))
            else:
                write = bytes(m)
                call.append(("write", m.addr, write))
        self.calls.append(call)
        reply = self.sim.sim.transfer(messages[0].addr, write, read.len if read is not None else 0)
        if read is not None:
            ctypes.memmove(read.buf, reply, read.len)

    def close(self) -> None:
        pass


class SimClockSMBus(SMBusBus):
    """SMBusBus whose waits run the simulation's clock, so homing can finish."""

    sim: SimBus

    def sleep(self, seconds: float) -> None:
        self.sim.sleep(seconds)

    def monotonic(self) -> float:
        return self.sim.monotonic()


@pytest.fixture
def wire() -> tuple[Joint, FakeSMBus]:
    sim = SimBus([J2])
    fake = FakeSMBus(sim)
    SimClockSMBus.sim = sim
    bus = SimClockSMBus(1, smbus_factory=lambda _: fake)
    joint = Joint("j2", 0x12, bus, reduction=J2.reduction, min=J2.min, max=J2.max, max_velocity=0.03)
    return joint, fake


def command(reg: int, payload: bytes) -> list[tuple[str, int, bytes | int]]:
    """The original's command: write [reg, payload], repeated START, read the 1-byte flags."""
    return [("write", 0x12, bytes([reg]) + payload), ("read", 0x12, 1)]


def read(reg: int, size: int) -> list[tuple[str, int, bytes | int]]:
    """The original's register read: write [reg], repeated START, read payload + flags."""
    return [("write", 0x12, bytes([reg])), ("read", 0x12, size + 1)]


def f32(value: float) -> bytes:
    return struct.pack("<f", value)


def test_every_joint_method_sends_the_original_transactions(wire: tuple[Joint, FakeSMBus]) -> None:
    joint, fake = wire
    r = J2.reduction
    steps = [
        (joint.init, [read(0x0F, 1)]),
        (lambda: joint.enable(40, 40), [command(0x10, bytes([40, 40, 0, 0]))]),
        (lambda: joint.enable_stallguard(12), [command(0x1E, bytes([12]))]),
        # |reduction|: the original sent J2's limits negative (-18000, -2700).
        (lambda: joint.set_max_acceleration(0.2), [command(0x1B, f32(18000.0))]),
        (lambda: joint.set_max_velocity(0.03), [command(0x1D, f32(2700.0))]),
        (lambda: joint.set_drive_current(30), [command(0x19, bytes([30]))]),
        (lambda: joint.set_hold_current(25), [command(0x1A, bytes([25]))]),
        (lambda: joint.set_brake_mode(BrakeMode.HARDBRAKE), [command(0x22, bytes([2]))]),
        (lambda: joint.move_steps(-100), [command(0x13, struct.pack("<i", -100))]),
        (joint.stop, [command(0x29, bytes([0]))]),
        (lambda: joint.enable(40, 40), [command(0x10, bytes([40, 40, 0, 0]))]),
        (lambda: joint.set_max_acceleration(0.001), [command(0x1B, f32(90.0))]),
        # 0.003 m/s on J2 is 45 motor RPM, direction 0; the original truncated a double 44.999 to 44.
        (lambda: joint.start_homing(0.003, 50, 30), [command(0x2D, bytes([0, 45, 50, 30]))]),
        (joint.get_velocity, [read(0x2C, 4)]),
    ]
    for call, expected in steps:
        fake.calls.clear()
        call()
        assert fake.calls == expected, call

    joint.wait_while_busy(0.1, 30.0)
    fake.calls.clear()
    joint.post_homing()
    assert fake.calls == [read(0x0F, 1), command(0x2E, f32(0.338))]

    steps = [
        (joint.get_position, [read(0x18, 4)]),
        (joint.get_homing_offset, [read(0x2E, 4)]),
        (joint.check_com, [read(0x0F, 1)]),
        (lambda: joint.set_position(0.2), [command(0x15, f32(math.degrees(r * (0.2 - 0.338))))]),
        (lambda: joint.set_velocity(-0.01), [command(0x11, f32(math.degrees(r * -0.01) / 6))]),
        (joint.disable_closed_loop, [command(0x26, bytes([0]))]),
        (joint.disable, [command(0x29, bytes([0])), command(0x1A, bytes([0])), command(0x19, bytes([0])),
                         command(0x22, bytes([0]))]),
    ]
    for call, expected in steps:
        fake.calls.clear()
        joint.flags_time = joint.bus.monotonic()  # flags from this cycle: no refresh PING first
        call()
        assert fake.calls == expected, call


def test_check_orientation_sends_raw_motor_degrees_then_polls(wire: tuple[Joint, FakeSMBus]) -> None:
    joint, fake = wire
    joint.init()
    joint.enable(40, 40)
    fake.calls.clear()
    joint.check_orientation(2.0)
    assert fake.calls[0] == command(0x2B, f32(2.0))
    assert all(call == read(0x0F, 1) for call in fake.calls[1:]) and len(fake.calls) > 1


def test_a_nack_is_a_comm_error_after_three_attempts(wire: tuple[Joint, FakeSMBus]) -> None:
    joint, fake = wire
    missing = Joint("j9", 0x19, joint.bus)
    with pytest.raises(CommError, match="0x19.*EREMOTEIO.*after 3 attempts"):
        missing.init()
    assert len(fake.calls) == 3 and missing.flags == 0x0C and not missing.is_open
