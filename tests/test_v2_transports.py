"""Protocol v2 over every transport: one combined transaction (7-byte mailbox write, repeated
START, 8-byte state read) through smbus2's i2c_rdwr, Blinka's writeto_then_readfrom, the HIL
bridge's XFER (the simulator's pseudo-terminal) and the simulated bus."""

from __future__ import annotations

import ctypes
from collections.abc import Iterator
from dataclasses import replace

import pytest
from smbus2 import i2c_msg

from bioscara.transports import open_bus
from bioscara.bus.base import Bus
from bioscara.bus.blinka import BlinkaBus
from bioscara.bus.sim import SimBus, SimJointSpec
from bioscara.firmware.spec import protocol as P
from bioscara.bus.smbus import SMBusBus
from bioscara.firmware.spec import protocol_v2 as V
from bioscara.joint import Joint
from bioscara.sim_server import SimServer

J1 = SimJointSpec("J1", 0x11, 35.0, -3.04647, 3.04647, 0.0)


class Wire:
    """Records what each transport put on the wire: (write bytes, read length) per transaction."""

    def __init__(self, sim: SimBus) -> None:
        self.sim = sim
        self.transactions: list[tuple[bytes, int]] = []

    def transfer(self, addr: int, write: bytes, read_len: int) -> bytes:
        self.transactions.append((write, read_len))
        return self.sim.sim.transfer(addr, write, read_len)


class FakeSMBus:
    def __init__(self, wire: Wire) -> None:
        self.wire = wire

    def i2c_rdwr(self, *messages: i2c_msg) -> None:
        write, read = messages  # one I2C_RDWR: write, repeated START, read
        assert not write.flags & 1 and read.flags & 1
        reply = self.wire.transfer(write.addr, bytes(write), read.len)
        ctypes.memmove(read.buf, reply, read.len)

    def close(self) -> None:
        pass


class FakeBusio:
    def __init__(self, wire: Wire) -> None:
        self.wire = wire

    def try_lock(self) -> bool:
        return True

    def unlock(self) -> None:
        pass

    def deinit(self) -> None:
        pass

    def writeto_then_readfrom(self, addr: int, out: bytes, into: bytearray) -> None:
        into[:] = self.wire.transfer(addr, bytes(out), len(into))


def _clocked(cls: type[Bus], sim: SimBus) -> type[Bus]:
    """The transport class with its waits on the simulation's clock."""
    return type(cls.__name__, (cls,), {"sleep": lambda self, s: sim.sleep(s),
                                       "monotonic": lambda self: sim.monotonic()})


@pytest.fixture(params=["smbus", "blinka", "sim"])
def transport(request: pytest.FixtureRequest) -> Iterator[tuple[Bus, Wire]]:
    sim = SimBus([J1])
    wire = Wire(sim)
    if request.param == "smbus":
        yield _clocked(SMBusBus, sim)(1, smbus_factory=lambda _: FakeSMBus(wire)), wire
    elif request.param == "blinka":
        yield _clocked(BlinkaBus, sim)(i2c=FakeBusio(wire)), wire
    else:
        original = sim._transfer_once
        sim._transfer_once = lambda addr, write, n: (wire.transactions.append((write, n)),  # type: ignore
                                                     original(addr, write, n))[1]
        yield sim, wire


def test_v2_runs_through_each_transport_one_transaction_per_exchange(transport: tuple[Bus, Wire]) -> None:
    bus, wire = transport
    joint = Joint("j1", 0x11, bus, reduction=35.0, min=-3.0, max=3.0, max_velocity=1.0)
    joint.init()
    joint.use_v2()
    joint.enable(40, 30)
    assert joint.is_enabled() and joint.protocol == "v2"
    wire.transactions.clear()
    samples = []
    for _ in range(10):
        samples.append(joint.cycle())
        bus.sleep(0.002)
    assert len(wire.transactions) == 10, "one transaction per exchange"
    assert all(len(w) == V.MAILBOX_SIZE and n == V.STATE_SIZE for w, n in wire.transactions)
    assert all(s is not None for s in samples[1:])
    joint.close()  # back to legacy
    assert bus.transfer(0x11, b"\x0f", 2)[0] == ord("O")


def test_v2_through_the_hil_bridge_on_the_simulators_pty() -> None:
    specs = [replace(J1, deadman_ms=500)]
    with SimServer(specs, seed=1) as server:
        bus = open_bus(f"serial:{server.bridge_path}")
        try:
            joint = Joint("j1", 0x11, bus, reduction=35.0, min=-3.0, max=3.0, max_velocity=1.0)
            joint.init()
            joint.use_v2()
            joint.enable(40, 30)
            assert joint.is_enabled()
            for _ in range(5):
                assert joint.link.read(P.register(P.PING))[1] == joint.flags
            joint.close()
            assert bus.transfer(0x11, b"\x0f", 2)[0] == ord("O"), "legacy again"
            assert bus.link.crc_errors == 0 and bus.link.timeouts == 0
        finally:
            bus.close()


def test_auto_keeps_a_joint_that_cannot_switch_on_legacy_and_the_arm_cycles_both(config, bus) -> None:
    from bioscara.arm import Arm
    from bioscara.communicator import Communicator
    from bioscara.errors import CommError
    from bioscara.firmware.spec import protocol as P
    bus.joint(0x11).core._handlers[P.PROTOCOL] = lambda q, off: None  # as on CircuitPython: no mem mode
    arm = Arm(config, bus, "auto")
    arm.configure()
    assert [aj.joint.protocol for aj in arm.joints.values()] == ["legacy", "v2", "v2", "v2"]
    Communicator(arm, 100.0, realtime_priority=None).run_for(0.2)
    assert all(aj.state.home == 0.0 and aj.joint.flags == P.FLAGS_AT_BOOT for aj in arm.joints.values())
    arm.cleanup()
    strict = Arm(config, bus, "v2")
    with pytest.raises(CommError, match="does not answer in protocol v2"):
        strict.configure()
