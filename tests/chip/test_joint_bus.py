"""The deployed joint firmware on the emulated Pico answers the original register map over its I2C0
target, driven by the emulated controller at 400 kHz, hard IRQ path, byte for byte as the simulator.

Without the joint's devices (TMC2209, AS5600 fakes) the motor backend fails at boot: the joint is
disabled but on the bus, answering reads and rejecting commands with its flags, as the simulated
joint with a failing motor does.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from chip.board import EmulatedPico
from chip.i2c import ChipBus, JointBusClient, joint_bus_plugin
from chip.testing import joint_image, requires_chip  # noqa: F401 (joint_image is a fixture)
from harness import Rig
from joint.spec import protocol as P

pytestmark = requires_chip

ADDRESS = 0x11  # J1


def valid_value(field: P.Field) -> float | int:
    if field.kind == P.U8:
        return field.lo
    if field.kind == P.F32:
        return field.lo if field.lo > 0 else min(1.0, field.hi)
    return 100


def register_reads() -> list[tuple[bytes, int]]:
    """Every readable register as the original host reads it: [reg], repeated START, payload + flags."""
    return [(bytes([reg.addr]), reg.rsize + 1) for reg in P.REGISTERS if reg.readable]


def commands() -> list[tuple[bytes, int]]:
    """Every command as the original host sends it, [reg, payload] then the flags, each followed by
    a LASTERROR read; unimplemented and unknown registers too."""
    lasterror = (bytes([P.LASTERROR]), P.register("LASTERROR").rsize + 1)
    out: list[tuple[bytes, int]] = []
    for reg in P.REGISTERS:
        if reg.writable:
            out += [(bytes([reg.addr]) + reg.encode(*[valid_value(f) for f in reg.write]), 1), lasterror]
        elif not reg.supported:
            out += [(bytes([reg.addr, 0]), 1), lasterror]
    return out + [(bytes([0x05]), 1), lasterror]


def assert_same_replies(bus: JointBusClient, transactions: list[tuple[bytes, int]]) -> None:
    rig = disabled_reference()
    wrong = []
    for write, read_len in transactions:
        t = bus.transfer(ADDRESS, write, read_len, gap_us=2000)
        expected = bytes(rig.xfer(write, read_len))
        rig.run_ms(2)
        assert t.ack, f"NAK for {write.hex()}"
        if t.data != expected:
            wrong.append(f"{write.hex()}: chip {t.data.hex()}, simulator {expected.hex()}")
        # The rest of the transaction is wire time at 400 kHz: the bit-time formula holds.
        assert t.bits == P.wire_bits(len(write), read_len)
        assert abs(t.total_us - t.scl_held_us - t.bits * 2.5) < 0.01
    assert not wrong, "\n".join(wrong)


def disabled_reference() -> Rig:
    """The simulated joint whose motor backend fails at boot, as the emulated one's does."""
    rig = Rig(boot=False)

    def broken() -> None:
        raise OSError(5, "no reply from the TMC2209")
    rig.motor.begin = broken
    rig.run_ms(5)
    assert rig.core.disabled and rig.core.ready
    return rig


@pytest.fixture(scope="module")
def joint_bus(joint_image: Path) -> Iterator[JointBusClient]:
    with EmulatedPico(joint_image, plugins=[joint_bus_plugin(khz=400)]) as pico:
        bus = JointBusClient(pico)
        # Boot: the joint joins the bus once its boot sequence has ended (here: motor fault).
        for _ in range(200):
            if bus.transfer(ADDRESS, None, 0, gap_us=20_000).ack:
                break
        else:
            pytest.fail(f"the joint never joined the bus: {pico.stderr_text()}")
        yield bus


def test_every_register_reads_as_in_the_simulator(joint_bus: JointBusClient) -> None:
    assert_same_replies(joint_bus, register_reads())


def test_every_command_is_answered_as_in_the_simulator(joint_bus: JointBusClient) -> None:
    # 5-byte commands at 400 kHz: the last byte and the repeated START reach the rp2 driver in one
    # interrupt, START_DET first; END_WRITE must take that byte from the FIFO (chip/README.md).
    assert_same_replies(joint_bus, commands())


def test_the_hard_irq_path_stretches_reads_not_writes(joint_bus: JointBusClient) -> None:
    ping = joint_bus.transfer(ADDRESS, bytes([P.PING]), 2, gap_us=2000)
    assert ping.data == bytes([P.ACK, P.FLAGS_AT_BOOT])
    assert ping.scl_held_us > 20, "the reply waits for the Python IRQ handler"
    assert ping.irq_cpu_us is not None and ping.irq_cpu_us > ping.scl_held_us / 2
    write = joint_bus.transfer(ADDRESS, bytes([P.PING, 1, 2]), 0, gap_us=2000)
    assert write.scl_held_us == 0, "received bytes are ACKed by the hardware"


def test_the_host_package_reaches_the_joint_unmodified(joint_bus: JointBusClient) -> None:
    from bioscara.joint import Joint

    bus = ChipBus(joint_bus)
    assert ADDRESS in bus.scan(0x10, 0x12)
    joint = Joint("J1", ADDRESS, bus)
    joint.init()  # PING
    identity = joint.identity()
    assert identity.spec_matches and identity.joint_id == 1
    assert not joint.is_enabled() and not joint.is_homed()
    assert bus.transactions[-1].scl_held_us > 0, "each transaction carries the chip's timing"


def test_back_to_back_transactions_each_reach_the_joint_whole(joint_bus: JointBusClient) -> None:
    """The original host's cycle with no gap between transactions at 400 kHz: a STOP the rp2
    driver services after the next START and first byte makes it end that write early; the
    joint still judges every frame whole (LASTERROR names the register and reason the simulator's
    does, not a fragment)."""
    setrpm = P.register("SETRPM")
    cycle = [(bytes([P.ANGLEMOVED]), 5), (bytes([P.GETENCODERRPM]), 5),
             (bytes([P.SETRPM]) + setrpm.encode(10.0), 1)]
    last_error = bytes([P.LASTERROR]), 5
    before = joint_bus.transfer(ADDRESS, *last_error, gap_us=2000).data
    done = joint_bus.schedule([(ADDRESS, w, r) for w, r in cycle], repeat=10, period_us=10_000)
    rig = disabled_reference()
    assert [t.data for t in done] == [bytes(rig.xfer(w, r)) for _ in range(10) for w, r in cycle]
    after = joint_bus.transfer(ADDRESS, *last_error, gap_us=2000).data
    assert after[:2] == bytes(rig.xfer(*last_error))[:2] == bytes([P.REJECT_DISABLED, P.SETRPM])
    rejects = int.from_bytes(after[2:4], "little") - int.from_bytes(before[2:4], "little")
    assert rejects == 10, "one reject per SETRPM frame, none for fragments"
